"""Issue 29: defects found in the native class-1 path (enip_farm/server/_class1.c, server/native.py)
where it meets the cyclic I/O thread, the device lock and the sockets: a reader under the lock,
farms started and stopped, the engine's receive on real sockets, a turn that leaves sockets unread."""

from __future__ import annotations

import gc
import os
import select
import socket
import threading
import time
import weakref
from contextlib import ExitStack

import pytest

from enip_farm.device.device import Device
from enip_farm.protocol.connection import decode_forward_open_reply, encode_io_packet
from enip_farm.pytest_plugin import start_farm
from enip_farm.server import implicit
from enip_farm.server.implicit import CyclicIoThread
from enip_farm.server.native import BUILT, NativeDevice, new_engine
from tests.helpers import RawClient, wait_for
from tests.test_cip_services_unit import MS, SCANNER
from tests.test_implicit import forward_close, forward_open
from tests.test_native_differential import T0, Path
from tests.test_pinned_paths import _Clock, _Endpoint

pytestmark = pytest.mark.skipif(not BUILT, reason="the native class-1 extension is not built")


def test_a_reader_under_the_device_lock_sees_one_image(class1_path: str, make_farm) -> None:
    """`read` promises a whole view of the images and the table: on the native path the engine went
    on consuming O->T into the output image (and writing its counters back) while a reader held the
    device lock. A datagram that comes meanwhile is taken after the lock, on both paths."""
    farm = make_farm({"name": "io1", "model": "DSQC1030", "implicit": {"first_watchdog_s": 30}})
    device = farm.device("io1")
    target = (device.profile.address, 2222)
    with RawClient(device.profile.address) as client, socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as udp:
        client.register()
        udp.bind(("127.0.0.1", 0))
        message, triad = forward_open(rpi=20_000, multiplier=4)  # a 1.28 s timeout: longer than the read
        oid = decode_forward_open_reply(client.request(message).data).o_t_connection_id
        udp.sendto(encode_io_packet(oid, 1, 1, b"\x01\0\0\0\x11\0"), target)
        assert wait_for(lambda: device.outputs == b"\x11\0")
        native = device.guard.native
        assert (native is not None and native.active) == (class1_path == "native")

        def reading() -> tuple[bytes, bytes, int]:
            before = bytes(device.guard.output.data)
            udp.sendto(encode_io_packet(oid, 2, 2, b"\x01\0\0\0\x22\0"), target)
            deadline = time.monotonic() + 0.3  # the engine took it within a turn (1 ms) before the fix
            while time.monotonic() < deadline and bytes(device.guard.output.data) == before:
                time.sleep(0.002)
            return before, bytes(device.guard.output.data), device.table.connections[oid].received

        before, during, received = device.guard.read(reading)
        assert (before, during, received) == (b"\x11\0", b"\x11\0", 1)
        assert wait_for(lambda: device.outputs == b"\x22\0")  # taken once the lock went
        assert device.guard.read(lambda: device.table.connections[oid].received) == 2
        assert client.request(forward_close(triad)).general_status == 0


def _one_farm(addresses, round_: int, class1_path: str) -> list[weakref.ref]:
    """A farm with a connection the engine runs (on the native path), stopped as it runs."""
    with ExitStack() as stack:
        farm = start_farm(stack, addresses, name="io1", model="DSQC1030", implicit={"first_watchdog_s": 30})
        device = farm.device("io1")
        target = (device.profile.address, 2222)
        with RawClient(device.profile.address) as client, socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as udp:
            client.register()
            udp.bind(("127.0.0.1", 0))
            oid = decode_forward_open_reply(client.request(forward_open()[0]).data).o_t_connection_id
            udp.sendto(encode_io_packet(oid, 1, 1, b"\x01\0\0\0" + bytes([round_ + 1, 0])), target)
            assert wait_for(lambda: device.outputs == bytes([round_ + 1, 0]))
            native = device.guard.native
            assert (native is not None and native.active) == (class1_path == "native")
            return [weakref.ref(device), weakref.ref(device.table.connections[oid]),
                    weakref.ref(device._counters), weakref.ref(farm)]  # noqa: SLF001


@pytest.mark.integration
def test_farms_started_and_stopped_in_one_process_let_everything_go(class1_path: str, free_address) -> None:
    """Three farms one after the other, each stopped while the engine runs a connection: every
    farm, device, connection and counter is freed with its farm (the engine that held them too),
    and no thread stays."""
    threads = threading.active_count()
    for round_ in range(3):
        gone = _one_farm(free_address, round_, class1_path)
        gc.collect()
        assert [ref() for ref in gone] == [None] * len(gone), round_
    assert wait_for(lambda: threading.active_count() <= threads)


class _Reader:
    """Cyclic garbage whose finalizer reads another engine's socket (as another cyclic I/O thread
    would, while a collection inside the first engine's `receive` lets it run), and leaves the
    same garbage behind for the next collection."""

    def __init__(self, engine: object, fd: int, read: list) -> None:
        self.engine, self.fd, self.read, self.cycle = engine, fd, read, self

    def __del__(self) -> None:
        self.read += self.engine.receive([self.fd], 32, 1)[0]
        _Reader(self.engine, self.fd, self.read)


@pytest.mark.integration
def test_two_engines_never_share_their_receive_buffers() -> None:
    """`receive` read into one static buffer of the module: a collection while it built its
    results ran another engine's `receive` (a second farm's I/O thread, or a finalizer), which
    overwrote the datagrams the first had not copied yet."""
    first, second = new_engine(), new_engine()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as a, socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as b, \
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sender:
        for sock in (a, b):
            sock.bind(("127.0.0.1", 0))
        sent = [bytes([n]) * 40 for n in range(1, 6)]
        for payload in sent:
            sender.sendto(payload, a.getsockname())
        for _ in range(200):
            sender.sendto(b"\xee" * 40, b.getsockname())
        assert wait_for(lambda: len(select.select([a], [], [], 0)[0]) == 1)
        read: list = []
        thresholds = gc.get_threshold()
        gc.collect()
        _Reader(second, b.fileno(), read)
        gc.set_threshold(1)  # a collection at the next allocation of a tracked object: inside `receive`
        try:
            rest, taken = first.receive([a.fileno()], 32, 1)
        finally:
            gc.set_threshold(*thresholds)
            gc.collect()
    assert read  # the other engine did read meanwhile
    assert ([payload for _, payload, *_ in rest], taken) == (sent, 0)


def take(device: Device, data: bytes, host: str, port: int, now: int) -> None:
    """server/device_io.py DeviceIo.take: a datagram the engine handed back, on the Python path."""
    device.io_traffic.received(len(data))
    if not device.receive_io(data, (host, port), now, lambda packet, address: None, now):
        device.io_traffic.discarded()


@pytest.mark.integration
def test_the_engine_reads_a_real_socket_as_the_python_path_takes_the_same_datagrams() -> None:
    """`receive`'s glue (recvmmsg, the source address and port, the batch's order, what it hands
    back): a burst of O->T of every kind read from a real socket by the engine, the rest through
    the Python path as the I/O thread does, against the same datagrams given to a Python twin."""
    python, native = Path(False), Path(False)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as device_socket, \
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as originator:
        device_socket.bind(("127.0.0.1", 0))
        originator.bind((SCANNER, 0))
        native.engine = new_engine()
        native.handle = NativeDevice(native.engine, device_socket.fileno(), native.device, lambda: None)
        native.handle.attach()
        oid = python.open(T0)
        assert native.open(T0) == oid
        run, idle = b"\x01\0\0\0", b"\0\0\0\0"
        batches = [[(1, run + b"\x01\0")],  # run, from idle: Python's
                   [(2, run + b"\x02\0"), (2, run + b"\x09\0"), (3, run + b"\x03\0"), None, (4, idle + b"\x04\0"),
                    (5, idle + b"\x05\0"), (6, run + b"\x06\0\0"), (7, run + b"\x07\0")],  # Python's from the malformed
                   [(8, run + b"\x08\0"), (9, run + b"\x09\0"), (7, run + b"\x0a\0")]]  # the engine's
        port = originator.getsockname()[1]
        now = T0 + 5 * MS
        for batch, expected in zip(batches, (0, 3, 3), strict=True):
            datagrams = [b"\x02\0\x02\x80\x08\0" if item is None else encode_io_packet(oid, item[0], item[0], item[1])
                         for item in batch]
            for datagram in datagrams:  # (on loopback each is queued when sendto returns)
                originator.sendto(datagram, device_socket.getsockname())
            assert wait_for(lambda: select.select([device_socket], [], [], 0)[0])
            rest, taken = native.engine.receive([device_socket.fileno()], 32, now)
            assert (taken, len(rest)) == (expected, len(batch) - expected)
            for fd, data, host, source_port, _at in rest:
                assert (fd, host, source_port) == (device_socket.fileno(), SCANNER, port)
                take(native.device, data, host, source_port, now)  # DeviceIo.take, as the I/O thread does
            for datagram in datagrams:
                python.o_t(datagram, SCANNER, port, now, now)
            for path in (python, native):
                path.turn(now + MS, now + 2 * MS)
            now += 10 * MS
    states = [path.state(now) for path in (python, native)]
    for state in states:
        del state["figures"]  # (the kernel's receive times of the engine's datagrams: not the twin's)
    assert states[1] == states[0]
    connections = [path.device.guard.read(lambda p=path: vars(p.device.table.connections[oid]).copy())
                   for path in (python, native)]
    for connection in connections:
        del connection["measure"], connection["owner"]
    assert connections[1] == connections[0] and connections[0]["o_t_port"] == port


class _BusyEpoll:
    """An epoll that finds more sockets ready than a native turn reads, every turn (a farm
    carrying more than it can read in a turn, for a while), and stops the thread after `turns`."""

    def __init__(self, thread: CyclicIoThread, turns: int, clock: _Clock) -> None:
        self.thread, self.turns, self.clock, self.polls = thread, turns, clock, 0

    def poll(self, timeout: float, maxevents: int = -1) -> list:
        self.polls += 1
        self.clock.sleep(0.001)
        if self.polls >= self.turns:
            self.thread._stopping = True  # noqa: SLF001
        return [(1_000_000 + n, select.EPOLLIN) for n in range(maxevents)]  # (no such descriptors: nothing read)


class _Periodic(_Endpoint):
    """A device on the Python path with a T->O stream every 10 ms: records when it is served and what was due."""

    def __init__(self, first: int) -> None:
        super().__init__()
        self.due = [first]

    def service(self, now: int, horizon: int) -> int:
        super().service(now, horizon)
        self.due.append(self.due[-1] + 10 * MS)
        return self.due[-1]


def test_a_turn_that_leaves_sockets_unread_does_not_starve_the_python_paths_devices(monkeypatch) -> None:
    """A thousand turns that each find more ready sockets than they read (a farm of 300 sockets:
    a round is 3 turns of 128): a device on the Python path, due every 10 ms from the start, is
    served each time within the round of skipping turns and the one after (4c814b0 skipped every
    such turn: never served), never before its turn's horizon."""
    clock = _Clock(T0)
    monkeypatch.setattr(implicit, "time", clock)
    thread = CyclicIoThread(native=True)
    real = thread._epoll  # noqa: SLF001
    try:
        thread._readers.update({-2 - n: None for n in range(300)})  # noqa: SLF001 - never among the events
        assert thread.skip_rounds == 3
        thread._epoll = _BusyEpoll(thread, 1000, clock)  # noqa: SLF001
        endpoint = _Periodic(T0)
        thread._schedule(endpoint, T0)  # noqa: SLF001
        thread._loop()  # noqa: SLF001
    finally:
        real.close()
        os.close(thread._wake_read)  # noqa: SLF001
        os.close(thread._wake_write)  # noqa: SLF001
    periods = (clock.now - T0) // (10 * MS)  # (a turn here: the epoll's 1 ms and the turn's own 1 ms)
    assert periods <= len(endpoint.served) <= periods + 2
    for served, due in zip(endpoint.served, endpoint.due, strict=False):  # 3 turns skipped, the 4th serves
        assert due - MS <= served <= due + 4 * 2 * MS, (served - due)
    assert max(served - due for served, due in zip(endpoint.served, endpoint.due, strict=False)) == 7 * MS
