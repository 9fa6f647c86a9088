"""The dashboard's overview (control/overview.py, GET /overview): each device in one state (idle,
running, timed_out, faulted), the counts, and the recent events a page shows when it opens. The
states are checked against a real scanner's class-1 connection (the `ethernetip` package): opened,
silent until the farm times it out, opened again and closed."""

from __future__ import annotations

import httpx

from enip_farm.cip.connection import Connection, ConnectionKind
from enip_farm.cip.connection_events import ConnectionClosed, ConnectionFaulted, ConnectionTimedOut
from enip_farm.config import parse_config
from enip_farm.control.overview import RECENT, Overview
from enip_farm.device.build import build_profiles
from enip_farm.device.catalogue import shipped_catalogue
from enip_farm.device.device import Device
from enip_farm.device.events import FaultInjected, TcpConnected
from enip_farm.device.faults import Fault
from enip_farm.protocol.connection import ConnectionTriad
from tests.helpers import wait_for
from tests.scanners import scanner

DEADLINE_S = 30.0  # generous: conditions end the waits as soon as they hold
OWNER = Connection(ConnectionKind.EXCLUSIVE_OWNER, ConnectionTriad(1, 1, 1), 1, 2, 10000, 10000, 0, "127.0.0.1", 0)
EXPLICIT = Connection(ConnectionKind.EXPLICIT, ConnectionTriad(2, 1, 1), 3, 4, 10000, 10000, 0, "127.0.0.1", 0)


def _devices(count: int) -> list[Device]:
    config = parse_config({"devices": [{"name": "io{n}", "address": "127.0.0.1", "count": count,
                                        "model": "DSQC1030"}]}, "<t>")
    return [Device(profile) for profile in build_profiles(config, shipped_catalogue())]


def _states(overview: Overview) -> dict[str, str]:
    return {device["name"]: device["state"] for device in overview.snapshot()["devices"]}


def test_the_last_class1_ending_decides_between_timed_out_and_idle() -> None:
    devices = _devices(3)
    io1, io2, io3 = devices
    overview = Overview(devices)
    assert _states(overview) == {"io1": "idle", "io2": "idle", "io3": "idle"}
    io1.record(ConnectionTimedOut(1, OWNER))
    io2.record(ConnectionTimedOut(2, EXPLICIT))  # a class-3 connection's timeout is not class 1's
    assert _states(overview) == {"io1": "timed_out", "io2": "idle", "io3": "idle"}
    io1.record(ConnectionTimedOut(3, EXPLICIT))  # nor does it clear a class-1 timeout
    io2.record(ConnectionFaulted(4, OWNER))
    io3.record(ConnectionTimedOut(5, OWNER))
    io3.record(ConnectionClosed(6, OWNER))  # a later class-1 connection closed normally
    assert _states(overview) == {"io1": "timed_out", "io2": "idle", "io3": "idle"}
    io3.faults.set(Fault("drop"), 0)
    io1.faults.set(Fault("delay", delay_ms=5), 0)  # a fault wins over a timeout
    snapshot = overview.snapshot()
    assert snapshot["counts"] == {"idle": 1, "running": 0, "timed_out": 0, "faulted": 2}
    assert [(d["name"], d["state"], d["faults"]) for d in snapshot["devices"]] == [
        ("io1", "faulted", ["delay"]), ("io2", "idle", []), ("io3", "faulted", ["drop"])]
    assert snapshot["devices"][1] == {"name": "io2", "address": "127.0.0.2", "model": "DSQC1030", "addons": [],
                                      "state": "idle", "io_connections": 0, "timeouts": 0, "faults": []}
    io1.faults.clear()
    assert _states(overview)["io1"] == "timed_out"
    overview.close()
    io1.record(ConnectionClosed(7, OWNER))  # closed: no longer observed
    assert _states(overview)["io1"] == "timed_out"


def test_recent_events_leave_out_requests_and_image_changes_and_keep_the_newest() -> None:
    (device,) = _devices(1)
    overview = Overview([device], recent=4)
    assert overview.snapshot(10)["events"] == []
    device.set_inputs(b"\x01\x00")  # an image change: not kept
    for n in range(6):
        device.record(TcpConnected(f"127.0.0.9:{n}"))
    device.record(FaultInjected({"kind": "drop"}))
    events = overview.snapshot(10)["events"]
    assert [(e["kind"], e["detail"]) for e in events] == [
        ("tcp connected", "127.0.0.9:3"), ("tcp connected", "127.0.0.9:4"), ("tcp connected", "127.0.0.9:5"),
        ("fault injected", {"kind": "drop"})]  # oldest first, as GET /events sends them
    assert events[0]["device"] == "io1" and events[0]["monotonic"] <= events[-1]["monotonic"]
    assert [e["detail"] for e in overview.snapshot(2)["events"]] == ["127.0.0.9:5", {"kind": "drop"}]
    assert overview.snapshot()["events"] == []  # none unless asked for


def test_overview_follows_a_real_scanners_connection_and_a_fault(enip_farm) -> None:
    farm = enip_farm({"devices": [{"name": "io{n}", "address": "127.0.0.1", "count": 3, "model": "DSQC1030"}]},
                     http=True)
    base = f"http://127.0.0.1:{farm.http.port}"

    def overview(**params: object) -> dict:
        answer = httpx.get(f"{base}/overview", params=params, timeout=DEADLINE_S)
        assert answer.status_code == 200, answer.text
        return answer.json()

    def states() -> dict[str, str]:
        return {device["name"]: device["state"] for device in overview()["devices"]}

    first = overview()
    assert first["counts"] == {"idle": 3, "running": 0, "timed_out": 0, "faulted": 0}
    assert [d["name"] for d in first["devices"]] == ["io1", "io2", "io3"] and first["events"] == []
    address = farm["io2"].address
    with scanner(address) as scan:
        assert scan.forward_open(20, 0) == 0
        scan.conn.produce()
        assert states() == {"io1": "idle", "io2": "running", "io3": "idle"}
        (io2,) = [d for d in overview()["devices"] if d["name"] == "io2"]
        assert (io2["io_connections"], io2["timeouts"]) == (1, 0)
        scan.conn.stopProduce()  # the scanner goes silent: the farm times the connection out (4 RPI)
        assert wait_for(lambda: states()["io2"] == "timed_out", timeout=DEADLINE_S), states()
        (io2,) = [d for d in overview()["devices"] if d["name"] == "io2"]
        assert (io2["io_connections"], io2["timeouts"]) == (0, 1)
        assert scan.forward_open(20, 2) == 0
        assert states()["io2"] == "running"
        assert scan.forward_close() == 0  # closed normally: idle, not timed out
        assert states()["io2"] == "idle"
    farm["io3"].inject("stop-io")
    snapshot = overview(events=RECENT)
    assert snapshot["counts"] == {"idle": 2, "running": 0, "timed_out": 0, "faulted": 1}
    kinds = [(e["device"], e["kind"]) for e in snapshot["events"]]
    assert kinds[-1] == ("io3", "fault injected") and snapshot["events"][-1]["detail"] == {"kind": "stop-io"}
    opened = [i for i, k in enumerate(kinds) if k == ("io2", "connection opened")]
    assert len(opened) == 2 and kinds.index(("io2", "connection timed out")) > opened[0]
    assert not any(kind in ("request", "io", "image changed") for _, kind in kinds)
    for bad in (-1, RECENT + 1):
        assert httpx.get(f"{base}/overview", params={"events": bad}).status_code == 422
