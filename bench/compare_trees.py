"""Run one benchmark against two source trees of the farm, interleaved, in one run, and print the
medians side by side with their ratio: how a change moved the figures on the same machine at the
same time (drift on a shared machine hits both alike).

    git worktree add /tmp/base 913aed5
    python bench/compare_trees.py --base /tmp/base --bench explicit --runs 3
    python bench/compare_trees.py --base /tmp/base --bench implicit --runs 3 -- --connections 200 --seconds 20

Each run starts the benchmark script of this tree with PYTHONPATH set to the tree under test, so
the farm it starts (`python -m enip_farm serve`) is that tree's; the measuring client is the same
script for both. Every loop is bounded (runs x the benchmark's own bounds).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent


def run_once(bench: str, tree: Path, extra: list[str], out: Path) -> list[dict]:
    env = {**os.environ, "PYTHONPATH": str(tree)}
    command = [sys.executable, str(HERE / f"bench_{bench}.py"), "--json", str(out), *extra]
    subprocess.run(command, env=env, check=True, stdout=subprocess.DEVNULL, timeout=1800)
    data = json.loads(out.read_text())
    if bench == "explicit":  # {"farm": [round, ...], "minimal": [...]}: the farm's rounds, and the reference's
        return [{**farm, **{f"minimal_{k}": v for k, v in minimal.items() if k != "server"}}
                for farm, minimal in zip(data["farm"], data["minimal"], strict=True)]
    return data[:-1] if len(data) > 1 else data  # with --repeat, the last entry is their median


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--base", type=Path, required=True, help="the tree to compare against (a worktree)")
    parser.add_argument("--new", type=Path, default=HERE.parent, help="the tree under test (default: this one)")
    parser.add_argument("--bench", choices=("explicit", "implicit"), required=True)
    parser.add_argument("--runs", type=int, default=3, help="runs per tree, interleaved base/new")
    parser.add_argument("extra", nargs="*", help="arguments for the benchmark (after --)")
    args = parser.parse_args()
    samples: dict[str, list[dict]] = {"base": [], "new": []}
    with tempfile.TemporaryDirectory() as tmp:
        for n in range(args.runs):
            for label, tree in (("base", args.base), ("new", args.new)):
                samples[label] += run_once(args.bench, tree.resolve(), args.extra, Path(tmp) / f"{label}{n}.json")
                print(f"run {n + 1}/{args.runs} {label} done", file=sys.stderr)
    keys = [k for k, v in samples["new"][0].items() if isinstance(v, (int, float)) and not isinstance(v, bool)]
    print(f"medians of {len(samples['base'])} samples per tree, interleaved; base {args.base}, new {args.new}")
    print(f"{'metric':40} {'base':>12} {'new':>12} {'new/base':>9}")
    for key in keys:
        base = statistics.median(s[key] for s in samples["base"])
        new = statistics.median(s[key] for s in samples["new"])
        ratio = f"{new / base:9.3f}" if base else f"{'-':>9}"
        print(f"{key:40} {base:12.2f} {new:12.2f} {ratio}")


if __name__ == "__main__":
    main()
