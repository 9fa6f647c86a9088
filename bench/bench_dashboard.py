"""The dashboard in headless Chromium: how soon a CIP write shows on the page, and how the page
copes with many devices and a busy event stream.

A farm runs in a subprocess with its HTTP API on 127.0.0.1 (and, on request, a thread that toggles
one input of its devices round-robin at `--load-hz` changes a second through the Python API, as a
simulated sensor would). This process drives Debian's chromium through chromedriver (Selenium)
and writes outputs over CIP with pycomm3 (Set Attribute Single, assembly 100, attribute 3).

  1. latency: one device; `--changes` writes, each to a new DO bit. A MutationObserver in the page
     stamps the LED's change with performance.timeOrigin + performance.now() (the wall clock this
     process reads with time.time()); latency = that stamp - the moment pycomm3 returned the reply.
     Writes are spaced by a random 0-40 ms, so they land at every phase of the stream's 20 ms tick.
  2. `--devices` devices (DSQC1030 + DSQC1032 each): time from navigation to the first cards with
     their signals, a filter's round trip (set the text, two animation frames later), the number
     of cards in the DOM, and the longest gap between animation frames while loading; then, for
     each rate of `--load-hz`, the latency of `--load-changes` writes to the first device and the
     longest frame gap while that many inputs change.
  3. the overview of `--devices` DSQC1030s (overview.js): `--overview-loads` page loads, each timed in
     the page from navigation to every device's tile and the counts shown; then `--faults` faults
     injected through the API on devices picked at random, each timed from the API's reply to its
     tile's change of colour (stamped by a MutationObserver in the page), and the longest frame gap.
  4. the same while `--connections` class-1 connections run at `--rpi-ms` (bench/bench_implicit.py's
     originator in another process, one exclusive owner per device, for 90 s once all are open):
     how long until the overview counts them all running, then the same page loads (and the counts
     the page shows) and faults, the farm's own counts after them, and what the originator saw
     (T->O received, lost, late, the period error, the farm's CPU; its `timeouts` counts the
     Forward Closes it sends one by one at the end that found their connection gone).

    python bench/bench_dashboard.py [--changes 200] [--devices 1000] [--load-hz 0,2000,10000]
                                    [--connections 1000] [--rpi-ms 250] [--overview-only]

Every wait is bounded; traffic goes to 127.0.0.0/8 only. Prints a line per phase and a JSON line.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import statistics
import subprocess
import sys
import time
from pathlib import Path

from pycomm3 import CIPDriver, Services

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import httpx  # noqa: E402

from tests.browser import (  # noqa: E402
    FILTER_ROUND_TRIP,
    MEASURE_FRAMES,
    OVERVIEW_COMPLETE,
    RECORD_CHANGES,
    RECORD_TILES,
    chromium,
    open_page,
    until,
)

FARM = """
import sys, threading, time
from enip_farm.config import parse_config
from enip_farm.farm.farm import Farm
first, count, addons = sys.argv[1], int(sys.argv[2]), sys.argv[3:]
device = {"name": "io{n}", "address": first, "model": "DSQC1030", "addons": addons}
if count > 1:
    device.update(count=count, netmask="255.255.0.0")
farm = Farm(parse_config({"devices": [device], "discovery": False}, "<bench>"), http=("127.0.0.1", 0))
rate, done = [0.0], [0]
def load():
    handles, i, due = list(farm.handles.values()), 0, time.monotonic()
    while True:
        hz = rate[0]
        if not hz:
            time.sleep(0.05)
            due = time.monotonic()
            continue
        handle = handles[1 + i % (len(handles) - 1)] if len(handles) > 1 else handles[0]  # not io1: it is measured
        handle.set(DI16=(i // len(handles)) % 2)
        i += 1
        done[0] += 1
        due += 1 / hz
        pause = due - time.monotonic()
        if pause > 0:
            time.sleep(pause)
with farm.running_in_thread():
    threading.Thread(target=load, daemon=True).start()
    print(farm.http.port, flush=True)
    since = time.monotonic()
    for line in sys.stdin:  # "RATE": changes a second from now on, answered with the rate reached since the last
        now = time.monotonic()
        print(done[0] / (now - since), flush=True)
        done[0], since, rate[0] = 0, now, float(line)
"""


# bench/bench_implicit.py's originator: argv = farm pid, RPI in us, seconds, then the devices' addresses.
ORIGINATOR = """
import json, sys
sys.path.insert(0, "bench")
from bench_implicit import run_load
pid, rpi_us, seconds, hosts = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3]), sys.argv[4:]
print(json.dumps(run_load(hosts, rpi_us, seconds, pid)), flush=True)
"""


class FarmProcess:
    def __init__(self, first: str, count: int, addons: tuple[str, ...] = ()) -> None:
        env = {**os.environ, "PYTHONPATH": str(ROOT)}
        self.process = subprocess.Popen([sys.executable, "-c", FARM, first, str(count), *addons], stdin=subprocess.PIPE,
                                        stdout=subprocess.PIPE, text=True, env=env, cwd=ROOT)
        self.url = f"http://127.0.0.1:{int(self.process.stdout.readline())}/"  # type: ignore[union-attr]
        self.first = first

    def load(self, rate: float) -> float:
        """Change inputs at `rate` a second from now on; the rate reached since the last call."""
        self.process.stdin.write(f"{rate}\n")  # type: ignore[union-attr]
        self.process.stdin.flush()  # type: ignore[union-attr]
        return float(self.process.stdout.readline())  # type: ignore[union-attr]

    def close(self) -> None:
        self.process.stdin.close()  # type: ignore[union-attr]
        try:
            self.process.wait(timeout=60)
        except subprocess.TimeoutExpired:
            self.process.kill()


def latencies(driver, address: str, changes: int, size: int, seed: int = 13) -> list[float]:
    """`size`: the output image's bytes (2 for a DSQC1030, 10 with a DSQC1032)."""
    driver.execute_script(RECORD_CHANGES)
    rng = random.Random(seed)
    out = []
    with CIPDriver(address) as client:
        for i in range(changes):
            bit = i % 16
            reply = client.generic_message(service=Services.set_attribute_single, class_code=4, instance=100,
                                           attribute=3, request_data=(1 << bit).to_bytes(size, "little"),
                                           connected=False, route_path=False)
            replied = time.time()
            if reply.error:
                raise RuntimeError(f"the write was refused: {reply.error}")
            shown = until(lambda bit=bit: driver.execute_script(
                "const hit = window.seen.find(s => s[0] === 'io1' && s[1] === arguments[0] && s[2] === 1);"
                "return hit ? hit[3] / 1000 : null;", f"DO{bit + 1}"), f"DO{bit + 1} on the page")
            out.append(shown - replied)
            time.sleep(rng.uniform(0.0, 0.04))
            driver.execute_script("window.seen = [];")
    return sorted(out)


def overview_loads(driver, url: str, devices: int, loads: int) -> dict:
    """Page loads until the overview is complete (tests/browser.py OVERVIEW_COMPLETE, the page's clock
    from navigation), and when its first answer arrived; medians and the worst."""
    complete, answered, slow = [], [], []
    for _ in range(loads):
        driver.get("about:blank")
        driver.get_log("browser")
        driver.get(url)
        try:
            complete.append(until(lambda: driver.execute_script("return window.overviewComplete"), "the overview",
                                  timeout=60))
        except AssertionError:  # counted, and the next load tried
            complete.append(float("inf"))
        if complete[-1] > 2000:  # say why
            requests = driver.execute_script(
                "return performance.getEntriesByType('resource').map(e => [e.name.replace(/^.*\\//, ''),"
                " Math.round(e.startTime), Math.round(e.responseEnd)])")
            page = driver.execute_script("const n = performance.getEntriesByType('navigation')[0];"
                                         "return n && [n.connectStart, n.requestStart, n.responseStart, n.responseEnd]"
                                         ".map(Math.round)")
            slow.append({"ms": round(complete[-1]) if complete[-1] < float("inf") else "not within 60 s",
                         "browser": network_changed(driver), "page": page, "requests": requests})
            if complete[-1] == float("inf"):
                continue
        answered.append(driver.execute_script(
            "return performance.getEntriesByType('resource').filter(e => /\\/overview(\\?|$)/.test(e.name))"
            "[0].responseEnd"))
        tiles = driver.execute_script("return document.querySelectorAll('#tiles .tile').length")
        if tiles != devices:
            raise RuntimeError(f"{tiles} tiles for {devices} devices")
    done = [ms for ms in complete if ms < float("inf")]
    p50 = statistics.median(complete)  # a load not complete in 60 s counts as the slowest
    return {"loads": loads, "complete_p50_ms": round(p50) if p50 < float("inf") else None,
            "complete_max_ms": round(max(done)) if done else None, "not_complete_in_60_s": loads - len(done),
            "first_answer_p50_ms": round(statistics.median(answered)) if answered else None,
            "slow_loads": slow}


def network_changed(driver) -> str:
    """What the browser said of its requests: Chromium fails (after holding them for up to 30 s) the
    requests under way when the host's network interfaces change, e.g. while containers start."""
    failed = [entry["message"] for entry in driver.get_log("browser") if "ERR_NETWORK_CHANGED" in entry["message"]]
    return (f"{len(failed)} requests failed with ERR_NETWORK_CHANGED (the host's interfaces changed)" if failed
            else "no request failed")


def page_counts(driver) -> dict[str, int]:
    return dict(driver.execute_script("return [...document.querySelectorAll('#counts [data-state]')]"
                                      ".map(b => [b.dataset.state, Number(b.querySelector('b').textContent)])"))


def recolours(driver, api: str, names: list[str], faults: int, seed: int = 7) -> dict:
    """`faults` faults injected (POST /devices/{name}/faults) on devices picked at random, each timed
    from the API's reply to its tile turning `faulted` in the page, then cleared (and its tile seen
    back) before the next; the longest frame gap meanwhile."""
    rng = random.Random(seed)
    driver.execute_script(RECORD_TILES)
    driver.execute_script("window.frameGaps.max = 0")
    out = []
    with httpx.Client(base_url=api, timeout=30) as client:
        for _ in range(faults):
            name = rng.choice(names)
            driver.execute_script("window.tileChanges = []")
            client.post(f"/devices/{name}/faults", json={"kind": "drop"}).raise_for_status()
            replied = time.time()
            shown = until(lambda name=name: driver.execute_script(
                "const hit = window.tileChanges.find(c => c[0] === arguments[0] && /\\bs-faulted\\b/.test(c[1]));"
                "return hit ? hit[2] / 1000 : null;", name),
                lambda name=name: f"{name}'s tile faulted; {network_changed(driver)}")
            out.append(shown - replied)
            client.delete(f"/devices/{name}/faults").raise_for_status()
            until(lambda name=name: driver.execute_script(
                "return !document.querySelector(`#tiles [data-device='${arguments[0]}']`).classList"
                ".contains('s-faulted')", name), lambda name=name: f"{name}'s tile back; {network_changed(driver)}")
    timed = summary(sorted(out))
    timed["longest_frame_gap_ms"] = round(driver.execute_script("return window.frameGaps.max"))
    return timed


def summary(values: list[float]) -> dict:
    ms = [v * 1000 for v in values]
    return {"n": len(ms), "p50_ms": round(statistics.median(ms), 1), "p95_ms": round(ms[int(0.95 * len(ms)) - 1], 1),
            "max_ms": round(ms[-1], 1), "within_200_ms": sum(v <= 200 for v in ms)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--changes", type=int, default=200, help="CIP writes timed on a one-device page")
    parser.add_argument("--devices", type=int, default=1000)
    parser.add_argument("--load-hz", default="0,2000,10000", help="input changes a second across the devices")
    parser.add_argument("--load-changes", type=int, default=50, help="CIP writes timed at each load")
    parser.add_argument("--first", default="127.0.205.1", help="the first device's address")
    parser.add_argument("--overview-loads", type=int, default=5, help="page loads timed to the overview complete")
    parser.add_argument("--faults", type=int, default=20, help="faults injected, each timed to its tile")
    parser.add_argument("--connections", type=int, default=1000, help="class-1 connections in phase 4 (0: none)")
    parser.add_argument("--rpi-ms", type=int, default=250, help="their RPI (250: what this Python originator keeps)")
    parser.add_argument("--overview-only", action="store_true", help="phases 3 and 4 only")
    args = parser.parse_args()
    result: dict = {}
    with chromium() as driver:
        driver.execute_cdp_cmd("Page.addScriptToEvaluateOnNewDocument", {"source": MEASURE_FRAMES})
        if not args.overview_only:
            cards(driver, args, result)
        farm = FarmProcess(args.first, args.devices)  # DSQC1030s, as the originator opens them
        try:
            overview(driver, farm, args, result)
        finally:
            farm.close()
    print(json.dumps(result))


def cards(driver, args: argparse.Namespace, result: dict) -> None:
    """Phases 1 and 2: the cards."""
    farm = FarmProcess(args.first, 1)
    try:
        open_page(driver, farm.url)
        result["one_device"] = summary(latencies(driver, args.first, args.changes, 2))
    finally:
        farm.close()
    print(f"1 device, CIP write reply -> LED: {result['one_device']}")
    farm = FarmProcess(args.first, args.devices, ("DSQC1032",))
    try:
        loaded = open_page(driver, farm.url)
        filtered = driver.execute_async_script(FILTER_ROUND_TRIP, "io99")
        cleared = driver.execute_async_script(FILTER_ROUND_TRIP, "")
        many = result["many_devices"] = {
            "devices": args.devices, "page_with_cards_s": round(loaded, 2), "filter_ms": round(filtered["ms"]),
            "unfilter_ms": round(cleared["ms"]), "cards_in_dom": cleared["cards"],
            "longest_frame_gap_ms": round(driver.execute_script("return window.frameGaps.max"))}
        print(f"{args.devices} devices: {many}")
        for rate in [float(r) for r in args.load_hz.split(",")]:
            farm.load(rate)
            time.sleep(1.0)
            farm.load(rate)  # the count starts here
            driver.execute_script("window.frameGaps.max = 0")
            timed = summary(latencies(driver, args.first, args.load_changes, 10))
            timed["longest_frame_gap_ms"] = round(driver.execute_script("return window.frameGaps.max"))
            timed["load_hz"] = rate
            timed["reached_hz"] = round(farm.load(rate))  # same rate on: only the count is read
            result.setdefault("under_load", []).append(timed)
            print(f"{args.devices} devices, {rate:g} input changes/s asked, {timed['reached_hz']} reached: {timed}")
        farm.load(0)
    finally:
        farm.close()

def overview(driver, farm: FarmProcess, args: argparse.Namespace, result: dict) -> None:
    """Phases 3 and 4: the overview idle, then while class-1 connections run."""
    driver.execute_cdp_cmd("Page.addScriptToEvaluateOnNewDocument", {"source": OVERVIEW_COMPLETE % args.devices})
    api = farm.url.rstrip("/")
    devices = httpx.get(api + "/devices", timeout=30).json()
    names = [device["name"] for device in devices]
    idle = result["overview"] = overview_loads(driver, farm.url, args.devices, args.overview_loads)
    idle.update(recolours(driver, api, names, args.faults))
    print(f"{args.devices} devices, overview: {idle}")
    if not args.connections:
        return
    hosts = [device["address"] for device in devices[:args.connections]]
    seconds = 90.0  # after every connection is open: the measures below take 20 to 60 s of it
    originator = subprocess.Popen([sys.executable, "-c", ORIGINATOR, str(farm.process.pid), str(args.rpi_ms * 1000),
                                   str(seconds), *hosts], stdout=subprocess.PIPE, text=True, cwd=ROOT,
                                  env={**os.environ, "PYTHONPATH": str(ROOT)})
    try:
        started = time.monotonic()
        with httpx.Client(base_url=api, timeout=30) as client:
            def all_running() -> bool:
                if originator.poll() is not None:
                    raise RuntimeError("the originator ended before its connections ran")
                return client.get("/overview").json()["counts"]["running"] >= args.connections

            until(all_running, f"{args.connections} connections running", timeout=300, step=0.1)
        opened = time.monotonic() - started
        busy = result["overview_with_connections"] = {"connections": args.connections, "rpi_ms": args.rpi_ms,
                                                      "all_running_after_s": round(opened, 1)}
        busy.update(overview_loads(driver, farm.url, args.devices, args.overview_loads))
        busy["page_counts"] = page_counts(driver)
        busy.update(recolours(driver, api, names[:args.connections], args.faults))
        busy["farm_counts_after"] = httpx.get(api + "/overview", timeout=30).json()["counts"]
        print(f"{args.devices} devices, {args.connections} connections at {args.rpi_ms} ms, overview: {busy}")
        out, _ = originator.communicate(timeout=seconds + 120)
        busy["originator"] = json.loads(out.strip().splitlines()[-1])
        print(f"the originator: {busy['originator']}")
    finally:
        if originator.poll() is None:
            originator.kill()
            originator.wait()


if __name__ == "__main__":
    main()
