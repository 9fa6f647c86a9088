"""RobotWare's EIO.cfg in and out: the file format (header, sections, continuation lines, flags,
comments, malformed lines named by file:line), `eio import` of a realistic file (tests/data/EIO.cfg:
DSQC1030s with and without add-on sizes, a device type the catalogue does not know, DI/DO/GI/GO/AI/AO
signals, unknown sections and attributes) checked against a served farm over CIP, `eio export`, and
the round trips between them; the CLI's exit codes and one-line messages."""

from __future__ import annotations

import struct
import subprocess
from ipaddress import IPv4Address
from pathlib import Path

import pytest
import yaml
from click.testing import CliRunner
from hypothesis import given, settings
from hypothesis import strategies as st
from pycomm3 import CIPDriver, Services

from enip_farm.cli import main
from enip_farm.config import parse_config
from enip_farm.device.build import build_profiles
from enip_farm.device.catalogue import shipped_catalogue
from enip_farm.eio.cfg import MAX_LINE, CfgError, format_entry, parse_cfg, write_cfg
from enip_farm.eio.exporter import ExportError, export_eio
from enip_farm.eio.importer import GENERIC_MODEL, EioError, EioImportWarning, import_eio
from enip_farm.protocol.epath import ElectronicKey
from tests.helpers import CLI, ROOT, RawClient
from tests.test_implicit import forward_close, forward_open

DATA = ROOT / "tests" / "data" / "EIO.cfg"
BASE = IPv4Address("127.0.20.1")


def parse(text: str, source: str = "EIO.cfg"):
    return parse_cfg(text, source)


def imported(base: IPv4Address | None = BASE, path: Path = DATA):
    return import_eio(parse_cfg(path.read_text(), path.name), shipped_catalogue(), base)


def devices_by_name(document: dict) -> dict[str, dict]:
    return {device["name"]: device for device in document["devices"]}


# -- the file format (unit) --------------------------------------------------------------------------


def test_entries_sections_continuations_flags_and_values() -> None:
    cfg = parse(DATA.read_text())
    assert (cfg.header, cfg.domain) == ("EIO:CFG_1.0:6:1::", "EIO")
    assert list(cfg.sections) == ["INDUSTRIAL_NETWORK", "ETHERNETIP_DEVICE", "LOCAL_DEVICE", "EIO_SIGNAL",
                                  "EIO_CROSS", "EIO_ACCESS", "ACME_VISION_SETTINGS"]
    gripper = next(e for e in cfg.entries if e.get("Name") == "Gripper")
    assert gripper.section == "ETHERNETIP_DEVICE" and gripper.line == 10
    assert gripper.attributes == {  # five lines joined, in file order, typed
        "Name": "Gripper", "VendorName": "ABB Robotics", "ProductName": "DSQC1030",
        "Label": "Gripper I/O, DSQC1030 + DSQC1032", "Address": "192.168.125.30", "VendorId": 75,
        "ProductCode": 1030, "DeviceType": 7, "OutputAssembly": 100, "InputAssembly": 101,
        "ConfigurationAssembly": 1, "ConnectionPriority": "SCHEDULE", "OutputSize": 10, "InputSize": 10}
    signals = {e.get("Name"): e for e in cfg.entries if e.section == "EIO_SIGNAL"}
    assert signals["diGripperOpen"].attributes == {"Name": "diGripperOpen", "SignalType": "DI", "Device": "Gripper",
                                                   "DeviceMap": "1", "Invert": True,
                                                   "Label": "open: the sensor's bit is clear"}
    assert signals["aiGripperPos"].get("MinLog") == -100 and signals["aoGripperSpeed"].get("MaxLog") == 2.5
    assert signals["diConveyorFault"].get("Invert") is True  # a flag at the end of its line
    # entries on consecutive lines (no blank line between them) are separate entries
    assert [signals[n].line for n in ("diPartPresent", "diConveyorFault", "giRecipe")] == [55, 56, 57]
    access = next(e for e in cfg.entries if e.section == "EIO_ACCESS")
    assert access.attributes == {"Name": "All", "Rapid": True, "LocalManual": True, "LocalAuto": True,
                                 "RemoteManual": True, "RemoteAuto": True}
    assert cfg.warnings == ()


def test_bare_words_numbers_crlf_and_comments() -> None:
    cfg = parse('EIO:CFG_1.0::\r\n# a comment line\r\n#\r\nEIO_SIGNAL:\r\n\r\n'
                '      -Name "s" -SignalType DO -Access All -Default -1 -MaxLog 1e3 -Pos .5\\\r\n'
                '            -Ver 1.2.3 -Quiet\r\n')
    [entry] = cfg.entries
    assert entry.attributes == {"Name": "s", "SignalType": "DO", "Access": "All", "Default": -1, "MaxLog": 1000.0,
                                "Pos": 0.5, "Ver": "1.2.3", "Quiet": True}
    assert entry.line == 6


def test_an_attribute_given_twice_is_a_warning_naming_its_line() -> None:
    cfg = parse('EIO:CFG_1.0::\n#\nEIO_SIGNAL:\n      -Name "a" -DeviceMap "1"\\\n      -DeviceMap "2"\n')
    assert cfg.entries[0].get("DeviceMap") == "2"
    assert cfg.warnings == ("EIO.cfg:5: -DeviceMap is given twice in one entry; the last value counts",)


@pytest.mark.parametrize(("text", "error"), [
    ("", "EIO.cfg:1: not a RobotWare configuration file: expected a header like EIO:CFG_1.0:6:1::, found an "
         "empty file"),
    ("devices:\n  - name: io1\n", "EIO.cfg:1: not a RobotWare configuration file: expected a header like "
                                  "EIO:CFG_1.0:6:1::, found 'devices:'"),
    ('EIO:CFG_1.0::\n#\nEIO_SIGNAL:\n      -Name "a -DeviceMap "1"\n', 'EIO.cfg:4: the value 1 follows no -Attribute'),
    ('EIO:CFG_1.0::\n#\nEIO_SIGNAL:\n      -Name "a" -Label "open\n', "EIO.cfg:4: a quoted string is not closed"),
    ('EIO:CFG_1.0::\n#\nEIO_SIGNAL:\n      -Name "a"\\\n      -Device "d" "x"\n',
     'EIO.cfg:5: the value "x" follows no -Attribute'),
    ('EIO:CFG_1.0::\n      -Name "a"\n', "EIO.cfg:2: an entry before any section line (such as EIO_SIGNAL:)"),
    ('EIO:CFG_1.0::\n#\nEIO_SIGNAL:\n      Name "a"\n',
     "EIO.cfg:4: expected an entry (-Attribute value ...), a section line (NAME:) or a # line, found 'Name \"a\"'"),
    ('EIO:CFG_1.0::\n#\nEIO_SIGNAL:\n      -Name "a"\\\n\n      -Device "d"\n',
     "EIO.cfg:4: the line ends in a continuation (\\) but no indented line of the entry follows"),
])
def test_malformed_lines_are_named_by_file_and_line(text: str, error: str) -> None:
    with pytest.raises(CfgError) as raised:
        parse(text)
    assert str(raised.value) == error


def test_every_malformed_line_gets_its_own_line() -> None:
    text = 'EIO:CFG_1.0::\n#\nEIO_SIGNAL:\n      -Name "a" "b"\n      -Name "ok"\n    junk\n      -Label "x\n'
    with pytest.raises(CfgError) as raised:
        parse(text)
    assert str(raised.value).splitlines() == [
        'EIO.cfg:4: the value "b" follows no -Attribute',
        "EIO.cfg:6: expected an entry (-Attribute value ...), a section line (NAME:) or a # line, found 'junk'",
        "EIO.cfg:7: a quoted string is not closed"]


def _cut(lines: int, then: str = "") -> str:
    """tests/data/EIO.cfg's first `lines` lines, each with its line break, then `then`."""
    return "".join(DATA.read_text().splitlines(keepends=True)[:lines]) + then


@pytest.mark.parametrize(("text", "error"), [
    # cut inside an entry, inside a line: Gripper's -OutputAssembly would be the flag -OutputAssemb
    (_cut(11, "      -VendorId 75 -ProductCode 1030 -DeviceType 7 -OutputAssemb"),
     "EIO.cfg:12: the file ends inside this line (no line break after it): it looks cut short (a copy that "
     "stopped?): take the whole file again; if it is whole, end its last line with a line break"),
    (_cut(11), "EIO.cfg:11: the file ends with a line that continues (\\) on a line that is not there, where "
               "RobotWare ends with an entry's line: it looks cut short (a copy that stopped?): take the whole file "
               "again"),
    # cut between entries: after the blank line before Conveyor, the # line before a section, a section line
    (_cut(26), "EIO.cfg:26: the file ends with a # line and no entry after it, where RobotWare ends with an entry's "
               "line: it looks cut short (a copy that stopped?): take the whole file again"),
    (_cut(27, "\n"), "EIO.cfg:27: the file ends with the section line LOCAL_DEVICE: and no entry after it, where "
                     "RobotWare ends with an entry's line: it looks cut short (a copy that stopped?): take the whole "
                     "file again"),
])
def test_a_file_cut_short_is_refused_naming_its_last_line(text: str, error: str) -> None:
    with pytest.raises(CfgError) as raised:
        parse(text)
    assert str(raised.value) == error


def test_a_file_ending_with_blank_lines_is_read_with_a_warning() -> None:
    # cut after the blank line before Conveyor, or a whole file a hand edit left a blank line at the end of
    cut = parse_cfg(_cut(15), "EIO.cfg")
    assert [entry.attributes.get("Name") for entry in cut.entries] == [
        entry.attributes.get("Name") for entry in parse_cfg(_cut(14), "EIO.cfg").entries]
    assert cut.warnings == ("EIO.cfg:15: the file ends with a blank line, where RobotWare ends with an entry's line: "
                            "if it was copied, check that the copy is whole (it may have stopped between entries)",)
    assert parse_cfg(DATA.read_text() + "\n\n", "EIO.cfg").warnings[-1].startswith(
        f"EIO.cfg:{len(DATA.read_text().splitlines()) + 2}: the file ends with a blank line")
    assert parse_cfg(DATA.read_text(), "EIO.cfg").warnings == ()


def test_whole_files_are_not_cut_short() -> None:
    assert len(parse(DATA.read_text()).entries) == 27
    assert len(parse(DATA.read_text().replace("\n", "\r\n")).entries) == 27
    assert len(parse(_cut(25)).entries) == 4  # cut right after an entry's line break: nothing can tell
    assert parse("EIO:CFG_1.0::\n\n").entries == ()  # a header alone is whole (and has nothing to import)


_names = st.from_regex(r"[A-Z][A-Za-z0-9_]{0,20}", fullmatch=True)
_values = st.one_of(
    st.just(True), st.integers(-(2**31), 2**31),
    st.floats(allow_nan=False, allow_infinity=False, min_value=-1e12, max_value=1e12).filter(
        lambda v: not v.is_integer()),
    st.text(st.characters(codec="ascii", exclude_characters='"\r\n\x0b\x0c\x1c\x1d\x1e\x85', min_codepoint=32),
            max_size=90))


@settings(max_examples=100, deadline=None, database=None)
@given(st.lists(st.dictionaries(_names, _values, min_size=1, max_size=12), min_size=1, max_size=4))
def test_what_is_written_reads_back_and_keeps_lines_under_80(entries: list[dict]) -> None:
    text = write_cfg("EIO:CFG_1.0::", [("EIO_SIGNAL", [list(entry.items()) for entry in entries])])
    assert [e.attributes for e in parse(text).entries] == entries
    for line in text.splitlines():
        # only a single quoted value longer than a line may exceed it
        assert len(line) <= MAX_LINE or line.strip().rstrip("\\").startswith('"'), line


def test_entries_are_wrapped_as_robotware_writes_them() -> None:
    lines = format_entry([("Name", "Feeder"), ("VendorName", "ABB Robotics"), ("Address", "192.168.125.30"),
                          ("VendorId", 75), ("ProductCode", 1030), ("DeviceType", 7), ("OutputAssembly", 100),
                          ("Simulated", True), ("MaxLog", 2.5)])
    assert lines == [
        '      -Name "Feeder" -VendorName "ABB Robotics" -Address "192.168.125.30"\\',
        "      -VendorId 75 -ProductCode 1030 -DeviceType 7 -OutputAssembly 100\\",
        "      -Simulated -MaxLog 2.5"]
    with pytest.raises(ValueError, match='^-Label: \'say "hi"\' holds a double quote or a line break, which the format '
                                         'cannot hold$'):
        format_entry([("Label", 'say "hi"')])


# -- import (unit) ------------------------------------------------------------------------------------


def test_import_makes_each_ethernetip_device_with_the_identity_and_sizes_the_controller_expects() -> None:
    result = imported()
    devices = devices_by_name(result.document)
    assert list(devices) == ["Gripper", "Conveyor", "Vision"]
    gripper, conveyor, vision = devices.values()
    assert [d["address"] for d in devices.values()] == ["127.0.20.1", "127.0.20.2", "127.0.20.3"]
    assert gripper["model"] == conveyor["model"] == "DSQC1030"
    # -ProductCode 1030 -DeviceType 7 -ProductName "DSQC1030" are DSQC1030's placeholders: no overrides
    assert gripper["identity"] == {"vendor_id": 75}
    assert gripper["assemblies"] == {"output": 100, "input": 101, "configuration": 1, "output_size": 10,
                                     "input_size": 10}
    assert gripper["extra"] == {"VendorName": "ABB Robotics", "Label": "Gripper I/O, DSQC1030 + DSQC1032"}
    assert conveyor["extra"] == {"VendorName": "ABB Robotics", "OutputConnectionType": "POINT2POINT"}
    assert vision["model"] == GENERIC_MODEL
    assert vision["identity"] == {"vendor_id": 283, "device_type": 43, "product_code": 4711,
                                  "product_name": "VS-200 vision sensor"}
    assert vision["assemblies"] == {"output": 150, "input": 100, "configuration": 151, "output_size": 4,
                                    "input_size": 12}
    signals = {s["name"]: s for d in devices.values() for s in d.get("signals", ())}
    assert [s["name"] for s in gripper["signals"]] == ["diGripperClosed", "diGripperOpen", "giGripperState",
                                                       "doGripperClose", "goGripperForce", "aiGripperPos",
                                                       "aoGripperSpeed"]
    assert signals["diGripperOpen"] == {"name": "diGripperOpen", "type": "DI", "device_map": "1", "invert": True,
                                        "extra": {"Label": "open: the sensor's bit is clear"}}
    assert signals["aiGripperPos"] == {
        "name": "aiGripperPos", "type": "AI", "device_map": "16-31", "enc_type": "TWO_COMP", "max_log": 100.0,
        "max_phys": 10.0, "max_phys_limit": 10.0, "max_bit_val": 32767.0, "min_log": -100.0, "min_phys": -10.0,
        "min_phys_limit": -10.0, "min_bit_val": -32767.0, "extra": {"FiltAct": 10}}
    assert signals["doConveyorRun"]["extra"] == {"Label": "belt runs", "PulseLength": 200}
    assert result.signal_count == 16 and result.device_count == 3
    # the written YAML is the document, and it builds: every identity and size as the entry says
    assert yaml.safe_load(result.yaml) == result.document
    profiles = {p.name: p for p in build_profiles(parse_config(result.document), shipped_catalogue())}
    vision_profile = profiles["Vision"]
    assert (vision_profile.vendor_id, vision_profile.device_type, vision_profile.product_code) == (283, 43, 4711)
    assert [(a.role, a.instance_id, a.size) for a in vision_profile.assemblies] == [
        ("output", 150, 4), ("input", 100, 12), ("configuration", 151, 0)]
    # what the entry gave is no longer a placeholder; what it did not give still is
    assert vision_profile.unverified == (f"{GENERIC_MODEL}.identity.revision", f"{GENERIC_MODEL}.assemblies.input_only",
                                         f"{GENERIC_MODEL}.assemblies.listen_only", f"{GENERIC_MODEL}.routing")
    gripper_profile = profiles["Gripper"]
    assert (gripper_profile.vendor_id, gripper_profile.device_type, gripper_profile.product_code,
            gripper_profile.product_name) == (75, 7, 1030, "DSQC1030")  # served as the entry says
    # a value equal to the catalogue's placeholder is no evidence: it stays unverified
    assert {"DSQC1030.identity.product_code", "DSQC1030.identity.device_type",
            "DSQC1030.identity.product_name"} <= set(gripper_profile.unverified)


def test_import_reports_what_it_did_not_import_or_does_not_know() -> None:
    result = imported()
    assert result.warnings == [
        "EIO.cfg:3: INDUSTRIAL_NETWORK (1 entry): not used by the farm, which serves devices and their signals: "
        "not imported, kept as comments",
        "EIO.cfg:10: ETHERNETIP_DEVICE 'Gripper': matched DSQC1030 on an unverified product code: 1030 is the "
        "catalogue's placeholder for DSQC1030, not a published value",
        "EIO.cfg:16: ETHERNETIP_DEVICE 'Conveyor': attribute -OutputConnectionType is unknown to the farm: kept in "
        "extra (eio export writes it back)",
        "EIO.cfg:16: ETHERNETIP_DEVICE 'Conveyor': matched DSQC1030 on an unverified product code: 1030 is the "
        "catalogue's placeholder for DSQC1030, not a published value",
        "EIO.cfg:21: ETHERNETIP_DEVICE 'Vision': vendor 283 product code 4711 is not a model of the catalogue: "
        f"served by {GENERIC_MODEL} with the entry's identity and sizes",
        "EIO.cfg:27: LOCAL_DEVICE (1 entry): devices that are not EtherNet/IP devices the controller scans: not "
        "imported, kept as comments",
        "EIO.cfg:59: EIO_SIGNAL 'doConveyorRun': attribute -PulseLength is unknown to the farm: kept in extra "
        "(eio export writes it back)",
        "EIO.cfg:62: EIO_SIGNAL 'doConveyorSpare': bit 20 is beyond the device's 2-byte output image "
        "(-OutputSize): not imported, kept as a comment",
        "EIO.cfg:75: EIO_SIGNAL 'diDriveReady': device 'DRV_1' is a LOCAL_DEVICE entry, not an EtherNet/IP device: "
        "not imported, kept as a comment",
        "EIO.cfg:77: EIO_SIGNAL 'doCycleOn': no -Device (a virtual signal): not imported, kept as a comment",
        "EIO.cfg:79: EIO_CROSS (1 entry): not used by the farm, which serves devices and their signals: not "
        "imported, kept as comments",
        "EIO.cfg:84: EIO_ACCESS (1 entry): not used by the farm, which serves devices and their signals: not "
        "imported, kept as comments",
        "EIO.cfg:88: ACME_VISION_SETTINGS (1 entry): an unknown section: not imported, kept as comments"]
    comments = [line for line in result.yaml.splitlines() if line.lstrip().startswith("#")]
    # every entry that was not imported is in the YAML as the file had it, and so is every warning
    assert "#   EIO.cfg:90 ACME_VISION_SETTINGS: -Name \"Vision\" -Exposure 1200 -Illumination \"ring\"" in comments
    assert '#   EIO.cfg:77 EIO_SIGNAL: -Name "doCycleOn" -SignalType "DO" -Access "All"' in comments
    assert all(f"#   {warning}" in comments for warning in result.warnings)
    assert "  # EIO.cfg:10 ETHERNETIP_DEVICE 'Gripper', controller address 192.168.125.30" in comments
    assert "  # for numbered channels of add-ons (AI1..), add: addons: [DSQC1032]" in comments


def test_import_keeps_the_controllers_addresses_by_default() -> None:
    devices = devices_by_name(imported(base=None).document)
    assert [d["address"] for d in devices.values()] == ["192.168.125.30", "192.168.125.31", "192.168.125.40"]


def test_renumbering_skips_network_and_broadcast_addresses() -> None:
    devices = imported(base=IPv4Address("127.0.20.254")).document["devices"]
    assert [d["address"] for d in devices] == ["127.0.20.254", "127.0.21.1", "127.0.21.2"]


def _one_device(attributes: str, signals: str = "", section: str = "ETHERNETIP_DEVICE") -> str:
    text = f"EIO:CFG_1.0:7:0::\n#\n{section}:\n\n      {attributes}\n"
    return text + (f"#\nEIO_SIGNAL:\n\n{signals}" if signals else "")


def _import_text(text: str, base: IPv4Address | None = None):
    return import_eio(parse(text), shipped_catalogue(), base)


def test_a_base_model_whose_own_channels_exceed_the_entry_is_served_generically() -> None:
    result = _import_text(_one_device('-Name "Small" -Address "10.0.0.5" -VendorId 75 -ProductCode 1030 '
                                      "-DeviceType 7 -OutputSize 1 -InputSize 1"))
    [device] = result.document["devices"]
    assert device["model"] == GENERIC_MODEL and device["assemblies"] == {"output_size": 1, "input_size": 1}
    assert result.warnings == [
        "EIO.cfg:5: ETHERNETIP_DEVICE 'Small': vendor 75 product code 1030 is catalogue model DSQC1030, but the sizes "
        f"1/1 bytes (in/out) are smaller than its own 2/2: served by {GENERIC_MODEL} with the entry's identity and "
        "sizes"]


def test_devices_the_farm_cannot_serve_are_reported_and_the_rest_imported() -> None:
    text = ("EIO:CFG_1.0::\n#\nETHERNETIP_DEVICE:\n\n"
            '      -Name "a" -Address "10.0.0.5" -VendorId 75 -ProductCode 1030\n'
            '      -Name "b" -VendorId 75 -ProductCode 1030\n'
            '      -Name "A" -Address "10.0.0.6" -VendorId 75 -ProductCode 1030\n'
            '      -Name "c" -Address "10.0.0.5" -VendorId 75 -ProductCode 1030\n'
            '      -Name "d" -Address "10.0.0.7" -VendorId "ABB" -ProductCode 1030 -InputAssembly 100\n'
            '      -Name "e f" -Address "10.0.0.8"\n'
            "#\nEIO_SIGNAL:\n"
            '      -Name "diB" -SignalType "DI" -Device "b" -DeviceMap "0"\n'
            '      -Name "DI3" -SignalType "DI" -Device "a" -DeviceMap "0"\n'
            '      -Name "diTwo" -SignalType "DI" -Device "a" -DeviceMap "0-1"\n'
            '      -Name "xiOdd" -SignalType "XI" -Device "a" -DeviceMap "0"\n'
            '      -Name "giNoMap" -SignalType "GI" -Device "a"\n'
            '      -Name "diOk" -SignalType "DI" -Device "A" -DeviceMap "0"\n'
            '      -Name "DIOK" -SignalType "DI" -Device "a" -DeviceMap "1"\n')
    result = _import_text(text)
    assert [d["name"] for d in result.document["devices"]] == ["a"]
    assert [s["name"] for s in result.document["devices"][0]["signals"]] == ["diOk"]
    assert result.warnings == [
        "EIO.cfg:5: ETHERNETIP_DEVICE 'a': matched DSQC1030 on an unverified product code: 1030 is the catalogue's "
        "placeholder for DSQC1030, not a published value",
        "EIO.cfg:6: ETHERNETIP_DEVICE 'b': no IPv4 -Address (None): not imported, kept as a comment (--base-address "
        "gives every device a farm address)",
        "EIO.cfg:7: ETHERNETIP_DEVICE 'A': a second device of this name: not imported, kept as a comment",
        "EIO.cfg:8: ETHERNETIP_DEVICE 'c': matched DSQC1030 on an unverified product code: 1030 is the catalogue's "
        "placeholder for DSQC1030, not a published value",
        "EIO.cfg:8: ETHERNETIP_DEVICE 'c': the same -Address 10.0.0.5 as device 'a': not imported, kept as a comment "
        "(--base-address gives every device its own)",
        "EIO.cfg:9: ETHERNETIP_DEVICE 'd': -VendorId 'ABB' is not a number in 0..65535: not used (the model's value "
        "is served)",
        f"EIO.cfg:9: ETHERNETIP_DEVICE 'd': no -VendorId or -ProductCode: served by {GENERIC_MODEL} with the entry's "
        "identity and sizes",
        "EIO.cfg:9: ETHERNETIP_DEVICE 'd': devices[0], assemblies: output and input are both instance 100: not "
        "imported, kept as a comment",
        "EIO.cfg:10: ETHERNETIP_DEVICE 'e f': no -Name a farm device can take (letters, digits, _ . -): not imported, "
        "kept as a comment",
        "EIO.cfg:13: EIO_SIGNAL 'diB': device 'b' was not imported: not imported, kept as a comment",
        "EIO.cfg:14: EIO_SIGNAL 'DI3': the name reads as the farm's numbered signal DI3: not imported, kept as a "
        "comment",
        "EIO.cfg:15: EIO_SIGNAL 'diTwo': signal diTwo: a DI maps one bit, not '0-1': not imported, kept as a comment",
        "EIO.cfg:16: EIO_SIGNAL 'xiOdd': type: Input should be 'DI', 'DO', 'GI', 'GO', 'AI' or 'AO' ('XI'): not "
        "imported, kept as a comment",
        "EIO.cfg:17: EIO_SIGNAL 'giNoMap': no -DeviceMap: not imported, kept as a comment",
        "EIO.cfg:19: EIO_SIGNAL 'DIOK': a second signal named 'DIOK' on device 'a': not imported, kept as a comment"]
    assert parse_config(yaml.safe_load(result.yaml))  # what was imported is a valid cell


def test_a_device_entry_of_another_section_with_an_address_and_vendor_is_read_as_ethernetip() -> None:
    result = _import_text(_one_device('-Name "io" -Address "10.0.0.5" -VendorId 75 -ProductCode 1030',
                                      section="EIO_DEVICE"))
    assert [d["name"] for d in result.document["devices"]] == ["io"]
    assert result.warnings == ["EIO.cfg:5: EIO_DEVICE 'io': read as an EtherNet/IP device (it has an IPv4 -Address "
                               "and a -VendorId)",
                               "EIO.cfg:5: EIO_DEVICE 'io': matched DSQC1030 on an unverified product code: 1030 is "
                               "the catalogue's placeholder for DSQC1030, not a published value"]


@pytest.mark.parametrize(("text", "message"), [
    ("SYS:CFG_1.0:6:0::\n#\nCAB_TASK_MODULES:\n\n      -File \"HOME:/m.mod\"\n",
     "EIO.cfg:1: a SYS configuration file, not EIO (the I/O configuration)"),
    ('EIO:CFG_1.0::\n#\nEIO_SIGNAL:\n      -Name "a" -SignalType "DI" -Device "x" -DeviceMap "0"\n',
     "EIO.cfg: no EtherNet/IP device (ETHERNETIP_DEVICE entry) the farm can serve: nothing to import"),
])
def test_a_file_with_nothing_to_serve_is_one_error(text: str, message: str) -> None:
    with pytest.raises(EioError) as raised:
        _import_text(text)
    assert str(raised.value) == message


# -- export and round trips (unit) -------------------------------------------------------------------

CELL = {"devices": [
    {"name": "io{n}", "address": "127.0.30.1", "count": 2, "model": "DSQC1030",
     "signals": [{"name": "diReady", "type": "DI", "device_map": "3", "invert": True},
                 {"name": "goProgram", "type": "GO", "device_map": "8-15", "extra": {"Access": "All", "Default": 3}}]},
    {"name": "analog", "address": "127.0.30.9", "model": "DSQC1030", "addons": ["DSQC1032"],
     "identity": {"product_name": "Analog cell I/O"}, "extra": {"VendorName": "ABB Robotics", "Simulated": True,
                                                                 "ConnectionPriority": "HIGH"},
     "signals": [{"name": "aiTemp", "type": "AI", "device_map": "16-31", "enc_type": "TWO_COMP", "min_log": -50,
                  "max_log": 150.5, "min_bit_val": -32768, "max_bit_val": 32767, "min_phys": -10, "max_phys": 10},
                 {"name": "aoValve", "type": "AO", "device_map": "16-31"}]},
    {"name": "scanner", "address": "127.0.30.10", "model": "GenericAdapter",
     "identity": {"vendor_id": 1, "device_type": 43, "product_code": 77, "product_name": "Gateway"},
     "assemblies": {"output": 150, "input": 151, "configuration": 1, "output_size": 32, "input_size": 64}},
    {"name": "safety", "address": "127.0.30.11", "model": "DSQC1042"},
]}


def _served(document: dict) -> dict[str, tuple]:
    """What a controller sees of each device: address, identity, assemblies and sizes, signals, and
    the attributes kept for its entry."""
    config = parse_config(document)
    profiles = build_profiles(config, shipped_catalogue())
    return {p.name: (p.address, p.vendor_id, p.device_type, p.product_code, p.product_name,
                     [(a.role, a.instance_id, a.size) for a in p.assemblies], [s.model_dump() for s in d.signals],
                     d.extra) for d, p in zip(config.devices, profiles, strict=True)}


def test_export_then_import_gives_back_the_same_devices_and_signals() -> None:
    text = export_eio(parse_config(CELL), shipped_catalogue())
    result = import_eio(parse(text), shipped_catalogue())
    assert _served(result.document) == _served(CELL)
    placeholder = ("matched {0} on an unverified product code: {1} is the catalogue's placeholder for {0}, not a "
                   "published value")
    assert result.warnings == [  # the farm's own output holds nothing else it does not know
        f"EIO.cfg:5: ETHERNETIP_DEVICE 'io1': {placeholder.format('DSQC1030', 1030)}",
        f"EIO.cfg:10: ETHERNETIP_DEVICE 'io2': {placeholder.format('DSQC1030', 1030)}",
        f"EIO.cfg:15: ETHERNETIP_DEVICE 'analog': {placeholder.format('DSQC1030', 1030)}",
        "EIO.cfg:20: ETHERNETIP_DEVICE 'scanner': vendor 1 product code 77 is not a model of the catalogue: served "
        f"by {GENERIC_MODEL} with the entry's identity and sizes",
        f"EIO.cfg:25: ETHERNETIP_DEVICE 'safety': {placeholder.format('DSQC1042', 1042)}"]
    assert all(len(line) <= MAX_LINE for line in text.splitlines())
    assert text.startswith("EIO:CFG_1.0::\n#\nETHERNETIP_DEVICE:\n\n")
    assert '      -Name "safety" -Address "127.0.30.11" -VendorId 75 -ProductCode 1042\\\n' \
           "      -DeviceType 7\n" in text  # no assemblies: identity only; no placeholder product name


def _unverified(document: dict) -> dict[str, tuple[str, ...]]:
    return {p.name: p.unverified for p in build_profiles(parse_config(document), shipped_catalogue())}


def test_export_then_import_keeps_the_placeholders_unverified() -> None:
    before = _unverified(CELL)
    result = import_eio(parse(export_eio(parse_config(CELL), shipped_catalogue())), shipped_catalogue())
    after = _unverified(result.document)
    assert {"DSQC1030.identity.device_type", "DSQC1030.identity.product_code"} <= set(after["io1"])
    for name in ("io1", "io2", "safety"):
        assert after[name] == before[name]
    # EIO.cfg names no add-on: the DSQC1032's own items go with it; the base's stay
    assert after["analog"] == tuple(item for item in before["analog"] if not item.startswith("DSQC1032."))
    # configuration instance 1 is GenericAdapter's placeholder too: given or not, the file cannot tell
    assert set(after["scanner"]) == {*before["scanner"], f"{GENERIC_MODEL}.assemblies.configuration"}
    io1 = devices_by_name(result.document)["io1"]
    assert io1["identity"] == {"vendor_id": 75}  # no placeholder as an override


def test_import_then_export_then_import_is_stable() -> None:
    first = imported()
    text = export_eio(parse_config(first.document), shipped_catalogue())
    second = import_eio(parse(text), shipped_catalogue())
    assert second.document == first.document  # exported addresses are the farm's, kept on import
    assert export_eio(parse_config(second.document), shipped_catalogue()) == text


def test_the_default_cell_exports() -> None:
    from enip_farm.config import default_config_path, load_config

    text = export_eio(load_config(default_config_path()), shipped_catalogue())
    assert text.count("      -Name ") == len(load_config(default_config_path()).devices)


@pytest.mark.parametrize(("change", "message"), [
    ({"extra": {"Address": "1.2.3.4"}}, "device 'io1': extra holds Address, which the export writes from the device"),
    ({"signals": [{"name": "diX", "type": "DI", "device_map": "0", "extra": {"DeviceMap": "1"}}]},
     "device 'io1', signal 'diX': extra holds DeviceMap"),
    ({"identity": {"product_name": 'io "one"'}}, "-ProductName: 'io \"one\"' holds a double quote"),
])
def test_what_eio_cfg_cannot_hold_is_refused_naming_it(change: dict, message: str) -> None:
    config = parse_config({"devices": [{"name": "io1", "address": "127.0.30.1", "model": "DSQC1030", **change}]})
    with pytest.raises(ExportError, match=message.replace("(", r"\(").replace(")", r"\)")):
        export_eio(config, shipped_catalogue())


# -- against a served farm (integration) -------------------------------------------------------------


def _identity(address: str) -> tuple[int, int, int, str]:
    """Vendor, device type, product code and product name from Get Attributes All of the Identity object."""
    with CIPDriver(address) as driver:
        reply = driver.generic_message(service=Services.get_attributes_all, class_code=1, instance=1,
                                       connected=False, route_path=False)
    assert reply.error is None, reply.error
    vendor, device_type, code = struct.unpack_from("<HHH", reply.value)
    name_length = reply.value[14]
    return vendor, device_type, code, reply.value[15:15 + name_length].decode()


def _get(address: str, instance: int, attribute: int) -> bytes:
    with CIPDriver(address) as driver:
        reply = driver.generic_message(service=Services.get_attribute_single, class_code=4, instance=instance,
                                       attribute=attribute, connected=False, route_path=False)
    assert reply.error is None, reply.error
    return reply.value


def _set_outputs(address: str, instance: int, data: bytes) -> None:
    with CIPDriver(address) as driver:
        reply = driver.generic_message(service=Services.set_attribute_single, class_code=4, instance=instance,
                                       attribute=3, request_data=data, connected=False, route_path=False)
    assert reply.error is None, reply.error


def test_an_imported_cell_answers_as_the_controller_expects(enip_farm) -> None:
    cfg = parse(DATA.read_text())
    farm = enip_farm(imported().document)
    for entry in (e for e in cfg.entries if e.section == "ETHERNETIP_DEVICE"):
        address = farm[entry.get("Name")].address
        vendor, device_type, code = entry.get("VendorId"), entry.get("DeviceType"), entry.get("ProductCode")
        assert _identity(address) == (vendor, device_type, code, entry.get("ProductName") or "DSQC1030")
        output, input_, config = entry.get("OutputAssembly"), entry.get("InputAssembly"), \
            entry.get("ConfigurationAssembly")
        assert _get(address, output, 4) == struct.pack("<H", entry.get("OutputSize"))
        assert _get(address, input_, 4) == struct.pack("<H", entry.get("InputSize"))
        # the controller's Forward Open: its electronic key, its connection points, its sizes
        path = bytes([0x20, 0x04, 0x24, config, 0x2C, output, 0x2C, input_])
        key = ElectronicKey(vendor, device_type, code, 0, 0, False)
        with RawClient(address) as client:
            client.register()
            message, triad = forward_open(path=path, key=key, o_t_size=entry.get("OutputSize") + 6,
                                          t_o_size=entry.get("InputSize") + 2)
            assert client.request(message).general_status == 0
            assert client.request(forward_close(triad, path)).general_status == 0
            wrong, _ = forward_open(path=path, key=key._replace(product_code=code + 1),
                                    o_t_size=entry.get("OutputSize") + 6, t_o_size=entry.get("InputSize") + 2)
            reply = client.request(wrong)
            assert (reply.general_status, reply.additional_status[0]) == (0x01, 0x0114)


def test_named_signals_of_an_imported_cell_over_cip(enip_farm) -> None:
    with pytest.warns(EioImportWarning) as caught:
        farm = enip_farm(DATA)  # the fixture imports a controller's EIO.cfg as `eio import` does
    # every warning `eio import` gives, in one Python warning pointing at this test (was: none at all, then
    # one each: 13 per test in pytest's summary)
    lines = import_eio(parse_cfg(DATA.read_text(), str(DATA)), shipped_catalogue()).warnings
    assert [str(w.message) for w in caught] == [f"{DATA}: imported with 13 warnings:\n" + "\n".join(
        f"  {line}" for line in lines)]
    assert {w.filename for w in caught} == {__file__}
    gripper, vision = farm["Gripper"], farm["Vision"]
    gripper.set(diGripperClosed=1, giGripperState=5, aiGripperPos=100.0)
    # bit 0 set; bit 1 clear (diGripperOpen is inverted: it reads 1); bits 4-7 = 5; bits 16-31 = 32767
    assert _get(gripper.address, 101, 3) == bytes([0x51, 0x00, 0xFF, 0x7F]) + bytes(6)
    assert gripper.get("diGripperOpen") == 1
    gripper.set(aiGripperPos=-100.0)
    assert _get(gripper.address, 101, 3)[2:4] == struct.pack("<h", -32767)
    _set_outputs(gripper.address, 100, bytes([0x01, 42]) + struct.pack("<H", 32767) + bytes(6))
    assert gripper.get("doGripperClose") == 1 and gripper.get("goGripperForce") == 42
    assert gripper.get("aoGripperSpeed") == 2.5
    vision.set(giVisionResult=1234, diVisionReady=1, aiVisionAngle=-900)
    assert _get(vision.address, 100, 3) == struct.pack("<HBxh", 1234, 1, -900) + bytes(6)
    _set_outputs(vision.address, 150, bytes([7, 0x01, 0, 0]))
    assert (vision.get("goVisionProgram"), vision.get("doVisionTrigger")) == (7, 1)
    assert vision.signal("aiVisionAngle") == {"name": "aiVisionAngle", "type": "AI", "role": "input", "value": -900}


# -- the CLI (system) ---------------------------------------------------------------------------------


def _cli(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([*CLI, *args], capture_output=True, text=True, timeout=120, cwd=cwd)


@pytest.mark.system
def test_cli_import_validate_export_import(tmp_path: Path) -> None:
    (tmp_path / "EIO.cfg").write_text(DATA.read_text())
    result = _cli("eio", "import", "EIO.cfg", "-o", "cell.yaml", "--base-address", "127.0.20.1", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    lines = result.stderr.splitlines()
    assert lines[:-1] == imported().warnings  # one line each
    assert lines[-1] == "cell.yaml: 3 devices, 16 named signals, 13 warnings"
    assert result.stdout == ""
    assert yaml.safe_load((tmp_path / "cell.yaml").read_text()) == imported().document
    validated = _cli("validate", "cell.yaml", cwd=tmp_path)
    assert (validated.returncode, validated.stdout) == (0, "cell.yaml: 3 devices, valid\n")
    exported = _cli("eio", "export", "--config", "cell.yaml", "-o", "out.cfg", cwd=tmp_path)
    assert (exported.returncode, exported.stderr) == (0, "out.cfg: 3 devices, 16 named signals\n")
    again = _cli("eio", "import", "out.cfg", cwd=tmp_path)  # to stdout
    assert again.returncode == 0
    assert yaml.safe_load(again.stdout) == imported().document
    to_stdout = _cli("eio", "export", "--config", "cell.yaml", cwd=tmp_path)
    assert to_stdout.stdout == (tmp_path / "out.cfg").read_text()


@pytest.mark.system
@pytest.mark.parametrize(("args", "files", "stderr"), [
    (["eio", "import", "bad.cfg", "-o", "cell.yaml"],
     {"bad.cfg": 'EIO:CFG_1.0::\n#\nEIO_SIGNAL:\n      -Name "a" "b"\n      -Label "x\n'},
     'bad.cfg:4: the value "b" follows no -Attribute\nbad.cfg:5: a quoted string is not closed\n'),
    (["eio", "import", "none.cfg"],
     {"none.cfg": 'EIO:CFG_1.0::\n#\nLOCAL_DEVICE:\n      -Name "DRV_1"\n'},
     "none.cfg:3: LOCAL_DEVICE (1 entry): devices that are not EtherNet/IP devices the controller scans: not "
     "imported, kept as comments\nnone.cfg: no EtherNet/IP device (ETHERNETIP_DEVICE entry) the farm can serve: "
     "nothing to import\n"),
    (["eio", "import", "missing.cfg"], {}, "missing.cfg: cannot read: No such file or directory\n"),
    (["eio", "export", "--config", "cell.yaml"],
     {"cell.yaml": "devices:\n  - {name: io1, address: 127.0.30.1, model: DSQC1030, extra: {Address: x}}\n"},
     "device 'io1': extra holds Address, which the export writes from the device itself (identity:, assemblies:, "
     "address)\n"),
    (["eio", "export", "--config", "cell.yaml"],
     {"cell.yaml": "devices:\n  - {name: io1, address: 127.0.30.1, model: DSQC9999}\n"},
     "cell.yaml:2: device 'io1' (devices[0]), model: unknown base model 'DSQC9999'; known: DSQC1030, DSQC1042, "
     f"{GENERIC_MODEL}\n"),
])
def test_cli_errors_are_one_line_each_and_exit_2(tmp_path: Path, args: list[str], files: dict[str, str],
                                                  stderr: str) -> None:
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    result = _cli(*args, cwd=tmp_path)
    assert (result.returncode, result.stderr, result.stdout) == (2, stderr, "")
    assert not (tmp_path / "cell.yaml").exists() or "cell.yaml" in files


@pytest.mark.system
def test_cli_refuses_a_bad_base_address(tmp_path: Path) -> None:
    result = _cli("eio", "import", str(DATA), "--base-address", "127.0.300.1", cwd=tmp_path)
    assert result.returncode == 2 and "--base-address" in result.stderr and "Traceback" not in result.stderr


def test_cli_refuses_a_cut_file_and_writes_nothing(tmp_path: Path) -> None:
    (tmp_path / "EIO.cfg").write_text(_cut(11, "      -VendorId 75 -ProductCode 1030 -DeviceType 7 -OutputAssemb"))
    result = CliRunner().invoke(main, ["eio", "import", str(tmp_path / "EIO.cfg"), "-o", str(tmp_path / "c.yaml")])
    assert (result.exit_code, result.output) == (2, f"{tmp_path / 'EIO.cfg'}:12: the file ends inside this line (no "
                                                 "line break after it): it looks cut short (a copy that stopped?): "
                                                 "take the whole file again; if it is whole, end its last line with a "
                                                 "line break\n")
    assert not (tmp_path / "c.yaml").exists()
