"""Unit tests of the limits a hostile peer meets in-process: nesting depth of Multiple Service
Packet / Unconnected Send, the session cap, TCP/IP attribute 13, fair batches of the session."""

from __future__ import annotations

import struct

from enip_farm.config import parse_config
from enip_farm.device.build import build_profiles
from enip_farm.device.catalogue import shipped_catalogue
from enip_farm.device.device import Device
from enip_farm.protocol.cip import decode_reply, encode_request, encode_unconnected_send
from enip_farm.protocol.commands import encode_send_rr_data
from enip_farm.protocol.encapsulation import Command, decode_frame, encode_frame
from enip_farm.protocol.epath import encode_port, encode_request_path
from enip_farm.protocol.session import EncapsulationSession, MessageContext

GET_OUTPUTS = encode_request(0x0E, encode_request_path(4, 100, 3))


def make_device(**fields: object) -> Device:
    config = parse_config({"devices": [{"name": "io1", "address": "127.0.0.1", "model": "DSQC1030", **fields}]})
    (profile,) = build_profiles(config, shipped_catalogue())
    return Device(profile)


def msp(*requests: bytes) -> bytes:
    offsets, body, at = [], b"", 2 + 2 * len(requests)
    for request in requests:
        offsets.append(at)
        body += request
        at += len(request)
    return encode_request(0x0A, encode_request_path(2, 1),
                          struct.pack(f"<H{len(requests)}H", len(requests), *offsets) + body)


def routed(message: bytes) -> bytes:
    return encode_request(0x52, encode_request_path(6, 1), encode_unconnected_send(message, encode_port(1, 0)))


def ask(device: Device, message: bytes) -> bytes:
    return device.handle_unconnected(message, MessageContext("127.0.0.9", None, (), 0))[0]


def test_nesting_is_bounded_with_a_status_reply() -> None:
    device = make_device()
    assert decode_reply(ask(device, routed(msp(GET_OUTPUTS)))).general_status == 0  # pycomm3's shape: 2 deep
    deep = GET_OUTPUTS
    for level in range(300):  # far deeper than any stack should go
        deep = msp(deep) if level % 2 else routed(deep)
    assert deep[0] == 0x0A
    reply = ask(device, deep)
    outer = decode_reply(reply)
    assert outer.service == 0x8A and outer.general_status == 0x1E  # an embedded service failed
    assert len(reply) < 40 and reply.endswith(b"\x8a\x00\x02\x00")  # cut 4 levels down with 0x02


def test_the_fifth_level_gets_resource_unavailable() -> None:
    device = make_device()
    five = routed(routed(routed(routed(routed(GET_OUTPUTS)))))  # 4 sends deep is fine, the 5th is not
    four = routed(routed(routed(routed(GET_OUTPUTS))))
    assert decode_reply(ask(device, four)).general_status == 0
    assert decode_reply(ask(device, five)).general_status == 0x02


def test_sessions_beyond_the_cap_get_insufficient_memory() -> None:
    device = make_device(limits={"max_sessions": 2})
    register = encode_frame(Command.REGISTER_SESSION, b"\x01\x00\x00\x00")
    sessions = [EncapsulationSession(device, "127.0.0.9") for _ in range(3)]
    statuses = [decode_frame(s.receive(register, 0)[0]).header.status for s in sessions]
    assert statuses == [0, 0, 0x0002]
    third = sessions[2]
    (identity,) = third.receive(encode_frame(Command.LIST_IDENTITY), 0)  # the connection stays usable
    assert decode_frame(identity).header.status == 0
    sessions[0].connection_lost(0)
    assert decode_frame(third.receive(register, 0)[0]).header.status == 0  # a freed slot is taken


def test_tcpip_attribute_13_reads_and_sets_within_range() -> None:
    device = make_device(encapsulation_inactivity_timeout_s=1)
    get = encode_request(0x0E, encode_request_path(0xF5, 1, 13))
    assert decode_reply(ask(device, get)).data == b"\x01\x00"

    def set_to(data: bytes) -> int:
        return decode_reply(ask(device, encode_request(0x10, encode_request_path(0xF5, 1, 13), data))).general_status

    assert set_to(struct.pack("<H", 3601)) == 0x09 and set_to(b"\x05") == 0x13 and set_to(b"\x05\x00\x00") == 0x15
    assert set_to(struct.pack("<H", 0)) == 0 and device.encapsulation_inactivity_timeout_s == 0
    assert set_to(struct.pack("<H", 3600)) == 0 and decode_reply(ask(device, get)).data == b"\x10\x0e"


def test_a_session_answers_one_batch_per_turn_in_order() -> None:
    device = make_device()
    session = EncapsulationSession(device, "127.0.0.9")
    (registered,) = session.receive(encode_frame(Command.REGISTER_SESSION, b"\x01\x00\x00\x00"), 0)
    handle = decode_frame(registered).header.session_handle
    stream = b"".join(encode_send_rr_data(GET_OUTPUTS, handle, struct.pack("<Q", n)) for n in range(40))
    first = session.receive(stream, 0, 16)
    assert len(first) == 16 and session.backlog
    second = session.receive(b"", 0, 16)
    third = session.receive(b"", 0, 16)
    assert len(second) == 16 and len(third) == 8 and not session.backlog
    contexts = [struct.unpack("<Q", decode_frame(r).header.sender_context)[0] for r in first + second + third]
    assert contexts == list(range(40))
