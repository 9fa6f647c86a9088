"""The fleet's two HTTP routers are one core (enip_farm/fleet/router.py) with one difference, how the
farms are found and what a part is called: the workers' (`serve --workers N --http`: their ports)
and the shards' (`enip-farm fleet-api`: DNS). Each is held to the same answers with one upstream
down: two real farms on 127.x with their HTTP APIs, and a port of 127.0.0.1 where nothing listens
for the part between them. The down part is listed as down, exactly; the others are served."""

from __future__ import annotations

import socket
from collections.abc import Iterator
from typing import Any

import httpx
import pytest
from prometheus_client.parser import text_string_to_metric_families

from enip_farm.config import parse_config
from enip_farm.fleet.api import create_worker_router, router_port, serving_router
from enip_farm.fleet.shard_api import create_shard_router, static_discovery
from enip_farm.fleet.slices import split
from tests.helpers import STARTUP_S

pytestmark = pytest.mark.integration

CELL = {"devices": [{"name": f"io{n}", "model": "DSQC1030", "address": f"127.0.0.{n}"} for n in range(1, 7)],
        "discovery": False}


def _closed_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@pytest.fixture(params=["worker", "shard"])
def fleet(request: pytest.FixtureRequest, enip_farm) -> Iterator[tuple[str, httpx.Client, list, list[str], str]]:
    """(label, a client of the router, the farms of parts 1 and 3, their URLs, part 2's dead URL)."""
    config = parse_config(CELL, "cell")
    slices = split(config, 3)
    assert [[d.name for d in part.devices] for part in slices] == [["io1", "io4"], ["io2", "io5"], ["io3", "io6"]]
    farms = [enip_farm(slices[i].model_dump(mode="json", by_alias=True), http=True) for i in (0, 2)]
    urls = [f"http://127.0.0.1:{farm.http.port}" for farm in farms]
    dead = f"http://127.0.0.1:{_closed_port()}"  # part 2: nothing listens there
    if request.param == "worker":
        router = create_worker_router(config, slices, [urls[0], dead, urls[1]], None)
    else:  # discovery finds them in any order
        router = create_shard_router(config, 3, static_discovery([urls[1], dead, urls[0]]), None)
    with serving_router(router, "127.0.0.1", 0, None) as server, \
            httpx.Client(base_url=f"http://127.0.0.1:{router_port(server)}", timeout=STARTUP_S) as api:
        yield request.param, api, farms, urls, dead


def _down_device(name: str, label: str) -> dict[str, Any]:
    return {"name": name, "address": f"127.0.0.{name[2:]}", "model": "DSQC1030", "addons": [], "identity": {},
            "input_size": 0, "output_size": 0, "connections": [], "faults": [], "unverified": [],
            label: 2, f"{label}_up": False}


def test_the_parts_and_the_devices_say_which_part_is_down(fleet) -> None:
    label, api, _, urls, _ = fleet
    assert api.get(f"/{label}s").json() == [
        {label: 1, "up": True, "endpoint": urls[0], "devices": ["io1", "io4"]},
        {label: 2, "up": False, "endpoint": None, "devices": ["io2", "io5"]},
        {label: 3, "up": True, "endpoint": urls[1], "devices": ["io3", "io6"]}]
    (io1, io4), (io3, io6) = (httpx.get(f"{url}/devices", timeout=STARTUP_S).json() for url in urls)
    assert api.get("/devices").json() == [
        {**io1, label: 1, f"{label}_up": True}, _down_device("io2", label), {**io3, label: 3, f"{label}_up": True},
        {**io4, label: 1, f"{label}_up": True}, _down_device("io5", label), {**io6, label: 3, f"{label}_up": True}]


def test_a_request_for_a_down_parts_device_gets_503_and_the_others_are_served(fleet) -> None:
    label, api, farms, _, _ = fleet
    refused = api.put("/devices/io5/io", json={"signals": {"DI3": 1}})
    assert (refused.status_code, refused.json()) == (503, {"detail": f"{label} 2/3 (devices io2..io5) is down"})
    written = api.put("/devices/io6/io", json={"signals": {"DI3": 1}})
    assert written.status_code == 200 and written.json()["inputs"] == "0400"
    assert farms[1]["io6"].get("DI3") == 1 and farms[0]["io1"].get("DI3") == 0
    assert api.get("/devices/io6/io/DI3").json() == {"name": "DI3", "type": "DI", "role": "input", "value": 1}
    assert api.get("/devices/io9").json() == {"detail": "no device named 'io9'; known: io1, io2, io3, io4, io5, io6"}


def test_state_metrics_and_health_merge_the_parts_that_answer(fleet) -> None:
    label, api, _, _, dead = fleet
    state = api.get("/state", params={"device": ["io5", "io4"]})
    assert state.status_code == 200
    (down, up) = state.json()
    assert down == {"name": "io5", "monotonic": 0.0, "signals": [], "status": 0, "owners": [], "connections": [],
                    "counters": {}, "faults": [], label: 2, f"{label}_up": False}
    assert (up["name"], up[label], up[f"{label}_up"], up["connections"]) == ("io4", 1, True, [])
    assert [(d["name"], d[f"{label}_up"]) for d in api.get("/state").json()] == [
        ("io1", True), ("io2", False), ("io3", True), ("io4", True), ("io5", False), ("io6", True)]
    families = {family.name: family for family in text_string_to_metric_families(api.get("/metrics").text)}
    assert {s.labels[label]: s.value for s in families[f"enip_farm_{label}_up"].samples} == {
        "1": 1.0, "2": 0.0, "3": 1.0}
    connections = {(s.labels["device"], s.labels[label]) for s in families["enip_farm_tcp_connections"].samples}
    assert connections == {("io1", "1"), ("io4", "1"), ("io3", "3"), ("io6", "3")}
    health = api.get("/health")
    assert health.status_code == 503
    parts = health.json()[f"{label}s"]
    assert health.json()["ok"] is False and [part["ok"] for part in parts] == [True, False, True]
    assert parts[1] == {label: 2, f"{label}_up": False, "ok": False,
                        "failure": f"{label} 2/3 (devices io2..io5) is down"}
    assert dead not in str(parts)


def test_the_overview_merges_every_parts_devices_and_events(fleet) -> None:
    """GET /overview through the router (the dashboard's one read of the plant): every part's
    devices in configuration order, a down part's faulted by its being down, the counts of them
    all, and the recent events of every part that answers, oldest first."""
    label, api, farms, urls, _ = fleet
    farms[1]["io6"].inject("drop")  # part 3
    farms[0]["io1"].inject("delay", delay_ms=1)  # part 1, later
    overview = api.get("/overview", params={"events": 10}).json()
    own = [httpx.get(f"{url}/overview", params={"events": 10}, timeout=STARTUP_S).json() for url in urls]
    (io1, io4), (io3, io6) = (part["devices"] for part in own)
    down = [{"name": name, "address": f"127.0.0.{name[2:]}", "model": "DSQC1030", "addons": [], "state": "faulted",
             "io_connections": 0, "timeouts": 0, "faults": [f"{label} down"], label: 2, f"{label}_up": False}
            for name in ("io2", "io5")]
    marks = {1: {label: 1, f"{label}_up": True}, 3: {label: 3, f"{label}_up": True}}
    assert overview["devices"] == [{**io1, **marks[1]}, down[0], {**io3, **marks[3]}, {**io4, **marks[1]}, down[1],
                                   {**io6, **marks[3]}]
    assert (io1["state"], io6["state"], io3["state"]) == ("faulted", "faulted", "idle")
    assert overview["counts"] == {"idle": 2, "running": 0, "timed_out": 0, "faulted": 4}
    assert [(e["device"], e["kind"]) for e in overview["events"]] == [
        ("io6", "fault injected"), ("io1", "fault injected")]
    assert overview["events"] == own[1]["events"] + own[0]["events"]
    assert api.get("/overview").json()["events"] == []
    assert api.get("/overview", params={"events": -1}).status_code == 422  # the farms' own check
