"""Explicit-messaging benchmark: the farm against a minimal struct+asyncio responder.

Both servers run pinned to one CPU and the client to another (taskset / sched_setaffinity), so
both pay the same cross-CPU wake-up. Measured per server, in one run:
  - Get/Set Attribute Single round trip p50 / p99 on one connection (alternating Get and Set)
  - sequential throughput on that connection
  - aggregate throughput over 8 connections (one request outstanding on each)
  - connect + RegisterSession p50
  - server CPU per request (utime + stime from /proc over the throughput phases)
Every loop is bounded in count and in time. Traffic goes to 127.0.0.0/8 only.

    python bench/bench_explicit.py [--requests 20000] [--server-cpu 1] [--client-cpu 0]

CPU per request comes from /proc, which counts in clock ticks (10 ms): with few requests a phase
may take no whole tick, and the ratio of two such figures is shown as n/a.
"""

from __future__ import annotations

import argparse
import json
import os
import selectors
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from enip_client import recv_exact, register

from enip_farm.protocol.commands import encode_send_rr_data
from enip_farm.protocol.encapsulation import Command, encode_frame

FARM_HOST = "127.0.200.1"
MINIMAL_HOST = "127.0.200.2"
PORT = 44818
REGISTER = encode_frame(Command.REGISTER_SESSION, b"\x01\x00\x00\x00")
GET_MESSAGE = bytes.fromhex("0E 03 20 04 24 64 30 03")
SET_MESSAGE = bytes.fromhex("10 03 20 04 24 64 30 03 10 00")
GET_REPLY_SIZE, SET_REPLY_SIZE = 46, 44
TIME_LIMIT = 20.0  # seconds, per phase


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def connect(host: str) -> tuple[socket.socket, bytes, bytes]:
    """A registered connection and its Get and Set frames (which carry its session handle)."""
    sock, handle = register(host)
    return sock, encode_send_rr_data(GET_MESSAGE, handle), encode_send_rr_data(SET_MESSAGE, handle)


def round_trips(host: str, count: int) -> tuple[list[float], float]:
    """Alternating Set and Get on one connection; per-request latency (µs) and requests/s."""
    sock, get, set_ = connect(host)
    latencies = []
    deadline = time.monotonic() + TIME_LIMIT
    start = time.perf_counter()
    for i in range(count):
        request, size = (set_, SET_REPLY_SIZE) if i % 2 else (get, GET_REPLY_SIZE)
        t0 = time.perf_counter_ns()
        sock.sendall(request)
        recv_exact(sock, size)
        latencies.append((time.perf_counter_ns() - t0) / 1000)
        if time.monotonic() > deadline:
            break
    elapsed = time.perf_counter() - start
    sock.close()
    return latencies, len(latencies) / elapsed


def aggregate(host: str, connections: int, count: int) -> tuple[int, float]:
    """Get requests over several connections, one outstanding on each; total requests/s."""
    selector = selectors.DefaultSelector()
    opened = [connect(host) for _ in range(connections)]
    socks = [sock for sock, _, _ in opened]
    gets = {sock: get for sock, get, _ in opened}
    pending = {}
    for sock in socks:
        sock.setblocking(False)
        selector.register(sock, selectors.EVENT_READ)
        sock.send(gets[sock])
        pending[sock] = GET_REPLY_SIZE
    done = 0
    sent = connections
    deadline = time.monotonic() + TIME_LIMIT
    start = time.perf_counter()
    while done < count and time.monotonic() < deadline:
        for key, _ in selector.select(timeout=1):
            sock = key.fileobj
            data = sock.recv(65536)
            pending[sock] -= len(data)
            while pending[sock] <= 0:
                done += 1
                if sent >= count:
                    break
                sock.send(gets[sock])
                sent += 1
                pending[sock] += GET_REPLY_SIZE
    elapsed = time.perf_counter() - start
    for sock in socks:
        selector.unregister(sock)
        sock.close()
    return done, done / elapsed


def connect_register(host: str, count: int) -> list[float]:
    times = []
    deadline = time.monotonic() + TIME_LIMIT
    for _ in range(count):
        t0 = time.perf_counter_ns()
        sock, _, _ = connect(host)
        times.append((time.perf_counter_ns() - t0) / 1000)
        sock.close()
        if time.monotonic() > deadline:
            break
    return times


def percentile(values: list[float], q: float) -> float:
    return statistics.quantiles(values, n=100, method="inclusive")[int(q) - 1] if len(values) > 1 else values[0]


def ratio(a: float, b: float) -> str:
    """a / b to two decimals, or n/a when b is 0 (e.g. CPU time below one clock tick)."""
    return f"{a / b:.2f}" if b else "n/a"


def wait_listening(host: str, process: subprocess.Popen, timeout: float = 20.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if process.poll() is not None:
            raise RuntimeError(f"server exited: {process.stderr.read() if process.stderr else ''}")
        try:
            socket.create_connection((host, PORT), timeout=0.2).close()
            return
        except OSError:
            time.sleep(0.05)
    raise TimeoutError(f"{host}:{PORT} did not listen")


def measure(name: str, host: str, pid: int, args: argparse.Namespace) -> dict[str, float]:
    round_trips(host, 2000)  # warm-up
    cpu0 = cpu_seconds(pid)
    latencies, sequential = round_trips(host, args.requests)
    cpu1 = cpu_seconds(pid)
    done, parallel = aggregate(host, 8, args.requests * 2)
    cpu2 = cpu_seconds(pid)
    setup = connect_register(host, args.connects)
    return {
        "server": name,
        "rtt_p50_us": statistics.median(latencies),
        "rtt_p99_us": percentile(latencies, 99),
        "sequential_per_s": sequential,
        "aggregate_8_per_s": parallel,
        "connect_register_p50_us": statistics.median(setup),
        "cpu_us_per_request_sequential": (cpu1 - cpu0) / len(latencies) * 1e6,
        "cpu_us_per_request_aggregate": (cpu2 - cpu1) / done * 1e6 if done else 0.0,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--requests", type=int, default=20000)
    parser.add_argument("--rounds", type=int, default=3, help="interleaved rounds; medians are reported")
    parser.add_argument("--connects", type=int, default=500)
    parser.add_argument("--server-cpu", type=int, default=1, help="CPU 0 takes this VM's interrupts")
    parser.add_argument("--client-cpu", type=int, default=0)
    parser.add_argument("--json", type=Path, default=None, help="also write the results here")
    parser.add_argument("--farm-host", default=FARM_HOST, help="the farm's device address (127.0.0.0/8)")
    parser.add_argument("--minimal-host", default=MINIMAL_HOST, help="the minimal responder's address")
    args = parser.parse_args()

    config = tempfile.NamedTemporaryFile("w", suffix=".yaml", delete=False)
    config.write(f"devices:\n  - {{name: bench, address: {args.farm_host}, model: DSQC1030}}\ndiscovery: false\n")
    config.close()
    pin = ["taskset", "-c", str(args.server_cpu)]
    servers = {
        "farm": (args.farm_host, subprocess.Popen([*pin, sys.executable, "-m", "enip_farm", "serve", "--quiet",
                                                   "--config", config.name], stdout=subprocess.DEVNULL,
                                                  stderr=subprocess.PIPE, text=True)),
        "minimal": (args.minimal_host, subprocess.Popen([*pin, sys.executable, str(Path(__file__).with_name(
            "minimal_responder.py")), args.minimal_host], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
            text=True)),
    }
    os.sched_setaffinity(0, {args.client_cpu})
    rounds: dict[str, list[dict[str, float]]] = {name: [] for name in servers}
    try:
        for host, process in servers.values():
            wait_listening(host, process)
        for _ in range(args.rounds):  # interleaved, so drift on a shared machine hits both alike
            for name, (host, process) in servers.items():
                rounds[name].append(measure(name, host, process.pid, args))
    finally:
        for _, process in servers.values():
            process.terminate()
            process.wait(10)
        os.unlink(config.name)

    results = [{key: statistics.median(r[key] for r in rounds[name]) for key in rounds[name][0] if key != "server"}
               for name in servers]
    farm, minimal = results
    print(f"medians of {args.rounds} interleaved rounds; server CPU {args.server_cpu}, client CPU {args.client_cpu}")
    print(f"{'metric':34} {'farm':>10} {'minimal':>10} {'farm/minimal':>13}")
    for key in farm:
        print(f"{key:34} {farm[key]:10.1f} {minimal[key]:10.1f} {ratio(farm[key], minimal[key]):>13}")
    if not all(farm[key] and minimal[key] for key in farm if key.startswith("cpu_")):
        print("n/a: a phase took less than one clock tick of CPU (10 ms); give more --requests for CPU figures")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(rounds, indent=2))


if __name__ == "__main__":
    main()
