"""The last differences from the spec (issues 22 and 30): class-level Get Attributes All answers the
class attributes each object's definition lists (1, 2, 6, 7 for most; 4 and 5 as counted lists where
they are in it), as real devices and Wireshark's dissectors lay them out; Message Router instance
attribute 2 is the maximum number of connections supported and 3 the number active (Vol. 1,
5-3); the TCP/IP Interface no longer claims a DHCP client it does not run (Vol. 2, 5-4);
and Wireshark's dissectors find no error and no warning in any reply of the objects the farm
serves (a recording of the farm, decoded by tshark)."""

from __future__ import annotations

import shutil
import struct
import subprocess
from pathlib import Path

import pytest

from enip_farm.config import parse_config
from enip_farm.farm.farm import Farm
from enip_farm.protocol.cip import encode_request
from enip_farm.protocol.epath import encode_request_path
from tests.helpers import RawClient
from tests.test_cip_services_unit import ask, make_device


def _gaa(device: object, class_id: int, instance: int = 0) -> bytes:
    reply = ask(device, encode_request(0x01, encode_request_path(class_id, instance)))  # type: ignore[arg-type]
    assert reply.general_status == 0
    return reply.data


#: Class-level Get Attributes All (issue 30, item 4): which class attributes each object returns.
#: Identity, Connection Manager, Assembly: 1, 2, 6, 7 (a real 1769-L23E answers its Identity class
#: `01 00 01 00 07 00 07 00`, and Wireshark decodes these four); Message Router: 1, 4, 5, 6, 7 (as
#: Wireshark's CIP dissector decodes it); TCP/IP Interface and Ethernet Link: 1-7 (Vol. 2; Wireshark's
#: ENIP dissector decodes the seven).
CLASS_GET_ALL = {0x01: (1, 2, 6, 7), 0x02: (1, 4, 5, 6, 7), 0x04: (1, 2, 6, 7), 0x06: (1, 2, 6, 7),
                 0xF5: (1, 2, 3, 4, 5, 6, 7), 0xF6: (1, 2, 3, 4, 5, 6, 7)}


def _class_attribute(device: object, class_id: int, attribute: int) -> bytes:
    reply = ask(device, encode_request(0x0E, encode_request_path(class_id, 0, attribute)))  # type: ignore[arg-type]
    assert reply.general_status == 0, (class_id, attribute)
    return reply.data


@pytest.mark.parametrize(("class_id", "expected"), [
    (0x01, struct.pack("<4H", 1, 1, 7, 8)),
    (0x02, struct.pack("<5H", 1, 0, 0, 7, 3)),
    (0x04, struct.pack("<4H", 2, 0x65, 7, 4)),
    (0x06, struct.pack("<4H", 1, 1, 7, 0)),
    (0xF5, struct.pack("<12H", 4, 1, 1, 7, 6, 8, 9, 10, 11, 12, 13, 0) + struct.pack("<2H", 7, 13)),
    (0xF6, struct.pack("<13H", 4, 1, 1, 8, 4, 5, 6, 7, 8, 9, 10, 11, 1) + struct.pack("<3H", 0x4C, 7, 11)),
])
def test_class_get_attributes_all_answers_the_objects_layout(class_id: int, expected: bytes) -> None:
    device = make_device()
    assert _gaa(device, class_id) == expected
    assert expected == b"".join(_class_attribute(device, class_id, a) for a in CLASS_GET_ALL[class_id])
    for attribute in range(1, 8):  # each class attribute is still there for Get_Attribute_Single
        _class_attribute(device, class_id, attribute)


def test_message_router_attribute_2_is_the_maximum_number_of_connections() -> None:
    device = make_device(implicit={"max_class1_connections": 5, "max_class3_connections": 3})
    attribute = {a: ask(device, encode_request(0x0E, encode_request_path(2, 1, a))) for a in (2, 3)}
    assert attribute[2].data == struct.pack("<H", 8) and attribute[3].data == struct.pack("<H", 0)
    data = _gaa(device, 2, 1)
    assert data[-4:] == struct.pack("<HH", 8, 0)
    (count,) = struct.unpack_from("<H", data)
    assert len(data) == 2 + 2 * count + 4 and count == 6  # object list: 1, 2, 4, 6, 0xF5, 0xF6


def _set_control(device: object, data: bytes) -> int:
    reply = ask(device, encode_request(0x10, encode_request_path(0xF5, 1, 3), data))  # type: ignore[arg-type]
    assert reply.data == b""
    return reply.general_status


def _control(device: object) -> bytes:
    return ask(device, encode_request(0x0E, encode_request_path(0xF5, 1, 3))).data  # type: ignore[arg-type]


def test_tcpip_configuration_control_takes_what_the_capabilities_offer() -> None:
    """Vol. 2, 5-4: attribute 3 is settable (Get/Set); attribute 2 says which methods the device
    offers. With no BOOTP, DNS or DHCP client (capability 0) only static (0) is taken: 0x09 for the
    others and for reserved methods and bits; the wrong size is 0x13 / 0x15."""
    device = make_device()
    capability = ask(device, encode_request(0x0E, encode_request_path(0xF5, 1, 2)))
    assert capability.data == bytes(4)  # no BOOTP, no DNS, no DHCP client, configuration not settable
    assert _set_control(device, bytes(4)) == 0x00
    for control in (1, 2, 3, 0x0F, 0x10, 0x12, 0x20, 0x8000_0000):  # BOOTP, DHCP, reserved, DNS, reserved bits
        assert _set_control(device, struct.pack("<I", control)) == 0x09, control
    assert _set_control(device, bytes(3)) == 0x13 and _set_control(device, bytes(5)) == 0x15
    assert _control(device) == bytes(4)


def test_tcpip_configuration_control_with_dhcp_and_dns_offered() -> None:
    device = make_device()
    tcpip = device._tcpip
    tcpip.capability = 0x04 | 0x02  # a DHCP and a DNS client
    assert _set_control(device, struct.pack("<I", 0x12)) == 0x00  # DHCP, DNS enabled
    assert _control(device) == b"\x12\x00\x00\x00"
    assert _set_control(device, struct.pack("<I", 1)) == 0x09  # BOOTP: not offered
    assert _control(device) == b"\x12\x00\x00\x00"
    tcpip.restore_defaults()  # Identity Reset type 1: out of the box, static
    assert _control(device) == bytes(4)


_CLASSES = (0x01, 0x02, 0x04, 0x06, 0xF5, 0xF6, 0x39, 0x3A)


def _requests(model: str, address: str) -> list[bytes]:
    requests = []
    for class_id in _CLASSES:
        for instance in (0, 1):
            requests.append(encode_request(0x01, encode_request_path(class_id, instance)))
            requests.extend(encode_request(0x0E, encode_request_path(class_id, instance, attribute))
                            for attribute in range(1, 14 if instance == 0 else 30))
    requests += [encode_request(0x01, encode_request_path(0x04, instance)) for instance in (100, 101)]
    requests += [encode_request(0x10, encode_request_path(0xF5, 1, 3), bytes(4)),
                 encode_request(0x10, encode_request_path(0xF5, 1, 8), b"\x05"),
                 encode_request(0x4C, encode_request_path(0xF6, 1, 4))]
    if model == "DSQC1042":  # the Safety Supervisor's services, accepted and refused
        node = struct.pack("<I", int.from_bytes(bytes(map(int, address.split("."))), "big"))
        tunid = bytes.fromhex("0000000000b7") + node
        supervisor = encode_request_path(0x39, 1)
        requests += [encode_request(0x57, supervisor, tunid), encode_request(0x56, supervisor, tunid),
                     encode_request(0x57, supervisor, tunid), encode_request(0x56, supervisor, b"\xff" * 10),
                     encode_request(0x54, supervisor, b"\x00" + bytes(16) + b"\xff" * 10),
                     encode_request(0x54, supervisor, b"\x02" + bytes(16) + tunid + b"\x04"),
                     encode_request(0x54, supervisor, b"\x01" + bytes(16) + tunid),
                     encode_request(0x01, supervisor), encode_request(0x0E, encode_request_path(0x39, 1, 28))]
    return requests


@pytest.mark.system
@pytest.mark.skipif(shutil.which("tshark") is None, reason="tshark (Debian) is not installed; .ci/run installs it")
@pytest.mark.parametrize("model", ["DSQC1030", "DSQC1042"])
def test_tshark_finds_no_error_in_any_reply_of_the_farm_objects(free_address, tmp_path: Path, model: str) -> None:
    address = free_address()
    recording = tmp_path / "objects.pcap"
    farm = Farm(parse_config({"devices": [{"name": "d", "address": address, "model": model}], "discovery": False}),
                record=recording)
    requests = _requests(model, address)
    with farm.running_in_thread(), RawClient(address) as client:
        client.register()
        statuses = [client.request(request).general_status for request in requests]
    assert statuses.count(0) > len(requests) // 4  # a real mix of answers and refusals
    expert = subprocess.run(["tshark", "-r", str(recording), "-q", "-z", "expert"], capture_output=True, text=True,
                            timeout=120)
    assert expert.returncode == 0, expert.stderr
    assert "Errors (" not in expert.stdout and "Warnings (" not in expert.stdout, expert.stdout
    listing = subprocess.run(["tshark", "-r", str(recording), "-Y", "cip"], capture_output=True, text=True,
                             timeout=120).stdout
    assert "Malformed" not in listing
    assert listing.count("Success: TCP/IP Interface - Get Attributes All") == 2
    assert listing.count("Success: Ethernet Link - Get Attributes All") == 2


_CLASS_FIELDS = {1: ("cip.class_revision",), 2: ("cip.class.max_inst", "cip.max_instance"),
                 3: ("cip.class.num_inst", "cip.num_instance"), 4: ("cip.num_attr", "cip.attr_num"),
                 5: ("cip.num_service", "cip.service_code"), 6: ("cip.num_class_attr",), 7: ("cip.num_inst_attr",)}


def _uints(data: bytes) -> list[int]:
    return list(struct.unpack(f"<{len(data) // 2}H", data))


@pytest.mark.system
@pytest.mark.skipif(shutil.which("tshark") is None, reason="tshark (Debian) is not installed; .ci/run installs it")
def test_tshark_decodes_every_field_of_the_class_level_get_attributes_all(free_address, tmp_path: Path) -> None:
    """Wireshark's dissectors decode each class-level reply field by field to the values the
    farm's Get_Attribute_Single gives, and leave nothing undissected (the Assembly class, which
    they do not dissect, is held to its bytes)."""
    address = free_address()
    recording = tmp_path / "classes.pcap"
    farm = Farm(parse_config({"devices": [{"name": "d", "address": address, "model": "DSQC1030"}],
                              "discovery": False}), record=recording)
    with farm.running_in_thread(), RawClient(address) as client:
        client.register()
        for class_id in CLASS_GET_ALL:
            assert client.request(encode_request(0x01, encode_request_path(class_id, 0))).general_status == 0
    fields = ["cip.class", "cip.data"] + [name for names in _CLASS_FIELDS.values() for name in names]
    command = ["tshark", "-r", str(recording), "-Y", "cip.rr == 1", "-T", "fields", "-E", "occurrence=a"]
    out = subprocess.run(command + [arg for name in fields for arg in ("-e", name)], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr
    device = make_device(address=address)
    decoded = {}
    for line in out.stdout.splitlines():
        values = dict(zip(fields, line.split("\t"), strict=True))
        decoded[int(values.pop("cip.class"), 16)] = values
    assert sorted(decoded) == sorted(CLASS_GET_ALL)
    for class_id, layout in CLASS_GET_ALL.items():
        values = decoded[class_id]
        if class_id == 0x04:  # not dissected at class level: its bytes
            assert values["cip.data"] == _gaa(device, 0x04).hex()
            continue
        assert values["cip.data"] == "", f"class 0x{class_id:02X}: undissected {values['cip.data']}"
        seen = {}
        for attribute, names in _CLASS_FIELDS.items():
            found = [int(value, 0) for name in names for value in values[name].split(",") if value]
            if found:
                seen[attribute] = found
        expected = {a: _uints(_class_attribute(device, class_id, a)) for a in layout}
        assert seen == expected, f"class 0x{class_id:02X}"
