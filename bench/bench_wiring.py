"""Wiring benchmark: how soon after a write is acknowledged do the wired inputs follow?

A farm (in this process, background thread) wires harness.DO1-16 to robot.DI1-16. A client writes
the harness outputs with Set Attribute Single, N times with changing values, and notes when each
reply arrived; the farm notes (monotonic clock, same process) when the wired input changed. A
second client reads robot's inputs right after each acknowledgement. Reported: the delay from
acknowledgement to wired input (negative: wired before the reply was sent), p50 / p99 / max,
and how many immediate reads already saw the new value. Bounded in count and time; 127.0.0.0/8.

    python bench/bench_wiring.py [--writes 2000]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from contextlib import ExitStack
from pathlib import Path

from enip_farm.pytest_plugin import start_farm

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # the tests' raw client
from tests.helpers import RawClient  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--writes", type=int, default=2000)
    args = parser.parse_args()
    with ExitStack() as stack:
        farm = start_farm(stack, {"devices": [{"name": "harness", "model": "DSQC1030"},
                                              {"name": "robot", "model": "DSQC1030"}],
                                  "wires": [{"from": "harness.DO1-16", "to": "robot.DI1-16"}]})
        robot = farm.devices["robot"]
        with RawClient(farm["harness"].address) as writer, RawClient(farm["robot"].address) as reader:
            writer.register()
            reader.register()
            acks, seen_at_once = [], 0
            deadline = time.monotonic() + 60
            for i in range(args.writes):
                value = (i % 65535 + 1).to_bytes(2, "little")
                assert writer.set(4, 100, 3, value).general_status == 0
                acks.append((time.monotonic(), value))
                seen_at_once += reader.get(4, 101, 3).data == value
                if time.monotonic() > deadline:
                    break
        wired = [e.monotonic_ns / 1e9 for e in robot.events.of_kind("wired")]
    delays = sorted((w - a) * 1e3 for (a, _), w in zip(acks, wired, strict=False))
    print(f"writes {len(acks)}, wired events {len(wired)}")
    print(f"ack -> wired input, ms: p50 {statistics.median(delays):.3f}  "
          f"p99 {delays[int(len(delays) * 0.99)]:.3f}  max {delays[-1]:.3f}  (negative: before the reply)")
    print(f"reads right after the ack that saw the new inputs: {seen_at_once}/{len(acks)}")


if __name__ == "__main__":
    main()
