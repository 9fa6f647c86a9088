"""Fleet benchmark: start time and memory for 1000 devices; then 500 devices polled with Get
Attribute Single at increasing aggregate rates, served by --workers 1 and --workers 2.

The load process (this one, asyncio + uvloop) keeps one registered connection per device and sends
each request on an idle connection at the target rate (open loop, capped at one outstanding request
per connection). Per step: achieved rate, latency p50 / p99, errors (non-zero status or lost
connections), and CPU of the farm's processes and of the load process. Every step is bounded in
time; traffic goes to 127.0.0.0/8 only. No CPU pinning: the workers need both cores, and the load
process shares them (this machine has 2).

    python bench/bench_fleet.py [--seconds 20] [--rates 5000,10000,20000,30000,40000]
"""

from __future__ import annotations

import argparse
import asyncio
import collections
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import psutil
import uvloop

from enip_farm.config import load_config
from enip_farm.protocol.commands import encode_send_rr_data
from enip_farm.protocol.encapsulation import Command, encode_frame

GET = bytes.fromhex("0E 03 20 04 24 64 30 03")
REPLY_SIZE = 46


def write_config(count: int, first: str) -> str:
    config = tempfile.NamedTemporaryFile("w", suffix=".yaml", delete=False)
    config.write(f"devices:\n  - {{name: 'io{{n}}', address: {first}, count: {count}, model: DSQC1030, "
                 "netmask: 255.0.0.0}\n")
    config.close()
    return config.name


def start_farm(config: str, workers: int) -> tuple[subprocess.Popen, float]:
    started = time.monotonic()
    process = subprocess.Popen([sys.executable, "-m", "enip_farm", "serve", "--quiet", "--config", config, "--workers",
                                str(workers)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    header = process.stdout.readline()
    if not header.startswith("NAME"):
        raise RuntimeError(process.stderr.read())
    return process, time.monotonic() - started


def tree_cpu(process: subprocess.Popen) -> float:
    root = psutil.Process(process.pid)
    total = 0.0
    for p in [root, *root.children(recursive=True)]:
        try:
            times = p.cpu_times()
            total += times.user + times.system
        except psutil.NoSuchProcess:
            pass
    return total


def tree_rss(process: subprocess.Popen) -> int:
    root = psutil.Process(process.pid)
    return sum(p.memory_info().rss for p in [root, *root.children(recursive=True)])


class Connection(asyncio.Protocol):
    def __init__(self, load: Load) -> None:
        self.load = load
        self.buffer = b""
        self.sent_at = 0.0
        self.request = b""
        self.registered = asyncio.get_running_loop().create_future()

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport
        transport.write(encode_frame(Command.REGISTER_SESSION, b"\x01\x00\x00\x00"))

    def data_received(self, data: bytes) -> None:
        self.buffer += data
        if not self.registered.done():
            if len(self.buffer) < 28:
                return
            handle = int.from_bytes(self.buffer[4:8], "little")
            self.request = encode_send_rr_data(GET, handle)
            self.buffer = self.buffer[28:]
            self.registered.set_result(True)
            return
        while len(self.buffer) >= REPLY_SIZE:
            reply, self.buffer = self.buffer[:REPLY_SIZE], self.buffer[REPLY_SIZE:]
            self.load.done(self, time.perf_counter() - self.sent_at, reply[42] == 0 and reply[8:12] == b"\0\0\0\0")

    def connection_lost(self, exc: Exception | None) -> None:
        self.load.errors += 1

    def send(self) -> None:
        self.sent_at = time.perf_counter()
        self.transport.write(self.request)


class Load:
    def __init__(self) -> None:
        self.idle: collections.deque[Connection] = collections.deque()
        self.latencies: list[float] = []
        self.errors = 0
        self.recording = False

    def done(self, connection: Connection, latency: float, ok: bool) -> None:
        if self.recording:
            self.latencies.append(latency)
            self.errors += not ok
        self.idle.append(connection)

    async def connect(self, addresses: list[str]) -> None:
        loop = asyncio.get_running_loop()
        for address in addresses:
            _, connection = await loop.create_connection(lambda: Connection(self), address, 44818)
            await connection.registered
            self.idle.append(connection)

    async def step(self, rate: float, seconds: float) -> dict[str, float]:
        self.latencies, self.errors, self.recording = [], 0, True
        start = time.monotonic()
        sent = skipped = 0
        while (now := time.monotonic()) - start < seconds:
            due = int((now - start) * rate) - sent - skipped
            for _ in range(due):
                if self.idle:
                    self.idle.popleft().send()
                    sent += 1
                else:
                    skipped += 1  # every connection busy: the farm is saturated
            await asyncio.sleep(0.0005)
        await asyncio.sleep(0.2)
        self.recording = False
        lat = sorted(self.latencies)
        return {"target": rate, "achieved": len(lat) / seconds, "p50_ms": statistics.median(lat) * 1e3 if lat else 0,
                "p99_ms": lat[int(len(lat) * 0.99)] * 1e3 if lat else 0, "errors": self.errors, "skipped": skipped}


async def run_load(addresses: list[str], rates: list[float], seconds: float, farm: subprocess.Popen) -> list[dict]:
    load = Load()
    await load.connect(addresses)
    me = psutil.Process()
    rows = []
    for rate in rates:
        farm_cpu, own_cpu, wall = tree_cpu(farm), sum(me.cpu_times()[:2]), time.monotonic()
        row = await load.step(rate, seconds)
        elapsed = time.monotonic() - wall
        row["farm_cpu_%"] = 100 * (tree_cpu(farm) - farm_cpu) / elapsed
        row["load_cpu_%"] = 100 * (sum(me.cpu_times()[:2]) - own_cpu) / elapsed
        rows.append(row)
        print("  " + "  ".join(f"{k} {v:.1f}" if isinstance(v, float) else f"{k} {v}" for k, v in row.items()),
              flush=True)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--rates", default="5000,10000,20000,30000,40000")
    args = parser.parse_args()
    rates = [float(r) for r in args.rates.split(",")]

    config = write_config(1000, "127.0.210.1")
    farm, started = start_farm(config, 1)
    time.sleep(0.5)
    rss = tree_rss(farm)
    probe = subprocess.run([sys.executable, "-m", "enip_farm", "probe", "--config", config], capture_output=True,
                           text=True, timeout=60)
    farm.terminate()
    farm.wait(30)
    Path(config).unlink()
    print(f"1000 devices: listening {started:.2f} s after start (process start included), RSS {rss >> 20} MB, "
          f"probe: {probe.stdout.strip()}")

    config = write_config(500, "127.0.220.1")
    addresses = [str(device.address) for device in load_config(config).devices]
    for workers in (1, 2):
        farm, started = start_farm(config, workers)
        print(f"500 devices, --workers {workers} (listening after {started:.2f} s):", flush=True)
        try:
            uvloop.run(run_load(addresses, rates, args.seconds, farm))
        finally:
            farm.terminate()
            farm.wait(30)
    Path(config).unlink()


if __name__ == "__main__":
    main()
