"""Stream framing over real TCP (frames split over many reads, several frames in one read), and
device state: the I/O image persists across connections, devices are isolated, sessions count."""

from __future__ import annotations

import time

import pytest

from enip_farm.protocol.commands import encode_send_rr_data
from enip_farm.protocol.encapsulation import HEADER, Command, StreamFramer, encode_frame
from tests.helpers import RawClient

SET_0x10 = bytes.fromhex("10 03 20 04 24 64 30 03 10 00")
GET = bytes.fromhex("0E 03 20 04 24 64 30 03")


def test_frames_sent_one_byte_at_a_time(dsqc1030: str) -> None:
    stream = (encode_frame(Command.REGISTER_SESSION, b"\x01\x00\x00\x00")
              + encode_send_rr_data(SET_0x10, 1, b"byte-set")
              + encode_send_rr_data(GET, 1, b"byte-get"))
    with RawClient(dsqc1030) as c:
        c.sock.setsockopt(6, 1, 1)  # TCP_NODELAY: each byte its own segment
        for i in range(len(stream)):
            c.send(stream[i : i + 1])
            time.sleep(0.0005)  # pacing, not synchronisation: the test holds however the bytes arrive
        frames = [c.recv_frame() for _ in range(3)]
    assert [f.header.command for f in frames] == [0x65, 0x6F, 0x6F]
    assert frames[2].header.sender_context == b"byte-get"
    assert frames[2].data.endswith(b"\x8e\x00\x00\x00\x10\x00")


def test_several_frames_in_one_write(dsqc1030: str) -> None:
    burst = (encode_frame(Command.REGISTER_SESSION, b"\x01\x00\x00\x00")
             + encode_frame(Command.NOP, b"xx")
             + b"".join(encode_send_rr_data(GET if i % 2 else SET_0x10, 1, bytes([i]) * 8) for i in range(20)))
    with RawClient(dsqc1030) as c:
        c.send(burst)
        frames = [c.recv_frame() for _ in range(21)]
    assert frames[0].header.command == Command.REGISTER_SESSION
    assert [f.header.sender_context for f in frames[1:]] == [bytes([i]) * 8 for i in range(20)]


@pytest.mark.parametrize("cut", [1, 5, 23, 24, 25, 40])
def test_framer_splits(cut: int) -> None:
    frames = encode_send_rr_data(GET, 1, b"AAAAAAAA") + encode_send_rr_data(GET, 1, b"BBBBBBBB")
    framer = StreamFramer()
    out = []
    for start in range(0, len(frames), cut):
        out += framer.feed(frames[start : start + cut])
    assert [f.header.sender_context for f in out] == [b"AAAAAAAA", b"BBBBBBBB"]
    assert framer.pending == 0


def test_framer_oversize_is_read_whole_and_the_stream_goes_on() -> None:
    framer = StreamFramer(max_length=100)
    out = framer.feed(HEADER.pack(0x6F, 101, 1, 0, bytes(8), 0) + bytes(101))
    assert [type(f).__name__ for f in out] == ["OversizeFrame"] and framer.pending == 0
    assert [f.header.command for f in framer.feed(encode_frame(Command.NOP))] == [Command.NOP]


def test_image_persists_across_connections_and_sessions(dsqc1030: str) -> None:
    with RawClient(dsqc1030) as c:
        c.register()
        c.set(4, 100, 3, b"\xaa\x55")
    with RawClient(dsqc1030) as c:
        assert c.register() == 2  # sessions numbered from 1 upward per device
        assert c.get(4, 100, 3).data == b"\xaa\x55"


def test_two_devices_are_isolated(make_farm) -> None:
    farm = make_farm({"name": "a", "model": "DSQC1030"}, {"name": "b", "model": "DSQC1030", "addons": ["DSQC1031"]})
    a, b = (farm.device(n).profile.address for n in ("a", "b"))
    with RawClient(a) as ca, RawClient(b) as cb:
        assert ca.register() == 1 and cb.register() == 1  # each device numbers its own sessions
        ca.set(4, 100, 3, b"\x01\x02")
        assert cb.get(4, 100, 3).data == b"\x00\x00\x00\x00"
        cb.set(4, 100, 3, b"\x09\x08\x07\x06")
        assert ca.get(4, 100, 3).data == b"\x01\x02"
    assert farm.device("a").outputs == b"\x01\x02"
    assert farm.device("b").outputs == b"\x09\x08\x07\x06"


def test_inputs_set_by_farm_and_writable_inputs(make_farm) -> None:
    farm = make_farm({"name": "robot", "model": "DSQC1030"},
                     {"name": "rig", "model": "DSQC1030", "writable_inputs": True})
    farm.device("robot").set_inputs(b"\x81\x00")
    with RawClient(farm.device("robot").profile.address) as c:
        c.register()
        assert c.get(4, 101, 3).data == b"\x81\x00"
        assert c.set(4, 101, 3, b"\x00\x00").general_status == 0x0E
    with RawClient(farm.device("rig").profile.address) as c:
        c.register()
        assert c.set(4, 101, 3, b"\x03\x00").general_status == 0
    assert farm.device("rig").inputs == b"\x03\x00"


def test_addon_sizes(make_farm) -> None:
    farm = make_farm(
        {"name": "d1", "model": "DSQC1030", "addons": ["DSQC1031"]},
        {"name": "d2", "model": "DSQC1030", "addons": ["DSQC1032"]},
        {"name": "d3", "model": "DSQC1030", "addons": ["DSQC1033"]},
        {"name": "d4", "model": "DSQC1030", "addons": ["DSQC1031", "DSQC1032"],
         "assemblies": {"input_size": 6}},
        {"name": "s1", "model": "DSQC1042"},
    )
    expected = {"d1": (4, 4), "d2": (10, 10), "d3": (3, 3), "d4": (6, 12)}
    for name, (inputs, outputs) in expected.items():
        with RawClient(farm.device(name).profile.address) as c:
            c.register()
            assert c.get(4, 101, 4).data == inputs.to_bytes(2, "little")
            assert c.get(4, 100, 4).data == outputs.to_bytes(2, "little")
    with RawClient(farm.device("s1").profile.address) as c:  # safety base: its safety assemblies
        c.register()
        assert c.get(1, 1, 7).data == b"\x08DSQC1042"
        assert c.get(4, 100, 4).data == b"\x01\x00" and c.get(4, 101, 4).data == b"\x02\x00"  # 4 DO, 12 DI
