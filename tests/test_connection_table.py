"""Unit tests of the sans-IO connection table (cip/connection_table.py) with an injected clock:
admission and refusals with their expected sizes, consumption, the T->O schedule, supervision to
the nanosecond (not a tick early, not a tick late) and close cascades. No sockets, no sleeps."""

from __future__ import annotations

import random

import pytest

from enip_farm.cip.admission import Originator
from enip_farm.cip.assembly import AssemblyInstance
from enip_farm.cip.connection import ConnectionKind
from enip_farm.cip.connection_events import (
    ConnectionClosed,
    ConnectionRefused,
    ConnectionShortData,
    ConnectionTimedOut,
)
from enip_farm.cip.connection_path import KeyIdentity
from enip_farm.cip.connection_policy import ConnectionPolicy, Refusal
from enip_farm.cip.connection_table import ConnectionTable, Opened
from enip_farm.protocol.connection import (
    ConnectionTriad,
    ConnectionType,
    ForwardOpenRequest,
    NetworkParameters,
    decode_io_packet,
    encode_io_packet,
)

MS = 1_000_000  # ns
T0 = 5_000 * MS  # an arbitrary origin: the table never reads a clock
P2P, MULTICAST = ConnectionType.POINT_TO_POINT, ConnectionType.MULTICAST
ORIGINATOR = Originator("127.0.0.9")
OWNER_PATH = bytes.fromhex("20 04 24 01 2C 64 2C 65")
INPUT_ONLY_PATH = bytes.fromhex("20 04 24 01 2C C6 2C 65")
LISTEN_ONLY_PATH = bytes.fromhex("20 04 24 01 2C C7 2C 65")


def make_table(first_watchdog_ms: int = 10_000, idle_off: bool = True, fault_off: bool = True,
               output_size: int = 2, input_size: int = 2) -> ConnectionTable:
    assemblies = {"output": AssemblyInstance(100, output_size, True), "input": AssemblyInstance(101, input_size, False),
                  "configuration": AssemblyInstance(1, 0, True)}
    policy = ConnectionPolicy(
        rpi_min_us=2_000, rpi_max_us=10_000_000, max_class1_connections=8, max_class3_connections=6,
        outputs_off_on_idle=idle_off, outputs_off_on_fault=fault_off, first_watchdog_ns=first_watchdog_ms * MS,
        input_only_point=198, listen_only_point=199, multicast_group="239.192.1.0")
    return ConnectionTable(assemblies, policy, lambda: KeyIdentity(75, 7, 1030, (1, 1)), rng=random.Random(1))


_serials = iter(range(1, 1_000_000))


def request(path: bytes = OWNER_PATH, o_t_size: int = 8, t_o_size: int = 4, rpi_us: int = 10_000,
            multiplier: int = 0, variable: bool = False, t_o_type: ConnectionType = P2P,
            transport: int = 0x01) -> ForwardOpenRequest:
    return ForwardOpenRequest(
        0x0A, 0x0E, 0, 0x7E570001, ConnectionTriad(next(_serials), 0x1234, 0xABCD), multiplier, rpi_us,
        NetworkParameters(False, P2P, 2, variable, o_t_size), rpi_us,
        NetworkParameters(False, t_o_type, 2, variable, t_o_size), transport, path)


def open_owner(table: ConnectionTable, now: int = T0, **kwargs) -> Opened:
    result = table.forward_open(request(**kwargs), ORIGINATOR, now)
    assert type(result) is Opened, result
    return result


def o_t(connection_id: int, sequence: int, data: bytes = b"\x33\x00", run: bool = True) -> bytes:
    return encode_io_packet(connection_id, sequence, sequence, (b"\x01" if run else b"\x00") + b"\x00\x00\x00" + data)


# -- supervision, to the tick -----------------------------------------------------------------------


def test_timeout_is_exactly_the_last_valid_packet_plus_rpi_times_multiplier() -> None:
    table = make_table(first_watchdog_ms=10_000)
    connection = open_owner(table, rpi_us=10_000, multiplier=0).connection  # timeout 10 ms x 2^2 = 40 ms
    assert connection.timeout_ns == 40 * MS
    last = T0 + 1_000 * MS
    for n, at in enumerate(range(T0 + 10 * MS, last + 1, 10 * MS), start=1):  # fed for 1 s
        assert table.receive_datagram(o_t(connection.o_t_id, n), "127.0.0.9", at)
    table.pop_events()
    assert table.assemblies["output"].data == b"\x33\x00" and table.status == 0x0061
    assert connection.deadline == last + 40 * MS  # the first watchdog (10 s) no longer counts
    table.handle_timer(last + 40 * MS - 1)
    assert connection.o_t_id in table.connections and table.pop_events() == []
    table.handle_timer(last + 40 * MS)
    assert connection.o_t_id not in table.connections
    (event,) = table.pop_events()
    assert (type(event), event.at, event.connection) == (ConnectionTimedOut, last + 40 * MS, connection)
    assert table.assemblies["output"].data == b"\x00\x00"  # the fault state: off
    assert table.status == 0x0030 and table.get_timer() is None


@pytest.mark.parametrize("multiplier", [0, 1, 3, 7])
def test_timeout_multiplier(multiplier: int) -> None:
    table = make_table()
    connection = open_owner(table, rpi_us=2_000, multiplier=multiplier).connection
    assert table.receive_datagram(o_t(connection.o_t_id, 1), "127.0.0.9", T0 + 1)
    timeout = 2 * MS << (2 + multiplier)
    assert table.get_timer() <= connection.deadline == T0 + 1 + timeout
    table.handle_timer(T0 + timeout)
    assert connection.o_t_id in table.connections
    table.handle_timer(T0 + 1 + timeout)
    assert connection.o_t_id not in table.connections


def test_first_watchdog_before_the_first_packet() -> None:
    table = make_table(first_watchdog_ms=10_000)
    connection = open_owner(table).connection
    table.handle_timer(T0 + 10_000 * MS - 1)
    assert connection.o_t_id in table.connections
    table.handle_timer(T0 + 10_000 * MS)
    assert connection.o_t_id not in table.connections


def test_first_watchdog_is_never_shorter_than_the_timeout() -> None:
    table = make_table(first_watchdog_ms=0)
    connection = open_owner(table, rpi_us=10_000, multiplier=2).connection  # 160 ms
    table.handle_timer(T0 + 160 * MS - 1)
    assert connection.o_t_id in table.connections
    table.handle_timer(T0 + 160 * MS)
    assert connection.o_t_id not in table.connections


def test_fault_state_hold_keeps_the_outputs() -> None:
    table = make_table(fault_off=False)
    connection = open_owner(table).connection
    table.receive_datagram(o_t(connection.o_t_id, 1, b"\x10\x00"), "127.0.0.9", T0)
    table.handle_timer(connection.deadline)
    assert table.assemblies["output"].data == b"\x10\x00" and not table.assemblies["output"].owned


def test_invalid_packets_do_not_feed_the_watchdog() -> None:
    table = make_table(first_watchdog_ms=0)
    connection = open_owner(table).connection
    assert table.receive_datagram(o_t(connection.o_t_id, 5), "127.0.0.9", T0 + 1 * MS)
    deadline = connection.deadline
    rejected = [
        (o_t(connection.o_t_id, 5), "127.0.0.9", "stale"),  # the same sequence again
        (o_t(connection.o_t_id, 4), "127.0.0.9", "stale"),
        (o_t(connection.o_t_id, 6), "127.0.0.8", "wrong_originator"),
        (o_t(connection.o_t_id ^ 1, 6), "127.0.0.9", "unknown_connection"),
        (o_t(connection.o_t_id, 6, b"\x33"), "127.0.0.9", "wrong_size"),
        (b"\x02\x00\x02\x80", "127.0.0.9", "malformed"),
    ]
    for n, (data, host, reason) in enumerate(rejected):
        assert not table.receive_datagram(data, host, T0 + 2 * MS)
        assert table.counters[f"o_t_dropped_{reason}"] == [r for _, _, r in rejected[:n + 1]].count(reason), reason
    assert connection.deadline == deadline and connection.received == 1


# -- the T->O schedule ------------------------------------------------------------------------------


def test_production_runs_on_absolute_deadlines() -> None:
    table = make_table()
    connection = open_owner(table, rpi_us=10_000).connection
    table.assemblies["input"].data[:] = b"\x81\x02"
    (packet, address), = table.datagrams_to_send(T0)  # the first at once
    assert address == ("127.0.0.9", 2222)
    decoded = decode_io_packet(packet)
    assert (decoded.connection_id, decoded.sequence, decoded.data) == (connection.t_o_id, 1, b"\x81\x02")
    assert table.datagrams_to_send(T0 + 10 * MS - 1) == []
    assert len(table.datagrams_to_send(T0 + 10 * MS + 3 * MS)) == 1  # 3 ms late: the next stays on the grid
    assert table.datagrams_to_send(T0 + 20 * MS - 1) == []
    assert len(table.datagrams_to_send(T0 + 20 * MS)) == 1
    assert len(table.datagrams_to_send(T0 + 55 * MS)) == 1  # 3.5 periods behind: no burst
    assert table.datagrams_to_send(T0 + 59 * MS) == []
    assert len(table.datagrams_to_send(T0 + 60 * MS)) == 1
    assert table.productions[connection.t_o_id, connection.t_o_address].late == 2


def test_nothing_is_produced_after_forward_close() -> None:
    table = make_table()
    opened = open_owner(table)
    assert table.datagrams_to_send(T0)
    closed = table.forward_close(opened.connection.triad, T0 + 10 * MS)  # exactly when the next one is due
    assert closed is opened.connection
    assert table.datagrams_to_send(T0 + 10 * MS) == [] and table.get_timer() is None
    assert table.forward_close(opened.connection.triad, T0 + 11 * MS) is None  # 0x0107


# -- sizes: refused with the size the target expects ------------------------------------------------


@pytest.mark.parametrize(
    ("kwargs", "additional"),
    [
        ({"o_t_size": 9}, (0x0127, 8)),
        ({"o_t_size": 7}, (0x0127, 8)),
        ({"o_t_size": 505, "variable": True}, (0x0127, 8)),  # EEIP's default: more than the assembly
        ({"o_t_size": 5, "variable": True}, (0x0127, 8)),  # not even the headers
        ({"t_o_size": 5}, (0x0128, 4)),
        ({"t_o_size": 505, "variable": True}, (0x0128, 4)),
        ({"t_o_size": 3, "variable": True}, (0x0128, 4)),
        ({"path": INPUT_ONLY_PATH, "o_t_size": 8}, (0x0127, 2)),
    ],
)
def test_sizes_that_cannot_be_honoured_are_refused(kwargs: dict, additional: tuple[int, int]) -> None:
    table = make_table()
    result = table.forward_open(request(**kwargs), ORIGINATOR, T0)
    assert type(result) is Refusal and result.additional_status == additional and result.general == 0x01
    assert not table.connections
    (event,) = table.pop_events()  # the refusal is told, with who asked and what was expected
    extended, size = additional
    assert type(event) is ConnectionRefused and event.at == T0
    assert event.reason.startswith(f"Forward Open from {ORIGINATOR.host}: 0x01/0x{extended:04X} "
                                   f"connection failure: invalid {'O->T' if extended == 0x0127 else 'T->O'} "
                                   f"connection size, {size} bytes expected (class 1, O->T RPI ")


def test_variable_o_t_that_fits_and_a_shorter_packet() -> None:
    table = make_table(output_size=4)
    connection = open_owner(table, o_t_size=9, t_o_size=4, variable=True).connection  # 3 of 4 bytes
    table.pop_events()
    assert table.receive_datagram(o_t(connection.o_t_id, 1, b"\x01\x02\x03\x04"), "127.0.0.9", T0)
    assert table.assemblies["output"].data == b"\x01\x02\x03\x04"
    assert table.receive_datagram(o_t(connection.o_t_id, 2, b"\x09\x09\x09"), "127.0.0.9", T0 + MS)
    assert table.assemblies["output"].data == b"\x01\x02\x03\x04"  # not applied: whole images only
    assert connection.last_received == T0 + MS  # but a valid packet: the watchdog is fed
    assert table.counters["o_t_short_data"] == 1
    (event,) = table.pop_events()
    assert type(event) is ConnectionShortData and event.reason == "3 of 4 bytes: not applied to the outputs"
    table.receive_datagram(o_t(connection.o_t_id, 3, b"\x09\x09"), "127.0.0.9", T0 + 2 * MS)
    assert table.pop_events() == [] and table.counters["o_t_short_data"] == 2  # one event per connection


def test_run_idle() -> None:
    table = make_table(idle_off=True)
    connection = open_owner(table).connection
    table.receive_datagram(o_t(connection.o_t_id, 1, b"\x44\x00"), "127.0.0.9", T0)
    assert table.status == 0x0061
    table.receive_datagram(o_t(connection.o_t_id, 2, b"\x55\x00", run=False), "127.0.0.9", T0 + MS)
    assert table.status == 0x0071 and table.assemblies["output"].data == b"\x00\x00"


# -- multicast, listen only, the close cascade ------------------------------------------------------


def test_point_to_point_streams_are_never_shared() -> None:
    """Two originators that chose the same T->O connection id each get their own stream."""
    table = make_table()
    first = open_owner(table).connection
    second = table.forward_open(request(path=INPUT_ONLY_PATH, o_t_size=2), Originator("127.0.0.10"), T0)
    assert type(second) is Opened and second.connection.t_o_id == first.t_o_id
    assert sorted(address for _, address in table.datagrams_to_send(T0)) == [("127.0.0.10", 2222),
                                                                            ("127.0.0.9", 2222)]
    table.forward_close(first.triad, T0 + MS)
    assert [address for _, address in table.datagrams_to_send(T0 + 10 * MS)] == [("127.0.0.10", 2222)]


def test_listen_only_closes_with_its_producer_and_shares_its_stream() -> None:
    table = make_table()
    owner = open_owner(table, t_o_type=MULTICAST)
    assert owner.reply_items[0][0] == 0x8001  # the group, in the reply
    listener = table.forward_open(request(path=LISTEN_ONLY_PATH, o_t_size=2, t_o_type=MULTICAST), ORIGINATOR, T0)
    assert type(listener) is Opened and listener.connection.kind is ConnectionKind.LISTEN_ONLY
    assert listener.connection.t_o_id == owner.connection.t_o_id and len(table.productions) == 1
    assert len(table.datagrams_to_send(T0)) == 1  # one stream for both
    table.pop_events()
    table.forward_close(owner.connection.triad, T0 + MS)
    assert [type(e) for e in table.pop_events()] == [ConnectionClosed, ConnectionClosed]
    assert not table.connections and not table.productions


def test_listen_only_needs_a_producer() -> None:
    table = make_table()
    result = table.forward_open(request(path=LISTEN_ONLY_PATH, o_t_size=2, t_o_type=MULTICAST), ORIGINATOR, T0)
    assert result == Refusal(0x0119)


def test_class3_session_close_and_supervision() -> None:
    table = make_table()
    session = object()
    explicit = request(path=bytes.fromhex("20 02 24 01"), transport=0xA3, o_t_size=500, t_o_size=500,
                       rpi_us=100_000, variable=True)
    opened = table.forward_open(explicit, Originator("127.0.0.9", session=session), T0)
    assert type(opened) is Opened and opened.connection.kind is ConnectionKind.EXPLICIT
    assert table.receive_connected(opened.connection.o_t_id, object(), T0 + MS) is None  # another session's
    assert table.receive_connected(opened.connection.o_t_id, session, T0 + MS) is opened.connection
    table.handle_timer(T0 + MS + 400 * MS - 1)
    assert opened.connection.o_t_id in table.connections
    table.session_closed(session, T0 + 2 * MS)
    assert not table.connections


# -- hostile peers ------------------------------------------------------------------------------------


def test_o_t_only_from_the_port_of_the_first_valid_packet() -> None:
    table = make_table()
    connection = open_owner(table).connection
    assert table.receive_datagram(o_t(connection.o_t_id, 1), "127.0.0.9", T0, 40001)
    forged = encode_io_packet(connection.o_t_id, 0x7FFFFFF0, 0, b"\x01\x00\x00\x00\x66\x00")
    assert not table.receive_datagram(forged, "127.0.0.9", T0 + MS, 40002)  # same host, another port
    assert table.counters["o_t_dropped_wrong_port"] == 1
    assert table.receive_datagram(o_t(connection.o_t_id, 2), "127.0.0.9", T0 + 2 * MS, 40001)  # not starved


def test_t_o_goes_to_the_originator_whatever_its_item_says() -> None:
    from enip_farm.protocol.commands import SocketAddress

    table = make_table()
    aimed = Originator("127.0.0.9", SocketAddress("127.0.0.77", 40000))  # a third host in the 0x8001 item
    result = table.forward_open(request(), aimed, T0)
    assert type(result) is Opened and result.connection.t_o_address == ("127.0.0.9", 40000)


def test_connection_ids_are_not_sequential() -> None:
    table = ConnectionTable(make_table().assemblies, make_table().policy, lambda: KeyIdentity(75, 7, 1030, (1, 1)))
    ids = [open_owner(table, path=INPUT_ONLY_PATH, o_t_size=2).connection.o_t_id for _ in range(6)]
    assert len(set(ids)) == 6 and sorted(b - a for a, b in zip(ids, ids[1:], strict=False)) != [1] * 5
