"""Summarise py-spy's raw stacks (`py-spy record --format raw`, as bench_cyclic.py --py-spy writes
them): the share of samples each function takes itself and with what it calls, every file given
together; `root`: the outermost frame of each stack (a thread's start).

    python bench/profile_summary.py DIR/farm-*.txt [--top 25]
"""

from __future__ import annotations

import argparse
import re
from collections import Counter
from pathlib import Path

_LINE = re.compile(r":\d+\)$")


def summary(files: list[Path], top: int) -> str:
    own: Counter[str] = Counter()
    within: Counter[str] = Counter()
    threads: Counter[str] = Counter()
    total = 0
    for path in files:
        for line in path.read_text(errors="replace").splitlines():
            stack, _, count = line.rpartition(" ")
            if not stack or not count.isdigit():
                continue
            samples = int(count)
            frames = [_LINE.sub(")", frame) for frame in stack.split(";")]  # per function, not per line
            total += samples
            threads[frames[0]] += samples
            own[frames[-1]] += samples
            for frame in set(frames[1:]):
                within[frame] += samples
    if not total:
        return "no samples"
    lines = [f"{total} samples"]
    lines += [f"{n / total:6.1%} root   {name}" for name, n in threads.most_common(8)]
    lines += [f"{n / total:6.1%} self   {name}" for name, n in own.most_common(top)]
    lines += [f"{n / total:6.1%} within {name}" for name, n in within.most_common(top)]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("files", nargs="+", type=Path)
    parser.add_argument("--top", type=int, default=25)
    args = parser.parse_args()
    print(summary(args.files, args.top))


if __name__ == "__main__":
    main()
