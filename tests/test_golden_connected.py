"""`golden` replays connected (class-3) sessions: the farm's own recording of pycomm3's connected
messaging replays with 0 failures (on 913aed5: `SEND_UNIT_DATA encapsulation.status: captured 0 !=
farm 3`), against a fresh farm and against the recorded farm while the recorded connection is still
open (fresh connection serials), and a capture that starts inside a connection is replayed on one
golden opens; the mask stays narrow."""

from __future__ import annotations

import shutil
import subprocess
import time
from pathlib import Path

import pytest
import yaml
from pycomm3 import CIPDriver, Services

from enip_farm.capture.compare import ReplayMap, compare_replies
from enip_farm.capture.exchanges import load_exchanges
from enip_farm.capture.golden import replay
from enip_farm.capture.recorder import Recorder
from enip_farm.config import parse_config
from enip_farm.farm.farm import Farm
from enip_farm.protocol.cip import decode_request, decode_unconnected_send, encode_reply
from enip_farm.protocol.commands import decode_send_data, encode_connected_payload, encode_unconnected_payload
from enip_farm.protocol.connection import (
    ConnectionTriad,
    ForwardOpenReply,
    decode_forward_open,
    encode_forward_open_reply,
)
from enip_farm.protocol.encapsulation import HEADER, Command, decode_frame, encode_frame
from enip_farm.pytest_plugin import AddressPool
from tests.helpers import CLI

pytestmark = pytest.mark.class1_paths  # both class-1 paths (tests/conftest.py)


def _connected_session(driver: CIPDriver) -> None:
    written = driver.generic_message(service=Services.set_attribute_single, class_code=4, instance=100,
                                     attribute=3, request_data=b"\x22\x00", connected=True)
    read = driver.generic_message(service=Services.get_attribute_single, class_code=1, instance=1, attribute=7,
                                  connected=True)
    assert written.error is None and read.value == b"\x08DSQC1030"


def _farm(address: str, record: Path | None = None) -> Farm:
    return Farm(parse_config({"devices": [{"name": "io1", "address": address, "model": "DSQC1030"}],
                              "discovery": False}), record=record)


def _captured_triad(capture: Path) -> ConnectionTriad:
    """The triad of the capture's Forward Open (pycomm3 may wrap it in Unconnected Send)."""
    (stream,) = load_exchanges(capture)
    request = decode_request(decode_send_data(stream[1].request.data).items[1].data)
    if request.service == 0x52:
        request = decode_request(decode_unconnected_send(request.data).message)
    return decode_forward_open(request.data, request.service == 0x5B).triad


def _commands(capture: Path) -> list[str]:
    (stream,) = load_exchanges(capture)
    return [Command(e.request.header.command).name for e in stream]


@pytest.mark.system
def test_a_recorded_class3_session_replays_as_golden(free_address: AddressPool, tmp_path: Path) -> None:
    recording, address = tmp_path / "class3.pcap", free_address()
    with _farm(address, recording).running_in_thread(), CIPDriver(address) as driver:
        _connected_session(driver)
    assert _commands(recording) == ["REGISTER_SESSION", "SEND_RR_DATA", "SEND_UNIT_DATA", "SEND_UNIT_DATA",
                                    "SEND_RR_DATA", "UNREGISTER_SESSION"]  # Forward Open ... Forward Close
    config = tmp_path / "cell.yaml"
    config.write_text(yaml.safe_dump({"devices": [{"name": "io1", "address": free_address(), "model": "DSQC1030"}],
                                      "discovery": False}))
    result = subprocess.run([*CLI, "golden", str(recording), "--config", str(config), "--device", "io1"],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stdout + result.stderr
    assert result.stdout.count("PASS  tcp stream 1 #") == 6 and result.stdout.count("SEND_UNIT_DATA") == 2
    assert result.stdout.endswith("6 exchanges: 6 passed, 0 failed\n")


@pytest.mark.integration
def test_replay_beside_the_recorded_connection_still_open(free_address: AddressPool, tmp_path: Path) -> None:
    """The recorded client's connection is still open on the farm when its own capture is replayed
    there, twice: each replay's Forward Open takes a fresh serial, so none collides (0x0100)."""
    recording, snapshot, address = tmp_path / "open.pcap", tmp_path / "snapshot.pcap", free_address()
    farm = _farm(address, recording)
    with farm.running_in_thread(), CIPDriver(address) as driver:
        _connected_session(driver)
        shutil.copy(recording, snapshot)  # the Forward Open and both requests; no Forward Close yet
        assert _commands(snapshot) == ["REGISTER_SESSION", "SEND_RR_DATA", "SEND_UNIT_DATA", "SEND_UNIT_DATA"]
        for _ in range(2):
            results = replay(load_exchanges(snapshot), lambda _: address)
            assert [r.line() for r in results if not r.passed] == [] and len(results) == 4
        device = farm.device("io1")
        deadline = time.monotonic() + 10  # the replays' connections close with their TCP connections
        while len(device.connections) > 1 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert [c.triad for c in device.connections.values()] == [_captured_triad(snapshot)]  # the client's


@pytest.mark.integration
def test_a_capture_that_starts_inside_a_connection(free_address: AddressPool, tmp_path: Path) -> None:
    """No RegisterSession, no Forward Open: golden registers a session and opens a class-3
    connection for the captured one, and the captured Forward Close closes golden's."""
    recording, address = tmp_path / "whole.pcap", free_address()
    with _farm(address, recording).running_in_thread(), CIPDriver(address) as driver:
        _connected_session(driver)
    (stream,) = load_exchanges(recording)
    middle = tmp_path / "middle.pcap"
    recorder = Recorder(middle)
    recorder.tcp_opened("s", ("192.168.125.5", 50000), (address, 44818))
    for exchange in stream[2:]:  # from the first SendUnitData on
        recorder.tcp_data("s", True, exchange.raw_request)
        if exchange.reply is not None:
            recorder.tcp_data("s", False, HEADER.pack(*exchange.reply.header) + exchange.reply.data)
    recorder.close()
    target = free_address()
    farm = _farm(target)
    with farm.running_in_thread():
        results = replay(load_exchanges(middle), lambda _: target)
        assert [r.line() for r in results] == [
            "PASS  tcp stream 1 #1 SEND_UNIT_DATA", "PASS  tcp stream 1 #2 SEND_UNIT_DATA",
            "PASS  tcp stream 1 #3 SEND_RR_DATA", "PASS  tcp stream 1 #4 UNREGISTER_SESSION"]
        assert farm.device("io1").outputs == b"\x22\x00"


def _forward_open_frame(o_t: int, t_o: int, triad: ConnectionTriad) -> bytes:
    reply = encode_reply(0x54, data=encode_forward_open_reply(ForwardOpenReply(o_t, t_o, triad, 20_000, 20_000)))
    return encode_frame(Command.SEND_RR_DATA, encode_unconnected_payload(reply), 1)


def test_the_connection_mask_is_narrow() -> None:
    """Only the ids the target chose and the serial golden replaced are mapped: an originator serial,
    an echoed T->O id or a connected reply's T->O id that differ are failures."""
    captured_triad, sent_triad = ConnectionTriad(7, 0x1234, 0xABCD), ConnectionTriad(99, 0x1234, 0xABCD)
    mapping = ReplayMap(sessions={1: 1}, triads={captured_triad: sent_triad}, sent_t_o_ids={0x7E57})
    captured = decode_frame(_forward_open_frame(0x1111, 0x7E57, captured_triad))
    assert compare_replies(captured, decode_frame(_forward_open_frame(0x2222, 0x7E57, sent_triad)), mapping) == []
    assert mapping.o_t_ids == {0x1111: 0x2222}
    assert compare_replies(captured, decode_frame(_forward_open_frame(0x2222, 0x7E58, sent_triad)), mapping) == [
        ("forward_open.t_o_connection_id", 0x7E57, 0x7E58)]
    other = sent_triad._replace(originator_serial=0xABCE)
    assert compare_replies(captured, decode_frame(_forward_open_frame(0x2222, 0x7E57, other)), mapping) == [
        ("forward_open.originator_serial", 0xABCD, 0xABCE)]
    assert compare_replies(captured, decode_frame(_forward_open_frame(0x3333, 0x7E57, sent_triad)), mapping) == [
        ("forward_open.o_t_connection_id", 0x2222, 0x3333)]  # mapped once, then held to it
    reply = encode_reply(0x0E, data=b"\x08DSQC1030")
    connected = decode_frame(encode_frame(Command.SEND_UNIT_DATA, encode_connected_payload(0x7E57, 3, reply), 1))
    assert compare_replies(connected, connected, mapping) == []
    wrong_id = decode_frame(encode_frame(Command.SEND_UNIT_DATA, encode_connected_payload(0x7E58, 3, reply), 1))
    assert compare_replies(connected, wrong_id, mapping) == [("cpf.item[0].connection_id", 0x7E57, 0x7E58)]
    wrong_count = decode_frame(encode_frame(Command.SEND_UNIT_DATA, encode_connected_payload(0x7E57, 4, reply), 1))
    assert compare_replies(connected, wrong_count, mapping) == [("cpf.item[1].sequence_count", "03 00", "04 00")]
