"""The farm's verdicts on a misbehaving originator (issue 27, item 5): bench/misbehaviour.py's modes of
bench/cyclic_originator.c, all at once on one farm, each on its own device, 300 deadlines at RPI
20 ms. Each mode fails exactly the bounds it breaks and passes every other; its counts equal what
the originator says it made (gaps, repeats, stale packets, bursts, run/idle transitions counted by
sequence number, so a busy machine cannot blur them); its times lie within both bounds of what it
sent (the jitter's p99 between 1.5 and 2 API, a gap's interval between 2.5 and 3.5, a burst's
silence between 3.5 and 4.5; a reconnection 1 s after the device is back, within 2 s more)."""

from __future__ import annotations

import os
import shutil
import sys
from contextlib import ExitStack
from pathlib import Path

import pytest

from enip_farm.pytest_plugin import AddressPool, start_farm

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "bench"))

import misbehaviour  # noqa: E402

pytestmark = [pytest.mark.system, pytest.mark.class1_paths,  # both class-1 paths (tests/conftest.py)
              pytest.mark.skipif(not (os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")),
                                 reason="no C compiler")]

RPI_MS, DEADLINES = 20, 300


@pytest.fixture(scope="module")
def rows(free_address: AddressPool) -> dict[str, dict]:
    with ExitStack() as stack:
        farm = start_farm(stack, free_address, misbehaviour.cell())
        realtime = 10 if os.geteuid() == 0 else 0  # SCHED_FIFO: the originator sends on time on a busy machine
        return {row["mode"]: row for row in misbehaviour.run_all(farm, RPI_MS, DEADLINES, realtime)}


EXPECTED = {
    "none": [],
    "jitter": ["interval p99"],
    "gap": ["intervals of 2 API or more", "sequence numbers lost"],
    "burst": ["intervals of 2 API or more"],
    "repeat": ["sequence numbers repeated"],
    "stale": ["stale sequence numbers"],
    "idle": [],
}


@pytest.mark.parametrize("mode", list(EXPECTED))
def test_each_mode_fails_exactly_its_bounds_with_the_counts_it_made(rows: dict[str, dict], mode: str) -> None:
    row = rows[mode]
    assert row["failed"] == EXPECTED[mode]
    assert all(v["verdict"] in ("pass", "fail") for v in row["figures"]["verdicts"])  # judged, not too short
    assert row["counts"] == row["expected_counts"]
    assert row["outside"] == {}, row["times_api"]
    made = row["made"]
    assert made["deadlines"] == DEADLINES and made["last_sequence"] == DEADLINES
    assert row["ok"]


def test_the_counts_are_the_modes_own(rows: dict[str, dict]) -> None:
    """The sizes chosen: 2 gaps of 2, 2 bursts of 3 held, 30 repeats, 30 stale, 5 toggles in 300."""
    assert (rows["gap"]["made"]["gap_runs"], rows["gap"]["made"]["gaps"]) == (2, 4)
    assert rows["gap"]["figures"]["sequence"]["lost"] == 4
    assert rows["burst"]["figures"]["intervals"]["late"] == rows["burst"]["made"]["bursts"] == 2
    assert rows["repeat"]["figures"]["sequence"]["repeats"] == 30
    assert rows["stale"]["figures"]["sequence"]["stale"] == 30
    assert rows["idle"]["figures"]["run_idle"]["transitions"] == 1 + 5  # idle to run at the first packet, then 5


def test_a_delayed_reconnection_fails_its_bound_and_nothing_else(rows: dict[str, dict]) -> None:
    row = rows["reconnect"]
    assert row["failed"] == row["expected_fails"]
    reconnection = row["reconnection"]
    delay_ns = misbehaviour.RECONNECT_DELAY_S * 1e9
    assert delay_ns <= reconnection["forward_open_after_ns"] <= delay_ns + misbehaviour.RECONNECT_SLACK_S * 1e9
    assert reconnection["forward_open_after_ns"] <= reconnection["first_o_t_after_ns"]
    assert row["ok"]


def test_the_table_lists_every_mode(rows: dict[str, dict]) -> None:
    text = misbehaviour.table(list(rows.values()))
    assert [line.split(" | ")[0].strip("| ") for line in text.splitlines()[2:]] == list(misbehaviour.MODE_NAMES)
    assert " NO |" not in text
