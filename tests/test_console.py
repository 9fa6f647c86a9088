"""The talking console (enip_farm/farm/console.py): one line per connection, session, Forward Open/Close
(originator, RPI, sizes), timeout, fault and refusal (status in hex and words), taken from the
devices' events; the lines of real sessions (pycomm3, the ethernetip scanner); a bounded number
of lines under a flood of connections, with every event accounted for; `serve`'s banner,
--quiet, --log-level and bind problems in one line."""

from __future__ import annotations

import asyncio
import logging
import math
import re
import shutil
import signal
import socket
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from click.testing import CliRunner
from pycomm3 import CIPDriver, Services

from enip_farm.cli import main
from enip_farm.config import parse_config
from enip_farm.device.device import Device
from enip_farm.device.faults import Fault
from enip_farm.farm.console import Console
from enip_farm.farm.farm import Farm
from enip_farm.protocol.cip import encode_multiple_service, encode_request, encode_unconnected_send
from enip_farm.protocol.connection import ConnectionTriad, encode_class0_packet, encode_forward_open
from enip_farm.protocol.encapsulation import Command, encode_frame
from enip_farm.protocol.epath import encode_request_path
from enip_farm.protocol.safety.messages import encode_data, mode_byte
from enip_farm.protocol.safety.validator import ticks
from enip_farm.protocol.session import EncapsulationSession, MessageContext
from enip_farm.pytest_plugin import AddressPool
from enip_farm.server.limits import RateLimitedLog
from tests.helpers import CLI, ROOT, STARTUP_S, RawClient, read_lines, serving, wait_for
from tests.scanners import scanner
from tests.test_implicit import forward_close, forward_open
from tests.test_safety import T0, _pid, safety_open

MS = 1_000_000
SCANNER = "127.0.0.9"
HEX8 = "0x[0-9A-F]{8}"


class Lines(logging.Handler):
    """Collects (level name, message) of every record."""

    def __init__(self) -> None:
        super().__init__(logging.DEBUG)
        self.records: list[tuple[str, str]] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append((record.levelname, record.getMessage()))

    def take(self) -> list[tuple[str, str]]:
        taken, self.records = self.records, []
        return taken


@pytest.fixture
def lines(request: pytest.FixtureRequest) -> Iterator[tuple[logging.Logger, Lines]]:
    """A logger of its own (nothing else writes to it) and what it received."""
    logger = logging.getLogger(f"enip_farm.farm.console.test.{request.node.name}")
    handler = Lines()
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    logger.propagate = False
    yield logger, handler
    logger.removeHandler(handler)


def _device(name: str = "io1", address: str = "127.0.0.5") -> tuple[Farm, Device]:
    farm = Farm({"devices": [{"name": name, "address": address, "model": "DSQC1030"}]})  # built, not started
    return farm, farm.devices[name]


def _ask(device: Device, message: bytes, now: int = 0) -> None:
    device.handle_unconnected(message, MessageContext(SCANNER, None, (), now))


# -- the rate limit ------------------------------------------------------------------------------------


def test_rate_limited_log_holds_back_and_accounts_for_every_line(lines) -> None:
    logger, handler = lines
    log = RateLimitedLog(logger, interval_s=1.0, burst=3)
    shown = [log.log(logging.INFO, "k", 0.1 * n, "line %d", n) for n in range(10)]  # 0.0 .. 0.9 s: one window
    assert shown == [True] * 3 + [False] * 7 and log.holding == 7
    assert [m for _, m in handler.take()] == ["line 0", "line 1", "line 2"]
    assert log.flush(0.99) == 0 and handler.take() == []  # the window is not over
    assert log.flush(1.0) == 1 and log.holding == 0
    assert handler.take() == [("INFO", "line 9 (6 more like this held back)")]  # the last, with the others
    # the flushed line opened a window: two more fit in it, the third waits for the next line of its key
    assert [log.log(logging.WARNING, "k", 1.5, "again %d", n) for n in range(3)] == [True, True, False]
    assert log.log(logging.WARNING, "other", 1.5, "another key")
    assert log.log(logging.WARNING, "k", 2.0, "later")
    assert [m for _, m in handler.take()] == ["again 0", "again 1", "another key",
                                              "later (1 more like this since the last line)"]


# -- what each event says (a device in-process, no sockets) -----------------------------------------


def test_each_event_is_one_line_naming_device_peer_and_status(lines) -> None:
    logger, handler = lines
    farm, device = _device()
    console = Console([device], logger).attach()
    prefix = "io1 127.0.0.5: "
    assert device.register_session(SCANNER) == 1
    assert handler.take() == [("INFO", prefix + "session registered: handle 1 from 127.0.0.9")]

    _ask(device, encode_request(0x0E, encode_request_path(4, 100, 3)))  # succeeds: not told at INFO
    _ask(device, encode_request(0x10, encode_request_path(4, 101, 3), b"\x01\x00"))
    assert handler.take() == [("INFO", prefix + "request refused: Set Attribute Single (0x10) path 20 04 24 65 30 03: "
                                                "0x0E attribute not settable")]

    message, _ = forward_open(rpi=1_000)  # RPI below the device's 2 ms
    _ask(device, message)
    refused = ("WARNING", prefix + "connection refused: Forward Open from 127.0.0.9: 0x01/0x0111 connection failure: "
                                   "RPI not supported (class 1, O->T RPI 1000 us 8 bytes, T->O RPI 1000 us 4 bytes, "
                                   "path 20 04 24 01 2c 64 2c 65)")
    assert handler.take() == [refused]  # one line, not a second for the request
    wrapped = encode_request(0x52, encode_request_path(6, 1), encode_unconnected_send(message, b"\x01\x00"))
    _ask(device, wrapped)  # through Unconnected Send: still one line
    assert handler.take() == [refused]
    route = encode_request(0x52, encode_request_path(6, 1), encode_unconnected_send(message, b"\x02\x00"))
    _ask(device, route)  # the route itself is refused: the Unconnected Send is told
    assert handler.take() == [("INFO", prefix + "request refused: Unconnected Send (0x52) path 20 06 24 01: "
                                                "0x01/0x0311 connection failure: invalid port in the route path")]
    packet = encode_request(0x0A, encode_request_path(2, 1), encode_multiple_service(
        [encode_request(0x0E, encode_request_path(4, 100, 3)), encode_request(0x0E, encode_request_path(4, 100, 9))]))
    _ask(device, packet)  # the failing embedded request is told, the packet's 0x1E is not
    assert handler.take() == [("INFO", prefix + "request refused: Get Attribute Single (0x0E) path 20 04 24 64 30 09: "
                                                "0x14 attribute not supported")]

    message, triad = forward_open(rpi=20_000, multiplier=1)
    _ask(device, message, now=0)
    ((level, line),) = handler.take()
    assert level == "INFO" and re.fullmatch(
        prefix + f"connection opened: exclusive owner from 127.0.0.9: O->T {HEX8} RPI 20000 us 8 bytes, "
                 r"T->O 0x7E570001 RPI 20000 us 4 bytes to 127\.0\.0\.9:2222", line), line
    unknown = ConnectionTriad(0x4242, 0x1234, 0xABCD)
    _ask(device, forward_close(unknown))
    assert handler.take() == [("WARNING", prefix + "connection refused: Forward Close from 127.0.0.9: 0x01/0x0107 "
                                                   "connection failure: target connection not found (connection "
                                                   "serial 0x4242, vendor 4660, originator serial 0x0000ABCD)")]
    device.service_io(10_000 * MS, lambda *_: None)  # the first watchdog (10 s) has passed: it times out
    ((level, line),) = handler.take()
    assert level == "WARNING" and re.fullmatch(
        prefix + f"connection timed out: exclusive owner from 127.0.0.9: O->T {HEX8} RPI 20000 us 8 bytes, "
                 r"T->O 0x7E570001 RPI 20000 us 4 bytes to 127\.0\.0\.9:2222: no packet for 160 ms", line), line
    message, triad = forward_open()
    _ask(device, message)
    handler.take()
    _ask(device, forward_close(triad))
    ((level, line),) = handler.take()
    assert level == "INFO" and line.startswith(prefix + "connection closed: exclusive owner from 127.0.0.9: ")
    assert line.endswith(": forward close")

    asyncio.run(farm.inject_fault("io1", Fault("delay", delay_ms=800)))
    asyncio.run(farm.clear_faults("io1"))
    assert handler.take() == [("WARNING", prefix + "fault injected: delay (delay_ms 800)"),
                              ("INFO", prefix + "fault cleared: delay")]
    device.unregister_session(1)
    assert handler.take() == [("INFO", prefix + "session ended: handle 1")]
    console.close()
    device.register_session(SCANNER)
    assert handler.take() == []  # detached


def test_a_faulting_safety_connection_is_told_at_warning(lines) -> None:
    logger, handler = lines
    logger.setLevel(logging.WARNING)  # what --quiet shows
    farm = Farm({"devices": [{"name": "s1", "address": "127.0.77.1", "model": "DSQC1042"}]})  # built, not started
    device = farm.devices["s1"]
    Console([device], logger).attach()
    prefix = "s1 127.0.77.1: "
    for n, bad_crc in enumerate((True, False), 1):
        request = safety_open()
        _ask(device, encode_request(0x54, encode_request_path(6, 1), encode_forward_open(request)), now=T0)
        (connection,) = device.connections.values()
        now = T0 + n * 1_000 * MS
        stamp = (ticks(now) - 1_000) & 0xFFFF  # 1000 ticks old: over the network time expectation (781)
        message = bytearray(encode_data(b"\x0f", mode_byte(True, 0), stamp, _pid(request), False))
        if bad_crc:
            message[2] ^= 0x01
        assert not device.receive_io(encode_class0_packet(connection.o_t_id, 1, bytes(message)),
                                     (SCANNER, 2222), now, lambda *_: None)
        fault = "safety crc fault" if bad_crc else "safety timing fault"
        taken = handler.take()
        assert [(level, line.split(": ", 2)[1]) for level, line in taken] == [
            ("WARNING", fault), ("WARNING", "connection faulted"), ("WARNING", "safe state")], taken
        assert all(line.startswith(prefix) for _, line in taken)


def test_debug_tells_every_request_and_image_change(lines) -> None:
    logger, handler = lines
    logger.setLevel(logging.DEBUG)
    _, device = _device()
    Console([device], logger).attach()
    _ask(device, encode_request(0x10, encode_request_path(4, 100, 3), b"\x10\x00"))
    assert handler.take() == [
        ("DEBUG", "io1 127.0.0.5: request: Set Attribute Single (0x10) path 20 04 24 64 30 03: 0x00 success"),
        ("DEBUG", "io1 127.0.0.5: image changed: output 0000 -> 1000")]


def test_encapsulation_refusals_are_collected_for_the_server() -> None:
    _, device = _device()
    session = EncapsulationSession(device, SCANNER)
    session.receive(encode_frame(Command.SEND_RR_DATA, b"\x00" * 16, 77), 0)  # no session registered
    session.receive(encode_frame(Command.REGISTER_SESSION, b"\x02\x00\x00\x00"), 0)  # protocol version 2
    assert session.refusals == [(Command.SEND_RR_DATA, 0x0064), (Command.REGISTER_SESSION, 0x0069)]


# -- real sessions -------------------------------------------------------------------------------------


def test_the_lines_of_a_pycomm3_and_a_scanner_session(enip_farm, lines) -> None:
    logger, handler = lines
    farm = enip_farm(name="io1", model="DSQC1030", implicit={"first_watchdog_s": 0})
    device = farm.device("io1")
    address = device.profile.address
    Console([device], logger).attach()
    prefix = f"io1 {address}: "
    peer = r"127\.0\.0\.1:\d+"

    with CIPDriver(address) as plc:
        assert plc.generic_message(service=Services.set_attribute_single, class_code=4, instance=100, attribute=3,
                                   request_data=b"\x10\x00", connected=False, route_path=False).error is None
        refused = plc.generic_message(service=Services.set_attribute_single, class_code=4, instance=101, attribute=3,
                                      request_data=b"\x10\x00", connected=False, route_path=False)
        assert refused.error == "Attribute not settable"
    assert wait_for(lambda: len(handler.records) >= 5)
    expected = [
        ("INFO", rf"tcp connected: {peer}"),
        ("INFO", r"session registered: handle 1 from 127\.0\.0\.1"),
        ("INFO", r"request refused: Set Attribute Single \(0x10\) path 20 04 24 65 30 03: 0x0E attribute not "
                 "settable"),
        ("INFO", r"session ended: handle 1"),  # pycomm3 unregisters; the farm then closes
        ("INFO", rf"tcp closed: {peer} closed by the farm after \d+\.\d s"),
    ]
    taken = handler.take()
    assert len(taken) == len(expected), taken
    for (level, line), (want_level, pattern) in zip(taken, expected, strict=True):
        assert level == want_level and re.fullmatch(re.escape(prefix) + pattern, line), line

    with scanner(address) as scan:
        assert scan.forward_open(50, 0) == 0
        scan.outputs[4] = True
        scan.conn.produce()
        assert wait_for(lambda: device.outputs == b"\x10\x00")
        scan.conn.stopProduce()  # the scanner goes silent: the connection times out after 4 x 50 ms
        assert wait_for(lambda: any("timed out" in line for _, line in handler.records))
    port = scan.enip.originator_udp_port
    connection = (rf"exclusive owner from 127\.0\.0\.1: O->T {HEX8} RPI 50000 us 8 bytes, T->O {HEX8} RPI 50000 us "
                  rf"4 bytes to 127\.0\.0\.1:{port}")
    expected = [
        ("INFO", rf"tcp connected: {peer}"),
        ("INFO", r"session registered: handle 2 from 127\.0\.0\.1"),
        ("INFO", rf"connection opened: {connection}"),
        ("WARNING", rf"connection timed out: {connection}: no packet for 200 ms"),
    ]
    taken = handler.take()
    assert len(taken) == len(expected), taken
    for (level, line), (want_level, pattern) in zip(taken, expected, strict=True):
        assert level == want_level and re.fullmatch(re.escape(prefix) + pattern, line), line


def test_a_flood_of_connections_gives_a_bounded_number_of_lines(enip_farm, lines) -> None:
    """500 connections opened and closed as fast as the client can: at most `burst` lines per kind
    and window (a window opens at most once an interval, plus the flush at the end), and the lines
    shown plus the counts they carry add up to every connection."""
    logger, handler = lines
    farm = enip_farm(name="io1", model="DSQC1030")
    device = farm.device("io1")
    console = Console([device], logger, interval_s=1.0, burst=20).attach()
    started = time.monotonic()
    for _ in range(500):
        socket.create_connection((device.profile.address, 44818), timeout=10).close()
    assert wait_for(lambda: len(device.events.of_kind("tcp closed")) == 500, timeout=30)
    elapsed = time.monotonic() - started
    console.close()  # shows what is still held back
    for kind in ("tcp connected", "tcp closed"):
        told = [line for _, line in handler.records if f": {kind}: " in line]
        windows = math.floor(elapsed / 1.0) + 2  # one per interval, and the flush at the end
        assert 1 <= len(told) <= 20 * windows, (kind, len(told), elapsed)
        counted = sum(int(n) for line in told for n in re.findall(r"\((\d+) more like this", line))
        assert len(told) + counted == 500, (kind, len(told), counted)


# -- serve -------------------------------------------------------------------------------------------


def test_the_device_table_names_models_alike_and_summarises_past_a_screenful(tmp_path: Path) -> None:
    """The MODEL column names what the configuration names (a catalogue model, or a profile file:
    a learned profile and an EDS alike), and a cell longer than a screen gets a screenful of rows
    and one line for the rest (issue 30)."""
    from enip_farm.farm.table import TABLE_HEADER, device_rows, device_table

    eds = ROOT / "tests" / "data" / "eds" / "abb_robotics_anybus_enip_fa.eds"
    learned = CliRunner().invoke(main, ["learn", str(ROOT / "captures" / "dsqc1030_explicit_session.pcap"), "-o",
                                        str(tmp_path / "seed.yaml")])
    assert learned.exit_code == 0, learned.output
    shutil.copy(eds, tmp_path / eds.name)
    config = {"discovery": False, "devices": [
        {"name": "w{n}", "address": "127.0.30.1", "count": 30, "model": "DSQC1030"},
        {"name": "x", "address": "127.0.30.100", "model": "seed.yaml"},
        {"name": "y", "address": "127.0.30.101", "model": eds.name},
        {"name": "z", "address": "127.0.30.102", "model": "DSQC1030", "addons": ["DSQC1032"]}]}
    farm = Farm(parse_config(config, "cell.yaml", tmp_path))
    rows = device_rows(farm.devices.values())
    assert [model for _, _, model in rows[-3:]] == ["seed.yaml", eds.name, "DSQC1030+DSQC1032"]
    assert device_table(rows, limit=40).splitlines() == [TABLE_HEADER, *(line for _, line, _ in rows)]
    assert device_table(rows, limit=10).splitlines() == [
        TABLE_HEADER, *(line for _, line, _ in rows[:9]),
        f"... and 24 more devices: 33 in all (30 DSQC1030, 1 seed.yaml, 1 {eds.name}, 1 DSQC1030+DSQC1032)"]


def test_serve_http_port_out_of_range_is_refused() -> None:
    result = CliRunner().invoke(main, ["serve", "--http", "70000"])
    assert result.exit_code == 2
    assert "the port 70000 is out of range (0..65535; 0 picks a free one)" in result.output


def _config(tmp_path: Path, address: str, name: str = "cell.yaml") -> Path:
    path = tmp_path / name
    path.write_text(f"devices:\n  - {{name: io1, address: {address}, model: DSQC1030}}\ndiscovery: false\n")
    return path


@pytest.mark.system
def test_serve_talks(free_address: AddressPool, tmp_path: Path) -> None:
    address = free_address()
    config = _config(tmp_path, address)
    log = tmp_path / "serve.log"
    with log.open("w") as stderr, serving(["serve", "--config", str(config), "--http", "0"], table_rows=1,
                                          stderr=stderr) as (server, _):
        assert wait_for(lambda: "cyclic I/O budget" in log.read_text(), timeout=STARTUP_S)
        banner = log.read_text().splitlines()
        api = banner[1].split()[-1]
        assert banner[:3] == [
            f"1 device listening on TCP and UDP 44818, from {config}. Ctrl-C to stop.",
            f"HTTP API on {api}",
            f"dashboard on {api}/ and API docs on {api}/docs; `enip-farm io` and `enip-farm fault` use this API "
            f"with --api {api}"]
        assert len(banner) == 4 and re.fullmatch(
            r"cyclic I/O budget: [\d ]+ datagrams/s per worker \([\d ]+ connections at RPI 10 ms; measured at start: "
            r"[\d.]+ us of CPU per O->T/T->O pair, for (50% of a core|the \d+% of a core the machine gave while "
            r"measuring \(50% once the I/O thread keeps time\))\)", banner[3]), banner[3]  # busy: the share it got
        with RawClient(address) as client:
            client.register()
            client.request(forward_open(rpi=1_000)[0])
        fault = subprocess.run([*CLI, "fault", "io1", "drop", "--api", api], capture_output=True, text=True,
                               timeout=STARTUP_S)
        assert fault.returncode == 0, fault.stderr
        assert wait_for(lambda: "fault injected" in log.read_text(), timeout=STARTUP_S)
        server.send_signal(signal.SIGINT)
        assert server.wait(timeout=STARTUP_S) == 0
    said = [re.sub(r"^\S+ \S+ ", "", line) for line in log.read_text().splitlines()[4:]]  # without the time
    assert said == [
        f"INFO io1 {address}: tcp connected: {said[0].split()[-1]}",
        f"INFO io1 {address}: session registered: handle 1 from 127.0.0.1",
        f"WARNING io1 {address}: connection refused: Forward Open from 127.0.0.1: 0x01/0x0111 connection failure: "
        "RPI not supported (class 1, O->T RPI 1000 us 8 bytes, T->O RPI 1000 us 4 bytes, path 20 04 24 01 2c 64 2c 65)",
        f"INFO io1 {address}: session ended: handle 1",
        f"INFO io1 {address}: tcp closed: {said[0].split()[-1]} closed by the client after {said[4].split()[-2]} s",
        f"WARNING io1 {address}: fault injected: drop",
    ], said


@pytest.mark.system
@pytest.mark.parametrize("options", [["--quiet"], ["--log-level", "debug"]])
def test_serve_quiet_and_debug(free_address: AddressPool, tmp_path: Path, options: list[str]) -> None:
    address = free_address()
    log = tmp_path / "serve.log"
    with log.open("w") as stderr, serving(["serve", "--config", str(_config(tmp_path, address)), *options],
                                          table_rows=1, stderr=stderr) as (server, _):
        with RawClient(address) as client:
            client.register()
            client.get(4, 100, 3)
            client.request(forward_open(rpi=1_000)[0])
        assert wait_for(lambda: "connection refused" in log.read_text(), timeout=STARTUP_S)
        server.send_signal(signal.SIGINT)
        assert server.wait(timeout=STARTUP_S) == 0
    text = log.read_text()
    assert "WARNING io1" in text  # the refusal, in both
    assert ("INFO io1" in text) is (options != ["--quiet"])
    assert (f"DEBUG io1 {address}: request: Get Attribute Single (0x0E) path 20 04 24 64 30 03: 0x00 success"
            in text) is (options != ["--quiet"])


@pytest.mark.system
def test_bind_problems_are_one_line(enip_farm, free_address: AddressPool, tmp_path: Path) -> None:
    """A device address in use, an address on no interface, an HTTP port in use: one line each on
    stderr, exit status 1, no traceback."""
    taken = enip_farm(name="io1", model="DSQC1030").device("io1").profile.address
    holder = socket.socket()
    holder.bind(("127.0.0.1", 0))
    holder.listen()
    port = holder.getsockname()[1]
    cases = [
        (["--config", str(_config(tmp_path, taken))],
         f"device 'io1': cannot bind TCP {taken}:44818: the port is already in use there (another farm or EtherNet/IP "
         "stack?). Stop it (`ss -ltunp 'sport = :44818'` names the process), or give the device an address nothing "
         "serves (on Linux any 127.x.y.z is this host's)."),
        (["--config", str(_config(tmp_path, "192.0.2.1", "remote.yaml"))],  # RFC 5737: on no interface
         "device 'io1': cannot bind TCP 192.0.2.1:44818: the address is not assigned to any interface of this host"),
        (["--config", str(_config(tmp_path, free_address(), "free.yaml")), "--http", str(port)],
         f"the HTTP API cannot listen on 127.0.0.1:{port}: the port is already in use (another farm's HTTP API?)"),
    ]
    try:
        for args, expected in cases:
            result = subprocess.run([*CLI, "serve", *args], capture_output=True, text=True, timeout=STARTUP_S)
            assert result.returncode == 1, result.stderr
            (line,) = result.stderr.splitlines()
            assert line.startswith(expected), line
    finally:
        holder.close()


@pytest.mark.system
def test_serve_http_on_any_loopback_address_needs_no_token(free_address: AddressPool, tmp_path: Path) -> None:
    host = free_address()  # as --http 127.0.10.1:8044
    with serving(["serve", "--config", str(_config(tmp_path, free_address())), "--http", f"{host}:0"],
                 table_rows=1) as (server, _):
        (api,) = [line.split()[-1] for line in read_lines(server.stderr, 3) if line.startswith("HTTP API on ")]
        assert api.startswith(f"http://{host}:")
        result = subprocess.run([*CLI, "io", "get", "io1", "--api", api], capture_output=True, text=True,
                                timeout=STARTUP_S)
        assert result.returncode == 0 and result.stdout.startswith("inputs  0000"), result.stderr
        server.send_signal(signal.SIGINT)
        assert server.wait(timeout=STARTUP_S) == 0


def test_encapsulation_refusals_are_told_with_the_peer(enip_farm, lines) -> None:
    logger, handler = lines
    device = enip_farm(name="io1", model="DSQC1030").device("io1")
    Console([device], logger).attach()
    with RawClient(device.profile.address) as client:  # SendRRData before RegisterSession
        reply = client.exchange(encode_frame(Command.SEND_RR_DATA, b"\x00" * 16, 77))
        assert reply.header.status == 0x0064
        port = client.sock.getsockname()[1]
    assert wait_for(lambda: any("encapsulation refused" in line for _, line in handler.records))
    assert ("WARNING", f"io1 {device.profile.address}: encapsulation refused: SendRRData from 127.0.0.1:{port}: "
            "encapsulation status 0x0064 invalid session handle") in handler.records
