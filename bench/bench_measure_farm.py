"""What the report's measurement costs a running farm: `enip-farm serve` with `cyclic_io: {measure:
true}` and `{measure: false}` in interleaved pairs (every other pair the unmeasured one first),
each carrying N connections at an RPI from bench_cyclic.py's C originator; the farm's CPU over a
window is `perf stat -e task-clock` of all its processes (the kernel's count of their CPU time,
read over exactly the window), divided by the pairs the originator moved in it. Each pair's
difference and their median are printed, with the medians of each side.

    python bench/bench_measure_farm.py                 # 8 pairs, 100 connections at 10 ms, 8 s windows
    python bench/bench_measure_farm.py --pairs 4 --connections 300

Needs perf (linux-perf) and, for the originator's SCHED_FIFO, root (as bench_cyclic.py).
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_cyclic as cyclic  # noqa: E402


def task_clock_ms(pids: list[int], seconds: float) -> float:
    """The CPU ms of these processes over the next `seconds` (perf stat's task-clock)."""
    result = subprocess.run(["perf", "stat", "-x,", "-e", "task-clock", "-p", ",".join(map(str, pids)), "--",
                             "sleep", str(seconds)], capture_output=True, text=True, timeout=seconds + 30)
    for line in result.stderr.splitlines():
        if "task-clock" in line:
            return float(line.split(",")[0])
    raise SystemExit(f"perf stat gave no task-clock: {result.stderr.strip()}")


def one(measure: bool, args: argparse.Namespace, originator: Path, work: Path) -> float:
    """The farm's CPU us per pair over one window."""
    config = work / "cell.yaml"
    cyclic.write_farm_config(config, args.connections, args.first_address, "", measure, "auto")
    farm = cyclic.start_farm(config, args.workers, None, work / "farm.log")
    try:
        pids = cyclic.descendants(farm.pid)
        udp = [cyclic.originator_socket()]
        try:
            hosts = [cyclic.address(i, args.first_address) for i in range(args.connections)]
            connections, _ = cyclic.forward_open(hosts, args.rpi_us, [udp[0].getsockname()[1]], 2)
            measured: dict[str, float] = {}

            def window() -> None:  # inside the originator's measured window, which is 2 s longer
                time.sleep(args.warmup + 1)
                measured["cpu_ms"] = task_clock_ms(pids, args.seconds)

            thread = threading.Thread(target=window)
            thread.start()
            figures = cyclic.drive(originator, connections, args.rpi_us, udp, args.seconds + 2, args.warmup, None,
                                   pids, work, lambda: (cyclic.forward_close(connections), {})[1], args.realtime)
            thread.join()
        finally:
            udp[0].close()
    finally:
        cyclic.stop(farm)
    pairs_per_s = (figures["o_t_received_window"] + figures["t_o_received_window"]) / 2 / (args.seconds + 2)
    return measured["cpu_ms"] * 1000 / (pairs_per_s * args.seconds)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--pairs", type=int, default=8)
    parser.add_argument("--connections", type=int, default=100)
    parser.add_argument("--rpi-us", type=int, default=10_000)
    parser.add_argument("--seconds", type=float, default=8.0, help="the CPU window (the originator's is 2 s longer)")
    parser.add_argument("--warmup", type=float, default=2.0)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--realtime", type=int, default=10)
    parser.add_argument("--first-address", default="127.0.241.1")
    args = parser.parse_args()
    originator = cyclic.build("cyclic_originator", ("-pthread",))
    on, off = [], []
    with tempfile.TemporaryDirectory(prefix="bench-measure-farm-") as tmp:
        for n in range(args.pairs):
            for measure in ((True, False) if n % 2 == 0 else (False, True)):
                (on if measure else off).append(one(measure, args, originator, Path(tmp)))
            print(f"pair {n + 1}: {on[-1]:.2f} us of farm CPU per pair measuring, {off[-1]:.2f} not "
                  f"({100 * (on[-1] / off[-1] - 1):+.1f} %)", flush=True)
    differences = [100 * (a / b - 1) for a, b in zip(on, off, strict=True)]
    print(f"{args.connections} connections at {args.rpi_us / 1000:g} ms, {args.pairs} pairs: median "
          f"{statistics.median(on):.2f} us per pair measuring, {statistics.median(off):.2f} not; median of "
          f"the pairs' differences {statistics.median(differences):+.1f} % (from {min(differences):+.1f} to "
          f"{max(differences):+.1f} %)")


if __name__ == "__main__":
    main()
