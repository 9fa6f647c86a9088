"""Named signals (RobotWare EIO_SIGNAL): device maps, group and analog values, the checks made when
a configuration is built, and names in the Python API, the HTTP API, wires and rules."""

from __future__ import annotations

import re

import httpx
import pytest
from pycomm3 import CIPDriver, Services

from enip_farm.config import ConfigError, SignalConfig, parse_config
from enip_farm.device.build import build_profiles
from enip_farm.device.catalogue import shipped_catalogue
from enip_farm.device.named_signals import SignalError, named_signal, parse_device_map
from enip_farm.device.signals import SignalMap
from enip_farm.pytest_plugin import AddressPool

GRIPPER_SIGNALS = [
    {"name": "diGripperClosed", "type": "DI", "device_map": "3"},
    {"name": "diDoorOpen", "type": "DI", "device_map": "4", "invert": True},
    {"name": "giPartType", "type": "GI", "device_map": "8-11"},
    {"name": "goProgramNo", "type": "GO", "device_map": "8-15"},
    {"name": "doClamp", "type": "DO", "device_map": "0"},
]


def signal(**fields: object) -> object:
    return named_signal(SignalConfig.model_validate(fields))


# -- device maps and values (unit) -------------------------------------------------------------------


@pytest.mark.parametrize(("text", "bits"), [
    ("3", (3,)), ("8-15", tuple(range(8, 16))), ("15-8", tuple(range(15, 7, -1))),
    ("0-3, 9", (0, 1, 2, 3, 9)), ("0-7,16-23", (*range(8), *range(16, 24))),
])
def test_device_map(text: str, bits: tuple[int, ...]) -> None:
    assert parse_device_map(text) == bits


@pytest.mark.parametrize(("text", "message"), [
    ("", "device map '': '' is not a bit or a range like 8-15"),
    ("a", "device map 'a': 'a' is not a bit or a range like 8-15"),
    ("3-", "device map '3-': '3-' is not a bit or a range like 8-15"),
    ("1,1", "device map '1,1' names a bit twice"), ("0-3,2", "device map '0-3,2' names a bit twice"),
])
def test_bad_device_map(text: str, message: str) -> None:
    with pytest.raises(SignalError, match=f"^{re.escape(message)}$"):
        parse_device_map(text)


@pytest.mark.parametrize(("text", "message"), [
    ("0-4000000000", "bit 4000000000 is beyond the largest image (496 bytes, bits 0-3967)"),
    ("4000000000-0", "bit 4000000000 is beyond the largest image (496 bytes, bits 0-3967)"),
    ("3968", "bit 3968 is beyond the largest image (496 bytes, bits 0-3967)"),
    ("0-32", "'0-32' spans 33 bits; a signal has at most 32"),
    ("100-3967", "'100-3967' spans 3868 bits; a signal has at most 32"),
])
def test_a_huge_device_map_is_refused_before_it_is_expanded(text: str, message: str) -> None:
    with pytest.raises(SignalError, match=f"^{re.escape(f'device map {text!r}: {message}')}$"):
        parse_device_map(text)  # before the fix: range(0, 4000000001) into a list, memory exhausted
    assert parse_device_map("3936-3967") == tuple(range(3936, 3968))  # the last 32 bits of a 496-byte image


def test_a_huge_device_map_in_a_configuration_is_a_config_error() -> None:
    config = parse_config({"devices": [{"name": "io1", "address": "127.0.0.1", "model": "DSQC1030", "signals": [
        {"name": "giHuge", "type": "GI", "device_map": "0-4000000000"}]}]})
    with pytest.raises(ConfigError, match=re.escape(
            "<config>: device 'io1' (devices[0]), signals: device map '0-4000000000': bit 4000000000 is beyond the "
            "largest image (496 bytes, bits 0-3967)")):
        build_profiles(config, shipped_catalogue())


def test_group_is_unsigned_over_its_bits_least_significant_first() -> None:
    go = signal(name="goProgramNo", type="GO", device_map="4-11")
    image = bytearray(2)
    go.write(image, 0xA5)
    assert image == bytes([0x50, 0x0A])  # bits 4..11 hold 0xA5, bit 4 = its bit 0
    assert go.read(image) == 0xA5
    reversed_go = signal(name="goRev", type="GO", device_map="7-0")
    image = bytearray(1)
    reversed_go.write(image, 0x01)
    assert image == b"\x80"  # the first listed bit (7) is the value's bit 0
    with pytest.raises(SignalError, match=re.escape("goProgramNo: 256 is out of range (0..255)")):
        go.write(image, 256)
    with pytest.raises(SignalError, match=re.escape("goProgramNo: -1 is out of range (0..255)")):
        go.write(image, -1)


def test_invert_and_digital_values() -> None:
    di = signal(name="diDoorOpen", type="DI", device_map="2", invert=True)
    image = bytearray(1)
    assert di.read(image) == 1  # bit clear = door open
    di.write(image, 1)
    assert image == b"\x00"
    di.write(image, 0)
    assert image == b"\x04"
    with pytest.raises(SignalError, match=re.escape("diDoorOpen: 2 is out of range (0 or 1)")):
        di.write(image, 2)
    with pytest.raises(SignalError, match="^diDoorOpen: values are numbers, got True$"):
        di.write(image, True)


def test_two_complement_and_scaled_analog() -> None:
    ai = signal(name="aiTemp", type="AI", device_map="0-15", enc_type="TWO_COMP")
    image = bytearray(2)
    ai.write(image, -2)
    assert image == b"\xfe\xff"
    assert ai.read(image) == -2
    with pytest.raises(SignalError, match=re.escape("aiTemp: 40000 is out of range (-32768..32767)")):
        ai.write(image, 40000)
    ao = signal(name="aoSpeed", type="AO", device_map="0-15", min_log=0, max_log=10, min_bit_val=0,
                max_bit_val=32767)
    ao.write(image, 5.0)
    assert int.from_bytes(image, "little") == 16384  # round(32767 / 2)
    assert ao.read(image) == pytest.approx(5.0, abs=10 / 32767)
    with pytest.raises(SignalError, match=re.escape("aoSpeed: 11.0 is out of range (0..10)")):
        ao.write(image, 11.0)


@pytest.mark.parametrize("value", [float("inf"), float("-inf"), float("nan")])
def test_non_finite_values_are_refused(value: float) -> None:
    ao = signal(name="aoSpeed", type="AO", device_map="0-15", min_log=0, max_log=10, min_bit_val=0,
                max_bit_val=32767)
    image = bytearray(2)
    with pytest.raises(SignalError, match=f"^aoSpeed: values are finite numbers, got {value}$"):  # was OverflowError
        ao.write(image, value)
    assert image == b"\0\0"
    huge = signal(name="aoHuge", type="AO", device_map="0-15", min_log=0, max_log=1e-300, min_bit_val=0,
                  max_bit_val=1e300)
    # finite, but its scaling overflows
    with pytest.raises(SignalError, match=re.escape("aoHuge: 1e+300 is out of range (0..1e-300)")):
        huge.write(image, 1e300)


@pytest.mark.parametrize("value", [float("inf"), float("nan")])
def test_non_finite_scaling_limits_are_refused_by_the_config(value: float) -> None:
    with pytest.raises(ValueError, match=r"max_log\n\s+Input should be a finite number \[type=finite_number"):
        SignalConfig.model_validate({"name": "aoSpeed", "type": "AO", "device_map": "0-15", "min_log": 0,
                                     "max_log": value, "min_bit_val": 0, "max_bit_val": 32767})


def test_a_digital_signal_maps_one_bit() -> None:
    with pytest.raises(SignalError, match="^signal diTwo: a DI maps one bit, not '0-1'$"):
        signal(name="diTwo", type="DI", device_map="0-1")


# -- configuration checks (unit) ---------------------------------------------------------------------


def build(signals: list[dict], **device: object) -> list:
    config = parse_config({"devices": [{"name": "io1", "address": "127.0.10.1", "model": "DSQC1030",
                                        "signals": signals, **device}]})
    return build_profiles(config, shipped_catalogue())


def test_named_signals_are_part_of_the_profile() -> None:
    [profile] = build(GRIPPER_SIGNALS)
    names = [info.name for info in SignalMap(profile).listing()]
    assert names[:16] == [f"DI{n}" for n in range(1, 17)]
    assert names[-5:] == ["diGripperClosed", "diDoorOpen", "giPartType", "goProgramNo", "doClamp"]


@pytest.mark.parametrize(("signals", "message"), [
    ([{"name": "DI3", "type": "DI", "device_map": "0"}],
     "devices[0], signals: DI3: the name reads as a built-in signal; choose another"),
    ([{"name": "goWide", "type": "GO", "device_map": "8-16"}],
     "devices[0], signals: goWide: bit 16 is beyond the 2-byte output image (bits 0..15)"),
    ([{"name": "a", "type": "DI", "device_map": "0"}, {"name": "A", "type": "DO", "device_map": "0"}],
     "device 'io1' (devices[0]): signals 'a' and 'A' have the same name"),
    ([{"name": "diTwo", "type": "DI", "device_map": "1-2"}],
     "device 'io1' (devices[0]), signals: signal diTwo: a DI maps one bit, not '1-2'"),
    ([{"name": "x", "type": "XI", "device_map": "1"}],
     "device 'io1' (devices[0]), signals.0.type: Input should be 'DI', 'DO', 'GI', 'GO', 'AI' or 'AO'"),
])
def test_bad_signals_are_refused_with_a_line_naming_them(signals: list[dict], message: str) -> None:
    with pytest.raises(ConfigError) as error:
        build(signals)
    assert str(error.value) == f"<config>: {message}"


def test_every_bad_signal_gets_its_line() -> None:
    with pytest.raises(ConfigError) as error:
        build([{"name": "DO1", "type": "DO", "device_map": "0"}, {"name": "giFar", "type": "GI", "device_map": "40"}])
    assert str(error.value).splitlines() == [
        "<config>: devices[0], signals: DO1: the name reads as a built-in signal; choose another",
        "<config>: devices[0], signals: giFar: bit 40 is beyond the 2-byte input image (bits 0..15)"]


# -- names in the APIs (integration) -----------------------------------------------------------------


def test_names_in_the_python_api_over_cip(enip_farm) -> None:
    io = enip_farm(name="io1", model="DSQC1030", signals=GRIPPER_SIGNALS)["io1"]
    io.set(diGripperClosed=1, giPartType=9)
    assert io.get("diGripperClosed") == 1 and io.get("DI4") == 1 and io.get("giPartType") == 9
    assert io.get("diDoorOpen") == 1  # inverted: bit 4 is clear
    assert io.inputs == bytes([0x18 ^ 0x10 | 0x08, 0x09])  # DI4 (bit 3) set, DI5 (bit 4) clear, bits 8-11 = 9
    with CIPDriver(io.address) as agent:
        agent.generic_message(service=Services.set_attribute_single, class_code=4, instance=100, attribute=3,
                              request_data=b"\x01\x2a", connected=False, route_path=False)
    assert io.get("goProgramNo") == 42 and io.get("doClamp") == 1 and io.get("goprogramno") == 42
    table = {row["name"]: row for row in io.signal_table()}
    assert table["goProgramNo"] == {"name": "goProgramNo", "type": "GO", "role": "output", "value": 42}
    assert table["DO1"]["value"] == 1
    with pytest.raises(SignalError, match=re.escape("giPartType: 16 is out of range (0..15)")):
        io.set(giPartType=16)
    with pytest.raises(SignalError, match="^'diNoSuchThing' is neither a signal of this device nor a name like DI3, "
                                          "DO1-16 or AI2$"):
        io.get("diNoSuchThing")
    assert io.get("giPartType") == 9  # the refused write changed nothing


def test_names_in_the_http_api(enip_farm) -> None:
    farm = enip_farm(name="io1", model="DSQC1030", signals=GRIPPER_SIGNALS, http=True)
    with httpx.Client(base_url=f"http://127.0.0.1:{farm.http.port}") as client:
        reply = client.put("/devices/io1/io", json={"signals": {"diGripperClosed": 1, "giPartType": 5}})
        assert reply.status_code == 200
        assert reply.json()["named"]["giPartType"] == 5
        assert farm["io1"].get("DI4") == 1
        bad = client.put("/devices/io1/io", json={"signals": {"giPartType": 99}})
        assert bad.status_code == 422 and bad.json() == {"detail": "giPartType: 99 is out of range (0..15)"}


@pytest.mark.integration
@pytest.mark.parametrize("value", ["Infinity", "-Infinity", "NaN"])
def test_a_non_finite_value_over_http_is_a_422(enip_farm, value: str) -> None:
    farm = enip_farm(name="io1", model="DSQC1030", http=True, signals=[
        {"name": "aoSpeed", "type": "AO", "device_map": "0-15", "min_log": 0, "max_log": 10, "min_bit_val": 0,
         "max_bit_val": 32767}])
    with httpx.Client(base_url=f"http://127.0.0.1:{farm.http.port}") as client:
        reply = client.put("/devices/io1/io", content='{"signals": {"aoSpeed": ' + value + "}}",
                           headers={"content-type": "application/json"})
        assert reply.status_code == 422, reply.text  # was a 500 (OverflowError / ValueError)
        shown = {"Infinity": "inf", "-Infinity": "-inf", "NaN": "nan"}[value]
        assert reply.json() == {"detail": f"aoSpeed: values are finite numbers, got {shown}"}
        assert client.put("/devices/io1/io", json={"signals": {"aoSpeed": 5.0}}).status_code == 200


def plc_and_robot(free_address: AddressPool) -> dict:
    """A PLC's recipe group and start bit wired and ruled to a robot's named inputs."""
    return {"devices": [
        {"name": "plc", "address": free_address(), "model": "DSQC1030",
         "signals": [{"name": "goRecipe", "type": "GO", "device_map": "0-7"},
                     {"name": "doStart", "type": "DO", "device_map": "15"}]},
        {"name": "robot", "address": free_address(), "model": "DSQC1030",
         "signals": [{"name": "giRecipe", "type": "GI", "device_map": "8-15"},
                     {"name": "diStarted", "type": "DI", "device_map": "0"}]}],
        "wires": [{"from": "plc.goRecipe", "to": "robot.giRecipe"}],
        "rules": [{"when": "plc.doStart", "set": "robot.diStarted"}]}


def test_wires_and_rules_between_named_signals(free_address: AddressPool, enip_farm) -> None:
    farm = enip_farm(plc_and_robot(free_address))
    farm["plc"].set(goRecipe=77, doStart=1)
    assert farm["robot"].get("giRecipe") == 77
    assert farm["robot"].get("diStarted") == 1
    assert farm["robot"].inputs == bytes([0x01, 77])


def test_a_wire_between_signals_of_different_widths_is_refused(free_address: AddressPool) -> None:
    devices = [{"name": "a", "address": free_address(), "model": "DSQC1030",
                "signals": [{"name": "goWide", "type": "GO", "device_map": "0-7"}]},
               {"name": "b", "address": free_address(), "model": "DSQC1030",
                "signals": [{"name": "giNarrow", "type": "GI", "device_map": "0-3"}]}]
    with pytest.raises(ConfigError, match="^<config>: wire a.goWide -> b.giNarrow: both ends need the same kind "
                                          "and number of signals$"):
        build_profiles(parse_config({"devices": devices, "wires": [{"from": "a.goWide", "to": "b.giNarrow"}]}),
                       shipped_catalogue())


def test_one_signal_by_name_over_http(enip_farm) -> None:
    farm = enip_farm(name="io1", model="DSQC1030", signals=GRIPPER_SIGNALS, http=True)
    farm["io1"].set(giPartType=9, DI1=1)
    with httpx.Client(base_url=f"http://127.0.0.1:{farm.http.port}") as client:
        assert client.get("/devices/io1/io/giparttype").json() == {"name": "giPartType", "type": "GI", "role": "input",
                                                                   "value": 9}
        assert client.get("/devices/io1/io/DI1-3").json() == {"name": "DI1-3", "type": "DI", "role": "input",
                                                              "value": [1, 0, 0]}
        assert client.get("/devices/io1/io/DO2").json() == {"name": "DO2", "type": "DO", "role": "output", "value": 0}
        missing = client.get("/devices/io1/io/diNoSuchThing")
        assert missing.status_code == 404 and missing.json() == {
            "detail": "device 'io1': 'diNoSuchThing' is neither a signal of this device nor a name like DI3, DO1-16 "
                      "or AI2"}
        assert client.get("/devices/io1/io/DI17").status_code == 404  # past the device's 16 DI
        assert client.get("/devices/nobody/io/DI1").status_code == 404


@pytest.mark.system
def test_io_get_prints_the_signals_named(enip_farm) -> None:
    import os
    import subprocess

    from tests.helpers import CLI

    farm = enip_farm(name="io1", model="DSQC1030", signals=GRIPPER_SIGNALS, http=True)
    farm["io1"].set(giPartType=9, diGripperClosed=1)
    env = {**os.environ, "ENIP_FARM_API": f"http://127.0.0.1:{farm.http.port}"}
    result = subprocess.run([*CLI, "io", "get", "io1", "giPartType", "DI3-4", "diDoorOpen"], capture_output=True,
                            text=True, env=env, timeout=60)
    assert (result.returncode, result.stdout) == (0, "giPartType = 9\nDI3-4 = [0, 1]\ndiDoorOpen = 1\n")
    whole = subprocess.run([*CLI, "io", "get", "io1"], capture_output=True, text=True, env=env, timeout=60)
    assert "giPartType = 9" in whole.stdout.splitlines() and "diGripperClosed = 1" in whole.stdout.splitlines()
    missing = subprocess.run([*CLI, "io", "get", "io1", "diNoSuchThing"], capture_output=True, text=True, env=env,
                             timeout=60)
    assert missing.returncode == 1 and "404" in missing.stderr and "diNoSuchThing" in missing.stderr


def test_wired_events_name_both_ends_and_the_cause(free_address: AddressPool, enip_farm) -> None:
    farm = enip_farm(plc_and_robot(free_address))
    farm["plc"].set(goRecipe=77, doStart=1)
    assert [event.text for event in farm["robot"].events("wired")] == [
        "robot.giRecipe = 77 (wire from plc.goRecipe)", "robot.diStarted = 1 (rule: plc.doStart rises)"]


def test_numbered_signals_end_where_a_smaller_image_ends() -> None:
    [profile] = build([], addons=["DSQC1031", "DSQC1032"], assemblies={"input_size": 6})
    signals = SignalMap(profile)
    assert signals.names() == {"DI": 32, "DO": 32, "AI": 1, "AO": 4}  # inputs: 4 bytes of DI, then one INT
    assert len(signals.values("input", bytes(6))) == 33
    with pytest.raises(SignalError, match="^AI2: this device has 1 AI signals$"):
        signals.lookup("AI2")


def test_two_assemblies_with_one_instance_id_are_refused() -> None:
    with pytest.raises(ConfigError) as error:
        build([], assemblies={"input": 100})
    assert str(error.value) == "<config>: devices[0], assemblies: output and input are both instance 100"


def test_names_through_the_fleet_client(enip_farm) -> None:
    from enip_farm.fleet.slices import FleetClient

    farm = enip_farm(name="io1", model="DSQC1030", signals=GRIPPER_SIGNALS, http=True)
    with FleetClient(f"http://127.0.0.1:{farm.http.port}") as fleet:
        fleet["io1"].set(goProgramNo=42, diGripperClosed=1)
        assert fleet["io1"].get("goProgramNo") == 42 and fleet["io1"].get("DI4") == 1
        assert fleet["io1"].get("DO9-12") == [0, 1, 0, 1]  # 42 = 0b101010 from bit 8 up
        with pytest.raises(KeyError, match="device 'io1': 'diNoSuchThing' is neither a signal of this device nor a "
                                           "name like DI3, DO1-16 or AI2"):
            fleet["io1"].get("diNoSuchThing")
    assert farm["io1"].get("goProgramNo") == 42
