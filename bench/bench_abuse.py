"""Reliability benchmark: a well-behaved client's round trips to one device while, in turn, an abuser
hits another device of the same farm (issue: hostile networks). Bounded, loopback only.

The farm runs as `enip-farm serve` pinned to one CPU; the abuser runs in a process of its own
(no GIL shared with the measuring client) and the client timestamps each reply with the kernel's
receive time (SO_TIMESTAMPNS), so its own scheduling counts as little as possible. Phases:
  none        no abuse (the reference)
  pipelining  one connection sends requests back to back and reads the replies
  no-reading  one connection sends requests and never reads a reply
  slowloris   600 connections that each send half a header, then nothing
  nesting     Multiple Service Packet / Unconnected Send nested 300 deep, back to back
  sse         100 subscribers of GET /events that never read
Per phase: the client's p50 / p99 / max round trip (ms) and errors, the farm's RSS (MB) during
the abuse and once the abuser has left.

    python bench/bench_abuse.py [--requests 3000] [--seconds 10] [--farm-cpu 1] [--client-cpu 0]
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import socket
import statistics
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from enip_client import recv_exact, register

from enip_farm.protocol.cip import encode_request, encode_unconnected_send
from enip_farm.protocol.commands import encode_send_rr_data
from enip_farm.protocol.encapsulation import Command, encode_frame
from enip_farm.protocol.epath import encode_port, encode_request_path

CALM, ABUSED = "127.0.201.1", "127.0.201.2"
PORT = 44818
SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)
REGISTER = encode_frame(Command.REGISTER_SESSION, b"\x01\x00\x00\x00")
GET = encode_request(0x0E, encode_request_path(4, 100, 3))
GET_REPLY_SIZE = 46
PHASES = ("none", "pipelining", "no-reading", "slowloris", "nesting", "sse")


def connect(host: str) -> tuple[socket.socket, int]:
    return register(host)


def nested(depth: int) -> bytes:
    message = GET
    for level in range(depth):
        if level % 2:
            message = encode_request(0x0A, encode_request_path(2, 1), struct.pack("<HH", 1, 4) + message)
        else:
            message = encode_request(0x52, encode_request_path(6, 1),
                                     encode_unconnected_send(message, encode_port(1, 0)))
    return message


# -- abusers (each in a process of its own, until told to stop or its own bound) ----------------------


def abuse(kind: str, http_port: int, ready: multiprocessing.Event, stop: multiprocessing.Event,
          seconds: float) -> None:
    deadline = time.monotonic() + seconds + 30
    held: list[socket.socket] = []
    try:
        if kind == "pipelining":
            sock, handle = connect(ABUSED)
            batch = encode_send_rr_data(GET, handle) * 64
            sock.settimeout(5)
            ready.set()
            while not stop.is_set() and time.monotonic() < deadline:
                sock.sendall(batch)
                recv_exact(sock, GET_REPLY_SIZE * 64)
        elif kind == "no-reading":
            sock, handle = connect(ABUSED)
            held.append(sock)
            sock.setblocking(False)
            burst = encode_send_rr_data(GET, handle) * 256
            sent, limit = 0, 200 << 20  # at most 200 MB of requests
            ready.set()
            while not stop.is_set() and time.monotonic() < deadline and sent < limit:
                try:
                    sent += sock.send(burst[sent % len(burst):])
                except BlockingIOError:
                    time.sleep(0.005)
        elif kind == "slowloris":
            for _ in range(600):
                sock = socket.create_connection((ABUSED, PORT), timeout=5)
                sock.sendall(REGISTER[:10])  # half a header
                held.append(sock)
            ready.set()
            stop.wait(deadline - time.monotonic())
        elif kind == "nesting":
            sock, handle = connect(ABUSED)
            request = encode_send_rr_data(nested(300), handle)
            sock.settimeout(5)
            ready.set()
            while not stop.is_set() and time.monotonic() < deadline:
                sock.sendall(request)
                header = recv_exact(sock, 24)
                recv_exact(sock, int.from_bytes(header[2:4], "little"))
        elif kind == "sse":
            for _ in range(100):
                sock = socket.create_connection(("127.0.0.1", http_port), timeout=5)
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
                sock.sendall(f"GET /events HTTP/1.1\r\nHost: 127.0.0.1:{http_port}\r\n\r\n".encode())
                held.append(sock)
            ready.set()
            stop.wait(deadline - time.monotonic())
    finally:
        ready.set()
        for sock in held:
            sock.close()


# -- the well-behaved client ------------------------------------------------------------------------


def round_trips(count: int, seconds: float) -> tuple[list[float], int]:
    """Sequential Get requests to the calm device: round trips (ms, to the kernel's receive time)
    and errors (timeouts, closed connections, wrong replies)."""
    latencies: list[float] = []
    errors = 0
    sock, handle = connect(CALM)
    sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
    sock.settimeout(2)
    request = encode_send_rr_data(GET, handle)
    deadline = time.monotonic() + seconds
    while len(latencies) + errors < count and time.monotonic() < deadline:
        sent_at = time.clock_gettime_ns(time.CLOCK_REALTIME)
        try:
            sock.sendall(request)
            data, ancillary, _, _ = sock.recvmsg(GET_REPLY_SIZE, socket.CMSG_SPACE(16))
            while len(data) < GET_REPLY_SIZE:
                data += recv_exact(sock, GET_REPLY_SIZE - len(data))
        except (OSError, ConnectionError):
            errors += 1
            sock.close()
            sock, handle = connect(CALM)
            sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
            sock.settimeout(2)
            request = encode_send_rr_data(GET, handle)
            continue
        received_at = time.clock_gettime_ns(time.CLOCK_REALTIME)
        for level, kind, payload in ancillary:
            if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS:
                seconds_, nanoseconds = struct.unpack("qq", payload[:16])
                received_at = seconds_ * 1_000_000_000 + nanoseconds
        if data[42:44] != b"\x00\x00" or data[40] != 0x8E:  # reply service 0x8E, general status 0
            errors += 1
        latencies.append((received_at - sent_at) / 1e6)
    sock.close()
    return latencies, errors


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--requests", type=int, default=3000, help="round trips per phase, at most")
    parser.add_argument("--seconds", type=float, default=10.0, help="per phase, at most")
    parser.add_argument("--farm-cpu", type=int, default=1)
    parser.add_argument("--client-cpu", type=int, default=0)
    args = parser.parse_args()

    config = tempfile.NamedTemporaryFile("w", suffix=".yaml", delete=False)
    config.write(f"discovery: false\ndevices:\n  - {{name: calm, address: {CALM}, model: DSQC1030}}\n"
                 f"  - {{name: abused, address: {ABUSED}, model: DSQC1030}}\n")
    config.close()
    farm = subprocess.Popen(["taskset", "-c", str(args.farm_cpu), sys.executable, "-m", "enip_farm", "serve", "--quiet",
                             "--config", config.name, "--http", "0"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    os.sched_setaffinity(0, {args.client_cpu})
    try:
        http_port = 0
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not http_port:
            line = farm.stderr.readline()
            if not line:
                raise SystemExit(f"the farm exited: {farm.stderr.read()}")
            if "HTTP API on" in line:
                http_port = int(line.rsplit(":", 1)[1].strip().strip("/"))
        print(f"{'phase':12} {'p50 ms':>8} {'p99 ms':>8} {'max ms':>8} {'replies':>8} {'errors':>7} "
              f"{'RSS MB':>7} {'during':>7} {'after':>7}")
        for phase in PHASES:
            before = rss_mb(farm.pid)
            ready, stop = multiprocessing.Event(), multiprocessing.Event()
            abuser = None
            if phase != "none":
                abuser = multiprocessing.Process(target=abuse, args=(phase, http_port, ready, stop, args.seconds))
                abuser.start()
                ready.wait(60)
                time.sleep(0.5)  # let the abuse build up
            latencies, errors = round_trips(args.requests, args.seconds)
            during = rss_mb(farm.pid)
            if abuser is not None:
                stop.set()
                abuser.join(60)
                if abuser.is_alive():
                    abuser.kill()
                time.sleep(2.0)  # the farm notices the abuser is gone
            after = rss_mb(farm.pid)
            latencies.sort()
            p99 = latencies[min(len(latencies) - 1, int(len(latencies) * 0.99))] if latencies else float("nan")
            print(f"{phase:12} {statistics.median(latencies) if latencies else float('nan'):8.3f} {p99:8.3f} "
                  f"{latencies[-1] if latencies else float('nan'):8.3f} {len(latencies):8d} {errors:7d} "
                  f"{before:7.1f} {during:7.1f} {after:7.1f}", flush=True)
    finally:
        farm.terminate()
        try:
            farm.wait(10)
        except subprocess.TimeoutExpired:
            farm.kill()
        os.unlink(config.name)


if __name__ == "__main__":
    main()
