"""A long network fuzz run against a running farm (tests/network_fuzz.py, the harness of
tests/test_network_fuzz.py): `enip-farm serve` with five DSQC1030s, two of them fuzzed on TCP 44818
(structure-aware frames in batches, every reply checked by an independent mirror), every one sent
mutated datagrams on UDP 2222 and 44818, three running class-1 connections at 20 ms whose T->O is
stamped by the kernel, and an explicit prober. Bounded by time and by frames. Prints the figures and
exits 1 on the first failure (its seed replays it: `--seed N`).

    python bench/network_fuzz.py --seconds 1200 --frames 2000000 [--seed N] [--batch 32]
"""

from __future__ import annotations

import argparse
import random
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # the tree under test and its tests
from tests.network_fuzz import FuzzFailure, fuzz_farm  # noqa: E402


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=600.0)
    parser.add_argument("--frames", type=int, default=2_000_000)
    parser.add_argument("--batch", type=int, default=32, help="largest batch of frames sent back to back")
    parser.add_argument("--seed", type=int, default=None)
    parser.add_argument("--block", type=int, default=201, help="the 127.BLOCK.0.x addresses to use")
    args = parser.parse_args()
    seed = args.seed if args.seed is not None else random.SystemRandom().getrandbits(32)
    print(f"seed {seed} (replay: --seed {seed})", flush=True)
    addresses = [f"127.{args.block}.0.{i}" for i in range(1, 6)]
    batches = (1, 2, 8, args.batch, args.batch)
    with tempfile.TemporaryDirectory() as workdir:
        try:
            report = fuzz_farm(Path(workdir), addresses, args.seconds, seed, args.frames, batches)
        except FuzzFailure as failure:
            print(f"FAILED: {failure}")
            return 1
    print("\n".join(report.lines()))
    problems = []
    if report.close_statuses != [0, 0, 0]:
        problems.append("a class-1 connection was timed out by the farm")
    if not report.health.get("ok") or report.health.get("loop_errors") or report.health["cyclic_io"]["errors"]:
        problems.append("the farm was not healthy or met errors")
    if "Traceback" in report.farm_log or " ERROR " in report.farm_log:
        problems.append("the farm logged an error")
    for problem in problems:
        print(f"FAILED: {problem}")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
