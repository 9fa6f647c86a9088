"""What one connection table's class-1 calls cost, in process (cip/connection_table.py with its
schedule, cip/io_schedule.py, and its per-packet bookkeeping, cip/io_packets.py): CPU ns per call of
`receive_datagram` (an O->T datagram taken), `produce(now, horizon)` (a period of the cyclic I/O
thread, every stream due) and `get_timer()`, with 1 and with 4 connections (an exclusive owner and
input-only ones, each its own T->O stream). Each figure is the fastest round's thread CPU time per
call (the least disturbed round on a shared machine).

With `--against TREE`, the same measurement of another source tree of the farm (a worktree of an
older commit) runs in a child process, the two trees' rounds alternating, and the figures are shown
side by side with their ratio:

    python bench/bench_table.py
    git worktree add /tmp/base 091e66f && python bench/bench_table.py --against /tmp/base

Every loop is bounded in count. No sockets.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve()
MS = 1_000_000
T0 = 5_000 * MS
HOST = "127.0.0.9"
OWNER_PATH = bytes.fromhex("20 04 24 01 2C 64 2C 65")  # assembly 1, O->T 100, T->O 101
INPUT_ONLY_PATH = bytes.fromhex("20 04 24 01 2C C6 2C 65")  # O->T the heartbeat point 198


def measure(connections: int, calls: int) -> dict[str, float]:
    """One round: CPU ns per call of each of the table's class-1 calls."""
    import random

    from enip_farm.cip.admission import Originator
    from enip_farm.cip.assembly import AssemblyInstance
    from enip_farm.cip.connection_path import KeyIdentity
    from enip_farm.cip.connection_policy import ConnectionPolicy
    from enip_farm.cip.connection_table import ConnectionTable
    from enip_farm.protocol.connection import (
        ConnectionTriad,
        ConnectionType,
        ForwardOpenRequest,
        NetworkParameters,
        encode_io_packet,
    )

    assemblies = {"output": AssemblyInstance(100, 2, True), "input": AssemblyInstance(101, 2, False),
                  "configuration": AssemblyInstance(1, 0, True)}
    policy = ConnectionPolicy(
        rpi_min_us=2_000, rpi_max_us=10_000_000, max_class1_connections=8, max_class3_connections=6,
        outputs_off_on_idle=True, outputs_off_on_fault=True, first_watchdog_ns=10_000 * MS,
        input_only_point=198, listen_only_point=199, multicast_group="239.192.1.0")
    table = ConnectionTable(assemblies, policy, lambda: KeyIdentity(75, 7, 1030, (1, 1)), rng=random.Random(1))
    p2p = ConnectionType.POINT_TO_POINT
    opened = []
    for n in range(connections):
        o_t_size = 8 if n == 0 else 2  # sequence count + run/idle header + 2 bytes; a heartbeat
        request = ForwardOpenRequest(0x0A, 0x0E, 0, 0x7E570001 + n, ConnectionTriad(n + 1, 0x1234, 0xABCD), 2, 10_000,
                                     NetworkParameters(False, p2p, 2, False, o_t_size), 10_000,
                                     NetworkParameters(False, p2p, 2, False, 4), 0x01,
                                     OWNER_PATH if n == 0 else INPUT_ONLY_PATH)
        opened.append(table.forward_open(request, Originator(HOST), T0).connection)
    owner = opened[0].o_t_id
    datagrams = [encode_io_packet(owner, n, n, b"\x01\x00\x00\x00" + bytes([n & 0xFF, 0])) for n in range(1, calls + 1)]
    figures = {}
    receive = table.receive_datagram
    start = time.thread_time_ns()
    for n in range(calls):
        receive(datagrams[n], HOST, T0 + n, 2222)
    figures["receive_datagram"] = (time.thread_time_ns() - start) / calls
    assert table.counters["o_t_packets"] == calls, table.counters
    produce, now = table.produce, T0
    start = time.thread_time_ns()
    for _ in range(calls):
        now += 10 * MS
        produce(now, now + MS)
    figures["produce"] = (time.thread_time_ns() - start) / calls
    assert table.counters["t_o_packets"] == calls * connections, table.counters
    get_timer = table.get_timer
    start = time.thread_time_ns()
    for _ in range(calls):
        get_timer()
    figures["get_timer"] = (time.thread_time_ns() - start) / calls
    return figures


def child(tree: Path, rounds: int, calls: int) -> dict[str, dict[str, float]]:
    """This script's measurement of `tree`, in a child process."""
    run = subprocess.run([sys.executable, str(HERE), "--rounds", str(rounds), "--calls", str(calls), "--json-out"],
                         env={**os.environ, "PYTHONPATH": str(tree)}, capture_output=True, text=True, timeout=600,
                         check=True)
    return json.loads(run.stdout)


def fastest(rounds: list[dict[str, dict[str, float]]]) -> dict[str, dict[str, float]]:
    return {k: {call: min(r[k][call] for r in rounds) for call in rounds[0][k]} for k in rounds[0]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=15, help="rounds per side; the fastest is shown")
    parser.add_argument("--calls", type=int, default=20_000, help="calls of each kind per round")
    parser.add_argument("--against", type=Path, help="another source tree of the farm, measured alternately")
    parser.add_argument("--json-out", action="store_true", help=argparse.SUPPRESS)  # a child's answer
    args = parser.parse_args()
    if args.json_out:
        sys.path.insert(0, os.environ.get("PYTHONPATH", str(HERE.parent.parent)))
        rounds = [{f"{k} connections": measure(k, args.calls) for k in (1, 4)} for _ in range(args.rounds)]
        print(json.dumps(fastest(rounds)))
        return
    trees = [HERE.parent.parent] + ([args.against.resolve()] if args.against else [])
    results: list[list[dict]] = [[] for _ in trees]
    for _ in range(min(args.rounds, 100)):  # alternating, one round each: drift falls on both alike
        for side, tree in enumerate(trees):
            results[side].append(child(tree, 1, args.calls))
    figures = [fastest(rounds) for rounds in results]
    print(f"CPU ns per call, the fastest of {args.rounds} rounds of {args.calls:,} calls"
          + (f"; this tree against {args.against}" if args.against else ""))
    print("| connections | call | this tree |" + (" other tree | this / other |" if args.against else ""))
    print("|---|---|---:|" + ("---:|---:|" if args.against else ""))
    for k, calls in figures[0].items():
        for call, ns in calls.items():
            row = f"| {k.split()[0]} | {call} | {ns:.0f} |"
            if args.against:
                other = figures[1][k][call]
                row += f" {other:.0f} | {ns / other:.3f} |"
            print(row)


if __name__ == "__main__":
    main()
