"""No silent skips on CI (issue 32): with CI set (.ci/run exports CI=1) a skip fails the run, unless
tests/conftest.py's CI_MAY_SKIP allows its reason; the summary says what CI may skip. The probe
below skips only when a run of this file asks it to."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from tests.helpers import ROOT, STARTUP_S

PROBE = "ENIP_FARM_SKIP_PROBE"


@pytest.mark.parametrize("what", ["skip", "xfail"])
def test_probe(what: str) -> None:
    if os.environ.get(PROBE) and what == "skip":
        pytest.skip("the probe's tool is not installed")
    if os.environ.get(PROBE) and what == "xfail":
        pytest.xfail("an expected failure is no skip")


def _probe(ci: str | None) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != "CI"}
    env.update({PROBE: "1", **({"CI": ci} if ci is not None else {})})
    return subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-rA",
                           f"{__file__}::test_probe"], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=4 * STARTUP_S)


@pytest.mark.system
def test_a_skip_fails_on_ci_and_only_there() -> None:
    on_ci = _probe("1")
    assert on_ci.returncode == 1, on_ci.stdout
    assert "skipped on CI (CI=1): the probe's tool is not installed" in on_ci.stdout
    assert "skips allowed on CI (tests/conftest.py CI_MAY_SKIP)" in on_ci.stdout
    assert on_ci.stdout.splitlines()[-1].startswith("1 failed, 1 xfailed in "), on_ci.stdout
    here = _probe(None)
    assert here.returncode == 0 and here.stdout.splitlines()[-1].startswith("1 skipped, 1 xfailed in "), here.stdout
    assert "CI_MAY_SKIP" not in here.stdout
