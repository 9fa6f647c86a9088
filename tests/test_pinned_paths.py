"""Issue 32's last survivors of one device's class-1 path (device/cyclic.py): which ended
connection a device fault renames, the time a reaction probe hears; and of the I/O thread's heap
(server/implicit.py): the lateness an overload reports, how long it waits. Exact values on an
injected clock (`now`, ns; the thread's `time` and epoll replaced), no sockets."""

from __future__ import annotations

import os

import pytest

from enip_farm.device.faults import Fault
from enip_farm.protocol.cip import ClassCode, Service
from enip_farm.protocol.connection import encode_forward_open, encode_io_packet
from enip_farm.server import implicit
from enip_farm.server.implicit import CyclicIoThread
from tests.test_pinned_details import PEER, T0, _dsqc1030, _explicit, _forward_open

MS = 1_000_000
RUN = b"\x01\x00\x00\x00"  # the 32-bit run/idle header, run


def _open(device) -> object:
    assert _explicit(device, Service.FORWARD_OPEN, ClassCode.CONNECTION_MANAGER, 1,
                     data=encode_forward_open(_forward_open(device))).general_status == 0
    (connection,) = device.connections.values()
    return connection


def test_a_device_fault_renames_only_the_timeout_of_its_own_turn() -> None:
    """A connection that timed out earlier, with no fault, keeps "timeout"; the one that times out
    while the device's fault stops the I/O ends as "device fault" (mutants of `measure is not None
    and measure.ended_at == now and measure.ended == "timeout"` renamed the earlier one too)."""
    device = _dsqc1030()
    first = _open(device)
    first_end = first.deadline + 3 * MS
    device.service_io(first_end, lambda *a: None)
    assert device.connections == {}
    assert (first.measure.ended_at, first.measure.ended) == (first_end, "timeout")
    second = _open(device)
    device.faults.set(Fault("stop-io"), first_end)
    second_end = max(second.deadline, first_end) + 5 * MS
    device.service_io(second_end, lambda *a: None)
    assert device.connections == {}
    assert (second.measure.ended_at, second.measure.ended) == (second_end, "device fault")
    assert (first.measure.ended_at, first.measure.ended) == (first_end, "timeout")


class _Expectation:
    """A reaction probe's side that hears the outputs (device/reaction.py's `consumed`)."""

    def __init__(self) -> None:
        self.heard: list[tuple[bytes, int]] = []

    def consumed(self, outputs: bytes | bytearray, at: int, via: str = "o->t") -> None:
        self.heard.append((bytes(outputs), at))


def test_a_reaction_probe_hears_the_kernels_receive_time_else_the_turns() -> None:
    """`consumed` gets the O->T's kernel receive time where the socket gave one, else the turn's
    `now`, and only when the outputs changed (a mutant swapped the two times)."""
    device, probe = _dsqc1030(), _Expectation()
    connection = _open(device)
    device.cyclic.expectations = (probe,)
    size = len(device.outputs)
    one, two = b"\x01" + bytes(size - 1), b"\x02" + bytes(size - 1)
    now = T0 + 10 * MS
    assert device.receive_io(encode_io_packet(connection.o_t_id, 1, 1, RUN + one), (PEER, 2222), now,
                             lambda *a: None, now - 250_000) is True
    assert device.receive_io(encode_io_packet(connection.o_t_id, 2, 2, RUN + one), (PEER, 2222), now + MS,
                             lambda *a: None, now + 1) is True  # the same outputs: nothing to hear
    assert device.receive_io(encode_io_packet(connection.o_t_id, 3, 3, RUN + two), (PEER, 2222), now + 2 * MS,
                             lambda *a: None, None) is True
    assert probe.heard == [(one, now - 250_000), (two, now + 2 * MS)]


class _Clock:
    """The I/O thread's `time` (monotonic_ns, sleep), set by the test; sleeping moves it."""

    def __init__(self, now: int) -> None:
        self.now = now

    def monotonic_ns(self) -> int:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.now += round(seconds * 1e9)


class _Epoll:
    """The I/O thread's epoll: records each poll's timeout, waits it out on the clock, stops the
    thread after `turns`."""

    def __init__(self, thread: CyclicIoThread, turns: int, clock: _Clock) -> None:
        self.thread, self.turns, self.clock, self.timeouts = thread, turns, clock, []

    def poll(self, timeout: float, maxevents: int = -1) -> list:  # (select.epoll.poll's)
        self.timeouts.append(timeout)
        self.clock.sleep(timeout)  # nothing comes: it waits the whole timeout
        if len(self.timeouts) >= self.turns:
            self.thread._stopping = True
        return []


class _Endpoint:
    """A device's endpoint in the I/O thread's heap: records when it is served."""

    def __init__(self) -> None:
        self.scheduled: int | None = None
        self.served: list[int] = []

    def service(self, now: int, horizon: int) -> None:
        self.served.append(now)


def _turns(monkeypatch, clock: _Clock, dues: list[int], turns: int) -> tuple[CyclicIoThread, _Epoll, list]:
    thread = CyclicIoThread()
    real = thread._epoll
    try:
        monkeypatch.setattr(implicit, "time", clock)
        fake = thread._epoll = _Epoll(thread, turns, clock)
        overloads: list[tuple[int, int]] = []
        thread._overloaded = lambda lag_ns, now: overloads.append((lag_ns, now))
        turns: list[int] = []
        thread.running_budget.turn = turns.append  # each turn that had something due, with its lag
        endpoints = [_Endpoint() for _ in dues]
        for endpoint, due in zip(endpoints, dues, strict=True):
            thread._schedule(endpoint, due)
        thread._loop()
    finally:
        real.close()
        os.close(thread._wake_read)
        os.close(thread._wake_write)
    return thread, fake, [overloads, endpoints, turns]


def test_a_late_turn_reports_the_lateness_of_the_earliest_due(monkeypatch) -> None:
    """An overload is the lateness of the turn's earliest due wake-up (a mutant read `heap[1][0]`:
    another endpoint's time, or an IndexError with one endpoint)."""
    now = T0 + 7 * MS
    thread, _, (overloads, (endpoint,), turns) = _turns(monkeypatch, _Clock(now), [T0], 1)
    assert overloads == [(7 * MS, now)] and endpoint.served == [now] and turns == [7 * MS]
    now = T0 + 8 * MS
    thread, _, (overloads, endpoints, turns) = _turns(monkeypatch, _Clock(now), [T0, T0 + MS // 2, now + 2 * MS], 1)
    assert overloads == [(8 * MS, now)] and turns == [8 * MS]
    assert [e.served for e in endpoints] == [[now], [now], []]  # the third is due after this turn


def test_a_wake_up_100_ms_ahead_is_one_poll_of_99_ms_and_nothing_served(monkeypatch) -> None:
    """The thread waits in epoll until 1 ms (a turn) before the earliest due time, less epoll's
    1 ms margin, and serves nothing before (mutants read `heap[0][1]`, the heap's tie-break
    counter, as a due time: a poll of 0 and a turn counted every time round)."""
    clock = _Clock(T0)
    thread, epoll, (overloads, (endpoint,), turns) = _turns(monkeypatch, clock, [T0 + 100 * MS], 1)
    assert epoll.timeouts == [pytest.approx(0.098, abs=1e-9)]
    assert endpoint.served == [] and turns == [] and overloads == []


def test_an_o_t_reaches_a_device_without_an_output_image() -> None:
    """Where the guard holds no output image (a model without an output assembly: input-only
    connections, whose O->T are heartbeats), an O->T is taken and nothing reads the missing image
    (a mutant of `old is not None and output.data != old` read `None.data` and raised)."""
    device = _dsqc1030()
    connection = _open(device)
    device.guard.output = None  # as such a model builds it (device/guard.py: `assemblies.get("output")`)
    packet = encode_io_packet(connection.o_t_id, 1, 1, RUN + bytes(len(device.outputs)))
    assert device.receive_io(packet, (PEER, 2222), T0 + MS, lambda *a: None, T0 + MS) is True


def test_the_lag_of_the_last_whole_second_rolls_over_at_an_on_time_turn(monkeypatch) -> None:
    """A turn 3 ms late in one second, then one on time in the next: the worst of the last whole
    second is 3 ms (the lag was told only of late turns, and kept 0 until the next late one)."""
    due = T0 + 1_500 * MS
    thread, _, (overloads, (early, later), turns) = _turns(monkeypatch, _Clock(T0 + 3 * MS), [T0, due], 8)
    assert early.served == [T0 + 3 * MS] and len(later.served) == 1 and due - MS <= later.served[0] <= due
    assert turns == [3 * MS, later.served[0] - due] and overloads == []
    assert (thread.lag.worst_ns, thread.lag.overloads) == (3 * MS, 0)
