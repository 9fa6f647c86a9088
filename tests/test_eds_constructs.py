"""EDS constructs of real vendors' files that used to stop an import or be served wrong (issue 30):
a stray line holding only a bare word before an entry (skipped with a warning); a connection whose
path is "SYMBOL_ANSI", a tag the user names (the file imports, that entry is kept out with a
warning); a configuration assembly the EDS sizes only through its [Assembly] entry (served at that
size, and a Forward Open carrying that much configuration data is accepted)."""

from __future__ import annotations

import struct
from pathlib import Path

from enip_farm.device.profile_file import write_profile
from enip_farm.eds.grammar import parse_eds_text
from enip_farm.eds.reader import eds_profile, read_eds
from tests.helpers import RawClient
from tests.test_eds_grammar import DEVICE, PARAMS, _eds
from tests.test_eds_real import _close, _open

ASSEMBLY = """[Assembly]
        Assem120 = "Configuration", "20 04 24 78 30 03", 26, 0x0000, , ;
"""
CONNECTIONS = """[Connection Manager]
        Connection1 =
                0x04010002, 0x44640405,         $ exclusive owner, run/idle O->T
                Param1, 8, ,
                Param1, 4, ,
                ,, ,,                           $ no configuration size: the [Assembly] entry's
                "Data", "",
                "20 04 24 78 2C 96 2C 64";
        Connection2 =
                0x04010002, 0x44640405,
                Param1, 8, ,
                Param1, 4, ,
                ,, ,,
                "Tag Connection", "",
                "SYMBOL_ANSI";
"""
STRAY = PARAMS.replace("        Param2 =", "Param3\n        Param2 =")  # a bare word alone on line 17
TEXT = _eds(DEVICE, STRAY, ASSEMBLY, CONNECTIONS)


def test_a_stray_word_alone_on_its_line_is_skipped_with_a_warning() -> None:
    parsed = parse_eds_text(TEXT)
    assert parsed.errors == []
    assert parsed.warnings == [(17, "'Param3' alone on its line (no '=', no ';'): skipped")]
    assert list(parsed.sections["Params"].entries) == ["Param1", "Param2", "Param3"]  # the real Param3 is read
    assert parsed.entry("Params", "Param2").values[6].text == "Out size"
    for text, line in (("[A]\n  B\n[C]\n  D = 1;\n", 2), ("[A]\n  X = 1;\n  B  $ comment\n\n", 3),
                       ("[A]\r\n  B\r\n  B = 2;\r\n", 2)):  # before a section, at the end, CRLF
        found = parse_eds_text(text)
        assert (found.errors, found.warnings) == ([], [(line, "'B' alone on its line (no '=', no ';'): skipped")])


def test_a_missing_semicolon_is_still_an_error() -> None:
    parsed = parse_eds_text("[A]\n  X = 1\n  Y = 2;\n")
    assert parsed.errors == [(3, "'=' where a value was expected: a ';' missing at the end of the entry before?")]
    assert parsed.warnings == []


def test_the_file_imports_with_its_warnings() -> None:
    name, document, notes = eds_profile(read_eds(TEXT, "robot.eds"), "robot.eds")
    model = document["models"][name]
    assert notes == [
        "line 36: [Connection Manager] Connection2 'Tag Connection': path 'SYMBOL_ANSI': a tag the user names (ANSI "
        "extended symbol segment), not assembly points; not served",
        "line 17: 'Param3' alone on its line (no '=', no ';'): skipped",
    ]
    assert [c["entry"] for c in model["connections"]] == ["Connection1"]
    assert model["assemblies"] == {"output": 150, "input": 100, "configuration": 120}
    assert model["sizes"] == {"output": 8, "input": 4, "configuration": 26}
    assert model["points"] == {100: 4, 120: 26, 150: 8}
    assert model["connections"][0]["configuration_size"] == 26


def test_the_configuration_assembly_is_served_at_its_eds_size(enip_farm, tmp_path: Path) -> None:
    device = read_eds(TEXT, "robot.eds")
    name, document, notes = eds_profile(device, "robot.eds")
    profile = tmp_path / "robot.yaml"
    write_profile(profile, document, "made from robot.eds by the test", notes)
    farm = enip_farm(name="robot", model=str(profile))
    entry = document["models"][name]["connections"][0]
    path = bytes.fromhex("20 04 24 78 2C 96 2C 64")
    with RawClient(farm["robot"].address) as client:
        client.register()
        assert client.get(4, 120, 4).data == struct.pack("<H", 26)
        assert client.get(4, 120, 3).data == bytes(26)
        with_data = path + bytes((0x80, 13)) + bytes(range(26))  # a simple data segment: 13 words
        reply, triad = _open(client, with_data, entry, 1, False)
        assert (reply.general_status, reply.additional_status) == (0, ())
        _close(client, triad, path)
        short = path + bytes((0x80, 12)) + bytes(24)  # data for another configuration
        reply, _ = _open(client, short, entry, 2, False)
        assert (reply.general_status, reply.additional_status) == (0x01, (0x0129,))


def test_an_assembly_entry_naming_a_tag_is_not_served() -> None:
    text = _eds(DEVICE, PARAMS, ASSEMBLY + '        Assem7 = "Tag", "SYMBOL_ANSI", 4, 0x0000, , ;\n', CONNECTIONS)
    name, document, notes = eds_profile(read_eds(text, "tags.eds"), "tags.eds")
    assert notes[0] == ("line 21: [Assembly] Assem7: path 'SYMBOL_ANSI': a tag the user names, not an assembly "
                        "instance; not served")
    assert 7 not in document["models"][name]["points"]
