"""Common CIP object behaviour (CIP Networks Library Vol. 1, chapter 4 and appendix A): the
class-level attributes and the common services every object answers from its declared attributes
(cip/attribute.py): Get/Set Attribute Single, Get Attributes All, and Get/Set_Attribute_List
(A-4.3, A-4.4).

Get_Attribute_List (0x03) request: attribute count UINT, then each attribute id UINT; reply: the
count, then per attribute its id UINT, its status UINT and, on success, its value. Set_Attribute_List
(0x04) request: the count, then per attribute its id UINT and its value; reply: the count, then per
attribute id and status. A failed attribute fails only itself; the general status is then 0x0A
(attribute list error), as OpENer's cipcommon.c answers. Parsing a Set list needs each value's
length: the attribute's data type reads it from the request (`CipType.size_in`). An attribute the object
does not have, or a value cut short, ends the list there: what follows cannot be parsed, so the
reply lists the attributes up to it (the count says how many).
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from typing import NamedTuple

from enip_farm.cip.attribute import GET_ALL, Access, Attribute, CipInstance
from enip_farm.cip.data_types import UINT, UINT_LIST
from enip_farm.protocol.cip import Service
from enip_farm.protocol.epath import RequestPath
from enip_farm.protocol.session import MessageContext, ReplyItems
from enip_farm.protocol.status import GeneralStatus


class Effect:
    """What a service asks of its device beyond the reply (the Identity object's `ResetRequested`):
    a value the service returns, which the message router queues (`MessageRouter.pop_effects`) and
    the device carries out once the reply is built, never a call into the device."""

    __slots__ = ()


class ServiceResult(NamedTuple):
    status: int
    data: bytes = b""
    additional_status: tuple[int, ...] = ()
    items: ReplyItems = ()
    effects: tuple[Effect, ...] = ()


class Reply(NamedTuple):
    """A whole encoded reply message and the CPF items that go beside it."""

    message: bytes
    items: ReplyItems = ()


#: A service handler: instance, parsed path, request data, context -> result, or a whole reply.
Handler = Callable[[CipInstance, RequestPath, bytes, MessageContext], "ServiceResult | Reply"]

NOT_SUPPORTED = ServiceResult(GeneralStatus.SERVICE_NOT_SUPPORTED)
ATTRIBUTE_NOT_SUPPORTED = ServiceResult(GeneralStatus.ATTRIBUTE_NOT_SUPPORTED)


class CipClass:
    """A CIP object class. Subclasses set `class_id`, `revision`, add instances and services.

    The class attributes (Vol. 1, 4-4.1): 1 revision, 2 max instance, 3 number of instances, 4 the
    optional instance attributes implemented and 5 the optional services implemented (each a UINT
    count and that many UINTs; subclasses list them in `optional_attributes`/`optional_services`),
    6 the highest class attribute id, 7 the highest instance attribute id.

    Get Attributes All of instance 0 answers the attributes in `class_get_all`, in id order. Each
    object's definition says which: 1 revision, 2 max instance, 6 and 7 the highest ids for most
    objects (a real 1769-L23E answers its Identity class so, `01 00 01 00 07 00 07 00`, and
    Wireshark's CIP dissector decodes these four); the TCP/IP Interface and Ethernet Link objects
    of Vol. 2 answer 1-7 (Wireshark's ENIP dissector decodes those seven).
    """

    class_id: int = 0
    revision: int = 1
    optional_attributes: tuple[int, ...] = ()
    optional_services: tuple[int, ...] = ()
    #: The class attributes Get Attributes All of instance 0 returns, in id order.
    class_get_all: tuple[int, ...] = (1, 2, 6, 7)

    def __init__(self) -> None:
        self.instances: dict[int, CipInstance] = {}
        def access(attribute_id: int) -> Access:
            return GET_ALL if attribute_id in self.class_get_all else Access.GET

        self.class_instance = CipInstance((
            Attribute(1, UINT, lambda: self.revision, access=access(1)),
            Attribute(2, UINT, lambda: max(self.instances, default=0), access=access(2)),
            Attribute(3, UINT, lambda: len(self.instances), access=access(3)),
            Attribute(4, UINT_LIST, lambda: self.optional_attributes, access=access(4)),
            Attribute(5, UINT_LIST, lambda: self.optional_services, access=access(5)),
            Attribute(6, UINT, lambda: max(self.class_instance.served_ids()), access=access(6)),
            Attribute(7, UINT, lambda: max((max(i.served_ids(), default=0) for i in self.instances.values()),
                                           default=0), access=access(7)),
        ))
        self.handlers: dict[int, Handler] = {
            Service.GET_ATTRIBUTE_SINGLE: self.get_attribute_single,
            Service.SET_ATTRIBUTE_SINGLE: self.set_attribute_single,
            Service.GET_ATTRIBUTES_ALL: self.get_attributes_all,
            Service.GET_ATTRIBUTE_LIST: self.get_attribute_list,
            Service.SET_ATTRIBUTE_LIST: self.set_attribute_list,
        }

    def instance(self, instance_id: int) -> CipInstance | None:
        return self.class_instance if instance_id == 0 else self.instances.get(instance_id)

    @staticmethod
    def get_attribute_single(instance: CipInstance, path: RequestPath, data: bytes,
                             context: MessageContext) -> ServiceResult:
        attribute = instance.attributes.get(path.attribute_id)  # type: ignore[arg-type]
        if attribute is None or not attribute.gettable:
            return ATTRIBUTE_NOT_SUPPORTED
        return ServiceResult(GeneralStatus.SUCCESS, attribute.read())

    @staticmethod
    def set_attribute_single(instance: CipInstance, path: RequestPath, data: bytes,
                             context: MessageContext) -> ServiceResult:
        attribute = instance.served(path.attribute_id)
        if attribute is None:
            return ATTRIBUTE_NOT_SUPPORTED
        return ServiceResult(attribute.write(data))

    @staticmethod
    def get_attributes_all(instance: CipInstance, path: RequestPath, data: bytes,
                             context: MessageContext) -> ServiceResult:
        return ServiceResult(GeneralStatus.SUCCESS, instance.get_attributes_all())

    @staticmethod
    def get_attribute_list(instance: CipInstance, path: RequestPath, data: bytes,
                           context: MessageContext) -> ServiceResult:
        ids = _attribute_ids(data)
        if type(ids) is not tuple:
            return ServiceResult(ids)
        if not ids:
            return ServiceResult(GeneralStatus.ATTRIBUTE_LIST_ERROR)  # as OpENer: an empty list is an error
        status = GeneralStatus.SUCCESS
        entries = []
        size = _COUNT.size
        for attribute_id in ids:
            attribute = instance.attributes.get(attribute_id)
            if attribute is None or not attribute.gettable:
                entry = _ENTRY.pack(attribute_id, GeneralStatus.ATTRIBUTE_NOT_SUPPORTED)
                status = GeneralStatus.ATTRIBUTE_LIST_ERROR
            else:
                entry = _ENTRY.pack(attribute_id, GeneralStatus.SUCCESS) + attribute.read()
            if size + len(entry) > MAX_LIST_REPLY_DATA:  # the rest would not fit: say so, as OpENer does
                if status == GeneralStatus.SUCCESS:
                    status = GeneralStatus.PARTIAL_TRANSFER
                break
            entries.append(entry)
            size += len(entry)
        return ServiceResult(status, _COUNT.pack(len(entries)) + b"".join(entries))

    @staticmethod
    def set_attribute_list(instance: CipInstance, path: RequestPath, data: bytes,
                           context: MessageContext) -> ServiceResult:
        if len(data) < _COUNT.size:
            return ServiceResult(GeneralStatus.NOT_ENOUGH_DATA)
        (count,) = _COUNT.unpack_from(data)
        if count == 0:
            return ServiceResult(GeneralStatus.ATTRIBUTE_LIST_ERROR)  # as OpENer: an empty list is an error
        # parse the whole list first: a request with bytes left over sets nothing
        parsed: list[tuple[int, Attribute | None, bytes | int]] = []  # id, attribute, value or status
        offset = _COUNT.size
        for _ in range(count):
            if offset + _COUNT.size > len(data):
                return ServiceResult(GeneralStatus.NOT_ENOUGH_DATA)
            (attribute_id,) = _COUNT.unpack_from(data, offset)
            offset += _COUNT.size
            attribute = instance.served(attribute_id)
            if attribute is None:  # its value's length is unknown: the list ends here
                parsed.append((attribute_id, None, GeneralStatus.ATTRIBUTE_NOT_SUPPORTED))
                break
            size = attribute.type.size_in(data[offset:])
            if size is None or offset + size > len(data):
                parsed.append((attribute_id, attribute, GeneralStatus.NOT_ENOUGH_DATA))
                break
            parsed.append((attribute_id, attribute, data[offset : offset + size]))
            offset += size
        else:
            if offset < len(data):
                return ServiceResult(GeneralStatus.TOO_MUCH_DATA)
        entries = []
        failed = False
        for attribute_id, attribute, value in parsed:
            if isinstance(value, int):
                status = value
            else:
                status = attribute.write(value)  # type: ignore[union-attr]
            failed = failed or status != GeneralStatus.SUCCESS
            entries.append(_ENTRY.pack(attribute_id, status))
        return ServiceResult(GeneralStatus.ATTRIBUTE_LIST_ERROR if failed else GeneralStatus.SUCCESS,
                             _COUNT.pack(len(entries)) + b"".join(entries))


#: The attribute count of a list request or reply.
_COUNT = struct.Struct("<H")
#: Each attribute of a list reply: its id and status (a status byte and a reserved zero byte).
_ENTRY = struct.Struct("<HH")
#: Get_Attribute_List replies stop short of this many data bytes (general status 0x06 then): the
#: usual size limit of an unconnected explicit message; OpENer stops at its 512-byte buffer.
MAX_LIST_REPLY_DATA = 504


def _attribute_ids(data: bytes) -> tuple[int, ...] | int:
    """A Get_Attribute_List request's ids, or the general status for a malformed one."""
    if len(data) < _COUNT.size:
        return GeneralStatus.NOT_ENOUGH_DATA
    (count,) = _COUNT.unpack_from(data)
    end = _COUNT.size * (1 + count)
    if len(data) < end:
        return GeneralStatus.NOT_ENOUGH_DATA
    if len(data) > end:
        return GeneralStatus.TOO_MUCH_DATA
    return struct.unpack_from(f"<{count}H", data, _COUNT.size)
