"""Driving and observing the cell: the Python API, faults as real clients see them, wiring and
rules end to end, the HTTP API (with its token) and the CLI client against a running farm."""

from __future__ import annotations

import os
import socket
import subprocess
import threading
import time

import httpx
import pytest
from pycomm3 import CIPDriver, CommError, Services

from enip_farm.config import ConfigError, parse_config
from enip_farm.control.client import ApiClient
from enip_farm.device.build import build_profiles
from enip_farm.device.catalogue import shipped_catalogue
from enip_farm.protocol.encapsulation import Command, decode_frame, encode_frame
from enip_farm.pytest_plugin import AddressPool
from tests.helpers import CLI, STARTUP_S, RawClient, metric_samples, read_lines, serving
from tests.scanners import scanner
from tests.test_implicit import ASSEMBLY_PATH, forward_open

GET_OUTPUTS = dict(service=Services.get_attribute_single, class_code=4, instance=100, attribute=3,
                   connected=False, route_path=False)


def set_outputs(data: bytes) -> dict:
    return dict(service=Services.set_attribute_single, class_code=4, instance=100, attribute=3, request_data=data,
                connected=False, route_path=False)


# -- the Python API ----------------------------------------------------------------------------------


def test_signals_across_addons(enip_farm) -> None:
    farm = enip_farm(name="io", model="DSQC1030", addons=["DSQC1031", "DSQC1032"])
    io = farm["io"]
    assert io.signals.names() == {"DI": 32, "DO": 32, "AI": 4, "AO": 4}
    io.set(DI1=1, DI17=1, AI2=-1200)
    assert io.inputs == bytes.fromhex("01 00 01 00 00 00 50 fb 00 00 00 00")
    assert io.get("DI17") == 1 and io.get("DI1-3") == [1, 0, 0] and io.get("AI2") == -1200
    with CIPDriver(io.address) as driver:
        assert driver.generic_message(**set_outputs(bytes.fromhex("00 80 00 00 e8 03 00 00 00 00 00 00"))).error is None
        read = driver.generic_message(service=Services.get_attribute_single, class_code=4, instance=101, attribute=3,
                                      connected=False, route_path=False)
    assert read.value == io.inputs
    assert io.get("DO16") == 1 and io.get("AO1") == 1000
    with pytest.raises(ValueError, match="^DI33: this device has 32 DI signals$"):
        io.get("DI33")


def test_concurrent_setters_lose_no_write(enip_farm) -> None:
    io = enip_farm(name="io", model="DSQC1030", addons=["DSQC1031"])["io"]

    def toggle(bit: int) -> None:
        for i in range(200):
            io.set({f"DI{bit}": i % 2})
        io.set({f"DI{bit}": 1})

    threads = [threading.Thread(target=toggle, args=(bit,)) for bit in range(1, 33)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert io.inputs == b"\xff\xff\xff\xff"


def test_wait_for_and_events(enip_farm) -> None:
    io = enip_farm(name="io", model="DSQC1030")["io"]
    threading.Timer(0.05, lambda: io.set(DO2=1)).start()
    io.wait_for(lambda d: d.get("DO2") == 1, timeout=5)
    with pytest.raises(TimeoutError, match=r"^io: condition not met within 0\.05 s$"):
        io.wait_for(lambda d: d.get("DO3") == 1, timeout=0.05)
    with RawClient(io.address) as c:
        c.register()
        c.get(4, 100, 3)
        c.get(4, 77, 3)
    io.wait_for(lambda d: d.events("tcp closed"), timeout=5)
    kinds = [e.kind for e in io.events()]
    assert {"tcp connected", "tcp closed", "request"} <= set(kinds)
    requests = [e.text for e in io.events("request")]
    assert "service 0x0E path 20 04 24 64 30 03 status 0x00" in requests
    assert "service 0x0E path 20 04 24 4d 30 03 status 0x05" in requests
    assert io.counters["sessions"] == 1 and io.counters["requests"]["0x0E/0x05"] == 1


def test_output_change_hook(enip_farm) -> None:
    io = enip_farm(name="io", model="DSQC1030")["io"]
    seen = []
    io.on_output_change(lambda handle, old, new: seen.append((old, new)))
    with CIPDriver(io.address) as driver:
        driver.generic_message(**set_outputs(b"\x01\x00"))
        driver.generic_message(**set_outputs(b"\x01\x00"))  # no change, no call
        driver.generic_message(**set_outputs(b"\x03\x00"))
    assert seen == [(b"\x00\x00", b"\x01\x00"), (b"\x01\x00", b"\x03\x00")]


@pytest.mark.integration
def test_plugin_teardown_leaves_nothing_behind(free_address: AddressPool) -> None:
    from contextlib import ExitStack

    from enip_farm.pytest_plugin import start_farm

    before = set(threading.enumerate())  # other tests' threads may end meanwhile: only new ones count
    with ExitStack() as stack:
        farm = start_farm(stack, free_address, name="io", model="DSQC1030", http=True)
        address, port = farm["io"].address, farm.http.port
        with RawClient(address) as c:
            c.register()
    assert {t.name for t in set(threading.enumerate()) - before} == set()
    with pytest.raises(OSError, match="Connection refused"):
        socket.create_connection((address, 44818), timeout=1)
    with pytest.raises(OSError, match="Connection refused"):
        socket.create_connection(("127.0.0.1", port), timeout=1)


# -- faults as real clients see them -----------------------------------------------------------------


def _driver(address: str, timeout: float) -> CIPDriver:
    """An open pycomm3 driver whose replies time out after `timeout` s. It opens (connect, register)
    with pycomm3's default 5 s, so a loaded machine does not fail the open itself."""
    driver = CIPDriver(address)
    driver.open()
    driver._sock.sock.settimeout(timeout)  # pycomm3 applies socket_timeout only when the socket opens
    return driver


def test_delay_makes_pycomm3_time_out_and_clears(enip_farm) -> None:
    io = enip_farm(name="io", model="DSQC1030")["io"]
    with _driver(io.address, 0.3) as driver:
        io.inject("delay", delay_ms=800)
        with pytest.raises(CommError, match="^failed to receive reply$"):
            driver.generic_message(**GET_OUTPUTS)
    io.clear_faults()
    with CIPDriver(io.address) as driver:
        assert driver.generic_message(**GET_OUTPUTS).error is None


def test_random_delay_range(enip_farm) -> None:
    io = enip_farm(name="io", model="DSQC1030")["io"]
    with RawClient(io.address) as c:
        c.register()
        io.inject("delay", delay_ms=40, max_delay_ms=80)
        times = []
        for _ in range(5):
            start = time.monotonic()
            c.get(4, 100, 3)
            times.append(time.monotonic() - start)
    assert all(t >= 0.039 for t in times)


def test_drop_processes_but_sends_nothing(enip_farm) -> None:
    io = enip_farm(name="io", model="DSQC1030")["io"]
    with _driver(io.address, 0.3) as driver:
        io.inject("drop")
        with pytest.raises(CommError, match="^failed to receive reply$"):
            driver.generic_message(**set_outputs(b"\x07\x00"))
    # the write happened (by now, or soon on a loaded machine: the client gave up first); its reply was lost
    io.wait_for(lambda d: d.counters["replies_dropped"] >= 1, timeout=10)
    assert io.counters["replies_dropped"] == 1
    assert io.outputs == b"\x07\x00"


@pytest.mark.parametrize("kind", ["close", "reset"])
def test_close_and_reset(enip_farm, kind: str) -> None:
    io = enip_farm(name="io", model="DSQC1030")["io"]
    existing = RawClient(io.address)
    existing.register()
    io.inject(kind)
    if kind == "reset":
        with pytest.raises(ConnectionResetError, match="Connection reset by peer"):
            existing.sock.recv(10)
    else:
        assert existing.is_closed()
    with pytest.raises(CommError, match="^failed to open a connection$"):
        with CIPDriver(io.address) as driver:
            driver.generic_message(**GET_OUTPUTS)
    io.clear_faults(kind)
    with CIPDriver(io.address) as driver:
        assert driver.generic_message(**GET_OUTPUTS).error is None


def test_offline_refuses_and_comes_back(enip_farm) -> None:
    io = enip_farm(name="io", model="DSQC1030")["io"]
    io.inject("offline")
    with pytest.raises(CommError, match="^failed to open a connection$"):
        CIPDriver(io.address).open()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as udp:
        udp.settimeout(0.3)
        udp.sendto(encode_frame(Command.LIST_IDENTITY), (io.address, 44818))
        with pytest.raises(TimeoutError, match="^timed out$"):
            udp.recv(1024)
    io.clear_faults()
    with CIPDriver(io.address) as driver:
        assert driver.generic_message(**GET_OUTPUTS).error is None


def test_offline_for_a_duration(enip_farm) -> None:
    io = enip_farm(name="io", model="DSQC1030")["io"]
    io.inject("offline", duration_s=2)  # long enough that a loaded machine still connects within it
    with pytest.raises(OSError, match="Connection refused"):
        socket.create_connection((io.address, 44818), timeout=1).close()
    # "fault cleared" is recorded once the device listens again; `faults` empties a moment before
    io.wait_for(lambda d: d.events("fault cleared"), timeout=10)
    assert not io.faults
    with RawClient(io.address) as c:
        assert c.register() == 1


def test_injected_status_is_read_by_pycomm3(enip_farm) -> None:
    io = enip_farm(name="io", model="DSQC1030")["io"]
    io.inject("status", service=0x0E, status=0x08)
    with CIPDriver(io.address) as driver:
        reply = driver.generic_message(**GET_OUTPUTS)
        assert reply.error == "Service not supported"
        assert driver.generic_message(**set_outputs(b"\x01\x00")).error is None  # other services unchanged


def test_stop_io_times_out_the_ethernetip_scanner(enip_farm) -> None:
    farm = enip_farm(name="io", model="DSQC1030", implicit={"first_watchdog_s": 0})
    io = farm["io"]
    with scanner(io.address) as scan:
        assert scan.forward_open(10, 1) == 0
        scan.conn.produce()
        io.set(DI1=1)
        assert _eventually(lambda: scan.inputs[0])
        io.inject("stop-io")
        io.set(DI2=1)  # no longer produced
        io.wait_for(lambda d: d.events("connection timed out"), timeout=5)
        assert not scan.inputs[1]


def test_identity_mismatch_fails_keying(enip_farm) -> None:
    from enip_farm.protocol.epath import ElectronicKey

    io = enip_farm(name="io", model="DSQC1030")["io"]
    key = ElectronicKey(75, 7, 1030, 1, 1, False)
    with RawClient(io.address) as c:
        c.register()
        io.inject("identity")
        reply = c.request(forward_open(key=key)[0])
        assert reply.general_status == 1 and reply.additional_status == (0x0114,)
        assert c.get(1, 1, 3).data == (1031).to_bytes(2, "little")
        io.clear_faults("identity")
        assert c.request(forward_open(key=key, path=ASSEMBLY_PATH)[0]).general_status == 0


def _eventually(predicate, timeout: float = 5.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.01)
    return False


# -- wiring and rules --------------------------------------------------------------------------------

CELL = {
    "devices": [{"name": "harness", "model": "DSQC1030"},
                {"name": "robot1", "model": "DSQC1030", "addons": ["DSQC1032"]}],
    "wires": [{"from": "harness.DO1-16", "to": "robot1.DI1-16"}],
    "rules": [{"when": "harness.DO16", "edge": "falls", "set": "robot1.DI1", "value": 1, "delay_ms": 100}],
}


def test_wiring_end_to_end_with_pycomm3(enip_farm) -> None:
    farm = enip_farm(CELL)
    with CIPDriver(farm["harness"].address) as harness, CIPDriver(farm["robot1"].address) as robot:
        assert harness.generic_message(**set_outputs(b"\x05\x80")).error is None
        read = robot.generic_message(service=Services.get_attribute_single, class_code=4, instance=101,
                                     attribute=3, connected=False, route_path=False)
        assert read.value[:2] == b"\x05\x80"  # already wired when the write was acknowledged
        assert harness.generic_message(**set_outputs(b"\x00\x00")).error is None  # DO16 falls
        farm["robot1"].wait_for(lambda d: d.get("DI1") == 1, timeout=10)  # the rule, 100 ms later
    # when, by the farm's own clock (a loaded test thread may look late, the farm's timestamps do not)
    wired = farm["robot1"].events("wired")
    (fall,) = [e for e in wired if e.text == f"robot1.DI1-16 = {[0] * 16} (wire from harness.DO1-16)"]
    (rule,) = [e for e in wired if e.text == "robot1.DI1 = 1 (rule: harness.DO16 falls, after 100 ms)"]
    assert 99_000_000 <= rule.monotonic_ns - fall.monotonic_ns < 2_000_000_000


def test_analog_wire(enip_farm) -> None:
    farm = enip_farm({"devices": [{"name": "a", "model": "DSQC1030", "addons": ["DSQC1032"]},
                                  {"name": "b", "model": "DSQC1030", "addons": ["DSQC1032"]}],
                      "wires": [{"from": "a.AO1-2", "to": "b.AI3-4"}]})
    farm["a"].set(AO1=1500, AO2=-7)
    assert farm["b"].get("AI3-4") == [1500, -7]


@pytest.mark.parametrize(("wiring", "message"), [
    ({"wires": [{"from": "a.DO1-8", "to": "b.DI1-8"}],
      "rules": [{"when": "b.DI1", "set": "a.DI1"}, {"when": "a.DI1", "set": "a.DO1"}]},
     "wiring cycle: a.inputs -> a.outputs -> b.inputs -> a.inputs"),
    ({"wires": [{"from": "a.DO1-8", "to": "b.DI1-7"}]},
     "wire a.DO1-8 -> b.DI1-7: both ends need the same kind and number of signals"),
    ({"wires": [{"from": "a.DI1-8", "to": "b.DI1-8"}]},
     "wire a.DI1-8 -> b.DI1-8: wires go from outputs (DO, AO) to inputs (DI, AI)"),
    ({"wires": [{"from": "a.DO1-8", "to": "c.DI1-8"}]}, "wire a.DO1-8 -> c.DI1-8: 'c.DI1-8': no device named 'c'"),
    ({"wires": [{"from": "a.DO17", "to": "b.DI1"}]},
     "wire a.DO17 -> b.DI1: 'a.DO17': DO17: this device has 16 DO signals"),
])
def test_bad_wiring_is_refused_at_load(free_address: AddressPool, wiring: dict, message: str) -> None:
    devices = [{"name": n, "address": free_address(), "model": "DSQC1030"} for n in ("a", "b")]
    with pytest.raises(ConfigError) as error:
        build_profiles(parse_config({"devices": devices, **wiring}), shipped_catalogue())
    assert str(error.value) == f"<config>: {message}"


# -- HTTP API and CLI --------------------------------------------------------------------------------


def test_http_api(enip_farm) -> None:
    farm = enip_farm(CELL, http=True)
    base = f"http://127.0.0.1:{farm.http.port}"
    devices = httpx.get(f"{base}/devices").json()
    assert [d["name"] for d in devices] == ["harness", "robot1"]
    assert devices[1]["identity"]["vendor_id"] == 75 and devices[1]["input_size"] == 10
    io = httpx.put(f"{base}/devices/harness/io", json={"signals": {"DO1": 1, "DO3": 1}}).json()
    assert io["outputs"] == "0500" and io["signals"]["DO"][:3] == [1, 0, 1]
    assert httpx.get(f"{base}/devices/robot1/io").json()["signals"]["DI"][:3] == [1, 0, 1]  # wired
    assert httpx.put(f"{base}/devices/robot1/io", json={"signals": {"AI2": 321}}).json()["signals"]["AI"][1] == 321
    assert httpx.put(f"{base}/devices/robot1/io", json={"signals": {"DI99": 1}}).status_code == 422
    assert httpx.get(f"{base}/devices/nobody/io").status_code == 404
    created = httpx.post(f"{base}/devices/harness/faults", json={"kind": "status", "service": 14, "status": 8})
    assert created.status_code == 201 and created.json()[0]["kind"] == "status"
    with CIPDriver(farm["harness"].address) as driver:
        assert driver.generic_message(**GET_OUTPUTS).error == "Service not supported"
    assert httpx.delete(f"{base}/devices/harness/faults").json() == {"cleared": ["status"]}
    metrics = httpx.get(f"{base}/metrics").text
    assert metric_samples(metrics, "enip_farm_requests_total") == {
        (("device", "harness"), ("service", "0x0E"), ("status", "0x08")): 1.0}
    assert metric_samples(metrics, "enip_farm_request_seconds_count") == {(("device", "harness"),): 2.0,
                                                                         (("device", "robot1"),): 0.0}
    assert "/devices/{name}/faults" in httpx.get(f"{base}/openapi.json").json()["paths"]


def test_http_event_stream(enip_farm) -> None:
    farm = enip_farm(name="io", model="DSQC1030", http=True)
    base = f"http://127.0.0.1:{farm.http.port}"
    received = []
    with ApiClient(base, timeout=5) as client, client.events({"kind": ["request", "fault injected"]}, 5) as events:
        with RawClient(farm["io"].address) as c:  # the stream is open (subscribed) once its headers are in
            c.register()
            c.get(1, 1, 7)
        farm["io"].inject("drop", duration_s=0.1)
        for event in events:
            received.append(event.json())
            if len(received) == 2:
                break
    assert received[0]["kind"] == "request" and received[0]["detail"].startswith("service 0x0E path 20 01 24 01")
    assert received[1]["kind"] == "fault injected" and received[1]["detail"] == {"kind": "drop", "duration_s": 0.1}


def test_http_token_off_loopback(free_address: AddressPool, enip_farm) -> None:
    from enip_farm.farm.farm import BindError, Farm

    config = parse_config({"devices": [{"name": "io", "address": free_address(), "model": "DSQC1030"}],
                           "discovery": False})
    # every address but loopback needs a token; refused before anything binds
    with pytest.raises(BindError, match=r"the HTTP API on 0\.0\.0\.0 needs a token"), \
            Farm(config, http=("0.0.0.0", 0)).running_in_thread():
        pass
    host = free_address()  # a loopback address other than 127.0.0.1 (as --http 127.0.10.1:8044): no token needed
    farm = Farm(config, http=(host, 0))
    with farm.running_in_thread():
        assert httpx.get(f"http://{host}:{farm.http.port}/devices").status_code == 200
    farm = Farm(config, http=(host, 0), token="s3cret")  # given one, it is required there too
    with farm.running_in_thread():
        url = f"http://{host}:{farm.http.port}/devices"
        assert httpx.get(url).status_code == 401
        assert httpx.get(url, headers={"Authorization": "Bearer wrong"}).status_code == 401
        assert httpx.get(url, headers={"Authorization": "Bearer s3cret"}).status_code == 200


@pytest.mark.system
def test_cli_drives_a_running_farm(free_address: AddressPool, tmp_path) -> None:
    address = free_address()
    config = tmp_path / "cell.yaml"
    config.write_text(f"devices:\n  - {{name: io1, address: {address}, model: DSQC1030}}\ndiscovery: false\n")
    # port 0: the system picks a free port, the farm says which (no probe-then-reuse race)
    with serving(["serve", "--config", str(config), "--http", "0"], table_rows=1) as (server, _):
        said = read_lines(server.stderr, 2)  # "1 device listening ...", "HTTP API on http://127.0.0.1:PORT"
        (api,) = [line.split()[-1] for line in said if line.startswith("HTTP API on ")]
        assert api.startswith("http://127.0.0.1:") and not api.endswith(":0"), said
        _drive_with_the_cli(address, api)
        server.terminate()
        assert server.wait(timeout=STARTUP_S) == 0


def _drive_with_the_cli(address: str, api: str) -> None:
    env = {**os.environ, "ENIP_FARM_API": api}

    def run(*args: str) -> str:
        result = subprocess.run([*CLI, *args], capture_output=True, text=True, env=env, timeout=60)
        assert result.returncode == 0, result.stderr
        return result.stdout

    assert "DI      DI1=0 DI2=0 DI3=1" in run("io", "set", "io1", "DI3=1")
    assert "inputs  0400" in run("io", "get", "io1")
    assert "active faults: status" in run("fault", "io1", "status", "--service", "0x0E", "--status", "0x08")
    with CIPDriver(address) as driver:
        assert driver.generic_message(**GET_OUTPUTS).error == "Service not supported"
    assert "cleared status" in run("fault", "clear", "io1")
    failed = subprocess.run([*CLI, "io", "get", "nobody"], capture_output=True, text=True, env=env, timeout=60)
    assert failed.returncode == 1 and "404" in failed.stderr


def test_udp_list_identity_still_answers_after_faults_clear(enip_farm) -> None:
    io = enip_farm(name="io", model="DSQC1030")["io"]
    io.inject("offline")
    io.clear_faults()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as udp:
        udp.settimeout(10)
        udp.sendto(encode_frame(Command.LIST_IDENTITY), (io.address, 44818))
        assert decode_frame(udp.recv(1024)).header.command == Command.LIST_IDENTITY


@pytest.mark.anyio
async def test_plugin_from_an_async_test(enip_farm) -> None:
    """The same fixture from an async test: an asyncio client, and an awaitable wait."""
    import asyncio

    from enip_farm.protocol.commands import encode_send_rr_data

    io = enip_farm(name="io", model="DSQC1030")["io"]
    reader, writer = await asyncio.open_connection(io.address, 44818)
    writer.write(encode_frame(Command.REGISTER_SESSION, b"\x01\x00\x00\x00"))
    handle = int.from_bytes((await reader.readexactly(28))[4:8], "little")
    writer.write(encode_send_rr_data(bytes.fromhex("10 03 20 04 24 64 30 03 20 00"), handle))
    assert (await reader.readexactly(44))[-4:] == b"\x90\x00\x00\x00"
    await io.until(lambda d: d.get("DO6") == 1, timeout=10)
    writer.close()
    await writer.wait_closed()
    assert [e.kind for e in io.events() if e.kind.startswith("session")][:1] == ["session registered"]


@pytest.fixture
def anyio_backend() -> str:
    return "asyncio"
