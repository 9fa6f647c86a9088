"""What the report's per-packet measurement costs (cip/o_t_measure.py), in process: a connection
table takes O->T datagrams with `measuring` on and off, in alternating rounds (so that the machine's
other load falls on both alike); each side's figure is the fastest round's CPU ns per datagram (the
thread's CPU time, the least disturbed round), and the difference set against the farm's CPU per
pair that bench_cyclic.py measures (its pairs/CPU-s, --pairs-per-cpu-s) says what share of it it is.

    python bench/bench_measure.py                      # 40 rounds of 20 000 datagrams each side
    python bench/bench_measure.py --pairs-per-cpu-s 47000
"""

from __future__ import annotations

import argparse
import random
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from enip_farm.cip.admission import Originator  # noqa: E402
from enip_farm.cip.assembly import AssemblyInstance  # noqa: E402
from enip_farm.cip.connection_path import KeyIdentity  # noqa: E402
from enip_farm.cip.connection_policy import ConnectionPolicy  # noqa: E402
from enip_farm.cip.connection_table import ConnectionTable, Opened  # noqa: E402
from enip_farm.protocol.connection import (  # noqa: E402
    ConnectionTriad,
    ConnectionType,
    ForwardOpenRequest,
    NetworkParameters,
    encode_io_packet,
)

MS = 1_000_000
HOST = "127.0.0.9"
OWNER_PATH = bytes.fromhex("20 04 24 01 2C 64 2C 65")  # assembly 1, O->T 100, T->O 101


def table(measuring: bool) -> tuple[ConnectionTable, int]:
    assemblies = {"output": AssemblyInstance(100, 2, True), "input": AssemblyInstance(101, 2, False),
                  "configuration": AssemblyInstance(1, 0, True)}
    policy = ConnectionPolicy(rpi_min_us=2_000, rpi_max_us=10_000_000, max_class1_connections=8,
                              max_class3_connections=6, outputs_off_on_idle=True, outputs_off_on_fault=True,
                              first_watchdog_ns=10_000 * MS, input_only_point=198, listen_only_point=199,
                              multicast_group="239.192.1.0")
    t = ConnectionTable(assemblies, policy, lambda: KeyIdentity(75, 7, 1030, (1, 1)), rng=random.Random(1))
    t.measuring = measuring
    p2p = ConnectionType.POINT_TO_POINT
    request = ForwardOpenRequest(0x0A, 0x0E, 0, 0x7E570001, ConnectionTriad(1, 0x1234, 0xABCD), 2, 10_000,
                                 NetworkParameters(False, p2p, 2, False, 8), 10_000,
                                 NetworkParameters(False, p2p, 2, False, 4), 0x01, OWNER_PATH)
    opened = t.forward_open(request, Originator(HOST), 0)
    assert type(opened) is Opened
    return t, opened.connection.o_t_id


def round_ns(measuring: bool, count: int, jitter: random.Random) -> float:
    """ns per O->T datagram over `count` packets 10 ms (+- 0.5 ms) apart."""
    t, oid = table(measuring)
    packets = [encode_io_packet(oid, n, n, b"\x01\x00\x00\x00" + bytes([n & 0xFF, 0])) for n in range(1, count + 1)]
    times = [n * 10 * MS + jitter.randrange(-MS // 2, MS // 2) for n in range(1, count + 1)]
    receive = t.receive_datagram
    start = time.thread_time_ns()  # this thread's CPU time: time the machine's other load takes is left out
    for packet, at in zip(packets, times, strict=True):
        receive(packet, HOST, at, 2222, at)
    return (time.thread_time_ns() - start) / count


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rounds", type=int, default=40)
    parser.add_argument("--count", type=int, default=20_000, help="datagrams per round")
    parser.add_argument("--pairs-per-cpu-s", type=float, default=None,
                        help="the farm's pairs per CPU second from bench_cyclic.py: the cost as a share of it")
    args = parser.parse_args()
    jitter = random.Random(7)
    figures: dict[bool, list[float]] = {False: [], True: []}
    for n in range(args.rounds):
        for measuring in ((False, True) if n % 2 else (True, False)):
            figures[measuring].append(round_ns(measuring, args.count, jitter))
    off, on = min(figures[False]), min(figures[True])
    print(f"O->T datagram taken by the table: {off:.0f} ns without measuring, {on:.0f} ns with "
          f"(+{on - off:.0f} ns, fastest of {args.rounds} rounds of {args.count:,} each)")
    if args.pairs_per_cpu_s:
        pair_ns = 1e9 / args.pairs_per_cpu_s
        print(f"the farm's CPU per pair at {args.pairs_per_cpu_s:,.0f} pairs/CPU-s: {pair_ns:.0f} ns; "
              f"measuring adds {100 * (on - off) / pair_ns:.1f} % of it")


if __name__ == "__main__":
    main()
