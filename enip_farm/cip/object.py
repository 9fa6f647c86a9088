"""Common CIP object behaviour (CIP Networks Library Vol. 1, chapter 4 and appendix A): attribute
tables, class-level attributes, and the common services every object answers: Get/Set Attribute
Single, Get Attributes All, and Get/Set_Attribute_List (A-4.3, A-4.4).

Get_Attribute_List (0x03) request: attribute count UINT, then each attribute id UINT; reply: the
count, then per attribute its id UINT, its status UINT and, on success, its value. Set_Attribute_List
(0x04) request: the count, then per attribute its id UINT and its value; reply: the count, then per
attribute id and status. A failed attribute fails only itself; the general status is then 0x0A
(attribute list error), as OpENer's cipcommon.c answers. Parsing a Set list needs each value's
length: an attribute of fixed size gives it by its own encoded value, a variable one (a string, a
counted array) says how to read it from the request (`Attribute.size`). An attribute the object
does not have, or a value cut short, ends the list there: what follows cannot be parsed, so the
reply lists the attributes up to it (the count says how many).
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


#: How many bytes an attribute's value takes at the start of some request data; None if it cannot tell.
SizeOf = Callable[[bytes], "int | None"]


class Attribute(NamedTuple):
    """`get` returns the encoded value; `set`, when present, takes encoded data, returns a status;
    `size` reads the length of a value in request data (Set_Attribute_List), needed for values of
    variable size only: without it the value's size is that of the attribute's own encoded value."""

    get: Callable[[], bytes]
    set: Callable[[bytes], int] | None = None
    size: SizeOf | None = None

    def size_in(self, data: bytes) -> int | None:
        return len(self.get()) if self.size is None else self.size(data)


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


class CipInstance:
    """An instance (or the class itself, as instance 0): its attributes, in id order. `all_ids` are
    the attributes Get Attributes All returns, in order; `all_defaults` gives the bytes it returns
    for those among them the instance does not have (the spec's defaults for optional attributes)."""

    __slots__ = ("attributes", "all_ids", "all_defaults")

    def __init__(self, attributes: dict[int, Attribute], all_ids: tuple[int, ...] | None = None,
                 all_defaults: dict[int, bytes] | None = None) -> None:
        self.attributes = attributes
        self.all_ids = tuple(sorted(attributes)) if all_ids is None else all_ids
        self.all_defaults = all_defaults or {}


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


def fixed_size(size: int) -> SizeOf:
    return lambda data: size


def short_string_size(data: bytes) -> int | None:
    """SHORT_STRING: a USINT length and the characters."""
    return 1 + data[0] if data else None


def string_size(data: bytes) -> int | None:
    """STRING as the TCP/IP object carries it: a UINT length, the characters, a pad byte if odd."""
    if len(data) < UINT.size:
        return None
    (length,) = UINT.unpack_from(data)
    return UINT.size + length + (length & 1)


def short_string(text: str) -> bytes:
    raw = text.encode("latin-1")
    return bytes((len(raw),)) + raw


def cip_string(text: str) -> bytes:
    """STRING: UINT length and characters, padded to an even length (as the TCP/IP object uses)."""
    raw = text.encode("latin-1")
    return UINT.pack(len(raw)) + raw + (b"\x00" if len(raw) % 2 else b"")


def uint_list(values: tuple[int, ...]) -> bytes:
    """A UINT count and that many UINTs (class attributes 4 and 5)."""
    return struct.pack(f"<H{len(values)}H", len(values), *values)


def uint_list_size(data: bytes) -> int | None:
    return UINT.size * (1 + UINT.unpack_from(data)[0]) if len(data) >= UINT.size else None


class CipClass:
    """A CIP object class. Subclasses set `class_id`, `revision`, add instances and services.

    The class attributes (Vol. 1, 4-4.1): 1 revision, 2 max instance, 3 number of instances, 4 the
    optional instance attributes implemented and 5 the optional services implemented (each a UINT
    count and that many UINTs; subclasses list them in `optional_attributes`/`optional_services`),
    6 the highest class attribute id, 7 the highest instance attribute id. Get Attributes All of
    instance 0 answers 1-7 in that order, as Wireshark's CIP dissector decodes them."""

    class_id: int = 0
    revision: int = 1
    optional_attributes: tuple[int, ...] = ()
    optional_services: tuple[int, ...] = ()

    def __init__(self) -> None:
        self.instances: dict[int, CipInstance] = {}
        self.class_instance = CipInstance(
            {
                1: Attribute(lambda: UINT.pack(self.revision)),
                2: Attribute(lambda: UINT.pack(max(self.instances, default=0))),
                3: Attribute(lambda: UINT.pack(len(self.instances))),
                4: Attribute(lambda: uint_list(self.optional_attributes), size=uint_list_size),
                5: Attribute(lambda: uint_list(self.optional_services), size=uint_list_size),
                6: Attribute(lambda: UINT.pack(max(self.class_instance.attributes))),
                7: Attribute(lambda: UINT.pack(max((max(i.attributes, default=0)
                                                     for i in self.instances.values()), default=0))),
            },
            all_ids=(1, 2, 3, 4, 5, 6, 7),
        )
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
        attributes, defaults = instance.attributes, instance.all_defaults
        return ServiceResult(GeneralStatus.SUCCESS, b"".join(
            attributes[i].get() if i in attributes else defaults[i] for i in instance.all_ids))

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
        size = UINT.size
        for attribute_id in ids:
            attribute = instance.attributes.get(attribute_id)
            if attribute is None:
                entry = _ENTRY.pack(attribute_id, GeneralStatus.ATTRIBUTE_NOT_SUPPORTED)
                status = GeneralStatus.ATTRIBUTE_LIST_ERROR
            else:
                entry = _ENTRY.pack(attribute_id, GeneralStatus.SUCCESS) + attribute.get()
            if size + len(entry) > MAX_LIST_REPLY_DATA:  # the rest would not fit: say so, as OpENer does
                if status == GeneralStatus.SUCCESS:
                    status = GeneralStatus.PARTIAL_TRANSFER
                break
            entries.append(entry)
            size += len(entry)
        return ServiceResult(status, UINT.pack(len(entries)) + b"".join(entries))

    @staticmethod
    def set_attribute_list(instance: CipInstance, path: RequestPath, data: bytes,
                           context: MessageContext) -> ServiceResult:
        if len(data) < UINT.size:
            return ServiceResult(GeneralStatus.NOT_ENOUGH_DATA)
        (count,) = UINT.unpack_from(data)
        if count == 0:
            return ServiceResult(GeneralStatus.ATTRIBUTE_LIST_ERROR)  # as OpENer: an empty list is an error
        # parse the whole list first: a request with bytes left over sets nothing
        parsed: list[tuple[int, Attribute | None, bytes | int]] = []  # id, attribute, value or status
        offset = UINT.size
        for _ in range(count):
            if offset + UINT.size > len(data):
                return ServiceResult(GeneralStatus.NOT_ENOUGH_DATA)
            (attribute_id,) = UINT.unpack_from(data, offset)
            offset += UINT.size
            attribute = instance.attributes.get(attribute_id)
            if attribute is None:  # its value's length is unknown: the list ends here
                parsed.append((attribute_id, None, GeneralStatus.ATTRIBUTE_NOT_SUPPORTED))
                break
            size = attribute.size_in(data[offset:])
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
            elif attribute is None or attribute.set is None:
                status = GeneralStatus.ATTRIBUTE_NOT_SETTABLE
            else:
                status = attribute.set(value)  # type: ignore[arg-type]
            failed = failed or status != GeneralStatus.SUCCESS
            entries.append(_ENTRY.pack(attribute_id, status))
        return ServiceResult(GeneralStatus.ATTRIBUTE_LIST_ERROR if failed else GeneralStatus.SUCCESS,
                             UINT.pack(len(entries)) + b"".join(entries))


#: Each attribute of a list reply: its id and status (a status byte and a reserved zero byte).
_ENTRY = struct.Struct("<HH")
#: Get_Attribute_List replies stop short of this many data bytes (general status 0x06 then): the
#: usual size limit of an unconnected explicit message; OpENer stops at its 512-byte buffer.
MAX_LIST_REPLY_DATA = 504


def _attribute_ids(data: bytes) -> tuple[int, ...] | int:
    """A Get_Attribute_List request's ids, or the general status for a malformed one."""
    if len(data) < UINT.size:
        return GeneralStatus.NOT_ENOUGH_DATA
    (count,) = UINT.unpack_from(data)
    end = UINT.size * (1 + count)
    if len(data) < end:
        return GeneralStatus.NOT_ENOUGH_DATA
    if len(data) > end:
        return GeneralStatus.TOO_MUCH_DATA
    return struct.unpack_from(f"<{count}H", data, UINT.size)
