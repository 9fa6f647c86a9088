"""Issue 29: the native class-1 path (server/native.py, enip_farm/server/_class1.c) against the
Python one, sans-IO. The same datagram sequences with the same injected times go through two
devices of the same configuration, one on each path, as the cyclic I/O thread hands them over
(server/implicit.py: the engine's `consume` first, what it refuses to the device's Python path;
its `produce` for the devices it runs, the Python `service_io` for the rest and for those it hands
back); after every step every T->O byte, both images, the counters, the interface counters, the
events and the report's figures must be the same."""

from __future__ import annotations

import random
import socket
from dataclasses import asdict

import pytest

from enip_farm.device.device import Device
from enip_farm.device.events import Event, ImageChanged
from enip_farm.device.faults import Fault
from enip_farm.device.report import connection_figures
from enip_farm.protocol.connection import ConnectionTriad, decode_forward_open_reply, encode_io_packet
from enip_farm.protocol.session import MessageContext
from enip_farm.server.native import BUILT, MAX_T_O_PAYLOAD, NativeDevice, new_engine, plan, publish_changes
from tests.test_cip_services_unit import MS, SCANNER, forward_open, get_list, make_device
from tests.test_implicit import forward_close

pytestmark = pytest.mark.skipif(not BUILT, reason="the native class-1 extension is not built")
T0 = 1_000 * MS
PORT = 50_000
CLASS1_10MS = forward_open(1, bytes.fromhex("20 04 24 01 2C 64 2C 65"), 0x01, 8, 4)
INPUT_ONLY = forward_open(7, bytes.fromhex("20 04 24 01 2C C6 2C 65"), 0x01, 2, 4)  # O->T point 198: a heartbeat
RUN, IDLE = b"\x01\x00\x00\x00", b"\x00\x00\x00\x00"


class Path:
    """One device and how the I/O thread drives it: natively (`engine` set) or in Python."""

    def __init__(self, native: bool) -> None:
        self.device: Device = make_device(implicit={"first_watchdog_s": 1})
        self.device.table.admission._rng = random.Random(29)  # noqa: SLF001 - the same connection ids on both
        self.sent: list[tuple[bytes, tuple[str, int]]] = []
        self.seen: list[tuple] = []  # what its observers (`observe`) were told, in order
        self.engine = new_engine() if native else None
        self.handle: NativeDevice | None = None
        if self.engine is not None:
            self.handle = NativeDevice(self.engine, 3, self.device, lambda: None)
            self.handle.attach()

    def observe(self) -> object:
        """An observer of every event (the dashboard's hub's kind: image changes too); the unsubscribe."""
        return self.device.observe(self._saw)

    def _saw(self, event: Event) -> None:
        detail = event.detail
        self.seen.append((event.monotonic_ns, _text(detail), tuple(detail) if isinstance(detail, ImageChanged) else ()))

    def _send(self, packet: bytes, address: tuple[str, int]) -> None:  # DeviceIo.send's counting
        self.device.io_traffic.sent(len(packet), True)
        self.sent.append((packet, address))

    def open(self, now: int) -> int:
        reply, _ = self.device.handle_unconnected(CLASS1_10MS, MessageContext(SCANNER, None, (), now))
        return decode_forward_open_reply(reply[4:]).o_t_connection_id

    def close(self, now: int) -> None:
        self.device.handle_unconnected(forward_close(ConnectionTriad(1, 0x1234, 0xABCD)),
                                       MessageContext(SCANNER, None, (), now))

    def o_t(self, data: bytes, host: str, port: int, now: int, received_at: int) -> None:
        """DeviceIo.take, behind the engine where there is one."""
        if self.engine is not None:  # the image changes it made told before what it leaves to Python
            taken = self.engine.consume(self.handle.slot, data, socket.inet_aton(host), port, now, received_at)
            publish_changes(self.engine.changes, lambda slot: self.device)
            if taken:
                return
        traffic = self.device.io_traffic
        traffic.received(len(data))
        if not self.device.receive_io(data, (host, port), now, self._send, received_at):
            traffic.discarded()

    def turn(self, now: int, horizon: int) -> None:
        """The thread's turn: the engine's devices, then Python's (the heap's, here: every turn)."""
        if self.engine is not None:
            python, _, _, _, packets = self.engine.produce(now, horizon, True)
            for _, packet, address in packets:
                self.sent.append((packet, address))
            if python or not self.engine.native(self.handle.slot):
                self.device.service_io(now, self._send, horizon)
        else:
            self.device.service_io(now, self._send, horizon)

    def state(self, now: int) -> dict:
        device = self.device
        counters = {k: v for k, v in device.counters.items() if v}
        connections = device.guard.read(lambda: list(device.table.connections.values()) + list(device.table.ended))
        figures = [asdict(connection_figures(device, c, now)) for c in connections if c.measure is not None]
        return {"sent": list(self.sent), "outputs": device.outputs, "inputs": device.inputs, "counters": counters,
                "traffic": device.io_traffic.values(), "figures": figures, "seen": list(self.seen),
                "events": [(e.monotonic_ns, _text(e.detail)) for e in device.events]}


def _text(detail: object) -> str:
    text = detail.text  # a method of most events, a field of some
    return text if isinstance(text, str) else text()


def _packet(oid: int, sequence: int, data: bytes, count: int | None = None) -> bytes:
    return encode_io_packet(oid, sequence, sequence if count is None else count, data)


def _run(steps: list[tuple], native_expected: bool = True, observed: bool = False) -> tuple[Path, Path]:
    """Each step through both paths; the states compared after each (with `observed`, what an
    observer of every event of each device was told too)."""
    python, native = Path(False), Path(True)
    if observed:
        python.observe(), native.observe()
    ran_native = False
    for step in steps:
        for path in (python, native):
            kind, now, *args = step
            if kind == "open":
                path.oid = path.open(now)
            elif kind == "open2":  # an input-only connection beside the exclusive owner (its own T->O)
                reply, _ = path.device.handle_unconnected(INPUT_ONLY, MessageContext(SCANNER, None, (), now))
                path.oid2 = decode_forward_open_reply(reply[4:]).o_t_connection_id
            elif kind == "o_t2":
                path.o_t(_packet(path.oid2, args[0], args[1]), SCANNER, PORT, now, now)
            elif kind == "close2":
                path.device.handle_unconnected(forward_close(ConnectionTriad(7, 0x1234, 0xABCD)),
                                               MessageContext(SCANNER, None, (), now))
            elif kind == "o_t":
                sequence, data, *rest = args
                host, port, at, count = (rest + [SCANNER, PORT, now, None][len(rest):])[:4]
                path.o_t(_packet(path.oid, sequence, data, count), host, port, now, at)
            elif kind == "raw":
                path.o_t(args[0], SCANNER, PORT, now, now)
            elif kind == "turn":
                path.turn(now, now + MS)
            elif kind == "close":
                path.close(now)
            elif kind == "explicit":  # a Get_Attribute_List of the identity: the engine keeps the device
                path.device.handle_unconnected(get_list(1, 1, 1, 2, 3), MessageContext(SCANNER, None, (), now))
            elif kind == "inputs":
                path.device.set_inputs(args[0], now)
            elif kind == "fault":
                if args[0]:
                    path.device.faults.set(Fault(args[0]), now)
                else:
                    path.device.faults.clear()
        ran_native = ran_native or native.engine.native(native.handle.slot)
        assert native.state(step[1]) == python.state(step[1]), step
    assert ran_native == native_expected
    return python, native


def _cyclic(start: int, first: int, count: int, data: bytes = RUN + b"\x01\x00", every: int = 10) -> list[tuple]:
    steps = []
    for n in range(count):
        now = start + n * every * MS
        steps += [("o_t", now + 300_000, first + n, data, SCANNER, PORT, now + 200_000), ("turn", now + MS)]
    return steps


def test_normal_exchange_with_inputs_written_between_turns() -> None:
    steps = [("open", T0), ("turn", T0)]
    steps += _cyclic(T0 + 5 * MS, 1, 20)
    steps += [("inputs", T0 + 120 * MS, b"\x5a\xa5"), ("turn", T0 + 125 * MS), ("explicit", T0 + 126 * MS)]
    steps += _cyclic(T0 + 215 * MS, 21, 5, RUN + b"\xff\x00")
    _run(steps)


def test_stale_duplicate_lost_and_wrapped_sequences() -> None:
    steps = [("open", T0)]
    t = T0 + MS
    for n, sequence in enumerate([0xFFFFFFFD, 0xFFFFFFFE, 0xFFFFFFFE, 0xFFFFFFFC, 0xFFFFFFFF, 2, 7, 7, 3, 8]):
        steps += [("o_t", t + n * 10 * MS, sequence, RUN + bytes([n, 0]), SCANNER, PORT, t + n * 10 * MS - 50_000,
                   (sequence * 3) & 0xFFFF), ("turn", t + n * 10 * MS + 2 * MS)]
    _run(steps)


def test_wrong_size_originator_port_and_malformed() -> None:
    steps = [("open", T0), ("o_t", T0 + MS, 1, RUN + b"\x01\x00")]
    steps += [("o_t", T0 + 2 * MS, 2, RUN + b"\x01\x00\x00"), ("o_t", T0 + 3 * MS, 3, RUN),
              ("o_t", T0 + 4 * MS, 4, b"\x01"), ("o_t", T0 + 5 * MS, 5, RUN + b"\x02\x00", "127.0.0.77"),
              ("o_t", T0 + 6 * MS, 6, RUN + b"\x03\x00", SCANNER, PORT + 1),
              ("raw", T0 + 7 * MS, b"\x02\x00\x02\x80\x08\x00"), ("raw", T0 + 8 * MS, bytes(20)),
              ("o_t", T0 + 9 * MS, 7, RUN + b"\x04\x00"), ("turn", T0 + 10 * MS)]
    _run(steps)


def test_run_idle_run_and_a_timeout_into_the_fault_state() -> None:
    steps = [("open", T0)] + _cyclic(T0 + MS, 1, 3)
    steps += _cyclic(T0 + 31 * MS, 4, 3, IDLE + b"\x07\x00") + _cyclic(T0 + 61 * MS, 7, 3, RUN + b"\x08\x00")
    last = T0 + 81 * MS
    steps += [("turn", last + n * 5 * MS) for n in range(1, 20)]  # the timeout: 100 ms x 4 after the last packet
    steps += [("turn", last + 400 * MS - 1), ("turn", last + 400 * MS), ("turn", last + 401 * MS)]
    _run(steps)


def test_a_forward_close_in_the_middle_and_a_new_connection() -> None:
    steps = [("open", T0)] + _cyclic(T0 + MS, 1, 5)
    steps += [("close", T0 + 52 * MS), ("turn", T0 + 53 * MS), ("o_t", T0 + 54 * MS, 6, RUN + b"\x01\x00"),
              ("open", T0 + 60 * MS)] + _cyclic(T0 + 61 * MS, 1, 5)
    _run(steps)


def test_several_connections_on_one_device_an_exclusive_owner_and_an_input_only() -> None:
    """The input-only connection's O->T is a heartbeat (nothing, or the run/idle header alone): the
    engine runs both, each with its own T->O stream; one of them closed, the other goes on."""
    steps = [("open", T0), ("open2", T0 + MS)]
    for n in range(1, 8):
        now = T0 + n * 10 * MS
        steps += [("o_t", now, n, RUN + bytes([n, 0])), ("o_t2", now + 200_000, n, RUN if n % 3 else b""),
                  ("o_t2", now + 300_000, n, b"\x01\x00"), ("turn", now + MS)]
    steps += [("o_t2", T0 + 80 * MS, 8, IDLE), ("close2", T0 + 81 * MS), ("turn", T0 + 82 * MS)]
    steps += _cyclic(T0 + 85 * MS, 8, 4)
    _run(steps)


def test_a_fault_takes_the_device_back_to_python_and_clearing_it_returns() -> None:
    steps = [("open", T0)] + _cyclic(T0 + MS, 1, 3)
    steps += [("fault", T0 + 30 * MS, "stop-io")] + _cyclic(T0 + 31 * MS, 4, 3)
    steps += [("fault", T0 + 61 * MS, None)] + _cyclic(T0 + 62 * MS, 7, 3)
    _run(steps)


def test_the_engine_runs_a_plain_connection_and_leaves_what_it_does_not_serve() -> None:
    path = Path(True)
    path.oid = path.open(T0)
    assert plan(path.device) is not None and path.engine.native(path.handle.slot)
    path.device.faults.set(Fault("stop-io"), T0)  # a fault: Python's
    assert not path.engine.native(path.handle.slot)
    assert plan(path.device) is None


def test_an_observed_device_stays_native_and_its_observer_hears_every_output_change() -> None:
    """An observer of every event (the dashboard's hub, an io-change watcher): the device stays in
    the engine, which reports each O->T that changes the output image (run data, and the zeros of
    an idle one where the outputs go off on idle); the observer hears the same events, with the same
    bytes before and after and the same times, in the same order as on the Python path."""
    steps = [("open", T0), ("turn", T0)] + _cyclic(T0 + 5 * MS, 1, 3)
    steps += _cyclic(T0 + 35 * MS, 4, 3, RUN + b"\x02\x00") + _cyclic(T0 + 65 * MS, 7, 2, RUN + b"\x03\x80")
    steps += [("inputs", T0 + 86 * MS, b"\x5a\xa5"), ("explicit", T0 + 87 * MS)]
    steps += _cyclic(T0 + 95 * MS, 9, 2, IDLE + b"\x07\x00") + _cyclic(T0 + 115 * MS, 11, 2, RUN + b"\x04\x00")
    python, native = _run(steps, observed=True)
    changes = [seen[2] for seen in native.seen if seen[2]]
    assert changes == [("output", b"\0\0", b"\x01\0"), ("output", b"\x01\0", b"\x02\0"),
                       ("output", b"\x02\0", b"\x03\x80"), ("input", b"\0\0", b"\x5a\xa5"),
                       ("output", b"\x03\x80", b"\0\0"), ("output", b"\0\0", b"\x04\0")]
    connection = native.device.table.connections[native.oid]
    assert plan(native.device)[0][0][5] is True and native.engine.native(native.handle.slot)
    assert connection.received == python.device.table.connections[python.oid].received


def test_a_turn_that_left_sockets_unread_times_nothing_out() -> None:
    """produce(..., supervise=False), the I/O thread's turn that read at most NATIVE_TURN_SOCKETS of
    the ready sockets: a device whose deadline has come is neither produced nor handed to Python (a
    datagram still unread may feed it); the next full turn hands it over."""
    path = Path(True)
    path.oid = path.open(T0)
    path.o_t(_packet(path.oid, 1, RUN + b"\x01\x00"), SCANNER, PORT, T0 + MS, T0 + MS)
    path.o_t(_packet(path.oid, 2, RUN + b"\x01\x00"), SCANNER, PORT, T0 + 2 * MS, T0 + 2 * MS)
    timeout = path.device.table.connections[path.oid].timeout_ns
    late = T0 + 2 * MS + timeout
    python, _, _, sent, packets = path.engine.produce(late, late + MS, True, False)
    assert (python, sent, packets) == ([], 0, [])
    assert path.engine.native(path.handle.slot)
    python, _, _, _, _ = path.engine.produce(late, late + MS, True)
    assert python == [path.handle.slot]


def test_a_t_o_longer_than_the_engines_packet_stays_on_the_python_path() -> None:
    """The engine's packets hold MAX_T_O_PAYLOAD bytes of header and data (it cut a longer T->O
    short before): a produced image that fits is loaded; one byte more is refused by `plan` (the
    Python path keeps the device) and by `load` (ValueError); and an image grown past it under the
    engine (never exported: Python may resize it) hands the device to Python, which sends it whole."""
    path = Path(True)
    path.oid = path.open(T0)
    slot = path.handle.slot
    planned = plan(path.device)
    (_, _, data, header, _), = planned[1]
    data[:] = bytes(range(256)) * 2 + bytes(MAX_T_O_PAYLOAD - len(header) - 512)
    assert plan(path.device) is not None
    path.engine.load(slot, *plan(path.device))
    _, _, _, sent, packets = path.engine.produce(T0 + MS, T0 + 2 * MS, True)
    assert sent == 1 and len(packets[0][1]) == 20 + MAX_T_O_PAYLOAD and packets[0][1].endswith(bytes(data))
    data.append(0x5A)
    assert plan(path.device) is None
    with pytest.raises(ValueError, match="MAX_PACKET"):
        path.engine.load(slot, *planned)
    assert not path.engine.native(slot)
    del data[-1]
    path.engine.load(slot, *planned)
    data.append(0x5A)  # grown under the engine
    python, _, _, sent, packets = path.engine.produce(T0 + 25 * MS, T0 + 26 * MS, True)
    assert (python, sent, packets) == ([slot], 0, [])
    path.device.service_io(T0 + 25 * MS, path._send, T0 + 26 * MS)  # noqa: SLF001 - the I/O thread's hand-over
    assert not path.engine.native(slot) and plan(path.device) is None
    (due,) = [production.due for production in path.device.table.productions.values()]
    path.device.service_io(due, path._send, due + MS)  # noqa: SLF001 - Python's from now on
    assert not path.engine.native(slot)
    packet, _ = path.sent[-1]
    assert len(packet) == 20 + len(header) + len(data) == 20 + MAX_T_O_PAYLOAD + 1 and packet.endswith(bytes(data))
