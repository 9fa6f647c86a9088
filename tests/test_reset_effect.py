"""Identity Reset as an effect (issue 23, item 2): the Identity object's Reset service returns
`ResetRequested(type)` beside its reply, the message router queues it, the device performs it once
the reply is built and records a `Reset` event (device/events.py), and the farm acts
on that type, never on an event's text. And the device's class-1 sends leave after its lock."""

from __future__ import annotations

import socket

import pytest

from enip_farm.cip.identity import IdentityObject, ResetRequested
from enip_farm.cip.message_router import MessageRouter
from enip_farm.config import DeviceConfig
from enip_farm.device.catalogue import shipped_catalogue
from enip_farm.device.device import Device
from enip_farm.device.events import Reset, TcpConnected
from enip_farm.device.profile import resolve
from enip_farm.protocol.cip import encode_multiple_service, encode_request
from enip_farm.protocol.commands import decode_send_data, encode_send_data
from enip_farm.protocol.connection import decode_io_packet, encode_class0_packet, encode_forward_open, encode_io_packet
from enip_farm.protocol.cpf import ItemType
from enip_farm.protocol.encapsulation import Command, encode_frame
from enip_farm.protocol.epath import encode_request_path
from enip_farm.protocol.safety.messages import encode_data, mode_byte
from enip_farm.protocol.session import MessageContext
from tests.helpers import ENIP_PORT, RawClient
from tests.test_cip_services_unit import CLASS1, MS, SCANNER, T0, ask, make_device
from tests.test_safety import ORIGINATOR, _pid, safety_open

pytestmark = pytest.mark.class1_paths  # both class-1 paths (tests/conftest.py)

RESET_PATH = encode_request_path(1, 1)


def _identity_router() -> MessageRouter:
    router = MessageRouter()
    router.register(IdentityObject(vendor_id=26, device_type=12, product_code=lambda: 1, revision=(1, 2),
                                   serial_number=7, product_name="io", status=lambda: 0x30))
    return router


@pytest.mark.parametrize(("data", "kind"), [(b"", 0), (b"\x00", 0), (b"\x01", 1), (b"\x02", 2)])
def test_the_identity_reset_service_returns_the_effect_of_its_type(data: bytes, kind: int) -> None:
    router = _identity_router()
    reply, items = router.dispatch(encode_request(0x05, RESET_PATH, data), MessageContext(SCANNER, None, (), T0))
    assert (reply, items) == (b"\x85\x00\x00\x00", ())
    effects = router.pop_effects()
    assert effects == [ResetRequested(kind)] and type(effects[0]) is ResetRequested and effects[0].type == kind
    assert router.pop_effects() == []


@pytest.mark.parametrize(("path", "data", "reply"), [
    (RESET_PATH, b"\x03", b"\x85\x00\x20\x00"), (RESET_PATH, b"\x00\x00", b"\x85\x00\x15\x00"),
    (encode_request_path(1, 0), b"", b"\x85\x00\x08\x00")])
def test_a_refused_reset_has_no_effect(path: bytes, data: bytes, reply: bytes) -> None:
    router = _identity_router()
    assert router.dispatch(encode_request(0x05, path, data), MessageContext(SCANNER, None, (), T0))[0] == reply
    assert router.pop_effects() == []


def test_effects_of_embedded_requests_are_queued_in_order() -> None:
    router = _identity_router()
    packet = encode_multiple_service([encode_request(0x05, RESET_PATH, b"\x02"),
                                      encode_request(0x0E, encode_request_path(1, 1, 1)),
                                      encode_request(0x05, RESET_PATH, b"\x01")])
    reply, _ = router.dispatch(encode_request(0x0A, encode_request_path(2, 1), packet),
                               MessageContext(SCANNER, None, (), T0))
    assert reply[:4] == b"\x8a\x00\x00\x00"
    assert router.pop_effects() == [ResetRequested(2), ResetRequested(1)]


@pytest.mark.parametrize("kind", [0, 1, 2])
def test_the_device_records_the_reset_it_performed_as_a_typed_detail(kind: int) -> None:
    device = make_device(reset_time_s=2.5)
    seen = []
    device.observe(seen.append)
    reply = ask(device, encode_request(0x05, RESET_PATH, bytes((kind,))), now=T0)
    assert (reply.service, reply.general_status, reply.data) == (0x85, 0, b"")
    (event,) = [e for e in seen if isinstance(e.detail, Reset)]
    assert event.detail == Reset(ResetRequested(kind), 2.5) and event.kind == "reset"
    assert event.as_dict()["detail"] == event.text  # the API's JSON: the text, as before
    assert device.restarts == 1 and device.reset_window.due() == T0 + 2_500 * MS


def test_the_api_reset_is_the_same_effect() -> None:
    device = make_device()
    assert device.reset(2, T0) is True and device.reset(0, T0) is False  # resetting already
    (event,) = device.events.of_type(Reset)
    assert event.detail == Reset(ResetRequested(2), 1.0)
    assert event.text == "type 2 (out-of-box configuration but the communication parameters): not answering for 1 s"
    with pytest.raises(ValueError, match=r"^reset type 3: one of 0, 1, 2$"):
        device.reset(3, T0)


def test_the_farm_acts_on_the_typed_reset_not_on_an_events_text(enip_farm) -> None:
    farm = enip_farm(name="io1", model="DSQC1030", reset_time_s=120.0)
    address = farm["io1"].address
    with RawClient(address) as client:
        client.register()
        farm.device("io1").record(TcpConnected("type 0 (power cycle): not answering for 120 s"))  # text only
        assert client.get(1, 1, 1).general_status == 0  # still served: nothing matched the text
        frame = client.exchange(encode_frame(Command.SEND_RR_DATA, encode_send_data(
            [(ItemType.NULL_ADDRESS, b""), (ItemType.UNCONNECTED_DATA, encode_request(0x05, RESET_PATH))]),
            client.session_handle))
        assert (frame.header.command, frame.header.status) == (Command.SEND_RR_DATA, 0)
        assert decode_send_data(frame.data).items[1].data == b"\x85\x00\x00\x00"  # the reply came first
        assert client.is_closed()  # then the farm dropped the TCP connection
    with pytest.raises(ConnectionRefusedError, match="Connection refused"):  # and listens no more until the window ends
        socket.create_connection((address, ENIP_PORT), timeout=5)
    resets = farm["io1"].events(Reset)
    assert [type(e.detail) for e in resets] == [Reset] and resets[0].detail.request == ResetRequested(0)
    assert farm["io1"].events("reset") == resets  # the API's kind names the class


def _lock_free_send(device: Device, sent: list[tuple[bytes, tuple[str, int]]]):  # noqa: ANN202
    def send(packet: bytes, address: tuple[str, int]) -> None:
        assert device.guard.lock.acquire(blocking=False), "a class-1 send under the device lock"
        device.guard.lock.release()
        sent.append((packet, address))
    return send


def test_t_o_packets_are_sent_after_the_lock_is_released() -> None:
    device = make_device()
    assert ask(device, CLASS1).general_status == 0
    (connection,) = device.connections.values()
    sent: list[tuple[bytes, tuple[str, int]]] = []
    send = _lock_free_send(device, sent)
    assert device.receive_io(encode_io_packet(connection.o_t_id, 1, 1, b"\x01\x00\x00\x00\x10\x02"),
                             (SCANNER, 2222), T0 + MS, send)
    assert sent == [] and device.outputs == b"\x10\x02"
    device.service_io(T0 + 100 * MS, send)
    (packet, address), = sent
    io = decode_io_packet(packet)
    assert io is not None and io.connection_id == connection.t_o_id and address == (SCANNER, 2222)
    assert device.counters["t_o_packets"] == 1


def test_a_time_coordination_reply_is_sent_after_the_lock_is_released() -> None:
    device = Device(resolve(DeviceConfig(name="s1", address="127.0.77.1", model="DSQC1042"), shipped_catalogue()))
    request = safety_open()
    reply, _ = device.handle_unconnected(encode_request(0x54, encode_request_path(6, 1), encode_forward_open(request)),
                                         MessageContext(ORIGINATOR.host, None, (), T0))
    assert reply[2] == 0
    (connection,) = device.connections.values()
    sent: list[tuple[bytes, tuple[str, int]]] = []
    idle = encode_data(b"\x00", mode_byte(False, 0), 0, _pid(request), False)
    assert device.receive_io(encode_class0_packet(connection.o_t_id, 1, idle), (ORIGINATOR.host, 2222),
                             T0 + 5 * MS, _lock_free_send(device, sent))
    assert len(sent) == 1 and device.counters["safety_time_coordination_sent"] == 1


def test_an_identity_reset_ends_its_connections_as_device_reset_in_the_report() -> None:
    """The report's word is the typed `ends` the reset passes, not a match on the reason's text."""
    device = make_device()
    assert ask(device, CLASS1).general_status == 0
    (connection,) = device.connections.values()
    assert ask(device, encode_request(0x05, RESET_PATH, b"\x00"), now=T0 + MS).general_status == 0
    assert not device.connections
    assert (connection.measure.ended, connection.measure.end_reason) == ("device reset", "identity reset (type 0)")
