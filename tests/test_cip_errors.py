"""CIP-level answers and error statuses (CIP Networks Library Vol. 1, appendix B), with raw frames;
the connection stays usable after each."""

from __future__ import annotations

import struct

import pytest

from enip_farm.protocol.cip import decode_reply, encode_multiple_service, encode_request, encode_unconnected_send
from enip_farm.protocol.epath import encode_port, encode_request_path
from enip_farm.protocol.status import GeneralStatus
from tests.helpers import RawClient


@pytest.fixture
def client(dsqc1030: str):
    with RawClient(dsqc1030) as c:
        c.register()
        yield c


@pytest.mark.parametrize(
    ("message", "status"),
    [
        (encode_request(0x0E, encode_request_path(0x77, 1, 1)), GeneralStatus.PATH_DESTINATION_UNKNOWN),
        (encode_request(0x0E, encode_request_path(4, 150, 3)), GeneralStatus.PATH_DESTINATION_UNKNOWN),
        (encode_request(0x0E, encode_request_path(1, 2, 1)), GeneralStatus.PATH_DESTINATION_UNKNOWN),
        (encode_request(0x4B, encode_request_path(4, 100, 3)), GeneralStatus.SERVICE_NOT_SUPPORTED),
        (encode_request(0x54, encode_request_path(6, 1)), GeneralStatus.NOT_ENOUGH_DATA),  # empty Forward Open
        (encode_request(0x56, encode_request_path(6, 1)), GeneralStatus.SERVICE_NOT_SUPPORTED),
        (encode_request(0x0E, encode_request_path(4, 100, 9)), GeneralStatus.ATTRIBUTE_NOT_SUPPORTED),
        (encode_request(0x0E, encode_request_path(1, 1, 99)), GeneralStatus.ATTRIBUTE_NOT_SUPPORTED),
        (encode_request(0x10, encode_request_path(4, 100, 4), b"\x02\x00"), GeneralStatus.ATTRIBUTE_NOT_SETTABLE),
        (encode_request(0x10, encode_request_path(1, 1, 1), b"\x4b\x00"), GeneralStatus.ATTRIBUTE_NOT_SETTABLE),
        (encode_request(0x10, encode_request_path(0xF5, 1, 5), bytes(22)), GeneralStatus.ATTRIBUTE_NOT_SETTABLE),
        (encode_request(0x10, encode_request_path(4, 101, 3), b"\x01\x00"), GeneralStatus.ATTRIBUTE_NOT_SETTABLE),
        (encode_request(0x10, encode_request_path(4, 100, 3), b"\x01"), GeneralStatus.NOT_ENOUGH_DATA),
        (encode_request(0x10, encode_request_path(4, 100, 3), b"\x01\x00\x00"), GeneralStatus.TOO_MUCH_DATA),
        (bytes((0x0E, 2)) + b"\x91\x02ab", GeneralStatus.PATH_SEGMENT_ERROR),  # symbolic segment
        (bytes((0x0E, 1)) + b"\x24\x01", GeneralStatus.PATH_SEGMENT_ERROR),  # no class segment
        (bytes((0x0E, 2)) + b"\x20\x04\x23\x00", GeneralStatus.PATH_SEGMENT_ERROR),  # reserved format
        (bytes((0x0E, 1)) + b"\x21\x00", GeneralStatus.PATH_SIZE_INVALID),  # a 16-bit class segment cut short
        (bytes((0x0E, 0)), GeneralStatus.PATH_SIZE_INVALID),  # no path at all
        (bytes((0x0E, 2)) + b"\x20\x04\x25\x00", GeneralStatus.PATH_SIZE_INVALID),  # 16-bit instance cut short
        (bytes((0x0E, 3)) + b"\x20\x04\x26\x00\x01\x00", GeneralStatus.PATH_SIZE_INVALID),  # 32-bit cut short
        (bytes((0x0E, 2)) + b"\x20\x04\x34\x04", GeneralStatus.PATH_SIZE_INVALID),  # electronic key cut short
        (bytes((0x0E, 1)) + b"\x20", GeneralStatus.PATH_SIZE_INVALID),  # path size beyond the request
        (bytes((0x0E, 9)) + b"\x20\x04\x24\x64", GeneralStatus.PATH_SIZE_INVALID),  # size beyond the request
    ],
)
def test_error_status(client: RawClient, message: bytes, status: int) -> None:
    reply = client.request(message)
    assert reply.service == message[0] | 0x80
    assert reply.general_status == status
    assert client.get(4, 100, 3).general_status == 0  # still usable


def test_short_message_gets_not_enough_data(client: RawClient) -> None:
    reply = client.request(b"\x0e")
    assert reply.service == 0x8E and reply.general_status == GeneralStatus.NOT_ENOUGH_DATA


def test_16_and_32_bit_segments(client: RawClient) -> None:
    client.set(4, 100, 3, b"\x05\x00")
    sixteen = bytes((0x0E, 5)) + b"\x21\x00\x04\x00\x25\x00\x64\x00\x30\x03"
    thirty_two = bytes((0x0E, 7)) + b"\x20\x04\x26\x00\x64\x00\x00\x00\x32\x00\x03\x00\x00\x00"
    assert client.request(sixteen).data == b"\x05\x00"
    assert client.request(thirty_two).data == b"\x05\x00"


def test_assembly_attributes(client: RawClient) -> None:
    assert client.get(4, 100, 4).data == b"\x02\x00"
    assert client.get(4, 101, 4).data == b"\x02\x00"
    assert client.get(4, 1, 4).data == b"\x00\x00"
    assert client.get(4, 1, 3).data == b""
    assert client.set(4, 1, 3, b"").general_status == 0  # the empty configuration assembly
    assert client.get(4, 0, 1).data == b"\x02\x00"  # class revision 2


def test_identity_attributes(client: RawClient) -> None:
    values = {attribute: client.get(1, 1, attribute).data for attribute in range(1, 8)}
    assert values[1] == b"\x4b\x00"  # vendor 75, ABB Robotics
    assert values[5] == b"\x30\x00"  # no I/O connections established
    assert values[7] == b"\x08DSQC1030"
    assert client.get(1, 1, None, service=0x01).data == b"".join(values[a] for a in range(1, 8))
    assert client.get(1, 0, 1).data == b"\x01\x00"  # class revision
    assert client.get(1, 0, 2).data == b"\x01\x00"  # max instance


def test_message_router_object_list(client: RawClient) -> None:
    data = client.get(2, 1, 1).data
    count = struct.unpack_from("<H", data)[0]
    assert set(struct.unpack_from(f"<{count}H", data, 2)) == {0x01, 0x02, 0x04, 0x06, 0xF5, 0xF6}


def test_multiple_service_packet(client: RawClient) -> None:
    good = [encode_request(0x10, encode_request_path(4, 100, 3), b"\x03\x00"),
            encode_request(0x0E, encode_request_path(4, 100, 3)),
            encode_request(0x0E, encode_request_path(1, 1, 1))]
    reply = client.request(encode_request(0x0A, encode_request_path(2, 1), encode_multiple_service(good)))
    assert reply.general_status == 0
    count, *offsets = struct.unpack_from("<4H", reply.data)
    assert count == 3
    parts = [reply.data[a:b] for a, b in zip(offsets, [*offsets[1:], len(reply.data)], strict=True)]
    assert [decode_reply(p).data for p in parts] == [b"", b"\x03\x00", b"\x4b\x00"]

    mixed = [encode_request(0x0E, encode_request_path(4, 100, 3)), encode_request(0x0E, encode_request_path(9, 1, 1))]
    reply = client.request(encode_request(0x0A, encode_request_path(2, 1), encode_multiple_service(mixed)))
    assert reply.general_status == GeneralStatus.EMBEDDED_SERVICE_ERROR
    count, first, second = struct.unpack_from("<3H", reply.data)
    assert decode_reply(reply.data[first:second]).general_status == 0
    assert decode_reply(reply.data[second:]).general_status == GeneralStatus.PATH_DESTINATION_UNKNOWN

    broken = encode_request(0x0A, encode_request_path(2, 1), b"\x05\x00\x02")
    assert client.request(broken).general_status == GeneralStatus.NOT_ENOUGH_DATA


def test_unconnected_send_routes(client: RawClient) -> None:
    inner = encode_request(0x0E, encode_request_path(1, 1, 1))
    to_self = encode_request(0x52, encode_request_path(6, 1), encode_unconnected_send(inner, encode_port(1, 0)))
    reply = client.request(to_self)
    assert reply.service == 0x8E and reply.data == b"\x4b\x00"
    no_route = encode_request(0x52, encode_request_path(6, 1), encode_unconnected_send(inner, b""))
    assert client.request(no_route).data == b"\x4b\x00"
    other_slot = encode_request(0x52, encode_request_path(6, 1), encode_unconnected_send(inner, encode_port(1, 3)))
    reply = client.request(other_slot)
    assert reply.service == 0xD2 and reply.general_status == 0x01 and reply.additional_status == (0x0312,)
    other_port = encode_request(0x52, encode_request_path(6, 1),
                                encode_unconnected_send(inner, encode_port(2, b"127.0.0.9")))
    reply = client.request(other_port)
    assert reply.general_status == 0x01 and reply.additional_status == (0x0311,)
    odd = encode_request(0x10, encode_request_path(4, 100, 3), b"\x07")  # 9 bytes: a pad byte follows
    padded = encode_request(0x52, encode_request_path(6, 1), encode_unconnected_send(odd, encode_port(1, 0)))
    assert client.request(padded).general_status == GeneralStatus.NOT_ENOUGH_DATA
    assert client.request(encode_request(0x52, encode_request_path(6, 1), b"\x0a")).general_status == \
        GeneralStatus.NOT_ENOUGH_DATA


def test_tcpip_and_ethernet_link(make_farm) -> None:
    farm = make_farm({"name": "a", "model": "DSQC1030"}, {"name": "b", "model": "DSQC1030"})
    macs = set()
    for device in farm.devices.values():
        address = device.profile.address
        with RawClient(address) as c:
            c.register()
            config = c.get(0xF5, 1, 5).data
            ip = struct.unpack_from("<I", config)[0]
            assert ip.to_bytes(4, "big") == bytes(int(x) for x in address.split("."))
            assert c.get(0xF5, 1, 1).data == b"\x01\x00\x00\x00"
            assert c.get(0xF5, 1, 4).data == b"\x02\x00\x20\xf6\x24\x01"
            mac = c.get(0xF6, 1, 3).data
            assert len(mac) == 6
            macs.add(mac)
            assert c.get(0xF6, 1, 1).data == struct.pack("<I", 100)
    assert len(macs) == 2
