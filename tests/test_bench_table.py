"""bench/bench_table.py still runs against the connection table's API and counts what it asks for
(its own asserts: every O->T datagram taken, one T->O packet per stream and period). Figures
belong to the benchmark; this holds only its shape: six rows, both trees' columns."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


@pytest.mark.system
def test_the_table_bench_runs_and_compares_two_trees() -> None:
    run = subprocess.run([sys.executable, str(ROOT / "bench" / "bench_table.py"), "--rounds", "1", "--calls", "200",
                          "--against", str(ROOT)], capture_output=True, text=True, timeout=120, check=True)
    rows = [line.split("|")[1:-1] for line in run.stdout.splitlines() if line.startswith("| ") and "call" not in line]
    assert [(row[0].strip(), row[1].strip()) for row in rows] == [
        (k, call) for k in ("1", "4") for call in ("receive_datagram", "produce", "get_timer")]
    assert all(float(row[2]) > 0 and float(row[3]) > 0 and float(row[4]) > 0 for row in rows)
