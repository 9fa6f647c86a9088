"""Event-stream subscribers that never read, and what they cost another client.

A farm (one device) runs in a subprocess pinned to one CPU, with the HTTP API on 127.0.0.1; this
process, pinned to another CPU, measures a well-behaved explicit-messaging client (Get Attribute
Single, one outstanding, one connection) in windows of `--window` seconds:
  1. with no event stream open;
  2. with `--subscribers` GET /events streams open whose clients never read past the headers
     (SO_RCVBUF 4 KiB); each explicit request is an event for each. Loopback still takes about
     3 MB per stream into the kernel before a stream's `send` waits, so the first `--settle`
     seconds (streams still being written) are reported apart from the windows after.
The farm runs with its default subscriber cap, and again with the cap raised to `--subscribers`
(`--cap`), so that both the refusals and the fan-out's cost show. `--tree` measures another
checkout (e.g. main before the hub) the same way. Medians of the windows are printed, and a JSON
line. Every loop is bounded in count and in time; traffic goes to 127.0.0.0/8 only.

    python bench/bench_sse.py [--subscribers 100] [--windows 5] [--window 1] [--settle 10] [--tree PATH]
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import statistics
import subprocess
import sys
import time
from pathlib import Path

from enip_client import recv_exact, register

from enip_farm.protocol.commands import encode_send_rr_data

FARM_HOST = "127.0.202.1"
PORT = 44818
ROOT = Path(__file__).resolve().parent.parent

FARM = """
import sys
from enip_farm.config import parse_config
from enip_farm.farm.farm import Farm
config = parse_config({"devices": [{"name": "io", "address": sys.argv[1], "model": "DSQC1030"}], "discovery": False})
farm = Farm(config, http=("127.0.0.1", 0))
with farm.running_in_thread():
    hub = getattr(farm.http, "hub", None)
    if hub is not None and int(sys.argv[2]):
        hub.max_subscribers = int(sys.argv[2])
    print(farm.http.port, flush=True)
    sys.stdin.read()  # until the bench closes our stdin
"""


def request_rate(seconds: float) -> float:
    """Get Attribute Single round trips per second on one registered connection, for `seconds`."""
    sock, handle = register(FARM_HOST)
    with sock:
        get = encode_send_rr_data(bytes.fromhex("0E 03 20 04 24 64 30 03"), handle)
        done, start = 0, time.perf_counter()
        while time.perf_counter() - start < seconds and done < 10_000_000:
            sock.sendall(get)
            recv_exact(sock, 46)
            done += 1
        return done / (time.perf_counter() - start)


def subscribe(port: int, count: int) -> tuple[list[socket.socket], dict[int, int]]:
    """`count` event streams whose clients read the status line and nothing more."""
    socks, statuses = [], {}
    for _ in range(count):
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        sock.settimeout(10)
        sock.connect(("127.0.0.1", port))
        sock.sendall(b"GET /events HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
        status = int(sock.recv(12).split()[1])  # "HTTP/1.1 200"
        statuses[status] = statuses.get(status, 0) + 1
        socks.append(sock)
    return socks, statuses


def run(tree: Path, cap: int, args: argparse.Namespace) -> dict:
    env = {**os.environ, "PYTHONPATH": str(tree)}
    farm = subprocess.Popen(["taskset", "-c", str(args.server_cpu), sys.executable, "-c", FARM, FARM_HOST, str(cap)],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env, cwd=tree)
    try:
        port = int(farm.stdout.readline())  # type: ignore[union-attr]
        request_rate(1.0)  # warm-up
        idle = [request_rate(args.window) for _ in range(args.windows)]
        socks, statuses = subscribe(port, args.subscribers)
        try:
            filling = [request_rate(args.window) for _ in range(int(args.settle / args.window))]
            loaded = [request_rate(args.window) for _ in range(args.windows)]
        finally:
            for sock in socks:
                sock.close()
        return {"tree": str(tree), "cap": cap or "default", "subscribers": args.subscribers,
                "streams": {str(k): v for k, v in sorted(statuses.items())},
                "idle_req_per_s": round(statistics.median(idle)),
                "while_their_buffers_fill_req_per_s": round(statistics.median(filling)) if filling else None,
                "with_subscribers_req_per_s": round(statistics.median(loaded)),
                "windows": [round(r) for r in filling + loaded]}
    finally:
        farm.stdin.close()  # type: ignore[union-attr]
        try:
            farm.wait(timeout=30)
        except subprocess.TimeoutExpired:
            farm.kill()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--subscribers", type=int, default=100)
    parser.add_argument("--windows", type=int, default=5)
    parser.add_argument("--window", type=float, default=1.0, help="seconds per measurement window")
    parser.add_argument("--settle", type=float, default=10.0,
                        help="seconds measured apart first, while the streams' socket buffers fill (~3 MB each)")
    parser.add_argument("--tree", type=Path, default=ROOT, help="the checkout to serve the farm from")
    parser.add_argument("--server-cpu", type=int, default=1)
    parser.add_argument("--client-cpu", type=int, default=0)
    args = parser.parse_args()
    os.sched_setaffinity(0, {args.client_cpu})
    for cap in (0, args.subscribers):
        result = run(args.tree.resolve(), cap, args)
        print(f"cap {result['cap']}: streams {result['streams']}; another client: "
              f"{result['idle_req_per_s']} req/s without, {result['with_subscribers_req_per_s']} req/s with "
              f"({result['while_their_buffers_fill_req_per_s']} while their buffers fill; windows {result['windows']})")
        print(json.dumps(result))


if __name__ == "__main__":
    main()
