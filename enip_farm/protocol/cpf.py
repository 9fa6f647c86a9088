"""Common Packet Format (CIP Networks Library Vol. 2, section 2-6): an item count, then items of
type id (UINT), length (UINT) and data.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable
from enum import IntEnum
from typing import NamedTuple

_UINT = struct.Struct("<H")
_ITEM_HEADER = struct.Struct("<HH")


class ItemType(IntEnum):
    NULL_ADDRESS = 0x0000
    LIST_IDENTITY = 0x000C
    CONNECTED_ADDRESS = 0x00A1
    CONNECTED_DATA = 0x00B1
    UNCONNECTED_DATA = 0x00B2
    LIST_SERVICES = 0x0100
    SOCKADDR_O_T = 0x8000
    SOCKADDR_T_O = 0x8001
    SEQUENCED_ADDRESS = 0x8002


class CpfItem(NamedTuple):
    type_id: int
    data: bytes


class CpfError(ValueError):
    """The item list is truncated or its lengths do not add up."""


def decode_items(data: bytes, offset: int = 0) -> list[CpfItem]:
    """Decode an item count and its items; trailing bytes after the last item are an error."""
    end = len(data)
    if end - offset < 2:
        raise CpfError("no item count")
    (count,) = _UINT.unpack_from(data, offset)
    offset += 2
    items = []
    for _ in range(count):
        if end - offset < 4:
            raise CpfError("truncated item header")
        type_id, length = _ITEM_HEADER.unpack_from(data, offset)
        offset += 4
        if end - offset < length:
            raise CpfError("item length exceeds data")
        items.append(CpfItem(type_id, data[offset : offset + length]))
        offset += length
    if offset != end:
        raise CpfError("bytes after the last item")
    return items


def encode_items(items: Iterable[tuple[int, bytes]]) -> bytes:
    items = list(items)
    parts = [_UINT.pack(len(items))]
    for type_id, data in items:
        parts.append(_ITEM_HEADER.pack(type_id, len(data)))
        parts.append(data)
    return b"".join(parts)
