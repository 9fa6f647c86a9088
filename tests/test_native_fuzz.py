"""Issue 29: a property-based differential fuzz of the native class-1 path (enip_farm/server/_class1.c,
server/native.py) against the Python one, sans-IO, as tests/test_native_differential.py drives them
(its `Path`): random sequences of O->T datagrams (valid, truncated, other ids, another originator or
port, stale, duplicate and wrapped sequences, run/idle flips, other sizes, random bytes) at random
injected times, with turns, Forward Opens and Closes (class 1 and class 3), explicit requests
(unconnected and on the class-3 connection), an input-only connection and its heartbeats, input
image writes, faults, image observers, the T->O sequence near its wrap and images resized under
the engine in between, through both paths with the same times. After every step every T->O byte,
both images, the counters, the interface counters, the events, what the observers were told and
the report's figures are the same; and two devices sharing one engine, each against its twin. The budget is fixed and
reproducible (`derandomize`, no example database): a few seconds on two busy cores;
ENIP_FARM_FUZZ_SCALE multiplies it, as in tests/test_fuzz.py.
"""

from __future__ import annotations

import os

import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from enip_farm.device.faults import Fault
from enip_farm.protocol.connection import ConnectionTriad, decode_forward_open_reply, encode_io_packet
from enip_farm.protocol.session import MessageContext
from enip_farm.server.native import BUILT, NativeDevice, new_engine
from tests.test_cip_services_unit import CLASS3, MS, SCANNER, get_list
from tests.test_implicit import forward_close
from tests.test_native_differential import CLASS1_10MS, INPUT_ONLY, PORT, T0, Path

pytestmark = pytest.mark.skipif(not BUILT, reason="the native class-1 extension is not built")
SCALE = float(os.environ.get("ENIP_FARM_FUZZ_SCALE", "1"))
OUTPUT_SIZE = 2  # the DSQC1030's output image (the O->T data after the run/idle header)
FAULTS = ("stop-io", "drop", "wrong-module", None)

# mostly what a controller sends (the next sequence, run, from its port), so that the engine takes most
_sequences = st.sampled_from(["next"] * 8 + ["same", "back", "jump", "half", "wrap", "any"]).flatmap(
    lambda chosen: st.integers(0, 0xFFFFFFFF) if chosen == "any" else st.just(chosen))
_o_t = st.tuples(st.just("o_t"), _sequences,
                 st.sampled_from(["run"] * 8 + ["idle", "idle", "short", "long", "empty", "header only"]),
                 st.sampled_from(["scanner"] * 12 + ["other host", "other port", "other id"]),
                 st.none() | st.integers(0, 0xFFFF), st.integers(0, 3 * MS), st.binary(min_size=2, max_size=2))
_heartbeat = st.tuples(st.just("heartbeat"), _sequences,  # nothing, the run/idle header alone, or another size
                       st.sampled_from([b"", b"", b"\x01\0\0\0", b"\0\0\0\0", b"\x01", b"\x01\0\0\0\0"]),
                       st.sampled_from(["scanner"] * 4 + ["other port"]))
_rare = st.one_of(
    st.tuples(st.just("truncated"), st.integers(0, 25)),
    st.tuples(st.just("raw"), st.binary(max_size=40)),
    st.tuples(st.just("open")), st.tuples(st.just("close")),
    st.tuples(st.just("class3")), st.tuples(st.just("class3 close")),
    st.tuples(st.just("input only")), st.tuples(st.just("input only close")),
    st.tuples(st.just("explicit")), st.tuples(st.just("class3 message")), st.tuples(st.just("class3 message")),
    st.tuples(st.just("inputs"), st.binary(min_size=2, max_size=2)),
    st.tuples(st.just("resize"), st.sampled_from(["output", "input"]), st.integers(0, 6)),
    st.tuples(st.just("t_o wrap"), st.integers(0xFFFFFFF0, 0x1_0000_FFF0)),
    st.tuples(st.just("fault"), st.sampled_from(FAULTS)),
    st.tuples(st.just("observe")), st.tuples(st.just("unobserve")))
# the O->T and the turns weigh most (one_of picks a branch uniformly and takes a strategy once)
_step = st.sampled_from([_o_t] * 12 + [_heartbeat] * 3 + [st.tuples(st.just("turn"))] * 5 + [_rare] * 6).flatmap(
    lambda strategy: strategy)
# how far each step is after the previous one: mostly within an RPI, sometimes past a timeout (400 ms)
_gaps = st.sampled_from([12 * MS] * 12 + [700 * MS]).flatmap(lambda most: st.integers(0, most))


class Driver:
    """One path and the originator's view of it (the O->T sequence it sends next)."""

    def __init__(self, native: bool) -> None:
        self.path = Path(native)
        self.oid = 0
        self.class3 = 0  # the class-3 connection's O->T id
        self.count = 0  # its sequence count
        self.input_only = 0  # the input-only connection's O->T id (its O->T: a heartbeat)
        self.heartbeats = 0  # the sequence of its heartbeats
        self.sequence = 0
        self.unobserve: list = []

    def ask(self, message: bytes, now: int) -> bytes:
        reply, _ = self.path.device.handle_unconnected(message, MessageContext(SCANNER, None, (), now))
        return reply

    def step(self, step: tuple, now: int) -> None:
        kind, *args = step
        device = self.path.device
        if kind == "o_t":
            self.o_t(now, *args)
        elif kind == "turn":
            self.path.turn(now, now + MS)
        elif kind == "truncated":
            self.path.o_t(encode_io_packet(self.oid, self.sequence + 1, 1, b"\x01\0\0\0\0\0")[: args[0]], SCANNER,
                          PORT, now, now)
        elif kind == "raw":
            self.path.o_t(args[0], SCANNER, PORT, now, now)
        elif kind == "open":
            reply = self.ask(CLASS1_10MS, now)
            if reply[2] == 0:
                self.oid = decode_forward_open_reply(reply[4:]).o_t_connection_id
        elif kind == "close":
            self.ask(forward_close(ConnectionTriad(1, 0x1234, 0xABCD)), now)
        elif kind == "class3":
            reply = self.ask(CLASS3, now)
            if reply[2] == 0:
                self.class3 = decode_forward_open_reply(reply[4:]).o_t_connection_id
        elif kind == "input only":
            reply = self.ask(INPUT_ONLY, now)
            if reply[2] == 0:
                self.input_only = decode_forward_open_reply(reply[4:]).o_t_connection_id
        elif kind == "input only close":
            self.ask(forward_close(ConnectionTriad(7, 0x1234, 0xABCD), bytes.fromhex("20 04 24 01 2C C6 2C 65")), now)
        elif kind == "heartbeat":
            sequence, data, source = args
            last = self.heartbeats
            self.heartbeats = (sequence if isinstance(sequence, int) else {
                "next": last + 1, "same": last, "back": last - 3, "jump": last + 1000, "half": last + 0x80000000,
                "wrap": 0xFFFFFFFE}[sequence]) & 0xFFFFFFFF
            self.path.o_t(encode_io_packet(self.input_only, self.heartbeats, self.heartbeats, data), SCANNER,
                          PORT + 1 if source == "other port" else PORT, now, now)
        elif kind == "explicit":  # an unconnected Get_Attribute_List of the identity
            self.ask(get_list(1, 1, 1, 2, 3), now)
        elif kind == "class3 message":  # the same on the class-3 connection: its watchdog fed
            self.count += 1
            device.handle_connected(self.class3, self.count, get_list(1, 1, 1, 2, 3),
                                    MessageContext(SCANNER, None, (), now))
        elif kind == "class3 close":
            self.ask(forward_close(ConnectionTriad(2, 0x1234, 0xABCD), bytes.fromhex("20 02 24 01")), now)
        elif kind == "inputs":
            device.set_inputs((args[0] * 4)[: len(device.guard.input.data)], now)  # whatever its size now
        elif kind == "t_o wrap":  # the T->O sequence near its 32-bit (and the count near its 16-bit) wrap
            with device.guard.transaction(now):
                for production in device.table.productions.values():
                    production.sequence = args[0]
        elif kind == "resize":  # an image of another size while the engine may hold it (never exported)
            image = device.guard.assemblies[args[0]].data
            image[:] = bytes(range(1, args[1] + 1))
        elif kind == "fault":
            if args[0] is None:
                device.faults.clear()
            else:
                device.faults.set(Fault(args[0]), now)
        elif kind == "observe":
            self.unobserve.append(self.path.observe())  # what it is told compared (`Path.state`)
        elif kind == "unobserve" and self.unobserve:
            self.unobserve.pop()()

    def o_t(self, now: int, sequence: object, form: str, source: str, count: int | None, early: int,
            data: bytes) -> None:
        last = self.sequence
        if isinstance(sequence, int):
            chosen = sequence
        else:
            chosen = {"next": last + 1, "same": last, "back": last - 3, "jump": last + 1000, "half": last + 0x80000000,
                      "wrap": 0xFFFFFFFE}[sequence]
        chosen &= 0xFFFFFFFF
        self.sequence = chosen
        payload = {"run": b"\x01\0\0\0" + data, "idle": b"\0\0\0\0" + data, "short": b"\x01\0\0\0" + data[:1],
                   "long": b"\x01\0\0\0" + data + b"\0", "empty": b"", "header only": b"\x01\0\0\0"}[form]
        oid = self.oid + 1 if source == "other id" else self.oid
        packet = encode_io_packet(oid, chosen, chosen if count is None else count, payload)
        host = "127.0.0.77" if source == "other host" else SCANNER
        port = PORT + 1 if source == "other port" else PORT
        self.path.o_t(packet, host, port, now, max(T0, now - early))


@settings(max_examples=max(1, round(300 * SCALE)), deadline=None, derandomize=True, database=None,
          print_blob=False, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(st.lists(st.tuples(_gaps, _step), min_size=1, max_size=40))
def test_random_sequences_through_both_paths(steps: list[tuple[int, tuple]]) -> None:
    python, native = Driver(False), Driver(True)
    now = T0
    for path in (python, native):  # every sequence starts with a connection (a Forward Open may come again)
        path.step(("open",), now)
    assert native.path.state(now) == python.path.state(now)
    held = 0
    for gap, step in steps:
        now += gap
        for path in (python, native):
            path.step(step, now)
        assert native.path.state(now) == python.path.state(now), step
        held += native.path.engine.native(native.path.handle.slot)
    event(f"steps with the device in the engine: {'none' if not held else 'some' if held < len(steps) else 'all'}")


def _turn(drivers: list[Driver], now: int) -> None:
    """The I/O thread's turn over devices that share one engine (server/implicit.py): its T->O to
    their own lists, the devices it hands over or does not run on the Python path."""
    engine = drivers[0].path.engine
    if engine is None:
        for driver in drivers:
            driver.path.turn(now, now + MS)
        return
    python, _, _, _, packets = engine.produce(now, now + MS, True)
    paths = {driver.path.handle.slot: driver.path for driver in drivers}
    for slot, packet, address in packets:
        paths[slot].sent.append((packet, address))
    for slot, path in paths.items():
        if slot in python or not engine.native(slot):
            path.device.service_io(now, path._send, now + MS)  # noqa: SLF001 - DeviceIo.send's counting


@settings(max_examples=max(1, round(100 * SCALE)), deadline=None, derandomize=True, database=None,
          print_blob=False, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(st.lists(st.tuples(_gaps, st.sampled_from([0, 1]), _step), min_size=1, max_size=40))
def test_two_devices_in_one_engine(steps: list[tuple[int, int, tuple]]) -> None:
    """Two devices of one engine (as one I/O thread's), each beside a twin on the Python path:
    what happens to one never shows in the other, and the turns serve both."""
    python, native = [Driver(False), Driver(False)], [Driver(False), Driver(False)]
    engine = new_engine()
    for fd, driver in enumerate(native, 3):
        driver.path.engine = engine
        driver.path.handle = NativeDevice(engine, fd, driver.path.device, lambda: None)
        driver.path.handle.attach()
    now = T0
    for driver in python + native:
        driver.step(("open",), now)
    for gap, which, step in steps:
        now += gap
        for drivers in (python, native):
            if step == ("turn",):
                _turn(drivers, now)
            else:
                drivers[which].step(step, now)
        for twin, driver in zip(python, native, strict=True):
            assert driver.path.state(now) == twin.path.state(now), (which, step)
