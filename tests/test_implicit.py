"""Implicit I/O: class-1 connections opened the way a robot controller's scanner opens them
(Forward Open, UDP 2222), their supervision, every refusal, EEIP's layout, and class-3
connected explicit messaging."""

from __future__ import annotations

import socket
import struct
import time

import pytest
from pycomm3 import CIPDriver, Services

from enip_farm.cip.connection import ConnectionKind
from enip_farm.protocol.cip import decode_reply, encode_request
from enip_farm.protocol.commands import SocketAddress, decode_sockaddr, encode_sockaddr
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
from enip_farm.protocol.cpf import ItemType
from enip_farm.protocol.epath import ElectronicKey, encode_electronic_key, encode_request_path
from tests.helpers import RawClient, wait_for
from tests.scanners import scanner

pytestmark = pytest.mark.class1_paths  # both class-1 paths (tests/conftest.py)

P2P, MULTICAST, NULL = ConnectionType.POINT_TO_POINT, ConnectionType.MULTICAST, ConnectionType.NULL
ASSEMBLY_PATH = bytes.fromhex("20 04 24 01 2C 64 2C 65")  # config 1, O->T 100, T->O 101
_serials = iter(range(1, 1_000_000))


def forward_open(path: bytes = ASSEMBLY_PATH, o_t_size: int = 8, t_o_size: int = 4, rpi: int = 20_000,
                 t_o_rpi: int | None = None, multiplier: int = 0, t_o_type: ConnectionType = P2P,
                 o_t_type: ConnectionType = P2P, transport: int = 0x01, variable: bool = False,
                 triad: ConnectionTriad | None = None, key: ElectronicKey | None = None, large: bool = False,
                 vendor: int = 0x1234, originator_serial: int = 0xABCD) -> tuple[bytes, ConnectionTriad]:
    """A Forward Open request message (0x54 or 0x5B) to the Connection Manager, and its triad."""
    triad = triad or ConnectionTriad(next(_serials), vendor, originator_serial)
    request = ForwardOpenRequest(
        0x0A, 0x0E, 0, 0x7E570001, triad, multiplier, rpi,
        NetworkParameters(False, o_t_type, 2, variable, o_t_size), t_o_rpi or rpi,
        NetworkParameters(False, t_o_type, 2, variable, t_o_size), transport,
        (encode_electronic_key(key) if key else b"") + path, large)
    return encode_request(0x5B if large else 0x54, encode_request_path(6, 1), encode_forward_open(request)), triad


def forward_close(triad: ConnectionTriad, path: bytes = ASSEMBLY_PATH) -> bytes:
    return encode_request(0x4E, encode_request_path(6, 1),
                          encode_forward_close(ForwardCloseRequest(0x0A, 0x0E, triad, path)))


@pytest.fixture
def device(make_farm):
    farm = make_farm({"name": "io1", "model": "DSQC1030", "implicit": {"first_watchdog_s": 0}})
    return farm.device("io1")


@pytest.fixture
def client(device):
    with RawClient(device.profile.address) as c:
        c.register()
        yield c


# -- the ethernetip scanner ------------------------------------------------------------------------


def test_ethernetip_scanner_exchanges_io(device) -> None:
    with scanner(device.profile.address) as scan:
        assert scan.forward_open(10, 2) == 0
        (connection,) = device.connections.values()
        assert connection.kind is ConnectionKind.EXCLUSIVE_OWNER
        assert connection.t_o_address[1] == scan.enip.originator_udp_port  # the 0x8001 item honoured
        scan.outputs[4] = scan.outputs[9] = True  # DO5 and DO10
        scan.conn.produce()
        assert wait_for(lambda: device.outputs == b"\x10\x02")
        device.set_inputs(b"\x81\x02")
        assert wait_for(lambda: [i for i, bit in enumerate(scan.inputs) if bit] == [0, 7, 9])
        assert device.status == 0x0061  # owned, an I/O connection in run mode
        scan.conn.stopProduce()
        assert scan.forward_close() == 0
        assert not device.connections and device.status == 0x0030
        assert device.outputs == b"\x00\x00"  # idle state on close: all off
        assert [e.kind for e in device.events if e.kind.startswith("connection")] == [
            "connection opened", "connection closed"]


@pytest.mark.parametrize(("fault_state", "expected"), [("off", b"\x00\x00"), ("hold", b"\x10\x00")])
def test_silent_scanner_times_out_into_fault_state(make_farm, fault_state: str, expected: bytes) -> None:
    """The scanner feeds its connection, then goes silent: the farm closes it no sooner than the
    timeout after the last valid packet and no later than 2 RPI after that (the farm's own event
    timestamps), with the outputs at the fault state. The first watchdog (10 s by default) must not
    count once packets have arrived."""
    farm = make_farm({"name": "io1", "model": "DSQC1030", "implicit": {"fault_state": fault_state}})
    device = farm.device("io1")
    rpi = 0.050
    with scanner(device.profile.address) as scan:
        assert scan.forward_open(50, 0) == 0
        (connection,) = device.connections.values()
        assert connection.timeout == pytest.approx(rpi * 4)  # RPI x 2^(2 + 0)
        scan.outputs[4] = True
        scan.conn.produce()
        assert wait_for(lambda: device.outputs == b"\x10\x00" and connection.received >= 5)
        scan.conn.stopProduce()  # the scanner goes silent
        assert wait_for(lambda: device.events.of_kind("connection timed out"), timeout=5)
        (event,) = device.events.of_kind("connection timed out")
        silent_for = (event.monotonic_ns - connection.last_received) / 1e9
        assert connection.timeout <= silent_for <= connection.timeout + 2 * rpi
        assert device.outputs == expected
        assert not device.connections and device.status == 0x0030


# -- refusals with raw frames ----------------------------------------------------------------------


def _refusal(client: RawClient, message: bytes) -> int:
    reply = client.request(message)
    if reply.additional_status and reply.additional_status[0] in (0x0127, 0x0128):
        assert len(reply.additional_status) == 2, reply  # with the size the target expects
    assert reply.service == message[0] | 0x80
    assert reply.general_status == 0x01, reply
    assert len(reply.data) == 10  # connection serial, vendor, originator serial, remaining path size, reserved
    return reply.additional_status[0]


KEY = ElectronicKey(75, 7, 1030, 1, 1, False)


@pytest.mark.parametrize(
    ("kwargs", "extended"),
    [
        ({"rpi": 1_000}, 0x0111),
        ({"rpi": 20_000_000}, 0x0111),
        ({"o_t_size": 9}, 0x0127),
        ({"o_t_size": 6}, 0x0127),
        ({"t_o_size": 5}, 0x0128),
        ({"t_o_size": 3, "variable": True}, 0x0128),
        ({"o_t_size": 505, "t_o_size": 505, "variable": True}, 0x0127),  # EEIP's default sizes
        ({"path": bytes.fromhex("20 04 24 01 2C 65 2C 65")}, 0x012A),
        ({"path": bytes.fromhex("20 04 24 01 2C 64 2C 64")}, 0x012B),
        ({"path": bytes.fromhex("20 04 24 07 2C 64 2C 65")}, 0x0129),
        ({"path": bytes.fromhex("20 05 24 01 2C 64 2C 65")}, 0x0315),
        ({"path": bytes.fromhex("91 02 61 62 2C 64 2C 65")}, 0x0315),
        ({"o_t_type": NULL, "t_o_type": NULL}, 0x0132),
        ({"transport": 0x11}, 0x0103),  # change of state trigger
        ({"transport": 0x00}, 0x0103),  # class 0
        ({"key": KEY._replace(vendor_id=76)}, 0x0114),
        ({"key": KEY._replace(product_code=9)}, 0x0114),
        ({"key": KEY._replace(device_type=12)}, 0x0115),
        ({"key": KEY._replace(major_revision=2)}, 0x0116),
        ({"key": KEY._replace(minor_revision=2)}, 0x0116),
        ({"key": KEY._replace(minor_revision=2, compatibility=True)}, 0x0116),
        ({"o_t_type": MULTICAST}, 0x0108),
        ({"path": bytes.fromhex("20 04 24 01 2C C7 2C 65"), "o_t_size": 2, "t_o_type": MULTICAST}, 0x0119),
    ],
)
def test_forward_open_refusals(client: RawClient, device, kwargs: dict, extended: int) -> None:
    message, _ = forward_open(**kwargs)
    assert _refusal(client, message) == extended
    assert not device.connections
    assert client.get(4, 100, 3).general_status == 0  # the connection stays usable


@pytest.mark.parametrize("key", [KEY, ElectronicKey(0, 0, 0, 0, 0, False), KEY._replace(minor_revision=0),
                                 KEY._replace(compatibility=True), ElectronicKey(75, 0, 1030, 1, 0, True)])
def test_matching_keys_are_accepted(client: RawClient, device, key: ElectronicKey) -> None:
    message, triad = forward_open(key=key)
    assert client.request(message).general_status == 0
    assert client.request(forward_close(triad)).general_status == 0


def test_duplicate_ownership_limits_and_close(make_farm) -> None:
    farm = make_farm({"name": "io1", "model": "DSQC1030",
                      "implicit": {"max_class1_connections": 2, "first_watchdog_s": 30}})
    device = farm.device("io1")
    with RawClient(device.profile.address) as c:
        c.register()
        owner, triad = forward_open()
        reply = c.request(owner)
        assert reply.general_status == 0
        opened = decode_forward_open_reply(reply.data)
        assert opened.triad == triad and opened.o_t_api == 20_000
        assert _refusal(c, forward_open(triad=triad)[0]) == 0x0100  # same triad: in use
        assert _refusal(c, forward_open()[0]) == 0x0106  # another exclusive owner
        heartbeat = bytes.fromhex("20 04 24 01 2C C6 2C 65")  # input only, 198 (unverified default)
        assert c.request(forward_open(path=heartbeat, o_t_size=2)[0]).general_status == 0
        assert _refusal(c, forward_open(path=heartbeat, o_t_size=6)[0]) == 0x0113  # out of connections
        assert _refusal(c, forward_close(ConnectionTriad(999, 1, 2))) == 0x0107
        assert c.request(forward_close(triad)).general_status == 0
        assert _refusal(c, forward_close(triad)) == 0x0107  # already closed


def test_forward_open_through_unconnected_send(client: RawClient, device) -> None:
    from enip_farm.protocol.cip import encode_unconnected_send
    from enip_farm.protocol.epath import encode_port

    message, triad = forward_open()
    routed = encode_request(0x52, encode_request_path(6, 1), encode_unconnected_send(message, encode_port(1, 0)))
    reply = client.request(routed)
    assert reply.service == 0xD4 and reply.general_status == 0
    assert device.find_connection(triad) is not None
    closed = client.request(encode_request(0x52, encode_request_path(6, 1),
                                           encode_unconnected_send(forward_close(triad), encode_port(1, 0))))
    assert closed.service == 0xCE and closed.general_status == 0 and not device.connections


def test_large_forward_open(client: RawClient, device) -> None:
    message, triad = forward_open(large=True, o_t_size=8, t_o_size=4)
    reply = client.request(message)
    assert reply.service == 0xDB and reply.general_status == 0
    assert client.request(forward_close(triad)).general_status == 0


def test_owned_output_assembly_refuses_explicit_writes(make_farm) -> None:
    farm = make_farm({"name": "strict", "model": "DSQC1030"},
                     {"name": "lenient", "model": "DSQC1030", "implicit": {"explicit_output_writes_while_owned": True}})
    for name, status in (("strict", 0x10), ("lenient", 0x00)):
        with RawClient(farm.device(name).profile.address) as c:
            c.register()
            message, triad = forward_open()
            assert c.request(message).general_status == 0
            assert c.set(4, 100, 3, b"\x01\x00").general_status == status
            assert c.get(4, 100, 3).general_status == 0  # reading stays allowed
            assert c.request(forward_close(triad)).general_status == 0
            assert c.set(4, 100, 3, b"\x01\x00").general_status == 0  # free again


def test_run_idle_header_and_stale_packets(client: RawClient, device) -> None:
    message, triad = forward_open()
    opened = decode_forward_open_reply(client.request(message).data)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as udp:
        udp.bind(("127.0.0.1", 0))
        target = (device.profile.address, 2222)
        udp.sendto(encode_io_packet(opened.o_t_connection_id, 10, 1, b"\x01\x00\x00\x00\x33\x00"), target)
        assert wait_for(lambda: device.outputs == b"\x33\x00")
        assert device.status == 0x0061
        udp.sendto(encode_io_packet(opened.o_t_connection_id, 9, 0, b"\x01\x00\x00\x00\x44\x00"), target)  # stale
        udp.sendto(encode_io_packet(opened.o_t_connection_id, 11, 2, b"\x00\x00\x00\x00\x55\x00"), target)  # idle
        assert wait_for(lambda: device.status == 0x0071)  # owned, all idle
        assert device.outputs == b"\x00\x00"  # idle state: all off
        udp.sendto(encode_io_packet(opened.o_t_connection_id, 12, 3, b"\x01\x00\x00\x00\x66\x00"), target)
        assert wait_for(lambda: device.outputs == b"\x66\x00")
    assert client.request(forward_close(triad)).general_status == 0


# -- EEIP's layout (../shared/reference/eeip-wire-notes.md) ----------------------------------------


def _eeip_forward_open(client: RawClient, connection_serial: int, o_t_point: int, o_t_size: int):
    """As EEIP sends it: priority 0x03, ticks 0xFA, multiplier 3, vendor 0xFF / serial 0xFFFFFFFF,
    owner-redundant and variable flags, T->O multicast, and a third CPF item 0x8001 (port 2222)."""
    request = ForwardOpenRequest(
        0x03, 0xFA, 0x11110000 + connection_serial, 0x22220000 + connection_serial,
        ConnectionTriad(connection_serial, 0x00FF, 0xFFFFFFFF), 3, 20_000,
        NetworkParameters(True, P2P, 0, True, o_t_size), 20_000, NetworkParameters(True, MULTICAST, 0, True, 2 + 2),
        0x01, bytes.fromhex(f"20 04 24 01 2C {o_t_point:02X} 2C 65"))
    sockaddr = encode_sockaddr(SocketAddress("0.0.0.0", 2222))
    return client.request_items(encode_request(0x54, bytes.fromhex("20 06 24 01"), encode_forward_open(request)),
                                [(ItemType.SOCKADDR_T_O, sockaddr)])


def test_eeip_layout_multicast_and_shared_originator(client: RawClient, device) -> None:
    reply, items = _eeip_forward_open(client, 0x1001, 0x64, 2 + 4 + 2)
    assert reply.general_status == 0, reply
    opened = decode_forward_open_reply(reply.data)
    (item,) = items  # the reply tells the multicast group, as EEIP requires
    assert item.type_id == ItemType.SOCKADDR_T_O
    group = decode_sockaddr(item.data)
    assert group.port == 2222 and group.host == device.profile.multicast_group
    assert group.host.startswith("239.192.")

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as receiver:
        receiver.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        receiver.bind(("0.0.0.0", 2222))  # as EEIP binds, beside the farm's device sockets
        receiver.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP,
                            socket.inet_aton(group.host) + socket.inet_aton("127.0.0.1"))
        receiver.settimeout(2)
        device.set_inputs(b"\x5a\xa5")
        deadline = time.monotonic() + 3
        packet = None
        while time.monotonic() < deadline:
            data, source = receiver.recvfrom(2048)
            candidate = decode_io_packet(data)
            if candidate and candidate.connection_id == opened.t_o_connection_id and candidate.data == b"\x5a\xa5":
                packet = candidate
                break
        assert packet is not None and source == (device.profile.address, 2222)

    # A second EEIP scanner: same originator vendor and serial, another connection serial.
    second, _ = _eeip_forward_open(client, 0x1002, 0x64, 8)
    assert second.general_status == 1 and second.additional_status == (0x0106,)  # one exclusive owner
    listener, items = _eeip_forward_open(client, 0x1003, 0xC6, 2)  # input only, on the same multicast
    assert listener.general_status == 0
    assert decode_forward_open_reply(listener.data).t_o_connection_id == opened.t_o_connection_id
    again, _ = _eeip_forward_open(client, 0x1001, 0x64, 8)
    assert again.additional_status == (0x0100,)  # the first scanner's triad is in use
    assert len(device.connections) == 2


# -- class-3 connected explicit messaging ----------------------------------------------------------


def test_pycomm3_connected_messaging(device) -> None:
    with CIPDriver(device.profile.address) as driver:
        written = driver.generic_message(service=Services.set_attribute_single, class_code=4, instance=100,
                                         attribute=3, request_data=b"\x22\x00", connected=True)
        assert written.error is None, written.error
        read = driver.generic_message(service=Services.get_attribute_single, class_code=1, instance=1,
                                      attribute=7, connected=True)
        assert read.error is None and read.value == b"\x08DSQC1030"
        (connection,) = device.connections.values()
        assert connection.kind is ConnectionKind.EXPLICIT and connection.received == 2
    assert device.outputs == b"\x22\x00"
    assert wait_for(lambda: not device.connections)  # Forward Close (or the TCP close) ended it


def test_class3_duplicate_sequence_is_not_executed_twice(client: RawClient, device) -> None:
    from enip_farm.protocol.commands import decode_send_data, encode_connected_payload
    from enip_farm.protocol.encapsulation import Command, encode_frame

    message, _ = forward_open(path=bytes.fromhex("20 02 24 01"), transport=0xA3, o_t_size=500, t_o_size=500,
                              variable=True, rpi=100_000)
    opened = decode_forward_open_reply(client.request(message).data)
    set_outputs = encode_request(0x10, encode_request_path(4, 100, 3), b"\x01\x00")
    first = client.exchange(encode_frame(Command.SEND_UNIT_DATA,
                                         encode_connected_payload(opened.o_t_connection_id, 7, set_outputs), 1))
    device.assemblies["output"].data[:] = b"\x00\x00"  # changed behind the client's back
    again = client.exchange(encode_frame(Command.SEND_UNIT_DATA,
                                         encode_connected_payload(opened.o_t_connection_id, 7, set_outputs), 1))
    assert first.data == again.data  # the same reply, and the write was not repeated
    assert device.outputs == b"\x00\x00"
    items = decode_send_data(again.data).items
    assert struct.unpack("<I", items[0].data)[0] == opened.t_o_connection_id
    assert decode_reply(items[1].data[2:]).service == 0x90


# -- defects found on 913aed5, each pinned ----------------------------------------------------------


def test_size_refusals_carry_the_expected_size(client: RawClient, device) -> None:
    """0x0127/0x0128 come with a second additional status word: the size the target expects."""
    assert client.request(forward_open(o_t_size=9)[0]).additional_status == (0x0127, 8)
    assert client.request(forward_open(t_o_size=5)[0]).additional_status == (0x0128, 4)
    eeip_defaults = forward_open(o_t_size=505, t_o_size=505, variable=True)[0]
    assert client.request(eeip_defaults).additional_status == (0x0127, 8)
    assert not device.connections


def test_reply_items_never_leak_into_the_next_reply(client: RawClient, device) -> None:
    """A multicast Forward Open sent over a class-3 connection (SendUnitData) gets its 0x8001 item;
    the next, unrelated SendRRData reply carries none."""
    from enip_farm.protocol.commands import decode_send_data, encode_connected_payload
    from enip_farm.protocol.encapsulation import Command, encode_frame

    message, _ = forward_open(path=bytes.fromhex("20 02 24 01"), transport=0xA3, o_t_size=500, t_o_size=500,
                              variable=True, rpi=100_000)
    explicit = decode_forward_open_reply(client.request(message).data)
    multicast, _ = forward_open(t_o_type=MULTICAST)
    reply = client.exchange(encode_frame(Command.SEND_UNIT_DATA,
                                         encode_connected_payload(explicit.o_t_connection_id, 1, multicast), 1))
    items = decode_send_data(reply.data).items
    assert [item.type_id for item in items] == [ItemType.CONNECTED_ADDRESS, ItemType.CONNECTED_DATA,
                                                ItemType.SOCKADDR_T_O]
    assert decode_reply(items[1].data[2:]).general_status == 0
    assert decode_sockaddr(items[2].data).host == device.profile.multicast_group
    get = client.exchange(encode_frame(Command.SEND_RR_DATA, bytes(6) + _items_for(encode_request(
        0x0E, encode_request_path(1, 1, 1))), 1))
    assert [item.type_id for item in decode_send_data(get.data).items] == [ItemType.NULL_ADDRESS,
                                                                          ItemType.UNCONNECTED_DATA]


def _items_for(message: bytes) -> bytes:
    from enip_farm.protocol.cpf import encode_items

    return encode_items([(ItemType.NULL_ADDRESS, b""), (ItemType.UNCONNECTED_DATA, message)])


def test_images_never_tear(make_farm) -> None:
    """The Python API's set() of 32 inputs races T->O production (RPI 2 ms) and explicit Gets: every
    image anyone sees is a whole set(), never half of one."""
    import threading

    farm = make_farm({"name": "io1", "model": "DSQC1030", "addons": ["DSQC1031"],
                      "implicit": {"first_watchdog_s": 30}})
    handle, device = farm["io1"], farm.device("io1")
    whole = {b"\x00" * 4, b"\xff" * 4}
    stop = threading.Event()

    def toggle() -> None:
        for n in range(200_000):
            if stop.is_set():
                return
            handle.set({"DI1-32": [n & 1] * 32})

    with RawClient(device.profile.address) as c, socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as udp:
        c.register()
        udp.bind(("127.0.0.1", 0))
        udp.setblocking(False)
        message, triad = forward_open(o_t_size=2 + 4 + 4, t_o_size=2 + 4, rpi=2_000)
        reply, _ = c.request_items(message, [(ItemType.SOCKADDR_T_O,
                                              encode_sockaddr(SocketAddress("0.0.0.0", udp.getsockname()[1])))])
        assert reply.general_status == 0, reply
        writer = threading.Thread(target=toggle)
        writer.start()
        seen_t_o, seen_get = [], []
        try:
            deadline = time.monotonic() + 2.0
            while time.monotonic() < deadline and len(seen_get) < 3_000:
                seen_get.append(c.get(4, 101, 3).data)
                while True:
                    try:
                        packet = decode_io_packet(udp.recv(2048))
                    except BlockingIOError:
                        break
                    seen_t_o.append(packet.data)
        finally:
            stop.set()
            writer.join(10)
        assert c.request(forward_close(triad)).general_status == 0
    assert len(seen_t_o) >= 50 and len(seen_get) >= 50
    assert set(seen_t_o) <= whole and set(seen_get) <= whole
    assert len(set(seen_get) | set(seen_t_o)) == 2  # both states were seen: the race was real


# -- one device's bug does not stop the others' cyclic I/O --------------------------------------------


def test_an_exception_in_one_device_leaves_the_others_cyclic_io_running(make_farm, monkeypatch, caplog) -> None:
    farm = make_farm(*({"name": name, "model": "DSQC1030", "implicit": {"first_watchdog_s": 30}}
                       for name in ("io1", "io2")))
    broken, healthy = farm.device("io1"), farm.device("io2")

    def receive_io(*_: object) -> bool:
        raise RuntimeError("a bug in io1's O->T path")

    monkeypatch.setattr(broken, "receive_io", receive_io)
    opened = {}
    for device in (broken, healthy):
        with RawClient(device.profile.address) as c:
            c.register()
            opened[device.name] = decode_forward_open_reply(c.request(forward_open(multiplier=7)[0]).data)  # 10 s
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as udp:
        udp.bind(("127.0.0.1", 0))
        udp.sendto(encode_io_packet(opened["io1"].o_t_connection_id, 1, 1, b"\x01\x00\x00\x00\x33\x00"),
                   (broken.profile.address, 2222))
        assert wait_for(lambda: broken.counters["io_errors"] == 1)
        produced = (broken.counters["t_o_packets"], healthy.counters["t_o_packets"])
        udp.sendto(encode_io_packet(opened["io2"].o_t_connection_id, 1, 1, b"\x01\x00\x00\x00\x44\x00"),
                   (healthy.profile.address, 2222))
        assert wait_for(lambda: healthy.outputs == b"\x44\x00")  # the thread still takes O->T
        # and both devices still produce T->O on their schedules (RPI 20 ms)
        assert wait_for(lambda: broken.counters["t_o_packets"] >= produced[0] + 5
                        and healthy.counters["t_o_packets"] >= produced[1] + 5)
    assert broken.outputs == b"\x00\x00" and broken.counters["io_errors"] == 1
    assert healthy.counters["io_errors"] == 0
    (record,) = [r for r in caplog.records if r.name == "enip_farm.server.implicit" and r.levelname == "ERROR"]
    assert record.getMessage() == "io1: cyclic I/O error taking an O->T datagram"
    assert record.exc_info is not None and "a bug in io1's O->T path" in str(record.exc_info[1])
