"""Common CIP object behaviour (CIP Networks Library Vol. 1, chapter 4 and appendix A): attribute
tables, class-level attributes, and the Get/Set Attribute Single and Get Attributes All services.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from typing import NamedTuple

from enip_farm.protocol.cip import Service
from enip_farm.protocol.epath import RequestPath
from enip_farm.protocol.session import MessageContext, ReplyItems
from enip_farm.protocol.status import GeneralStatus

UINT = struct.Struct("<H")
UDINT = struct.Struct("<I")


class Attribute(NamedTuple):
    """`get` returns the encoded value; `set`, when present, takes encoded data, returns a status."""

    get: Callable[[], bytes]
    set: Callable[[bytes], int] | None = None


class ServiceResult(NamedTuple):
    status: int
    data: bytes = b""
    additional_status: tuple[int, ...] = ()
    items: ReplyItems = ()


class Reply(NamedTuple):
    """A whole encoded reply message and the CPF items that go beside it."""

    message: bytes
    items: ReplyItems = ()


class CipInstance:
    """An instance (or the class itself, as instance 0): its attributes, in id order."""

    __slots__ = ("attributes", "all_ids")

    def __init__(self, attributes: dict[int, Attribute], all_ids: tuple[int, ...] | None = None) -> None:
        self.attributes = attributes
        self.all_ids = tuple(sorted(attributes)) if all_ids is None else all_ids


#: A service handler: instance, parsed path, request data, context -> result, or a whole reply.
Handler = Callable[[CipInstance, RequestPath, bytes, MessageContext], "ServiceResult | Reply"]

NOT_SUPPORTED = ServiceResult(GeneralStatus.SERVICE_NOT_SUPPORTED)
ATTRIBUTE_NOT_SUPPORTED = ServiceResult(GeneralStatus.ATTRIBUTE_NOT_SUPPORTED)
NOT_SETTABLE = ServiceResult(GeneralStatus.ATTRIBUTE_NOT_SETTABLE)


def constant(value: bytes) -> Attribute:
    return Attribute(lambda: value)


def uint(value: int) -> Attribute:
    return constant(UINT.pack(value))


def udint(value: int) -> Attribute:
    return constant(UDINT.pack(value))


def short_string(text: str) -> bytes:
    raw = text.encode("latin-1")
    return bytes((len(raw),)) + raw


def cip_string(text: str) -> bytes:
    """STRING: UINT length and characters, padded to an even length (as the TCP/IP object uses)."""
    raw = text.encode("latin-1")
    return UINT.pack(len(raw)) + raw + (b"\x00" if len(raw) % 2 else b"")


class CipClass:
    """A CIP object class. Subclasses set `class_id`, `revision`, add instances and services."""

    class_id: int = 0
    revision: int = 1

    def __init__(self) -> None:
        self.instances: dict[int, CipInstance] = {}
        self.class_instance = CipInstance(
            {
                1: Attribute(lambda: UINT.pack(self.revision)),
                2: Attribute(lambda: UINT.pack(max(self.instances, default=0))),
                3: Attribute(lambda: UINT.pack(len(self.instances))),
                6: Attribute(lambda: UINT.pack(7)),
                7: Attribute(lambda: UINT.pack(max((max(i.attributes, default=0)
                                                     for i in self.instances.values()), default=0))),
            }
        )
        self.handlers: dict[int, Handler] = {
            Service.GET_ATTRIBUTE_SINGLE: self.get_attribute_single,
            Service.SET_ATTRIBUTE_SINGLE: self.set_attribute_single,
            Service.GET_ATTRIBUTES_ALL: self.get_attributes_all,
        }

    def instance(self, instance_id: int) -> CipInstance | None:
        return self.class_instance if instance_id == 0 else self.instances.get(instance_id)

    @staticmethod
    def get_attribute_single(instance: CipInstance, path: RequestPath, data: bytes,
                             context: MessageContext) -> ServiceResult:
        attribute = instance.attributes.get(path.attribute_id)  # type: ignore[arg-type]
        if attribute is None:
            return ATTRIBUTE_NOT_SUPPORTED
        return ServiceResult(GeneralStatus.SUCCESS, attribute.get())

    @staticmethod
    def set_attribute_single(instance: CipInstance, path: RequestPath, data: bytes,
                             context: MessageContext) -> ServiceResult:
        attribute = instance.attributes.get(path.attribute_id)  # type: ignore[arg-type]
        if attribute is None:
            return ATTRIBUTE_NOT_SUPPORTED
        if attribute.set is None:
            return NOT_SETTABLE
        return ServiceResult(attribute.set(data))

    @staticmethod
    def get_attributes_all(instance: CipInstance, path: RequestPath, data: bytes,
                             context: MessageContext) -> ServiceResult:
        return ServiceResult(GeneralStatus.SUCCESS,
                             b"".join(instance.attributes[i].get() for i in instance.all_ids))
