"""CIP message-router requests and replies (CIP Networks Library Vol. 1, section 2-4), and the
data layouts of Multiple Service Packet (Vol. 1, 4-A.5) and Unconnected Send (Vol. 1, 3-5.5.2).
"""

from __future__ import annotations

import struct
from enum import IntEnum
from typing import NamedTuple

from enip_farm.protocol.status import GeneralStatus

_UINT = struct.Struct("<H")
_UNCONNECTED_SEND_HEADER = struct.Struct("<BBH")

REPLY_BIT = 0x80


class Service(IntEnum):
    GET_ATTRIBUTES_ALL = 0x01
    SET_ATTRIBUTES_ALL = 0x02
    GET_ATTRIBUTE_LIST = 0x03
    SET_ATTRIBUTE_LIST = 0x04
    RESET = 0x05
    MULTIPLE_SERVICE_PACKET = 0x0A
    GET_ATTRIBUTE_SINGLE = 0x0E
    SET_ATTRIBUTE_SINGLE = 0x10
    GET_AND_CLEAR = 0x4C
    FORWARD_CLOSE = 0x4E
    UNCONNECTED_SEND = 0x52
    FORWARD_OPEN = 0x54
    LARGE_FORWARD_OPEN = 0x5B


class ClassCode(IntEnum):
    """The CIP object classes the farm serves or addresses (Vol. 1, table 5-1.1; Vol. 2, 5-4 and
    5-5; Vol. 5, chapter 5): the one list of class codes, used everywhere."""

    IDENTITY = 0x01
    MESSAGE_ROUTER = 0x02
    ASSEMBLY = 0x04
    CONNECTION_MANAGER = 0x06
    PARAMETER = 0x0F
    SAFETY_SUPERVISOR = 0x39
    SAFETY_VALIDATOR = 0x3A
    TCP_IP_INTERFACE = 0xF5
    ETHERNET_LINK = 0xF6


class MessageRouterRequest(NamedTuple):
    service: int
    path: bytes  # the padded EPATH, undecoded
    data: bytes


class MessageRouterReply(NamedTuple):
    service: int  # with the reply bit set
    general_status: int
    additional_status: tuple[int, ...]
    data: bytes


class CipDecodeError(ValueError):
    def __init__(self, status: int, reason: str) -> None:
        super().__init__(reason)
        self.status = status


def decode_request(message: bytes) -> MessageRouterRequest:
    size = len(message)
    if size < 2:
        raise CipDecodeError(GeneralStatus.NOT_ENOUGH_DATA, "request shorter than service and path size")
    path_end = 2 + 2 * message[1]
    if path_end > size:
        raise CipDecodeError(GeneralStatus.PATH_SIZE_INVALID, "path size exceeds the request")
    return MessageRouterRequest(message[0], message[2:path_end], message[path_end:])


def encode_request(service: int, path: bytes, data: bytes = b"") -> bytes:
    if len(path) % 2:
        raise ValueError("EPATH must be padded to whole words")
    return bytes((service, len(path) // 2)) + path + data


def encode_reply(
    request_service: int,
    general_status: int = 0,
    data: bytes = b"",
    additional_status: tuple[int, ...] = (),
) -> bytes:
    """Reply to a request: the service with the reply bit, reserved, status, additional status."""
    head = bytes((request_service | REPLY_BIT, 0, general_status, len(additional_status)))
    if additional_status:
        head += struct.pack(f"<{len(additional_status)}H", *additional_status)
    return head + data


def decode_reply(message: bytes) -> MessageRouterReply:
    if len(message) < 4:
        raise CipDecodeError(GeneralStatus.NOT_ENOUGH_DATA, "reply shorter than 4 bytes")
    words = message[3]
    end = 4 + 2 * words
    if end > len(message):
        raise CipDecodeError(GeneralStatus.NOT_ENOUGH_DATA, "additional status exceeds the reply")
    additional = struct.unpack_from(f"<{words}H", message, 4) if words else ()
    return MessageRouterReply(message[0], message[2], tuple(additional), message[end:])


# -- Multiple Service Packet -----------------------------------------------------------------------


def decode_multiple_service_request(data: bytes) -> list[bytes]:
    """The embedded requests, cut by their offsets (relative to the start of the service count)."""
    size = len(data)
    if size < 2:
        raise CipDecodeError(GeneralStatus.NOT_ENOUGH_DATA, "no service count")
    (count,) = _UINT.unpack_from(data, 0)
    table_end = 2 + 2 * count
    if count == 0 or table_end > size:
        raise CipDecodeError(GeneralStatus.NOT_ENOUGH_DATA, "offset table truncated")
    offsets = list(struct.unpack_from(f"<{count}H", data, 2)) + [size]
    requests = []
    for start, stop in zip(offsets, offsets[1:], strict=False):
        if not table_end <= start < stop <= size:
            raise CipDecodeError(GeneralStatus.INVALID_PARAMETER, "offset out of range")
        requests.append(data[start:stop])
    return requests


def encode_multiple_service(messages: list[bytes]) -> bytes:
    """Count, offsets and the messages: the layout of both the request and the reply data."""
    offsets = []
    position = 2 + 2 * len(messages)
    for message in messages:
        offsets.append(position)
        position += len(message)
    return struct.pack(f"<H{len(messages)}H", len(messages), *offsets) + b"".join(messages)


# -- Unconnected Send ------------------------------------------------------------------------------


class UnconnectedSend(NamedTuple):
    priority_time_tick: int
    timeout_ticks: int
    message: bytes
    route_path: bytes  # padded EPATH of port segments


def decode_unconnected_send(data: bytes) -> UnconnectedSend:
    if len(data) < 4:
        raise CipDecodeError(GeneralStatus.NOT_ENOUGH_DATA, "unconnected send header truncated")
    tick, ticks, size = _UNCONNECTED_SEND_HEADER.unpack_from(data, 0)
    message_end = 4 + size
    route_start = message_end + (size & 1)
    if route_start + 2 > len(data):
        raise CipDecodeError(GeneralStatus.NOT_ENOUGH_DATA, "embedded message or route path truncated")
    route_end = route_start + 2 + 2 * data[route_start]
    if route_end > len(data):
        raise CipDecodeError(GeneralStatus.PATH_SIZE_INVALID, "route path size exceeds the request")
    if route_end < len(data):
        raise CipDecodeError(GeneralStatus.TOO_MUCH_DATA, "bytes after the route path")
    return UnconnectedSend(tick, ticks, data[4:message_end], data[route_start + 2 : route_end])


def encode_unconnected_send(message: bytes, route_path: bytes, priority_time_tick: int = 0x0A,
                            timeout_ticks: int = 0x0E) -> bytes:
    pad = b"\x00" if len(message) % 2 else b""
    return (
        _UNCONNECTED_SEND_HEADER.pack(priority_time_tick, timeout_ticks, len(message))
        + message
        + pad
        + bytes((len(route_path) // 2, 0))
        + route_path
    )
