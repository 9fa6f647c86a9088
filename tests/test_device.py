"""Unit tests of one device in-process (device/device.py) with an injected clock and an injected
datagram sender: the device lock makes the connection table, the images and the T->O packets one
story. No sockets, no sleeps."""

from __future__ import annotations

from enip_farm.cip.connection_events import ConnectionTimedOut
from enip_farm.config import parse_config
from enip_farm.device.build import build_profiles
from enip_farm.device.catalogue import shipped_catalogue
from enip_farm.device.device import Device
from enip_farm.device.events import Event, ImageChanged
from enip_farm.protocol.cip import decode_reply, encode_request
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
from enip_farm.protocol.epath import encode_request_path
from enip_farm.protocol.session import MessageContext

MS = 1_000_000
T0 = 1_000 * MS
PATH = bytes.fromhex("20 04 24 01 2C 64 2C 65")
TRIAD = ConnectionTriad(7, 0x1234, 0xABCD)
SCANNER = "127.0.0.9"


def make_device(**implicit: object) -> Device:
    config = parse_config({"devices": [{"name": "io1", "address": "127.0.0.1", "model": "DSQC1030",
                                        "implicit": implicit}]})
    (profile,) = build_profiles(config, shipped_catalogue())
    return Device(profile)


def request(device: Device, message: bytes, now: int) -> bytes:
    reply, _ = device.handle_unconnected(message, MessageContext(SCANNER, None, (), now))
    return reply


def forward_open(rpi_us: int = 10_000) -> bytes:
    p2p = ConnectionType.POINT_TO_POINT
    fo = ForwardOpenRequest(0x0A, 0x0E, 0, 0x7E570001, TRIAD, 0, rpi_us, NetworkParameters(False, p2p, 2, False, 8),
                            rpi_us, NetworkParameters(False, p2p, 2, False, 4), 0x01, PATH)
    return encode_request(0x54, encode_request_path(6, 1), encode_forward_open(fo))


def forward_close() -> bytes:
    return encode_request(0x4E, encode_request_path(6, 1),
                          encode_forward_close(ForwardCloseRequest(0x0A, 0x0E, TRIAD, PATH)))


def test_no_t_o_packet_after_the_forward_close() -> None:
    device = make_device()
    sent: list[tuple[int, bytes]] = []
    assert decode_reply(request(device, forward_open(), T0)).general_status == 0
    assert device.service_io(T0, lambda data, address: sent.append((T0, data))) == T0 + 10 * MS
    assert len(sent) == 1 and decode_io_packet(sent[0][1]).sequence == 1
    # The Forward Close is handled at the very time the next T->O packet is due.
    assert decode_reply(request(device, forward_close(), T0 + 10 * MS)).general_status == 0
    assert device.service_io(T0 + 10 * MS, lambda data, address: sent.append((T0 + 10 * MS, data))) is None
    assert len(sent) == 1


def test_silence_closes_at_the_deadline_with_outputs_off_and_observers_told() -> None:
    device = make_device()  # first watchdog 10 s (the default)
    seen: list[Event] = []
    device.observe(seen.append)
    opened = decode_forward_open_reply(decode_reply(request(device, forward_open(), T0)).data)
    for n in range(1, 101):  # fed for 1 s at the RPI
        assert device.receive_io(encode_io_packet(opened.o_t_connection_id, n, n, b"\x01\x00\x00\x00\x10\x00"),
                                 (SCANNER, 2222), T0 + n * 10 * MS, lambda *_: None)
    last = T0 + 100 * 10 * MS
    assert device.outputs == b"\x10\x00" and device.status == 0x0061
    assert device.service_io(last + 40 * MS - 1, lambda *_: None) <= last + 40 * MS
    assert device.connections and device.outputs == b"\x10\x00"
    device.service_io(last + 40 * MS, lambda *_: None)
    assert not device.connections and device.outputs == b"\x00\x00" and device.status == 0x0030
    timed_out = [e for e in seen if isinstance(e.detail, ConnectionTimedOut)]
    assert len(timed_out) == 1 and timed_out[0].monotonic_ns == last + 40 * MS
    changes = [e.detail for e in seen if isinstance(e.detail, ImageChanged)]
    assert [(c.role, c.old, c.new) for c in changes] == [("output", b"\x00\x00", b"\x10\x00"),
                                                         ("output", b"\x10\x00", b"\x00\x00")]


def test_a_failed_write_changes_nothing() -> None:
    device = make_device()

    def half_then_fail(image: bytearray) -> None:
        image[0] = 0xFF
        raise ValueError("bad signal value")

    try:
        device.write_image("input", half_then_fail)
    except ValueError:
        pass
    assert device.inputs == b"\x00\x00"
