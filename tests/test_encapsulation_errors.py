"""Encapsulation-level error cases with raw frames (CIP Networks Library Vol. 2, 2-3.3 and 2-4):
each gets the status the spec assigns, and the connection stays usable where the spec allows."""

from __future__ import annotations

import struct

from enip_farm.protocol.commands import encode_connected_payload, encode_send_data, encode_send_rr_data
from enip_farm.protocol.cpf import ItemType
from enip_farm.protocol.encapsulation import HEADER, Command, EncapsulationStatus, encode_frame
from tests.helpers import RawClient

GET_OUTPUTS = bytes.fromhex("0E 03 20 04 24 64 30 03")
CONTEXT = b"ctx-1234"


def _still_usable(c: RawClient) -> None:
    assert c.request(GET_OUTPUTS).general_status == 0


def test_unknown_command_gets_0x0001_and_connection_stays(dsqc1030: str) -> None:
    with RawClient(dsqc1030) as c:
        c.register()
        reply = c.exchange(encode_frame(0x00C8, b"abc", c.session_handle, sender_context=CONTEXT))
        assert reply.header.command == 0x00C8
        assert reply.header.status == EncapsulationStatus.INVALID_COMMAND
        assert reply.header.sender_context == CONTEXT
        _still_usable(c)


def test_register_session_wrong_version_gets_0x0069(dsqc1030: str) -> None:
    with RawClient(dsqc1030) as c:
        reply = c.exchange(encode_frame(Command.REGISTER_SESSION, b"\x02\x00\x00\x00", sender_context=CONTEXT))
        assert reply.header.status == EncapsulationStatus.UNSUPPORTED_PROTOCOL
        assert reply.header.session_handle == 0
        assert reply.data == b"\x01\x00\x00\x00"  # the version the device supports
        assert reply.header.sender_context == CONTEXT
        assert c.register() == 1  # still usable; no handle was consumed


def test_register_session_twice_on_one_connection(dsqc1030: str) -> None:
    with RawClient(dsqc1030) as c:
        assert c.register() == 1
        reply = c.exchange(encode_frame(Command.REGISTER_SESSION, b"\x01\x00\x00\x00"))
        assert reply.header.status == EncapsulationStatus.INVALID_COMMAND
        assert reply.header.session_handle == 1
        _still_usable(c)


def test_session_belongs_to_its_connection(dsqc1030: str) -> None:
    with RawClient(dsqc1030) as a, RawClient(dsqc1030) as b:
        assert a.register() == 1
        assert b.register() == 2
        stolen = b.exchange(encode_send_rr_data(GET_OUTPUTS, 1))  # a's handle on b's connection
        assert stolen.header.status == EncapsulationStatus.INVALID_SESSION_HANDLE
        assert stolen.header.session_handle == 1
        unknown = a.exchange(encode_send_rr_data(GET_OUTPUTS, 77))
        assert unknown.header.status == EncapsulationStatus.INVALID_SESSION_HANDLE
        _still_usable(a)
        _still_usable(b)


def test_send_rr_data_without_session(dsqc1030: str) -> None:
    with RawClient(dsqc1030) as c:
        reply = c.exchange(encode_send_rr_data(GET_OUTPUTS, 0))
        assert reply.header.status == EncapsulationStatus.INVALID_SESSION_HANDLE
        c.register()
        _still_usable(c)


def test_unregister_with_wrong_handle_gets_0x0064_and_stays_open(dsqc1030: str) -> None:
    with RawClient(dsqc1030) as c:
        c.register()
        reply = c.exchange(encode_frame(Command.UNREGISTER_SESSION, session_handle=9))
        assert reply.header.status == EncapsulationStatus.INVALID_SESSION_HANDLE
        _still_usable(c)


def test_length_over_maximum_gets_0x0065_once_read_whole_and_stays_open(dsqc1030: str) -> None:
    """Vol. 2, 2-3.3: the whole message is read even when it exceeds the target's buffers."""
    with RawClient(dsqc1030) as c:
        c.register()
        c.send(HEADER.pack(Command.SEND_RR_DATA, 0xFFFF, 1, 0, CONTEXT, 0) + bytes(0xFFFF))
        reply = c.recv_frame()
        assert reply.header.status == EncapsulationStatus.INVALID_LENGTH
        assert reply.header.sender_context == CONTEXT
        _still_usable(c)


def test_malformed_cpf_gets_0x0003_and_stays_open(dsqc1030: str) -> None:
    with RawClient(dsqc1030) as c:
        c.register()
        truncated = encode_frame(Command.SEND_RR_DATA, struct.pack("<IHH", 0, 0, 2) + b"\x00\x00", 1)
        assert c.exchange(truncated).header.status == EncapsulationStatus.INCORRECT_DATA
        connected_item = encode_frame(
            Command.SEND_RR_DATA, encode_send_data([(ItemType.CONNECTED_ADDRESS, b"\x01\x00\x00\x00"),
                                                   (ItemType.UNCONNECTED_DATA, GET_OUTPUTS)]), 1)
        assert c.exchange(connected_item).header.status == EncapsulationStatus.INCORRECT_DATA
        empty_message = encode_frame(
            Command.SEND_RR_DATA, encode_send_data([(ItemType.NULL_ADDRESS, b""),
                                                   (ItemType.UNCONNECTED_DATA, b"")]), 1)
        assert c.exchange(empty_message).header.status == EncapsulationStatus.INCORRECT_DATA
        _still_usable(c)


def test_nop_gets_no_reply(dsqc1030: str) -> None:
    with RawClient(dsqc1030) as c:
        c.register()
        c.send(encode_frame(Command.NOP, b"padding", 1))
        reply = c.exchange(encode_send_rr_data(GET_OUTPUTS, 1, sender_context=CONTEXT))
        assert reply.header.command == Command.SEND_RR_DATA  # the NOP got nothing back
        assert reply.header.sender_context == CONTEXT


def test_list_commands_over_tcp(dsqc1030: str) -> None:
    with RawClient(dsqc1030) as c:
        identity = c.exchange(encode_frame(Command.LIST_IDENTITY, sender_context=CONTEXT))
        assert identity.header.status == 0 and identity.header.sender_context == CONTEXT
        services = c.exchange(encode_frame(Command.LIST_SERVICES))
        assert services.data[:4] == b"\x01\x00\x00\x01" and b"Communications" in services.data
        interfaces = c.exchange(encode_frame(Command.LIST_INTERFACES))
        assert interfaces.data == b"\x00\x00"


def test_send_unit_data_on_unknown_connection_gets_0x0003(dsqc1030: str) -> None:
    """No silence: a SendUnitData that names no connection of this session gets 0x0003."""
    with RawClient(dsqc1030) as c:
        c.register()
        reply = c.exchange(encode_frame(Command.SEND_UNIT_DATA, encode_send_data([]), 1))
        assert reply.header.status == EncapsulationStatus.INCORRECT_DATA
        reply = c.exchange(encode_frame(Command.SEND_UNIT_DATA, encode_connected_payload(0x1234, 1, GET_OUTPUTS), 1))
        assert reply.header.status == EncapsulationStatus.INCORRECT_DATA
        reply = c.exchange(encode_frame(Command.SEND_UNIT_DATA, encode_connected_payload(0x1234, 1, GET_OUTPUTS), 5))
        assert reply.header.status == EncapsulationStatus.INVALID_SESSION_HANDLE
        _still_usable(c)


def test_non_zero_options_are_discarded(dsqc1030: str) -> None:
    """Vol. 2, 2-3.6: a receiver discards a frame whose options field is not zero."""
    with RawClient(dsqc1030) as c:
        c.register()
        c.send(encode_frame(Command.SEND_RR_DATA, encode_send_data([(ItemType.NULL_ADDRESS, b""),
                                                                    (ItemType.UNCONNECTED_DATA, GET_OUTPUTS)]),
                            1, sender_context=b"optioned", options=1))
        reply = c.exchange(encode_send_rr_data(GET_OUTPUTS, 1, sender_context=CONTEXT))
        assert reply.header.sender_context == CONTEXT  # the optioned frame got no reply
