"""CIP Safety I/O messages (CIP Networks Library Vol. 5, 2-4.4 and 2-4.5): the data message in
its four encodings and the time coordination message, base and extended formats.

Data message (`n` data bytes, timestamps in 128 us ticks, little endian):

- base, 1-2 bytes:   data, mode, CRC-S1(actual), CRC-S2(complement), timestamp, CRC-S1(timestamp)
- base, 3-250 bytes: data, mode, CRC-S3(actual), ~data, CRC-S3(complement), timestamp, CRC-S1(timestamp)
- extended, 1-2:     data, mode, CRC-S5 low 16 bits, timestamp, CRC-S5 high 8 bits
- extended, 3-250:   data, mode, CRC-S3(actual), ~data, CRC-S5(complement) low 16, timestamp, high 8

The actual-data CRCs cover the mode byte's run/idle bits (mode & 0xE0) then the data; the
complement CRCs cover (~mode & 0xE0) then ~data (base) or (mode & 0x1F), ~data and the timestamp
(extended, long); the extended short CRC covers mode & 0xE0, the data and the timestamp. Extended
CRCs are seeded with the PID seed continued over the 16-bit rollover count, which is not sent.

Mode byte (Wireshark's field layout): bit 7 run, 6 TBD 2, 5 TBD, 4 not run, 3 TBD 2 copy,
2 not TBD, 1-0 ping count.

Time coordination message (6 bytes), consumer to producer: ack byte (ping count reply in bits
1-0, ping response bit 3, even parity in bit 7), consumer time value, then ack byte 2 and
CRC-S3 over ack byte and time value (base) or CRC-S5 over the same, 3 bytes (extended); seeded
with the consumer's CID seed.
"""

from __future__ import annotations

import struct
from typing import NamedTuple

from enip_farm.protocol.safety.crc import Seeds, crc_s1, crc_s2, crc_s3, crc_s5

_U16 = struct.Struct("<H")
TCOO_SIZE = 6
RUN = 0x80


def wire_size(length: int) -> int:
    """The connection size of a data message carrying `length` bytes (either format)."""
    return length + 6 if length <= 2 else 2 * length + 8


def data_length(size: int) -> int | None:
    """The data bytes a connection size carries, None when no data message has that size."""
    if 7 <= size <= 8:
        return size - 6
    if size >= 14 and size % 2 == 0 and 3 <= (size - 8) // 2 <= 250:
        return (size - 8) // 2
    return None


def mode_byte(run: bool, ping_count: int) -> int:
    return (RUN if run else 0x10) | 0x04 | (ping_count & 3)


def mode_byte_valid(mode: int) -> bool:
    """The redundant bits of the mode byte agree (Vol. 5, 2-4.4.3)."""
    return (bool(mode & 0x80) != bool(mode & 0x10) and bool(mode & 0x20) != bool(mode & 0x04)
            and bool(mode & 0x40) == bool(mode & 0x08))


class DataMessage(NamedTuple):
    data: bytes
    mode: int
    timestamp: int

    @property
    def run(self) -> bool:
        return bool(self.mode & RUN)

    @property
    def ping_count(self) -> int:
        return self.mode & 3


def _complement(data: bytes) -> bytes:
    return bytes(b ^ 0xFF for b in data)


def rollover_seeds(seeds: Seeds, rollover: int) -> tuple[int, int]:
    """The extended format's S3 and S5 seeds for a rollover count."""
    count = _U16.pack(rollover & 0xFFFF)
    return crc_s3(count, seeds.s3), crc_s5(count, seeds.s5)


def encode_data(data: bytes, mode: int, timestamp: int, seeds: Seeds, extended: bool, rollover: int = 0) -> bytes:
    ts = _U16.pack(timestamp & 0xFFFF)
    ts_crc = bytes((crc_s1(ts, crc_s1(bytes((mode & 0x1F,)), seeds.s1)),))
    actual = bytes((mode & 0xE0,)) + data
    if not extended:
        if len(data) <= 2:
            complement = crc_s2(bytes(((mode ^ 0xFF) & 0xE0,)) + _complement(data), seeds.s1)
            return data + bytes((mode, crc_s1(actual, seeds.s1), complement)) + ts + ts_crc
        return (data + bytes((mode,)) + _U16.pack(crc_s3(actual, seeds.s3)) + _complement(data)
                + _U16.pack(crc_s3(bytes(((mode ^ 0xFF) & 0xE0,)) + _complement(data), seeds.s3)) + ts + ts_crc)
    seed3, seed5 = rollover_seeds(seeds, rollover)
    if len(data) <= 2:
        s5 = crc_s5(actual + ts, seed5)
        return data + bytes((mode,)) + _U16.pack(s5 & 0xFFFF) + ts + bytes((s5 >> 16,))
    s5 = crc_s5(bytes((mode & 0x1F,)) + _complement(data) + ts, seed5)
    return (data + bytes((mode,)) + _U16.pack(crc_s3(actual, seed3)) + _complement(data)
            + _U16.pack(s5 & 0xFFFF) + ts + bytes((s5 >> 16,)))


def message_timestamp(message: bytes, length: int, extended: bool) -> int:
    """The timestamp of a data message before its CRCs are checked (the extended CRC depends on
    the rollover count, which the consumer derives from the timestamp)."""
    return _U16.unpack_from(message, length + 3 if length <= 2 else 2 * length + 5)[0]


def decode_data(message: bytes, length: int, seeds: Seeds, extended: bool, rollover: int = 0) -> DataMessage | None:
    """The data message if its size, redundant mode bits, complement and every CRC are right,
    else None (a message with any integrity fault; Vol. 5, 2-4.6.3)."""
    if len(message) != wire_size(length):
        return None
    data, mode = bytes(message[:length]), message[length]
    if not mode_byte_valid(mode):
        return None
    timestamp = message_timestamp(message, length, extended)
    if length > 2 and message[length + 3:2 * length + 3] != _complement(data):
        return None
    if encode_data(data, mode, timestamp, seeds, extended, rollover) != bytes(message):
        return None
    return DataMessage(data, mode, timestamp)


# -- time coordination ------------------------------------------------------------------------------


class TimeCoordination(NamedTuple):
    ping_count_reply: int
    consumer_time: int  # 128 us ticks


def ack_byte(ping_count_reply: int) -> int:
    ack = (ping_count_reply & 3) | 0x08
    return ack | 0x80 if bin(ack).count("1") % 2 else ack


def encode_time_coordination(ping_count_reply: int, consumer_time: int, cid: Seeds, extended: bool) -> bytes:
    ack = ack_byte(ping_count_reply)
    head = bytes((ack,)) + _U16.pack(consumer_time & 0xFFFF)
    if extended:
        s5 = crc_s5(head, cid.s5)
        return head + bytes((s5 & 0xFF, s5 >> 8 & 0xFF, s5 >> 16))
    ack2 = ((ack ^ 0xFF) & 0x55) | (ack & 0xAA)
    return head + bytes((ack2,)) + _U16.pack(crc_s3(head, cid.s3))


def decode_time_coordination(message: bytes, cid: Seeds, extended: bool) -> TimeCoordination | None:
    """None unless the message is 6 bytes with a well-formed ack byte and a right CRC."""
    if len(message) != TCOO_SIZE:
        return None
    ack = message[0]
    if ack & 0x74 or not ack & 0x08 or bin(ack).count("1") % 2:
        return None
    reply = TimeCoordination(ack & 3, _U16.unpack_from(message, 1)[0])
    if encode_time_coordination(reply.ping_count_reply, reply.consumer_time, cid, extended) != bytes(message):
        return None
    return reply


# -- time correction (multicast) --------------------------------------------------------------------

TIME_CORRECTION_SIZE = 6
#: Mcast byte (Wireshark's field layout): bits 3-0 consumer number, bit 5 multicast active/idle,
#: bit 7 even parity.
_MULTICAST_ACTIVE = 0x20


class TimeCorrection(NamedTuple):
    consumer_number: int  # 0: a null section (no consumer)
    active: bool
    value: int  # Time_Correction_Value, 128 us ticks


def _parity(byte: int) -> int:
    return byte | 0x80 if bin(byte).count("1") % 2 else byte


def encode_time_correction(correction: TimeCorrection, pid: Seeds, extended: bool) -> bytes:
    """A time correction section, producer to consumers (Vol. 5, 2-4.4.4): what a multicast
    producer appends to its data message on EtherNet/IP. Mcast byte, Time_Correction_Value, then
    Mcast byte 2 and CRC-S3 (base) or CRC-S5, 3 bytes (extended), seeded with the producer's PID."""
    mcast = _parity((correction.consumer_number & 0x0F) | (_MULTICAST_ACTIVE if correction.active else 0))
    head = bytes((mcast,)) + _U16.pack(correction.value & 0xFFFF)
    if extended:
        s5 = crc_s5(head, pid.s5)
        return head + bytes((s5 & 0xFF, s5 >> 8 & 0xFF, s5 >> 16))
    mcast2 = ((mcast ^ 0xFF) & 0x55) | (mcast & 0xAA)
    return head + bytes((mcast2,)) + _U16.pack(crc_s3(head, pid.s3))


def decode_time_correction(section: bytes, pid: Seeds, extended: bool) -> TimeCorrection | None:
    """None unless the section is 6 bytes with even parity, no reserved bit and a right CRC."""
    if len(section) != TIME_CORRECTION_SIZE or section[0] & 0x50 or bin(section[0]).count("1") % 2:
        return None
    correction = TimeCorrection(section[0] & 0x0F, bool(section[0] & _MULTICAST_ACTIVE),
                                _U16.unpack_from(section, 1)[0])
    return correction if encode_time_correction(correction, pid, extended) == bytes(section) else None
