"""The device transaction (device/guard.py), typed events (device/events.py) and observers by class
(device/observers.py): in-process, with an injected clock, no sockets. Events are published once,
after the lock, in order; images are compared only while someone observes image changes; an error
in the work releases the lock and publishes what had happened, once; each observer is told only
the classes it asked for; the wire's words are the ones the API has always shown."""

from __future__ import annotations

import logging

import pytest

from enip_farm.cip.admission import Originator
from enip_farm.cip.connection_events import ConnectionClosed, ConnectionEvent, ConnectionOpened
from enip_farm.cip.identity import ResetRequested
from enip_farm.config import parse_config
from enip_farm.device.build import build_profiles
from enip_farm.device.catalogue import shipped_catalogue
from enip_farm.device.device import Device
from enip_farm.device.events import (
    AddressConflict,
    EncapsulationIgnored,
    EncapsulationRefused,
    Event,
    FaultCleared,
    FaultInjected,
    ImageChanged,
    LinkDown,
    PowerReturned,
    RequestHandled,
    Reset,
    ResetDone,
    SessionEnded,
    SessionRegistered,
    TcpClosed,
    TcpConnected,
    TcpInactive,
    Wired,
)
from enip_farm.device.guard import NO_IMAGES, OUTPUT_IMAGE
from enip_farm.farm.console import Console
from enip_farm.protocol.connection import ConnectionTriad, ConnectionType, ForwardOpenRequest, NetworkParameters

MS = 1_000_000
T0 = 1_000 * MS
PATH = bytes.fromhex("20 04 24 01 2C 64 2C 65")
REQUEST = (0x0E, bytes.fromhex("20 01 24 01 30 01"), 0, None, False)


class Clock:
    """The clock a test gives the device: it moves only when told."""

    def __init__(self, now: int) -> None:
        self.now = now

    def __call__(self) -> int:
        return self.now


def make_device(clock: Clock | None = None) -> Device:
    config = parse_config({"devices": [{"name": "io1", "address": "127.0.0.1", "model": "DSQC1030"}]})
    (profile,) = build_profiles(config, shipped_catalogue())
    return Device(profile, clock=clock or Clock(T0))


def forward_open_request() -> ForwardOpenRequest:
    p2p = ConnectionType.POINT_TO_POINT
    return ForwardOpenRequest(0x0A, 0x0E, 0, 0x7E570001, ConnectionTriad(7, 0x1234, 0xABCD), 0, 10_000,
                              NetworkParameters(False, p2p, 2, False, 8), 10_000,
                              NetworkParameters(False, p2p, 2, False, 4), 0x01, PATH)


def lock_free_observer(device: Device, seen: list[Event]):  # noqa: ANN201
    def observe(event: Event) -> None:
        assert device.guard.lock.acquire(blocking=False), "published under the device lock"
        device.guard.lock.release()
        seen.append(event)
    return observe


def test_a_transaction_publishes_once_after_the_lock_in_order() -> None:
    device = make_device()
    seen: list[Event] = []
    device.observe(lock_free_observer(device, seen))
    with device.guard.transaction(T0 + 5) as transaction:
        transaction.requests = [REQUEST]
        device.table.forward_open(forward_open_request(), Originator("127.0.0.9"), T0 + 4)
        device.assemblies["output"].data[0] = 0x10
        transaction.emit(Wired("io1.DI1", (1,), "a test"))
        assert seen == []  # nothing told while the work runs
    assert [type(e.detail) for e in seen] == [RequestHandled, ConnectionOpened, ImageChanged, Wired]
    assert [e.monotonic_ns for e in seen] == [T0 + 5, T0 + 4, T0 + 5, T0 + 5]  # a connection event: its own time
    assert seen[2].detail == ImageChanged("output", b"\x00\x00", b"\x10\x00")
    with device.guard.transaction(T0 + 6):
        pass
    assert len(seen) == 4  # published once: nothing is carried over
    logged = [type(e.detail) for e in device.events]
    assert logged == [RequestHandled, ConnectionOpened, Wired]  # image changes are told, not logged


def test_an_error_in_the_work_releases_the_lock_and_publishes_what_happened_once() -> None:
    device = make_device()
    seen: list[Event] = []
    device.observe(lock_free_observer(device, seen))
    device.table.forward_open(forward_open_request(), Originator("127.0.0.9"), T0)
    device.table.pop_events()
    (connection,) = device.table.connections.values()
    with pytest.raises(RuntimeError, match="^half way$"), device.guard.transaction(T0 + 1) as transaction:
        device.table.close(connection, "a test", T0 + 1)
        device.assemblies["output"].data[1] = 0x01
        transaction.emit(LinkDown("drop", 1.0))
        raise RuntimeError("half way")
    assert device.guard.lock.acquire(blocking=False)
    device.guard.lock.release()
    assert [type(e.detail) for e in seen] == [ConnectionClosed, ImageChanged, LinkDown]
    with device.guard.transaction(T0 + 2):
        pass
    assert len(seen) == 3


def test_a_failed_write_publishes_nothing_and_changes_nothing() -> None:
    device = make_device()
    seen: list[Event] = []
    device.observe(seen.append)

    def fail(image: bytearray) -> None:
        image[0] = 0xFF
        raise ValueError("no")

    with pytest.raises(ValueError, match="^no$"):
        device.write_image("input", fail)
    assert seen == [] and device.inputs == b"\x00\x00"


def test_images_are_compared_only_while_someone_observes_their_changes() -> None:
    device = make_device()
    others: list[Event] = []
    changes: list[Event] = []
    device.observe(others.append, ConnectionEvent, SessionRegistered)
    device.set_inputs(b"\x01\x00")
    assert others == [] and device.guard.observers.of_images == []
    unobserve = device.observe(changes.append, ImageChanged)
    device.set_inputs(b"\x03\x00")
    with device.guard.transaction(T0, NO_IMAGES) as transaction:  # the work decides what to watch
        transaction.watch(OUTPUT_IMAGE)
        device.assemblies["output"].data[0] = 0x20
    assert [e.detail for e in changes] == [ImageChanged("input", b"\x01\x00", b"\x03\x00"),
                                           ImageChanged("output", b"\x00\x00", b"\x20\x00")]
    unobserve()
    device.set_inputs(b"\x07\x00")
    assert len(changes) == 2 and others == []


def test_each_observer_is_told_only_its_classes_and_requests_are_logged_without_observers() -> None:
    device = make_device()
    connections: list[Event] = []
    device.observe(connections.append, ConnectionEvent)
    with device.guard.transaction(T0) as transaction:
        transaction.requests = [REQUEST]
        device.table.forward_open(forward_open_request(), Originator("127.0.0.9"), T0)
    assert device.guard.observers.of_requests == []
    assert [type(e.detail) for e in connections] == [ConnectionOpened]  # a subclass of ConnectionEvent
    (request,) = device.events.of_type(RequestHandled)
    assert request.detail == RequestHandled(*REQUEST) and request.kind == "request"
    assert request.text == "service 0x0E path 20 01 24 01 30 01 status 0x00"


def test_the_api_edge_takes_its_time_from_the_clock_it_is_given() -> None:
    clock = Clock(T0)
    device = make_device(clock)
    seen: list[Event] = []
    device.observe(seen.append)
    device.set_inputs(b"\x01\x00")
    clock.now = T0 + 7
    device.record(TcpConnected("127.0.0.9:1234"))
    assert [e.monotonic_ns for e in seen] == [T0, T0 + 7]
    assert device.reset(0) is True  # at the clock's now: answers again 1 s later (reset_time_s)
    assert device.reset_window.due() == T0 + 7 + 1_000 * MS
    clock.now = T0 + 7 + 1_000 * MS - 1
    assert device.end_reset() is False and device.resetting
    clock.now += 1
    assert device.end_reset() is True and not device.resetting
    assert [type(e.detail) for e in seen][-2:] == [Reset, ResetDone] and seen[-1].monotonic_ns == clock.now


def test_the_wire_words_of_each_event_are_the_ones_the_api_showed() -> None:
    """The kinds and details GET /events, the SSE stream and the dashboard have always shown."""
    words = [
        (TcpConnected("127.0.0.9:5000"), "tcp connected", "127.0.0.9:5000"),
        (TcpInactive("127.0.0.9:5000", 30), "tcp inactive",
         "127.0.0.9:5000: no whole request for 30 s, closed (TCP/IP attribute 13)"),
        (TcpInactive("", 30), "tcp inactive", ""),
        (TcpClosed("127.0.0.9:5000", True, 1.25), "tcp closed", "127.0.0.9:5000 closed by the client after 1.2 s"),
        (TcpClosed("?", False, 3.0), "tcp closed", "? closed by the farm after 3.0 s"),
        (EncapsulationRefused(0x65, "127.0.0.9:5000", 0x69), "encapsulation refused",
         "RegisterSession from 127.0.0.9:5000: encapsulation status 0x0069 unsupported protocol"),
        (EncapsulationIgnored(0x6F, "127.0.0.9:5000", 1), "encapsulation ignored",
         "SendRRData from 127.0.0.9:5000 carried status 0x00000001; a request's status must be 0 "
         "(Vol. 2, 2-3.5): no reply"),
        (SessionRegistered(3, "127.0.0.9"), "session registered", "handle 3 from 127.0.0.9"),
        (SessionRegistered(3), "session registered", "handle 3"),
        (SessionEnded(3), "session ended", "handle 3"),
        (Reset(ResetRequested(1), 0.5), "reset", "type 1 (out-of-box configuration): not answering for 0.5 s"),
        (ResetDone(), "reset done", "answering again"),
        (Wired("robot.DI1-2", (0, 1), "wire from plc.DO1-2"), "wired", "robot.DI1-2 = [0, 1] (wire from plc.DO1-2)"),
        (Wired("robot.DI1", (1,), "rule: plc.doStart rises"), "wired", "robot.DI1 = 1 (rule: plc.doStart rises)"),
        (PowerReturned(2.5), "power returned", "booting: not answering for 2.5 s"),
        (AddressConflict(bytes.fromhex("020000000001"), True, False), "address conflict",
         "with 02:00:00:00:00:01: address defended"),
        (LinkDown("link-down", 0.25), "link down", "link-down: for 0.250 s"),
        (ImageChanged("input", b"\x01", b"\x03"), "image changed", "input 01 -> 03"),
        (RequestHandled(0x10, b"\x20\x04", 0x14, 0x0001, False), "request",
         "service 0x10 path 20 04 status 0x14 extended 0x0001"),
    ]
    assert [(e.kind, e.text) for e, _, _ in words] == [(kind, text) for _, kind, text in words]
    delay = FaultInjected({"kind": "delay", "delay_ms": 800.0, "duration_s": 10.0})
    event = Event(T0, T0 + 5, "io1", delay)
    assert event.as_dict() == {"time": (T0 + 5) / 1e9, "monotonic": T0 / 1e9, "device": "io1",
                               "kind": "fault injected", "detail": {"kind": "delay", "delay_ms": 800.0,
                                                                    "duration_s": 10.0}}
    assert event.text == "delay (delay_ms 800, duration_s 10)"
    cleared = Event(T0, T0, "io1", FaultCleared(("delay", "drop")))
    assert (cleared.kind, cleared.as_dict()["detail"], cleared.text) == ("fault cleared", {"kind": "delay, drop"},
                                                                        "delay, drop")


def test_a_quiet_console_observes_only_the_warnings(caplog: pytest.LogCaptureFixture) -> None:
    device = make_device()
    logger = logging.getLogger("tests.transaction.console")
    logger.setLevel(logging.WARNING)
    console = Console([device], logger).attach()
    assert device.guard.observers.of_requests == [] and device.guard.observers.of_images == []
    device.table.forward_open(forward_open_request(), Originator("127.0.0.9"), T0)
    with caplog.at_level(logging.WARNING, logger.name):
        with device.guard.transaction(T0 + 1):
            (connection,) = device.table.connections.values()
            device.table.close(connection, "a test", T0 + 1)  # a close: INFO, not observed
        device.record(FaultInjected({"kind": "drop"}))  # a WARNING
    console.close()
    assert [r.getMessage() for r in caplog.records] == ["io1 127.0.0.1: fault injected: drop"]
    assert device.guard.observers.of(FaultInjected) == []


def test_wait_for_observes_image_changes_only_while_it_waits() -> None:
    from enip_farm.control.handle import DeviceHandle

    device = make_device()
    handle = DeviceHandle(None, device)  # type: ignore[arg-type]  # (no farm: signals and images only)
    assert device.guard.observers.of_images == []
    device.set_inputs(b"\x01\x00")
    handle.wait_for(lambda h: h.get("DI1") == 1, timeout=1)
    assert device.guard.observers.of_images == []
