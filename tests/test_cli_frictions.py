"""A new user's first hour with the CLI (issue 23): each friction they met, now fixed, one test each;
and the CLI's shape: commands that import their heavy modules only when they run."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import httpx
import pytest
import yaml
from click.testing import CliRunner

from enip_farm.cli import main
from enip_farm.control.client import ApiClient, encode_event
from enip_farm.device.catalogue import shipped_catalogue
from enip_farm.pytest_plugin import AddressPool
from enip_farm.words import plural
from tests.helpers import CLI, ROOT, STARTUP_S, serving, wait_for

SEED = ROOT / "captures" / "dsqc1030_explicit_session.pcap"


def _cell(tmp_path: Path, *addresses: str) -> Path:
    path = tmp_path / "cell.yaml"
    path.write_text(yaml.safe_dump({"devices": [{"name": f"io{i}", "address": address, "model": "DSQC1030"}
                                                for i, address in enumerate(addresses, 1)], "discovery": False}))
    return path


@pytest.mark.system
def test_ctrl_c_on_workers_with_http_is_quiet_and_the_banner_shows_the_dashboard(free_address: AddressPool,
                                                                                 tmp_path: Path) -> None:
    config = _cell(tmp_path, *(free_address() for _ in range(4)))
    log = tmp_path / "serve.log"
    with log.open("w") as stderr, serving(["serve", "--config", str(config), "--workers", "2", "--http", "0"],
                                          table_rows=4, stderr=stderr, start_new_session=True) as (server, table):
        assert [row.split()[0] for row in table] == ["NAME", "io1", "io2", "io3", "io4"]  # the config's order
        assert wait_for(lambda: "dashboard on " in log.read_text(), timeout=STARTUP_S), log.read_text()
        banner = log.read_text().splitlines()
        api = banner[1].split()[3]
        assert banner[:3] == [
            f"4 devices listening on TCP and UDP 44818 in 2 workers, from {config}. Ctrl-C to stop.",
            f"HTTP API on {api} (the devices of both workers)",
            f"dashboard on {api}/ and API docs on {api}/docs; `enip-farm io` and `enip-farm fault` use this API "
            f"with --api {api}"]
        for _ in range(3):  # proxied requests: none of them is a console line
            assert httpx.get(f"{api}/devices/io2/io", timeout=STARTUP_S).status_code == 200
        with httpx.stream("GET", f"{api}/events", timeout=STARTUP_S) as stream:  # open at Ctrl-C
            assert stream.status_code == 200
            os.killpg(server.pid, signal.SIGINT)  # what a terminal's Ctrl-C does: the whole group
            assert server.wait(timeout=STARTUP_S) == 0
    said = log.read_text()
    assert "Traceback" not in said and "CancelledError" not in said and "HTTP Request" not in said, said
    assert len(said.splitlines()) == 5, said  # the banner and the two workers' budgets: nothing else


@pytest.mark.integration
def test_golden_runs_beside_a_farm_serving_the_same_cell(enip_farm, tmp_path: Path) -> None:
    """The README's golden example beside the README's running cell: golden serves the cell on
    loopback addresses of its own (issue 30)."""
    farm = enip_farm(name="io1", model="DSQC1030")
    result = CliRunner().invoke(main, ["golden", str(SEED), "--config", str(_cell(tmp_path, farm["io1"].address)),
                                       "--device", "io1"])
    assert (result.exit_code, result.output.splitlines()[-1]) == (0, "4 exchanges: 4 passed, 0 failed"), result.output
    # a cell on a controller's addresses (not this host's, RFC 5737 here): golden serves it on its own
    elsewhere = CliRunner().invoke(main, ["golden", str(SEED), "--config", str(_cell(tmp_path, "203.0.113.7"))])
    assert (elsewhere.exit_code, elsewhere.output.splitlines()[-1]) == (0, "4 exchanges: 4 passed, 0 failed")


@pytest.mark.integration
def test_golden_where_nothing_answers_is_one_line_and_exit_1(free_address: AddressPool) -> None:
    address = free_address()  # nothing listens there
    result = CliRunner().invoke(main, ["golden", str(SEED), "--address", address])
    assert (result.exit_code, result.output) == (1, f"cannot replay against {address}:44818: Connection refused; "
                                                 "is a farm serving there? Start one (enip-farm serve), or leave out "
                                                 "--address to let golden start its own\n")


@pytest.mark.parametrize(("args", "error"), [
    (["--address", "127.0.0.1", "--device", "nope"], "Error: --device: only for the farm golden starts itself; with "
     "--address, what answers at 127.0.0.1 is compared: leave out --device or --address"),
    (["--device", "nope"], "Error: no device 'nope' in {default}; known: io1, io2, io3, io4, io5, io6, harness, "
     "safety1"),
])
def test_golden_refuses_a_device_it_would_not_use(args: list[str], error: str) -> None:
    from enip_farm.config import default_config_path

    result = CliRunner().invoke(main, ["golden", str(SEED), *args])
    assert (result.exit_code, result.output.splitlines()[-1]) == (2, error.format(default=default_config_path()))


@pytest.mark.integration
def test_an_unknown_device_is_answered_with_the_known_ones(enip_farm) -> None:
    farm = enip_farm(name="io1", model="DSQC1030", http=True)
    api = f"http://127.0.0.1:{farm.http.port}"
    reply = httpx.get(f"{api}/devices/io9/io", timeout=10)
    assert (reply.status_code, reply.json()) == (404, {"detail": "no device named 'io9'; known: io1"})
    result = CliRunner().invoke(main, ["io", "get", "io9", "--api", api])
    assert (result.exit_code, result.output) == (1, "GET /devices/io9/io: 404 no device named 'io9'; known: io1\n")


def test_no_such_device_lists_the_first_twenty_of_many() -> None:
    from enip_farm.control.http import no_such_device

    names = [f"io{i}" for i in range(1, 31)]
    assert no_such_device("x", names) == (f"no device named 'x'; known: {', '.join(names[:20])}, ... (30 in all)")
    assert no_such_device("x", []) == "no device named 'x'; known: none"


def test_every_command_s_summary_is_a_whole_sentence() -> None:
    """What a group's --help lists for each command is its help's first sentence: one cut at an
    abbreviation (`io set`: "Set signals, e.g.") says nothing (issue 30)."""
    import click

    def commands(group: click.Group, prefix: str = "") -> list[tuple[str, click.Command]]:
        found = []
        for name, command in group.commands.items():
            found.append((prefix + name, command))
            if isinstance(command, click.Group):
                found += commands(command, f"{prefix}{name} ")
        return found

    summaries = {name: command.get_short_help_str(limit=1000) for name, command in commands(main)}
    assert len(summaries) > 20
    assert {name: text for name, text in summaries.items() if text.endswith(("e.g.", "i.e.", "etc.", "cf."))
            or not text.endswith((".", ")"))} == {}
    assert summaries["io set"] == "Set signals of a device, SIGNAL=VALUE each."


def test_io_set_says_which_values_are_accepted() -> None:
    result = CliRunner().invoke(main, ["io", "set", "io1", "DI3=yes", "--api", "http://127.0.0.1:9"])  # not asked
    assert result.exit_code == 2
    assert result.output.splitlines()[-1] == (
        "Error: Invalid value for SIGNAL=VALUE: 'DI3=yes': expected SIGNAL=VALUE, VALUE being a number: 0 or 1 for a "
        "digital signal (DI3=1), an integer for a group or analog one (goProgramNo=5, AI1=0x4B0), a decimal for a "
        "scaled one (AI1=2.5), or integers separated by commas for a range (DI1-4=1,0,1,1)")


@pytest.mark.integration
def test_io_set_takes_a_range_as_a_list(enip_farm) -> None:
    farm = enip_farm(name="io1", model="DSQC1030", http=True)
    result = CliRunner().invoke(main, ["io", "set", "io1", "DI1-4=1,0,1,1", "--api",
                                       f"http://127.0.0.1:{farm.http.port}"])
    assert result.exit_code == 0, result.output
    assert farm["io1"].get("DI1-4") == [1, 0, 1, 1] and farm["io1"].inputs == b"\x0d\x00"


def test_eio_export_to_dash_writes_standard_output(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    plain = CliRunner().invoke(main, ["eio", "export"])
    dashed = CliRunner().invoke(main, ["eio", "export", "-o", "-"])
    assert plain.exit_code == dashed.exit_code == 0
    assert dashed.output == plain.output and dashed.output.startswith("EIO:CFG_")
    assert list(tmp_path.iterdir()) == []  # no file named "-"


@pytest.mark.integration  # validate binds a UDP socket to port 0 of each address: is it this host's?
def test_one_device_is_one_device(tmp_path: Path) -> None:
    config = _cell(tmp_path, "127.0.0.5")
    result = CliRunner().invoke(main, ["validate", str(config)])
    assert (result.exit_code, result.output) == (0, f"{config}: 1 device, valid\n"), repr(result.exception)
    elsewhere = _cell(tmp_path, "127.0.0.5", "203.0.113.7", "203.0.113.8")  # RFC 5737 TEST-NET-3: on no interface here
    warned = CliRunner().invoke(main, ["validate", str(elsewhere)])
    assert (warned.exit_code, warned.output.splitlines()) == (0, [
        f"{elsewhere}: warning: device 'io2' (devices[1]): 203.0.113.7 is not an address of this host, so serve cannot "
        "bind it here",
        f"{elsewhere}: warning: device 'io3' (devices[2]): 203.0.113.8 is not an address of this host, so serve cannot "
        "bind it here",
        f"{elsewhere}: warning: add each address to this host, e.g. `sudo ip addr add 203.0.113.7/32 dev lo`, or move "
        "the devices to 127.x addresses (every one is this host's on Linux; `eio import --base-address 127.0.20.1` "
        "renumbers an import)",
        f"{elsewhere}: 3 devices, valid; 2 addresses not on this host"])
    assert [plural(n, "device") for n in (0, 1, 2)] == ["0 devices", "1 device", "2 devices"]
    assert plural(1, "replay entry", "replay entries") == "1 replay entry"
    assert plural(3, "replay entry", "replay entries") == "3 replay entries"


def test_eds_export_of_an_unknown_model_names_the_model_and_the_known_ones() -> None:
    result = CliRunner().invoke(main, ["eds", "export", "DSQC1300", "-o", "-"])
    known = ", ".join(shipped_catalogue().bases())
    assert (result.exit_code, result.output) == (2, (
        f"eds export: unknown model 'DSQC1300'; known: {known}, or a profile file (PROFILE.yaml, FILE.eds)\n"))
    addon = CliRunner().invoke(main, ["eds", "export", "DSQC1030", "--addons", "DSQC9999", "-o", "-"])
    assert (addon.exit_code, addon.output) == (2, (
        f"eds export: unknown add-on 'DSQC9999'; known: {', '.join(shipped_catalogue().addons())}\n"))


@pytest.mark.integration
def test_fault_kinds_come_from_the_farm(enip_farm) -> None:
    farm = enip_farm(name="io1", model="DSQC1030", http=True)
    api = f"http://127.0.0.1:{farm.http.port}"
    kinds = httpx.get(f"{api}/fault-kinds", timeout=10).json()
    listed = CliRunner().invoke(main, ["fault", "--list", "--api", api])
    assert listed.exit_code == 0
    names = [line.split()[0] for line in listed.output.splitlines() if not line.startswith(" ")]
    assert names == [kind["kind"] for kind in kinds]
    assert "    delay_ms=VALUE (--delay-ms): ms to hold each reply, 0..60000" in listed.output.replace(
        " " * (max(map(len, names)) + 2), "", 1)  # under its kind, indented past the names
    given = CliRunner().invoke(main, ["fault", "io1", "delay", "delay_ms=5", "--duration", "30", "--api", api])
    assert (given.exit_code, given.output) == (0, "io1: active faults: delay\n")
    assert [(f["kind"], f["delay_ms"]) for f in farm["io1"].faults] == [("delay", 5.0)]
    stray = CliRunner().invoke(main, ["fault", "io1", "drop", "delay_ms=5", "--api", api])
    assert (stray.exit_code, stray.output) == (2, "fault io1 drop: delay_ms: not a parameter of drop (it takes no "
                                                  "parameter, and --duration)\n")
    # issue 30: an unknown kind lists the kinds one a line with what each does, and the closest one
    unknown = CliRunner().invoke(main, ["fault", "io1", "dealy", "--api", api])
    width = max(map(len, names))
    assert (unknown.exit_code, unknown.output.splitlines()) == (2, [
        "fault io1 dealy: unknown kind 'dealy' (did you mean delay?); the farm's kinds (fault --list: their "
        "parameters):", *(f"  {kind['kind']:{width}}  {kind['summary']}" for kind in kinds)])
    # a number as the user wrote it: 70000, not 70000.0
    far = CliRunner().invoke(main, ["fault", "io1", "delay", "--delay-ms", "70000", "--api", api])
    assert (far.exit_code, far.output) == (2, "fault io1 delay: --delay-ms: must be 0..60000 ms, got 70000 (e.g. "
                                              "--delay-ms 800)\n")


def test_an_event_written_again_reads_the_same() -> None:
    from httpx_sse import ServerSentEvent
    from httpx_sse._decoders import SSEDecoder

    for event in (ServerSentEvent("message", json.dumps({"device": "io1"})), ServerSentEvent("lost", '{"lost": 3}'),
                  ServerSentEvent("message", "two\nlines", id="7", retry=100)):
        decoder = SSEDecoder()
        decoded = [decoder.decode(line) for line in encode_event(event).decode().splitlines()]
        (again,) = [item for item in decoded if item is not None]
        assert (again.event, again.data, again.id, again.retry) == (event.event, event.data, event.id, event.retry)
    assert encode_event(ServerSentEvent("message", "{}")) == b"data: {}\n\n"


@pytest.mark.integration
def test_the_client_reads_the_event_stream(enip_farm) -> None:
    farm = enip_farm(name="io1", model="DSQC1030", http=True)
    with ApiClient(f"http://127.0.0.1:{farm.http.port}") as client, \
            client.events({"device": "io1", "kind": "io"}, 10) as events:
        assert wait_for(lambda: farm.http.hub.subscribers, timeout=10)
        farm["io1"].set(DI2=1)
        event = next(events)
    assert (event.event, event.json()["device"], event.json()["signals"]) == ("message", "io1",
                                                                              {"DI2": {"old": 0, "new": 1}})


@pytest.mark.system
def test_the_cli_imports_only_click_until_a_command_runs() -> None:
    code = ("import sys; import enip_farm.cli; print(sorted({m.split('.')[0] for m in sys.modules} & "
            "{'httpx', 'pydantic', 'fastapi', 'starlette', 'uvicorn', 'yaml', 'dpkt', 'lark', 'prometheus_client'}))")
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert (loaded.returncode, loaded.stdout) == (0, "[]\n"), loaded.stderr
    helped = subprocess.run([*CLI, "--help"], capture_output=True, text=True, timeout=60)
    assert helped.returncode == 0 and "serve " in helped.stdout and "fault " in helped.stdout


@pytest.mark.system
def test_the_public_api_is_at_the_top_and_imported_on_first_use() -> None:
    """`from enip_farm import Farm` (issue 30), without making `import enip_farm.protocol.cip` or
    the CLI pay for the farm's imports."""
    code = ("import sys; import enip_farm.protocol.cip; import enip_farm; "
            "heavy = {'pydantic', 'enip_farm.farm.farm'}; print(sorted(heavy & set(sys.modules))); "
            "from enip_farm import Farm, BindError, ConfigError, DeviceHandle; "
            "from enip_farm import EioImportWarning, FarmConfig, load_config, parse_config; "
            "print(Farm.__module__, BindError.__name__, sorted(heavy & set(sys.modules)), "
            "set(enip_farm.__all__) <= set(dir(enip_farm)))")
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert (loaded.returncode, loaded.stdout) == (
        0, "[]\nenip_farm.farm.farm BindError ['enip_farm.farm.farm', 'pydantic'] True\n"), loaded.stderr
    import enip_farm

    with pytest.raises(AttributeError, match="module 'enip_farm' has no attribute 'Farms'"):
        enip_farm.Farms  # noqa: B018


def test_the_cli_run_in_process_leaves_the_modules_it_marked_missing_importable() -> None:
    """The CLI marks modules it never uses as missing while a command runs (a quick start); a test
    calling it in its own process gets them back when it returns."""
    from enip_farm.cli import UNUSED

    absent = [name for name in UNUSED if name not in sys.modules]
    result = CliRunner().invoke(main, ["models"])
    assert result.exit_code == 0, result.output
    assert [name for name in absent if name in sys.modules] == []
