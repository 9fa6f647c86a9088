"""How long the CLI takes to answer: `enip-farm --help`, and `enip-farm io get io1` against a farm
with its HTTP API (one device on a free 127.x address, in a subprocess). Each command runs `--runs` times as
the installed `enip-farm` script would run it (a fresh interpreter each time), and so does
`python -c pass`, the floor; the median and the spread of the wall-clock time, and the median CPU
time (the steadier figure on a busy machine), are printed, and a JSON line. Issue 23's goal: both
under 0.25 s. `--tree PATH` measures another checkout (e.g. main before the CLI's lazy imports) the
same way. Where the time goes:
`python -X importtime -m enip_farm --help 2> imports.txt`.

    python bench/cli_startup.py [--runs 15] [--tree PATH]
"""

from __future__ import annotations

import argparse
import json
import os
import random
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _free_address() -> str:
    """A loopback address with TCP 44818 free (the farm's one device listens there)."""
    for _ in range(100):
        address = f"127.{random.randint(100, 250)}.{random.randint(0, 255)}.{random.randint(1, 254)}"
        with socket.socket() as sock:
            try:
                sock.bind((address, 44818))
            except OSError:
                continue
        return address
    raise SystemExit("no free loopback address")


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _timed(command: list[str], env: dict[str, str], cwd: Path, runs: int) -> tuple[list[float], list[float]]:
    """Wall-clock and CPU (user + system) seconds of each run: on a busy machine the CPU time is the
    steadier figure, the wall-clock one what a user waits."""
    walls, cpus = [], []
    for _ in range(runs):
        start = time.perf_counter()
        process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env, cwd=cwd)
        _, status, usage = os.wait4(process.pid, 0)
        walls.append(time.perf_counter() - start)
        cpus.append(usage.ru_utime + usage.ru_stime)
        process.returncode = os.waitstatus_to_exitcode(status)
        if process.returncode != 0:
            raise SystemExit(f"{' '.join(command)}: exit {process.returncode}")
    return walls, cpus


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=15)
    parser.add_argument("--tree", type=Path, default=ROOT, help="the checkout to measure")
    args = parser.parse_args()
    env = {**os.environ, "PYTHONPATH": str(args.tree.resolve())}  # run from the tree: it comes first on sys.path
    cli = [sys.executable, "-c", "import sys; from enip_farm.cli import main; sys.exit(main())"]  # the script's body
    port = _free_port()
    with tempfile.TemporaryDirectory() as tmp:
        cell = Path(tmp) / "cell.yaml"
        cell.write_text(f"devices:\n  - {{name: io1, address: {_free_address()}, model: DSQC1030}}\n"
                        "discovery: false\n")
        farm = subprocess.Popen([*cli, "serve", "--config", str(cell), "--http", str(port), "-q"], env=env,
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        try:
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline and farm.poll() is None:
                try:
                    socket.create_connection(("127.0.0.1", port), timeout=1).close()
                    break
                except OSError:
                    time.sleep(0.1)
            else:
                raise SystemExit(f"the farm did not start: {farm.stderr.read().decode() if farm.stderr else ''}")
            api = f"http://127.0.0.1:{port}"
            tree = args.tree.resolve()
            results = {"python": _timed([sys.executable, "-c", "pass"], env, tree, args.runs),  # the floor
                       "help": _timed([*cli, "--help"], env, tree, args.runs),
                       "io get": _timed([*cli, "io", "get", "io1", "--api", api], env, tree, args.runs)}
        finally:
            farm.terminate()
            farm.wait(30)
    figures = {}
    for name, (walls, cpus) in results.items():
        figures[name] = {"wall": round(statistics.median(walls), 4), "cpu": round(statistics.median(cpus), 4)}
        label = "python -c pass" if name == "python" else f"enip-farm {name}"
        print(f"{label:16}  median {statistics.median(walls) * 1000:6.1f} ms wall-clock (min "
              f"{min(walls) * 1000:.1f}, max {max(walls) * 1000:.1f}), {statistics.median(cpus) * 1000:6.1f} ms CPU; "
              f"{len(walls)} runs")
    print(json.dumps({"bench": "cli_startup", "tree": str(args.tree), "runs": args.runs, "median_s": figures}))


if __name__ == "__main__":
    main()
