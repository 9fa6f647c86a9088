"""The sans-IO codec on its own: EPATH, CPF, CIP layouts, and a bounded, seeded fuzz of the session
state machine (malformed input must become status replies, never exceptions)."""

from __future__ import annotations

import random

import pytest

from enip_farm.config import parse_config
from enip_farm.device import reset as device_reset
from enip_farm.device.build import build_profiles
from enip_farm.device.catalogue import shipped_catalogue
from enip_farm.device.device import Device
from enip_farm.farm import console
from enip_farm.protocol import encapsulation, status
from enip_farm.protocol.cip import (
    CipDecodeError,
    decode_multiple_service_request,
    decode_reply,
    decode_unconnected_send,
    encode_multiple_service,
    encode_reply,
    encode_request,
    encode_unconnected_send,
)
from enip_farm.protocol.commands import decode_unconnected_message, encode_send_data, encode_send_rr_data
from enip_farm.protocol.cpf import CpfError, ItemType, decode_items, encode_items
from enip_farm.protocol.encapsulation import Command, Frame, StreamFramer, encode_frame
from enip_farm.protocol.epath import (
    ElectronicKey,
    LogicalSegment,
    LogicalType,
    PathError,
    PortSegment,
    decode_epath,
    decode_request_path,
    encode_electronic_key,
    encode_logical,
    encode_port,
    encode_request_path,
)
from enip_farm.protocol.safety import segment


@pytest.mark.parametrize("value", [0, 1, 0xFF, 0x100, 0xFFFF, 0x10000, 0xFFFFFFFF])
@pytest.mark.parametrize("kind", [LogicalType.CLASS_ID, LogicalType.INSTANCE_ID, LogicalType.ATTRIBUTE_ID,
                                  LogicalType.CONNECTION_POINT])
def test_logical_segment_round_trip(kind: LogicalType, value: int) -> None:
    encoded = encode_logical(kind, value)
    assert len(encoded) == (2 if value <= 0xFF else 4 if value <= 0xFFFF else 6)
    assert decode_epath(encoded) == [LogicalSegment(kind, value)]


def test_port_segments() -> None:
    assert encode_port(1, 0) == b"\x01\x00"
    assert decode_epath(b"\x01\x00") == [PortSegment(1, b"\x00")]
    extended = encode_port(2, b"127.0.0.9")  # 0x12, size 9, address, pad
    assert extended == b"\x12\x09127.0.0.9\x00"
    assert decode_epath(extended) == [PortSegment(2, b"127.0.0.9")]
    big_port = encode_port(0x123, 5)  # port 15 escape, 16-bit port id, link 5: even, no pad
    assert big_port == b"\x0f\x23\x01\x05"
    assert decode_epath(big_port) == [PortSegment(0x123, b"\x05")]
    with pytest.raises(PathError, match="^truncated link address$"):
        decode_epath(b"\x12\x09127")


def test_electronic_key_and_connection_path() -> None:
    key = ElectronicKey(75, 7, 1030, 1, 1, True)
    path = encode_electronic_key(key) + bytes.fromhex("20 04 24 01 2C 64 2C 65")
    segments = decode_epath(path)
    assert segments[0] == key
    assert segments[1:] == [LogicalSegment(LogicalType.CLASS_ID, 4), LogicalSegment(LogicalType.INSTANCE_ID, 1),
                            LogicalSegment(LogicalType.CONNECTION_POINT, 100),
                            LogicalSegment(LogicalType.CONNECTION_POINT, 101)]


def test_request_path() -> None:
    assert decode_request_path(encode_request_path(4, 100, 3)) == (4, 100, 3, None)
    assert decode_request_path(encode_request_path(1)) == (1, 0, None, None)  # the class itself
    with pytest.raises(PathError, match="^request path does not start with a class segment$") as error:
        decode_request_path(b"\x24\x01")
    assert error.value.status == 0x04


def test_cpf_round_trip_and_errors() -> None:
    items = [(ItemType.NULL_ADDRESS, b""), (ItemType.UNCONNECTED_DATA, b"\x0e\x01\x20\x01")]
    assert [tuple(i) for i in decode_items(encode_items(items))] == items
    for broken, message in ((b"", "no item count"), (b"\x01\x00\x00", "truncated item header"),
                            (b"\x01\x00\xb2\x00\x05\x00ab", "item length exceeds data"),
                            (encode_items(items) + b"x", "bytes after the last item")):
        with pytest.raises(CpfError, match=f"^{message}$"):
            decode_items(broken)


def test_canonical_and_general_send_data_paths_agree() -> None:
    message = b"\x0e\x01\x20\x01"
    canonical = encode_send_data([(ItemType.NULL_ADDRESS, b""), (ItemType.UNCONNECTED_DATA, message)])
    assert decode_unconnected_message(canonical) == (message, ())
    assert decode_unconnected_message(canonical + b"x") is None  # caught by both paths
    assert decode_unconnected_message(canonical[:-1]) is None
    sockaddr = bytes.fromhex("0002 08ae 00000000 0000000000000000")
    with_item = encode_send_data([(ItemType.NULL_ADDRESS, b""), (ItemType.UNCONNECTED_DATA, message),
                                  (ItemType.SOCKADDR_T_O, sockaddr)])
    assert decode_unconnected_message(with_item) == (message, ((ItemType.SOCKADDR_T_O, sockaddr),))
    wrong_item = encode_send_data([(ItemType.NULL_ADDRESS, b""), (ItemType.UNCONNECTED_DATA, message),
                                   (ItemType.CONNECTED_DATA, sockaddr)])
    assert decode_unconnected_message(wrong_item) is None


def test_cip_layouts() -> None:
    assert encode_reply(0x0E, 0, b"\x01\x02") == b"\x8e\x00\x00\x00\x01\x02"
    assert decode_reply(encode_reply(0x52, 1, b"\x01", (0x0312,))) == (0xD2, 1, (0x0312,), b"\x01")
    parts = [b"\x0e\x01\x20\x01", b"\x0e\x02\x20\x01\x24\x01"]
    assert decode_multiple_service_request(encode_multiple_service(parts)) == parts
    with pytest.raises(CipDecodeError, match="^offset out of range$"):
        decode_multiple_service_request(b"\x02\x00\x06\x00\x50\x00")
    inner = encode_request(0x10, encode_request_path(4, 100, 3), b"\x07")
    decoded = decode_unconnected_send(encode_unconnected_send(inner, encode_port(1, 0)))
    assert decoded.message == inner and decoded.route_path == b"\x01\x00"


def test_fuzzed_frames_never_raise() -> None:
    """Mutations of valid frames: every one becomes replies or silence, and replies are whole frames."""
    config = parse_config({"devices": [{"name": "f", "address": "127.0.0.5", "model": "DSQC1030",
                                        "addons": ["DSQC1032"]}]})
    device = Device(build_profiles(config, shipped_catalogue())[0])
    seeds = [
        encode_frame(Command.REGISTER_SESSION, b"\x01\x00\x00\x00"),
        encode_send_rr_data(bytes.fromhex("10 03 20 04 24 64 30 03 10 00"), 1),
        encode_send_rr_data(encode_request(0x0A, encode_request_path(2, 1), encode_multiple_service(
            [encode_request(0x0E, encode_request_path(1, 1, 7)), encode_request(0x01, encode_request_path(0xF5, 1))]
        )), 1),
        encode_send_rr_data(encode_request(0x52, encode_request_path(6, 1), encode_unconnected_send(
            encode_request(0x0E, encode_request_path(4, 101, 3)), encode_port(1, 0))), 1),
        encode_frame(Command.LIST_IDENTITY),
    ]
    rng = random.Random(20261122)
    for _ in range(4000):
        frame = bytearray(rng.choice(seeds))
        for _ in range(rng.randint(1, 4)):
            position = rng.randrange(len(frame))
            choice = rng.random()
            if choice < 0.6:
                frame[position] = rng.randrange(256)
            elif choice < 0.8:
                del frame[position]
            else:
                frame.insert(position, rng.randrange(256))
        session = device_session(device)
        for reply in session.receive(bytes(frame), 0):
            out = StreamFramer(65535).feed(reply)
            assert len(out) == 1 and type(out[0]) is Frame


def device_session(device: Device):
    from enip_farm.protocol.session import EncapsulationSession

    session = EncapsulationSession(device)
    session.receive(encode_frame(Command.REGISTER_SESSION, b"\x01\x00\x00\x00"), 0)
    return session


def test_status_words_and_module_constants_are_read_only() -> None:
    assert status.describe_status(0x01, 0x0205) == (
        "0x01/0x0205 connection failure: parameter error in unconnected request service")  # Vol. 1, 3-5.33
    tables = (status.GENERAL_STATUS_TEXT, status.EXTENDED_STATUS_TEXT, segment.SIZE_WORDS, console._LEVELS,
              encapsulation._COMMAND_NAMES, device_reset.RESET_KINDS)
    for table in tables:
        with pytest.raises(TypeError, match="^'mappingproxy' object does not support item assignment$"):
            table[0x7FFF] = 0  # type: ignore[index]
    assert isinstance(console._TOLD_ELSEWHERE, frozenset)
