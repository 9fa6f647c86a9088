"""Hostile and misbehaving peers against a farm on loopback: the encapsulation inactivity
timeout (TCP/IP attribute 13), the cap on TCP connections, and a client that never reads its
replies (backpressure: nothing lost, another device still answered)."""

from __future__ import annotations

import socket
import time

import pytest

from enip_farm.protocol.cip import decode_reply, encode_request
from enip_farm.protocol.commands import encode_send_rr_data
from enip_farm.protocol.encapsulation import StreamFramer
from enip_farm.protocol.epath import encode_request_path
from tests.helpers import RawClient

pytestmark = pytest.mark.integration
GET_OUTPUTS = encode_request(0x0E, encode_request_path(4, 100, 3))


def _eof_within(sock: socket.socket, timeout: float) -> bool:
    sock.settimeout(timeout)
    try:
        return sock.recv(64) == b""
    except (TimeoutError, ConnectionResetError):
        return False


def test_an_idle_connection_is_closed_after_the_inactivity_timeout(make_farm) -> None:
    farm = make_farm({"name": "io1", "model": "DSQC1030", "encapsulation_inactivity_timeout_s": 1})
    device = farm.device("io1")
    with socket.create_connection((device.profile.address, 44818), timeout=5) as idle, \
            RawClient(device.profile.address) as busy:
        idle.sendall(b"\x65\x00\x04\x00\x00\x00")  # half a header: not a request
        busy.register()
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and not device.events.of_kind("tcp inactive"):
            assert busy.get(4, 100, 3).general_status == 0  # a request every 0.2 s keeps it open
            time.sleep(0.2)
        assert _eof_within(idle, 5)
        (closed,) = device.events.of_kind("tcp inactive")
        opened = device.events.of_kind("tcp connected")[0]
        assert 1_000_000_000 <= closed.monotonic_ns - opened.monotonic_ns <= 3_000_000_000
        assert busy.get(4, 100, 3).general_status == 0  # fed every 0.2 s: still open
    assert device.counters["tcp_inactivity_closed"] == 1


def test_connections_over_the_device_cap_are_closed_at_once(make_farm) -> None:
    farm = make_farm({"name": "io1", "model": "DSQC1030", "limits": {"max_tcp_connections": 2}},
                     {"name": "io2", "model": "DSQC1030"})
    io1, io2 = farm.device("io1"), farm.device("io2")
    with RawClient(io1.profile.address) as first, RawClient(io1.profile.address) as second, \
            socket.create_connection((io1.profile.address, 44818), timeout=5) as third, \
            RawClient(io2.profile.address) as other:
        assert _eof_within(third, 5)
        for client in (first, second, other):
            client.register()
            assert client.get(4, 100, 3).general_status == 0
    assert io1.counters["tcp_refused"] == 1


def test_a_client_that_never_reads_loses_nothing_and_stalls_no_one(make_farm) -> None:
    farm = make_farm({"name": "flood", "model": "DSQC1030"}, {"name": "calm", "model": "DSQC1030"})
    flood, calm = farm.device("flood"), farm.device("calm")
    with RawClient(flood.profile.address) as c, RawClient(calm.profile.address) as well_behaved:
        handle = c.register()
        well_behaved.register()
        frame = encode_send_rr_data(GET_OUTPUTS, handle)
        c.sock.setblocking(False)
        burst = frame * 256
        sent = 0
        deadline = time.monotonic() + 20
        stalled_since = None
        while time.monotonic() < deadline and sent < 4000 * len(burst):  # at most ~40 MB
            try:
                sent += c.sock.send(burst[sent % len(burst):])
                stalled_since = None
            except BlockingIOError:  # the farm stopped reading: its replies are not being read
                stalled_since = stalled_since or time.monotonic()
                if flood.counters["tcp_write_paused"] and time.monotonic() - stalled_since > 0.5:
                    break  # the farm paused reading because its replies pile up
                time.sleep(0.01)
            assert well_behaved.get(4, 100, 3).general_status == 0  # another device keeps answering
        assert flood.counters["tcp_write_paused"] >= 1, sent
        requests = sent // len(frame)
        c.sock.setblocking(True)
        c.sock.settimeout(10)
        framer, replies = StreamFramer(), 0
        while replies < requests:
            data = c.sock.recv(1 << 20)
            assert data, f"closed after {replies} of {requests} replies"
            for reply in framer.feed(data):
                assert decode_reply(reply.data[16:]).general_status == 0
                replies += 1
        assert replies == requests  # every whole request answered, none dropped
