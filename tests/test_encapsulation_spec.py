"""Raw frames against the encapsulation rules of CIP Networks Library Vol. 2 that a client rarely
meets: a request with a non-zero Status is ignored with no reply (2-3.5, TCP and UDP); a message
longer than the farm takes is read whole, so the stream keeps its framing (2-3.3); a NOP may carry
0-65511 bytes and never gets a reply (2-4.1); ListInterfaces is answered over UDP as over TCP
(Table 2-3.2). Each check waits a bounded time for the reply that must not come, then proves the
connection usable with the next request, answered first."""

from __future__ import annotations

import select
import socket
import struct

import pytest

from enip_farm.protocol.encapsulation import HEADER, Command, StreamFramer, encode_frame
from tests.helpers import RawClient

CONTEXT = b"next-req"
SILENCE_S = 0.3  # the bounded wait for a reply that must not come
# Get_Attribute_Single, assembly 100 (outputs) attribute 3; Set_Attribute_Single of the same, 2 bytes
GET_OUTPUTS = bytes.fromhex("0E 03 20 04 24 64 30 03")
SET_OUTPUTS = bytes.fromhex("10 03 20 04 24 64 30 03 5A A5")


def send_rr_data(message: bytes, handle: int, status: int = 0, context: bytes = CONTEXT) -> bytes:
    """A SendRRData frame built byte by byte: interface handle, timeout, null address, unconnected data."""
    body = struct.pack("<IHHHHHH", 0, 0, 2, 0x0000, 0, 0x00B2, len(message)) + message
    return HEADER.pack(0x006F, len(body), handle, status, context, 0) + body


def rr_reply(message: bytes, handle: int, context: bytes = CONTEXT) -> bytes:
    """The exact SendRRData reply frame carrying `message`."""
    return send_rr_data(message, handle, 0, context)


def silent(sock: socket.socket, timeout: float = SILENCE_S) -> bool:
    """True when nothing arrives on the socket within `timeout` seconds."""
    readable, _, _ = select.select([sock], [], [], timeout)
    return not readable


def raw_reply(c: RawClient, expected_length: int) -> bytes:
    """Exactly `expected_length` bytes from the stream (a reply read whole, not through the codec)."""
    data = b""
    while len(data) < expected_length:
        chunk = c.sock.recv(expected_length - len(data))
        assert chunk, "the device closed the connection"
        data += chunk
    return data


# -- 2-3.5: a request whose Status is not zero gets no reply ---------------------------------------------


@pytest.mark.parametrize("status", [1, 0x64, 0xFFFFFFFF])
def test_send_rr_data_with_status_is_ignored(dsqc1030: str, status: int) -> None:
    with RawClient(dsqc1030) as c:
        handle = c.register()
        c.send(send_rr_data(GET_OUTPUTS, handle, status, b"ignored!"))
        assert silent(c.sock)
        c.send(send_rr_data(GET_OUTPUTS, handle))
        reply = rr_reply(bytes.fromhex("8E 00 00 00 00 00"), handle)  # success, outputs 00 00
        assert raw_reply(c, len(reply)) == reply


def test_set_with_status_changes_nothing(enip_farm) -> None:
    device = enip_farm(name="io1", model="DSQC1030")["io1"]
    with RawClient(device.address) as c:
        handle = c.register()
        c.send(send_rr_data(SET_OUTPUTS, handle, 0x64, b"ignored!"))
        assert silent(c.sock)
        c.send(send_rr_data(GET_OUTPUTS, handle))
        reply = rr_reply(bytes.fromhex("8E 00 00 00 00 00"), handle)
        assert raw_reply(c, len(reply)) == reply  # the outputs are still 00 00
    (event,) = device.events("encapsulation ignored")
    assert event.text.startswith("SendRRData from 127.") and event.text.endswith(
        "carried status 0x00000064; a request's status must be 0 (Vol. 2, 2-3.5): no reply")


@pytest.mark.parametrize("command", [Command.REGISTER_SESSION, Command.UNREGISTER_SESSION, Command.LIST_IDENTITY,
                                     Command.LIST_SERVICES, Command.LIST_INTERFACES, 0x00C8])
def test_any_command_with_status_is_ignored(dsqc1030: str, command: int) -> None:
    """RegisterSession registers nothing, UnRegisterSession ends nothing, an unknown command gets no 0x0001."""
    with RawClient(dsqc1030) as c:
        data = b"\x01\x00\x00\x00" if command == Command.REGISTER_SESSION else b""
        c.send(HEADER.pack(command, len(data), 1, 7, b"ignored!", 0) + data)
        assert silent(c.sock)
        assert c.register() == 1  # the first session of the device: the ignored RegisterSession took none
        c.send(HEADER.pack(command, len(data), 1, 2, b"ignored!", 0) + data)  # with the session now open
        assert silent(c.sock)
        c.send(send_rr_data(GET_OUTPUTS, 1))
        reply = rr_reply(bytes.fromhex("8E 00 00 00 00 00"), 1)
        assert raw_reply(c, len(reply)) == reply


def test_udp_list_identity_with_status_is_ignored(dsqc1030: str) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.sendto(HEADER.pack(Command.LIST_IDENTITY, 0, 0, 7, b"ignored!", 0), (dsqc1030, 44818))
        sock.sendto(HEADER.pack(Command.LIST_SERVICES, 0, 0, 1, b"ignored!", 0), (dsqc1030, 44818))
        sock.sendto(HEADER.pack(Command.LIST_INTERFACES, 0, 0, 0x65, b"ignored!", 0), (dsqc1030, 44818))
        assert silent(sock)
        sock.sendto(HEADER.pack(Command.LIST_IDENTITY, 0, 0, 0, CONTEXT, 0), (dsqc1030, 44818))
        sock.settimeout(10)
        data, _ = sock.recvfrom(2048)
        assert data[:2] == b"\x63\x00" and data[8:24] == bytes(4) + CONTEXT + bytes(4)  # status 0, the marker


# -- Table 2-3.2: ListInterfaces over UDP, answered as over TCP ------------------------------------------


def test_list_interfaces_over_udp_as_over_tcp(dsqc1030: str) -> None:
    request = HEADER.pack(Command.LIST_INTERFACES, 0, 0, 0, b"ifaces!!", 0)
    expected = bytes.fromhex("64 00 02 00 00 00 00 00 00 00 00 00") + b"ifaces!!" + bytes.fromhex("00 00 00 00 00 00")
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.settimeout(10)
        sock.sendto(request, (dsqc1030, 44818))
        data, source = sock.recvfrom(2048)
    assert (data, source) == (expected, (dsqc1030, 44818))
    with RawClient(dsqc1030) as c:
        c.send(request)
        assert raw_reply(c, len(expected)) == expected


# -- 2-3.3 and 2-4.1: whole messages, however long -------------------------------------------------------


def test_longest_nop_gets_no_reply_and_the_stream_goes_on(dsqc1030: str) -> None:
    with RawClient(dsqc1030) as c:
        handle = c.register()
        c.send(encode_frame(Command.NOP, bytes(range(256)) * 255 + bytes(231), handle))  # 65511 bytes of data
        assert silent(c.sock)
        c.send(send_rr_data(GET_OUTPUTS, handle))
        reply = rr_reply(bytes.fromhex("8E 00 00 00 00 00"), handle)
        assert raw_reply(c, len(reply)) == reply


def test_nop_in_pieces_then_a_request(dsqc1030: str) -> None:
    """A 20000-byte NOP sent in pieces, the last one carrying the next request too."""
    with RawClient(dsqc1030) as c:
        handle = c.register()
        nop = encode_frame(Command.NOP, b"\xff" * 20000, handle)
        c.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        head, tail = nop[:-1000], nop[-1000:]
        for start in range(0, len(head), 3000):
            c.send(head[start : start + 3000])
        assert silent(c.sock, 0.05)
        c.send(tail + send_rr_data(GET_OUTPUTS, handle))
        reply = rr_reply(bytes.fromhex("8E 00 00 00 00 00"), handle)
        assert raw_reply(c, len(reply)) == reply


def test_request_longer_than_the_farm_takes_gets_0x0065_and_the_stream_goes_on(dsqc1030: str) -> None:
    with RawClient(dsqc1030) as c:
        handle = c.register()
        c.send(send_rr_data(GET_OUTPUTS + bytes(5000), handle, context=b"too-long"))
        refused = HEADER.pack(0x006F, 0, handle, 0x0065, b"too-long", 0)  # no data
        assert raw_reply(c, len(refused)) == refused
        c.send(send_rr_data(GET_OUTPUTS, handle))
        reply = rr_reply(bytes.fromhex("8E 00 00 00 00 00"), handle)
        assert raw_reply(c, len(reply)) == reply


def test_framer_reads_an_oversize_message_whole() -> None:
    framer = StreamFramer(max_length=100)
    long_message = HEADER.pack(0x6F, 300, 1, 0, b"too-long", 0) + bytes(300)
    after = encode_frame(Command.LIST_SERVICES, sender_context=b"after!!!")
    assert framer.feed(long_message[:50]) == []
    assert framer.pending == 300 + 24 - 50  # counted, not buffered
    assert framer.feed(long_message[50:200]) == []
    out = framer.feed(long_message[200:] + after)
    assert [type(f).__name__ for f in out] == ["OversizeFrame", "Frame"]
    assert out[0].header.sender_context == b"too-long" and out[0].header.length == 300
    assert out[1].header.sender_context == b"after!!!" and framer.pending == 0
    whole = framer.feed(long_message + after, limit=1)  # a whole one in a read: in its place, limits kept
    assert [type(f).__name__ for f in whole] == ["OversizeFrame"] and framer.has_frame
    assert [f.header.sender_context for f in framer.feed(b"")] == [b"after!!!"]
