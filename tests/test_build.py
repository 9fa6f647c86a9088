"""Building devices from a configuration and an explicit catalogue (device/build.py): profile files
never shadow a model of the catalogue, the shipped catalogue cannot change, problems name file,
device and field; and `enip-farm learn` never names its model like a built-in one."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from enip_farm.capture.learn import learn
from enip_farm.capture.recorder import Recorder
from enip_farm.config import ConfigError, parse_config
from enip_farm.device.build import build_profiles
from enip_farm.device.catalogue import BUILT_IN, Catalogue, shipped_catalogue
from enip_farm.farm.farm import Farm
from enip_farm.fleet.slices import split
from enip_farm.protocol.commands import IdentityItem, SocketAddress, encode_identity_item
from enip_farm.protocol.cpf import ItemType, encode_items
from enip_farm.protocol.encapsulation import Command, encode_frame

CLI = [sys.executable, "-m", "enip_farm"]


def _profile(path: Path, name: str, di: int = 0) -> Path:
    path.write_text(yaml.safe_dump({"models": {name: {
        "kind": "base", "description": "a learned device",
        "identity": {"vendor_id": 1, "device_type": 2, "product_code": 3, "revision": [1, 0], "product_name": name},
        "assemblies": {"output": 100, "input": 101, "configuration": 1}, "io": {"di": di}}}}))
    return path


def _dsqc1030_input_size() -> int:
    config = parse_config({"devices": [{"name": "io", "address": "127.0.0.5", "model": "DSQC1030"}]})
    return build_profiles(config, shipped_catalogue())[0].input_size


def test_a_profile_named_like_a_built_in_model_is_refused(tmp_path: Path) -> None:
    shadow = _profile(tmp_path / "shadow.yaml", "DSQC1030")
    data = {"devices": [{"name": "io1", "address": "127.0.0.5", "model": "shadow.yaml"}]}
    config = parse_config(data, "cell.yaml", tmp_path)
    with pytest.raises(ConfigError) as error:
        build_profiles(config, shipped_catalogue())
    assert str(error.value) == (
        f"cell.yaml: device 'io1' (devices[0]), model: profile {shadow} defines model 'DSQC1030', which would "
        "replace the built-in model: give the profile's model another name (enip-farm learn --name)")
    with pytest.raises(ConfigError) as again:
        Farm(config)
    assert str(again.value) == str(error.value)
    # the built-in model is unchanged, in this process and for the next test
    assert shipped_catalogue().models["DSQC1030"].io.di == 16
    assert _dsqc1030_input_size() == 2


def test_the_shipped_catalogue_cannot_change(tmp_path: Path) -> None:
    shipped = shipped_catalogue()
    with pytest.raises(TypeError, match="^'mappingproxy' object does not support item assignment$"):
        shipped.models["DSQC1030"] = shipped.models["DSQC1031"]  # type: ignore[index]
    extended, base = shipped.with_profile(_profile(tmp_path / "mine.yaml", "MINE", di=8))
    assert base == "MINE" and extended.origins["MINE"] == str(tmp_path / "mine.yaml")
    assert "MINE" not in shipped.models and shipped_catalogue() is shipped
    assert extended.origins["DSQC1030"] == BUILT_IN and extended.models["DSQC1030"] is shipped.models["DSQC1030"]


def test_profile_models_are_per_farm(tmp_path: Path) -> None:
    """A profile file's model exists for the farm that names it, not for the next configuration."""
    _profile(tmp_path / "mine.yaml", "MINE", di=8)
    config = parse_config({"devices": [{"name": "d", "address": "127.0.0.5", "model": "mine.yaml"}]}, "a", tmp_path)
    (profile,) = build_profiles(config, shipped_catalogue())
    assert profile.model == "MINE" and profile.input_size == 1
    with pytest.raises(ConfigError, match=r"^<config>: device 'd' \(devices\[0\]\), model: unknown base model 'MINE'; "
                                          r"known: DSQC1030, DSQC1042, GenericAdapter$"):
        build_profiles(parse_config({"devices": [{"name": "d", "address": "127.0.0.5", "model": "MINE"}]}),
                       shipped_catalogue())


def test_a_worker_builds_its_slice_with_the_profile_file(tmp_path: Path) -> None:
    """`serve --workers N` hands each worker its slice as data; a profile file named relative to the
    config's directory is still found there (the worker never saw that directory)."""
    _profile(tmp_path / "mine.yaml", "MINE", di=8)
    config = parse_config({"devices": [{"name": "a", "address": "127.0.0.5", "model": "mine.yaml"},
                                       {"name": "b", "address": "127.0.0.6", "model": "DSQC1030"}]}, "c", tmp_path)
    slices = [parse_config(part.model_dump(mode="json", by_alias=True), f"worker {i}")
              for i, part in enumerate(split(config, 2))]
    assert [[p.model for p in build_profiles(part, shipped_catalogue())] for part in slices] == [["MINE"], ["DSQC1030"]]


def test_two_profiles_with_one_model_name_are_refused(tmp_path: Path) -> None:
    _profile(tmp_path / "a.yaml", "LEARNED", di=8)
    _profile(tmp_path / "b.yaml", "LEARNED", di=16)
    config = parse_config({"devices": [{"name": "a", "address": "127.0.0.5", "model": "a.yaml"},
                                       {"name": "b", "address": "127.0.0.6", "model": "b.yaml"}]}, "cell", tmp_path)
    with pytest.raises(ConfigError) as error:
        build_profiles(config, shipped_catalogue())
    assert str(error.value) == (f"cell: device 'b' (devices[1]), model: profile {tmp_path / 'b.yaml'} defines "
                                f"model 'LEARNED', which would replace the model of {tmp_path / 'a.yaml'}: give the "
                                "profile's model another name (enip-farm learn --name)")


def test_problems_of_a_count_entry_are_reported_once() -> None:
    config = parse_config({"devices": [{"name": "io{n}", "address": "127.0.0.5", "count": 3, "model": "DSQC1042",
                                        "addons": ["DSQC9"]}]}, "cell.yaml")
    with pytest.raises(ConfigError) as error:
        build_profiles(config, shipped_catalogue())
    assert str(error.value).splitlines() == [
        "cell.yaml: device 'io1' (devices[0]), addons: unknown add-on 'DSQC9' (did you mean DSQC1033?); known: "
        + ", ".join(shipped_catalogue().addons())]


@pytest.mark.system
def test_validate_reports_model_addon_and_wiring_problems(tmp_path: Path) -> None:
    path = tmp_path / "cell.yaml"
    path.write_text(yaml.safe_dump({"devices": [{"name": "a", "address": "127.0.0.5", "model": "DSQC1030"},
                                                {"name": "b", "address": "127.0.0.6", "model": "DSQC1030"}],
                                    "wires": [{"from": "a.DO1-8", "to": "b.DI1-7"}, {"from": "a.DI1", "to": "b.DI2"}]}))
    result = subprocess.run([*CLI, "validate", str(path)], capture_output=True, text=True, timeout=60)
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert result.stderr.splitlines() == [
        f"{path}:9: wire a.DO1-8 -> b.DI1-7: both ends need the same kind and number of signals",
        f"{path}:11: wire a.DI1 -> b.DI2: wires go from outputs (DO, AO) to inputs (DI, AI)"]


def _identity_capture(path: Path, product_name: str) -> Path:
    device, client = ("192.168.125.77", 44818), ("192.168.125.5", 50000)  # data in a file, never a target
    identity = IdentityItem(1, SocketAddress(device[0], 44818), 75, 7, 1030, 1, 1, 0x30, 0x1234, product_name, 3)
    recorder = Recorder(path)
    recorder.udp(client, device, encode_frame(Command.LIST_IDENTITY))
    recorder.udp(device, client, encode_frame(Command.LIST_IDENTITY,
                                              encode_items([(ItemType.LIST_IDENTITY, encode_identity_item(identity))])))
    recorder.close()
    return path


@pytest.mark.system
def test_learn_never_names_a_model_like_a_built_in_one(tmp_path: Path) -> None:
    capture = _identity_capture(tmp_path / "real.pcap", "DSQC1030")
    assert [p.name for p in learn(capture)] == ["DSQC1030_learned"]
    mine = Catalogue.from_document({"models": {"DSQC1030_learned": shipped_catalogue().models["DSQC1030"]}}, "mine")
    assert [p.name for p in learn(capture, catalogue=shipped_catalogue().with_models(mine.models, "mine"))] == [
        "DSQC1030_learned_learned"]
    with pytest.raises(ValueError, match="^'DSQC1031' is a model of the catalogue: a learned profile never replaces "
                                         "one, choose another name$"):
        learn(capture, name="DSQC1031")
    refused = subprocess.run([*CLI, "learn", str(capture), "-o", str(tmp_path / "p.yaml"), "--name", "DSQC1030"],
                             capture_output=True, text=True, timeout=120)
    assert refused.returncode == 2 and "never replaces" in refused.stderr and not (tmp_path / "p.yaml").exists()
    learned = subprocess.run([*CLI, "learn", str(capture), "-o", str(tmp_path / "p.yaml")], capture_output=True,
                             text=True, timeout=120)
    assert learned.returncode == 0, learned.stderr
    config = parse_config({"devices": [{"name": "real", "address": "127.0.0.5", "model": "p.yaml"},
                                       {"name": "farm", "address": "127.0.0.6", "model": "DSQC1030"}]}, "c", tmp_path)
    real, built_in = build_profiles(config, shipped_catalogue())
    assert real.model == "DSQC1030_learned" and real.serial_number == 0x1234
    assert built_in.model == "DSQC1030" and built_in.input_size == 2


def _chain(count: int, closed: bool) -> dict:
    """`count` devices, each one's DO1 wired to the next one's DI1 and a rule DI1 -> DO1 inside each:
    one path through 2 * count nodes, closed into a loop when `closed`."""
    devices = [{"name": f"d{n}", "address": f"127.1.{n // 250}.{n % 250 + 1}", "model": "DSQC1030"}
               for n in range(count)]
    last = count if closed else count - 1
    wires = [{"from": f"d{n}.DO1", "to": f"d{(n + 1) % count}.DI1"} for n in range(last)]
    rules = [{"when": f"d{n}.DI1", "set": f"d{n}.DO1"} for n in range(count)]
    return {"devices": devices, "wires": wires, "rules": rules}


@pytest.mark.parametrize("closed", [False, True])
def test_a_chain_of_thousands_of_devices_does_not_exhaust_the_stack(closed: bool) -> None:
    config = parse_config(_chain(3000, closed))  # the recursive search raised RecursionError past ~500
    if not closed:
        assert len(build_profiles(config, shipped_catalogue())) == 3000
        return
    with pytest.raises(ConfigError) as error:
        build_profiles(config, shipped_catalogue())
    cycle = [f"d{n}.{end}" for n in range(3000) for end in ("inputs", "outputs")] + ["d0.inputs"]
    assert str(error.value) == "<config>: wiring cycle: " + " -> ".join(cycle)


def test_every_worker_gets_the_cyclic_io_settings() -> None:
    """`serve --workers N`: each worker's I/O thread has the budget and the measurement configured
    (they were dropped, and every worker measured its own budget whatever the config said)."""
    config = parse_config({"cyclic_io": {"budget_datagrams_per_s": 150000, "measure": False},
                           "devices": [{"name": f"d{i}", "address": f"127.0.0.{5 + i}", "model": "DSQC1030"}
                                       for i in range(3)]})
    slices = [parse_config(part.model_dump(mode="json", by_alias=True), f"worker {i}")
              for i, part in enumerate(split(config, 2))]
    assert [(s.cyclic_io.budget_datagrams_per_s, s.cyclic_io.measure) for s in slices] == [(150000, False)] * 2
    assert [s.bounds for s in slices] == [config.bounds] * 2
