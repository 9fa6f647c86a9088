"""The Safety Supervisor (class 0x39) of the DSQC1042 (issue 22, item 1): its attributes as
Wireshark's CIP Safety dissector numbers them, Propose_TUNID / Apply_TUNID, Safety_Reset types 0, 1
and 2 with password, TUNID and attribute bit map, their effect on the TUNID, SCID, ownership and
open safety connections, and what Identity Resets keep. Every malformed or refused request
changes nothing."""

from __future__ import annotations

import struct

import pytest

from enip_farm.config import DeviceConfig
from enip_farm.device.catalogue import shipped_catalogue
from enip_farm.device.device import Device
from enip_farm.device.profile import resolve
from enip_farm.protocol.cip import decode_reply, encode_request
from enip_farm.protocol.connection import encode_forward_open
from enip_farm.protocol.epath import encode_request_path
from enip_farm.protocol.safety.crc import crc_s4
from enip_farm.protocol.safety.segment import Unid
from enip_farm.protocol.session import MessageContext
from tests.test_safety import MS, NODE, ORIGINATOR, OUNID, SNN, T0, TUNID, safety_open

SCID = bytes.fromhex("78563412") + bytes.fromhex("010203040506")
UNSET = b"\xff" * 10
PASSWORD = bytes(16)
NEW_TUNID = Unid(bytes.fromhex("0000000000b7"), NODE)


def make_device(scid: bytes = bytes(10)) -> Device:
    config = DeviceConfig(name="s1", address="127.0.77.1", model="DSQC1042", safety={"scid": scid.hex()})
    return Device(resolve(config, shipped_catalogue()))


def ask(device: Device, service: int, data: bytes = b"", attribute: int | None = None, instance: int = 1,
        class_id: int = 0x39, now: int = T0):  # noqa: ANN201
    path = encode_request_path(class_id, instance, attribute) if attribute else encode_request_path(class_id, instance)
    context = MessageContext(ORIGINATOR.host, None, (), now)
    reply, _ = device.handle_unconnected(encode_request(service, path, data), context)
    return decode_reply(reply)


def attribute(device: Device, number: int) -> bytes:
    reply = ask(device, 0x0E, attribute=number)
    assert reply.general_status == 0, hex(reply.general_status)
    return reply.data


def open_safety(device: Device, **kwargs: object) -> int:
    message = encode_request(0x54, encode_request_path(6, 1), encode_forward_open(safety_open(**kwargs)))
    reply, _ = device.handle_unconnected(message, MessageContext(ORIGINATOR.host, None, (), T0))
    decoded = decode_reply(reply)
    return decoded.general_status if not decoded.additional_status else decoded.additional_status[0]


def reset_request(kind: int, password: bytes = PASSWORD, tunid: Unid = TUNID, preserve: int | None = None) -> bytes:
    return bytes((kind,)) + password + tunid.encode() + (bytes((preserve,)) if preserve is not None else b"")


def test_attributes_as_wireshark_numbers_them() -> None:
    device = make_device(SCID)
    assert attribute(device, 11) == b"\x02"  # idle: TUNID set, no safety connection
    assert attribute(device, 12) == b"\x00" and attribute(device, 24) == b"\x00"
    assert attribute(device, 25) == bytes(10)  # no configuration owner
    assert attribute(device, 26) == SCID and attribute(device, 27) == TUNID.encode()
    assert attribute(device, 28) == b"\x00\x00" and attribute(device, 29) == UNSET
    assert open_safety(device, scid=SCID) == 0
    assert attribute(device, 11) == b"\x04"  # executing
    path = bytes((0x20, 0x04, 0x24, 100))
    assert attribute(device, 28) == struct.pack("<H", 1) + OUNID.encode() + bytes((len(path),)) + path
    assert ask(device, 0x10, b"\x01", attribute=24).general_status == 0x0E
    everything = ask(device, 0x01)
    assert everything.general_status == 0 and everything.data.startswith(b"\x04\x00")


def test_propose_then_apply_sets_the_tunid_and_the_tcpip_safety_network_number() -> None:
    device = make_device()
    assert ask(device, 0x57, NEW_TUNID.encode()).general_status == 0x0C  # no proposal pending
    assert ask(device, 0x56, NEW_TUNID.encode()).general_status == 0
    assert attribute(device, 29) == NEW_TUNID.encode()
    assert ask(device, 0x57, TUNID.encode()).general_status == 0x0C  # not the proposed one
    assert attribute(device, 27) == TUNID.encode()
    assert ask(device, 0x57, NEW_TUNID.encode()).general_status == 0
    assert attribute(device, 27) == NEW_TUNID.encode() and attribute(device, 29) == UNSET
    tcpip = ask(device, 0x0E, attribute=7, class_id=0xF5)
    assert tcpip.data == NEW_TUNID.snn
    assert open_safety(device) == 0x080E  # the old TUNID no longer matches
    assert open_safety(device, tunid=NEW_TUNID) == 0


def test_propose_cancelled_by_all_ff_and_malformed_requests_change_nothing() -> None:
    device = make_device()
    assert ask(device, 0x56, NEW_TUNID.encode()).general_status == 0
    assert ask(device, 0x56, UNSET).general_status == 0  # cancel
    assert attribute(device, 29) == UNSET
    assert ask(device, 0x57, NEW_TUNID.encode()).general_status == 0x0C
    assert ask(device, 0x56, NEW_TUNID.encode()[:9]).general_status == 0x13
    assert ask(device, 0x56, NEW_TUNID.encode() + b"\x00").general_status == 0x15
    assert ask(device, 0x56, Unid(SNN, NODE + 1).encode()).general_status == 0x20  # another node address
    assert ask(device, 0x56, NEW_TUNID.encode(), instance=0).general_status == 0x08
    assert attribute(device, 29) == UNSET and attribute(device, 27) == TUNID.encode()


def test_no_tunid_change_while_a_safety_connection_is_open() -> None:
    device = make_device()
    assert open_safety(device) == 0
    assert ask(device, 0x56, NEW_TUNID.encode()).general_status == 0x10
    assert attribute(device, 29) == UNSET


@pytest.mark.parametrize(("data", "status"), [
    (b"", 0x13),
    (reset_request(3), 0x20),
    (reset_request(0)[:-1], 0x13),
    (reset_request(0) + b"\x00", 0x15),
    (reset_request(2), 0x13),  # type 2 needs the attribute bit map
    (reset_request(2, preserve=0x40), 0x20),
    (reset_request(2, preserve=0x80), 0x20),
    (reset_request(1, password=b"\x01" + bytes(15)), 0x0F),  # wrong password
    (reset_request(1, tunid=NEW_TUNID), 0x20),  # not this device's TUNID
])
def test_refused_safety_resets_change_nothing(data: bytes, status: int) -> None:
    device = make_device(SCID)
    assert open_safety(device, scid=SCID) == 0
    before = {number: attribute(device, number) for number in (11, 25, 26, 27, 28)}
    assert ask(device, 0x54, data).general_status == status
    assert {number: attribute(device, number) for number in (11, 25, 26, 27, 28)} == before
    assert len(device.connections) == 1


def test_safety_reset_type_0_closes_the_safety_connections_and_keeps_the_configuration() -> None:
    device = make_device(SCID)
    assert open_safety(device, scid=SCID) == 0 and open_safety(device, server=False, scid=SCID) == 0
    assert ask(device, 0x54, reset_request(0), now=T0 + MS).general_status == 0
    assert device.connections == {}
    assert [e.text for e in device.events.of_kind("safe state")][0].endswith("safety reset (type 0)")
    assert attribute(device, 26) == SCID and attribute(device, 27) == TUNID.encode()
    assert attribute(device, 11) == b"\x02"
    assert open_safety(device, scid=SCID) == 0


def test_safety_reset_type_1_is_out_of_box_waiting_for_a_tunid() -> None:
    device = make_device(SCID)
    assert open_safety(device, scid=SCID) == 0
    assert ask(device, 0x54, reset_request(1)).general_status == 0
    assert device.connections == {}
    assert attribute(device, 27) == UNSET and attribute(device, 26) == bytes(10)
    assert attribute(device, 11) == b"\x08"  # waiting for TUNID
    assert open_safety(device) == 0x080D  # TUNID not set
    assert ask(device, 0x56, TUNID.encode()).general_status == 0
    assert ask(device, 0x57, TUNID.encode()).general_status == 0
    assert attribute(device, 11) == b"\x02" and open_safety(device) == 0


@pytest.mark.parametrize(("preserve", "tunid_after"), [(0x00, UNSET), (0x04, TUNID.encode()), (0x3F, TUNID.encode())])
def test_safety_reset_type_2_keeps_what_the_bit_map_preserves(preserve: int, tunid_after: bytes) -> None:
    device = make_device(SCID)
    assert open_safety(device, scid=SCID) == 0
    assert ask(device, 0x54, reset_request(2, preserve=preserve)).general_status == 0
    assert device.connections == {} and attribute(device, 28) == b"\x00\x00"
    assert attribute(device, 27) == tunid_after and attribute(device, 26) == bytes(10)


def test_identity_resets_keep_the_tunid_types_1_and_2_clear_the_safety_configuration() -> None:
    for kind, scid_after in ((0, SCID), (1, bytes(10)), (2, bytes(10))):
        device = make_device(SCID)
        assert ask(device, 0x05, bytes((kind,)), class_id=1).general_status == 0
        assert attribute(device, 11) == b"\x01"  # self-testing in the reset window
        assert attribute(device, 27) == TUNID.encode() and attribute(device, 26) == scid_after


CONFIGURATION = bytes.fromhex("0102030405060708")
OTHER_OWNER = Unid(bytes.fromhex("0000000000cc"), 2)


def signed(data: bytes, scts: bytes = bytes.fromhex("0a0b0c0d0e0f")) -> bytes:
    """The SCID of configuration `data`: SCCRC = CRC-S4 over it, then the SCTS."""
    return struct.pack("<I", crc_s4(data)) + scts


def test_type_1_safety_open_configures_the_target_and_makes_its_originator_the_owner() -> None:
    device = make_device()
    scid = signed(CONFIGURATION)
    assert open_safety(device, scid=scid, configuration_data=CONFIGURATION) == 0
    assert attribute(device, 25) == OUNID.encode() and attribute(device, 26) == scid
    assert open_safety(device, server=False, scid=scid) == 0  # a Type 2 with the SCID held
    assert open_safety(device, server=False, scid=signed(b"\x09" * 8)) == 0x080C  # another SCID


@pytest.mark.parametrize(("kwargs", "extended"), [
    ({"scid": bytes(10)}, 0x080C),  # a Type 1 must carry an SCID
    ({"scid": signed(CONFIGURATION[:-2] + b"\xff\xff")}, 0x080C),  # SCCRC not that of the data
    ({"scid": signed(CONFIGURATION), "points": (2, 100, 0)}, 0x0129),  # not the configuration assembly
])
def test_type_1_safety_open_refusals_configure_nothing(kwargs: dict, extended: int) -> None:
    device = make_device()
    assert open_safety(device, configuration_data=CONFIGURATION, **kwargs) == extended
    assert attribute(device, 25) == bytes(10) and attribute(device, 26) == bytes(10) and device.connections == {}


def test_another_originator_cannot_reconfigure_until_safety_reset_type_2_clears_the_owner() -> None:
    device = make_device()
    assert open_safety(device, scid=signed(CONFIGURATION), configuration_data=CONFIGURATION) == 0
    other = b"\x07" * 8
    assert open_safety(device, server=False, scid=signed(other), configuration_data=other,
                       ounid=OTHER_OWNER) == 0x0105  # configuration owned by another originator
    assert open_safety(device, server=False, scid=signed(other), configuration_data=other) == 0x080F  # in use
    assert attribute(device, 25) == OUNID.encode() and attribute(device, 26) == signed(CONFIGURATION)
    assert ask(device, 0x54, reset_request(2, preserve=0x04)).general_status == 0  # keep the TUNID only
    assert attribute(device, 25) == bytes(10) and attribute(device, 26) == bytes(10)
    assert open_safety(device, server=False, scid=signed(other), configuration_data=other, ounid=OTHER_OWNER) == 0
    assert attribute(device, 25) == OTHER_OWNER.encode()


def test_safety_reset_type_2_can_preserve_the_owner() -> None:
    device = make_device()
    assert open_safety(device, scid=signed(CONFIGURATION), configuration_data=CONFIGURATION) == 0
    assert ask(device, 0x54, reset_request(2, preserve=0x14)).general_status == 0
    assert attribute(device, 25) == OUNID.encode() and attribute(device, 26) == bytes(10)
