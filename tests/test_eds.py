"""Electronic Data Sheets: `eds export` writes an EDS eds-pie parses without a warning and whose
identity, assembly sizes and connection points a running device of the model answers over CIP;
`eds import` makes a profile of a vendor's EDS (written by hand, with comments and continued
lines) and of an exported one, and the farm serves it as the EDS says."""

from __future__ import annotations

import datetime
import logging
import struct
import subprocess
import threading
from pathlib import Path

import pytest
import yaml

from enip_farm.config import parse_config
from enip_farm.device.build import build_profiles
from enip_farm.device.catalogue import shipped_catalogue
from enip_farm.device.profile_file import write_profile
from enip_farm.eds.reader import EdsError, _eds_pie_messages, eds_profile, parse_eds, read_eds
from enip_farm.eds.writer import model_profile, write_eds
from enip_farm.protocol.epath import LogicalSegment, LogicalType, decode_epath
from tests.helpers import CLI, ROOT, RawClient, forward_open_message

VENDOR_EDS = ROOT / "tests" / "data" / "example_adapter.eds"
CREATED = datetime.datetime(2024, 5, 6, 7, 8, 9)
MODELS = [("DSQC1030", ()), ("DSQC1030", ("DSQC1031",)), ("DSQC1030", ("DSQC1032",)),
          ("DSQC1030", ("DSQC1031", "DSQC1032", "DSQC1033")), ("DSQC1042", ())]


def _export(model: str, addons: tuple[str, ...] = ()) -> str:
    return write_eds(model_profile(model, addons, shipped_catalogue()), CREATED)


@pytest.mark.parametrize(("model", "addons"), MODELS)
def test_exported_eds_parses_with_eds_pie_without_a_warning(model: str, addons: tuple[str, ...]) -> None:
    text = _export(model, addons)
    eds, messages = parse_eds(text)
    assert messages == []  # eds-pie's checker: no error, no warning
    assert eds.protocol == "EtherNetIP"
    assert eds.get_value("File", "CreateDate") == "05-06-2024" and eds.get_value("Device", "VendCode") == 75
    profile = model_profile(model, addons, shipped_catalogue())
    for item in profile.unverified:  # every placeholder of the catalogue is marked
        assert f"$ UNVERIFIED: {item}\n" in text
    assert f"ProdCode = {profile.product_code};  $ UNVERIFIED placeholder\n" in text
    assert "[Connection Manager]" in text  # class-1 connections, or the DSQC1042's safety connections


def test_exported_members_describe_the_farm_layout() -> None:
    eds, _ = parse_eds(_export("DSQC1030", ("DSQC1032",)))
    output = [f.value for f in eds.get_entry("Assembly", "Assem100").fields]
    assert output[2] == 10 and output[6:] == [16, "Param2", 16, "Param3", 16, "Param4", 16, "Param5", 16, "Param6"]
    assert [eds.get_value("Params", f"Param{n}", 6) for n in (2, 3, 6, 7, 8)] == [
        "DSQC1030 DO1-16", "DSQC1032 AO1", "DSQC1032 AO4", "DSQC1030 DI1-16", "DSQC1032 AI1"]
    rpi = [f.value for f in eds.get_entry("Params", "Param1").fields]
    assert (rpi[6], rpi[9], int(rpi[10]), int(rpi[11])) == ("RPI", 2000, 10_000_000, 10_000)


def _points(path: str) -> list[int]:
    return [s.value for s in decode_epath(bytes.fromhex(path)) if isinstance(s, LogicalSegment)
            and s.type in (LogicalType.INSTANCE_ID, LogicalType.CONNECTION_POINT)]


def _check_against_device(eds, client: RawClient, serials: int = 0) -> int:
    """Identity, assembly sizes and every connection entry of an EDS held against a device; the
    number of connections opened."""
    for attribute, value in ((1, struct.pack("<H", eds.get_value("Device", "VendCode"))),
                             (2, struct.pack("<H", eds.get_value("Device", "ProdType"))),
                             (3, struct.pack("<H", eds.get_value("Device", "ProdCode"))),
                             (4, bytes((eds.get_value("Device", "MajRev"), eds.get_value("Device", "MinRev"))))):
        assert client.get(1, 1, attribute).data == value
    name = eds.get_value("Device", "ProdName").encode()
    assert client.get(1, 1, 7).data == bytes((len(name),)) + name
    for keyword, entry in eds.get_section("Assembly").entries.items():
        if not keyword.startswith("Assem"):
            continue
        fields = [f.value for f in entry.fields]
        instance = _points(fields[1])[0]
        size = fields[2] if fields[2] != "" else sum(fields[6::2]) // 8
        assert client.get(4, instance, 4).data == struct.pack("<H", size), keyword
        assert len(client.get(4, instance, 3).data) == size, keyword
    rpi_default = int(eds.get_value("Params", "Param1", 11))
    section = eds.get_section("Connection Manager")
    opened = 0
    for number, (keyword, entry) in enumerate(section.entries.items(), 1):
        if not keyword.startswith("Connection"):
            continue
        fields = [f.value for f in entry.fields]
        transport, parameters = fields[0], fields[1]
        o_t_header = 4 if parameters >> 8 & 7 == 4 else 0  # real-time format 4: the run/idle header
        assert parameters >> 12 & 7 == 0  # T->O modeless
        multicast = not parameters >> 22 & 1  # listen only: no point-to-point T->O
        message = forward_open_message(bytes.fromhex(fields[14]), 2 + o_t_header + int(fields[3] or 0),
                                       2 + int(fields[6]), rpi_default, serials + number,
                                       t_o_multicast=multicast or bool(transport >> 26 & 1))
        reply = client.request(message)
        assert (reply.general_status, reply.additional_status) == (0, ()), (keyword, reply)
        opened += 1
    return opened


@pytest.mark.parametrize("addons", [(), ("DSQC1032",), ("DSQC1031", "DSQC1033")])
def test_exported_eds_matches_the_device_over_cip(enip_farm, addons: tuple[str, ...]) -> None:
    farm = enip_farm(name="io1", model="DSQC1030", addons=list(addons))
    eds, _ = parse_eds(_export("DSQC1030", addons))
    with RawClient(farm["io1"].address) as client:
        client.register()
        assert _check_against_device(eds, client) == 3  # exclusive owner, input only, listen only
    kinds = sorted(c.kind.name for c in farm.device("io1").connections.values())
    assert kinds == ["EXCLUSIVE_OWNER", "INPUT_ONLY", "LISTEN_ONLY"]


EXAMPLE_MODEL = {
    "kind": "base",
    "description": "from example_adapter.eds: Example Vendor (test data) EX-IO 8DI/8DO/2AI, catalog EX-IO-882",
    "identity": {"vendor_id": 65500, "device_type": 12, "product_code": 4711, "revision": [3, 12],
                 "product_name": "EX-IO 8DI/8DO/2AI"},
    "assemblies": {"output": 150, "input": 100, "configuration": 151, "input_only": 152, "listen_only": 153},
    "sizes": {"output": 6, "input": 8, "configuration": 10},
    "configuration_data": "03000000000000000000",  # Assem151's members: Param2 (default 3), Param3, Param4
    "rpi_us": [1000, 750000],
    "io": {},
    "points": {100: 8, 101: 2, 150: 6, 151: 10, 152: 0, 153: 0},
    "unverified": ["io layout"],
}
#: (entry, kind, configuration, O->T, T->O, O->T size, T->O size, O->T format, T->O multicast, point to point)
EXAMPLE_CONNECTIONS = [
    ("Connection1", "exclusive owner", 151, 150, 100, 6, 8, "run/idle", True, True),
    ("Connection2", "input only", 151, 152, 100, 0, 8, "heartbeat", True, True),
    ("Connection3", "listen only", 151, 153, 100, 0, 8, "heartbeat", True, False),
    ("Connection4", "input only", 151, 152, 101, 0, 2, "heartbeat", True, True),
]


@pytest.mark.parametrize("newline", ["\n", "\r\n"])
def test_import_a_vendors_eds(newline: str) -> None:
    text = VENDOR_EDS.read_text().replace("\n", newline)
    name, document, notes = eds_profile(read_eds(text, "example_adapter.eds"), "example_adapter.eds")
    model = document["models"][name]
    connections = model.pop("connections")
    parameters = model.pop("parameters")
    assert [(p["instance"], p["name"], p.get("default")) for p in parameters] == [
        (1, "RPI", 10000), (2, "Digital inputs", 0), (3, "Digital outputs", 0), (4, "Analog input", 0),
        (5, "T->O size", 8), (6, "Filter time", 3)]
    assert name == "EX-IO_8DI_8DO_2AI" and document == {"models": {name: EXAMPLE_MODEL}}
    assert [(c["entry"], c["kind"], c["configuration"], c["o_t"], c["t_o"], c["o_t_size"], c["t_o_size"],
             c["o_t_format"], c["t_o_multicast"], c["t_o_point_to_point"]) for c in connections] == EXAMPLE_CONNECTIONS
    assert {c["t_o_format"] for c in connections} == {"modeless"} and {tuple(c["rpi_us"]) for c in connections} == {
        (1000, 750000)}
    assert notes == []  # the vendor section [65500_Diagnostics] and [Port] are kept, not warned about


def test_import_refuses_what_it_cannot_serve() -> None:
    text = VENDOR_EDS.read_text()
    with pytest.raises(EdsError, match=r"^x.eds:2: not an EDS file: 'DescText' where an entry or a section was "
                       "expected$"):
        read_eds("[File\nDescText = 1;\n", "x.eds")
    with pytest.raises(EdsError, match=r"^x.eds:\d+: \[Device\] has no ProdCode$"):
        read_eds(text.replace("ProdCode = 4711;", ""), "x.eds")
    too_big = text.replace("Param1,,Assem150,", "Param1,500,Assem150,")
    _, document, notes = eds_profile(read_eds(too_big, "x.eds"), "x.eds")
    assert [c["entry"] for c in document["models"]["EX-IO_8DI_8DO_2AI"]["connections"]] == [
        "Connection2", "Connection3", "Connection4"]
    assert notes == ["Connection1 'Exclusive Owner' (exclusive owner, path 20 04 24 97 2C 96 2C 64): o_t_size 500 is "
                     "beyond the farm's 496 bytes; not served"]
    with pytest.raises(EdsError, match="^'DSQC1030' is a model of the catalogue: a profile never replaces one, choose "
                                       "another name$"):
        eds_profile(read_eds(text, "x.eds"), "x.eds", name="DSQC1030")
    renamed = text.replace('ProdName = "EX-IO 8DI/8DO/2AI";', 'ProdName = "DSQC1030";')
    assert eds_profile(read_eds(renamed, "x.eds"), "x.eds")[0] == "DSQC1030_eds"


def _write_profile(path: Path, document: dict) -> Path:
    return write_profile(path, document, "a test's profile")


def test_imported_vendor_profile_is_served_as_the_eds_says(enip_farm, tmp_path: Path) -> None:
    _, document, _ = eds_profile(read_eds(VENDOR_EDS.read_text(), "example_adapter.eds"), "example_adapter.eds")
    farm = enip_farm(name="ex", model=str(_write_profile(tmp_path / "ex.yaml", document)))
    eds, _ = parse_eds(VENDOR_EDS.read_text())
    with RawClient(farm["ex"].address) as client:
        client.register()
        for instance, size in ((150, 6), (100, 8), (151, 10)):
            assert client.get(4, instance, 4).data == struct.pack("<H", size)
        for attribute, value in ((1, b"\xdc\xff"), (2, b"\x0c\x00"), (3, b"\x67\x12"), (4, b"\x03\x0c"),
                                 (7, b"\x11EX-IO 8DI/8DO/2AI")):
            assert client.get(1, 1, attribute).data == value
        owner = forward_open_message(bytes.fromhex("20 04 24 97 2C 96 2C 64"), 2 + 4 + 6, 2 + 8, 10_000, 1,
                                     t_o_multicast=True)
        assert client.request(owner).general_status == 0
        for serial, point in ((2, 0x98), (3, 0x99)):  # input only, listen only
            heartbeat = forward_open_message(bytes((0x20, 0x04, 0x24, 0x97, 0x2C, point, 0x2C, 0x64)), 2, 2 + 8,
                                             10_000, serial, t_o_multicast=True)
            assert client.request(heartbeat).general_status == 0
        status_only = forward_open_message(bytes.fromhex("20 04 24 97 2C 98 2C 65"), 2, 4, 10_000, 4)
        assert client.request(status_only).general_status == 0  # Connection4: its own T->O point, 2 bytes
        other = forward_open_message(bytes.fromhex("20 04 24 97 2C 98 2C 66"), 2, 4, 10_000, 5)
        refused = client.request(other)  # no entry produces 0x66
        assert (refused.general_status, refused.additional_status) == (0x01, (0x012B,))
    assert eds.get_value("Device", "ProdCode") == 4711


def test_export_import_round_trip(enip_farm, tmp_path: Path) -> None:
    addons = ("DSQC1031", "DSQC1032")
    text = _export("DSQC1030", addons)
    name, document, notes = eds_profile(read_eds(text, "dsqc1030.eds"), "dsqc1030.eds")
    model = document["models"][name]
    built_in = model_profile("DSQC1030", addons, shipped_catalogue())
    assert name == "DSQC1030_eds"  # never the built-in model's name
    assert model["identity"] == {"vendor_id": 75, "device_type": built_in.device_type,
                                 "product_code": built_in.product_code, "revision": list(built_in.revision),
                                 "product_name": "DSQC1030"}
    assert model["assemblies"] == {"output": 100, "input": 101, "configuration": 1, "input_only": 198,
                                   "listen_only": 199}
    assert model["sizes"] == {"output": built_in.output_size, "input": built_in.input_size, "configuration": 0} \
        == {"output": 12, "input": 12, "configuration": 0}
    assert notes == []
    profile = _write_profile(tmp_path / "imported.yaml", document)
    farm = enip_farm({"devices": [{"name": "built_in", "model": "DSQC1030", "addons": list(addons)},
                                  {"name": "imported", "model": str(profile)}]})
    eds, _ = parse_eds(text)
    with RawClient(farm["built_in"].address) as a, RawClient(farm["imported"].address) as b:
        a.register(), b.register()
        for path in ((1, 1, 1), (1, 1, 2), (1, 1, 3), (1, 1, 4), (1, 1, 5), (1, 1, 7), (4, 100, 4), (4, 101, 4),
                     (4, 100, 3), (4, 101, 3)):
            assert a.get(*path) == b.get(*path), path
        assert _check_against_device(eds, b) == 3


def test_export_import_keeps_the_placeholders_unverified(tmp_path: Path) -> None:
    addons = ("DSQC1031", "DSQC1032")
    built_in = model_profile("DSQC1030", addons, shipped_catalogue())
    name, document, _ = eds_profile(read_eds(_export("DSQC1030", addons), "dsqc1030.eds"), "dsqc1030.eds")
    # was ["io layout"] alone: every placeholder the EDS marks is still one
    assert document["models"][name]["unverified"] == [
        "io layout", *(item.removeprefix("DSQC1030.") for item in built_in.unverified)]
    assert {"identity.product_code", "identity.device_type", "DSQC1032.analog scaling"} \
        <= set(document["models"][name]["unverified"])
    profile_file = _write_profile(tmp_path / "imported.yaml", document)
    [imported] = build_profiles(parse_config({"devices": [{"name": "x", "address": "127.0.0.1",
                                                           "model": str(profile_file)}]}), shipped_catalogue())
    assert f"{name}.identity.product_code" in imported.unverified


def test_an_eds_without_unverified_comments_has_only_its_io_layout_unverified() -> None:
    _, document, _ = eds_profile(read_eds(VENDOR_EDS.read_text(), "vendor.eds"), "vendor.eds", "Vendor")
    assert document["models"]["Vendor"]["unverified"] == ["io layout"]


def test_reading_an_eds_puts_the_eds_pie_logger_level_back() -> None:
    logger = logging.getLogger("eds_pie")
    before = logger.level
    try:
        for level in (logging.ERROR, logging.NOTSET):
            logger.setLevel(level)
            read_eds(VENDOR_EDS.read_text(), "vendor.eds")
            assert logger.level == level  # was left at INFO for the rest of the process
            assert logger.handlers == []
    finally:
        logger.setLevel(before)


def test_each_read_collects_its_own_thread_messages_only() -> None:
    other = threading.Thread(target=lambda: logging.getLogger("eds_pie.eds").warning("another read's warning"))
    with _eds_pie_messages() as messages:
        other.start()
        other.join()
        logging.getLogger("eds_pie.eds").warning("this read's warning")
    assert messages.messages == ["this read's warning"]  # was both: one collector heard every thread


@pytest.mark.system
def test_eds_commands(tmp_path: Path) -> None:
    exported = tmp_path / "dsqc1030.eds"
    result = subprocess.run([*CLI, "eds", "export", "DSQC1030", "--addons", "DSQC1031,DSQC1032", "-o", str(exported)],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stderr.startswith(f"{exported}: EDS of DSQC1030 + DSQC1031 + DSQC1032; UNVERIFIED: ")
    assert parse_eds(exported.read_text())[1] == []
    profile = tmp_path / "p.yaml"
    result = subprocess.run([*CLI, "eds", "import", str(exported), "-o", str(profile)], capture_output=True,
                            text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.splitlines()[0] == (
        f"{profile}: model DSQC1030_eds, assemblies {{'output': 100, 'input': 101, 'configuration': 1, "
        "'input_only': 198, 'listen_only': 199}, sizes {'output': 12, 'input': 12, 'configuration': 0}, "
        "3 class-1 connections")
    assert list(yaml.safe_load(profile.read_text())["models"]) == ["DSQC1030_eds"]
    for args, message in (
            (["export", "DSQC9", "-o", str(tmp_path / "x.eds")],
             "eds export: unknown model 'DSQC9'; known: DSQC1030, DSQC1042"),
            (["import", str(ROOT / "README.md"), "-o", str(tmp_path / "x.yaml")],
             f"{ROOT / 'README.md'}:1: not an EDS"),
            (["import", str(tmp_path / "missing.eds"), "-o", str(tmp_path / "x.yaml")],
             f"{tmp_path / 'missing.eds'}: No such file or directory")):
        result = subprocess.run([*CLI, "eds", *args], capture_output=True, text=True, timeout=120)
        assert result.returncode == 2 and result.stderr.startswith(message), result.stderr
        assert len(result.stderr.splitlines()) == 1 and not (tmp_path / "x.yaml").exists()


@pytest.mark.system
def test_reading_an_eds_leaves_the_process_logging_alone() -> None:
    """eds-pie calls logging.basicConfig(level=DEBUG) when imported; through the reader it changes
    nothing (else every later debug message of the process would be printed)."""
    script = ("import logging; from enip_farm.eds.reader import read_eds; "
              f"read_eds(open({str(VENDOR_EDS)!r}).read(), 'x'); "
              "root = logging.getLogger(); print(root.level, root.handlers, logging.getLogger('eds_pie').handlers)")
    result = subprocess.run([*CLI[:1], "-c", script], capture_output=True, text=True, timeout=120)
    assert (result.returncode, result.stdout, result.stderr) == (0, "30 [] []\n", "")
