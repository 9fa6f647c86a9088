"""Issue 28, items 3 and 4: scenarios run on a farm with a real originator (the `ethernetip` scanner
from PyPI, reconnecting as a controller does), judged, and undone however they end."""

from __future__ import annotations

import asyncio
import threading
import time
from pathlib import Path

import pytest

from enip_farm.scenario.run import run_scenario
from tests.scanners import Scanner, start_scanner
from tests.test_cell_faults import list_identity_answered

pytestmark = [pytest.mark.integration, pytest.mark.class1_paths]  # both class-1 paths (tests/conftest.py)

CELL = {"devices": [{"name": "io1", "address": "127.0.0.1", "model": "DSQC1030",
                     "implicit": {"first_watchdog_s": 0}},
                    {"name": "r2-io{n}", "count": 2, "address": "127.0.0.1", "model": "DSQC1030"}],
        "groups": [{"name": "rack2", "members": ["r2-*"]}]}

SCENARIO = """\
name: io1 link lost
duration: 3.5 s
steps:
  - at: 300 ms
    id: cut
    fault: link-down
    target: io1
    duration: 1500 ms
  - set: {r2-io1.DI3: 1}
expect:
  - io1.DO5 == 0 within 1 s of step cut
  - io1 reconnected within 3 s of end of step cut
  - no connection timed out outside io1
  - count(connection timed out, io1) == 1
"""


class Controller:
    """A controller's scanner: holds io1's DO5 at 1 over class 1 (RPI 10 ms, timeout x64: 640 ms, so that
    a late thread of the scanner on a loaded machine does not time it out) and,
    when its connection is gone, opens it again once the module answers ListIdentity."""

    def __init__(self, farm) -> None:
        self.device = farm.device("io1")
        self.address = self.device.profile.address
        self.stopped = threading.Event()
        self.opens = 0
        self.scan: Scanner | None = None
        self.thread = threading.Thread(target=self.run, daemon=True)
        self.thread.start()

    def open(self) -> None:
        self.scan = scan = start_scanner(self.address)
        scan.outputs[4] = True  # DO5
        if scan.forward_open(10, 4) == 0:
            scan.conn.produce()
            self.opens += 1

    def run(self) -> None:
        deadline = time.monotonic() + 60
        while not self.stopped.is_set() and time.monotonic() < deadline:
            if not self.device.connections and list_identity_answered(self.address, 0.05):
                self.close()
                self.open()
            time.sleep(0.01)
        self.close()

    def close(self) -> None:
        if self.scan is not None:
            self.scan.stop()

    def stop(self) -> None:
        self.stopped.set()
        self.thread.join(10)


@pytest.fixture
def cell(enip_farm, tmp_path):
    farm = enip_farm(CELL)
    controller = Controller(farm)
    try:
        assert _until(lambda: farm["io1"].get("DO5") == 1)
        yield farm, tmp_path
    finally:
        controller.stop()


def _until(predicate, timeout: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.005)
    return bool(predicate())


def test_a_link_down_scenario_passes_with_what_the_scanner_did(cell) -> None:
    farm, tmp_path = cell
    path = tmp_path / "link.yaml"
    path.write_text(SCENARIO)
    lines: list[str] = []
    result = farm.run_scenario(path, progress=lines.append)
    assert result.status == "passed", result.table()
    within, reconnected, quiet, count = result.verdicts
    # the module's watchdog: 640 ms after the scanner's last O->T, which came at most a few RPIs before the cut
    assert within.passed and 0 < float(within.figure.split()[1]) <= 1000
    assert reconnected.passed and quiet.figure == "none" and count.figure == "1 connection timed out"
    # judged from the report's reconnection (issue 27): the scanner's first O->T after its Forward
    # Open, once io1 came back from the link-down (the fault's end)
    io1 = next(d for d in farm.report().devices if d.device == "io1")
    back = [r for r in io1.reconnections if r.after == "fault cleared"]
    assert len(back) == 1 and back[0].originator == "127.0.0.1" and back[0].first_o_t_ns is not None
    assert reconnected.figure.startswith("last io1 after ") and reconnected.figure.endswith(
        f" (127.0.0.1: first O->T {back[0].first_o_t_after_ns / 1e6:.1f} ms, Forward Open "
        f"{back[0].forward_open_after_ns / 1e6:.1f} ms after it came back) (bound 3000.0 ms)")
    assert 0 < back[0].forward_open_after_ns <= back[0].first_o_t_after_ns
    assert [step.state for step in result.steps] == ["done", "done"]
    assert 0.3 <= result.steps[0].started_s < 0.3 + 0.1 and result.duration_s >= 3.5
    assert lines[0].endswith("step 1 (cut): link-down on io1 for 1.5 s") and "set r2-io1.DI3=1" in lines[1]
    assert farm["io1"].faults == [] and farm["r2-io1"].get("DI3") == 0  # nothing outlives the scenario
    assert "PASS  io1.DO5 == 0 within 1 s of step cut" in result.table()


def test_a_broken_expectation_fails_the_scenario_with_its_figure(cell) -> None:
    farm, tmp_path = cell
    path = tmp_path / "tight.yaml"
    path.write_text(SCENARIO.replace("within 1 s of step cut", "within 20 ms of step cut")
                    .replace("count(connection timed out, io1) == 1", "count(connection timed out, io1) == 0"))
    result = farm.run_scenario(path)
    assert result.status == "failed" and [v.passed for v in result.verdicts] == [False, True, True, False]
    assert result.verdicts[0].figure.endswith("(bound 20.0 ms)")
    xml = result.junit().tostring().decode()
    assert 'failures="2"' in xml and "expectation not met" in xml


def test_a_cancelled_scenario_clears_every_fault_and_signal_it_set(cell) -> None:
    farm, tmp_path = cell
    path = tmp_path / "long.yaml"
    path.write_text("""\
steps:
  - {fault: power-loss, target: rack2, params: {boot_time_s: 0}}
  - {set: {io1.DI3: 1}}
  - {wait: io1.DI4 == 1, timeout: 60 s}
""")
    scenario = farm.load_scenario(path)

    async def cancelled_soon():
        task = asyncio.ensure_future(run_scenario(farm, scenario))
        while farm["io1"].get("DI3") != 1:
            await asyncio.sleep(0.005)
        assert [f["kind"] for f in farm["r2-io1"].faults] == ["power-loss"]
        task.cancel()
        return await task

    result = farm.run(cancelled_soon())
    assert result.status == "cancelled" and [s.state for s in result.steps] == ["done", "done", "skipped"]
    assert farm["r2-io1"].faults == [] and farm["r2-io2"].faults == [] and farm["io1"].get("DI3") == 0


def test_a_wait_that_times_out_fails_its_step_and_skips_what_comes_after(cell) -> None:
    farm, tmp_path = cell
    path = tmp_path / "wait.yaml"
    path.write_text("""\
steps:
  - {fault: stop-io, target: r2-io1}
  - {wait: io1.DI4 == 1, timeout: 100 ms}
  - {clear: r2-io1}
""")
    result = farm.run_scenario(path)
    assert result.status == "failed" and [s.state for s in result.steps] == ["done", "failed", "skipped"]
    assert result.steps[1].detail == "io1.DI4 == 1 not met within 0.1 s"
    assert farm["r2-io1"].faults == []


def test_marking_a_step_never_waits_on_the_disk(tmp_path) -> None:
    """Farm.mark on the event loop hands the line to the recorder's thread: while an injected writer
    holds that thread, the loop goes on; once let go, FILE.steps holds every step in order, each
    stamped by the recorder's wall clock, exactly."""
    from enip_farm.capture.recorder import Recorder, append_line
    from enip_farm.farm.farm import Farm

    held, writing = threading.Event(), threading.Event()

    def slow(path: Path, line: str) -> None:
        writing.set()
        assert held.wait(10)
        append_line(path, line)

    stamps = iter([1_700_000_000.25, 1_700_000_001.5])
    farm = Farm({"devices": [{"name": "x", "address": "127.0.0.1", "model": "DSQC1030"}], "discovery": False})
    farm.recorder = Recorder(tmp_path / "cell.pcap", wall=lambda: next(stamps), append=slow)
    steps = tmp_path / "cell.pcap.steps"

    async def on_the_loop() -> None:
        farm.mark("step 1: link-down on x")
        farm.mark("step 2: set x.DI2=1")
        assert await asyncio.to_thread(writing.wait, 10)  # the writer holds the first line; the loop runs
        await asyncio.sleep(0.01)  # and its timers fire
        assert not steps.exists()

    asyncio.run(on_the_loop())
    held.set()
    farm.recorder.close()
    stamps = iter([1_700_000_002.0])
    farm.mark("step 3: late")  # after close: at once
    assert steps.read_text() == ("1700000000.250000 step 1: link-down on x\n1700000001.500000 step 2: set x.DI2=1\n"
                                 "1700000002.000000 step 3: late\n")


def test_each_step_is_marked_in_the_recording_and_the_event_logs(enip_farm, tmp_path) -> None:
    from enip_farm.farm.farm import Farm

    farm = enip_farm(CELL)
    path = tmp_path / "mark.yaml"
    path.write_text("steps:\n  - {fault: link-down, target: rack2, duration: 100 ms}\n  - {set: {io1.DI2: 1}}\n")
    record = tmp_path / "cell.pcap"
    recording = Farm({"devices": [{"name": "x", "address": farm["io1"].address.rsplit(".", 1)[0] + ".250",
                                   "model": "DSQC1030"}], "discovery": False}, record=record)
    recording.mark("step 1: link-down on x")  # a farm recording its traffic (serve --record) marks the steps
    recording.recorder.close()
    assert (tmp_path / "cell.pcap.steps").read_text().split(" ", 1)[1] == "step 1: link-down on x\n"
    result = farm.run_scenario(path)
    assert result.passed
    for name in ("r2-io1", "r2-io2"):
        assert [e.text for e in farm[name].events("scenario step")] == ["step 1: link-down on rack2 for 0.1 s"]
    assert [e.text for e in farm["io1"].events("scenario step")] == ["step 2: set io1.DI2=1"]
