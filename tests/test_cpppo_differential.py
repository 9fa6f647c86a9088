"""Every reply kind the codec produces, decoded by cpppo's parsers (an independent reference
decoder) with the same fields as our own decoder reads."""

from __future__ import annotations

import pytest
from cpppo import dotdict, peekable
from cpppo.server.enip import device as cpppo_device
from cpppo.server.enip import logix, parser

from enip_farm.config import parse_config
from enip_farm.device.build import build_profiles
from enip_farm.device.catalogue import shipped_catalogue
from enip_farm.device.device import Device
from enip_farm.protocol.cip import decode_reply, encode_multiple_service, encode_request
from enip_farm.protocol.commands import decode_identity_item, decode_send_data, encode_send_rr_data
from enip_farm.protocol.cpf import decode_items
from enip_farm.protocol.encapsulation import Command, decode_frame, encode_frame
from enip_farm.protocol.epath import encode_request_path
from enip_farm.protocol.session import EncapsulationSession

pytestmark = pytest.mark.class1_paths  # both class-1 paths (tests/conftest.py)


def cpppo_decode(frame: bytes) -> dotdict:
    data = dotdict()
    with parser.enip_machine(terminal=True) as machine:
        for _ in machine.run(source=peekable(frame), data=data):
            pass
    if "enip.input" in data:
        with parser.CIP(terminal=True) as machine:
            for _ in machine.run(path="enip", source=peekable(data.enip.input), data=data):
                pass
    if "enip.CIP.send_data" in data:
        for item in data.enip.CIP.send_data.CPF.item:
            if "unconnected_send.request" in item:
                request = item.unconnected_send.request
                with logix.Logix.parser as machine:
                    for _ in machine.run(source=peekable(request.input), data=request):
                        pass
    return data


@pytest.fixture
def session() -> EncapsulationSession:
    config = parse_config({"devices": [{"name": "d", "address": "127.0.0.5", "model": "DSQC1030",
                                        "addons": ["DSQC1031"]}]})
    session = EncapsulationSession(Device(build_profiles(config, shipped_catalogue())[0]))
    session.receive(encode_frame(Command.REGISTER_SESSION, b"\x01\x00\x00\x00"), 0)
    return session


def _header_matches(ours: bytes, theirs: dotdict) -> None:
    frame = decode_frame(ours)
    assert theirs.enip.command == frame.header.command
    assert theirs.enip.length == frame.header.length
    assert theirs.enip.session_handle == frame.header.session_handle
    assert theirs.enip.status == frame.header.status
    assert bytes(theirs.enip.sender_context.input) == frame.header.sender_context


def test_register_session_reply(session: EncapsulationSession) -> None:
    fresh = EncapsulationSession(session.target)
    (reply,) = fresh.receive(encode_frame(Command.REGISTER_SESSION, b"\x01\x00\x00\x00", sender_context=b"12345678"), 0)
    theirs = cpppo_decode(reply)
    _header_matches(reply, theirs)
    assert theirs.enip.CIP.register.protocol_version == 1 and theirs.enip.CIP.register.options == 0


def test_list_identity_reply(session: EncapsulationSession) -> None:
    (reply,) = session.receive(encode_frame(Command.LIST_IDENTITY), 0)
    theirs = cpppo_decode(reply)
    _header_matches(reply, theirs)
    ours = decode_identity_item(decode_items(decode_frame(reply).data)[0].data)
    item = theirs.enip.CIP.list_identity.CPF.item[0].identity_object
    assert (item.sin_addr, item.sin_port, item.vendor_id, item.device_type, item.product_code,
            item.status_word, item.serial_number, item.product_name, item.state) == (
        ours.socket_address.host, ours.socket_address.port, ours.vendor_id, ours.device_type, ours.product_code,
        ours.status, ours.serial_number, ours.product_name, ours.state)
    assert item.product_revision == ours.revision_major | ours.revision_minor << 8


def test_list_services_reply(session: EncapsulationSession) -> None:
    (reply,) = session.receive(encode_frame(Command.LIST_SERVICES), 0)
    theirs = cpppo_decode(reply)
    _header_matches(reply, theirs)
    service = theirs.enip.CIP.list_services.CPF.item[0].communications_service
    assert (service.version, service.capability, service.service_name) == (1, 0x120, "Communications")


def test_list_interfaces_reply(session: EncapsulationSession) -> None:
    (reply,) = session.receive(encode_frame(Command.LIST_INTERFACES), 0)
    theirs = cpppo_decode(reply)
    _header_matches(reply, theirs)
    assert theirs.enip.CIP.list_interfaces.CPF.count == 0


def test_encapsulation_error_reply(session: EncapsulationSession) -> None:
    (reply,) = session.receive(encode_send_rr_data(b"\x0e\x01\x20\x01", 99), 0)
    theirs = cpppo_decode(reply)
    _header_matches(reply, theirs)
    assert theirs.enip.status == 0x64


REQUESTS = {
    "get_attribute_single": encode_request(0x0E, encode_request_path(4, 100, 3)),
    "set_attribute_single": encode_request(0x10, encode_request_path(4, 100, 3), b"\x01\x02\x03\x04"),
    "get_attributes_all": encode_request(0x01, encode_request_path(1, 1)),
    "error_status": encode_request(0x0E, encode_request_path(4, 100, 9)),
    "unknown_object": encode_request(0x0E, encode_request_path(0x70, 1, 1)),
    "extended_status": encode_request(0x52, encode_request_path(6, 1),
                                      bytes.fromhex("0a0e0800 0e032004246430 03 0100 0103")),
    "multiple_service": encode_request(0x0A, encode_request_path(2, 1), encode_multiple_service(
        [encode_request(0x0E, encode_request_path(1, 1, 1)), encode_request(0x0E, encode_request_path(1, 1, 7))])),
}


@pytest.mark.parametrize("kind", sorted(REQUESTS))
def test_send_rr_data_replies(session: EncapsulationSession, kind: str, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(cpppo_device, "dialect", logix.Logix)  # cpppo parses embedded replies by dialect
    (reply,) = session.receive(encode_send_rr_data(REQUESTS[kind], 1, b"diff-ctx"), 0)
    theirs = cpppo_decode(reply)
    _header_matches(reply, theirs)
    ours_items = decode_send_data(decode_frame(reply).data).items
    cpf = theirs.enip.CIP.send_data.CPF
    assert cpf.count == len(ours_items) == 2
    assert [item.type_id for item in cpf.item] == [item.type_id for item in ours_items]
    ours = decode_reply(ours_items[1].data)
    request = cpf.item[1].unconnected_send.request
    assert request.service == ours.service
    assert request.status == ours.general_status
    assert request.status_ext.size == len(ours.additional_status)
    if ours.additional_status:
        assert list(request.status_ext.data) == list(ours.additional_status)
    if kind == "get_attribute_single":
        assert bytes(request.get_attribute_single.data) == ours.data
    if kind == "get_attributes_all":
        assert bytes(request.get_attributes_all.data) == ours.data
    if kind == "multiple_service":
        replies = request.multiple.request
        assert [r.status for r in replies] == [0, 0]
        assert [bytes(r.get_attribute_single.data) for r in replies] == [b"\x4b\x00", b"\x08DSQC1030"]
