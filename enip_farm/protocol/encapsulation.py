"""Encapsulation header, commands, status codes and the TCP stream framer.

CIP Networks Library Vol. 2 (EtherNet/IP adaptation), section 2-3: a 24-byte little-endian header
(command, length, session handle, status, sender context, options) followed by `length` bytes of
command-specific data.

A request whose Status field is not zero is ignored, with no reply (2-3.5). The whole message is
read from the stream even when its length exceeds what the farm takes (2-3.3): the framer skips
the rest of an oversize message without buffering it, so the stream keeps its framing.
"""

from __future__ import annotations

import struct
from collections.abc import Mapping
from enum import IntEnum
from types import MappingProxyType
from typing import NamedTuple

#: The EtherNet/IP port, TCP and UDP (Vol. 2, 2-2).
ENIP_PORT = 44818
HEADER = struct.Struct("<HHII8sI")
HEADER_SIZE = HEADER.size  # 24

#: Largest command-specific data length the farm takes; the data of a longer message is read and
#: discarded, and the request gets status 0x0065 (a NOP gets nothing: it may carry 0-65511 bytes).
MAX_DATA_LENGTH = 4096


class Command(IntEnum):
    NOP = 0x0000
    LIST_SERVICES = 0x0004
    LIST_IDENTITY = 0x0063
    LIST_INTERFACES = 0x0064
    REGISTER_SESSION = 0x0065
    UNREGISTER_SESSION = 0x0066
    SEND_RR_DATA = 0x006F
    SEND_UNIT_DATA = 0x0070


class EncapsulationStatus(IntEnum):
    SUCCESS = 0x0000
    INVALID_COMMAND = 0x0001
    INSUFFICIENT_MEMORY = 0x0002
    INCORRECT_DATA = 0x0003
    INVALID_SESSION_HANDLE = 0x0064
    INVALID_LENGTH = 0x0065
    UNSUPPORTED_PROTOCOL = 0x0069


_COMMAND_NAMES: Mapping[int, str] = MappingProxyType({
    Command.NOP: "NOP", Command.LIST_SERVICES: "ListServices", Command.LIST_IDENTITY: "ListIdentity",
    Command.LIST_INTERFACES: "ListInterfaces", Command.REGISTER_SESSION: "RegisterSession",
    Command.UNREGISTER_SESSION: "UnRegisterSession", Command.SEND_RR_DATA: "SendRRData",
    Command.SEND_UNIT_DATA: "SendUnitData"})


def command_name(command: int) -> str:
    """A command as the spec names it (SendRRData), or its code."""
    return _COMMAND_NAMES.get(command, f"command 0x{command:04X}")


def describe_encapsulation_status(status: int) -> str:
    """An encapsulation status in hex and words, e.g. `0x0064 invalid session handle`."""
    try:
        words = EncapsulationStatus(status).name.lower().replace("_", " ")
    except ValueError:
        words = "unknown status"
    return f"0x{status:04X} {words}"


class EncapsulationHeader(NamedTuple):
    command: int
    length: int
    session_handle: int
    status: int
    sender_context: bytes
    options: int


class Frame(NamedTuple):
    """One complete encapsulation message."""

    header: EncapsulationHeader
    data: bytes


class OversizeFrame(NamedTuple):
    """A whole message whose length field exceeds what the framer takes: its header, its data read
    and discarded (Vol. 2, 2-3.3). The stream goes on after it."""

    header: EncapsulationHeader


def decode_header(data: bytes, offset: int = 0) -> EncapsulationHeader:
    return EncapsulationHeader._make(HEADER.unpack_from(data, offset))


def encode_frame(
    command: int,
    data: bytes = b"",
    session_handle: int = 0,
    status: int = 0,
    sender_context: bytes = bytes(8),
    options: int = 0,
) -> bytes:
    """A whole encapsulation message: header and command-specific data."""
    return HEADER.pack(command, len(data), session_handle, status, sender_context, options) + data


def decode_frame(data: bytes) -> Frame:
    """Decode one complete message (e.g. a UDP datagram). Raises ValueError if incomplete."""
    if len(data) < HEADER_SIZE:
        raise ValueError("shorter than an encapsulation header")
    header = decode_header(data)
    if len(data) < HEADER_SIZE + header.length:
        raise ValueError("shorter than the header's length field")
    return Frame(header, data[HEADER_SIZE : HEADER_SIZE + header.length])


class StreamFramer:
    """Cuts a TCP byte stream into encapsulation frames.

    Handles a frame split over any number of reads and several frames in one read. A message whose
    length field exceeds `max_length` is read whole and discarded as it arrives (at most
    `max_length` + 24 bytes are ever buffered for a message); once its last byte is in, it yields an
    OversizeFrame, in its place among the frames.
    """

    __slots__ = ("_buffer", "max_length", "_skipping", "_skip_left")

    def __init__(self, max_length: int = MAX_DATA_LENGTH) -> None:
        self._buffer = b""
        self.max_length = max_length
        self._skipping: EncapsulationHeader | None = None  # the oversize message being read and discarded
        self._skip_left = 0  # its bytes still to come

    @property
    def pending(self) -> int:
        """Bytes received that do not yet form a whole frame (an oversize message's still to come
        count too)."""
        return len(self._buffer) + self._skip_left

    def feed(self, data: bytes, limit: int | None = None) -> list[Frame | OversizeFrame]:
        """Append `data` and cut at most `limit` frames (all by default); the rest stays buffered
        for the next call (`feed(b"", limit)`)."""
        frames: list[Frame | OversizeFrame] = []
        if self._skip_left:
            if len(data) < self._skip_left:
                self._skip_left -= len(data)
                return frames
            data = data[self._skip_left :]
            self._skip_left = 0
            frames.append(OversizeFrame(self._skipping))  # type: ignore[arg-type]
            self._skipping = None
        buffer = self._buffer + data if self._buffer else data
        offset = 0
        end = len(buffer)
        unpack_from = HEADER.unpack_from
        max_length = self.max_length
        while end - offset >= HEADER_SIZE and (limit is None or len(frames) < limit):
            header = EncapsulationHeader._make(unpack_from(buffer, offset))
            stop = offset + HEADER_SIZE + header.length
            if header.length > max_length:
                if stop > end:  # read the rest as it comes, and drop it
                    self._skipping, self._skip_left = header, stop - end
                    offset = end
                    break
                frames.append(OversizeFrame(header))
            elif stop > end:
                break
            else:
                frames.append(Frame(header, buffer[offset + HEADER_SIZE : stop]))
            offset = stop
        self._buffer = buffer[offset:] if offset < end else b""
        return frames

    @property
    def has_frame(self) -> bool:
        """Whether a whole frame (or an oversize header, which can be taken) is buffered, waiting to
        be cut."""
        buffer = self._buffer
        if self._skip_left or len(buffer) < HEADER_SIZE:
            return False
        length = buffer[2] | buffer[3] << 8
        return length > self.max_length or len(buffer) >= HEADER_SIZE + length
