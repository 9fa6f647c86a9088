"""Nothing stops the farm's cyclic I/O (issue: one request stopped every device's T->O): waits
handed to the OS are bounded, Forward Open RPIs and timeout multipliers are checked for every
transport class, the cyclic I/O thread supervises its loop, and the farm's health (the API's
/health, /metrics, the container's heartbeat file) says when class-1 I/O is not running."""

from __future__ import annotations

import logging
import math
import os
import subprocess
import time
from pathlib import Path

import httpx
import pytest

from enip_farm.config import parse_config
from enip_farm.farm.farm import SUPERVISE_S, Farm
from enip_farm.protocol.connection import decode_forward_open_reply
from enip_farm.server.waits import MAX_WAIT_S, os_wait_ns, os_wait_s
from tests.helpers import ROOT, RawClient, metric_samples, wait_for
from tests.test_implicit import forward_close, forward_open

pytestmark = pytest.mark.class1_paths  # both class-1 paths (tests/conftest.py)

MESSAGE_ROUTER_PATH = bytes.fromhex("20 02 24 01")
CLASS_3 = 0xA3  # class 3, application triggered, server


# -- bounds where the core meets the OS -------------------------------------------------------------


@pytest.mark.parametrize(("seconds", "expected"), [
    (0.25, 0.25), (0.0, 0.0), (-1.0, 0.0), (math.nan, 0.0), (MAX_WAIT_S, MAX_WAIT_S),
    (MAX_WAIT_S + 0.001, MAX_WAIT_S), (0xFFFFFFFF * 512 / 1e6, MAX_WAIT_S), (math.inf, MAX_WAIT_S)])
def test_os_waits_are_bounded(seconds: float, expected: float) -> None:
    assert os_wait_s(seconds) == expected


def test_the_timeout_of_the_largest_rpi_is_waited_for_in_bounded_steps() -> None:
    timeout_ns = 0xFFFFFFFF * 1000 << 9  # RPI 0xFFFFFFFF us x 512: about 25 days
    assert os_wait_ns(timeout_ns) == MAX_WAIT_S
    assert os_wait_ns(1_500_000) == 0.0015


# -- Forward Open: RPI and timeout multiplier, every transport class ----------------------------------


def _status(client: RawClient, message: bytes) -> tuple[int, tuple[int, ...]]:
    reply = client.request(message)
    assert reply.service == message[0] | 0x80
    return reply.general_status, tuple(reply.additional_status)


@pytest.mark.integration
@pytest.mark.parametrize(("kwargs", "extended"), [
    ({"transport": CLASS_3, "path": MESSAGE_ROUTER_PATH, "rpi": 0xFFFFFFFF, "multiplier": 7}, 0x0111),  # the issue's
    ({"transport": CLASS_3, "path": MESSAGE_ROUTER_PATH, "rpi": 0}, 0x0111),
    ({"transport": CLASS_3, "path": MESSAGE_ROUTER_PATH, "rpi": 999}, 0x0111),
    ({"transport": CLASS_3, "path": MESSAGE_ROUTER_PATH, "rpi": 60_000_001}, 0x0111),
    ({"transport": CLASS_3, "path": MESSAGE_ROUTER_PATH, "rpi": 2_000_000, "t_o_rpi": 1}, 0x0111),
    ({"transport": CLASS_3, "path": MESSAGE_ROUTER_PATH, "rpi": 2_000_000, "multiplier": 8}, 0x0205),
    ({"rpi": 0}, 0x0111),
    ({"rpi": 20_000, "t_o_rpi": 1}, 0x0111),
    ({"rpi": 20_000, "multiplier": 255}, 0x0205),
])
def test_forward_open_rpi_and_multiplier_are_checked(make_farm, kwargs: dict, extended: int) -> None:
    farm = make_farm({"name": "io1", "model": "DSQC1030"})
    device = farm.device("io1")
    with RawClient(device.profile.address) as client:
        client.register()
        message, _ = forward_open(o_t_size=500 if "path" in kwargs else 8, t_o_size=500 if "path" in kwargs else 4,
                                  variable="path" in kwargs, **kwargs)
        assert _status(client, message) == (0x01, (extended,))
        assert not device.connections
        assert client.get(4, 100, 3).general_status == 0  # the session stays usable


@pytest.mark.integration
@pytest.mark.parametrize("rpi", [1_000, 2_113_537, 60_000_000])  # 2_113_537: pycomm3's
def test_class3_rpis_in_range_are_accepted(make_farm, rpi: int) -> None:
    farm = make_farm({"name": "io1", "model": "DSQC1030"})
    with RawClient(farm.device("io1").profile.address) as client:
        client.register()
        message, triad = forward_open(path=MESSAGE_ROUTER_PATH, transport=CLASS_3, rpi=rpi, multiplier=7,
                                      o_t_size=500, t_o_size=500, variable=True)
        assert _status(client, message) == (0, ())
        assert _status(client, forward_close(triad, MESSAGE_ROUTER_PATH)) == (0, ())


def _t_o_rate(device, seconds: float) -> tuple[int, float]:
    """T->O packets the device produced in a window the test measures itself, and its length."""
    start, before = time.monotonic(), device.counters["t_o_packets"]
    time.sleep(seconds)
    return device.counters["t_o_packets"] - before, time.monotonic() - start


@pytest.mark.integration
def test_a_25_day_timeout_on_one_device_leaves_every_device_producing(make_farm) -> None:
    """The issue's three-device cell: a connection whose timeout is about 25 days (a class-1 RPI of
    0xFFFFFFFF us, x512, which this device's configuration allows) on A; B's class-1 connection,
    opened afterwards, gets its T->O at its RPI and the thread runs on."""
    farm = make_farm({"name": "a", "model": "DSQC1030", "implicit": {"rpi_max_us": 0xFFFFFFFF}},
                     {"name": "b", "model": "DSQC1030", "implicit": {"first_watchdog_s": 30}},
                     {"name": "c", "model": "DSQC1030"})
    a, b = farm.device("a"), farm.device("b")
    with RawClient(a.profile.address) as client:
        client.register()
        assert _status(client, forward_open(rpi=0xFFFFFFFF, multiplier=7)[0]) == (0, ())
        (huge,) = a.connections.values()
        assert huge.timeout_ns == 0xFFFFFFFF * 1000 * 512
        with RawClient(b.profile.address) as other:
            other.register()
            reply = other.request(forward_open(rpi=20_000, multiplier=7)[0])  # 20 ms x 512: 10 s
            assert reply.general_status == 0
            decode_forward_open_reply(reply.data)
            produced, elapsed = _t_o_rate(b, 2.0)
            periods = elapsed / 0.020
            assert periods * 0.5 <= produced <= periods + 2, (produced, elapsed)  # at its RPI: not stopped, no burst
            assert farm.health()["ok"] and farm.health()["cyclic_io"] == {"running": True, "errors": 0,
                                                                            "device_errors": 0}


# -- the cyclic I/O thread is supervised -------------------------------------------------------------


@pytest.mark.integration
def test_an_error_of_the_cyclic_io_loop_is_counted_logged_once_and_the_loop_goes_on(
        enip_farm, caplog: pytest.LogCaptureFixture) -> None:
    farm = enip_farm({"devices": [{"name": "io1", "model": "DSQC1030", "implicit": {"first_watchdog_s": 30}}]},
                     http=True)
    device = farm.device("io1")
    thread = farm._implicit.thread  # the loop's own code, not a device's (those have io_errors)
    failures = iter([RuntimeError("a bug in the cyclic I/O loop")])
    schedule = thread._schedule

    def failing_once(endpoint, timer):
        for error in failures:
            raise error
        return schedule(endpoint, timer)

    with RawClient(device.profile.address) as client:
        client.register()
        assert client.request(forward_open(rpi=20_000, multiplier=7)[0]).general_status == 0
        caplog.set_level(logging.ERROR, "enip_farm.server.implicit")
        thread._schedule = failing_once
        thread.reschedule(farm._implicit.endpoints[0])
        assert wait_for(lambda: thread.loop_errors == 1)
        produced, elapsed = _t_o_rate(device, 2.0)  # long enough that a loaded machine does not stall it by half
        periods = elapsed / 0.020
        assert periods * 0.5 <= produced <= periods + 2, (produced, elapsed)
    assert thread.is_alive() and thread.loop_errors == 1
    (record,) = [r for r in caplog.records if r.name == "enip_farm.server.implicit"]
    assert record.getMessage() == "cyclic I/O thread: unexpected error (1 so far); the thread goes on"
    assert record.exc_info is not None and str(record.exc_info[1]) == "a bug in the cyclic I/O loop"
    api = f"http://127.0.0.1:{farm.http.port}"
    health = httpx.get(api + "/health")
    assert health.status_code == 200
    assert health.json() == {"ok": True, "failure": None, "loop_errors": 0,
                             "cyclic_io": {"running": True, "errors": 1, "device_errors": 0}}
    metrics = httpx.get(api + "/metrics").text
    assert metric_samples(metrics, "enip_farm_cyclic_io_running") == {(): 1.0}
    assert metric_samples(metrics, "enip_farm_cyclic_io_loop_errors_total") == {(): 1.0}
    assert metric_samples(metrics, "enip_farm_io_errors_total") == {(("device", "io1"),): 0.0}


@pytest.mark.integration
def test_a_farm_whose_cyclic_io_thread_ended_fails_and_says_so(enip_farm) -> None:
    farm = enip_farm({"devices": [{"name": "io1", "model": "DSQC1030"}]}, http=True)
    thread = farm._implicit.thread
    assert farm.health()["ok"] and not farm.failed.is_set()
    thread._stopping = True  # the thread ends as if an error had escaped it
    thread._wake()
    thread.join(5)
    ended = time.monotonic()
    assert not thread.is_alive()
    health = httpx.get(f"http://127.0.0.1:{farm.http.port}/health")
    assert health.status_code == 503
    assert health.json()["cyclic_io"]["running"] is False and health.json()["ok"] is False
    assert metric_samples(httpx.get(f"http://127.0.0.1:{farm.http.port}/metrics").text,
                          "enip_farm_cyclic_io_running") == {(): 0.0}
    assert wait_for(farm.failed.is_set, timeout=SUPERVISE_S * 10)  # `serve` exits 1 on it
    assert time.monotonic() - ended <= SUPERVISE_S * 10
    assert farm.failure == "the cyclic I/O thread has ended: no device sends T->O"


@pytest.mark.integration
def test_health_needs_no_token_where_everything_else_does(free_address) -> None:
    farm = Farm(parse_config({"devices": [{"name": "io1", "model": "DSQC1030", "address": free_address()}]}),
                http=("127.0.0.1", 0), token="s3cret")
    with farm.running_in_thread():
        api = f"http://127.0.0.1:{farm.http.port}"
        assert httpx.get(api + "/health").status_code == 200
        assert httpx.get(api + "/state").status_code == 401
        assert httpx.get(api + "/state", headers={"Authorization": "Bearer s3cret"}).status_code == 200


# -- the container's health check --------------------------------------------------------------------


@pytest.mark.system
def test_healthcheck_fails_once_the_heartbeat_stops(free_address, tmp_path: Path) -> None:
    address = free_address()
    heartbeat = tmp_path / "heartbeat"
    (tmp_path / "addresses").write_text(address + "\n")
    farm = Farm(parse_config({"devices": [{"name": "io1", "model": "DSQC1030", "address": address}]}),
                heartbeat=heartbeat)
    environment = {**os.environ, "ENIP_FARM_ADDRESS_FILE": str(tmp_path / "addresses"),
                   "ENIP_FARM_HEARTBEAT": str(heartbeat), "ENIP_FARM_HEARTBEAT_MAX_AGE": "2"}

    def check() -> subprocess.CompletedProcess:
        return subprocess.run(["bash", str(ROOT / "docker" / "healthcheck.sh")], env=environment,
                              capture_output=True, text=True, timeout=30)

    with farm.running_in_thread():
        assert wait_for(heartbeat.exists, timeout=SUPERVISE_S * 10)
        healthy = check()
        assert healthy.returncode == 0, healthy.stderr
        assert healthy.stdout == "1 device listens on TCP 44818, class-1 I/O running\n"
        thread = farm._implicit.thread
        thread._stopping = True
        thread._wake()
        thread.join(5)
        assert not thread.is_alive()
        # the check reads whole seconds (date +%s, stat %Y) and fails once `now - set > 2`: so it
        # passes while the file is under 2 s old and fails once it is 3 s old, whenever it was last set
        checks: list[tuple[float, float, int]] = []  # (wall clock before, after, exit status)
        for _ in range(3000):  # bounded: 30 s of checks at the most
            before = time.time()
            status = check().returncode
            checks.append((before, time.time(), status))
            if status == 1 or before - heartbeat.stat().st_mtime > 30:
                break
            time.sleep(0.01)
        set_at = heartbeat.stat().st_mtime  # no longer set: the I/O thread has stopped
        _, failing_after, status = checks[-1]
        assert status == 1, checks[-5:]
        assert failing_after - set_at > 2  # not before: it failed only once the file was over 2 s old
        assert all(before - set_at < 3 for before, _, _ in checks[:-1])  # not after: none passed past 3 s
        failing = check()
        assert failing.stderr.startswith(f"class-1 I/O is not running: {heartbeat} was last set ")
