"""Command-specific data of the encapsulation commands (CIP Networks Library Vol. 2, 2-4):
RegisterSession, SendRRData/SendUnitData, ListIdentity's CIP Identity item, ListServices' item and
the socket-address item.
"""

from __future__ import annotations

import socket
import struct
from collections.abc import Iterable
from typing import NamedTuple

from enip_farm.protocol.cpf import CpfItem, ItemType, decode_items, encode_items
from enip_farm.protocol.encapsulation import Command, encode_frame

PROTOCOL_VERSION = 1
REGISTER_SESSION = struct.Struct("<HH")
_SEND_DATA_HEADER = struct.Struct("<IH")
_SOCKADDR = struct.Struct(">HH4s8x")
_IDENTITY = struct.Struct("<HHHBBHI")
_LIST_SERVICES = struct.Struct("<HH16s")

#: ListServices capability flags: bit 5 CIP encapsulation over TCP, bit 8 class 0/1 over UDP.
CAPABILITY_TCP = 0x0020
CAPABILITY_UDP_CLASS_0_1 = 0x0100


class SendData(NamedTuple):
    """SendRRData / SendUnitData body."""

    interface_handle: int
    timeout: int
    items: list[CpfItem]


def decode_send_data(data: bytes) -> SendData:
    """Raises ValueError (CpfError) if the body or its items are malformed."""
    if len(data) < 6:
        raise ValueError("send data shorter than interface handle and timeout")
    handle, timeout = _SEND_DATA_HEADER.unpack_from(data, 0)
    return SendData(handle, timeout, decode_items(data, 6))


# interface handle and timeout (6 bytes), then: 2 items, null address of length 0, unconnected data
_CANONICAL_ITEMS = struct.pack("<HHHH", 2, ItemType.NULL_ADDRESS, 0, ItemType.UNCONNECTED_DATA)


_SOCKADDR_ITEMS = (ItemType.SOCKADDR_O_T, ItemType.SOCKADDR_T_O)
_NO_ITEMS: tuple[CpfItem, ...] = ()


def decode_unconnected_message(data: bytes) -> tuple[bytes, tuple[CpfItem, ...]] | None:
    """The CIP message of a SendRRData body and its socket-address items (0x8000/0x8001, as a
    Forward Open may carry), or None if the body is malformed or carries other items than a null
    address, a non-empty unconnected data item and socket-address items of 16 bytes.

    The layout every client sends is recognised by comparing bytes; anything else takes the general
    item decoder, so both paths accept exactly the same inputs."""
    if data[6:14] == _CANONICAL_ITEMS and len(data) >= 16:
        length = data[14] | data[15] << 8
        if length and length == len(data) - 16:
            return data[16:], _NO_ITEMS
    try:
        items = decode_send_data(data).items
    except ValueError:
        return None
    if (
        len(items) < 2
        or items[0].type_id != ItemType.NULL_ADDRESS
        or items[0].data
        or items[1].type_id != ItemType.UNCONNECTED_DATA
        or not items[1].data
        or any(item.type_id not in _SOCKADDR_ITEMS or len(item.data) != 16 for item in items[2:])
    ):
        return None
    return items[1].data, tuple(items[2:])


def decode_connected_message(data: bytes) -> tuple[int, int, bytes, list[CpfItem]] | None:
    """SendUnitData body: (connection id, sequence count, CIP message, socket-address items), or
    None if malformed (other items than a connected address, connected data and socket addresses)."""
    try:
        items = decode_send_data(data).items
    except ValueError:
        return None
    if (len(items) < 2 or items[0].type_id != ItemType.CONNECTED_ADDRESS or len(items[0].data) != 4
            or items[1].type_id != ItemType.CONNECTED_DATA or len(items[1].data) < 3
            or any(item.type_id not in _SOCKADDR_ITEMS or len(item.data) != 16 for item in items[2:])):
        return None
    return (int.from_bytes(items[0].data, "little"), int.from_bytes(items[1].data[:2], "little"),
            items[1].data[2:], items[2:])


def encode_connected_payload(connection_id: int, sequence_count: int, message: bytes,
                             extra_items: Iterable[tuple[int, bytes]] = ()) -> bytes:
    """SendUnitData body: connected address item, connected data item (sequence count first), and
    any items that go beside the reply (a Forward Open's T->O socket address)."""
    return _SEND_DATA_HEADER.pack(0, 0) + encode_items(
        ((ItemType.CONNECTED_ADDRESS, struct.pack("<I", connection_id)),
         (ItemType.CONNECTED_DATA, struct.pack("<H", sequence_count) + message), *extra_items))


def encode_send_data(items: list[tuple[int, bytes]], timeout: int = 0, interface_handle: int = 0) -> bytes:
    return _SEND_DATA_HEADER.pack(interface_handle, timeout) + encode_items(items)


def encode_unconnected_payload(message: bytes, timeout: int = 0) -> bytes:
    """SendRRData body for an unconnected message: null address item, unconnected data item."""
    return _SEND_DATA_HEADER.pack(0, timeout) + encode_items(
        ((ItemType.NULL_ADDRESS, b""), (ItemType.UNCONNECTED_DATA, message))
    )


def encode_send_rr_data(message: bytes, session_handle: int, sender_context: bytes = bytes(8),
                        timeout: int = 0) -> bytes:
    """A whole SendRRData frame carrying one unconnected CIP message."""
    return encode_frame(Command.SEND_RR_DATA, encode_unconnected_payload(message, timeout), session_handle,
                        sender_context=sender_context)


class SocketAddress(NamedTuple):
    host: str
    port: int
    family: int = socket.AF_INET


def encode_sockaddr(address: SocketAddress) -> bytes:
    """sockaddr_in in network byte order, as the ListIdentity and 0x8000/0x8001 items carry it."""
    return _SOCKADDR.pack(address.family, address.port, socket.inet_aton(address.host))


def decode_sockaddr(data: bytes, offset: int = 0) -> SocketAddress:
    family, port, host = _SOCKADDR.unpack_from(data, offset)
    return SocketAddress(socket.inet_ntoa(host), port, family)


class IdentityItem(NamedTuple):
    """The CIP Identity item (type 0x0C) of a ListIdentity reply."""

    protocol_version: int
    socket_address: SocketAddress
    vendor_id: int
    device_type: int
    product_code: int
    revision_major: int
    revision_minor: int
    status: int
    serial_number: int
    product_name: str
    state: int


def encode_identity_item(item: IdentityItem) -> bytes:
    name = item.product_name.encode("latin-1")
    return (
        struct.pack("<H", item.protocol_version)
        + encode_sockaddr(item.socket_address)
        + _IDENTITY.pack(item.vendor_id, item.device_type, item.product_code, item.revision_major,
                         item.revision_minor, item.status, item.serial_number)
        + bytes((len(name),))
        + name
        + bytes((item.state,))
    )


def decode_identity_item(data: bytes) -> IdentityItem:
    (version,) = struct.unpack_from("<H", data, 0)
    address = decode_sockaddr(data, 2)
    fields = _IDENTITY.unpack_from(data, 18)
    offset = 18 + _IDENTITY.size
    length = data[offset]
    name = data[offset + 1 : offset + 1 + length].decode("latin-1")
    state = data[offset + 1 + length]
    return IdentityItem(version, address, *fields, name, state)


class ServiceItem(NamedTuple):
    """The item (type 0x0100) of a ListServices reply."""

    protocol_version: int
    capability_flags: int
    name: str


def encode_service_item(item: ServiceItem) -> bytes:
    return _LIST_SERVICES.pack(item.protocol_version, item.capability_flags, item.name.encode("ascii"))


def decode_service_item(data: bytes) -> ServiceItem:
    version, flags, name = _LIST_SERVICES.unpack_from(data, 0)
    return ServiceItem(version, flags, name.rstrip(b"\x00").decode("ascii"))
