"""Class-1 benchmark: N exclusive-owner connections at a given RPI, against a farm of N devices.

The farm runs pinned to one CPU; this originator (written for the benchmark, using the project's
codec) runs pinned to the other. It opens every connection with Forward Open (T->O point-to-point
to its own UDP port, given in a 0x8001 item), sends O->T on absolute deadlines, and timestamps
every T->O packet with the kernel's receive time (SO_TIMESTAMPNS), so the originator's own
scheduling does not count against the farm. Per connection: T->O period error against the RPI
(p50, p99, max), lost packets (gaps in the 32-bit sequence), late packets (an interval of 2 RPI
or more), and at the end each Forward Close tells whether the connection had timed out (0x0107). Farm CPU from /proc.
Every loop is bounded in time. Traffic goes to 127.0.0.0/8 only.

    python bench/bench_implicit.py --connections 200 --rpi-ms 10 --seconds 60
    python bench/bench_implicit.py --sweep 10          # lowest RPI with p99 error <= 0.5 ms, 10 s per RPI

Each run says on stderr when it starts and what it found, so a sweep shows its progress.
"""

from __future__ import annotations

import argparse
import heapq
import ipaddress
import json
import os
import select
import socket
import statistics
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from enip_farm.protocol.cip import decode_reply, encode_request
from enip_farm.protocol.commands import (
    SocketAddress,
    decode_send_data,
    encode_send_data,
    encode_sockaddr,
)
from enip_farm.protocol.connection import (
    ConnectionTriad,
    ConnectionType,
    ForwardCloseRequest,
    ForwardOpenRequest,
    NetworkParameters,
    decode_forward_open_reply,
    decode_io_packet,
    encode_forward_close,
    encode_forward_open,
    encode_io_packet,
)
from enip_farm.protocol.cpf import ItemType
from enip_farm.protocol.encapsulation import Command, StreamFramer, encode_frame

PATH = bytes.fromhex("20 04 24 01 2C 64 2C 65")
SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)  # Linux; kernel receive time of each datagram
TIMESPEC = struct.Struct("qq")
CM = bytes.fromhex("20 06 24 01")


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


SWEEP_RPIS_MS = (10, 5, 4, 3, 2, 1.5, 1, 0.5)
FIRST_ADDRESS = "127.0.201.1"


def address(i: int, first: str = FIRST_ADDRESS) -> str:
    """Device i's address: 250 per /24 from `first` (x.y.z.1 by default), the next 250 in the next /24."""
    return str(ipaddress.IPv4Address(first) + (i // 250) * 256 + i % 250)


class Session:
    def __init__(self, host: str) -> None:
        self.sock = socket.create_connection((host, 44818), timeout=10)
        self.framer = StreamFramer(65535)
        self.handle = self.exchange(encode_frame(Command.REGISTER_SESSION, b"\x01\x00\x00\x00")).header.session_handle

    def exchange(self, frame: bytes):
        self.sock.sendall(frame)
        while True:
            frames = self.framer.feed(self.sock.recv(65536))
            if frames:
                return frames[0]

    def request(self, message: bytes, items=()):
        frame = self.exchange(encode_frame(Command.SEND_RR_DATA, encode_send_data(
            [(ItemType.NULL_ADDRESS, b""), (ItemType.UNCONNECTED_DATA, message), *items]), self.handle))
        return decode_reply(decode_send_data(frame.data).items[1].data)


def run_load(hosts: list[str], rpi_us: int, seconds: float, farm_pid: int) -> dict[str, float]:
    udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    udp.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
    udp.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
    udp.bind(("127.0.0.1", 0))
    udp.setblocking(False)
    port = udp.getsockname()[1]
    sessions, connections = [], {}
    for i, host in enumerate(hosts):
        session = Session(host)
        triad = ConnectionTriad(i + 1, 0x0BE0, 0x12345678)
        request = ForwardOpenRequest(0x0A, 0x0E, 0, 0x70000000 + i, triad, 2, rpi_us,
                                     NetworkParameters(False, ConnectionType.POINT_TO_POINT, 2, False, 8), rpi_us,
                                     NetworkParameters(False, ConnectionType.POINT_TO_POINT, 2, False, 4), 0x01, PATH)
        reply = session.request(encode_request(0x54, CM, encode_forward_open(request)),
                                [(ItemType.SOCKADDR_T_O, encode_sockaddr(SocketAddress("0.0.0.0", port)))])
        if reply.general_status:
            raise RuntimeError(f"{host}: Forward Open refused: {reply}")
        opened = decode_forward_open_reply(reply.data)
        sessions.append((session, triad))
        connections[opened.t_o_connection_id] = {"o_t": opened.o_t_connection_id, "host": host, "arrivals": [],
                                                 "sequences": []}
    period = rpi_us / 1e6
    start = time.monotonic() + 0.05
    heap = [(start + k * period / len(hosts), k, conn) for k, conn in enumerate(connections.values())]
    heapq.heapify(heap)
    counts = {id(c): 0 for c in connections.values()}
    warmup_end = start + min(1.0, seconds / 5)
    end = start + seconds
    cpu0 = wall0 = None
    while True:
        now = time.monotonic()
        if now >= end:
            break
        if cpu0 is None and now >= warmup_end:
            cpu0, wall0 = cpu_seconds(farm_pid), now
            for conn in connections.values():
                conn["arrivals"].clear()
                conn["sequences"].clear()
        timeout = max(0.0, heap[0][0] - now)
        readable, _, _ = select.select([udp], [], [], timeout)
        if readable:
            for _ in range(256):
                try:
                    data, ancillary, _, _ = udp.recvmsg(2048, 64)
                except BlockingIOError:
                    break
                stamp = time.time()  # fallback: when this loop got to it
                for level, kind, value in ancillary:
                    if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS:
                        seconds, nanoseconds = TIMESPEC.unpack(value[:TIMESPEC.size])
                        stamp = seconds + nanoseconds / 1e9
                packet = decode_io_packet(data)
                conn = connections.get(packet.connection_id) if packet else None
                if conn is not None:
                    conn["arrivals"].append(stamp)
                    conn["sequences"].append(packet.sequence)
        now = time.monotonic()
        while heap[0][0] <= now:
            due, k, conn = heapq.heappop(heap)
            counts[id(conn)] += 1
            udp.sendto(encode_io_packet(conn["o_t"], counts[id(conn)], counts[id(conn)], b"\x01\x00\x00\x00\x01\x00"),
                       (conn["host"], 2222))
            heapq.heappush(heap, (due + period, k, conn))
    cpu1, wall1 = cpu_seconds(farm_pid), time.monotonic()
    timeouts = 0
    for session, triad in sessions:
        reply = session.request(encode_request(0x4E, CM, encode_forward_close(ForwardCloseRequest(0x0A, 0x0E, triad,
                                                                                                  PATH))))
        timeouts += reply.general_status == 1 and reply.additional_status == (0x0107,)
        session.sock.close()
    udp.close()

    errors, worst_p99, lost, late, received = [], 0.0, 0, 0, 0
    for conn in connections.values():
        intervals = [b - a for a, b in zip(conn["arrivals"], conn["arrivals"][1:], strict=False)]
        errs = [abs(i - period) * 1e3 for i in intervals]
        errors += errs
        received += len(conn["arrivals"])
        if len(errs) > 1:
            worst_p99 = max(worst_p99, statistics.quantiles(errs, n=100)[98])
        late += sum(i >= 2 * period for i in intervals)
        seqs = conn["sequences"]
        lost += sum((b - a) - 1 for a, b in zip(seqs, seqs[1:], strict=False) if b - a > 1)
    errors.sort()
    return {
        "connections": len(hosts), "rpi_ms": rpi_us / 1000, "t_o_packets": received,
        "err_p50_ms": statistics.median(errors) if errors else float("nan"),
        "err_p99_ms": statistics.quantiles(errors, n=100)[98] if len(errors) > 1 else float("nan"),
        "err_max_ms": errors[-1] if errors else float("nan"), "worst_connection_p99_ms": worst_p99,
        "lost": lost, "late": late, "timeouts": timeouts,
        "farm_cpu_percent": 100 * (cpu1 - cpu0) / (wall1 - wall0) if cpu0 is not None else float("nan"),
    }


def start_farm(count: int, rpi_min_us: int, cpu: int, first: str = FIRST_ADDRESS) -> tuple[subprocess.Popen, str]:
    config = tempfile.NamedTemporaryFile("w", suffix=".yaml", delete=False)
    config.write("discovery: false\ndevices:\n")
    for i in range(count):
        config.write(f"  - {{name: b{i}, address: {address(i, first)}, model: DSQC1030, "
                     f"implicit: {{rpi_min_us: {rpi_min_us}}}}}\n")
    config.close()
    process = subprocess.Popen(["taskset", "-c", str(cpu), sys.executable, "-m", "enip_farm", "serve", "--quiet",
                                "--config", config.name], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    process.stdout.readline()  # the table's header: every device listens
    return process, config.name


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--connections", type=int, default=200)
    parser.add_argument("--rpi-ms", type=float, default=10.0)
    parser.add_argument("--seconds", type=float, default=None,
                        help="length of each run (default: 60 s, or 10 s per RPI with --sweep)")
    parser.add_argument("--repeat", type=int, default=1, help="runs against the same farm; the median is reported")
    parser.add_argument("--sweep", type=int, default=0, metavar="N",
                        help=f"instead: N connections at each RPI of {', '.join(map(str, SWEEP_RPIS_MS))} ms")
    parser.add_argument("--first-address", default=FIRST_ADDRESS,
                        help="the first device's address (127.0.0.0/8); 250 per /24 from there")
    parser.add_argument("--farm-cpu", type=int, default=1, help="CPU 0 takes this VM's interrupts")
    parser.add_argument("--client-cpu", type=int, default=0)
    parser.add_argument("--json", type=Path, default=None, help="also write the results here")
    args = parser.parse_args()
    seconds = args.seconds if args.seconds is not None else 10.0 if args.sweep else 60.0
    os.sched_setaffinity(0, {args.client_cpu})
    count = args.sweep or args.connections
    farm, config = start_farm(count, 250, args.farm_cpu, args.first_address)
    hosts = [address(i, args.first_address) for i in range(count)]
    runs = list(SWEEP_RPIS_MS) if args.sweep else [args.rpi_ms] * args.repeat
    results = []
    try:
        for n, rpi_ms in enumerate(runs, 1):
            print(f"run {n}/{len(runs)}: {count} connections at RPI {rpi_ms:g} ms for {seconds:g} s ...",
                  file=sys.stderr, flush=True)
            result = run_load(hosts, int(rpi_ms * 1000), seconds, farm.pid)
            results.append(result)
            print(f"run {n}/{len(runs)}: error p99 {result['err_p99_ms']:.3f} ms, {result['late']} late, "
                  f"{result['timeouts']} timeouts, farm CPU {result['farm_cpu_percent']:.0f}%",
                  file=sys.stderr, flush=True)
    finally:
        farm.terminate()
        farm.wait(10)
        os.unlink(config)
    keys = list(results[0])
    print(" ".join(f"{k:>14}" for k in keys))
    if len(results) > 1 and not args.sweep:
        results.append({k: statistics.median(r[k] for r in results) for k in keys})
    for i, r in enumerate(results):
        label = "median" if args.repeat > 1 and i == len(results) - 1 else ""
        print(" ".join(f"{r[k]:14.3f}" if isinstance(r[k], float) else f"{r[k]:14d}" for k in keys), label)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
