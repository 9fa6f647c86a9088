"""A device's signal timeline (control/timeline.py, GET /devices/{name}/timeline): steps per signal
from the window's start, marks by who changed the image. The arithmetic with injected times on a
stand-in device (unit); then a farm whose inputs a test sets, whose outputs pycomm3 writes
explicitly and the `ethernetip` scanner writes over class 1, each marked by its maker."""

from __future__ import annotations

from collections.abc import Callable

import httpx
import pytest
from pycomm3 import CIPDriver, Services

from enip_farm.cip.connection_events import ConnectionTimedOut
from enip_farm.config import parse_config
from enip_farm.control.timeline import MAX_CHANGES, DeviceRecorder
from enip_farm.device.build import build_profiles
from enip_farm.device.catalogue import shipped_catalogue
from enip_farm.device.events import Event, ImageChanged, RequestHandled
from tests.helpers import wait_for
from tests.scanners import scanner

S = 1_000_000_000


class StandIn:
    """What DeviceRecorder reads of a device: name, profile, images, observe."""

    def __init__(self) -> None:
        config = parse_config({"devices": [{"name": "io", "address": "127.0.0.1", "model": "DSQC1030"}]}, "<t>")
        (self.profile,) = build_profiles(config, shipped_catalogue())
        self.name = "io"
        self.inputs, self.outputs = b"\x00\x00", b"\x00\x00"
        self.observers: list[Callable[[Event], None]] = []

    def observe(self, observer: Callable[[Event], None]) -> Callable[[], None]:
        self.observers.append(observer)
        return lambda: self.observers.remove(observer)

    def tell(self, at: int, detail: object) -> None:
        if isinstance(detail, ImageChanged):
            setattr(self, detail.role + "s", detail.new)
        for observer in self.observers:
            observer(Event(at, at, "io", detail))


def trace(timeline: dict, name: str) -> list:
    return next(s["values"] for s in timeline["signals"] if s["name"] == name)


def test_steps_and_marks_with_injected_times() -> None:
    device = StandIn()
    recorder = DeviceRecorder(device, 10 * S)  # type: ignore[arg-type]
    device.tell(11 * S, ImageChanged("input", b"\x00\x00", b"\x04\x00"))  # DI3 on: the test
    device.tell(12 * S, RequestHandled(0x10, bytes.fromhex("20 04 24 96 30 03"), 0, None, False))
    device.tell(12 * S, ImageChanged("output", b"\x00\x00", b"\x10\x00"))  # DO5 on: explicit
    device.tell(13 * S, ImageChanged("output", b"\x10\x00", b"\x30\x00"))  # DO6 on: O->T
    device.tell(14 * S, ConnectionTimedOut(14 * S, None))  # type: ignore[arg-type]  # (no connection: not read)
    device.tell(14 * S, ImageChanged("output", b"\x30\x00", b"\x00\x00"))  # fault state
    whole = recorder.timeline(60, 20 * S)
    assert (whole["start"], whole["now"], whole["recording_since"]) == (10.0, 20.0, 10.0)  # not before recording
    assert trace(whole, "DI3") == [[10.0, 0], [11.0, 1]]
    assert trace(whole, "DO5") == [[10.0, 0], [12.0, 1], [14.0, 0]]
    assert trace(whole, "DO6") == [[10.0, 0], [13.0, 1], [14.0, 0]]
    assert trace(whole, "DI1") == [[10.0, 0]]
    assert whole["marks"] == [
        {"at": 11.0, "role": "input", "by": "stimulus", "signals": ["DI3"]},
        {"at": 12.0, "role": "output", "by": "explicit", "signals": ["DO5"]},
        {"at": 13.0, "role": "output", "by": "o->t", "signals": ["DO6"]},
        {"at": 14.0, "role": "output", "by": "connection timed out", "signals": ["DO5", "DO6"]}]
    # a window that starts after some changes: the values then, the later changes only
    late = recorder.timeline(7.5, 20 * S)
    assert late["start"] == 12.5
    assert trace(late, "DI3") == [[12.5, 1]]
    assert trace(late, "DO5") == [[12.5, 1], [14.0, 0]]
    assert [m["at"] for m in late["marks"]] == [13.0, 14.0]
    # a change that leaves every value as it was is no mark
    device.tell(15 * S, ImageChanged("output", b"\x00\x00", b"\x00\x00"))
    assert len(recorder.timeline(60, 20 * S)["marks"]) == 4


def test_memory_is_bounded_whatever_the_controller_writes() -> None:
    device = StandIn()
    recorder = DeviceRecorder(device, 0)  # type: ignore[arg-type]
    for k in range(3 * MAX_CHANGES):
        old, new = bytes([k % 2, 0]), bytes([(k + 1) % 2, 0])
        device.tell(k + 1, ImageChanged("output", old, new))
    assert len(recorder.changes) == MAX_CHANGES
    recorder.unobserve()
    assert device.observers == []


@pytest.mark.integration
def test_the_timeline_marks_stimuli_explicit_writes_and_class1_writes(enip_farm) -> None:
    farm = enip_farm(name="io1", model="DSQC1030", implicit={"first_watchdog_s": 0}, http=True)
    url = f"http://127.0.0.1:{farm.http.port}/devices/io1/timeline"
    assert httpx.get(url, params={"seconds": 601}).status_code == 422
    assert httpx.get(f"http://127.0.0.1:{farm.http.port}/devices/nope/timeline").status_code == 404
    first = httpx.get(url).json()  # recording starts here
    assert first["marks"] == [] and first["seconds"] == 30
    assert {s["name"] for s in first["signals"]} >= {"DI1", "DI16", "DO1", "DO16"}
    io = farm["io1"]
    io.set(DI3=1)
    with CIPDriver(io.address) as plc:  # explicit: Set_Attribute_Single of the output assembly
        reply = plc.generic_message(service=Services.set_attribute_single, class_code=4, instance=100,
                                    attribute=3, request_data=b"\x10\x00", connected=False, route_path=False)
        assert not reply.error
    with scanner(io.address, forward_close=True) as scan:
        scan.outputs[4] = scan.outputs[5] = True  # DO5 stays, DO6 on: class 1
        assert scan.forward_open(10, 2) == 0
        scan.conn.produce()
        assert wait_for(lambda: io.get("DO6") == 1, 10)
        timeline = httpx.get(url).json()
    assert [(m["by"], m["signals"]) for m in timeline["marks"]] == [
        ("stimulus", ["DI3"]), ("explicit", ["DO5"]), ("o->t", ["DO6"])]
    marks = timeline["marks"]
    assert timeline["start"] <= marks[0]["at"] <= marks[1]["at"] <= marks[2]["at"] <= timeline["now"]
    assert [v for _, v in trace(timeline, "DI3")] == [0, 1]
    assert [v for _, v in trace(timeline, "DO6")] == [0, 1]
