"""CIP data types as attribute declarations use them (CIP Networks Library Vol. 1, appendix C-2):
each type encodes a value, decodes one, and tells how many bytes a value takes at the start of
some data (`size_in`: what Set_Attribute_List needs to walk its list). `size` is the fixed size of
a type, None where the value says its own length (strings, counted lists).

Elementary types by their type code (C-6.1) are in `ELEMENTARY`, as an EDS's [Params] and the
Parameter object's attribute 5 name them.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Mapping
from types import MappingProxyType
from typing import Any


class CipType:
    """A data type: `encode(value) -> bytes`, `decode(data) -> value` (data holds exactly one value)."""

    __slots__ = ("name", "size")

    def __init__(self, name: str, size: int | None) -> None:
        self.name = name
        self.size = size

    def encode(self, value: Any) -> bytes:
        raise NotImplementedError

    def decode(self, data: bytes) -> Any:
        raise NotImplementedError

    def size_in(self, data: bytes) -> int | None:
        """How many bytes the value at the start of `data` takes; None if `data` cannot tell."""
        return self.size

    def __repr__(self) -> str:
        return self.name


class Packed(CipType):
    """A fixed layout of numbers (a `struct` format): one field is its value, several a tuple."""

    __slots__ = ("_struct", "_single")

    def __init__(self, name: str, layout: str) -> None:
        self._struct = struct.Struct(layout)
        self._single = len(self._struct.unpack(bytes(self._struct.size))) == 1
        super().__init__(name, self._struct.size)

    def encode(self, value: Any) -> bytes:
        return self._struct.pack(value) if self._single else self._struct.pack(*value)

    def decode(self, data: bytes) -> Any:
        values = self._struct.unpack(data)
        return values[0] if self._single else values


class Octets(CipType):
    """A fixed number of bytes taken as they are (a MAC address, an array of USINTs)."""

    __slots__ = ()

    def __init__(self, size: int, name: str = "") -> None:
        super().__init__(name or f"USINT[{size}]", size)

    def encode(self, value: bytes) -> bytes:
        if len(value) != self.size:
            raise ValueError(f"{self.name}: {len(value)} bytes, not {self.size}")
        return value if type(value) is bytes else bytes(value)

    def decode(self, data: bytes) -> bytes:
        return bytes(data)


class Integer(CipType):
    """An integer of any size, little-endian (a parameter whose EDS gives a size its type does not have)."""

    __slots__ = ("signed",)

    def __init__(self, name: str, size: int, signed: bool) -> None:
        super().__init__(name, size)
        self.signed = signed

    def encode(self, value: int) -> bytes:
        return int(value).to_bytes(self.size, "little", signed=self.signed)  # type: ignore[arg-type]

    def decode(self, data: bytes) -> int:
        return int.from_bytes(data, "little", signed=self.signed)


class Encoded(CipType):
    """A structure the object encodes itself (an EPATH, a counted list of structures): the value is
    its encoding; `size_in` reads the length from the encoding."""

    __slots__ = ("_size_in",)

    def __init__(self, name: str, size_in: Callable[[bytes], int | None]) -> None:
        super().__init__(name, None)
        self._size_in = size_in

    def encode(self, value: bytes) -> bytes:
        return value

    def decode(self, data: bytes) -> bytes:
        return bytes(data)

    def size_in(self, data: bytes) -> int | None:
        return self._size_in(data)


class ShortString(CipType):
    """SHORT_STRING: a USINT length and the characters."""

    __slots__ = ()

    def encode(self, value: str) -> bytes:
        raw = value.encode("latin-1")
        return bytes((len(raw),)) + raw

    def decode(self, data: bytes) -> str:
        return data[1:].decode("latin-1")

    def size_in(self, data: bytes) -> int | None:
        return 1 + data[0] if data else None


class PaddedString(CipType):
    """STRING as the TCP/IP object carries it (Vol. 2, 5-4): a UINT length, the characters and a
    pad byte after an odd number of them."""

    __slots__ = ()

    def encode(self, value: str) -> bytes:
        raw = value.encode("latin-1")
        return UINT.encode(len(raw)) + raw + (b"\x00" if len(raw) % 2 else b"")

    def decode(self, data: bytes) -> str:
        return data[2 : 2 + UINT.decode(data[:2])].decode("latin-1")

    def size_in(self, data: bytes) -> int | None:
        if len(data) < 2:
            return None
        length = UINT.decode(data[:2])
        return 2 + length + (length & 1)


class UintList(CipType):
    """A UINT count and that many UINTs (class attributes 4 and 5, the router's object list)."""

    __slots__ = ()

    def encode(self, value: tuple[int, ...]) -> bytes:
        return struct.pack(f"<H{len(value)}H", len(value), *value)

    def decode(self, data: bytes) -> tuple[int, ...]:
        return struct.unpack_from(f"<{UINT.decode(data[:2])}H", data, 2)

    def size_in(self, data: bytes) -> int | None:
        return 2 * (1 + UINT.decode(data[:2])) if len(data) >= 2 else None


BOOL = Packed("BOOL", "<B")  # a byte: 0 false, 1 true (the setters refuse other values: 0x09)
SINT, INT, DINT, LINT = Packed("SINT", "<b"), Packed("INT", "<h"), Packed("DINT", "<i"), Packed("LINT", "<q")
USINT, UINT, UDINT, ULINT = Packed("USINT", "<B"), Packed("UINT", "<H"), Packed("UDINT", "<I"), Packed("ULINT", "<Q")
REAL, LREAL = Packed("REAL", "<f"), Packed("LREAL", "<d")
BYTE, WORD, DWORD, LWORD = Packed("BYTE", "<B"), Packed("WORD", "<H"), Packed("DWORD", "<I"), Packed("LWORD", "<Q")
SHORT_STRING = ShortString("SHORT_STRING", None)
PADDED_STRING = PaddedString("STRING", None)
UINT_LIST = UintList("UINT count, UINT[count]", None)

#: The elementary types by type code (Vol. 1, C-6.1).
ELEMENTARY: Mapping[int, Packed] = MappingProxyType({
    0xC1: BOOL, 0xC2: SINT, 0xC3: INT, 0xC4: DINT, 0xC5: LINT, 0xC6: USINT, 0xC7: UINT, 0xC8: UDINT,
    0xC9: ULINT, 0xCA: REAL, 0xCB: LREAL, 0xD1: BYTE, 0xD2: WORD, 0xD3: DWORD, 0xD4: LWORD,
})
#: The signed integer types among them.
SIGNED = frozenset((0xC2, 0xC3, 0xC4, 0xC5))
