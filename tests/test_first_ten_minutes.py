"""A new user's first ten minutes, item by item: configuration problems all reported one line each
(duplicates, wiring, subnets, YAML booleans), digital values other than 0 or 1 refused on every
path, CLI errors that name the flag and say how to start the HTTP API, `Farm` built from a dict or
a path, every counter there from the start, fault events as JSON, and the benchmarks' small runs.
(The quick start and every README example run in tests/test_readme.py.)"""

from __future__ import annotations

import ast
import asyncio
import json
import re
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest
import yaml
from click.testing import CliRunner

from enip_farm.cli import main
from enip_farm.config import ConfigError, load_config, parse_config
from enip_farm.device.build import build_profiles
from enip_farm.device.catalogue import shipped_catalogue
from enip_farm.device.device import COUNTERS
from enip_farm.device.faults import Fault
from enip_farm.device.signals import SignalError
from enip_farm.farm.farm import Farm
from enip_farm.pytest_plugin import AddressPool
from tests.helpers import ROOT

PACKAGE = ROOT / "enip_farm"


def _problems(data: dict, source: str = "cell.yaml") -> list[str]:
    with pytest.raises(ConfigError) as error:
        build_profiles(parse_config(data, source), shipped_catalogue())
    return str(error.value).splitlines()


# -- configuration -------------------------------------------------------------------------------------


def test_every_duplicate_is_one_line() -> None:
    lines = _problems({"devices": [
        {"name": "a", "address": "127.0.0.3", "model": "DSQC1030"},
        {"name": "a", "address": "127.0.0.4", "model": "DSQC1030"},
        {"name": "b", "address": "127.0.0.4", "model": "DSQC1030"},
        {"name": "c", "address": "127.0.0.4", "model": "DSQC1030"},
        {"name": "io{n}", "address": "127.0.0.2", "count": 3, "model": "DSQC1030"},  # io1..io3 on .2 .. .4
    ]})
    assert lines == [
        "cell.yaml: device 'a' (devices[1]), name: a is taken by device 'a' (devices[0])",
        "cell.yaml: device 'b' (devices[2]), address: 127.0.0.4 is taken by device 'a' (devices[1]) (here by 'b')",
        "cell.yaml: device 'c' (devices[3]), address: 127.0.0.4 is taken by device 'a' (devices[1]) (here by 'c')",
        "cell.yaml: device 'io{n}' (devices[4]), address: 127.0.0.3 is taken by device 'a' (devices[0]) "
        "(here by 'io2')",
        "cell.yaml: device 'io{n}' (devices[4]), address: 127.0.0.4 is taken by device 'a' (devices[1]) "
        "(here by 'io3')",
    ]


def test_every_wiring_problem_and_cycle_is_one_line() -> None:
    devices = [{"name": n, "address": f"127.0.0.{i}", "model": "DSQC1030"} for i, n in enumerate("abd", 3)]
    devices.append({"name": "c", "address": "127.0.0.9", "model": "DSQC9999"})
    lines = _problems({"devices": devices, "wires": [
        {"from": "a.DO1", "to": "b.DI99"},
        {"from": "a.DO1", "to": "zz.DI1"},
        {"from": "a.DI1-8", "to": "b.DI1-8"},
        {"from": "a.DO1-8", "to": "b.DI1-8"},
        {"from": "b.DO1-8", "to": "a.DI1-8"},
        {"from": "c.DO1", "to": "a.DI9"},  # c cannot be built: told once, its wire not again
        {"from": "d.DO1", "to": "d.DI1"},
    ], "rules": [
        {"when": "a.DI1", "set": "a.DO9"},
        {"when": "b.DI1", "set": "b.DO9"},  # with a's rule, closes a -> b -> a
        {"when": "d.DI2", "set": "d.DO2"},  # closes d -> d
        {"when": "b.DI1-2", "set": "b.DO9"},
    ]})
    assert lines == [
        "cell.yaml: device 'c' (devices[3]), model: unknown base model 'DSQC9999'; known: "
        + ", ".join(shipped_catalogue().bases()),
        "cell.yaml: wire a.DO1 -> b.DI99: 'b.DI99': DI99: this device has 16 DI signals",
        "cell.yaml: wire a.DO1 -> zz.DI1: 'zz.DI1': no device named 'zz'",
        "cell.yaml: wire a.DI1-8 -> b.DI1-8: wires go from outputs (DO, AO) to inputs (DI, AI)",
        "cell.yaml: rule b.DI1-2 -> b.DO9: a rule watches one bit and sets one bit",
        "cell.yaml: wiring cycle: a.inputs -> a.outputs -> b.inputs -> b.outputs -> a.inputs",
        "cell.yaml: wiring cycle: d.inputs -> d.outputs -> d.inputs",
    ]


@pytest.mark.parametrize(("entry", "expected"), [
    ({"address": "127.0.1.250", "count": 10},
     "count 10 from 127.0.1.250 runs past the subnet 127.0.1.0/24 (netmask 255.255.255.0): the addresses would end "
     "at 127.0.2.3, the last host is 127.0.1.254; start lower, use fewer, or widen the netmask"),
    ({"address": "127.0.1.250", "count": 6},  # .250 .. .255: the broadcast address is one of them
     "count 6 from 127.0.1.250 runs past the subnet 127.0.1.0/24"),
    ({"address": "127.0.2.0"},
     "address 127.0.2.0 is the network address of the subnet 127.0.2.0/24 (netmask 255.255.255.0): no device can "
     "have it; choose a host address (127.0.2.1 .. 127.0.2.254)"),
    ({"address": "127.0.2.255"}, "address 127.0.2.255 is the broadcast address of the subnet 127.0.2.0/24"),
    ({"address": "10.1.0.0", "netmask": "255.255.0.0"}, "address 10.1.0.0 is the network address of the subnet "
                                                        "10.1.0.0/16"),
    ({"address": "127.0.4.0", "count": 3}, "count 3 from 127.0.4.0 starts at the network address of the subnet "
                                           "127.0.4.0/24 (netmask 255.255.255.0): start at 127.0.4.1"),
    ({"address": "127.0.3.4", "netmask": "255.0.255.0"}, "netmask: 255.0.255.0 is not a netmask"),
])
def test_addresses_beyond_the_subnet_are_refused(entry: dict, expected: str) -> None:
    (line,) = _problems({"devices": [{"name": "io{n}", "model": "DSQC1030", **entry}]})
    assert line.startswith("cell.yaml: device 'io{n}' (devices[0])") and expected in line, line


@pytest.mark.parametrize("entry", [
    {"address": "127.0.1.245", "count": 10},  # .245 .. .254
    {"address": "127.0.1.250", "count": 10, "netmask": "255.255.0.0"},  # across /24s of a /16
    {"address": "127.0.2.255", "netmask": "255.255.0.0"},
    {"address": "192.168.1.0", "netmask": "255.255.255.255"},  # a /32 (and /31) has no network or broadcast address
])
def test_addresses_inside_the_subnet_are_taken(entry: dict) -> None:
    build_profiles(parse_config({"devices": [{"name": "io{n}", "model": "DSQC1030", **entry}]}), shipped_catalogue())


def test_unquoted_off_gets_a_hint(tmp_path: Path) -> None:
    path = tmp_path / "cell.yaml"
    path.write_text("devices:\n  - name: io1\n    address: 127.0.0.5\n    model: DSQC1030\n"
                    "    implicit: {idle_state: off, fault_state: hold}\n")
    assert yaml.safe_load(path.read_text())["devices"][0]["implicit"]["idle_state"] is False  # what YAML makes of it
    with pytest.raises(ConfigError) as error:
        load_config(path)
    assert str(error.value) == (
        f"{path}:5: device 'io1' (devices[0]), implicit.idle_state: Input should be 'off' or 'hold' (YAML reads an "
        'unquoted off, no as false: quote the value, e.g. "off")')
    path.write_text(path.read_text().replace("idle_state: off", 'idle_state: "off"'))
    load_config(path)


# -- the Python API ------------------------------------------------------------------------------------


def test_farm_takes_a_dict_or_a_path(tmp_path: Path) -> None:
    data = {"devices": [{"name": "io1", "address": "127.0.0.5", "model": "DSQC1030"}], "discovery": False}
    path = tmp_path / "cell.yaml"
    path.write_text(yaml.safe_dump(data))
    for config in (data, str(path), path, load_config(path)):
        farm = Farm(config)  # built, not started: no socket
        assert list(farm.devices) == ["io1"] and farm.config.discovery is False
    with pytest.raises(ConfigError, match=r"^<config>: device 'io1' \(devices\[0\]\), model: unknown base model "
                                          r"'nope'; known: DSQC1030, DSQC1042, GenericAdapter$"):
        Farm({"devices": [{"name": "io1", "address": "127.0.0.5", "model": "nope"}]})
    with pytest.raises(TypeError, match="^a configuration is a FarmConfig, a dict or a file path, not int$"):
        Farm(42)  # type: ignore[arg-type]


def test_every_counter_is_there_from_the_start() -> None:
    farm = Farm({"devices": [{"name": "io1", "address": "127.0.0.5", "model": "DSQC1030"}]})
    counters = farm["io1"].counters
    assert counters["tcp_connections"] == 0
    assert {name: counters[name] for name in COUNTERS} == dict.fromkeys(COUNTERS, 0)
    # and every counter the package counts is one of them (literal names and the O->T drop reasons)
    counted = set()
    for path in PACKAGE.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if (isinstance(node, ast.Subscript) and isinstance(node.value, ast.Attribute)
                    and node.value.attr == "counters" and isinstance(node.slice, ast.Constant)):
                counted.add(node.slice.value)
    assert counted and counted <= set(COUNTERS), counted - set(COUNTERS)


def test_fault_events_carry_json() -> None:
    farm = Farm({"devices": [{"name": "io1", "address": "127.0.0.5", "model": "DSQC1030"}]})
    asyncio.run(farm.inject_fault("io1", Fault("delay", delay_ms=800, duration_s=5)))
    asyncio.run(farm.clear_faults("io1"))
    injected, cleared = farm["io1"].events("fault injected") + farm["io1"].events("fault cleared")
    assert json.loads(json.dumps(injected.as_dict()))["detail"] == {"kind": "delay", "delay_ms": 800.0,
                                                                    "duration_s": 5.0}
    assert json.loads(json.dumps(cleared.as_dict()))["detail"] == {"kind": "delay"}
    assert injected.text == "delay (delay_ms 800, duration_s 5)"


# -- digital values, on every path ------------------------------------------------------------------


def test_a_digital_value_is_0_or_1_on_every_path(enip_farm) -> None:
    farm = enip_farm(name="io1", model="DSQC1030", http=True)
    io1 = farm["io1"]
    with pytest.raises(SignalError, match="DI3: a digital signal is 0 or 1, got 2"):
        io1.set(DI3=2)
    api = f"http://127.0.0.1:{farm.http.port}"
    for signals, expected in [({"DI3": 2}, "DI3: a digital signal is 0 or 1, got 2"),
                              ({"DI1-2": [1, 2]}, "DI1-2: a digital signal is 0 or 1, got 2"),
                              ({"DI3": "1"}, "DI3: expected a number, or a list of integers for a range, got '1'"),
                              ({"DI3": True}, "DI3: expected a number, or a list of integers for a range, got True"),
                              ({"DI1-2": [1.0, 0]},
                               "DI1-2: expected a number, or a list of integers for a range, got [1.0, 0]")]:
        response = httpx.put(f"{api}/devices/io1/io", json={"signals": signals}, timeout=10)
        detail = response.json()["detail"]  # the handler's message, or the request model's validation errors
        messages = [detail] if isinstance(detail, str) else [e["msg"].removeprefix("Value error, ") for e in detail]
        assert response.status_code == 422 and messages == [expected], (signals, detail)
    result = CliRunner().invoke(main, ["io", "set", "io1", "DI3=2", "--api", api])
    assert result.exit_code == 1
    assert result.output == "PUT /devices/io1/io: 422 DI3: a digital signal is 0 or 1, got 2\n"
    assert io1.inputs == b"\x00\x00"  # nothing was written by any of them


# -- the CLI's messages ------------------------------------------------------------------------------


@pytest.mark.parametrize(("args", "expected"), [
    (["delay"], "fault io1 delay: --delay-ms: a delay fault needs --delay-ms > 0 (and optionally --max-delay-ms) "
                "(e.g. --delay-ms 800)"),
    (["delay", "--delay-ms", "800", "--max-delay-ms", "10"],
     "fault io1 delay: --max-delay-ms: must not be below --delay-ms (800), got 10"),
    (["status", "--service", "0x0E"], "fault io1 status: --status: a status fault needs a service and a status (e.g. "
                                      "--service 0x0E --status 0x08)"),
    (["drop", "--duration", "-1"], "fault io1 drop: --duration: must be > 0, got -1"),
])
@pytest.mark.integration
def test_fault_errors_are_one_line_naming_the_flag(enip_farm, args: list[str], expected: str) -> None:
    farm = enip_farm(name="io1", model="DSQC1030", http=True)  # the kinds and their checks are the farm's
    result = CliRunner().invoke(main, ["fault", "io1", *args, "--api", f"http://127.0.0.1:{farm.http.port}"])
    assert result.exit_code == 2 and result.output == expected + "\n", result.output
    assert farm["io1"].faults == []


@pytest.mark.integration
@pytest.mark.parametrize("command", [["io", "get", "io1"], ["fault", "io1", "drop"]])
def test_the_cli_says_to_start_serve_http(command: list[str]) -> None:
    with socket.socket() as probe:  # a port nothing listens on (bound, never listened)
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
        result = CliRunner().invoke(main, [*command, "--api", f"http://127.0.0.1:{port}"])
    assert result.exit_code == 1
    assert result.output == (
        f"cannot reach the farm's HTTP API at http://127.0.0.1:{port} (Connection refused): is the farm running with "
        f"its HTTP API? Start it with `enip-farm serve --http {port}`, or give the API's address with --api (or "
        "ENIP_FARM_API).\n")


# -- the benchmarks' small runs ---------------------------------------------------------------------


@pytest.mark.system
def test_bench_explicit_with_few_requests(free_address: AddressPool) -> None:
    """200 requests take less than a clock tick of CPU: the CPU ratios say n/a, nothing divides by 0."""
    result = subprocess.run(
        [sys.executable, str(ROOT / "bench" / "bench_explicit.py"), "--requests", "200", "--rounds", "1",
         "--connects", "20", "--server-cpu", "0", "--client-cpu", "0", "--farm-host", free_address(),
         "--minimal-host", free_address()], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert result.returncode == 0, result.stderr
    rows = {line.split()[0]: line.split()[1:] for line in result.stdout.splitlines()[2:] if "_" in line.split()[0]}
    assert set(rows) >= {"rtt_p50_us", "cpu_us_per_request_sequential", "cpu_us_per_request_aggregate"}
    for values in rows.values():
        assert len(values) == 3 and re.fullmatch(r"\d+\.\d\d|n/a", values[2]), values


@pytest.mark.system
def test_bench_implicit_sweep_honours_seconds_and_says_how_far_it_is(free_address: AddressPool) -> None:
    started = time.monotonic()
    result = subprocess.run(
        [sys.executable, str(ROOT / "bench" / "bench_implicit.py"), "--sweep", "1", "--seconds", "0.3", "--farm-cpu",
         "0", "--client-cpu", "0", "--first-address", free_address()], capture_output=True, text=True, timeout=300,
        cwd=ROOT)
    elapsed = time.monotonic() - started
    assert result.returncode == 0, result.stderr
    # 8 RPIs of 0.3 s, not of 10 s: well under the 80 s the sweep took whatever --seconds said
    assert 8 * 0.3 <= elapsed < 60, elapsed
    progress = result.stderr.splitlines()
    assert [line.split(":")[0] for line in progress] == [f"run {n}/8" for n in range(1, 9) for _ in (0, 1)]
    assert progress[0] == "run 1/8: 1 connections at RPI 10 ms for 0.3 s ..."
    assert re.fullmatch(r"run 1/8: error p99 \d+\.\d{3} ms, \d+ late, \d+ timeouts, farm CPU \d+%", progress[1])
    assert len(result.stdout.splitlines()) == 1 + 8  # the header and one row per RPI
