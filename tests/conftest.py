"""The project's tests use the pytest plugin's `enip_farm` fixture (enip_farm/pytest_plugin.py).

Tiers (markers registered in pyproject.toml): a test that takes the `enip_farm` fixture (directly
or through the fixtures below) is `integration`, marked here; tests that bind or connect sockets
otherwise say `integration` themselves; tests that start subprocesses, need root or a network
namespace say `system`. Everything else is a unit test: it runs in-process, and opening a socket or
starting a process from one fails it, so a mis-tiered test cannot pass unnoticed.
"""

from __future__ import annotations

import os
import socket
import subprocess
import tempfile
from collections.abc import Callable, Iterator, Mapping
from types import MappingProxyType
from typing import Any

import pytest

from enip_farm.farm.farm import Farm
from tests.helpers import ROOT
from tests.virtual_clock import Scenario, VirtualClockLoop, run_on

# Subprocesses (`python -m enip_farm`, pytest of the README example) import the tree under test,
# not whatever copy is installed, whatever their working directory.
os.environ["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))
# Hypothesis (tests/test_fuzz.py) keeps no example database (its settings say so) and caches what
# it learns of the source outside the tree, never in .hypothesis/ under the working directory.
os.environ.setdefault("HYPOTHESIS_STORAGE_DIRECTORY", os.path.join(tempfile.gettempdir(), "enip-farm-hypothesis"))


# -- no silent skips on CI ------------------------------------------------------------------------------
# A test skips where its tool or privilege is missing (tshark, kubectl, chromium, root, a network
# namespace, a Docker engine). On CI (.ci/run exports CI=1) every skip fails instead, so the suite
# cannot shrink unnoticed when an install step breaks, except the skips below: what CI can never
# have, matched by a part of the skip's reason, each with why. The summary prints them.
CI_MAY_SKIP: Mapping[str, str] = MappingProxyType({
})
_ALLOWED_SKIPS = pytest.StashKey[list[tuple[str, str]]]()  # (test, reason) skipped on CI under CI_MAY_SKIP


def _skip_reason(report: pytest.TestReport | pytest.CollectReport) -> str:
    longrepr = report.longrepr
    reason = longrepr[2] if isinstance(longrepr, tuple) else str(longrepr)
    return reason.removeprefix("Skipped: ")


def _fail_skip_on_ci(config: pytest.Config, report: pytest.TestReport | pytest.CollectReport) -> None:
    if not os.environ.get("CI") or not report.skipped or hasattr(report, "wasxfail"):
        return
    reason = _skip_reason(report)
    if any(part in reason for part in CI_MAY_SKIP):
        config.stash.setdefault(_ALLOWED_SKIPS, []).append((report.nodeid, reason))
        return
    report.outcome = "failed"
    report.longrepr = (f"skipped on CI (CI={os.environ['CI']}): {reason}\nCI must have what this test needs "
                       "(.ci/run installs it); if CI never can, add the reason to CI_MAY_SKIP in tests/conftest.py")


# -- the two class-1 paths ------------------------------------------------------------------------------
# A module marked `pytestmark = pytest.mark.class1_paths` runs each of its tests twice: on the native
# path (server/native.py; on CI the extension must be built, or the test fails) and on the Python one.
def pytest_generate_tests(metafunc: pytest.Metafunc) -> None:
    marked = metafunc.definition.get_closest_marker("class1_paths") is not None
    if marked and "class1_path" not in metafunc.fixturenames:
        metafunc.fixturenames.insert(0, "class1_path")  # first: before any fixture that starts a farm
    if "class1_path" in metafunc.fixturenames:
        metafunc.parametrize("class1_path", ["native", "python"], indirect=True)


@pytest.fixture
def class1_path(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> str:
    """Which class-1 path the farms this test starts run (ENIP_FARM_NATIVE)."""
    from enip_farm.server.native import BUILT, ENVIRONMENT

    path: str = request.param
    if path == "native" and not BUILT:
        message = "the native class-1 extension (enip_farm/server/_class1.c) is not built"
        if os.environ.get("CI") or os.environ.get("ENIP_FARM_REQUIRE_NATIVE") == "1":
            pytest.fail(message + " (CI builds it: pip install -e .)")
        pytest.skip(message)
    monkeypatch.setenv(ENVIRONMENT, "1" if path == "native" else "0")
    return path


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo) -> Iterator[None]:
    outcome = yield
    _fail_skip_on_ci(item.config, outcome.get_result())


@pytest.hookimpl(hookwrapper=True)
def pytest_make_collect_report(collector: pytest.Collector) -> Iterator[None]:
    outcome = yield
    _fail_skip_on_ci(collector.config, outcome.get_result())


def pytest_terminal_summary(terminalreporter: Any) -> None:
    if not os.environ.get("CI"):
        return
    write = terminalreporter.write_line
    terminalreporter.section("skips allowed on CI (tests/conftest.py CI_MAY_SKIP)")
    for part, why in CI_MAY_SKIP.items() or {"(none)": "every skip fails on CI"}.items():
        write(f"{part}: {why}")
    for nodeid, reason in terminalreporter.config.stash.get(_ALLOWED_SKIPS, []):
        write(f"skipped {nodeid}: {reason}")


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        if "enip_farm" in getattr(item, "fixturenames", ()) and item.get_closest_marker("system") is None:
            item.add_marker(pytest.mark.integration)


@pytest.fixture(autouse=True)
def _unit_tests_stay_in_process(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    if request.node.get_closest_marker("integration") or request.node.get_closest_marker("system"):
        yield
        return

    def refuse(what: str) -> Callable[..., Any]:
        def refused(*args: object, **kwargs: object) -> None:
            raise AssertionError(f"a unit test {what}: mark it integration (sockets) or system (processes)")
        return refused

    for name in ("bind", "connect", "connect_ex", "sendto"):
        monkeypatch.setattr(socket.socket, name, refuse(f"called socket.{name}"))
    monkeypatch.setattr(subprocess.Popen, "__init__", refuse("started a process"))
    yield


@pytest.fixture
def on_virtual_clock() -> Iterator[Callable[..., None]]:
    """Runs a scenario with a farm (built, not serving) whose loop is a virtual clock (tests/virtual_clock.py)."""
    loop = VirtualClockLoop()

    def run(scenario: Scenario, address: str = "127.0.0.1") -> None:
        run_on(loop, scenario, address)

    yield run
    loop.close()


@pytest.fixture
def make_farm(enip_farm: Callable[..., Farm]) -> Callable[..., Farm]:
    """Several device dicts at once: make_farm({"name": "a", "model": "DSQC1030"}, ..., discovery=True)."""

    def factory(*devices: dict[str, Any], discovery: bool = False) -> Farm:
        return enip_farm({"devices": list(devices)}, discovery=discovery)

    return factory


@pytest.fixture
def dsqc1030(enip_farm: Callable[..., Farm]) -> str:
    """The address of one fresh DSQC1030."""
    return enip_farm(name="io1", model="DSQC1030")["io1"].address
