"""Issue 28, item 3: a scenario from the CLI (`enip-farm scenario validate|run`, progress lines, the
verdict table, the exit status, `--junit`) and from the HTTP API (start, status, result, cancel)."""

from __future__ import annotations

import subprocess
import time
import xml.etree.ElementTree as ElementTree

import httpx
import pytest
import yaml

from tests.helpers import CLI

pytestmark = pytest.mark.system

SCENARIO = """\
name: rack power dip
duration: 3 s
steps:
  - at: 100 ms
    id: dip
    fault: power-loss
    target: rack
    duration: 300 ms
    params: {boot_time_s: 0.2}
  - set: {spare.DI1: 1}
  - wait: spare.DI1 == 1
    timeout: 1 s
expect:
  - count(power lost, rack) == 2
  - count(reset done, rack) == 2
  - spare.DI1 == 1 within 200 ms of step 2
  - no connection timed out
"""


@pytest.fixture
def cell(tmp_path, free_address):
    first = free_address()
    for _ in range(2):
        free_address()
    path = tmp_path / "cell.yaml"
    path.write_text(yaml.safe_dump({
        "discovery": False,
        "devices": [{"name": "r{n}", "count": 2, "address": first, "model": "DSQC1030", "netmask": "255.0.0.0"},
                    {"name": "spare", "address": free_address(), "model": "DSQC1030"}],
        "groups": [{"name": "rack", "members": ["r*"]}]}))
    return path


def test_validate_lists_every_defect_and_run_prints_progress_a_table_and_junit(cell, tmp_path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("steps:\n  - {fault: link-down, target: rack9}\n  - {wait: spare.DI99 == 1}\n")
    checked = subprocess.run([*CLI, "scenario", "validate", str(bad), "--config", str(cell)], capture_output=True,
                             text=True, timeout=60)
    assert checked.returncode == 2 and checked.stdout == ""
    assert checked.stderr.splitlines() == [
        f"{bad}:2: step 1: target: 'rack9' is neither a device nor a group of the cell (groups: rack)",
        f"{bad}:3: step 2: wait: device 'spare': DI99: this device has 16 DI signals"]
    good = tmp_path / "good.yaml"
    good.write_text(SCENARIO)
    checked = subprocess.run([*CLI, "scenario", "validate", str(good), "--config", str(cell)], capture_output=True,
                             text=True, timeout=60)
    assert (checked.returncode, checked.stdout) == (0, f"{good}: 3 steps, 4 expectations: can run\n")
    junit = tmp_path / "verdicts.xml"
    ran = subprocess.run([*CLI, "scenario", "run", str(good), "--config", str(cell), "--junit", str(junit)],
                         capture_output=True, text=True, timeout=120)
    assert ran.returncode == 0, ran.stdout + ran.stderr
    lines = ran.stdout.splitlines()
    assert lines[0].endswith("step 1 (dip): power-loss on rack for 0.3 s boot_time_s=0.2")
    assert lines[1].endswith("step 2: set spare.DI1=1") and lines[3].endswith("step 3: spare.DI1 == 1: met")
    assert lines[4].startswith("PASS  count(power lost, rack) == 2") and lines[4].endswith("2 power lost")
    assert lines[-1].startswith("rack power dip: PASSED (")
    suite = ElementTree.parse(junit).getroot().find("testsuite")
    assert (suite.get("tests"), suite.get("failures"), suite.get("skipped")) == ("7", "0", "0")
    failing = tmp_path / "failing.yaml"
    failing.write_text(SCENARIO.replace("count(power lost, rack) == 2", "count(power lost, rack) == 3"))
    ran = subprocess.run([*CLI, "scenario", "run", str(failing), "--config", str(cell)], capture_output=True,
                         text=True, timeout=120)
    assert ran.returncode == 1 and "FAIL  count(power lost, rack) == 3" in ran.stdout
    assert ran.stdout.splitlines()[-1].startswith("rack power dip: FAILED (")


def test_the_http_api_starts_follows_and_cancels_a_scenario(enip_farm) -> None:
    farm = enip_farm({"devices": [{"name": "r{n}", "count": 2, "address": "127.0.0.1", "model": "DSQC1030"},
                                  {"name": "spare", "address": "127.0.0.1", "model": "DSQC1030"}],
                      "groups": [{"name": "rack", "members": ["r*"]}]}, http=True)
    base = f"http://127.0.0.1:{farm.http.port}"
    refused = httpx.post(f"{base}/scenarios", json={"text": "steps:\n  - {clear: rack9}\n", "source": "x.yaml"})
    assert refused.status_code == 422
    assert refused.json()["detail"]["problems"] == [
        "x.yaml:2: step 1: clear: 'rack9' is neither a device nor a group of the cell (groups: rack)"]
    started = httpx.post(f"{base}/scenarios", json={"text": SCENARIO})
    assert started.status_code == 201 and started.json() == {"id": 1, "name": "rack power dip", "status": "running"}
    assert httpx.get(f"{base}/scenarios/1/result").status_code == 409
    deadline = time.monotonic() + 30
    while (state := httpx.get(f"{base}/scenarios/1").json())["status"] == "running" and time.monotonic() < deadline:
        time.sleep(0.05)
    assert state["status"] == "passed" and len(state["progress"]) == 4
    assert httpx.get(f"{base}/scenarios/1/result").json() == state["result"]
    assert [v["passed"] for v in state["result"]["verdicts"]] == [True] * 4
    long = httpx.post(f"{base}/scenarios", json={"text": "steps:\n  - {fault: link-down, target: rack}\n"
                                                         "  - {wait: spare.DI2 == 1, timeout: 60 s}\n"}).json()
    assert long["id"] == 2
    while [f["kind"] for f in farm["r1"].faults] != ["link-down"] and time.monotonic() < deadline:
        time.sleep(0.01)
    cancelled = httpx.delete(f"{base}/scenarios/2").json()
    assert cancelled["status"] == "cancelled" and cancelled["result"]["status"] == "cancelled"
    assert farm["r1"].faults == [] and farm["r2"].faults == []  # nothing it set outlives it
    assert [run["status"] for run in httpx.get(f"{base}/scenarios").json()] == ["passed", "cancelled"]
    assert httpx.get(f"{base}/scenarios/9").status_code == 404
