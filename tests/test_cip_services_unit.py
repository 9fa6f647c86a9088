"""Unit tests (bytes in, bytes out, an injected clock) of the services a complete CIP device adds:
Get/Set_Attribute_List on every object, Identity Reset and state, the TCP/IP Interface attributes
7-13, the Ethernet Link attributes 4-11 with their counters and Get_and_Clear, and routing as
profile data. The same services against real clients over the network: tests/test_cip_services.py."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest
import yaml

from enip_farm.cip.object import MAX_LIST_REPLY_DATA
from enip_farm.config import parse_config
from enip_farm.device.build import build_profiles
from enip_farm.device.catalogue import shipped_catalogue
from enip_farm.device.device import Device
from enip_farm.device.reset import ResetWindow
from enip_farm.protocol.cip import decode_reply, encode_multiple_service, encode_request, encode_unconnected_send
from enip_farm.protocol.commands import (
    decode_identity_item,
    decode_send_data,
    encode_connected_payload,
    encode_send_rr_data,
)
from enip_farm.protocol.connection import (
    ConnectionTriad,
    ConnectionType,
    ForwardOpenRequest,
    NetworkParameters,
    decode_forward_open_reply,
    encode_forward_open,
    encode_io_packet,
)
from enip_farm.protocol.cpf import decode_items
from enip_farm.protocol.encapsulation import Command, decode_frame, encode_frame
from enip_farm.protocol.epath import encode_port, encode_request_path
from enip_farm.protocol.session import EncapsulationSession, MessageContext

MS = 1_000_000
T0 = 1_000 * MS
SCANNER = "127.0.0.9"
P2P = ConnectionType.POINT_TO_POINT


def _unsent(data: bytes, address: tuple[str, int]) -> None:
    raise AssertionError(f"nothing is sent at once here: {data.hex()} to {address}")


def make_device(**fields: object) -> Device:
    config = parse_config({"devices": [{"name": "io1", "address": "127.0.0.1", "model": "DSQC1030", **fields}]})
    (profile,) = build_profiles(config, shipped_catalogue())
    return Device(profile)


def ask(device: Device, message: bytes, now: int = T0, session: object | None = None):  # noqa: ANN201
    reply, _ = device.handle_unconnected(message, MessageContext(SCANNER, session, (), now))
    return decode_reply(reply)


def get_list(class_id: int, instance: int, *ids: int) -> bytes:
    data = struct.pack(f"<{len(ids) + 1}H", len(ids), *ids)
    return encode_request(0x03, encode_request_path(class_id, instance), data)


def set_list(class_id: int, instance: int, *entries: tuple[int, bytes], count: int | None = None) -> bytes:
    data = struct.pack("<H", len(entries) if count is None else count)
    data += b"".join(struct.pack("<H", attribute) + value for attribute, value in entries)
    return encode_request(0x04, encode_request_path(class_id, instance), data)


def forward_open(serial: int, path: bytes, transport: int, size_o_t: int, size_t_o: int) -> bytes:
    request = ForwardOpenRequest(0x0A, 0x0E, 0, 0x7E570000 + serial, ConnectionTriad(serial, 0x1234, 0xABCD), 0,
                                 100_000, NetworkParameters(False, P2P, 2, transport == 0xA3, size_o_t), 100_000,
                                 NetworkParameters(False, P2P, 2, transport == 0xA3, size_t_o), transport, path)
    return encode_request(0x54, encode_request_path(6, 1), encode_forward_open(request))


CLASS1 = forward_open(1, bytes.fromhex("20 04 24 01 2C 64 2C 65"), 0x01, 8, 4)
CLASS3 = forward_open(2, bytes.fromhex("20 02 24 01"), 0xA3, 500, 500)
RESET = encode_request(0x05, encode_request_path(1, 1))


# -- Get_Attribute_List (0x03) ---------------------------------------------------------------------


def test_get_attribute_list_bytes() -> None:
    reply = ask(make_device(), get_list(1, 1, 1, 7, 8))
    assert reply.service == 0x83 and reply.general_status == 0
    assert reply.data == bytes.fromhex(
        "0300"                             # three attributes
        "0100 0000 4b00"                   # 1 vendor: success, 75
        "0700 0000 08" + b"DSQC1030".hex() +  # 7 product name: success, SHORT_STRING
        "0800 0000 03")                    # 8 state: success, 3 operational


def test_get_attribute_list_statuses_per_attribute() -> None:
    device = make_device()
    reply = ask(device, get_list(0xF5, 1, 13, 99, 7, 1))  # 7 (safety network number) is not a safety device's
    assert reply.general_status == 0x0A  # attribute list error, as OpENer
    assert reply.data == bytes.fromhex("0400" "0d00 0000 7800" "6300 1400" "0700 1400" "0100 0000 01000000")
    assert ask(device, get_list(4, 0, 1, 2)).data == bytes.fromhex("0200" "0100 0000 0200" "0200 0000 6500")


@pytest.mark.parametrize(("data", "status"), [
    (b"", 0x13), (b"\x01", 0x13), (b"\x02\x00\x01\x00", 0x13), (b"\x01\x00\x01\x00\x02", 0x15), (b"\x00\x00", 0x0A)])
def test_get_attribute_list_malformed(data: bytes, status: int) -> None:
    reply = ask(make_device(), encode_request(0x03, encode_request_path(1, 1), data))
    assert (reply.general_status, reply.data) == (status, b"")


def test_get_attribute_list_stops_where_the_reply_is_full() -> None:
    """Two 400-byte assemblies do not fit one reply: the first is returned, then 0x06 (partial)."""
    device = make_device(assemblies={"output_size": 400})
    reply = ask(device, get_list(4, 100, 3, 3, 4))
    assert reply.general_status == 0x06
    assert reply.data == b"\x01\x00" + b"\x03\x00\x00\x00" + bytes(400)
    assert len(reply.data) <= MAX_LIST_REPLY_DATA


# -- Set_Attribute_List (0x04) ---------------------------------------------------------------------


def test_set_attribute_list_sets_fixed_and_variable_sizes() -> None:
    device = make_device()
    reply = ask(device, set_list(0xF5, 1, (8, b"\x05"), (6, b"\x03\x00io1\x00"), (13, b"\x1e\x00"), (12, b"\x01")))
    assert reply.service == 0x84 and reply.general_status == 0
    assert reply.data == bytes.fromhex("0400" "0800 0000" "0600 0000" "0d00 0000" "0c00 0000")
    assert ask(device, get_list(0xF5, 1, 8, 6, 13, 12)).data == bytes.fromhex(
        "0400" "0800 0000 05" "0600 0000 0300" + b"io1".hex() + "00" "0d00 0000 1e00" "0c00 0000 01")
    assert device.encapsulation_inactivity_timeout_s == 30


def test_set_attribute_list_statuses_per_attribute() -> None:
    """A read-only attribute of fixed or variable size is skipped by its own length (0x0E) and the
    list goes on; a bad value fails only itself."""
    device = make_device()
    reply = ask(device, set_list(0xF5, 1, (1, b"\x00\x00\x00\x00"), (6, b"\x02\x00-x"),
                                 (5, bytes(20) + b"\x01\x00a\x00"), (8, b"\x00"), (13, b"\x0a\x00")))
    assert reply.general_status == 0x0A
    assert reply.data == bytes.fromhex("0500" "0100 0e00" "0600 0900" "0500 0e00" "0800 0900" "0d00 0000")
    assert device.encapsulation_inactivity_timeout_s == 10
    identity = ask(device, set_list(1, 1, (7, b"\x03abc"), (1, b"\x4b\x00")))
    assert identity.data == bytes.fromhex("0200" "0700 0e00" "0100 0e00")


def test_set_attribute_list_ends_where_it_cannot_be_parsed() -> None:
    """An attribute the object does not have has no known length: the list ends there (0x14), the
    attributes before it are set, the reply counts what it lists. A value cut short ends it with 0x13."""
    device = make_device()
    reply = ask(device, set_list(0xF5, 1, (13, b"\x0b\x00"), (99, b"\x01\x00"), (8, b"\x02")))
    assert (reply.general_status, reply.data) == (0x0A, bytes.fromhex("0200" "0d00 0000" "6300 1400"))
    assert device.encapsulation_inactivity_timeout_s == 11
    short = ask(device, set_list(0xF5, 1, (8, b"\x03"), (13, b"\x0c")))
    assert (short.general_status, short.data) == (0x0A, bytes.fromhex("0200" "0800 0000" "0d00 1300"))
    assert ask(device, get_list(0xF5, 1, 8)).data.endswith(b"\x03")


def test_set_attribute_list_malformed_sets_nothing() -> None:
    device = make_device()
    for data, status in ((b"", 0x13), (b"\x00\x00", 0x0A), (b"\x02\x00\x0d\x00\x0b\x00", 0x13),
                         (b"\x01\x00\x0d\x00\x0b\x00\xff", 0x15)):
        reply = ask(device, encode_request(0x04, encode_request_path(0xF5, 1), data))
        assert (reply.general_status, reply.data) == (status, b"")
    assert device.encapsulation_inactivity_timeout_s == 120


def test_set_attribute_list_on_the_output_assembly() -> None:
    device = make_device()
    assert ask(device, set_list(4, 100, (3, b"\x10\x00"))).data == bytes.fromhex("0100 0300 0000")
    assert device.outputs == b"\x10\x00"
    reply = ask(device, set_list(4, 101, (3, b"\x01\x00"), (4, b"\x02\x00")))  # the inputs are not writable
    assert reply.data == bytes.fromhex("0200" "0300 0e00" "0400 0e00") and device.inputs == b"\x00\x00"


# -- Identity: state (attribute 8) and Reset (0x05) ---------------------------------------------------


def test_identity_state_matches_list_identity() -> None:
    device = make_device()
    assert ask(device, encode_request(0x0E, encode_request_path(1, 1, 8))).data == b"\x03"
    assert device.identity_item().state == 3
    items = decode_items(device.list_identity_data())
    assert decode_identity_item(items[0].data).state == 3
    assert ask(device, encode_request(0x01, encode_request_path(1, 1))).data.endswith(b"\x08DSQC1030")  # 1-7 only


@pytest.mark.parametrize(("data", "status"), [(b"\x03", 0x20), (b"\xff", 0x20), (b"\x00\x00", 0x15)])
def test_reset_refusals(data: bytes, status: int) -> None:
    device = make_device()
    reply = ask(device, encode_request(0x05, encode_request_path(1, 1), data))
    assert (reply.service, reply.general_status) == (0x85, status)
    assert device.restarts == 0 and not device.resetting
    assert ask(device, encode_request(0x05, encode_request_path(1, 0))).general_status == 0x08  # the class


def open_everything(device: Device) -> None:
    """A class-1 connection fed with outputs, a class-3 connection, inputs set by the field."""
    owner = object()
    assert ask(device, CLASS1).general_status == 0 and ask(device, CLASS3, session=owner).general_status == 0
    (class1,) = [c for c in device.connections.values() if c.is_io]
    assert device.receive_io(encode_io_packet(class1.o_t_id, 1, 1, b"\x01\x00\x00\x00\x10\x02"), (SCANNER, 2222),
                             T0 + MS, _unsent)
    device.set_inputs(b"\x81\x00")
    assert device.outputs == b"\x10\x02" and len(device.connections) == 2 and device.status == 0x0061


@pytest.mark.parametrize("data", [b"", b"\x00"])
def test_reset_type_0_ends_connections_clears_outputs_and_answers_again_at_its_deadline(data: bytes) -> None:
    device = make_device(reset_time_s=1.5, implicit={"idle_state": "hold"})  # a power cycle does not hold
    seen = []
    device.observe(seen.append)
    open_everything(device)
    ask(device, set_list(0xF5, 1, (13, b"\x0b\x00"), (8, b"\x07")))
    reply = ask(device, encode_request(0x05, encode_request_path(1, 1), data), now=T0 + 2 * MS)
    assert (reply.service, reply.general_status, reply.data) == (0x85, 0, b"")
    assert not device.connections and device.status == 0x0030
    assert device.outputs == b"\x00\x00" and device.inputs == b"\x81\x00"  # the field keeps the inputs
    closed = [e.text for e in seen if e.kind == "connection closed"]
    assert len(closed) == 2 and all(text.endswith(": identity reset (type 0)") for text in closed)
    assert [e.text for e in seen if e.kind == "reset"] == ["type 0 (power cycle): not answering for 1.5 s"]
    assert device.encapsulation_inactivity_timeout_s == 11  # set values survive a power cycle
    assert device.restarts == 1 and device.resetting and device.identity_state == 1
    deadline = T0 + 2 * MS + 1_500 * MS
    assert device.reset_window.due() == deadline
    assert device.receive_io(encode_io_packet(1, 2, 2, b""), (SCANNER, 2222), deadline - 1, _unsent) is False
    assert device.counters["o_t_dropped_resetting"] == 1
    assert device.end_reset(deadline - 1) is False and device.resetting
    assert device.end_reset(deadline) is True and not device.resetting and device.identity_state == 3
    assert [e.kind for e in seen if e.kind.startswith("reset")] == ["reset", "reset done"]


def test_reset_type_1_restores_the_configured_settings() -> None:
    device = make_device(host_name="cell-io1", encapsulation_inactivity_timeout_s=60)
    assert ask(device, set_list(0xF5, 1, (13, b"\x0b\x00"), (8, b"\x07"), (6, b"\x02\x00ab"), (10, b"\x01"),
                                (12, b"\x01"))).general_status == 0
    assert ask(device, encode_request(0x10, encode_request_path(0xF6, 1, 6), b"\x02\x00\x64\x00")).general_status == 0
    assert ask(device, encode_request(0x05, encode_request_path(1, 1), b"\x01")).general_status == 0
    assert ask(device, get_list(0xF5, 1, 6, 8, 10, 12, 13)).data == bytes.fromhex(
        "0500" "0600 0000 0800" + b"cell-io1".hex() + "0800 0000 01" "0a00 0000 00" "0c00 0000 00" "0d00 0000 3c00")
    assert ask(device, encode_request(0x0E, encode_request_path(0xF6, 1, 6))).data == b"\x01\x00\x00\x00"
    assert device.events.of_kind("reset")[0].text == "type 1 (out-of-box configuration): not answering for 1 s"


def test_reset_type_2_keeps_the_communication_parameters() -> None:
    device = make_device(host_name="cell-io1")
    assert ask(device, set_list(0xF5, 1, (8, b"\x07"), (6, b"\x02\x00ab"))).general_status == 0
    assert ask(device, encode_request(0x10, encode_request_path(0xF6, 1, 6), b"\x02\x00\x64\x00")).general_status == 0
    assert ask(device, encode_request(0x05, encode_request_path(1, 1), b"\x02")).general_status == 0
    assert device.restarts == 1 and device.identity_state == 1
    assert ask(device, get_list(0xF5, 1, 6, 8)).data == bytes.fromhex(
        "0200" "0600 0000 0200" + b"ab".hex() + "0800 0000 07")
    assert ask(device, encode_request(0x0E, encode_request_path(0xF6, 1, 6))).data == b"\x02\x00\x64\x00"
    assert device.events.of_kind("reset")[0].text == (
        "type 2 (out-of-box configuration but the communication parameters): not answering for 1 s")


def test_reset_in_a_multiple_service_packet_happens_after_the_whole_packet() -> None:
    device = make_device()
    packet = encode_multiple_service([RESET, encode_request(0x10, encode_request_path(4, 100, 3), b"\x01\x00")])
    reply = ask(device, encode_request(0x0A, encode_request_path(2, 1), packet))
    assert reply.general_status == 0 and device.restarts == 1
    assert device.outputs == b"\x00\x00"  # the write came before the reset took effect


def test_the_reset_reply_is_the_sessions_last_and_other_sessions_end_unanswered() -> None:
    device = make_device()
    register = encode_frame(Command.REGISTER_SESSION, b"\x01\x00\x00\x00")
    resetter, other = EncapsulationSession(device, SCANNER), EncapsulationSession(device, SCANNER)
    handles = [decode_frame(s.receive(register, T0)[0]).header.session_handle for s in (resetter, other)]
    get = encode_request(0x0E, encode_request_path(1, 1, 1))
    replies = resetter.receive(encode_send_rr_data(RESET, handles[0]) + encode_send_rr_data(get, handles[0]), T0)
    assert len(replies) == 1 and resetter.closing  # the Get after the Reset is not answered
    message = decode_send_data(decode_frame(replies[0]).data).items[1].data
    assert decode_reply(message).service == 0x85 and decode_reply(message).general_status == 0
    assert other.receive(encode_send_rr_data(get, handles[1]), T0) == [] and other.closing
    resetter.connection_lost(T0)  # the farm closes both TCP connections
    other.connection_lost(T0)
    fresh = EncapsulationSession(device, SCANNER)  # a connection once the device answers again
    assert decode_frame(fresh.receive(register, T0)[0]).header.session_handle == 1  # numbered from 1 again


def test_reset_on_a_class_3_connection() -> None:
    """Reset sent connected (SendUnitData): answered on the connection, which then closes with the
    session; the device restarts after the reply is built."""
    device = make_device()
    session = EncapsulationSession(device, SCANNER)
    handle = decode_frame(session.receive(encode_frame(Command.REGISTER_SESSION, b"\x01\x00\x00\x00"), T0)[0]
                          ).header.session_handle
    (opened,) = session.receive(encode_send_rr_data(CLASS3, handle), T0)
    reply = decode_reply(decode_send_data(decode_frame(opened).data).items[1].data)
    connection = decode_forward_open_reply(reply.data)
    (answer,) = session.receive(encode_frame(Command.SEND_UNIT_DATA, encode_connected_payload(
        connection.o_t_connection_id, 1, RESET), handle), T0 + MS)
    items = decode_send_data(decode_frame(answer).data).items
    assert struct.unpack("<I", items[0].data)[0] == connection.t_o_connection_id
    assert items[1].data == b"\x01\x00" + b"\x85\x00\x00\x00"  # sequence count echoed, Reset success
    assert session.closing and device.restarts == 1 and not device.connections
    assert device.reset_window.due() == T0 + MS + 1_000 * MS  # reset_time_s 1.0 by default


def test_reset_window_to_the_tick() -> None:
    window = ResetWindow(250 * MS)
    assert not window.active and window.due() is None and window.end(T0) is False
    assert window.start(T0) == T0 + 250 * MS and window.active and window.resets == 1
    assert window.end(T0 + 250 * MS - 1) is False and window.active
    assert window.end(T0 + 250 * MS) is True and not window.active
    with pytest.raises(ValueError, match="^a reset time is not negative$"):
        ResetWindow(-1)


# -- TCP/IP Interface (0xF5) -------------------------------------------------------------------------


def test_tcpip_get_attributes_all_layout() -> None:
    """Attributes 1-13 in order, as the spec lays out Get Attributes All and OpENer's GetAttributeAll
    of class 0xF5 encodes them (7 as six zero bytes, not gettable alone): 96 bytes when
    the domain and host names are empty, each name adding its length padded to even. The 98 bytes
    the issue measured on OpENer fit this layout with 2 bytes of names (OpENer fills them from its
    host); they were not measured here."""
    data = ask(make_device(), encode_request(0x01, encode_request_path(0xF5, 1))).data
    expected = bytes.fromhex(
        "01000000"                                  # 1 status: valid configuration
        "00000000"                                  # 2 capability: no BOOTP/DHCP client, not settable
        "00000000"                                  # 3 control: static
        "0200 20f6 2401"                            # 4 physical link: 2 words, Ethernet Link instance 1
        "0100007f 00ffffff 00000000 00000000 00000000 0000"  # 5 127.0.0.1/24, no gateway, name servers, domain
        "0000"                                      # 6 host name: empty STRING
        "000000000000"                              # 7 safety network number: six zero bytes
        "01"                                        # 8 TTL 1
        "00 00 0100 0001c0ef"                       # 9 mcast: CIP algorithm, 1 address, 239.192.1.0
        "00"                                        # 10 SelectAcd 0
        + "00" * 35 +                               # 11 last conflict: activity 0, MAC, ARP PDU
        "00"                                        # 12 quick connect 0
        "7800")                                     # 13 inactivity timeout 120 s
    assert data == expected and len(data) == 96
    named = ask(make_device(host_name="abc"), encode_request(0x01, encode_request_path(0xF5, 1))).data
    assert len(named) == 96 + 4 and named[40:46] == b"\x03\x00abc\x00"


def test_tcpip_safety_network_number_of_a_safety_target() -> None:
    """A CIP Safety target (DSQC1042) shows its safety network number (the catalogue's, unverified)
    as attribute 7, alone and in Get Attributes All; other devices have none."""
    config = parse_config({"devices": [{"name": "s1", "address": "127.0.0.2", "model": "DSQC1042"}]})
    (profile,) = build_profiles(config, shipped_catalogue())
    device = Device(profile)
    assert ask(device, encode_request(0x0E, encode_request_path(0xF5, 1, 7))).data == profile.safety.snn
    assert ask(device, encode_request(0x01, encode_request_path(0xF5, 1))).data[42:48] == profile.safety.snn
    assert ask(make_device(), encode_request(0x0E, encode_request_path(0xF5, 1, 7))).general_status == 0x14


def test_tcpip_multicast_config_from_the_configuration() -> None:
    device = make_device(implicit={"multicast_group": "239.192.5.32"})
    assert ask(device, encode_request(0x0E, encode_request_path(0xF5, 1, 9))).data == bytes.fromhex("01000100 2005c0ef")


@pytest.mark.parametrize(("attribute", "value", "status"), [
    (8, b"\x00", 0x09), (8, b"\x01\x00", 0x15), (10, b"\x02", 0x09), (12, b"", 0x13), (9, bytes(8), 0x0E),
    (11, bytes(35), 0x0E), (7, bytes(6), 0x14), (6, b"\x41\x00" + b"a" * 65 + b"\x00", 0x15),
    (6, b"\x03\x00a_b\x00", 0x09), (6, b"\x03\x00abc", 0x13), (6, b"\x02\x00ab\x00", 0x15), (6, b"\x00\x00", 0x00)])
def test_tcpip_set_attribute_single_checks(attribute: int, value: bytes, status: int) -> None:
    reply = ask(make_device(), encode_request(0x10, encode_request_path(0xF5, 1, attribute), value))
    assert reply.general_status == status


# -- Ethernet Link (0xF6) --------------------------------------------------------------------------


def test_ethernet_link_get_attributes_all_layout() -> None:
    data = ask(make_device(), encode_request(0x01, encode_request_path(0xF6, 1))).data
    assert data == bytes.fromhex(
        "64000000"                 # 1 speed 100 Mbit/s
        "0f000000"                 # 2 flags: link, full duplex, auto-negotiated
        "02007f000001"             # 3 MAC
        + "00" * 44 +              # 4 interface counters, 11 UDINTs (no traffic yet)
        "00" * 48 +                # 5 media counters, 12 UDINTs
        "0100 0000"                # 6 interface control: auto-negotiate, no forced speed
        "02" "01" "01"             # 7 twisted pair, 8 enabled, 9 admin enabled
        "06" + b"port 1".hex() +   # 10 label
        "0a000000 01 6400 01")     # 11 capability: auto-negotiate, manual; one mode, 100 Mbit/s full duplex
    assert len(data) == 128


def test_interface_counters_sum_the_threads_and_get_and_clear_zeroes_them() -> None:
    device = make_device()
    device.traffic.received(100)
    device.traffic.received(60, unicast=False)
    device.traffic.sent(40)
    device.io_traffic.received(26)
    device.io_traffic.discarded()
    device.io_traffic.sent(22, unicast=False)
    device.io_traffic.send_failed()
    expected = struct.pack("<11I", 186, 2, 1, 1, 0, 0, 62, 1, 1, 0, 1)
    get = encode_request(0x0E, encode_request_path(0xF6, 1, 4))
    clear = encode_request(0x4C, encode_request_path(0xF6, 1, 4))
    assert ask(device, get).data == expected
    reply = ask(device, clear)
    assert (reply.service, reply.general_status, reply.data) == (0xCC, 0, expected)
    assert ask(device, get).data == bytes(44)
    device.io_traffic.received(5)
    assert ask(device, get).data == struct.pack("<11I", 5, 1, *[0] * 9)
    media = ask(device, encode_request(0x4C, encode_request_path(0xF6, 1, 5)))
    assert (media.general_status, media.data) == (0, bytes(48))


def test_interface_counters_wrap_as_udints() -> None:
    device = make_device()
    device.traffic.received(0xFFFFFFFF)
    device.traffic.received(3)
    data = ask(device, encode_request(0x0E, encode_request_path(0xF6, 1, 4))).data
    assert struct.unpack_from("<2I", data) == (2, 2)


@pytest.mark.parametrize(("path", "status"), [((0xF6, 1, 1), 0x2E), ((0xF6, 1, 10), 0x2E), ((0xF6, 1, 12), 0x14),
                                              ((0xF6, 1, None), 0x14), ((0xF6, 0, 4), 0x2E), ((0xF6, 0, 8), 0x14),
                                                  ((1, 1, 1), 0x08)])
def test_get_and_clear_elsewhere(path: tuple, status: int) -> None:
    assert ask(make_device(), encode_request(0x4C, encode_request_path(*path))).general_status == status


@pytest.mark.parametrize(("value", "status", "flags"), [
    (b"\x02\x00\x64\x00", 0x00, 0x13), (b"\x01\x00\x00\x00", 0x00, 0x0F), (b"\x01\x00\x64\x00", 0x0C, 0x0F),
    (b"\x03\x00\x00\x00", 0x0C, 0x0F), (b"\x00\x00\x64\x00", 0x09, 0x0F), (b"\x02\x00\x0a\x00", 0x09, 0x0F),
    (b"\x04\x00\x00\x00", 0x09, 0x0F), (b"\x02\x00\x64", 0x13, 0x0F), (b"\x02\x00\x64\x00\x00", 0x15, 0x0F)])
def test_interface_control(value: bytes, status: int, flags: int) -> None:
    device = make_device()
    assert ask(device, encode_request(0x10, encode_request_path(0xF6, 1, 6), value)).general_status == status
    assert ask(device, encode_request(0x0E, encode_request_path(0xF6, 1, 2))).data == struct.pack("<I", flags)


def test_ethernet_link_read_only_attributes() -> None:
    device = make_device()
    for attribute in (4, 5, 7, 8, 9, 10, 11):
        reply = ask(device, encode_request(0x10, encode_request_path(0xF6, 1, attribute), b"\x02"))
        assert reply.general_status == 0x0E


# -- routing as profile data ---------------------------------------------------------------------------


def non_routing_profile(tmp_path: Path) -> Path:
    path = tmp_path / "nonrouting.yaml"
    path.write_text(yaml.safe_dump({"models": {"NonRouting": {
        "kind": "base", "description": "an adapter that routes nothing", "io": {"di": 16, "do": 16},
        "identity": {"vendor_id": 1, "device_type": 12, "product_code": 65001, "revision": [2, 1],
                     "product_name": "NonRouting"},
        "assemblies": {"output": 100, "input": 101, "configuration": 1},
        "routing": {"multiple_service_packet": False, "unconnected_send": False}}}}))
    return path


def test_a_non_routing_model_answers_0x08(tmp_path: Path) -> None:
    model = str(non_routing_profile(tmp_path))
    config = parse_config({"devices": [{"name": "io1", "address": "127.0.0.1", "model": model}]})
    (profile,) = build_profiles(config, shipped_catalogue())
    assert not any(item.endswith("routing") for item in profile.unverified)  # the profile says how it routes
    device = Device(profile)
    inner = encode_request(0x0E, encode_request_path(1, 1, 1))
    msp = encode_request(0x0A, encode_request_path(2, 1), encode_multiple_service([inner]))
    send = encode_request(0x52, encode_request_path(6, 1), encode_unconnected_send(inner, encode_port(1, 0)))
    assert [(r.service, r.general_status, r.data) for r in (ask(device, msp), ask(device, send))] == [
        (0x8A, 0x08, b""), (0xD2, 0x08, b"")]
    assert ask(device, inner).data == b"\x01\x00"


def test_the_abb_models_routing_is_the_default_and_unverified() -> None:
    catalogue = shipped_catalogue()
    for name in catalogue.bases():
        assert catalogue.models[name].routing is None and "routing" in catalogue.models[name].unverified
    assert "routing" not in catalogue.models["DSQC1031"].unverified  # an add-on routes nothing itself
    device = make_device()
    assert "DSQC1030.routing" in device.profile.unverified
    inner = encode_request(0x0E, encode_request_path(1, 1, 1))
    msp = encode_request(0x0A, encode_request_path(2, 1), encode_multiple_service([inner]))
    assert ask(device, msp).general_status == 0
