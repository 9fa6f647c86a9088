"""Issue 29: defects found in the native class-1 path (enip_farm/server/_class1.c, server/native.py),
each pinned by the case that showed it, sans-IO (tests/test_native_io_checks.py: those with the
I/O thread, sockets or farms)."""

from __future__ import annotations

import gc
import pathlib
import random
import sys
import tracemalloc

import pytest
import yaml

from enip_farm.device.faults import Fault
from enip_farm.eds.reader import eds_document
from enip_farm.protocol.connection import decode_forward_open_reply, encode_io_packet
from enip_farm.protocol.session import MessageContext
from enip_farm.server.native import BUILT, NativeDevice, new_engine
from tests.test_cip_services_unit import MS, SCANNER, make_device
from tests.test_cip_services_unit import forward_open as open_request
from tests.test_native_differential import PORT, T0, Path
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


def _held(path: Path) -> dict[str, object]:
    """What the engine holds of a device (server/native.py `plan`), by name."""
    device = path.device
    (connection,) = device.table.connections.values()
    (production,) = device.table.productions.values()
    return {"output": device.guard.output.data, "input": device.guard.input.data, "connection": connection,
            "measure": connection.measure, "production": production, "counters": device._counters,  # noqa: SLF001
            "traffic": device.io_traffic}


def _cycles(path: Path, oid: int, first: int, count: int, start: int, faults: bool = True) -> int:
    """`count` O->T and turns, an input write (a transaction) every 50th, a fault set and cleared
    (the device parked, then loaded again; two events logged) every 100th (the 50th on)."""
    now = start
    for n in range(count):
        now = start + n * 10 * MS
        path.o_t(encode_io_packet(oid, first + n, first + n, b"\x01\0\0\0" + bytes([n & 0xFF, 0])), SCANNER, PORT, now,
                 now)
        path.turn(now + MS, now + 2 * MS)
        path.sent.clear()
        if n % 50 == 0:
            path.device.set_inputs(bytes([n & 0xFF, 1]), now)  # a transaction (logs nothing)
            if path.engine is not None:
                path.engine.sync(1)
        if faults and n % 100 == 49:
            path.device.faults.set(Fault("stop-io"), now)
            path.device.faults.clear()
    return now


def _references(held: dict[str, object]) -> dict[str, int]:
    return {name: sys.getrefcount(value) for name, value in held.items()}


def test_the_engine_neither_leaks_nor_frees_early_what_it_holds() -> None:
    """Over thousands of O->T, turns, transactions, parks, loads and write-backs the engine's
    references to the images, the connection, its measurement, the stream and the counters stay
    as they were and no memory grows; once the connection closed and the engine went, every one
    of them has the references of its twin that only the Python path ran."""
    python, native = Path(False), Path(False)
    native.engine = new_engine()
    native.handle = NativeDevice(native.engine, 3, native.device, lambda: None)
    native.handle.attach()
    oids = [path.open(T0) for path in (python, native)]
    held = [_held(path) for path in (python, native)]
    for path, oid in zip((python, native), oids, strict=True):
        now = _cycles(path, oid, 1, 100, T0 + MS)
    assert native.engine.native(native.handle.slot)
    before = _references(held[1])
    mine = [tracemalloc.Filter(True, __file__, all_frames=True)]  # this thread's: not a farm's that ends meanwhile
    tracemalloc.start(64)  # before the warm-up: the values it replaces later are traced too
    try:
        now = _cycles(native, oids[1], 101, 2000, now + 10 * MS, faults=False)  # warm, as measured
        gc.collect()
        first = tracemalloc.take_snapshot().filter_traces(mine)
        now = _cycles(native, oids[1], 2101, 3000, now + 10 * MS, faults=False)  # (faults: the event log grows)
        gc.collect()
        after = tracemalloc.take_snapshot().filter_traces(mine)
        grown = sum(stat.size_diff for stat in after.compare_to(first, "filename"))
    finally:
        tracemalloc.stop()
    assert native.engine.native(native.handle.slot)
    assert _references(held[1]) == before
    assert grown < 48_000, grown  # one object a cycle kept: 3000 x 28+ bytes; the values replaced: < 16 kB
    assert native.device.outputs == bytes([2999 & 0xFF, 0])
    assert native.device.guard.read(lambda: (held[1]["connection"].received, held[1]["measure"].packets)) == (5100,
                                                                                                                5100)
    _cycles(python, oids[0], 101, 5000, T0 + 1000 * MS)
    for path in (python, native):
        path.close(now + MS)  # the Forward Close: the device's table lets them go
    native.handle.detach()  # the farm's stop
    del native.handle, native.engine
    gc.collect()
    assert _references(held[1]) == _references(held[0])


def test_a_class3_deadline_the_engine_watched_is_read_again_after_it_handed_the_device_over() -> None:
    """A class-3 message moves its connection's deadline in a transaction the engine resumes
    from, so the engine's watch stayed the old deadline: from then on it handed the device to
    Python every turn until a T->O fell due (12 % of the turns here), not once a timeout period."""
    driver = Driver(True)
    path = driver.path
    driver.step(("open",), T0)
    driver.step(("class3",), T0)
    handed = 0
    for n in range(1000):  # 10 s: class 1 every 10 ms, a turn every 1 ms, a class-3 message every 100 ms
        base = T0 + MS + n * 10 * MS
        driver.step(("o_t", "next", "run", "scanner", None, 0, b"\x01\x00"), base)
        if n % 10 == 5:
            driver.step(("class3 message",), base)
        for k in range(10):
            now = base + k * MS
            python = path.engine.produce(now, now + MS, True)[0]
            if python:
                handed += 1
                path.device.service_io(now, path._send, now + MS)  # noqa: SLF001 - the I/O thread's Python turn
    assert path.device.counters["connection_timeouts"] == 0
    assert handed <= 10_000 // 400 + 1  # at most once per class-3 timeout (400 ms)


def _eds_paths(tmp_path: pathlib.Path) -> tuple[Path, Path]:
    """Two devices of an EDS's profile (OpENer's sample), its exclusive owner's T->O with the 32-bit
    run/idle header and its input-only connection's T->O a heartbeat: one on each path."""
    document = eds_document(pathlib.Path(__file__).parent / "data" / "eds" / "opener_sample_app.eds")
    (model,) = document["models"].values()
    owner, input_only, _ = model["connections"]
    owner["t_o_format"] = "run/idle"
    input_only["t_o_format"], input_only["t_o_size"] = "heartbeat", 0
    profile = tmp_path / "opener.yaml"
    profile.write_text(yaml.safe_dump(document))
    paths = []
    for native in (False, True):
        path = Path(False)
        path.device = make_device(model=str(profile), implicit={"first_watchdog_s": 1})
        path.device.table.admission._rng = random.Random(29)  # noqa: SLF001 - the same connection ids on both
        if native:
            path.engine = new_engine()
            path.handle = NativeDevice(path.engine, 3, path.device, lambda: None)
            path.handle.attach()
        paths.append(path)
    return paths[0], paths[1]


def test_an_eds_device_with_a_t_o_run_idle_header_and_a_t_o_heartbeat(tmp_path: pathlib.Path) -> None:
    """The T->O formats an EDS may declare (the run/idle header before the data, nothing but the
    sequence count), produced by the engine as the Python path does, beside its O->T."""
    python, native = _eds_paths(tmp_path)
    owner = open_request(1, bytes.fromhex("20 04 24 97 2C 96 2C 64"), 0x01, 2 + 4 + 32, 2 + 4 + 32)
    heartbeat = open_request(2, bytes.fromhex("20 04 24 97 2C 98 2C 64"), 0x01, 2, 2)  # its own T->O stream
    ids = []
    for path in (python, native):
        ids.append([decode_forward_open_reply(path.device.handle_unconnected(message, MessageContext(
            SCANNER, None, (), T0))[0][4:]).o_t_connection_id for message in (owner, heartbeat)])
    assert ids[0] == ids[1]
    (oid, heartbeat_id), ran_native = ids[0], 0
    for n in range(1, 40):
        now = T0 + n * 10 * MS
        for path in (python, native):
            run = b"\0\0\0\0" if 20 <= n < 25 else b"\x01\0\0\0"
            path.o_t(encode_io_packet(oid, n, n, run + bytes([n]) * 32), SCANNER, PORT, now, now - 100_000)
            path.o_t(encode_io_packet(heartbeat_id, n, n, b"" if n % 2 else b"\x01\0\0\0"), SCANNER, PORT, now, now)
            if n % 7 == 0:
                path.device.set_inputs(bytes([n]) * 32, now)
            path.turn(now + MS, now + 2 * MS)
        ran_native += native.engine.native(native.handle.slot)
        assert native.state(now) == python.state(now), n
    assert ran_native > 30
    assert {len(packet) for packet, _ in native.sent} == {20, 20 + 4 + 32}  # the heartbeat, the header and data
