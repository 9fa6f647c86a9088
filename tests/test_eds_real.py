"""Real vendors' EDS files (tests/data/eds/, README there names each one's source): each is read
by the grammar without an error, imported, served, and checked over CIP with the project's codec
as the peer: identity, every assembly's size, a Forward Open per class-1 connection entry with the
entry's own path, sizes and RPI (accepted), then class-1 I/O both ways on the main connection."""

from __future__ import annotations

import socket
import struct
from pathlib import Path

import pytest
import yaml

from enip_farm.device.catalogue import Catalogue
from enip_farm.device.profile_file import write_profile
from enip_farm.eds.grammar import decode_eds_bytes, parse_eds_text
from enip_farm.eds.reader import EdsDevice, eds_profile, read_eds
from enip_farm.protocol.cip import encode_request
from enip_farm.protocol.commands import SocketAddress, encode_sockaddr
from enip_farm.protocol.connection import (
    ConnectionTriad,
    ConnectionType,
    ForwardCloseRequest,
    ForwardOpenRequest,
    NetworkParameters,
    decode_forward_open_reply,
    decode_io_packet,
    encode_forward_close,
    encode_forward_open,
    encode_io_packet,
)
from enip_farm.protocol.cpf import ItemType
from enip_farm.protocol.epath import encode_request_path
from tests.helpers import ROOT, RawClient, wait_for
from tests.scanners import scanner

pytestmark = pytest.mark.class1_paths  # both class-1 paths (tests/conftest.py)

REAL = ROOT / "tests" / "data" / "eds"
FILES = sorted(p.name for p in REAL.glob("*.eds"))
#: What each file declares: (vendor id, product code, class-1 connection entries).
EXPECTED = {
    "abb_robotics_anybus_enip_fa.eds": (75, 28, 5),
    "eds_pie_demo.eds": (65535, 1, 1),
    "esp32p4_opener.eds": (55512, 1, 3),
    "esp32p4_opener_file_object.eds": (55512, 1, 3),
    "mettler_toledo_m800.eds": (666, 2048, 2),
    "opener_sample_app.eds": (1, 65001, 3),
    "opener_sample_app_2012.eds": (1, 200, 3),
    "sick_inspector_pi50.eds": (808, 131, 19),
    "teknic_clearlink.eds": (424, 1, 4),
    "yaskawa_mp3300iec.eds": (44, 132, 8),
}
P2P, MULTICAST = ConnectionType.POINT_TO_POINT, ConnectionType.MULTICAST
SEQUENCE, HEADER = 2, 4


def _read(name: str) -> tuple[EdsDevice, str, dict, list[str]]:
    text = decode_eds_bytes((REAL / name).read_bytes())
    device = read_eds(text, name)
    model_name, document, notes = eds_profile(device, name)
    return device, model_name, document, notes


def test_a_model_is_named_after_the_whole_product_name_in_safe_characters() -> None:
    """Issue 30: `ABB EtherNet/IP Anybus Adapter Device` made the model `ABB_EtherNet/IP_Anybus_Adapter_D`
    (cut at the identity object's 32 characters, a slash in it)."""
    device, model_name, document, notes = _read("abb_robotics_anybus_enip_fa.eds")
    assert device.product_name == "ABB EtherNet/IP Anybus Adapter Device"
    assert model_name == "ABB_EtherNet_IP_Anybus_Adapter_Device"
    assert document["models"][model_name]["identity"]["product_name"] == "ABB EtherNet/IP Anybus Adapter D"
    assert "product name 'ABB EtherNet/IP Anybus Adapter Device' cut to 32 characters" in notes


def test_the_real_files_are_ten_from_at_least_five_vendors() -> None:
    assert FILES == sorted(EXPECTED) and len(FILES) == 10
    assert len({vendor for vendor, _, _ in EXPECTED.values()}) == 8


@pytest.mark.parametrize("name", FILES)
def test_every_real_file_is_read_and_imported(name: str) -> None:
    raw = (REAL / name).read_bytes()
    parsed = parse_eds_text(decode_eds_bytes(raw))
    assert parsed.errors == []
    device, model_name, document, _ = _read(name)
    vendor, product, entries = EXPECTED[name]
    assert (device.vendor_id, device.product_code) == (vendor, product)
    model = document["models"][model_name]
    assert len(model["connections"]) == entries  # every class-1 entry is served
    Catalogue.from_document(document)  # the profile is a valid catalogue document


def _wire(entry: dict, direction: str) -> int:
    form, size = entry[f"{direction}_format"], entry[f"{direction}_size"]
    if form == "heartbeat":
        return SEQUENCE
    return SEQUENCE + (HEADER if form == "run/idle" else 0) + size


def _rpi(entry: dict) -> int:
    low, high = entry.get("rpi_us") or (2_000, 10_000_000)
    return min(max(20_000, low), high)


def _path(device: EdsDevice, entry: dict) -> bytes:
    return next(c.path_bytes for c in device.connections if c.keyword == entry["entry"])


def _open(client: RawClient, path: bytes, entry: dict, serial: int, multicast: bool, port: int = 0):
    triad = ConnectionTriad(serial, 0x1234, 0xABCD)
    request = ForwardOpenRequest(
        0x0A, 0x0E, 0, 0x7E570000 + serial, triad, 1, _rpi(entry),
        NetworkParameters(False, P2P, 2, False, _wire(entry, "o_t")), _rpi(entry),
        NetworkParameters(False, MULTICAST if multicast else P2P, 2, False, _wire(entry, "t_o")), 0x01, path,
        max(_wire(entry, "o_t"), _wire(entry, "t_o")) > 511)
    message = encode_request(0x5B if request.large else 0x54, encode_request_path(6, 1), encode_forward_open(request))
    items = [(ItemType.SOCKADDR_T_O, encode_sockaddr(SocketAddress("0.0.0.0", port)))] if port else []
    reply, _ = client.request_items(message, items)
    return reply, triad


def _close(client: RawClient, triad: ConnectionTriad, path: bytes) -> None:
    message = encode_request(0x4E, encode_request_path(6, 1),
                             encode_forward_close(ForwardCloseRequest(0x0A, 0x0E, triad, path)))
    assert client.request(message).general_status == 0


def _served_farm(enip_farm, tmp_path: Path, name: str):
    device, model_name, document, _ = _read(name)
    profile = tmp_path / "profile.yaml"
    write_profile(profile, document, f"made from {name} by the test")
    farm = enip_farm(name="dev", model=str(profile), implicit={"first_watchdog_s": 30})
    return device, document["models"][model_name], farm


@pytest.mark.parametrize("name", FILES)
def test_a_real_file_is_served_as_its_eds_says(enip_farm, tmp_path: Path, name: str) -> None:
    device, model, farm = _served_farm(enip_farm, tmp_path, name)
    accepted, refused = 0, []
    with RawClient(farm["dev"].address) as client:
        client.register()
        for attribute, value in ((1, struct.pack("<H", device.vendor_id)), (2, struct.pack("<H", device.device_type)),
                                 (3, struct.pack("<H", device.product_code)), (4, bytes(device.revision))):
            assert client.get(1, 1, attribute).data == value
        product = device.product_name[:32].encode("latin-1")
        assert client.get(1, 1, 7).data == bytes((len(product),)) + product
        for instance, size in model["points"].items():
            assert client.get(4, instance, 4).data == struct.pack("<H", size), instance
            assert len(client.get(4, instance, 3).data) == size, instance
        serial = 1
        for entry in model["connections"]:
            path = _path(device, entry)
            owner = None
            if entry["kind"] == "listen only":  # it needs a multicast T->O opened by another connection
                owner_entry = next(e for e in model["connections"] if e["t_o"] == entry["t_o"]
                                   and e["kind"] in ("exclusive owner", "input only") and e["t_o_multicast"])
                serial += 1
                reply, owner = _open(client, _path(device, owner_entry), owner_entry, serial, True)
                assert reply.general_status == 0, (owner_entry["entry"], reply)
            serial += 1
            multicast = entry["kind"] == "listen only" or not entry["t_o_point_to_point"]
            reply, triad = _open(client, path, entry, serial, multicast)
            if reply.general_status == 0:
                accepted += 1
                _close(client, triad, path)
            else:
                refused.append((entry["entry"], hex(reply.general_status), reply.additional_status))
            if owner is not None:
                _close(client, owner, _path(device, owner_entry))
    assert refused == [] and accepted == EXPECTED[name][2]


@pytest.mark.parametrize("name", ["opener_sample_app.eds", "teknic_clearlink.eds", "sick_inspector_pi50.eds"])
def test_io_both_ways_on_the_main_connection(enip_farm, tmp_path: Path, name: str) -> None:
    device, model, farm = _served_farm(enip_farm, tmp_path, name)
    main = next(e for e in model["connections"] if e["o_t"] == model["assemblies"]["output"]
                and e["t_o"] == model["assemblies"]["input"])
    inputs = bytes((n + 1) & 0xFF for n in range(main["t_o_size"]))
    outputs = bytes((7 * n) & 0xFF for n in range(main["o_t_size"]))
    farm["dev"].set_inputs(inputs)
    path = _path(device, main)
    with RawClient(farm["dev"].address) as client, socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as udp:
        client.register()
        udp.bind(("127.0.0.1", 0))
        udp.settimeout(5)
        reply, triad = _open(client, path, main, 1, False, udp.getsockname()[1])
        assert reply.general_status == 0, reply
        opened = decode_forward_open_reply(reply.data)
        header = b"\x01\x00\x00\x00" if main["o_t_format"] == "run/idle" else b""
        udp.sendto(encode_io_packet(opened.o_t_connection_id, 1, 1, header + outputs), (farm["dev"].address, 2222))
        assert wait_for(lambda: farm["dev"].outputs == outputs)
        packet = decode_io_packet(udp.recv(2048))
        t_o_header = b"\x01\x00\x00\x00" if main["t_o_format"] == "run/idle" else b""
        assert packet is not None and packet.data == t_o_header + inputs
        _close(client, triad, path)


def test_a_cell_names_eds_files_as_models(enip_farm, tmp_path: Path) -> None:
    cell = tmp_path / "cell.yaml"
    (tmp_path / "vendor").mkdir()
    for name in ("teknic_clearlink.eds", "sick_inspector_pi50.eds"):
        (tmp_path / "vendor" / name).write_bytes((REAL / name).read_bytes())
    cell.write_text(yaml.safe_dump({"devices": [
        {"name": "drive", "address": "127.0.0.1", "model": str(tmp_path / "vendor" / "teknic_clearlink.eds")},
        {"name": "camera", "address": "127.0.0.1", "model": str(tmp_path / "vendor" / "sick_inspector_pi50.eds")}]}))
    farm = enip_farm(str(cell))
    for name, vendor, size in (("drive", 424, 332), ("camera", 808, 36)):
        with RawClient(farm[name].address) as client:
            client.register()
            assert client.get(1, 1, 1).data == struct.pack("<H", vendor)
            assert len(farm[name].inputs) == size


@pytest.mark.parametrize("name", FILES)
def test_export_writes_every_served_connection_and_both_readers_read_it_back(name: str) -> None:
    import datetime

    from enip_farm.eds.reader import eds_catalogue, parse_eds
    from enip_farm.eds.writer import model_profile, write_eds

    _, _, document, _ = _read(name)
    original = next(iter(document["models"].values()))
    text = write_eds(model_profile(str(REAL / name), (), eds_catalogue()), datetime.datetime(2024, 5, 6))
    exported = read_eds(text, "exported.eds")
    model = next(iter(eds_profile(exported, "exported.eds")[1]["models"].values()))

    def served(connections: list[dict]) -> list[dict]:
        return [{k: v for k, v in c.items() if k not in ("entry", "name")} for c in connections]

    assert served(model["connections"]) == served(original["connections"])
    assert model["points"] == original["points"]
    eds, messages = parse_eds(text)  # eds-pie: no warning, and the same entries
    assert messages == []
    for connection in exported.connections:
        fields = [f.value for f in eds.get_entry("Connection Manager", connection.keyword).fields]
        assert (fields[0], fields[1], fields[3] or 0, fields[6] or 0, fields[14]) == (
            connection.transport_classes, connection.parameters, connection.o_t_size, connection.t_o_size,
            connection.path)


def test_params_are_parameter_object_instances_with_limits_and_access(enip_farm, tmp_path: Path) -> None:
    device, model, farm = _served_farm(enip_farm, tmp_path, "mettler_toledo_m800.eds")
    parameters = {p["instance"]: p for p in model["parameters"]}
    assert len(parameters) == len([k for k in device.params if k.startswith("Param")])
    settable = next(p for p in parameters.values() if not p["descriptor"] & 0x10 and p["data_type"] in (0xC7, 0xC8)
                    and p.get("minimum") is not None and p.get("maximum") is not None
                    and p["minimum"] < p["maximum"] and p["maximum"] < 2 ** (8 * p["size"]) - 1)
    read_only = next((p for p in parameters.values() if p["descriptor"] & 0x10), None)
    with RawClient(farm["dev"].address) as client:
        client.register()
        for number, parameter in parameters.items():
            value = client.get(0x0F, number, 1).data
            assert len(value) == parameter["size"] and client.get(0x0F, number, 5).data == bytes(
                (parameter["data_type"],)), number
            if parameter["data_type"] in (0xC6, 0xC7, 0xC8) and "default" in parameter:
                assert int.from_bytes(value, "little") == parameter["default"], number
        size, number = settable["size"], settable["instance"]
        assert client.set(0x0F, number, 1, int(settable["maximum"]).to_bytes(size, "little")).general_status == 0
        assert client.get(0x0F, number, 1).data == int(settable["maximum"]).to_bytes(size, "little")
        assert client.set(0x0F, number, 1, int(settable["maximum"] + 1).to_bytes(size, "little")).general_status == 0x09
        assert client.set(0x0F, number, 1, bytes(size + 1)).general_status == 0x15
        if read_only is not None:
            assert client.set(0x0F, read_only["instance"], 1, bytes(read_only["size"])).general_status == 0x0E


def test_the_ethernetip_scanner_opens_an_eds_made_device(enip_farm, tmp_path: Path) -> None:
    """A real scanner (PyPI's `ethernetip`) opens OpENer's sample EDS's exclusive owner (config 151,
    O->T 150, T->O 100, 32 bytes each way) on the device made from that EDS, and I/O goes both ways."""
    _, _, farm = _served_farm(enip_farm, tmp_path, "opener_sample_app.eds")
    address = farm["dev"].address
    with scanner(address, t_o=(100, 32), o_t=(150, 32), configuration=151) as scan:
        assert scan.forward_open(10, 2) == 0
        scan.outputs[3] = scan.outputs[255] = True
        scan.conn.produce()
        assert wait_for(lambda: farm["dev"].outputs == b"\x08" + bytes(30) + b"\x80")
        farm["dev"].set_inputs(b"\x01" + bytes(30) + b"\x40")
        assert wait_for(lambda: [i for i, bit in enumerate(scan.inputs) if bit] == [0, 254])
        scan.conn.stopProduce()
        assert scan.forward_close() == 0
