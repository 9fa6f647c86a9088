"""The CIP Safety CRCs (CIP Networks Library Vol. 5, 2-4.5 and appendix C): CRC-S1 (8-bit,
polynomial 0x37), CRC-S2 (8-bit, 0x3B), CRC-S3 (16-bit, 0x080F), CRC-S4 (32-bit, the reflected
CRC-32 polynomial, preset 0xFFFFFFFF, no final inversion) and CRC-S5 (24-bit, 0x5D6DCB). S1, S2,
S3 and S5 shift most significant bit first, take a seed (the PID/CID seed of a connection) and
have no final XOR, as Wireshark's CIP Safety dissector computes them.

PID and CID seeds (Vol. 5, 2-4.5.4): the CRC of vendor id (UINT), device serial number (UDINT)
and connection serial number (UINT), little endian, from seed 0.
"""

from __future__ import annotations

import struct
import zlib
from typing import NamedTuple

_ID = struct.Struct("<HIH")


def _table(width: int, polynomial: int) -> tuple[int, ...]:
    top, mask = 1 << (width - 1), (1 << width) - 1
    table = []
    for byte in range(256):
        crc = byte << (width - 8)
        for _ in range(8):
            crc = ((crc << 1) ^ polynomial) & mask if crc & top else (crc << 1) & mask
        table.append(crc)
    return tuple(table)


_S1 = _table(8, 0x37)
_S2 = _table(8, 0x3B)
_S3 = _table(16, 0x080F)
_S5 = _table(24, 0x5D6DCB)


def crc_s1(data: bytes, seed: int = 0) -> int:
    crc = seed & 0xFF
    for byte in data:
        crc = _S1[crc ^ byte]
    return crc


def crc_s2(data: bytes, seed: int = 0) -> int:
    crc = seed & 0xFF
    for byte in data:
        crc = _S2[crc ^ byte]
    return crc


def crc_s3(data: bytes, seed: int = 0) -> int:
    crc = seed & 0xFFFF
    for byte in data:
        crc = _S3[(crc >> 8) ^ byte] ^ ((crc << 8) & 0xFFFF)
    return crc


def crc_s4(data: bytes, seed: int = 0xFFFFFFFF) -> int:
    """zlib's CRC-32 without its final inversion: continue from `seed` (a previous CRC-S4)."""
    return zlib.crc32(data, seed ^ 0xFFFFFFFF) ^ 0xFFFFFFFF


def crc_s5(data: bytes, seed: int = 0) -> int:
    crc = seed & 0xFFFFFF
    for byte in data:
        crc = _S5[(crc >> 16) ^ byte] ^ ((crc << 8) & 0xFFFFFF)
    return crc


class Seeds(NamedTuple):
    """The PID (or CID) seeds of one connection end for each CRC."""

    s1: int
    s3: int
    s5: int

    @classmethod
    def of(cls, vendor_id: int, serial_number: int, connection_serial: int) -> Seeds:
        data = _ID.pack(vendor_id, serial_number, connection_serial)
        return cls(crc_s1(data), crc_s3(data), crc_s5(data))
