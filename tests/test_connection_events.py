"""Typed connection events (cip/connection_events.py), one outbound queue and the time as a
required parameter: consumers match on the class, the wire form (the JSON the API, the SSE stream
and the dashboard show) is what it always was, the cyclic I/O thread is re-armed by a typed event,
and nothing in cip/ or protocol/ takes a default for `now`. No sockets, no sleeps."""

from __future__ import annotations

import importlib
import inspect
import pkgutil
import socket

import pytest

import enip_farm.cip
import enip_farm.protocol
from enip_farm.cip.connection_events import (
    ConnectionClosed,
    ConnectionEvent,
    ConnectionFaulted,
    ConnectionOpened,
    ConnectionRefused,
    ConnectionShortData,
    ConnectionTimedOut,
    SafeState,
    SafetyCrcFault,
    SafetyTimingFault,
)
from enip_farm.cip.identity import ResetRequested
from enip_farm.device.events import EventLog, Reset, ResetDone
from enip_farm.protocol.cip import decode_reply, encode_request
from enip_farm.protocol.connection import (
    ConnectionTriad,
    ForwardCloseRequest,
    decode_forward_open_reply,
    encode_forward_close,
)
from enip_farm.protocol.encapsulation import Command, encode_frame
from enip_farm.protocol.epath import encode_request_path
from enip_farm.protocol.session import EncapsulationSession, MessageContext
from enip_farm.server.implicit import CyclicIoThread, DeviceIo
from tests.test_connection_table import make_table, open_owner
from tests.test_device import PATH, forward_close, forward_open, make_device, request

MS = 1_000_000  # ns
T0 = 7_000 * MS  # an arbitrary origin: nothing here reads a clock

# -- one class per kind, the wire's text made in one place ---------------------------------------------


def test_each_event_class_has_the_wire_kind_and_text_it_always_had() -> None:
    connection = open_owner(make_table()).connection
    line = (f"exclusive owner from 127.0.0.9: O->T 0x{connection.o_t_id:08X} RPI 10000 us 8 bytes, "
            f"T->O 0x{connection.t_o_id:08X} RPI 10000 us 4 bytes to 127.0.0.9:2222")
    events: list[tuple[ConnectionEvent, str, str]] = [
        (ConnectionOpened(T0, connection), "connection opened", line),
        (ConnectionClosed(T0, connection, "forward close"), "connection closed", f"{line}: forward close"),
        (ConnectionTimedOut(T0, connection, "no packet for 40 ms"), "connection timed out",
         f"{line}: no packet for 40 ms"),
        (ConnectionFaulted(T0, connection, "safety crc fault: CRC"), "connection faulted",
         f"{line}: safety crc fault: CRC"),
        (SafeState(T0, connection, "safe outputs off: forward close"), "safe state",
         f"{line}: safe outputs off: forward close"),
        (SafetyCrcFault(T0, connection, "CRC or redundancy mismatch"), "safety crc fault",
         f"{line}: CRC or redundancy mismatch"),
        (SafetyTimingFault(T0, connection, "data age 9 ticks"), "safety timing fault", f"{line}: data age 9 ticks"),
        (ConnectionShortData(T0, connection, "3 of 4 bytes: not applied to the outputs"), "connection short data",
         f"{line}: 3 of 4 bytes: not applied to the outputs"),
        (ConnectionRefused(T0, "Forward Close from ?: 0x01/0x0107"), "connection refused",
         "Forward Close from ?: 0x01/0x0107"),
    ]
    assert [(event.kind, event.text, event.at) for event, _, _ in events] == [
        (kind, text, T0) for _, kind, text in events]
    assert len({type(event) for event, _, _ in events}) == len(events)  # one class per kind


def test_events_are_frozen() -> None:
    event = ConnectionRefused(T0, "refused")
    with pytest.raises(AttributeError, match="cannot assign to field 'reason'"):
        event.reason = "changed"  # type: ignore[misc]


def _close(triad: ConnectionTriad) -> bytes:
    return encode_request(0x4E, encode_request_path(6, 1),
                          encode_forward_close(ForwardCloseRequest(0x0A, 0x0E, triad, PATH)))


def test_the_json_of_each_connection_event_is_unchanged() -> None:
    device = make_device()  # first watchdog 10 s
    opened = decode_forward_open_reply(decode_reply(request(device, forward_open(), T0)).data)
    assert decode_reply(request(device, forward_open(), T0 + MS)).general_status == 0x01  # the same triad again
    assert decode_reply(request(device, forward_close(), T0 + 2 * MS)).general_status == 0
    again = decode_forward_open_reply(decode_reply(request(device, forward_open(), T0 + 3 * MS)).data)
    device.service_io(T0 + 3 * MS + 10_000 * MS, lambda *_: None)  # the first watchdog
    assert decode_reply(request(device, _close(ConnectionTriad(9, 0x1234, 0xABCD)), T0 + 11_000 * MS)).general_status
    offset = device.events.wall_offset_ns

    def line(reply: object) -> str:
        return (f"exclusive owner from 127.0.0.9: O->T 0x{reply.o_t_connection_id:08X} RPI 10000 us 8 bytes, "  # type: ignore[attr-defined]
                f"T->O 0x{reply.t_o_connection_id:08X} RPI 10000 us 4 bytes to 127.0.0.9:2222")  # type: ignore[attr-defined]

    def wire(at: int, kind: str, detail: str) -> dict:
        return {"time": (at + offset) / 1e9, "monotonic": at / 1e9, "device": "io1", "kind": kind, "detail": detail}

    assert [e.as_dict() for e in device.events if e.kind.startswith("connection")] == [
        wire(T0, "connection opened", line(opened)),
        wire(T0 + MS, "connection refused",
             "Forward Open from 127.0.0.9: 0x01/0x0100 connection failure: connection in use or duplicate Forward "
             "Open (class 1, O->T RPI 10000 us 8 bytes, T->O RPI 10000 us 4 bytes, path 20 04 24 01 2c 64 2c 65)"),
        wire(T0 + 2 * MS, "connection closed", f"{line(opened)}: forward close"),
        wire(T0 + 3 * MS, "connection opened", line(again)),
        wire(T0 + 10_003 * MS, "connection timed out", f"{line(again)}: no packet for 40 ms"),
        wire(T0 + 11_000 * MS, "connection refused",
             "Forward Close from 127.0.0.9: 0x01/0x0107 connection failure: target connection not found "
             "(connection serial 0x0009, vendor 4660, originator serial 0x0000ABCD)"),
    ]


# -- the cyclic I/O thread re-armed by a typed event -------------------------------------------------------


def test_the_io_thread_is_rearmed_when_a_connection_opens_and_only_then() -> None:
    device = make_device()
    thread = CyclicIoThread()  # not started: its requests are read, not served
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        endpoint = DeviceIo(device, sock, thread)
        assert device.timer_moved == endpoint._timer_moved
        assert decode_reply(request(device, forward_open(), T0)).general_status == 0
        assert list(thread._requests) == [endpoint]  # a new stream and watchdog: the timer moved
        thread._requests.clear()
        assert decode_reply(request(device, forward_open(), T0 + MS)).general_status == 0x01  # refused
        assert decode_reply(request(device, forward_close(), T0 + 2 * MS)).general_status == 0  # closed
        assert decode_reply(request(device, encode_request(0x0E, encode_request_path(1, 1, 1)), T0 + 3 * MS)
                            ).general_status == 0
        assert list(thread._requests) == []
        endpoint.close()
        assert device.timer_moved is None
    finally:
        sock.close()
        thread.stop()


def test_the_device_tells_its_timer_moved_once_per_opened_connection() -> None:
    device = make_device()
    moved: list[int] = []
    device.timer_moved = lambda: moved.append(len(device.connections))
    request(device, forward_open(), T0)
    request(device, forward_close(), T0 + MS)
    request(device, forward_open(), T0 + 2 * MS)
    assert moved == [1, 1]  # told after the lock, with the connection in the table


# -- one outbound queue ----------------------------------------------------------------------------------


def test_the_table_has_one_way_out() -> None:
    table = make_table()
    assert not hasattr(table, "pop_replies") and not hasattr(table, "has_replies")
    connection = open_owner(table).connection
    assert not table.answers_queued
    (packet, address), = table.datagrams_to_send(T0)
    assert address == connection.t_o_address and table.counters["t_o_packets"] == 1


# -- the time: required, integer nanoseconds --------------------------------------------------------------


def _callables_of(package: object) -> list[tuple[str, object]]:
    found = []
    for module_info in pkgutil.walk_packages(package.__path__, package.__name__ + "."):  # type: ignore[attr-defined]
        module = importlib.import_module(module_info.name)
        for name, member in vars(module).items():
            if getattr(member, "__module__", None) != module.__name__:
                continue
            if inspect.isfunction(member):
                found.append((f"{module.__name__}.{name}", member))
            elif inspect.isclass(member):
                for attribute, value in vars(member).items():
                    if inspect.isfunction(value):
                        found.append((f"{module.__name__}.{name}.{attribute}", value))
    return found


@pytest.mark.parametrize("package", [enip_farm.cip, enip_farm.protocol], ids=["cip", "protocol"])
def test_no_now_in_cip_or_protocol_has_a_default(package: object) -> None:
    callables = _callables_of(package)
    with_now = [name for name, function in callables if "now" in inspect.signature(function).parameters]
    assert len(with_now) > (20 if package is enip_farm.cip else 2)  # the walk saw them
    defaulted = [name for name, function in callables
                 if inspect.signature(function).parameters.get("now", inspect.Parameter("now", 1)).default
                 is not inspect.Parameter.empty]
    assert defaulted == []
    assert "now" not in MessageContext._field_defaults


def test_now_is_required_by_the_session_and_the_message_context() -> None:
    session = EncapsulationSession(make_device(), "127.0.0.9")
    with pytest.raises(TypeError, match="missing 1 required positional argument: 'now'"):
        session.receive(encode_frame(Command.LIST_IDENTITY))  # type: ignore[call-arg]
    with pytest.raises(TypeError, match="missing 1 required positional argument: 'now'"):
        session.connection_lost()  # type: ignore[call-arg]
    with pytest.raises(TypeError, match="missing 1 required positional argument: 'now'"):
        MessageContext("127.0.0.9", None, ())  # type: ignore[call-arg]
    log = EventLog("io1")
    with pytest.raises(TypeError, match="missing 1 required positional argument: 'now'"):
        log.record(ResetDone())  # type: ignore[call-arg]
    with pytest.raises(TypeError, match="missing 1 required positional argument: 'now'"):
        log.request((0x0E, b"", 0, None, False))  # type: ignore[call-arg]


def test_the_event_log_counts_integer_nanoseconds() -> None:
    log = EventLog("io1")
    event = log.record(Reset(ResetRequested(0), 1.0), T0 + 1)
    assert (event.monotonic_ns, event.wall_ns) == (T0 + 1, T0 + 1 + log.wall_offset_ns)
    assert type(event.monotonic_ns) is int and type(event.wall_ns) is int
    assert event.as_dict() == {"time": (T0 + 1 + log.wall_offset_ns) / 1e9, "monotonic": (T0 + 1) / 1e9,
                               "device": "io1", "kind": "reset",
                               "detail": "type 0 (power cycle): not answering for 1 s"}
