"""The exported EDS of a DSQC1042 (issue 22, item 4): its safe assemblies and its two safety
connections, checked by eds-pie without a warning, read back by the farm's reader, and each
connection's path and sizes admitted by the farm's own safety target as a SafetyOpen."""

from __future__ import annotations

import datetime

from enip_farm.device.catalogue import shipped_catalogue
from enip_farm.eds.reader import eds_profile, parse_eds, read_eds
from enip_farm.eds.writer import SAFETY_INPUT, SAFETY_OUTPUT, model_profile, write_eds
from enip_farm.protocol.epath import LogicalSegment, LogicalType, decode_epath
from tests.test_safety_supervisor import make_device, open_safety

CREATED = datetime.datetime(2024, 5, 6, 7, 8, 9)


def _text() -> str:
    return write_eds(model_profile("DSQC1042", (), shipped_catalogue()), CREATED)


def test_dsqc1042_eds_has_its_safety_connections_and_eds_pie_finds_nothing_wrong() -> None:
    eds, messages = parse_eds(_text())
    assert messages == []
    for keyword, expected in (("Assem100", ["Safe Outputs", "20 04 24 64 30 03", 1]),
                              ("Assem101", ["Safe Inputs", "20 04 24 65 30 03", 2])):
        assert [f.value for f in eds.get_entry("Assembly", keyword).fields][:3] == expected
    names = [eds.get_value("Connection Manager", f"Connection{n}", 12) for n in (1, 2)]
    assert names == ["Safety Output", "Safety Input"]
    assert eds.get_value("Capacity", "MaxIOConnections") == 8


def test_the_farm_reads_the_safety_connections_back_and_its_target_admits_them() -> None:
    device = read_eds(_text(), "DSQC1042.eds")
    assert device.notes == () and (device.vendor_id, device.product_code) == (75, 1042)
    output, inputs = device.connections
    assert (output.kind, output.transport_classes, output.o_t_size, output.t_o_size, output.points) == (
        "exclusive owner", SAFETY_OUTPUT, 1, 0, (1, 100, 0))
    assert (inputs.kind, inputs.transport_classes, inputs.o_t_size, inputs.t_o_size, inputs.points) == (
        "input only", SAFETY_INPUT, 0, 2, (1, 0, 101))
    assert output.transport_class == inputs.transport_class == 0  # class 0: CIP Safety
    assert output.rpi == inputs.rpi == (1_000, 100_000)
    target = make_device()
    for connection, server, trigger in ((output, True, SAFETY_OUTPUT), (inputs, False, SAFETY_INPUT)):
        assert bool(trigger >> 31) == server  # bit 31: the target is the server of the safe outputs
        points = tuple(s.value for s in decode_epath(bytes.fromhex(connection.path))
                       if isinstance(s, LogicalSegment) and s.type is not LogicalType.CLASS_ID)
        assert open_safety(target, server=server, points=points) == 0
    # an EDS import serves class-1 entries only: the safety target imports as explicit-only, and says why
    _, document, notes = eds_profile(device, "DSQC1042.eds")
    assert "connections" not in document
    assert notes[:2] == [
        "Connection1 'Safety Output' (exclusive owner, path 20 04 24 01 2C 64 2C 00): transport class 0; "
        "only class-1 entries are served",
        "Connection2 'Safety Input' (input only, path 20 04 24 01 2C 00 2C 65): transport class 0; "
        "only class-1 entries are served"]
