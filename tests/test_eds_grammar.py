"""The EDS grammar and reader on what real tools write and on real defects: vendor sections and
keywords, brace lists, comments anywhere (also between a value and its comma), quoted and unquoted
EPATHs, empty sections, CRLF, Latin-1, `[ParamN]` in a path; every defect refused at once as
`file:line: reason`; a non-numeric VendCode is an error; an EDS without class-1 entries is an
explicit-only device; a heartbeat-only exclusive owner does not hide the data-carrying one."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest

from enip_farm.device.profile_file import write_profile
from enip_farm.eds.grammar import decode_eds_bytes, parse_eds_text
from enip_farm.eds.reader import EdsError, eds_profile, read_eds
from tests.helpers import RawClient, forward_open_message

DEVICE = """[File]
        DescText = "Tiny";
        1_RSNetWorx_CNetTool = 0x0000, {1, 2, {3, 4}}, "x";  $ a vendor keyword with a brace list
[Device]
        VendCode = 283;
        VendName = "Hilscher GmbH";
        ProdType = 12;
        ProdCode = 7;
        MajRev = 1;
        MinRev = 2;
        ProdName = "Gr\xe4fin";        $ Latin-1
[Device Classification]
[75_BusName]
        Anything = some words here, 12;
"""

PARAMS = """[Params]
        Param1 = 0, ,, 0x0000, 0xC8, 4, "RPI", "us", "", 2000, 100000, 10000, ,,,, ,,,, ;
        Param2 = 0, ,, 0x0010, 0xC7, 2, "Out size", "", "", 0, 64, 8, ,,,, ,,,, ;
        Param3 = 0, ,, 0x0010, 0xC6, 1, "Out point", "", "", 150, 150, 150, ,,,, ,,,, ;
"""

CONNECTIONS = """[Connection Manager]
        Connection1 =
                0x04010002, 0x44640305,       $ exclusive owner, heartbeat both ways
                Param1, 0, ,
                Param1, 0, ,
                ,, ,,
                "Heartbeat owner", "",
                "20 04 24 01 2C 97 2C 98";
        Connection2 =
                0x04010002,
                0x44640405
                $ a comment between a value and its comma
                , Param1, Param2, ,
                Param1, 4 $ here too
                , ,
                ,, ,,
                "Data", "",
                "20 04 24 01 2C [Param3] 2C 64";
[Port]
        Port1 = TCP, "EtherNet/IP", 20 F5 24 01, 2;   $ an unquoted EPATH
[Empty Section]
"""


def _eds(*parts: str, newline: str = "\n") -> str:
    return "".join(parts).replace("\n", newline)


@pytest.mark.parametrize("newline", ["\n", "\r\n"])
def test_what_real_tools_write_is_read(newline: str) -> None:
    text = _eds(DEVICE, PARAMS, CONNECTIONS, newline=newline)
    parsed = parse_eds_text(decode_eds_bytes(text.encode("latin-1")))
    assert parsed.errors == []
    vendor = parsed.entry("File", "1_RSNetWorx_CNetTool")
    assert [v.kind for v in vendor.values] == ["bare", "list", "string"]
    assert vendor.values[1].text == "{1, 2, {3, 4}}" and vendor.values[1].items[2].items[1].text == "4"
    assert parsed.entry("75_BusName", "Anything").values[0].text == "some words here"
    assert parsed.entry("Port", "Port1").values[2].text == "20 F5 24 01"
    assert parsed.sections["Empty Section"].entries == {}
    device = read_eds(text, "tiny.eds")
    assert (device.vendor_id, device.product_code, device.revision, device.product_name) == (283, 7, (1, 2), "Gräfin")
    heartbeat, data = device.connections
    assert (heartbeat.o_t_size, heartbeat.t_o_size, heartbeat.o_t_format, heartbeat.t_o_format) == (0, 0, 3, 0)
    assert (data.o_t_size, data.t_o_size, data.rpi, data.rpi_default) == (8, 4, (2000, 100000), 10000)
    assert data.points == (1, 150, 100) and data.path_bytes == bytes.fromhex("20 04 24 01 2C 96 2C 64")
    assert device.params["Param2"].read_only and not device.params["Param1"].read_only


def test_a_heartbeat_only_owner_does_not_hide_the_data_connection() -> None:
    _, document, notes = eds_profile(read_eds(_eds(DEVICE, PARAMS, CONNECTIONS), "tiny.eds"), "tiny.eds")
    model = document["models"]["Gräfin"]
    assert model["assemblies"] == {"output": 150, "input": 100, "configuration": 1}  # Connection2's, not 0x97/0x98
    assert model["sizes"] == {"output": 8, "input": 4, "configuration": 0}
    assert [(c["entry"], c["o_t"], c["t_o"], c["o_t_size"], c["t_o_size"], c["o_t_format"]) for c in
            model["connections"]] == [("Connection1", 151, 152, 0, 0, "heartbeat"),
                                      ("Connection2", 150, 100, 8, 4, "run/idle")]
    assert model["points"] == {1: 0, 100: 4, 150: 8, 151: 0, 152: 0} and notes == []


def test_every_defect_is_refused_at_once_with_its_line() -> None:
    text = _eds(DEVICE.replace("VendCode = 283;", 'VendCode = "ABB";').replace("ProdCode = 7;", "ProdCode = 7"),
                PARAMS.replace("150, 150, 150", "150, 150, 300"),
                CONNECTIONS.replace('"Data", "",', '"Data", "'))
    with pytest.raises(EdsError) as raised:
        read_eds(text, "bad.eds")
    lines = str(raised.value).splitlines()
    assert lines == [
        "bad.eds:5: [Device] VendCode = 'ABB': a number is required (the vendor id ODVA assigned, not the vendor's "
        "name)",
        "bad.eds:9: '=' where a value was expected: a ';' missing at the end of the entry before?",  # after line 8
        "bad.eds:18: [Params] Param3: default 300 is outside its limits 150..150",
        "bad.eds:27: [Connection Manager] Connection2: 14 fields, 15 expected",  # the string swallowed two
        "bad.eds:35: a string without its closing quote on the same line",
    ]


def test_a_reference_to_nothing_and_a_short_entry_are_defects() -> None:
    text = _eds(DEVICE, PARAMS, CONNECTIONS.replace("Param1, 4 $ here too", "Param9, 4 $ here too")
                .replace('"Heartbeat owner", "",\n                "20 04 24 01 2C 97 2C 98";', '"x";'))
    with pytest.raises(EdsError) as raised:
        read_eds(text, "bad.eds")
    assert str(raised.value).splitlines() == [
        "bad.eds:20: [Connection Manager] Connection1: 13 fields, 15 expected",
        "bad.eds:31: [Connection Manager] Connection2: T->O RPI Param9 is not in [Params]"]


def test_not_an_eds_is_one_line() -> None:
    with pytest.raises(EdsError, match=r"^notes.txt:1: not an EDS file: unexpected '#'$"):
        read_eds("# a markdown file\n", "notes.txt")


def test_a_device_without_class_1_entries_is_explicit_only(enip_farm, tmp_path: Path) -> None:
    text = _eds(DEVICE, "[Assembly]\n        Assem5 = \"Status\", \"20 04 24 05 30 03\", 6, 0x0000, , ;\n")
    name, document, notes = eds_profile(read_eds(text, "bridge.eds"), "bridge.eds")
    model = document["models"][name]
    assert "assemblies" not in model and model["connections"] == [] and model["points"] == {5: 6}
    assert notes == ["no class-1 connection entry the farm serves: an explicit-only device (identity and its "
                     "assemblies)"]
    profile = tmp_path / "bridge.yaml"
    write_profile(profile, document, "made from bridge.eds by the test", notes)
    farm = enip_farm(name="bridge", model=str(profile))
    with RawClient(farm["bridge"].address) as client:
        client.register()
        assert client.get(1, 1, 1).data == struct.pack("<H", 283)
        assert client.get(1, 1, 7).data == b"\x06Gr\xe4fin"  # SHORT_STRING: the name's Latin-1 bytes
        assert client.get(4, 5, 4).data == struct.pack("<H", 6)
        refused = client.request(forward_open_message(bytes.fromhex("20 04 24 01 2C 05 2C 05"), 6, 8, 10_000, 1))
        assert (refused.general_status, refused.additional_status) == (0x01, (0x0129,))  # no configuration assembly
