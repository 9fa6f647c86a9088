"""Issue 29: defects found in the native class-1 path (enip_farm/server/_class1.c, server/native.py),
each pinned by the case that showed it, sans-IO unless it needs the cyclic I/O thread."""

from __future__ import annotations

import socket
import time

import pytest

from enip_farm.protocol.connection import decode_forward_open_reply, encode_io_packet
from enip_farm.server.native import BUILT, new_engine
from tests.helpers import RawClient, wait_for
from tests.test_cip_services_unit import MS
from tests.test_implicit import forward_close, forward_open
from tests.test_native_differential import PORT, T0
from tests.test_native_fuzz import Driver

pytestmark = pytest.mark.skipif(not BUILT, reason="the native class-1 extension is not built")


def test_a_class3_connection_times_out_while_the_engine_runs_the_class1_one() -> None:
    """The engine held only the class-1 connections' deadlines: a silent class-3 connection of a
    native device never timed out (its 400 ms) while the class-1 one ran."""
    paths = Driver(False), Driver(True)
    for path in paths:
        path.step(("open",), T0)
        path.step(("class3",), T0)
        for n in range(60):  # the class-1 originator goes on, the class-3 one is silent
            now = T0 + MS + n * 10 * MS
            path.step(("o_t", "next", "run", "scanner", None, 0, b"\x01\x00"), now)
            path.step(("turn",), now + MS)
    python, native = paths
    assert native.path.engine.native(native.path.handle.slot)
    assert python.path.device.counters["connection_timeouts"] == 1
    assert native.path.state(T0 + 600 * MS) == python.path.state(T0 + 600 * MS)
    assert native.path.device.counters["connection_timeouts"] == 1


def test_the_sans_io_consume_releases_its_buffers_when_the_slot_is_wrong() -> None:
    """`consume` took the buffers of its arguments, then refused the slot without giving them back:
    the bytearray stayed exported and could never be resized again."""
    engine = new_engine()
    data = bytearray(30)
    with pytest.raises(IndexError):
        engine.consume(5, data, bytes(4), PORT, T0, T0)
    data.append(1)  # BufferError while the export leaked
    assert len(data) == 31


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
