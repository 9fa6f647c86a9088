"""The pytest plugin's report option (enip_farm/pytest_plugin.py): `--enip-report` attaches each
test's farm report to its result (a JUnit property), and `@pytest.mark.enip_bounds(...)` fails a
test whose cell broke a bound the test asked for, and only such a bound. Run as a pytest of its own."""

from __future__ import annotations

import json
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

pytestmark = pytest.mark.system

EXAMPLE = '''
import pytest

def _no_controller(farm):  # nothing answers DI3: every repetition times out
    return farm.reaction(set=("io1", "DI3", 1), expect=("io1", "DO5", 1), timeout=0.05, repeat=2)

@pytest.mark.enip_bounds(reaction_timeouts=0)
def test_asks_for_no_timeout(enip_farm):
    _no_controller(enip_farm(name="io1", model="DSQC1030"))

@pytest.mark.enip_bounds(reaction_timeouts=2)
def test_asks_for_at_most_two(enip_farm):
    _no_controller(enip_farm(name="io1", model="DSQC1030"))

def test_asks_nothing(enip_farm):  # the default bound (no timeout) informs, it does not fail the test
    _no_controller(enip_farm(name="io1", model="DSQC1030"))

def test_the_yaml_asks(enip_farm):
    farm = enip_farm({"bounds": {"reaction_timeouts": 1}, "devices": [{"name": "io1", "model": "DSQC1030"}]})
    _no_controller(farm)
'''


def test_the_report_is_attached_and_a_broken_bound_asked_for_fails_the_test(tmp_path: Path) -> None:
    (tmp_path / "test_cell.py").write_text(EXAMPLE)
    junit = tmp_path / "junit.xml"
    result = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "--enip-report",
                             f"--junitxml={junit}", "test_cell.py"], capture_output=True, text=True, timeout=120,
                            cwd=tmp_path)
    assert result.returncode == 1, result.stdout + result.stderr
    assert "2 failed, 2 passed" in result.stdout
    assert "FAILED test_cell.py::test_asks_for_no_timeout" in result.stdout
    assert "FAILED test_cell.py::test_the_yaml_asks" in result.stdout
    assert ("enip-farm: the cell broke bounds the test asked for:\n"
            "  reaction io1.DI3=1 -> io1.DO5=1: reactions timed out 2 repetitions > bound 0 (test)") in result.stdout
    assert "reactions timed out 2 repetitions > bound 1 (cell configuration)" in result.stdout
    cases = {case.get("name"): case for case in ET.parse(junit).getroot().iter("testcase")}
    assert set(cases) == {"test_asks_for_no_timeout", "test_asks_for_at_most_two", "test_asks_nothing",
                          "test_the_yaml_asks"}
    for name, case in cases.items():
        (prop,) = [p for p in case.iter("property") if p.get("name") == "enip_farm_report"]
        report = json.loads(prop.get("value"))
        (reaction,) = report["reactions"]
        assert (reaction["count"], reaction["timeouts"]) == (0, 2), name
        assert [d["device"] for d in report["devices"]] == ["io1"]
        expected = {"test_asks_for_at_most_two": "pass"}.get(name, "fail")
        assert reaction["verdict"] == expected, name


def test_without_the_option_nor_a_marker_nothing_is_attached(tmp_path: Path) -> None:
    (tmp_path / "test_cell.py").write_text(EXAMPLE)
    junit = tmp_path / "junit.xml"
    result = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", f"--junitxml={junit}",
                             "test_cell.py::test_asks_nothing"], capture_output=True, text=True, timeout=120,
                            cwd=tmp_path)
    assert result.returncode == 0, result.stdout + result.stderr
    assert not list(ET.parse(junit).getroot().iter("property"))
