"""Long fuzz runs of the sans-IO layers, in-process, without hypothesis's overhead.

The generators and the independent checkers of tests/fuzzing.py in a tight seeded loop, in turn:
- a session run: a new DSQC1030 and two TCP connections to it one after the other, each fed 40
  structure-aware frames split at random points, every reply held by the `SessionMirror`, the
  device's timer turned now and then (T->O packets checked);
- a table run: 200 random operations on a new connection table (Forward Opens, O->T datagrams,
  Forward Closes, session ends, timer turns), its invariants checked after each;
- 100 random or structured class-1 packets, `decode_io_packet` against the reference decoder.
An input is a frame, a table operation or a packet. Bounded by count and by time; prints the
rate, the totals and every failure with the seed that replays it:

    python bench/fuzz.py [--inputs 1000000] [--seconds 900] [--seed 1]
    python bench/fuzz.py --replay session:1234567   # one run again, with its traceback

Unhandled exceptions are those that escape and those the farm caught and logged at ERROR (the
message router's last resort); malformed replies are the checker's findings. Exit status 1 if any.
"""

from __future__ import annotations

import argparse
import random
import struct
import sys
import time
import traceback
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # the tree under test and its tests
from enip_farm.device.device import Device  # noqa: E402
from enip_farm.protocol.connection import decode_io_packet  # noqa: E402
from tests.fuzzing import (  # noqa: E402
    MS,
    Malformed,
    SessionRun,
    TableFuzzer,
    dsqc1030_profile,
    logged_errors,
    reference_decode_io_packet,
)

SESSIONS_PER_RUN, FRAMES_PER_SESSION, TABLE_STEPS, PACKETS = 2, 40, 200, 100


def session_run(seed: int, profile: object, statistics: Counter) -> int:
    rng = random.Random(seed)
    device = Device(profile)  # type: ignore[arg-type]
    now = rng.getrandbits(50)
    inputs = 0
    for _ in range(SESSIONS_PER_RUN):
        run = SessionRun(rng, device, now)
        try:
            run.run(FRAMES_PER_SESSION)
        finally:
            inputs += run.inputs
            statistics["replies checked"] += run.mirror.replies
            statistics["successful CIP replies"] += run.mirror.cip_statuses.get(0, 0)
            statistics["connections opened over SendRRData"] += len(run.mirror.connections)
        now = run.now + rng.choice((0, MS, 30_000 * MS))
    return inputs


def table_run(seed: int, profile: object, statistics: Counter) -> int:
    fuzzer = TableFuzzer(random.Random(seed))
    try:
        for _ in range(TABLE_STEPS):
            fuzzer.step()
    finally:
        statistics.update({f"table: {name}": count for name, count in fuzzer.operations.items()})
    return fuzzer.inputs


def packet_run(seed: int, profile: object, statistics: Counter) -> int:
    rng = random.Random(seed)
    for _ in range(PACKETS):
        if rng.random() < 0.3:
            packet = rng.randbytes(rng.randint(0, 40))
        else:
            data = rng.randbytes(rng.randint(0, 40))
            fields = [2, 0x8002, 8, rng.getrandbits(32), rng.getrandbits(32), 0x00B1, 2 + len(data),
                      rng.getrandbits(16)]
            if rng.random() < 0.5:
                at = rng.randrange(len(fields))
                fields[at] = rng.getrandbits(16) if at not in (3, 4) else rng.getrandbits(32)
            packet = struct.pack("<HHHIIHHH", *fields) + data
            if rng.random() < 0.1:
                packet = packet[: rng.randint(0, len(packet))] if rng.random() < 0.5 else packet + b"\x00"
        decoded = decode_io_packet(packet)
        if (None if decoded is None else tuple(decoded)) != reference_decode_io_packet(packet):
            raise Malformed(f"decode_io_packet({packet.hex()}) = {decoded}")
        statistics["packets decoded" if decoded else "packets refused"] += 1
    return PACKETS


RUNS = {"session": session_run, "table": table_run, "packets": packet_run}
ROTATION = ["session", "session", "session", "table", "session", "packets"]  # 320 frames, 200 operations, 100


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--inputs", type=int, default=1_000_000, help="stop after this many inputs")
    parser.add_argument("--seconds", type=float, default=900.0, help="and after this long")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--replay", metavar="KIND:SEED", help="run one session/table/packets run again")
    args = parser.parse_args()
    profile = dsqc1030_profile()

    if args.replay:
        kind, seed = args.replay.split(":")
        with logged_errors() as errors:
            RUNS[kind](int(seed), profile, Counter())
        for record in errors:
            print(f"logged: {record.getMessage()}\n{record.exc_text or ''}")
        print("replayed without an escaped exception" + (f", {len(errors)} logged error(s)" if errors else ""))
        return 1 if errors else 0

    rng = random.Random(args.seed)
    inputs: Counter = Counter()
    statistics: Counter = Counter()
    failures: list[str] = []
    unhandled = malformed = logged = 0
    start = time.perf_counter()
    report = start + 10
    turn = 0
    with logged_errors() as errors:
        while sum(inputs.values()) < args.inputs and time.perf_counter() - start < args.seconds:
            kind = ROTATION[turn % len(ROTATION)]
            turn += 1
            seed = rng.getrandbits(64)
            before = len(errors)
            try:
                inputs[kind] += RUNS[kind](seed, profile, statistics)
            except Malformed as error:
                malformed += 1
                failures.append(f"malformed: {error} (--replay {kind}:{seed})")
            except Exception:  # noqa: BLE001 - counting them is the point
                unhandled += 1
                failures.append(f"unhandled: {traceback.format_exc(limit=-3)} (--replay {kind}:{seed})")
            if len(errors) > before:
                logged += len(errors) - before
                failures.append(f"logged: {errors[before].getMessage()} (--replay {kind}:{seed})")
            if time.perf_counter() > report:
                report += 10
                total = sum(inputs.values())
                print(f"  {total:>9,} inputs, {total / (time.perf_counter() - start):,.0f}/s", flush=True)
    elapsed = time.perf_counter() - start
    total = sum(inputs.values())
    print(f"seed {args.seed}: {total:,} inputs in {elapsed:.1f} s, {total / elapsed:,.0f} inputs/s "
          f"({inputs['session']:,} frames, {inputs['table']:,} table operations, {inputs['packets']:,} packets)")
    for name, count in sorted(statistics.items()):
        print(f"  {name}: {count:,}")
    print(f"unhandled exceptions: {unhandled + logged} ({unhandled} escaped, {logged} caught and logged); "
          f"malformed replies or broken invariants: {malformed}")
    for failure in failures[:20]:
        print(failure)
    return 1 if unhandled or logged or malformed else 0


if __name__ == "__main__":
    sys.exit(main())
