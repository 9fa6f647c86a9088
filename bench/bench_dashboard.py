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

    python bench/bench_dashboard.py [--changes 200] [--devices 1000] [--load-hz 0,2000,10000]

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

from tests.browser import FILTER_ROUND_TRIP, MEASURE_FRAMES, RECORD_CHANGES, chromium, open_page, until  # noqa: E402

FARM = """
import sys, threading, time
from enip_farm.config import parse_config
from enip_farm.farm import Farm
first, count = sys.argv[1], int(sys.argv[2])
device = {"name": "io{n}", "address": first, "model": "DSQC1030"}
if count > 1:
    device.update(count=count, addons=["DSQC1032"])
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


class FarmProcess:
    def __init__(self, first: str, count: int) -> None:
        env = {**os.environ, "PYTHONPATH": str(ROOT)}
        self.process = subprocess.Popen([sys.executable, "-c", FARM, first, str(count)], stdin=subprocess.PIPE,
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
    args = parser.parse_args()
    result: dict = {}
    with chromium() as driver:
        farm = FarmProcess(args.first, 1)
        try:
            open_page(driver, farm.url)
            result["one_device"] = summary(latencies(driver, args.first, args.changes, 2))
        finally:
            farm.close()
        print(f"1 device, CIP write reply -> LED: {result['one_device']}")
        farm = FarmProcess(args.first, args.devices)
        try:
            driver.execute_cdp_cmd("Page.addScriptToEvaluateOnNewDocument", {"source": MEASURE_FRAMES})
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
    print(json.dumps(result))


if __name__ == "__main__":
    main()
