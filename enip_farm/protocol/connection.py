"""Connection Manager service data and class-1 packets (CIP Networks Library Vol. 1, 3-5.5:
Forward Open 0x54, Large Forward Open 0x5B, Forward Close 0x4E; Vol. 2, 3-2: the CPF of an I/O
packet on UDP 2222)."""

from __future__ import annotations

import struct
from enum import IntEnum
from typing import NamedTuple

from enip_farm.protocol.cpf import ItemType

#: The UDP port of class-1 I/O packets (Vol. 2, 3-3.9.4).
IO_PORT = 2222
_FO_HEAD = struct.Struct("<BBIIHHIB3x")  # up to and including the timeout multiplier and reserved
_FO_RPI_PARAMS = struct.Struct("<IH")
_LFO_RPI_PARAMS = struct.Struct("<II")
_FO_REPLY = struct.Struct("<IIHHIIIBB")
_TRIAD = struct.Struct("<HHI")
_FC_HEAD = struct.Struct("<BBHHI")
_IO_HEADER = struct.Struct("<HHHIIHHH")  # count, 0x8002 item, conn id, seq, 0x00B1 item, seq count
_CLASS_0_HEADER = struct.Struct("<HHHIIHH")  # the same without the sequence count (class 0)


class ConnectionType(IntEnum):
    NULL = 0
    MULTICAST = 1
    POINT_TO_POINT = 2


class NetworkParameters(NamedTuple):
    """Network connection parameters, 16-bit (Forward Open) or 32-bit (Large Forward Open)."""

    redundant_owner: bool
    connection_type: ConnectionType
    priority: int
    variable: bool
    size: int

    @classmethod
    def decode(cls, value: int, large: bool) -> NetworkParameters:
        if large:
            return cls(bool(value >> 31 & 1), ConnectionType(value >> 29 & 3) if value >> 29 & 3 < 3 else 3,
                       value >> 26 & 3, bool(value >> 25 & 1), value & 0xFFFF)  # type: ignore[arg-type]
        return cls(bool(value >> 15 & 1), ConnectionType(value >> 13 & 3) if value >> 13 & 3 < 3 else 3,
                   value >> 10 & 3, bool(value >> 9 & 1), value & 0x1FF)  # type: ignore[arg-type]

    def encode(self, large: bool) -> int:
        if large:
            return (self.redundant_owner << 31 | int(self.connection_type) << 29 | self.priority << 26
                    | self.variable << 25 | self.size & 0xFFFF)
        return (self.redundant_owner << 15 | int(self.connection_type) << 13 | self.priority << 10
                | self.variable << 9 | self.size & 0x1FF)


class ConnectionTriad(NamedTuple):
    connection_serial: int
    originator_vendor_id: int
    originator_serial: int


class ForwardOpenRequest(NamedTuple):
    priority_time_tick: int
    timeout_ticks: int
    o_t_connection_id: int
    t_o_connection_id: int
    triad: ConnectionTriad
    timeout_multiplier: int
    o_t_rpi: int  # microseconds
    o_t_parameters: NetworkParameters
    t_o_rpi: int
    t_o_parameters: NetworkParameters
    transport_type_trigger: int
    connection_path: bytes
    large: bool = False

    @property
    def transport_class(self) -> int:
        return self.transport_type_trigger & 0x0F

    @property
    def production_trigger(self) -> int:
        return self.transport_type_trigger >> 4 & 0x07


class ForwardCloseRequest(NamedTuple):
    priority_time_tick: int
    timeout_ticks: int
    triad: ConnectionTriad
    connection_path: bytes


class DecodeError(ValueError):
    pass


def decode_forward_open(data: bytes, large: bool = False) -> ForwardOpenRequest:
    rpi_params = _LFO_RPI_PARAMS if large else _FO_RPI_PARAMS
    fixed = _FO_HEAD.size + 2 * rpi_params.size + 2
    if len(data) < fixed:
        raise DecodeError("forward open shorter than its fixed fields")
    tick, ticks, o_t_id, t_o_id, serial, vendor, originator_serial, multiplier = _FO_HEAD.unpack_from(data, 0)
    offset = _FO_HEAD.size
    o_t_rpi, o_t_params = rpi_params.unpack_from(data, offset)
    t_o_rpi, t_o_params = rpi_params.unpack_from(data, offset + rpi_params.size)
    offset += 2 * rpi_params.size
    transport, path_words = data[offset], data[offset + 1]
    path = data[offset + 2 :]
    if len(path) != 2 * path_words:
        raise DecodeError("connection path size does not match the request")
    return ForwardOpenRequest(tick, ticks, o_t_id, t_o_id, ConnectionTriad(serial, vendor, originator_serial),
                              multiplier, o_t_rpi, NetworkParameters.decode(o_t_params, large), t_o_rpi,
                              NetworkParameters.decode(t_o_params, large), transport, path, large)


def encode_forward_open(request: ForwardOpenRequest) -> bytes:
    rpi_params = _LFO_RPI_PARAMS if request.large else _FO_RPI_PARAMS
    return (
        _FO_HEAD.pack(request.priority_time_tick, request.timeout_ticks, request.o_t_connection_id,
                      request.t_o_connection_id, *request.triad, request.timeout_multiplier)
        + rpi_params.pack(request.o_t_rpi, request.o_t_parameters.encode(request.large))
        + rpi_params.pack(request.t_o_rpi, request.t_o_parameters.encode(request.large))
        + bytes((request.transport_type_trigger, len(request.connection_path) // 2))
        + request.connection_path
    )


class ForwardOpenReply(NamedTuple):
    o_t_connection_id: int
    t_o_connection_id: int
    triad: ConnectionTriad
    o_t_api: int
    t_o_api: int
    application_reply: bytes = b""


def encode_forward_open_reply(reply: ForwardOpenReply) -> bytes:
    return _FO_REPLY.pack(reply.o_t_connection_id, reply.t_o_connection_id, *reply.triad, reply.o_t_api,
                          reply.t_o_api, len(reply.application_reply) // 2, 0) + reply.application_reply


def decode_forward_open_reply(data: bytes) -> ForwardOpenReply:
    o_t, t_o, serial, vendor, originator_serial, o_t_api, t_o_api, words, _ = _FO_REPLY.unpack_from(data, 0)
    return ForwardOpenReply(o_t, t_o, ConnectionTriad(serial, vendor, originator_serial), o_t_api, t_o_api,
                            data[_FO_REPLY.size : _FO_REPLY.size + 2 * words])


def encode_connection_failure(triad: ConnectionTriad, remaining_path_words: int = 0) -> bytes:
    """The data of an unsuccessful Forward Open or Forward Close reply."""
    return _TRIAD.pack(*triad) + bytes((remaining_path_words, 0))


def decode_forward_close(data: bytes) -> ForwardCloseRequest:
    if len(data) < _FC_HEAD.size + 2:
        raise DecodeError("forward close shorter than its fixed fields")
    tick, ticks, serial, vendor, originator_serial = _FC_HEAD.unpack_from(data, 0)
    path_words = data[_FC_HEAD.size]
    path = data[_FC_HEAD.size + 2 :]
    if len(path) != 2 * path_words:
        raise DecodeError("connection path size does not match the request")
    return ForwardCloseRequest(tick, ticks, ConnectionTriad(serial, vendor, originator_serial), path)


def encode_forward_close(request: ForwardCloseRequest) -> bytes:
    return (_FC_HEAD.pack(request.priority_time_tick, request.timeout_ticks, *request.triad)
            + bytes((len(request.connection_path) // 2, 0)) + request.connection_path)


def encode_forward_close_reply(triad: ConnectionTriad) -> bytes:
    return _TRIAD.pack(*triad) + b"\x00\x00"  # application reply size 0, reserved


# -- class-1 packets on UDP 2222 ------------------------------------------------------------------


class IoPacket(NamedTuple):
    connection_id: int
    sequence: int  # 32-bit, from the sequenced address item
    sequence_count: int  # 16-bit CIP sequence count at the start of the connected data
    data: bytes  # after the sequence count: run/idle header (if any) and application data


_SEQUENCED_ADDRESS, _CONNECTED_DATA = int(ItemType.SEQUENCED_ADDRESS), int(ItemType.CONNECTED_DATA)  # plain ints: fast


def encode_io_packet(connection_id: int, sequence: int, sequence_count: int, data: bytes) -> bytes:
    return _IO_HEADER.pack(2, _SEQUENCED_ADDRESS, 8, connection_id, sequence & 0xFFFFFFFF,
                           _CONNECTED_DATA, 2 + len(data), sequence_count & 0xFFFF) + data


def encode_class0_packet(connection_id: int, sequence: int, data: bytes) -> bytes:
    """A class-0 packet (CIP Safety connections): no 16-bit sequence count before the data."""
    return _CLASS_0_HEADER.pack(2, _SEQUENCED_ADDRESS, 8, connection_id, sequence & 0xFFFFFFFF,
                                _CONNECTED_DATA, len(data)) + data


def class0_data(packet: IoPacket) -> bytes:
    """The connected data of a class-0 packet that `decode_io_packet` read as class 1."""
    return packet.sequence_count.to_bytes(2, "little") + packet.data


def decode_io_packet(datagram: bytes) -> IoPacket | None:
    """None for anything that is not a two-item sequenced-address + connected-data packet."""
    fields = unpack_io_header(datagram)
    if fields is None:
        return None
    return IoPacket(fields[0], fields[1], fields[2], datagram[_IO_HEADER.size :])


def unpack_io_header(datagram: bytes) -> tuple[int, int, int] | None:
    """(connection id, sequence, sequence count) of a class-1 packet, its data from byte
    `IO_HEADER_SIZE` on; None for anything that is not a two-item sequenced-address + connected-data
    packet (the hot path's decoder: no object made)."""
    if len(datagram) < 20:  # _IO_HEADER.size
        return None
    count, address_type, address_length, connection_id, sequence, data_type, data_length, sequence_count = (
        _IO_HEADER.unpack_from(datagram, 0))
    if (count != 2 or address_type != _SEQUENCED_ADDRESS or address_length != 8
            or data_type != _CONNECTED_DATA or data_length != len(datagram) - 18 or data_length < 2):
        return None
    return connection_id, sequence, sequence_count


#: Where a class-1 packet's data begins (after the item count, both item headers and the sequence count).
IO_HEADER_SIZE = _IO_HEADER.size
