"""What the dashboard stands on: "io" events (signals by name, old and new, coalesced per device and
image each tick), GET /state, the page and its assets served without the token (and nothing else),
/docs and /redoc from assets shipped in the package, and `enip-farm io watch`. The page itself is
driven in a real browser in tests/test_dashboard_browser.py."""

from __future__ import annotations

import asyncio
import re
import signal
import socket
import subprocess
import threading
import time
from html.parser import HTMLParser

import httpx
import pytest

from enip_farm.config import parse_config
from enip_farm.control.client import ApiClient
from enip_farm.control.dashboard import WEB
from enip_farm.control.guard import public
from enip_farm.control.io_changes import IoChange, SignalDiff, coalesce
from enip_farm.control.stream import EventHub
from enip_farm.device.build import build_profiles
from enip_farm.device.catalogue import shipped_catalogue
from enip_farm.device.events import Event, FaultInjected, ImageChanged
from enip_farm.device.faults import FaultKind
from enip_farm.device.signals import SignalMap
from tests.helpers import CLI, ROOT, RawClient, read_lines, wait_for
from tests.scanners import scanner

MS = 1_000_000  # ns
S = 1_000_000_000  # ns
DEADLINE_S = 30.0  # generous: conditions end the waits as soon as they hold
NAMED = [{"name": "diGripperClosed", "type": "DI", "device_map": "3"},
         {"name": "goProgramNo", "type": "GO", "device_map": "8-15"}]


def _diff(**device: object) -> SignalDiff:
    config = parse_config({"devices": [{"name": "io", "address": "127.0.0.1", "model": "DSQC1030", **device}]}, "<t>")
    (profile,) = build_profiles(config, shipped_catalogue())
    return SignalDiff(SignalMap(profile))


def _change(device: str, role: str, old: str, new: str, at: int = 1_000_000_000) -> Event:
    return Event(at, at + 1000 * S, device, ImageChanged(role, bytes.fromhex(old), bytes.fromhex(new)))


# -- signals by name (unit) -------------------------------------------------------------------------------


def test_signal_diff_names_numbered_and_named_signals() -> None:
    diff = _diff(addons=["DSQC1032"], signals=NAMED)  # inputs: 2 bytes DI, 4 AI; outputs: 2 bytes DO, 4 AO
    assert diff.changes("input", bytes(10), bytes(10)) == {}
    assert diff.changes("input", bytes(10), bytes.fromhex("0800 b004 0000 0000 0000")) == {
        "DI4": (0, 1), "AI1": (0, 1200), "diGripperClosed": (0, 1)}
    assert diff.changes("output", bytes(10), bytes.fromhex("0005 0000 0000 0000 ffff")) == {
        "DO9": (0, 1), "DO11": (0, 1), "AO4": (0, -1), "goProgramNo": (0, 5)}
    # a byte changed under a signal whose value did not: only DI5 is named, not DI1-3 or the GI
    assert diff.changes("input", bytes.fromhex("0700") + bytes(8), bytes.fromhex("1700") + bytes(8)) == {"DI5": (0, 1)}


def test_coalesce_merges_each_devices_image_changes_into_one_io_event() -> None:
    diff = _diff(signals=NAMED)
    events = [
        _change("a", "input", "0000", "0100", 1_000 * MS),
        Event(1_100 * MS, 1_001_100 * MS, "a", FaultInjected({"kind": "drop"})),
        _change("a", "input", "0100", "0300", 1_200 * MS),
        _change("b", "input", "0000", "0100", 1_300 * MS),
        _change("a", "output", "0000", "0001", 1_400 * MS),
        _change("b", "input", "0100", "0000", 1_500 * MS),  # b's DI1 set and cleared: no change in the end
        _change("a", "input", "0300", "0200", 1_600 * MS),
    ]
    out = coalesce(events, lambda name: diff)
    assert [(e.device, e.kind) for e in out] == [("a", "fault injected"), ("a", "io"), ("a", "io")]
    output, inputs = out[1], out[2]
    assert output.detail == IoChange("output", {"DO9": (0, 1), "goProgramNo": (0, 1)}, 1)
    assert inputs.detail == IoChange("input", {"DI2": (0, 1)}, 3) and inputs.monotonic_ns == 1_600 * MS
    assert str(inputs.detail) == "input DI2 0 -> 1"
    assert inputs.detail.as_dict(inputs) == {
        "time": 1001.6, "monotonic": 1.6, "device": "a", "kind": "io", "role": "input",
        "signals": {"DI2": {"old": 0, "new": 1}}, "changes": 3, "detail": "input DI2 0 -> 1"}
    assert coalesce(events[1:2], lambda name: diff) == events[1:2]


def test_the_page_lists_no_fault_kind_of_its_own() -> None:
    """The faults panel reads the kinds from GET fault-kinds (tests/test_dashboard_modules.py checks
    the menu against the farm's list); no script names a kind."""
    for script in sorted(WEB.glob("*.js")):
        text = script.read_text()
        assert not [kind for kind in FaultKind if f"'{kind.value}'" in text or f'"{kind.value}"' in text], script.name
        assert "FAULT_KINDS" not in text and "PARAM_HINT" not in text, script.name
    assert "api('fault-kinds')" in (WEB / "faults-panel.js").read_text()


_IMPORT = re.compile(r"^import .* from '\./([\w.-]+\.js)';$", re.MULTILINE)


def test_the_scripts_are_es_modules_each_reached_from_the_entry() -> None:
    """index.html loads one module script; its relative imports reach every script of web/ and
    only those (no bundler, no module left over), without a cycle."""
    html = (WEB / "index.html").read_text()
    assert re.findall(r"<script[^>]*>", html) == ['<script type="module" src="dashboard/dashboard.js">']
    graph = {script.name: _IMPORT.findall(script.read_text()) for script in WEB.glob("*.js")}
    reached, order = set(), []

    def visit(name: str, path: tuple[str, ...]) -> None:
        assert name in graph and name not in path, (name, path)
        if name not in reached:
            reached.add(name)
            for imported in graph[name]:
                visit(imported, (*path, name))
            order.append(name)

    visit("dashboard.js", ())
    assert reached == set(graph), set(graph) - reached
    assert sorted(graph) == ["api.js", "dashboard.js", "devices.js", "dom.js", "event-log.js", "events.js",
                             "faults-panel.js", "frame.js", "histogram.js", "inspect.js", "io-panel.js", "overview.js",
                             "svg.js", "table.js", "timeline.js"]
    assert all("'use strict'" not in (WEB / name).read_text() for name in graph)  # modules are strict already


class _References(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.urls: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.urls += [value for name, value in attrs if name in ("src", "href") and value]


def _references(html: str) -> list[str]:
    parser = _References()
    parser.feed(html)
    return parser.urls


def test_the_page_is_package_data_and_names_no_other_host() -> None:
    urls = _references((WEB / "index.html").read_text())
    assert sorted(urls) == ["dashboard/dashboard.css", "dashboard/dashboard.js", "data:,", "docs"]
    for path in sorted(WEB.iterdir()):
        # SVG's namespace name (svg.js) is a name, not an address the page loads
        assert not re.search(r"https?://(?!www\.w3\.org/2000/svg')", path.read_text()), path.name
    assert '"control/web/*"' in (ROOT / "pyproject.toml").read_text()


def test_public_paths_are_the_pages_gets_only() -> None:
    def scope(path: str, method: str = "GET") -> dict:
        return {"type": "http", "method": method, "path": path}

    assert public(scope("/")) and public(scope("/dashboard/dashboard.js")) and public(scope("/", "HEAD"))
    for refused in (scope("/", "POST"), scope("/devices"), scope("/dashboard"), scope("/dashboard/../devices"),
                    scope("/docs"), scope("/openapi.json"), scope("/dashboardx/a"), scope("//dashboard/a")):
        assert not public(refused), refused


# -- the HTTP API (integration) ----------------------------------------------------------------------------


def _stream_lines(base: str, params: dict, count: int, act) -> list[dict]:
    """`count` data events of GET /events, `act()` called once the stream is open."""
    received: list[dict] = []
    with ApiClient(base, timeout=DEADLINE_S) as client, client.events(params, DEADLINE_S) as events:
        act()  # the stream is open (subscribed) once its headers are in
        for event in events:
            received.append(event.json())
            if len(received) == count:
                break
    return received


def test_io_events_name_the_changed_signals(enip_farm) -> None:
    farm = enip_farm(name="io", model="DSQC1030", signals=NAMED, http=True)
    base, io = f"http://127.0.0.1:{farm.http.port}", farm["io"]

    def act() -> None:
        io.set(DI3=1)
        time.sleep(0.1)  # another tick
        io.set(goProgramNo=5)

    first, second = _stream_lines(base, {"kind": "io"}, 2, act)
    assert first["device"] == "io" and first["role"] == "input" and first["changes"] == 1
    assert first["signals"] == {"DI3": {"old": 0, "new": 1}} and first["detail"] == "input DI3 0 -> 1"
    assert second["role"] == "output" and second["signals"] == {
        "DO9": {"old": 0, "new": 1}, "DO11": {"old": 0, "new": 1}, "goProgramNo": {"old": 0, "new": 5}}
    assert first["monotonic"] < second["monotonic"] <= time.monotonic()
    # excluded kinds stay out: a request event between two I/O changes is not sent
    (event,) = _stream_lines(base, {"exclude_kind": ["request", "fault injected"]}, 1,
                             lambda: (io.inject("drop", duration_s=5), io.clear_faults(), io.set(DI3=0)))
    assert event["kind"] == "fault cleared"


def test_a_1khz_change_rate_is_coalesced_to_one_event_per_tick(enip_farm) -> None:
    farm = enip_farm(name="io", model="DSQC1030", http=True)
    base, io, hub = f"http://127.0.0.1:{farm.http.port}", farm["io"], farm.http.hub
    changes = 1000
    received: list[dict] = []
    with ApiClient(base, timeout=DEADLINE_S) as client, client.events({"kind": "io"}, DEADLINE_S) as events:
        started = time.monotonic()
        for i in range(changes):  # about 1 kHz: DI1 toggles, DI2 follows every tenth change
            io.set({"DI1": (i + 1) % 2, "DI2": (i // 10 + 1) % 2})
            time.sleep(0.001)
        elapsed = time.monotonic() - started
        io.set(DI16=1)  # the end marker
        for event in events:
            received.append(event.json())
            if "DI16" in received[-1]["signals"]:
                break
    # coalesced: call_later(tick_s) after each tick, so no more events than ticks went by, however
    # fast the changes came (about 1 kHz, 20 a tick: the bound holds whatever time.sleep really slept)
    ticks = (time.monotonic() - started) / hub.tick_s + 2
    assert 2 <= len(received) <= ticks, (len(received), ticks, elapsed)
    assert sum(e["changes"] for e in received) <= changes + 1
    state = {"DI1": 0, "DI2": 0, "DI16": 0}
    for event in received:  # replayed from the start, the events reach the device's state
        for name, change in event["signals"].items():
            assert state[name] == change["old"], (name, event)
            state[name] = change["new"]
    assert [state["DI1"], state["DI2"], state["DI16"]] == [*io.get("DI1-2"), 1]


def test_state_tells_what_is_open_apart_from_the_totals(enip_farm) -> None:
    """Issue 30: "TCP 7 · sessions 7" were totals since start, shown beside "0 connections"; the
    state says what is open now too (`open`), and the totals stay totals."""
    farm = enip_farm(name="io", model="DSQC1030", http=True)
    base, address = f"http://127.0.0.1:{farm.http.port}", farm["io"].address

    def state() -> dict:
        (one,) = httpx.get(f"{base}/state", params={"device": "io"}).json()
        return {"open": one["open"], "tcp": one["counters"]["tcp_connections"], "sessions": one["counters"]["sessions"]}

    clients = [RawClient(address) for _ in range(3)]
    try:
        for client in clients[:2]:
            client.register()
        assert wait_for(lambda: state() == {"open": {"tcp": 3, "sessions": 2}, "tcp": 3, "sessions": 2})
    finally:
        for client in clients:
            client.close()
    assert wait_for(lambda: state() == {"open": {"tcp": 0, "sessions": 0}, "tcp": 3, "sessions": 2}), state()


def test_state_shows_signals_connections_counters_and_faults(enip_farm) -> None:
    farm = enip_farm(name="io", model="DSQC1030", signals=NAMED, implicit={"first_watchdog_s": 0}, http=True)
    base, io = f"http://127.0.0.1:{farm.http.port}", farm["io"]
    io.set(DI4=1, goProgramNo=7)  # diGripperClosed is bit 3: DI4
    before = time.monotonic()
    (state,) = httpx.get(f"{base}/state").json()
    assert before <= state["monotonic"] <= time.monotonic()
    assert state["signals"] == io.signal_table()
    values = {s["name"]: s["value"] for s in state["signals"]}
    assert values["DI4"] == values["diGripperClosed"] == 1 and values["goProgramNo"] == 7
    assert [s["name"] for s in state["signals"]][:3] == ["DI1", "DI2", "DI3"]
    assert (state["status"], state["owners"], state["connections"], state["faults"]) == (0x0030, [], [], [])
    assert state["counters"] == {"o_t_packets": 0, "t_o_packets": 0, "connection_timeouts": 0,
                                 "tcp_connections": 0, "sessions": 0}
    assert state["open"] == {"tcp": 0, "sessions": 0}
    with scanner(io.address, forward_close=True) as scan:  # a real scanner's class-1 connection
        assert scan.forward_open(10, 2) == 0
        scan.conn.produce()
        assert wait_for(lambda: farm.devices["io"].counters["o_t_packets"] >= 3, timeout=DEADLINE_S), "O->T packets"
        io.inject("status", service=0x0E, status=0x08)
        (state,) = httpx.get(f"{base}/state", params={"device": "io"}).json()
        (connection,) = state["connections"]
        assert connection["kind"] == "exclusive owner" and connection["o_t_rpi_us"] == 10_000
        assert state["owners"] == ["127.0.0.1"] and connection["received"] >= 3
        assert state["status"] == 0x0061 and state["counters"]["o_t_packets"] >= 3
        assert state["counters"]["tcp_connections"] == state["counters"]["sessions"] == 1
        assert [f["kind"] for f in state["faults"]] == ["status"] and state["faults"][0]["status"] == 8
    assert httpx.get(f"{base}/state", params={"device": ["io", "nobody"]}).status_code == 404


@pytest.mark.integration
def test_the_page_passes_the_guard_without_a_token_and_nothing_else_does(free_address) -> None:
    from enip_farm.farm.farm import Farm

    config = parse_config({"devices": [{"name": "io", "address": free_address(), "model": "DSQC1030"}],
                           "discovery": False})
    farm = Farm(config, http=("127.0.0.1", 0), token="s3cret")
    with farm.running_in_thread():
        base = f"http://127.0.0.1:{farm.http.port}"
        page = httpx.get(base + "/")
        assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
        assert page.text == (WEB / "index.html").read_text()
        scripts = sorted(path.name for path in WEB.glob("*.js"))
        assert len(scripts) == 15
        for name, kind in (*((name, "text/javascript; charset=utf-8") for name in scripts),
                           ("dashboard.css", "text/css; charset=utf-8")):
            asset = httpx.get(f"{base}/dashboard/{name}")
            assert asset.status_code == 200 and asset.headers["content-type"] == kind, name
            assert asset.text == (WEB / name).read_text()
        assert httpx.get(base + "/dashboard/nothing.js").status_code == 404
        for path in ("/devices", "/state", "/overview", "/events", "/docs", "/openapi.json",
                     "/static-offline-docs/swagger-ui.css"):
            assert httpx.get(base + path).status_code == 401, path
        assert httpx.post(base + "/").status_code == 401
        # the Host check holds for the page too (a rebinding page cannot load it)
        assert httpx.get(base + "/", headers={"Host": "rebound.example"}).status_code == 421
        raw = socket.create_connection(("127.0.0.1", farm.http.port), timeout=DEADLINE_S)
        with raw:  # a path that climbs out of the assets is not public, whatever serves it
            raw.sendall(b"GET /dashboard/../devices HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n")
            assert raw.recv(4096).startswith(b"HTTP/1.1 401 ")
        auth = {"Authorization": "Bearer s3cret"}
        assert httpx.get(base + "/state", headers=auth).json()[0]["name"] == "io"


def test_docs_load_nothing_from_another_host(enip_farm) -> None:
    farm = enip_farm(name="io", model="DSQC1030", http=True)
    base = f"http://127.0.0.1:{farm.http.port}"
    for page, assets in (("/docs", {"swagger-ui-bundle.js": "javascript", "swagger-ui.css": "text/css"}),
                         ("/redoc", {"redoc.standalone.js": "javascript"})):
        html = httpx.get(base + page)
        assert html.status_code == 200
        urls = _references(html.text) + re.findall(r"""url: ['"]([^'"]+)""", html.text)
        assert urls and all(url.startswith("/") and not url.startswith("//") for url in urls), urls
        assert not re.search(r"https?://", html.text), html.text
        served = {url.rsplit("/", 1)[1]: url for url in urls}
        for name, kind in assets.items():
            asset = httpx.get(base + served[name])
            assert asset.status_code == 200 and kind in asset.headers["content-type"], name
            assert len(asset.content) > 100_000, name  # the library itself, not a stub
    assert "/devices/{name}/io" in httpx.get(base + "/openapi.json").json()["paths"]


# -- io watch (system) ---------------------------------------------------------------------------------------


@pytest.mark.system
def test_io_watch_streams_changes_and_ends_on_ctrl_c(enip_farm) -> None:
    farm = enip_farm(name="io", model="DSQC1030", signals=NAMED, http=True)
    io, hub = farm["io"], farm.http.hub
    watch = subprocess.Popen([*CLI, "io", "watch", "io", "--api", f"http://127.0.0.1:{farm.http.port}"],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert wait_for(lambda: hub.subscribers, timeout=DEADLINE_S), "io watch subscribed"
        io.set(DI4=1)
        first = read_lines(watch.stdout, 1, DEADLINE_S)
        io.set(goProgramNo=5)
        second = read_lines(watch.stdout, 1, DEADLINE_S)
        toggler = threading.Thread(target=lambda: [io.set(DI1=i % 2) for i in range(1, 201)])
        toggler.start()
        toggler.join()
        watch.send_signal(signal.SIGINT)
        rest, errors = watch.communicate(timeout=DEADLINE_S)
    finally:
        if watch.poll() is None:
            watch.kill()
    assert re.fullmatch(r"\d\d:\d\d:\d\d\.\d{3} io input DI4 0 -> 1, diGripperClosed 0 -> 1\n", first[0]), first
    assert second[0].endswith(" io output DO9 0 -> 1, DO11 0 -> 1, goProgramNo 0 -> 5\n"), second
    assert watch.returncode == 0 and errors == ""  # Ctrl-C: no traceback
    assert all(" io input DI1 " in line for line in rest.splitlines())  # only io events, only this device


@pytest.mark.system
def test_io_watch_says_what_went_wrong(enip_farm) -> None:
    farm = enip_farm(name="io", model="DSQC1030", http=True)
    api = f"http://127.0.0.1:{farm.http.port}"
    unknown = subprocess.run([*CLI, "io", "watch", "nobody", "--api", api], capture_output=True, text=True,
                             timeout=DEADLINE_S)
    assert unknown.returncode == 1 and unknown.stderr == "GET /events: 404 no device named 'nobody'; known: io\n"
    with socket.socket() as closed:
        closed.bind(("127.0.0.1", 0))
        port = closed.getsockname()[1]
    refused = subprocess.run([*CLI, "io", "watch", "io", "--api", f"http://127.0.0.1:{port}"], capture_output=True,
                             text=True, timeout=DEADLINE_S)
    assert (refused.returncode, refused.stderr) == (1, (  # the words of every client command (cli/api.py)
        f"cannot reach the farm's HTTP API at http://127.0.0.1:{port} (Connection refused): is the farm running with "
        f"its HTTP API? Start it with `enip-farm serve --http {port}`, or give the API's address with --api (or "
        "ENIP_FARM_API).\n"))


@pytest.mark.system
def test_io_watch_ends_when_the_farm_stops(free_address) -> None:
    from enip_farm.farm.farm import Farm

    config = parse_config({"devices": [{"name": "io", "address": free_address(), "model": "DSQC1030"}],
                           "discovery": False})
    farm = Farm(config, http=("127.0.0.1", 0))
    with farm.running_in_thread():
        watch = subprocess.Popen([*CLI, "io", "watch", "io", "--api", f"http://127.0.0.1:{farm.http.port}"],
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        assert wait_for(lambda: farm.http.hub.subscribers or watch.poll() is not None,
                        timeout=DEADLINE_S), "io watch subscribed"
    try:
        out, errors = watch.communicate(timeout=DEADLINE_S)
    finally:
        if watch.poll() is None:
            watch.kill()
    assert (watch.returncode, out, errors) == (1, "", "the farm ended the event stream\n")


def test_io_of_devices_nobody_watches_is_not_named(make_farm) -> None:
    farm = make_farm({"name": "a", "model": "DSQC1030"}, {"name": "b", "model": "DSQC1030"})

    async def watch_a() -> tuple[list, set]:
        hub = EventHub(farm.devices.values())  # as `io watch a` subscribes
        subscriber = hub.subscribe(["a"], ["io"])
        farm["b"].set(DI1=1)
        farm["a"].set(DI2=1)
        while not subscriber.queue:
            await asyncio.sleep(hub.tick_s)
        hub.unsubscribe(subscriber)
        return [item.event for item in subscriber.queue], set(hub._diffs)

    events, diffed = asyncio.run(watch_a())
    assert [(e.device, e.kind, str(e.detail)) for e in events] == [("a", "io", "input DI2 0 -> 1")]
    assert diffed == {"a"}  # b's change was dropped before its signals were named
