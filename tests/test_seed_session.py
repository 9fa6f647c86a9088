"""The seed's captured session (../shared/seed-facts.md) against a farm device, with each real peer,
and the farm's bytes for the seed's messages compared with the capture."""

from __future__ import annotations

import socket

import ethernetip
from cpppo.server.enip import client as cpppo_client
from cpppo.server.enip.get_attribute import attribute_operations
from pycomm3 import CIPDriver, Services

from enip_farm.protocol.commands import encode_send_rr_data
from enip_farm.protocol.encapsulation import HEADER_SIZE, Command, encode_frame
from tests.helpers import RawClient

# seed-facts.md: the device's Register Session reply, without Ethernet (14), IPv4 (20), TCP (24).
SEED_REGISTER_REPLY = bytes.fromhex(
    "65 00 04 00 01 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 01 00 00 00"
)
SEED_SET = bytes.fromhex("10 03 20 04 24 64 30 03 10 00")
SEED_GET = bytes.fromhex("0E 03 20 04 24 64 30 03")


def test_seed_bytes(dsqc1030: str) -> None:
    """EEIP's frames (zero sender context) get the captured reply bytes and lengths."""
    with RawClient(dsqc1030) as c:
        c.send(encode_frame(Command.REGISTER_SESSION, b"\x01\x00\x00\x00"))
        raw = c.sock.recv(255)  # EEIP reads each reply with one recv(255)
        assert raw == SEED_REGISTER_REPLY

        fresh = c.exchange(encode_send_rr_data(SEED_GET, 1))
        assert HEADER_SIZE + len(fresh.data) == 46
        assert fresh.data[-6:] == bytes.fromhex("8E 00 00 00 00 00")  # nobody has written: 00 00

        set_reply = c.exchange(encode_send_rr_data(SEED_SET, 1))
        assert HEADER_SIZE + len(set_reply.data) == 44
        assert set_reply.data[-4:] == bytes.fromhex("90 00 00 00")

        get_reply = c.exchange(encode_send_rr_data(SEED_GET, 1))
        assert HEADER_SIZE + len(get_reply.data) == 46
        assert get_reply.data[-6:] == bytes.fromhex("8E 00 00 00 10 00")
        # CIP general status at byte 42 and data from byte 44, where EEIP reads them by position
        whole = encode_frame(get_reply.header.command, get_reply.data, 1)
        assert whole[42] == 0 and whole[44:46] == b"\x10\x00"

        c.send(encode_frame(Command.UNREGISTER_SESSION, session_handle=1))
        assert c.is_closed(), "device must close after UnRegisterSession, without a reply"


def test_seed_session_pycomm3(dsqc1030: str) -> None:
    with CIPDriver(dsqc1030) as driver:
        assert driver._session == 1  # the device's first session, as captured
        fresh = driver.generic_message(service=Services.get_attribute_single, class_code=4, instance=100,
                                       attribute=3, connected=False, route_path=False)
        assert fresh.error is None and fresh.value == b"\x00\x00"
        written = driver.generic_message(service=Services.set_attribute_single, class_code=4, instance=100,
                                         attribute=3, request_data=b"\x10\x00", connected=False, route_path=False)
        assert written.error is None
        read = driver.generic_message(service=Services.get_attribute_single, class_code=4, instance=100,
                                      attribute=3, connected=False, route_path=False)
        assert read.error is None and read.value == b"\x10\x00"


def test_seed_session_pycomm3_unconnected_send(make_farm) -> None:
    """pycomm3 with a route path wraps the request in Unconnected Send (0x52) to backplane slot 0."""
    farm = make_farm({"name": "io1", "model": "DSQC1030"})
    address = farm.device("io1").profile.address
    with CIPDriver(f"{address}/bp/0") as driver:
        written = driver.generic_message(service=Services.set_attribute_single, class_code=4, instance=100,
                                         attribute=3, request_data=b"\x10\x00", connected=False,
                                         unconnected_send=True, route_path=True)
        assert written.error is None
        read = driver.generic_message(service=Services.get_attribute_single, class_code=4, instance=100,
                                      attribute=3, connected=False, unconnected_send=True, route_path=True)
        assert read.value == b"\x10\x00"
    assert farm.device("io1").outputs == b"\x10\x00"


def test_seed_session_cpppo(dsqc1030: str) -> None:
    direct = list(attribute_operations(["@4/100/3", "@4/100/3=(USINT)16,0", "@4/100/3"],
                                       route_path=False, send_path=""))
    with cpppo_client.connector(host=dsqc1030, timeout=5) as conn:
        results = [(status, value) for _, _, _, _, status, value in conn.synchronous(operations=direct)]
    assert results == [(0, [0, 0]), (0, True), (0, [16, 0])]
    # cpppo's default: Unconnected Send through the Connection Manager, route port 1 link 0
    routed = list(attribute_operations(["@4/100/3"]))
    with cpppo_client.connector(host=dsqc1030, timeout=5) as conn:
        results = [(status, value) for _, _, _, _, status, value in conn.synchronous(operations=routed)]
    assert results == [(0, [16, 0])]


def test_seed_session_ethernetip(dsqc1030: str) -> None:
    conn = ethernetip.EtherNetIP(dsqc1030).explicit_conn()
    try:
        assert conn.registerSession() == 0
        assert conn.session == 1
        assert conn.getAttrSingle(4, 100, 3) == [0, b"\x00\x00"]
        assert conn.setAttrSingle(4, 100, 3, b"\x10\x00") == [0, b""]
        assert conn.getAttrSingle(4, 100, 3) == [0, b"\x10\x00"]
        conn.unregisterSession()
        conn.sock.settimeout(10)
        assert conn.sock.recv(16) == b""  # closed by the device, no reply
    finally:
        conn.sock.close()


def test_pycomm3_identity(dsqc1030: str) -> None:
    with CIPDriver(dsqc1030) as driver:
        info = driver.list_identity(dsqc1030)
        assert info["vendor"] == "ABB Robotics" and info["product_name"] == "DSQC1030"
        assert info["ip_address"] == dsqc1030
        reply = driver.generic_message(service=Services.get_attributes_all, class_code=1, instance=1,
                                       connected=False, route_path=False)
        assert reply.error is None
        assert reply.value[:2] == (75).to_bytes(2, "little")
        assert reply.value.endswith(b"\x08DSQC1030")


def test_unregister_closes_socket_like_eeip(dsqc1030: str) -> None:
    """EEIP sends UnRegisterSession and closes without reading; the device must cope."""
    sock = socket.create_connection((dsqc1030, 44818), timeout=5)
    sock.sendall(encode_frame(Command.REGISTER_SESSION, b"\x01\x00\x00\x00"))
    assert sock.recv(255)[4:8] == b"\x01\x00\x00\x00"
    sock.sendall(encode_frame(Command.UNREGISTER_SESSION, session_handle=1))
    sock.close()
    with RawClient(dsqc1030) as c:  # the device is still serving; session numbers go on
        assert c.register() == 2
