"""The safety network segment of a SafetyOpen (CIP Networks Library Vol. 5, 3-5.3, and Vol. 1,
C-1.4.3: network segment type 0x40 | subtype 0x10 = 0x50), and the connection parameter CRC
(CPCRC) that protects the Forward Open (Vol. 5, 3-5.3.3).

Layout after `50 <size in words> <format> 00` (little endian):
SCID = SCCRC (UDINT) + SCTS (6 bytes), time correction EPI (UDINT), time correction network
connection parameters (WORD), TUNID (10 bytes: SNN 6 + node address UDINT), OUNID (10 bytes),
ping interval EPI multiplier (UINT), time coordination message min multiplier (UINT, 128 us),
network time expectation multiplier (UINT, 128 us), timeout multiplier (USINT), max consumer
number (USINT); extended format only: max fault number (UINT); then CPCRC (UDINT), time
correction connection id (UDINT); extended only: initial timestamp (UINT), initial rollover value
(UINT). Format 0 (target, base) is 27 words, format 2 (extended) 30 words; format 1 (router) is
not for a target.

CPCRC: CRC-S4 over connection serial number and originator vendor id (bytes 10-13 of the Forward
Open data), bytes 18 to the connection path size inclusive (timeout multiplier, reserved, RPIs and
network connection parameters, transport type/trigger, path size counted without the route to the
target), the connection path from the electronic key to the safety segment, and the safety segment
up to the CPCRC field. (The layout cm-ethernetip's originator and target both use.)
"""

from __future__ import annotations

import struct
from collections.abc import Mapping
from types import MappingProxyType
from typing import NamedTuple

from enip_farm.protocol.safety.crc import crc_s4

SAFETY_SEGMENT = 0x50
FORMAT_BASE, FORMAT_ROUTER, FORMAT_EXTENDED = 0, 1, 2
SIZE_WORDS: Mapping[int, int] = MappingProxyType({FORMAT_BASE: 27, FORMAT_EXTENDED: 30})
_COMMON = struct.Struct("<I6sIH10s10sHHHBB")
_BASE_TAIL = struct.Struct("<II")
_EXTENDED_TAIL = struct.Struct("<HIIHH")
NOT_USED = 0xFFFF  # initial timestamp / rollover value "not used" (a consumer's SafetyOpen)
TIME_CORRECTION_NOT_USED = 0xFFFFFFFF  # time correction connection id of a single-cast connection


class SegmentError(ValueError):
    """A safety segment that cannot be read; `format_error` when the format is the problem."""

    def __init__(self, reason: str, format_error: bool = False) -> None:
        super().__init__(reason)
        self.format_error = format_error


class Unid(NamedTuple):
    """A unique network identifier: safety network number (6 bytes) and node address (UDINT;
    on EtherNet/IP the IPv4 address)."""

    snn: bytes
    node_address: int

    @classmethod
    def decode(cls, data: bytes) -> Unid:
        return cls(bytes(data[:6]), struct.unpack_from("<I", data, 6)[0])

    def encode(self) -> bytes:
        return self.snn + struct.pack("<I", self.node_address)


class SafetySegment(NamedTuple):
    format: int
    sccrc: int
    scts: bytes
    time_correction_epi: int
    time_correction_parameters: int
    tunid: Unid
    ounid: Unid
    ping_interval_epi_multiplier: int
    time_coord_msg_min_multiplier: int  # 128 us
    network_time_expectation_multiplier: int  # 128 us
    timeout_multiplier: int
    max_consumer_number: int
    cpcrc: int
    time_correction_connection_id: int
    max_fault_number: int = 0
    initial_timestamp: int = NOT_USED
    initial_rollover_value: int = NOT_USED

    @property
    def extended(self) -> bool:
        return self.format == FORMAT_EXTENDED

    @property
    def scid(self) -> bytes:
        """The safety configuration identifier: SCCRC then SCTS (10 bytes)."""
        return struct.pack("<I", self.sccrc) + self.scts

    @property
    def network_time_expectation_ns(self) -> int:
        return self.network_time_expectation_multiplier * 128_000


def decode_segment(raw: bytes) -> SafetySegment:
    """`raw` is the whole segment from its 0x50 byte."""
    if len(raw) < 4 or raw[0] != SAFETY_SEGMENT or len(raw) != 2 + 2 * raw[1]:
        raise SegmentError("truncated safety segment")
    fmt = raw[2]
    if fmt not in SIZE_WORDS:
        raise SegmentError(f"safety segment format {fmt} is not a target format", format_error=True)
    if raw[1] != SIZE_WORDS[fmt]:
        raise SegmentError(f"safety segment of format {fmt} has {raw[1]} words, not {SIZE_WORDS[fmt]}",
                           format_error=True)
    (sccrc, scts, tc_epi, tc_params, tunid, ounid, ping, tcoo_min, nte, timeout, max_consumers) = (
        _COMMON.unpack_from(raw, 4))
    offset = 4 + _COMMON.size
    common = (fmt, sccrc, scts, tc_epi, tc_params, Unid.decode(tunid), Unid.decode(ounid), ping, tcoo_min, nte,
              timeout, max_consumers)
    if fmt == FORMAT_BASE:
        cpcrc, tc_id = _BASE_TAIL.unpack_from(raw, offset)
        return SafetySegment(*common, cpcrc, tc_id)
    max_faults, cpcrc, tc_id, initial_ts, initial_rv = _EXTENDED_TAIL.unpack_from(raw, offset)
    return SafetySegment(*common, cpcrc, tc_id, max_faults, initial_ts, initial_rv)


def encode_segment(segment: SafetySegment) -> bytes:
    fmt = segment.format
    body = _COMMON.pack(segment.sccrc, segment.scts, segment.time_correction_epi,
                        segment.time_correction_parameters, segment.tunid.encode(), segment.ounid.encode(),
                        segment.ping_interval_epi_multiplier, segment.time_coord_msg_min_multiplier,
                        segment.network_time_expectation_multiplier, segment.timeout_multiplier,
                        segment.max_consumer_number)
    if fmt == FORMAT_BASE:
        body += _BASE_TAIL.pack(segment.cpcrc, segment.time_correction_connection_id)
    else:
        body += _EXTENDED_TAIL.pack(segment.max_fault_number, segment.cpcrc, segment.time_correction_connection_id,
                                    segment.initial_timestamp, segment.initial_rollover_value)
    return bytes((SAFETY_SEGMENT, SIZE_WORDS[fmt], fmt, 0)) + body


def cpcrc_offset(fmt: int) -> int:
    """Where the CPCRC sits in the segment (from its 0x50 byte)."""
    return 4 + _COMMON.size + (2 if fmt == FORMAT_EXTENDED else 0)


def compute_cpcrc(forward_open_fixed: bytes, application_path: bytes, raw_segment: bytes) -> int:
    """`forward_open_fixed`: the Forward Open data up to and including the path size byte, whose
    value counts the application path and the safety segment only; `application_path`: the path
    from the electronic key up to the safety segment; `raw_segment`: the segment from 0x50."""
    data = (forward_open_fixed[10:14] + forward_open_fixed[18:] + application_path
            + raw_segment[:cpcrc_offset(raw_segment[2])])
    return crc_s4(data)
