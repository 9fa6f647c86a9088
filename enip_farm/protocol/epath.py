"""EPATH: padded CIP paths (CIP Networks Library Vol. 1, appendix C-1).

Logical segments (class, instance, member, connection point, attribute; 8, 16 and 32-bit formats;
the electronic key), port segments (with extended link addresses and extended port numbers),
network segments (the safety network segment 0x50 kept whole, Vol. 5, 3-5.3) and simple data
segments. Decoding errors carry the CIP general status that the
message router returns for them: 0x26 (path size invalid: a segment cut short by the end of the
path, or no path at all, i.e. a path size "not large enough to allow the request to be routed to an
object", Vol. 1, appendix B, as OpENer answers `0E 01 21 00`) or 0x04 (path segment error: a
segment of a type or format the farm does not take, or in a place it does not belong).
"""

from __future__ import annotations

import struct
from enum import IntEnum
from typing import NamedTuple

from enip_farm.protocol.status import GeneralStatus

_UINT = struct.Struct("<H")
_UDINT = struct.Struct("<I")
_KEY = struct.Struct("<HHHBB")


class LogicalType(IntEnum):
    CLASS_ID = 0
    INSTANCE_ID = 1
    MEMBER_ID = 2
    CONNECTION_POINT = 3
    ATTRIBUTE_ID = 4
    SPECIAL = 5
    SERVICE_ID = 6


class LogicalSegment(NamedTuple):
    type: LogicalType
    value: int


class ElectronicKey(NamedTuple):
    """Key format 4. 0 in vendor, device type, product code or major revision is a wildcard."""

    vendor_id: int
    device_type: int
    product_code: int
    major_revision: int  # bits 0-6
    minor_revision: int
    compatibility: bool  # bit 7 of the major revision byte


class PortSegment(NamedTuple):
    port: int
    link_address: bytes


class NetworkSegment(NamedTuple):
    subtype: int
    value: int


class DataSegment(NamedTuple):
    data: bytes


class SafetyNetworkSegment(NamedTuple):
    """The safety network segment (0x50, then its size in words), its bytes from the 0x50 on."""

    raw: bytes


Segment = LogicalSegment | ElectronicKey | PortSegment | NetworkSegment | DataSegment | SafetyNetworkSegment


class PathError(ValueError):
    def __init__(self, status: int, reason: str) -> None:
        super().__init__(reason)
        self.status = status


def _segment_error(reason: str) -> PathError:
    return PathError(GeneralStatus.PATH_SEGMENT_ERROR, reason)


def _size_error(reason: str) -> PathError:
    """A segment that runs past the end of the path: the path size is too small for it."""
    return PathError(GeneralStatus.PATH_SIZE_INVALID, reason)


def decode_epath(path: bytes) -> list[Segment]:
    """Decode a padded EPATH whose length is already known (the request's path size in words)."""
    segments: list[Segment] = []
    offset = 0
    end = len(path)
    while offset < end:
        kind = path[offset]
        if kind < 0x20:
            segment, offset = _decode_port(path, offset)
        elif kind < 0x40:
            segment, offset = _decode_logical(path, offset)
        elif kind < 0x50:
            if offset + 2 > end:
                raise _size_error("truncated network segment")
            segment = NetworkSegment(kind, path[offset + 1])
            offset += 2
        elif kind == 0x50:
            if offset + 2 > end or offset + 2 + 2 * path[offset + 1] > end:
                raise _size_error("truncated safety network segment")
            stop = offset + 2 + 2 * path[offset + 1]
            segment = SafetyNetworkSegment(path[offset:stop])
            offset = stop
        elif kind == 0x80:
            if offset + 2 > end:
                raise _size_error("truncated data segment")
            stop = offset + 2 + 2 * path[offset + 1]
            if stop > end:
                raise _size_error("truncated data segment")
            segment = DataSegment(path[offset + 2 : stop])
            offset = stop
        else:
            raise _segment_error(f"unsupported segment type 0x{kind:02X}")
        segments.append(segment)
    return segments


def _decode_logical(path: bytes, offset: int) -> tuple[Segment, int]:
    kind = path[offset]
    logical_type = (kind >> 2) & 0x07
    fmt = kind & 0x03
    end = len(path)
    if logical_type == LogicalType.SPECIAL:
        if fmt != 0 or (offset + 1 < end and path[offset + 1] != 4):
            raise _segment_error("unsupported electronic key")
        if offset + 10 > end:
            raise _size_error("truncated electronic key")
        vendor, device_type, product, major, minor = _KEY.unpack_from(path, offset + 2)
        return ElectronicKey(vendor, device_type, product, major & 0x7F, minor, bool(major & 0x80)), offset + 10
    if logical_type > LogicalType.SERVICE_ID:
        raise _segment_error("reserved logical type")
    if fmt == 0:
        if offset + 2 > end:
            raise _size_error("truncated 8-bit logical segment")
        return LogicalSegment(LogicalType(logical_type), path[offset + 1]), offset + 2
    if fmt == 1:
        if offset + 4 > end:
            raise _size_error("truncated 16-bit logical segment")
        return LogicalSegment(LogicalType(logical_type), _UINT.unpack_from(path, offset + 2)[0]), offset + 4
    if fmt == 2:
        if offset + 6 > end:
            raise _size_error("truncated 32-bit logical segment")
        return LogicalSegment(LogicalType(logical_type), _UDINT.unpack_from(path, offset + 2)[0]), offset + 6
    raise _segment_error("reserved logical format")


def _decode_port(path: bytes, offset: int) -> tuple[PortSegment, int]:
    kind = path[offset]
    end = len(path)
    start = offset
    offset += 1
    extended_link = bool(kind & 0x10)
    port = kind & 0x0F
    link_size = 1
    if extended_link:
        if offset >= end:
            raise _size_error("truncated port segment")
        link_size = path[offset]
        offset += 1
    if port == 0x0F:
        if offset + 2 > end:
            raise _size_error("truncated extended port")
        port = _UINT.unpack_from(path, offset)[0]
        offset += 2
    if offset + link_size > end:
        raise _size_error("truncated link address")
    link = path[offset : offset + link_size]
    offset += link_size
    if (offset - start) % 2:
        offset += 1  # pad byte
    if offset > end:
        raise _size_error("missing pad byte")
    return PortSegment(port, link), offset


def encode_logical(logical_type: LogicalType | int, value: int) -> bytes:
    """Smallest format that holds the value (8, 16 or 32 bits, padded)."""
    kind = 0x20 | (int(logical_type) << 2)
    if value <= 0xFF:
        return bytes((kind, value))
    if value <= 0xFFFF:
        return bytes((kind | 1, 0)) + _UINT.pack(value)
    return bytes((kind | 2, 0)) + _UDINT.pack(value)


def encode_port(port: int, link_address: bytes | int) -> bytes:
    link = bytes((link_address,)) if isinstance(link_address, int) else link_address
    extended = len(link) > 1
    kind = (0x10 if extended else 0) | (port if port < 0x0F else 0x0F)
    out = bytes((kind,))
    if extended:
        out += bytes((len(link),))
    if port >= 0x0F:
        out += _UINT.pack(port)
    out += link
    return out + b"\x00" if len(out) % 2 else out


def encode_electronic_key(key: ElectronicKey) -> bytes:
    major = (key.major_revision & 0x7F) | (0x80 if key.compatibility else 0)
    return b"\x34\x04" + _KEY.pack(key.vendor_id, key.device_type, key.product_code, major, key.minor_revision)


def encode_request_path(class_id: int, instance_id: int | None = None, attribute_id: int | None = None) -> bytes:
    path = encode_logical(LogicalType.CLASS_ID, class_id)
    if instance_id is not None:
        path += encode_logical(LogicalType.INSTANCE_ID, instance_id)
    if attribute_id is not None:
        path += encode_logical(LogicalType.ATTRIBUTE_ID, attribute_id)
    return path


class RequestPath(NamedTuple):
    """The object a message-router request addresses. Instance 0 addresses the class itself."""

    class_id: int
    instance_id: int
    attribute_id: int | None
    member_id: int | None = None


def decode_request_path(path: bytes) -> RequestPath:
    """Class, then optional instance (or connection point), then optional attribute and member."""
    if not path:
        raise _size_error("no request path")
    segments = decode_epath(path)
    if not isinstance(segments[0], LogicalSegment) or segments[0].type != LogicalType.CLASS_ID:
        raise _segment_error("request path does not start with a class segment")
    class_id = segments[0].value
    instance_id = 0
    attribute_id = member_id = None
    rest = segments[1:]
    if rest and isinstance(rest[0], LogicalSegment) and rest[0].type in (
        LogicalType.INSTANCE_ID,
        LogicalType.CONNECTION_POINT,
    ):
        instance_id = rest.pop(0).value
    if rest and isinstance(rest[0], LogicalSegment) and rest[0].type == LogicalType.ATTRIBUTE_ID:
        attribute_id = rest.pop(0).value
    if rest and isinstance(rest[0], LogicalSegment) and rest[0].type == LogicalType.MEMBER_ID:
        member_id = rest.pop(0).value
    if rest:
        raise _segment_error("unexpected segment in request path")
    return RequestPath(class_id, instance_id, attribute_id, member_id)
