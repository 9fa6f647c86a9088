"""The values that vary in the field and did not in the tests (issue 32), each held to both bounds
with injected time: O->T and T->O RPIs that differ, sequences across the 32-bit wrap and the 16-bit
CIP count's, a first watchdog anywhere between 0 and the timeout, fault durations to the tick (a
virtual clock on the farm's loop), a fault set again while it runs, and random delays that stay
within their bounds and spread over them (seeded). Unit tests: no sockets, no sleeps.

Each test here kills a mutation that every other test let through (bench/mutation.py --named)."""

from __future__ import annotations

import random
from collections.abc import Iterator

import pytest

from enip_farm.cip.admission import Originator
from enip_farm.cip.assembly import AssemblyInstance
from enip_farm.cip.connection_events import ConnectionTimedOut
from enip_farm.cip.connection_path import KeyIdentity
from enip_farm.cip.connection_policy import ConnectionPolicy
from enip_farm.cip.connection_table import ConnectionTable, Opened
from enip_farm.device.faults import DROP, DeviceFaults, Fault
from enip_farm.farm.farm import Farm
from enip_farm.protocol.connection import (
    ConnectionTriad,
    ConnectionType,
    ForwardOpenRequest,
    NetworkParameters,
    decode_io_packet,
    encode_io_packet,
)
from tests.virtual_clock import VirtualClockLoop, at

MS = 1_000_000  # ns
T0 = 7_000 * MS  # an arbitrary origin: the table never reads a clock
HOST = "127.0.0.9"
OWNER_PATH = bytes.fromhex("20 04 24 01 2C 64 2C 65")
WRAP = 1 << 32
HALF = 1 << 31


def make_table(first_watchdog_ns: int = 10_000 * MS) -> ConnectionTable:
    assemblies = {"output": AssemblyInstance(100, 2, True), "input": AssemblyInstance(101, 2, False),
                  "configuration": AssemblyInstance(1, 0, True)}
    policy = ConnectionPolicy(
        rpi_min_us=1_000, rpi_max_us=10_000_000, max_class1_connections=8, max_class3_connections=6,
        outputs_off_on_idle=True, outputs_off_on_fault=True, first_watchdog_ns=first_watchdog_ns,
        input_only_point=198, listen_only_point=199, multicast_group="239.192.1.0")
    return ConnectionTable(assemblies, policy, lambda: KeyIdentity(75, 7, 1030, (1, 1)), rng=random.Random(32))


_serials = iter(range(1, 1_000_000))


def open_owner(table: ConnectionTable, o_t_rpi_us: int = 10_000, t_o_rpi_us: int = 10_000, multiplier: int = 0,
               now: int = T0) -> Opened:
    p2p = ConnectionType.POINT_TO_POINT
    request = ForwardOpenRequest(
        0x0A, 0x0E, 0, 0x7E570001, ConnectionTriad(next(_serials), 0x1234, 0xABCD), multiplier, o_t_rpi_us,
        NetworkParameters(False, p2p, 2, False, 8), t_o_rpi_us, NetworkParameters(False, p2p, 2, False, 4), 0x01,
        OWNER_PATH)
    result = table.forward_open(request, Originator(HOST), now)
    assert type(result) is Opened, result
    return result


def o_t(connection_id: int, sequence: int, data: bytes = b"\x33\x00", count: int | None = None) -> bytes:
    """An O->T packet in run mode; its 16-bit CIP count is the sequence's low half unless given."""
    return encode_io_packet(connection_id, sequence, sequence if count is None else count, b"\x01\x00\x00\x00" + data)


# -- O->T and T->O RPIs that differ -------------------------------------------------------------------


@pytest.mark.parametrize(("o_t_rpi_us", "t_o_rpi_us", "multiplier"),
                         [(10_000, 50_000, 0), (50_000, 10_000, 0), (2_000, 100_000, 3), (100_000, 2_000, 1)])
def test_the_timeout_counts_from_the_o_t_rpi_and_t_o_runs_at_its_own(o_t_rpi_us: int, t_o_rpi_us: int,
                                                                      multiplier: int) -> None:
    """Vol. 1, 3-4.4.9: the consumer's (O->T) RPI x 2^(2 + multiplier), whatever the T->O RPI."""
    table = make_table()
    connection = open_owner(table, o_t_rpi_us, t_o_rpi_us, multiplier).connection
    timeout = o_t_rpi_us * 1000 << (2 + multiplier)
    assert connection.timeout_ns == timeout
    fed = T0 + 3 * MS
    assert table.receive_datagram(o_t(connection.o_t_id, 1), HOST, fed)
    table.pop_events()  # the opening
    assert table.get_timer() <= connection.deadline == fed + timeout
    table.handle_timer(fed + timeout - 1)
    assert connection.o_t_id in table.connections and table.pop_events() == []
    table.handle_timer(fed + timeout)
    assert connection.o_t_id not in table.connections
    (event,) = table.pop_events()
    assert (type(event), event.at) == (ConnectionTimedOut, fed + timeout)


@pytest.mark.parametrize(("o_t_rpi_us", "t_o_rpi_us"), [(10_000, 50_000), (50_000, 10_000)])
def test_t_o_is_produced_on_the_t_o_rpi(o_t_rpi_us: int, t_o_rpi_us: int) -> None:
    table = make_table()
    open_owner(table, o_t_rpi_us, t_o_rpi_us)
    period = t_o_rpi_us * 1000
    assert len(table.datagrams_to_send(T0)) == 1
    for n in range(1, 4):
        assert table.datagrams_to_send(T0 + n * period - 1) == []
        assert len(table.datagrams_to_send(T0 + n * period)) == 1


# -- sequences across the wraps ---------------------------------------------------------------------


def test_o_t_sequence_across_the_32_bit_wrap() -> None:
    """Vol. 2, 3-2.1: newer is a step of 1 .. 2^31 - 1 modulo 2^32; 0 after 0xFFFFFFFF is newer."""
    table = make_table()
    connection = open_owner(table).connection
    output = table.assemblies["output"]
    for n, sequence in enumerate([0xFFFFFFFE, 0xFFFFFFFF, 0, 1, 2]):
        assert table.receive_datagram(o_t(connection.o_t_id, sequence, bytes([n, 0xA0])), HOST, T0 + n * MS)
        assert output.data == bytes([n, 0xA0]) and connection.last_received == T0 + n * MS
    for older in (2, 1, 0, 0xFFFFFFFF):
        assert not table.receive_datagram(o_t(connection.o_t_id, older, b"\xEE\xEE"), HOST, T0 + 9 * MS)
    assert table.counters["o_t_dropped_stale"] == 4 and output.data == bytes([4, 0xA0])
    assert connection.received == 5 and connection.last_received == T0 + 4 * MS


@pytest.mark.parametrize("last", [0, 1, HALF - 1, HALF, 0xFFFFFFFE, 0xFFFFFFFF])
@pytest.mark.parametrize(("step", "taken"), [(1, True), (HALF - 1, True), (0, False), (HALF, False),
                                             (HALF + 1, False), (WRAP - 1, False)])
def test_newer_is_a_step_of_1_to_half_minus_1_modulo_2_32(last: int, step: int, taken: bool) -> None:
    table = make_table()
    connection = open_owner(table).connection
    assert table.receive_datagram(o_t(connection.o_t_id, last), HOST, T0)
    assert table.receive_datagram(o_t(connection.o_t_id, (last + step) % WRAP, b"\x44\x00"), HOST, T0 + MS) is taken
    assert connection.last_sequence == ((last + step) % WRAP if taken else last)
    assert table.assemblies["output"].data == (b"\x44\x00" if taken else b"\x33\x00")


def test_o_t_16_bit_count_wraps_while_the_32_bit_sequence_goes_on() -> None:
    table = make_table()
    connection = open_owner(table).connection
    for n, (sequence, count) in enumerate([(0x1FFFE, 0xFFFE), (0x1FFFF, 0xFFFF), (0x20000, 0), (0x20001, 1)]):
        assert table.receive_datagram(o_t(connection.o_t_id, sequence, count=count), HOST, T0 + n * MS)
    assert connection.received == 4 and connection.last_sequence == 0x20001


def test_t_o_16_bit_count_wraps_to_0_and_the_32_bit_sequence_goes_on() -> None:
    """T->O packets 0xFFFF, 0x10000, 0x10001 of one stream, produced one RPI apart (no poke)."""
    table = make_table()
    connection = open_owner(table, t_o_rpi_us=1_000).connection
    seen = []
    for n in range(0x10001):
        for packet, _ in table.datagrams_to_send(T0 + n * MS):
            seen.append(decode_io_packet(packet))
    assert len(seen) == 0x10001 and all(p.connection_id == connection.t_o_id for p in seen)
    assert [(p.sequence, p.sequence_count) for p in seen[:2]] == [(1, 1), (2, 2)]
    assert [(p.sequence, p.sequence_count) for p in seen[-3:]] == [(0xFFFF, 0xFFFF), (0x10000, 0), (0x10001, 1)]


def test_t_o_32_bit_sequence_wraps_to_0() -> None:
    table = make_table()
    connection = open_owner(table).connection
    (production,) = table.productions.values()
    production.sequence = 0xFFFFFFFE  # four billion packets later
    sent = [decode_io_packet(p) for n in range(3) for p, _ in table.datagrams_to_send(T0 + n * 10 * MS)]
    assert [(p.connection_id, p.sequence, p.sequence_count) for p in sent] == [
        (connection.t_o_id, 0xFFFFFFFF, 0xFFFF), (connection.t_o_id, 0, 0), (connection.t_o_id, 1, 1)]


# -- the first watchdog -----------------------------------------------------------------------------

TIMEOUT = 40 * MS  # 10 ms x 2^2


@pytest.mark.parametrize("first_watchdog_ns", [0, 1, TIMEOUT // 4, TIMEOUT // 2, TIMEOUT - 1, TIMEOUT, TIMEOUT + 1,
                                               10_000 * MS])
def test_the_first_watchdog_never_undercuts_the_timeout(first_watchdog_ns: int) -> None:
    """Before the first packet the deadline is the open + the longer of the first watchdog and the timeout."""
    table = make_table(first_watchdog_ns)
    connection = open_owner(table, 10_000, 10_000, 0).connection
    deadline = T0 + max(TIMEOUT, first_watchdog_ns)
    assert connection.deadline == deadline
    table.handle_timer(deadline - 1)
    assert connection.o_t_id in table.connections
    table.handle_timer(deadline)
    assert connection.o_t_id not in table.connections


# -- faults: durations to the tick, re-set while running ---------------------------------------------


@pytest.mark.parametrize("duration_s", [0.004, 0.25, 1.0, 30.0, 7_200.5])  # the last: waits longer than MAX_WAIT_S
def test_a_fault_lasts_its_duration_not_a_tick_less_or_more(on_virtual_clock, duration_s: float) -> None:
    async def scenario(farm: Farm, loop: VirtualClockLoop) -> None:
        faults = farm.devices["io1"].faults
        start = loop.now
        await farm.inject_fault("io1", Fault("drop", duration_s=duration_s))
        await at(loop, start + duration_s / 4)
        await at(loop, start + duration_s - 1e-6)
        assert list(faults.active) == ["drop"]
        await at(loop, start + duration_s)
        assert faults.active == {}
        assert [e.kind for e in farm.devices["io1"].events if e.kind.startswith("fault")] == [
            "fault injected", "fault cleared"]

    on_virtual_clock(scenario)


@pytest.mark.parametrize(("first_s", "again_s"), [(1.0, 1.0), (1.0, 3.0), (10.0, 0.5), (1.0, None)])
def test_a_fault_set_again_while_it_runs_ends_on_the_new_duration(on_virtual_clock, first_s: float,
                                                                  again_s: float | None) -> None:
    async def scenario(farm: Farm, loop: VirtualClockLoop) -> None:
        faults = farm.devices["io1"].faults
        start = loop.now
        await farm.inject_fault("io1", Fault("delay", delay_ms=5, duration_s=first_s))
        await at(loop, start + 0.25)
        await farm.inject_fault("io1", Fault("delay", delay_ms=7, duration_s=again_s))
        end = start + 0.25 + again_s if again_s is not None else start + 1e6
        for when in sorted({start + first_s, start + first_s + 1e-3, end - 1e-6}):
            if when < end:
                await at(loop, when)
                assert faults.active["delay"].delay_ms == 7, when - start
        await at(loop, end)
        assert ("delay" in faults.active) is (again_s is None)

    on_virtual_clock(scenario)


def test_another_kind_keeps_its_own_end(on_virtual_clock) -> None:
    async def scenario(farm: Farm, loop: VirtualClockLoop) -> None:
        faults = farm.devices["io1"].faults
        start = loop.now
        await farm.inject_fault("io1", Fault("drop", duration_s=1.0))
        await farm.inject_fault("io1", Fault("identity", duration_s=2.0))
        await at(loop, start + 1.0 - 1e-6)
        assert sorted(faults.active) == ["drop", "identity"]
        await at(loop, start + 1.0)
        assert list(faults.active) == ["identity"]
        await at(loop, start + 2.0 - 1e-6)
        assert list(faults.active) == ["identity"]
        await at(loop, start + 2.0)
        assert faults.active == {}

    on_virtual_clock(scenario)


def test_a_fault_cleared_early_does_not_end_the_next_one(on_virtual_clock) -> None:
    async def scenario(farm: Farm, loop: VirtualClockLoop) -> None:
        faults = farm.devices["io1"].faults
        start = loop.now
        await farm.inject_fault("io1", Fault("drop", duration_s=1.0))
        await at(loop, start + 0.5)
        assert await farm.clear_faults("io1", "drop") == ["drop"]
        await farm.inject_fault("io1", Fault("drop"))  # until cleared
        await at(loop, start + 1.0)
        await at(loop, start + 5.0)
        assert list(faults.active) == ["drop"]

    on_virtual_clock(scenario)


# -- delays: within their bounds, spread over them ---------------------------------------------------


@pytest.fixture
def seeded() -> Iterator[None]:
    """The delay kind draws from `random`: seeded here, its state put back after."""
    state = random.getstate()
    random.seed(32)
    yield
    random.setstate(state)


def holds(fault_faults: DeviceFaults, n: int) -> list[int]:
    return [fault_faults.on_reply() for _ in range(n)]  # type: ignore[misc]


@pytest.mark.usefixtures("seeded")
@pytest.mark.parametrize(("delay_ms", "max_delay_ms"), [(40, 80), (0, 5), (100, 100.5), (800, 60_000)])
def test_random_delays_stay_within_their_bounds_and_spread_over_them(delay_ms: float, max_delay_ms: float) -> None:
    faults = DeviceFaults()
    faults.set(Fault("delay", delay_ms=delay_ms, max_delay_ms=max_delay_ms), T0)
    low, high, drawn = round(delay_ms * MS), round(max_delay_ms * MS), holds(faults, 2000)
    assert low <= min(drawn) and max(drawn) <= high
    span = high - low
    assert min(drawn) < low + span / 50 and max(drawn) > high - span / 50  # they reach both ends
    assert abs(sum(drawn) / len(drawn) - (low + high) / 2) < span / 20  # uniform: centred
    assert len(set(drawn)) > 1900  # they vary
    quarters = [sum(low + q * span / 4 <= d < low + (q + 1) * span / 4 for d in drawn) for q in range(4)]
    assert all(400 < q < 600 for q in quarters), quarters


@pytest.mark.parametrize(("delay_ms", "max_delay_ms"), [(40, None), (40, 40), (0.001, None), (60_000, None)])
def test_a_fixed_delay_is_exactly_delay_ms(delay_ms: float, max_delay_ms: float | None) -> None:
    faults = DeviceFaults()
    faults.set(Fault("delay", delay_ms=delay_ms, max_delay_ms=max_delay_ms), T0)
    assert set(holds(faults, 50)) == {round(delay_ms * MS)}


@pytest.mark.usefixtures("seeded")
def test_a_random_delay_beside_a_drop_the_drop_wins() -> None:
    faults = DeviceFaults()
    faults.set(Fault("delay", delay_ms=30, max_delay_ms=60), T0)
    assert all(30 * MS <= d <= 60 * MS for d in holds(faults, 200))
    faults.set(Fault("drop"), T0)
    assert set(holds(faults, 20)) == {DROP}
