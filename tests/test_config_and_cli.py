"""Configuration errors (named file, device and field; no traceback), bind failures, and the CLI:
`serve` prints its table once listening and exits 0 on SIGTERM; `validate`; `models`."""

from __future__ import annotations

import signal
import subprocess
import textwrap
from pathlib import Path

import pytest
from click.testing import CliRunner

from enip_farm.cli import main
from enip_farm.config import ConfigError, load_config, parse_config
from enip_farm.device.build import build_profiles
from enip_farm.device.catalogue import shipped_catalogue
from enip_farm.farm.farm import BindError, Farm
from enip_farm.pytest_plugin import AddressPool
from tests.helpers import CLI, STARTUP_S, RawClient, own_network_namespace, serving


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "cell.yaml"
    path.write_text(textwrap.dedent(text))
    return path


@pytest.mark.parametrize(
    ("body", "expected"),
    [
        ("devices:\n  - {name: io1, address: 127.0.0.300, model: DSQC1030}\n",
         ":2: device 'io1' (devices[0]), address: Input is not a valid IPv4 address"),
        ("devices:\n  - {name: io1, address: 127.0.0.3, model: DSQC9999}\n",
         ":2: device 'io1' (devices[0]), model: unknown base model 'DSQC9999'; known: DSQC1030, DSQC1042, "
         "GenericAdapter"),
        ("devices:\n  - {name: io1, address: 127.0.0.3, model: DSQC1030, addons: [DSQC1030]}\n",
         ":2: device 'io1' (devices[0]), addons: unknown add-on 'DSQC1030' (did you mean DSQC1033?); known: DSQC1031, "
         "DSQC1032, DSQC1033"),
        ("devices:\n  - {name: io1, address: 127.0.0.3, model: DSQC1030, colour: red}\n",
         ":2: device 'io1' (devices[0]), colour: unknown key; the keys here: name, address, count, model, addons, "
         "identity, assemblies, writable_inputs, netmask, gateway, mac, host_name, implicit, "
         "encapsulation_inactivity_timeout_s, limits, reset_time_s, duplicate_address, select_acd, signals, "
         "safety, bounds, extra"),
        ("devices:\n  - {name: io1, address: 127.0.0.3, model: DSQC1030, identity: {vendor_id: 70000}}\n",
         ":2: device 'io1' (devices[0]), identity.vendor_id: Input should be less than or equal to 65535"),
        ("devices:\n  - {name: a, address: 127.0.0.3, model: DSQC1030}\n"
         "  - {name: a, address: 127.0.0.4, model: DSQC1030}\n",
         ":3: device 'a' (devices[1]), name: a is taken by device 'a' (devices[0])"),
        ("devices:\n  - {name: a, address: 127.0.0.3, model: DSQC1030}\n"
         "  - {name: b, address: 127.0.0.3, model: DSQC1030}\n",
         ":3: device 'b' (devices[1]), address: 127.0.0.3 is taken by device 'a' (devices[0]) (here by 'b')"),
        ("devices: []\n", ":1: devices: List should have at least 1 item after validation, not 0"),
        ("devices:\n  - {name: a, address: 127.0.0.3, model: DSQC1030, signals: [{name: s1, type: DI}]}\n",
         ":2: device 'a' (devices[0]), signals.0.device_map: missing: the key is required here"),
        ("devices:\n  - {name: a, address: 127.0.0.3, model: DSQC1030}\nrules:\n  - {when: a.DI1, set: a.DO1, "
         "value: 3}\n", ":4: rules[0], value: Input should be 0 or 1"),
        ("devices: [\n", ":2:1: not valid YAML: while parsing a flow node: expected the node content, but found "
                          "'<stream end>'"),
        ("", ": the file is empty: a cell configuration is a mapping whose devices: lists the devices (see "
             "configs/default-cell.yaml)"),
    ],
)
def test_config_errors_name_file_line_device_field(tmp_path: Path, body: str, expected: str) -> None:
    path = _write(tmp_path, body)
    catalogue = shipped_catalogue()
    with pytest.raises(ConfigError) as error:  # the schema and the catalogue's names, in one pass
        build_profiles(load_config(path, known=(catalogue.bases(), catalogue.addons())), catalogue)
    assert str(error.value) == f"{path}{expected}"
    result = CliRunner().invoke(main, ["validate", str(path)])
    assert (result.exit_code, result.output) == (2, f"{path}{expected}\n")


def test_every_problem_is_told_at_once_at_its_line(tmp_path: Path) -> None:
    """Issue 30: field errors, unknown models and add-ons, duplicates and unknown keys came in two
    passes and in pydantic's words; now one pass, in the file's order, with suggestions."""
    path = _write(tmp_path, """\
        devices:
          - name: io1
            address: 127.0.0.300
            model: DSQC1013
            addons: [DSQC1032, DSQC1099]
            identity: {vendor_id: 70000, prodcut_code: 3}
          - {name: io1, address: 127.0.0.3, model: DSQC1030}
          - {name: io3, address: 127.0.0.3, model: DSQC1030, implicit: {idle_state: off}}
        discvery: false
        """)
    result = CliRunner().invoke(main, ["validate", str(path)])
    assert (result.exit_code, result.output.splitlines()) == (2, [
        f"{path}:3: device 'io1' (devices[0]), address: Input is not a valid IPv4 address",
        f"{path}:4: device 'io1' (devices[0]), model: unknown base model 'DSQC1013' (did you mean DSQC1030?); known: "
        "DSQC1030, DSQC1042, GenericAdapter",
        f"{path}:5: device 'io1' (devices[0]), addons: unknown add-on 'DSQC1099' (did you mean DSQC1033?); known: "
        "DSQC1031, DSQC1032, DSQC1033",
        f"{path}:6: device 'io1' (devices[0]), identity.vendor_id: Input should be less than or equal to 65535",
        f"{path}:6: device 'io1' (devices[0]), identity.prodcut_code: unknown key (did you mean product_code?)",
        f"{path}:7: device 'io1' (devices[1]), name: io1 is taken by device 'io1' (devices[0])",
        f"{path}:8: device 'io3' (devices[2]), implicit.idle_state: Input should be 'off' or 'hold' (YAML reads an "
        "unquoted off, no as false: quote the value, e.g. \"off\")",
        f"{path}:8: device 'io3' (devices[2]), address: 127.0.0.3 is taken by device 'io1' (devices[1]) (here by "
        "'io3')",
        f"{path}:9: discvery: unknown key (did you mean discovery?)"])
    wiring = _write(tmp_path, "devices:\n  - {name: a, address: 127.0.0.3, model: DSQC1030}\nwires:\n"
                              "  - {from: a.DO1, to: a.DI1}\n  - {from: a.DO2, to: b.DI1}\n")
    built = CliRunner().invoke(main, ["validate", str(wiring)])  # what only building the devices tells
    assert (built.exit_code, built.output) == (2, f"{wiring}:5: wire a.DO2 -> b.DI1: 'b.DI1': no device named 'b'\n")
    both = _write(tmp_path, """\
        devices:
          - {name: a, address: 127.0.0.3, model: DSQC1030, writeable_inputs: true}
          - {name: b, address: 127.0.0.4, model: DSQC1030, signals: [{name: diX, type: DI, device_map: "99"}]}
          - {name: "c{n}", count: 2, address: 127.0.0.5, model: DSQC1030}
        wires:
          - {from: a.DO1, to: b.DI1}
          - {from: c1.DO1, to: b.DI99}
          - {from: c2.DO1, to: zz.DI1}
        rules:
          - {when: a.DI1, set: b.DO1}
        """)
    together = CliRunner().invoke(main, ["validate", str(both)])  # a field's problem and building's, in one pass
    assert (together.exit_code, together.output.splitlines()) == (2, [
        f"{both}:2: device 'a' (devices[0]), writeable_inputs: unknown key (did you mean writable_inputs?)",
        f"{both}:3: devices[1], signals: diX: bit 99 is beyond the 2-byte input image (bits 0..15)",
        f"{both}:7: wire c1.DO1 -> b.DI99: 'b.DI99': DI99: this device has 16 DI signals",
        f"{both}:8: wire c2.DO1 -> zz.DI1: 'zz.DI1': no device named 'zz'"])  # a's wire and rule wait for a


def test_a_problem_outside_the_devices_is_told_with_what_building_tells_in_every_loader(tmp_path: Path) -> None:
    """A top-level key's problem, a group's and a wire's no longer hold back what building the
    devices tells; `enip_farm.load_config(path)`, `Farm(path)` and the CLI tell the same, in one
    pass (a plain load_config told the catalogue's names only when the devices were built)."""
    import enip_farm

    path = _write(tmp_path, """\
        devices:
          - {name: a, address: 127.0.0.3, model: DSQC1099}
          - {name: b, address: 127.0.0.4, model: DSQC1030, signals: [{name: diX, type: DI, device_map: "99"}]}
        wires:
          - {from: a.DO1, to: b.DI1}
          - {from: b.DO1, to: zz.DI1}
          - {from: b.DO2}
        colour: red
        bounds: {lost: -1}
        """)
    expected = [
        f"{path}:2: device 'a' (devices[0]), model: unknown base model 'DSQC1099' (did you mean DSQC1042?); known: "
        "DSQC1030, DSQC1042, GenericAdapter",
        f"{path}:3: devices[1], signals: diX: bit 99 is beyond the 2-byte input image (bits 0..15)",
        f"{path}:6: wire b.DO1 -> zz.DI1: 'zz.DI1': no device named 'zz'",
        f"{path}:7: wires[2], to: missing: the key is required here",
        f"{path}:8: colour: unknown key; the keys here: devices, groups, cyclic_io, discovery, max_tcp_connections, "
        "wires, rules, bounds",
        f"{path}:9: bounds.lost: Input should be greater than or equal to 0"]  # a's wire waits for a
    for load in (enip_farm.load_config, Farm):
        with pytest.raises(ConfigError) as error:
            load(path)
        assert str(error.value).splitlines() == expected
    result = CliRunner().invoke(main, ["validate", str(path)])
    assert (result.exit_code, result.output.splitlines()) == (2, expected)
    path.write_text("devices:\n  - {name: a, address: 127.0.0.3, model: DSQC1030}\n")
    assert [d.name for d in enip_farm.load_config(path).devices] == ["a"]


@pytest.mark.system
def test_invalid_config_refused_before_binding(free_address: AddressPool, tmp_path: Path) -> None:
    address = free_address()
    path = _write(tmp_path, f"devices:\n  - {{name: ok, address: {address}, model: DSQC1030}}\n"
                            "  - {name: bad, address: nonsense, model: DSQC1030}\n")
    result = subprocess.run([*CLI, "serve", "--config", str(path)], capture_output=True, text=True, timeout=60)
    assert result.returncode == 2 and "device 'bad'" in result.stderr and "Traceback" not in result.stderr


@pytest.mark.system
def test_unbindable_address_names_device_and_alias(free_address: AddressPool, tmp_path: Path) -> None:
    # 192.0.2.1 (RFC 5737 documentation range) is on no interface: bind fails, no packet is sent.
    config = parse_config({"devices": [{"name": "first", "address": free_address(), "model": "DSQC1030"},
                                       {"name": "remote", "address": "192.0.2.1", "model": "DSQC1030"}],
                           "discovery": False})
    farm = Farm(config)
    with pytest.raises(BindError) as error, farm.running_in_thread():
        pass
    assert str(error.value) == ("device 'remote': cannot bind TCP 192.0.2.1:44818: the address is not assigned to any "
                                "interface of this host. Add it as an alias, e.g. `sudo ip addr add 192.0.2.1/32 dev "
                                "lo` (every 127.x.y.z address works on Linux without this).")
    with pytest.raises(OSError, match="Connection refused"):  # the first device's sockets were released again
        RawClient(config.devices[0].address.exploded, timeout=1)
    path = _write(tmp_path, "devices:\n  - {name: remote, address: 192.0.2.1, model: DSQC1030}\ndiscovery: false\n")
    result = subprocess.run([*CLI, "serve", "--config", str(path)], capture_output=True, text=True, timeout=60)
    assert result.returncode == 1 and "ip addr add" in result.stderr and "Traceback" not in result.stderr


@pytest.mark.system
def test_serve_prints_table_and_stops_on_sigterm(free_address: AddressPool, tmp_path: Path) -> None:
    a, b = free_address(), free_address()
    path = _write(tmp_path, f"""\
        devices:
          - {{name: left, address: {a}, model: DSQC1030, addons: [DSQC1032]}}
          - {{name: right, address: {b}, model: DSQC1030}}
        discovery: false
        """)
    with serving(["serve", "--config", str(path)], table_rows=2) as (process, table):  # once every device listens
        header, *rows = table
        assert header.split() == ["NAME", "ADDRESS", "MODEL", "IN", "BYTES", "OUT", "BYTES"]
        assert rows[0].split() == ["left", a, "DSQC1030+DSQC1032", "10", "10"]
        with RawClient(b) as c:
            c.register()
            assert c.get(4, 100, 3).data == b"\x00\x00"
        process.send_signal(signal.SIGTERM)
        assert process.wait(timeout=STARTUP_S) == 0
    with pytest.raises(OSError, match="Connection refused"):
        RawClient(a, timeout=1)


@pytest.mark.system
def test_serve_default_cell_sigint() -> None:
    """`enip-farm serve` with no --config serves the shipped default cell on 127.0.10.x, in a network
    namespace of its own: the quick-start farm may well be running beside the suite."""
    namespace = own_network_namespace()
    with serving(["serve"], table_rows=8, prefix=namespace) as (process, table):
        names = [line.split()[0] for line in table[1:]]
        assert names == ["io1", "io2", "io3", "io4", "io5", "io6", "harness", "safety1"]
        assert [line.split()[1] for line in table[1:]] == [f"127.0.10.{n}" for n in range(1, 9)]
        probe = subprocess.run(["nsenter", f"--net=/proc/{process.pid}/ns/net", *CLI, "probe", "--timeout",
                                str(STARTUP_S)], capture_output=True, text=True, timeout=2 * STARTUP_S)
        assert probe.returncode == 0 and "8/8 devices answered" in probe.stdout, probe.stdout + probe.stderr
        process.send_signal(signal.SIGINT)
        assert process.wait(timeout=STARTUP_S) == 0


@pytest.mark.system
def test_models_marks_unverified() -> None:
    result = subprocess.run([*CLI, "models"], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0
    for model in ("DSQC1030", "DSQC1031", "DSQC1032", "DSQC1033", "DSQC1042"):
        assert model in result.stdout
    assert "UNVERIFIED: identity.device_type, identity.product_code" in result.stdout


def test_the_abb_models_select_acd_is_unverified_unless_the_device_sets_it() -> None:
    """docs/unverified.md: whether ABB's modules ship with ACD on is not published; the profile's
    unverified tuple (what `models`, the dashboard and an exported EDS mark) says so, exactly."""
    devices = [{"name": "a", "model": "DSQC1030", "address": "127.0.0.1"},
               {"name": "b", "model": "DSQC1030", "address": "127.0.0.2", "select_acd": False},
               {"name": "c", "model": "DSQC1042", "address": "127.0.0.3", "select_acd": True}]
    a, b, c = build_profiles(parse_config({"devices": devices}), shipped_catalogue())
    assert a.unverified == tuple(f"DSQC1030.{item}" for item in (
        "identity.device_type", "identity.product_code", "identity.revision", "identity.product_name",
        "assemblies.input_only", "assemblies.listen_only", "RPI limits", "select_acd", "routing"))
    assert b.unverified == tuple(item for item in a.unverified if item != "DSQC1030.select_acd")
    assert "DSQC1042.select_acd" not in c.unverified and c.select_acd is True
    unset = {key: value for key, value in devices[2].items() if key != "select_acd"}
    (safety,) = build_profiles(parse_config({"devices": [unset]}), shipped_catalogue())
    assert "DSQC1042.select_acd" in safety.unverified and safety.select_acd is False


def test_shipped_default_cell_is_valid() -> None:
    repo_copy = Path(__file__).parent.parent / "configs" / "default-cell.yaml"
    config = load_config(repo_copy)
    addons = {addon for device in config.devices for addon in device.addons}
    assert addons == {"DSQC1031", "DSQC1032", "DSQC1033"}
    assert {device.model for device in config.devices} == {"DSQC1030", "DSQC1042"}


@pytest.mark.integration
@pytest.mark.parametrize(("setting", "native"), [("off", False), ('"off"', False), ("false", False),
                                                  ("auto", True), ("true", True)])
def test_the_native_class1_path_is_switched_off_by_a_bare_off_too(
        setting: str, native: bool, free_address: AddressPool, tmp_path: Path,
        monkeypatch: pytest.MonkeyPatch) -> None:
    """YAML reads a bare `off` as false: the farm takes it as off, not as a configuration error."""
    from enip_farm.server.native import BUILT, ENVIRONMENT

    monkeypatch.delenv(ENVIRONMENT, raising=False)
    path = _write(tmp_path, f"devices:\n  - {{name: a, address: {free_address()}, model: DSQC1030}}\n"
                            f"discovery: false\ncyclic_io: {{native: {setting}, budget_datagrams_per_s: 1000}}\n")
    farm = Farm(load_config(path))
    with farm.running_in_thread():
        engine = farm._implicit.thread.native  # type: ignore[union-attr]
        assert (engine is not None) is (native and BUILT)
