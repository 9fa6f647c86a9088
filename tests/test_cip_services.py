"""The services of a complete CIP device, each checked over the network by two independent real
clients, pycomm3 (`generic_message`) and cpppo (its client's Service Code requests): Get/Set
_Attribute_List, Get_and_Clear on the Ethernet Link counters (which count the device's real
traffic), Identity Reset, and a model that routes nothing. The bytes and statuses of each are held
to the letter in tests/test_cip_services_unit.py.

cpppo's client parses every reply by one global dialect (Logix by default, where 0x4C is Read Tag;
its Read Tag parser is registered on the shared Object parser as soon as cpppo's logix module is
imported): these tests give it a dialect of their own whose only reply parser is cpppo's generic
Service Code reply, so every reply's data comes back as it is."""

from __future__ import annotations

import contextlib
import socket
import struct
import threading
import time
from pathlib import Path

import pytest
from cpppo.automata import dfa_post, state
from cpppo.server.enip import client as cpppo_client
from cpppo.server.enip import device as cpppo_device
from pycomm3 import CIPDriver, CommError

from enip_farm.protocol.cip import encode_multiple_service, encode_request
from enip_farm.protocol.commands import encode_send_rr_data
from enip_farm.protocol.encapsulation import HEADER_SIZE, Command, decode_frame, encode_frame
from enip_farm.protocol.epath import encode_request_path
from tests.helpers import ENIP_PORT, RawClient, wait_for
from tests.scanners import Scanner, start_scanner
from tests.test_cip_services_unit import non_routing_profile

RESET_TIME_S = 2.0  # long enough to look at the silent device on a busy machine


class ServiceCodeReplies(cpppo_device.Object):
    """A cpppo dialect with its own parser, which reads any reply as a generic Service Code reply."""

    service: dict = {}
    transit: dict = {}
    lock = threading.Lock()
    parser = dfa_post(service, initial=state("Any svc"), terminal=True)


ServiceCodeReplies.register_service_parser(number=True, name=cpppo_device.Object.SV_COD_NAM,
                                           short=cpppo_device.Object.SV_COD_CTX,
                                           machine=vars(cpppo_device)["__service_code_reply"]())


@pytest.fixture
def cpppo_plain(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(cpppo_device, "dialect", ServiceCodeReplies)


def generic(driver: CIPDriver, service: int, class_code: int, instance: int, attribute: int | bytes = b"",
            data: bytes = b"", connected: bool = False):  # noqa: ANN201
    return driver.generic_message(service=service, class_code=class_code, instance=instance, attribute=attribute,
                                  request_data=data, connected=connected, route_path=False)


def cpppo_op(code: int, path: str, data: bytes | None = None, **kwargs: object) -> dict:
    op = {"method": "service_code", "code": code, "path": path, "route_path": False, "send_path": "",
          "data_size": 64, **kwargs}
    if data is not None:
        op["data"] = list(data)
    return op


def cpppo_replies(address: str, *ops: dict) -> list[tuple[int, int, bytes]]:
    """(reply service, general status, reply data) of each request, over one cpppo connection."""
    out = []
    with cpppo_client.connector(host=address, timeout=5) as conn:
        for _, _, _, reply, _, _ in conn.synchronous(operations=list(ops)):
            payload = reply.get("service_code")
            data = payload.get("data", []) if isinstance(payload, dict) else []
            out.append((reply.service, reply.status, bytes(data)))
    return out


def answers(address: str) -> bool:
    try:
        socket.create_connection((address, ENIP_PORT), timeout=1).close()
    except OSError:
        return False
    return True


def list_identity_answered(address: str, timeout: float = 0.3) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.settimeout(timeout)
        sock.sendto(encode_frame(Command.LIST_IDENTITY), (address, ENIP_PORT))
        try:
            return bool(sock.recv(1024))
        except TimeoutError:
            return False


# -- Get_Attribute_List, Set_Attribute_List ------------------------------------------------------------


GET_IDENTITY = b"\x02\x00\x01\x00\x05\x00"  # vendor, status
GET_WITH_UNKNOWN = b"\x02\x00\x01\x00\x63\x00"  # vendor, attribute 99
IDENTITY_LIST = bytes.fromhex("0200" "0100 0000 4b00" "0500 0000 3000")
UNKNOWN_LIST = bytes.fromhex("0200" "0100 0000 4b00" "6300 1400")


def test_get_attribute_list_pycomm3(dsqc1030: str) -> None:
    with CIPDriver(dsqc1030) as driver:
        good = generic(driver, 0x03, 1, 1, data=GET_IDENTITY)
        bad = generic(driver, 0x03, 1, 1, data=GET_WITH_UNKNOWN)
        empty = generic(driver, 0x03, 1, 1, data=b"\x00\x00")
    assert good.error is None and good.value == IDENTITY_LIST
    assert bad.error == "Attribute list error" and bad.value == UNKNOWN_LIST
    assert empty.error == "Attribute list error"


def test_get_attribute_list_cpppo(dsqc1030: str, cpppo_plain: None) -> None:
    assert cpppo_replies(dsqc1030, cpppo_op(0x03, "@1/1", GET_IDENTITY), cpppo_op(0x03, "@1/1", GET_WITH_UNKNOWN)) == [
        (0x83, 0x00, IDENTITY_LIST), (0x83, 0x0A, UNKNOWN_LIST)]


SET_TCPIP = b"\x02\x00" + b"\x08\x00\x05" + b"\x0d\x00\x1e\x00"  # TTL 5, inactivity timeout 30 s
SET_READ_ONLY = b"\x02\x00" + b"\x01\x00\x00\x00\x00\x00" + b"\x0d\x00\x3c\x00"  # status (read-only), timeout 60 s
SET_TCPIP_REPLY = bytes.fromhex("0200" "0800 0000" "0d00 0000")
SET_READ_ONLY_REPLY = bytes.fromhex("0200" "0100 0e00" "0d00 0000")


def test_set_attribute_list_pycomm3(make_farm) -> None:
    device = make_farm({"name": "io1", "model": "DSQC1030"}).device("io1")
    with CIPDriver(device.profile.address) as driver:
        written = generic(driver, 0x04, 0xF5, 1, data=SET_TCPIP)
        assert written.error is None and written.value == SET_TCPIP_REPLY
        assert generic(driver, 0x0E, 0xF5, 1, 8).value == b"\x05"
        assert device.encapsulation_inactivity_timeout_s == 30
        partly = generic(driver, 0x04, 0xF5, 1, data=SET_READ_ONLY)
        assert partly.error == "Attribute list error" and partly.value == SET_READ_ONLY_REPLY
    assert device.encapsulation_inactivity_timeout_s == 60


def test_set_attribute_list_cpppo(make_farm, cpppo_plain: None) -> None:
    device = make_farm({"name": "io1", "model": "DSQC1030"}).device("io1")
    replies = cpppo_replies(device.profile.address, cpppo_op(0x04, "@0xF5/1", SET_TCPIP),
                            cpppo_op(0x04, "@0xF5/1", SET_READ_ONLY),
                            cpppo_op(0x03, "@0xF5/1", b"\x02\x00\x0d\x00\x01\x00"))
    assert replies == [(0x84, 0x00, SET_TCPIP_REPLY), (0x84, 0x0A, SET_READ_ONLY_REPLY),
                       (0x83, 0x00, bytes.fromhex("0200" "0d00 0000 3c00" "0100 0000 01000000"))]
    assert device.encapsulation_inactivity_timeout_s == 60


# -- Ethernet Link counters and Get_and_Clear -------------------------------------------------------------


COUNTERS = "<11I"
GET_COUNTERS = encode_request(0x0E, encode_request_path(0xF6, 1, 4))
#: An unconnected request's frame on the wire: header, interface handle and timeout, item count,
#: null address item, unconnected data item header, then the CIP request.
SEND_RR_DATA_OVERHEAD = HEADER_SIZE + 6 + 2 + 4 + 4


def test_get_and_clear_pycomm3(dsqc1030: str) -> None:
    with CIPDriver(dsqc1030) as driver:
        cleared = generic(driver, 0x4C, 0xF6, 1, 4)
        after = generic(driver, 0x0E, 0xF6, 1, 4)
        elsewhere = generic(driver, 0x4C, 0xF6, 1, 1)
    assert cleared.error is None and len(cleared.value) == 44
    before = struct.unpack(COUNTERS, cleared.value)
    # in, RegisterSession and this request; out, RegisterSession's reply (this reply is counted after it is read)
    assert before == (28 + SEND_RR_DATA_OVERHEAD + len(GET_COUNTERS), 2, 0, 0, 0, 0, 28, 1, 0, 0, 0)
    # Since the clear: in, the one Get request; out, the Get_and_Clear reply (4 + 44 bytes of CIP)
    assert struct.unpack(COUNTERS, after.value) == (SEND_RR_DATA_OVERHEAD + len(GET_COUNTERS), 1, 0, 0, 0, 0,
                                                    SEND_RR_DATA_OVERHEAD + 4 + 44, 1, 0, 0, 0)
    assert elsewhere.error == "Unknown Error (2e)" and elsewhere.value == b""  # 0x2E: not for that attribute


def test_get_and_clear_cpppo(dsqc1030: str, cpppo_plain: None) -> None:
    (cleared, after, media, elsewhere) = cpppo_replies(
        dsqc1030, cpppo_op(0x4C, "@0xF6/1/4"), cpppo_op(0x0E, "@0xF6/1/4"), cpppo_op(0x4C, "@0xF6/1/5"),
        cpppo_op(0x4C, "@0xF6/1/1"))
    assert cleared[:2] == (0xCC, 0) and struct.unpack(COUNTERS, cleared[2]) == (
        28 + SEND_RR_DATA_OVERHEAD + len(GET_COUNTERS), 2, 0, 0, 0, 0, 28, 1, 0, 0, 0)
    assert after[:2] == (0x8E, 0)
    counters = struct.unpack(COUNTERS, after[2])
    assert counters[0] == SEND_RR_DATA_OVERHEAD + len(GET_COUNTERS) and counters[1] == 1
    assert counters[6] == SEND_RR_DATA_OVERHEAD + 4 + 44 and counters[7] == 1
    assert media == (0xCC, 0, bytes(48))
    assert elsewhere == (0xCC, 0x2E, b"")


def test_counters_count_tcp_and_udp_traffic(make_farm) -> None:
    """After a clear, exactly what went through the device's sockets: a ListIdentity on UDP 44818
    and its reply, three datagrams on UDP 2222 that no connection takes (In Discards), the one TCP
    request that reads the counters, and the clear's own reply."""
    device = make_farm({"name": "io1", "model": "DSQC1030"}).device("io1")
    address = device.profile.address
    with RawClient(address) as client:
        client.register()
        cleared = client.get(0xF6, 1, 4, service=0x4C)
        assert cleared.general_status == 0
        list_identity = encode_frame(Command.LIST_IDENTITY)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            sock.settimeout(5)
            sock.sendto(list_identity, (address, ENIP_PORT))
            identity_reply = sock.recv(1024)
            for size in (10, 20, 30):
                sock.sendto(bytes(size), (address, 2222))
        assert wait_for(lambda: device.link.counters()[3] == 3)
        after = client.get(0xF6, 1, 4)
    get_frame = SEND_RR_DATA_OVERHEAD + len(GET_COUNTERS)
    clear_reply = SEND_RR_DATA_OVERHEAD + 4 + 44
    assert struct.unpack(COUNTERS, after.data) == (
        len(list_identity) + 60 + get_frame, 5, 0, 3, 0, 0, len(identity_reply) + clear_reply, 2, 0, 0, 0)


# -- Identity Reset -------------------------------------------------------------------------------------


def producing(address: str) -> Scanner:
    """The `ethernetip` scanner with a class-1 connection producing outputs (DO5 on)."""
    scan = start_scanner(address)
    assert scan.forward_open(20, 2) == 0
    scan.outputs[4] = True
    scan.conn.produce()
    return scan


def test_reset_pycomm3_drops_everything_and_answers_again_after_the_reset_time(make_farm) -> None:
    farm = make_farm({"name": "io1", "model": "DSQC1030", "reset_time_s": RESET_TIME_S,
                      "implicit": {"first_watchdog_s": 0}})
    device = farm.device("io1")
    address = device.profile.address
    scan = producing(address)
    connected = CIPDriver(address)
    resetter = CIPDriver(address)
    try:
        connected.open()
        resetter.open()
        assert generic(connected, 0x0E, 1, 1, 1, connected=True).value == b"\x4b\x00"  # a class-3 connection
        assert wait_for(lambda: device.outputs == b"\x10\x00" and len(device.connections) == 2)
        device.set_inputs(b"\x01\x00")
        sent = time.monotonic()
        reply = generic(resetter, 0x05, 1, 1, data=b"\x00")
        assert reply.error is None
        # the device is silent: sessions ended, no TCP listener, UDP unanswered
        with pytest.raises(CommError, match="^failed to receive reply$"):
            generic(resetter, 0x0E, 1, 1, 1)
        with pytest.raises(ConnectionRefusedError, match="Connection refused"):
            socket.create_connection((address, ENIP_PORT), timeout=1)
        assert not list_identity_answered(address)
        # still in the reset window (only the farm ends it, at its deadline or later): the silence
        # above was checked inside the window by construction
        assert device.resetting and device.identity_state == 1
        assert not device.connections and device.outputs == b"\x00\x00" and device.inputs == b"\x01\x00"
        closed = [e.text for e in device.events.of_kind("connection closed")]
        assert len(closed) == 2 and all("identity reset (type 0)" in text for text in closed)
        assert wait_for(lambda: answers(address), timeout=RESET_TIME_S + 10)
        answering = time.monotonic()
        assert sent + RESET_TIME_S <= answering <= sent + RESET_TIME_S + 3.0
        with pytest.raises(CommError, match="^failed to receive reply$"):  # the class-3 session ended with the reset
            generic(connected, 0x0E, 1, 1, 1, connected=True)
    finally:
        scan.stop()
        for driver in (connected, resetter):
            with contextlib.suppress(CommError):  # its Forward Close or UnRegisterSession has nowhere to go
                driver.close()
    assert [e.kind for e in device.events if e.kind.startswith("reset")] == ["reset", "reset done"]
    with CIPDriver(address) as again:
        assert generic(again, 0x0E, 1, 1, 8).value == b"\x03"  # operational
        assert again.list_identity(address)["state"] == 3
        assert generic(again, 0x0E, 4, 100, 3).value == b"\x00\x00"  # outputs at their power-up state


def test_reset_type_1_cpppo_restores_the_configuration(make_farm, cpppo_plain: None) -> None:
    device = make_farm({"name": "io1", "model": "DSQC1030", "reset_time_s": 0.2}).device("io1")
    address = device.profile.address
    assert cpppo_replies(address, cpppo_op(0x04, "@0xF5/1", SET_TCPIP))[0][1] == 0
    with cpppo_client.connector(host=address, timeout=5) as conn:
        results = [(reply.service, reply.status) for _, _, _, reply, _, _ in conn.synchronous(
            operations=[cpppo_op(0x05, "@1/1", b"\x01"), cpppo_op(0x0E, "@1/1/1")])]
    assert results == [(0x85, 0)]  # the Get after it got no reply: the connection ended
    assert device.events.of_kind("reset")[0].text == "type 1 (out-of-box configuration): not answering for 0.2 s"
    assert wait_for(lambda: answers(address))
    assert cpppo_replies(address, cpppo_op(0x03, "@0xF5/1", b"\x01\x00\x0d\x00")) == [
        (0x83, 0, bytes.fromhex("0100" "0d00 0000 7800"))]  # 120 s again
    assert cpppo_replies(address, cpppo_op(0x0E, "@0xF5/1/8")) == [(0x8E, 0, b"\x01")]


def test_reset_refusals_both_clients(make_farm, cpppo_plain: None) -> None:
    device = make_farm({"name": "io1", "model": "DSQC1030"}).device("io1")
    address = device.profile.address
    with CIPDriver(address) as driver:
        assert generic(driver, 0x05, 1, 1, data=b"\x03").error == "Unknown Error (20)"  # pycomm3 names no 0x20
        assert generic(driver, 0x05, 1, 1, data=b"\x00\x00").error == "Too much data"
        assert generic(driver, 0x0E, 1, 1, 1).value == b"\x4b\x00"  # still answering
    assert cpppo_replies(address, cpppo_op(0x05, "@1/1", b"\x07"), cpppo_op(0x05, "@1/1", b"\x00\x00"),
                         cpppo_op(0x0E, "@1/1/8")) == [(0x85, 0x20, b""), (0x85, 0x15, b""), (0x8E, 0, b"\x03")]
    assert device.restarts == 0


def test_a_second_connection_of_the_device_ends_with_the_reset(make_farm) -> None:
    device = make_farm({"name": "io1", "model": "DSQC1030", "reset_time_s": 0.2}).device("io1")
    address = device.profile.address
    with RawClient(address) as bystander, RawClient(address) as resetter:
        bystander.register()
        resetter.register()
        reset = resetter.get(1, 1, service=0x05)
        assert (reset.service, reset.general_status) == (0x85, 0)
        assert resetter.is_closed() and bystander.is_closed()
    assert wait_for(lambda: answers(address))


# -- routing as profile data ------------------------------------------------------------------------------


def test_a_non_routing_model_answers_0x08_to_both_clients(make_farm, tmp_path: Path, cpppo_plain: None) -> None:
    device = make_farm({"name": "io1", "model": str(non_routing_profile(tmp_path))}).device("io1")
    address = device.profile.address
    inner = encode_request(0x0E, encode_request_path(1, 1, 1))
    with CIPDriver(f"{address}/bp/0") as driver:
        routed = driver.generic_message(service=0x0E, class_code=1, instance=1, attribute=1, connected=False,
                                        unconnected_send=True, route_path=True)
        packet = generic(driver, 0x0A, 2, 1, data=encode_multiple_service([inner]))
        direct = generic(driver, 0x0E, 1, 1, 1)
    assert routed.error == "Service not supported" and packet.error == "Service not supported"
    assert direct.value == b"\x01\x00"
    # cpppo raises the status of a failed Multiple Service Packet (0x8A) or Unconnected Send (0xD2) reply
    with pytest.raises(cpppo_client.MSVCStatusError, match="^Response EtherNet/IP Multiple Service status: 0x08$"):
        cpppo_replies(address, cpppo_op(0x0A, "@2/1", encode_multiple_service([inner])))
    routed_op = {"method": "service_code", "code": 0x0E, "path": "@1/1/1", "data_size": 2}  # through Unconnected Send
    with pytest.raises(cpppo_client.SENDStatusError, match="^Response EtherNet/IP Un/Connected Send status: 0x08$"):
        cpppo_replies(address, routed_op)
    assert cpppo_replies(address, cpppo_op(0x0E, "@1/1/1")) == [(0x8E, 0, b"\x01\x00")]


def test_raw_frames_after_a_reset_in_the_same_write_are_not_answered(make_farm) -> None:
    """Reset and a Get in one TCP write: the Reset is answered, the Get is not, the connection ends."""
    device = make_farm({"name": "io1", "model": "DSQC1030", "reset_time_s": 0.2}).device("io1")
    with RawClient(device.profile.address) as client:
        handle = client.register()
        client.send(encode_send_rr_data(encode_request(0x05, encode_request_path(1, 1)), handle)
                    + encode_send_rr_data(encode_request(0x0E, encode_request_path(1, 1, 1)), handle))
        data = b""
        client.sock.settimeout(5)
        while chunk := client.sock.recv(4096):
            data += chunk
    frame = decode_frame(data)
    assert HEADER_SIZE + len(frame.data) == len(data)  # one reply, then the close
    assert frame.data.endswith(b"\x85\x00\x00\x00")
