"""Unit tests of a device whose EDS declares its class-1 connections (admission.DeclaredConnection):
each entry admitted with its own points, sizes and RPI range, the others refused with the status
the spec gives; its real-time formats on the wire (a T->O 32-bit run/idle header, a heartbeat-only
T->O, a modeless O->T with data, zero-length idle); its own consumed and produced assemblies; the
configuration data of a Forward Open written to the configuration assembly. No sockets, no clock."""

from __future__ import annotations

import random

from enip_farm.cip.admission import Originator
from enip_farm.cip.assembly import AssemblyInstance
from enip_farm.cip.connection import ConnectionKind
from enip_farm.cip.connection_path import KeyIdentity
from enip_farm.cip.connection_policy import ConnectionPolicy, DeclaredConnection, Refusal
from enip_farm.cip.connection_table import ConnectionTable, Opened
from enip_farm.protocol.connection import (
    ConnectionTriad,
    ConnectionType,
    ForwardOpenRequest,
    NetworkParameters,
    decode_io_packet,
    encode_io_packet,
)

MS = 1_000_000
T0 = 7_000 * MS
P2P, MULTICAST = ConnectionType.POINT_TO_POINT, ConnectionType.MULTICAST
ORIGINATOR = Originator("127.0.0.9")
OWNER, INPUT_ONLY, LISTEN_ONLY = ConnectionKind.EXCLUSIVE_OWNER, ConnectionKind.INPUT_ONLY, ConnectionKind.LISTEN_ONLY
DECLARED = (
    # a heartbeat-only owner first (as real files have it), then the data one with a T->O run/idle header
    DeclaredConnection(OWNER, 1, 0x97, 0x98, 0, 0, "heartbeat", "heartbeat", rpi_us=(4_000, 8_000)),
    DeclaredConnection(OWNER, 0x96, 0x70, 0x64, 6, 4, "run/idle", "run/idle", configuration_size=3,
                       rpi_us=(2_000, 100_000)),
    DeclaredConnection(OWNER, 1, 0x71, 0x65, 2, 2, "modeless", "modeless"),
    DeclaredConnection(INPUT_ONLY, 1, 0x80, 0x64, 0, 4, "heartbeat", "run/idle"),
    DeclaredConnection(LISTEN_ONLY, 1, 0x81, 0x64, 0, 4, "heartbeat", "run/idle", t_o_point_to_point=False),
)
_serials = iter(range(1, 1_000_000))


def make_table(declared: tuple[DeclaredConnection, ...] = DECLARED, configuration_size: int = 3) -> ConnectionTable:
    assemblies = {"output": AssemblyInstance(0x70, 6, True), "input": AssemblyInstance(0x64, 4, False),
                  "configuration": AssemblyInstance(0x96, configuration_size, True),
                  "point 113": AssemblyInstance(0x71, 2, True), "point 101": AssemblyInstance(0x65, 2, False)}
    policy = ConnectionPolicy(
        rpi_min_us=2_000, rpi_max_us=10_000_000, max_class1_connections=8, max_class3_connections=6,
        outputs_off_on_idle=True, outputs_off_on_fault=True, first_watchdog_ns=10_000 * MS,
        input_only_point=None, listen_only_point=None, multicast_group="239.192.1.0", declared=declared)
    return ConnectionTable(assemblies, policy, lambda: KeyIdentity(424, 43, 1, (2, 92)), rng=random.Random(3))


def request(path: str, o_t_size: int, t_o_size: int, rpi_us: int = 10_000,
            t_o_type: ConnectionType = P2P) -> ForwardOpenRequest:
    serial = next(_serials)
    return ForwardOpenRequest(
        0x0A, 0x0E, 0, 0x7E570000 + serial, ConnectionTriad(serial, 0x1234, 0xABCD), 0, rpi_us,
        NetworkParameters(False, P2P, 2, False, o_t_size), rpi_us,
        NetworkParameters(False, t_o_type, 2, False, t_o_size), 0x01, bytes.fromhex(path))


def test_each_entry_is_admitted_with_its_own_points_sizes_and_rpi() -> None:
    table = make_table()
    heartbeat = table.forward_open(request("20 04 24 01 2C 97 2C 98", 2, 2, rpi_us=5_000), ORIGINATOR, T0)
    assert type(heartbeat) is Opened and heartbeat.connection.t_o_heartbeat
    data = table.forward_open(request("20 04 24 96 2C 70 2C 64", 2 + 4 + 6, 2 + 4 + 4), ORIGINATOR, T0)
    assert type(data) is Opened and data.connection.t_o_run_idle_header
    refusals = {
        "RPI beyond the entry's range": (request("20 04 24 01 2C 97 2C 98", 2, 2, rpi_us=10_000), (0x0111,)),
        "O->T size without the header": (request("20 04 24 01 2C 71 2C 65", 2 + 4 + 2, 4), (0x0127, 4)),
        "T->O without its run/idle header": (request("20 04 24 01 2C 80 2C 64", 2, 2 + 4), (0x0128, 10)),
        "no entry consumes 0x72": (request("20 04 24 01 2C 72 2C 64", 8, 6), (0x012A,)),
        "no entry produces 0x66 from 0x70": (request("20 04 24 96 2C 70 2C 66", 12, 10), (0x012B,)),
        "another configuration point": (request("20 04 24 05 2C 70 2C 64", 12, 10), (0x0129,)),
        "listen only without a multicast owner": (request("20 04 24 01 2C 81 2C 64", 2, 10, t_o_type=MULTICAST),
                                                  (0x0119,)),
        "listen only point to point": (request("20 04 24 01 2C 81 2C 64", 2, 10), (0x0108,)),
    }
    for why, (message, status) in refusals.items():
        refused = table.forward_open(message, ORIGINATOR, T0)
        assert type(refused) is Refusal and refused.additional_status == status, why


def test_t_o_run_idle_header_heartbeat_and_each_point_produced() -> None:
    table = make_table()
    table.assemblies["input"].data[:] = b"\x0a\x0b\x0c\x0d"
    table.assemblies["point 101"].data[:] = b"\x55\x66"
    for path, o_t_size, t_o_size in (("20 04 24 96 2C 70 2C 64", 12, 10), ("20 04 24 01 2C 97 2C 98", 2, 2),
                                     ("20 04 24 01 2C 71 2C 65", 4, 4)):
        assert type(table.forward_open(request(path, o_t_size, t_o_size, rpi_us=5_000), ORIGINATOR, T0)) is Opened
    sent = sorted(decode_io_packet(data).data for data, _ in table.datagrams_to_send(T0))
    assert sent == [b"", b"\x01\x00\x00\x00\x0a\x0b\x0c\x0d", b"\x55\x66"]


def test_modeless_o_t_data_goes_to_its_own_point_and_zero_length_is_idle() -> None:
    table = make_table()
    opened = table.forward_open(request("20 04 24 01 2C 71 2C 65", 4, 4), ORIGINATOR, T0)
    assert type(opened) is Opened and opened.connection.o_t_modeless
    o_t_id = opened.connection.o_t_id
    assert table.receive_datagram(encode_io_packet(o_t_id, 1, 1, b"\x12\x34"), "127.0.0.9", T0 + MS)
    assert table.assemblies["point 113"].data == b"\x12\x34" and table.assemblies["output"].data == bytes(6)
    assert not table.receive_datagram(encode_io_packet(o_t_id, 2, 2, b"\x12\x34\x56"), "127.0.0.9", T0 + 2 * MS)
    assert table.receive_datagram(encode_io_packet(o_t_id, 3, 3, b""), "127.0.0.9", T0 + 3 * MS)  # idle
    assert table.assemblies["point 113"].data == b"\x00\x00" and not opened.connection.run


def test_the_forward_opens_configuration_data_is_written_and_a_wrong_size_refused() -> None:
    table = make_table()
    with_data = bytes.fromhex("20 04 24 96 2C 70 2C 64 80 02 aa bb cc 00")  # data segment: 2 words, 3 bytes + pad
    refused = table.forward_open(request(with_data.hex(), 12, 10), ORIGINATOR, T0)
    assert type(refused) is Refusal and refused.additional_status == (0x0129,)  # 4 bytes, the entry says 3
    right = bytes.fromhex("20 04 24 96 2C 70 2C 64 80 02 aa bb cc dd")
    table = make_table((DeclaredConnection(OWNER, 0x96, 0x70, 0x64, 6, 4, "run/idle", "modeless",
                                           configuration_size=4),), configuration_size=4)
    opened = table.forward_open(request(right.hex(), 12, 6), ORIGINATOR, T0)
    assert type(opened) is Opened and opened.connection.configuration_data == b"\xaa\xbb\xcc\xdd"
    assert table.assemblies["configuration"].data == b"\xaa\xbb\xcc\xdd"
