"""pytest plugin, registered through the `pytest11` entry point: the `enip_farm` fixture.

    def test_sensor_reaches_controller(enip_farm):
        farm = enip_farm(name="io1", model="DSQC1030")
        farm["io1"].set(DI3=1)
        ...

The report on the controller under test (`farm.report()`, cip/report.py): `--enip-report` (or the
ini option `enip_report = true`) attaches every farm's report of a test to its result (JSON, a user
property `enip_farm_report`, so `--junitxml` carries it), and a test marked
`@pytest.mark.enip_bounds(interval_p99_api=1.2, reaction_p99_ms=30, ...)` fails when its cell broke
a bound it asked for: the marker's, or the cell's YAML `bounds:` (the defaults only inform).

`enip_farm(...)` takes a config file path (a cell's YAML, or a controller's EIO.cfg, imported as
`enip-farm eio import` does, its warnings raised as one `EioImportWarning`), a config dict, or one
device's fields as keyword arguments. Devices go on fresh 127.x addresses (each test process takes
its own block, so parallel tests never collide) unless `keep_addresses=True`. The farm serves from
a background thread, so synchronous clients (pycomm3) and async tests alike can talk to it; at
teardown every socket and the thread are gone.
"""

from __future__ import annotations

import json
import os
import warnings
from collections.abc import Callable, Iterator
from contextlib import ExitStack
from pathlib import Path
from typing import Any

import pytest
import yaml

from enip_farm.config import parse_config
from enip_farm.device.catalogue import shipped_catalogue
from enip_farm.eio.cfg import parse_cfg
from enip_farm.eio.importer import EioImportWarning, import_eio
from enip_farm.farm.farm import BindError, Farm
from enip_farm.farm.loopback import LoopbackPool

#: Kept under its first name: tests and users import it from here.
AddressPool = LoopbackPool


@pytest.fixture(scope="session")
def free_address() -> AddressPool:
    """`free_address()`: a 127.x address no other farm of this test process has used."""
    return AddressPool(64 + os.getpid() % 150)


def _config_dict(source: str | Path | dict[str, Any] | None, device: dict[str, Any]) -> dict[str, Any]:
    if source is None:
        if not device:
            raise TypeError("enip_farm() needs a config file, a config dict, or a device's fields")
        return {"devices": [device]}
    if isinstance(source, dict):
        return dict(source)
    if str(source).lower().endswith(".cfg"):  # the controller's EIO.cfg, as `enip-farm eio import` reads it
        result = import_eio(parse_cfg(Path(source).read_text(), str(source)), shipped_catalogue())
        if result.warnings:  # what `eio import` prints, as one warning: pytest's summary shows it once per import
            warnings.warn(eio_summary(str(source), result.warnings), EioImportWarning, stacklevel=4)
        return result.document
    return yaml.safe_load(Path(source).read_text())


def eio_summary(source: str, lines: list[str]) -> str:
    """An EIO.cfg import's warnings as one message: a count, then each line as `eio import` prints it."""
    return f"{source}: imported with {len(lines)} warning{'s' if len(lines) != 1 else ''}:\n" + "\n".join(
        f"  {line}" for line in lines)


def start_farm(stack: ExitStack, addresses: Callable[[], str], source: str | Path | dict[str, Any] | None = None, *,
               keep_addresses: bool = False, discovery: bool = False, http: bool = False, **device: Any) -> Farm:
    data = _config_dict(source, device)
    data.setdefault("discovery", discovery)
    for attempt in range(5):
        devices = [dict(entry) for entry in data["devices"]]
        if not keep_addresses:
            for entry in devices:
                entry["address"] = addresses()
                count = entry.get("count", 1)
                if isinstance(count, int) and count > 1:  # its devices take the next addresses too
                    for _ in range(count - 1):
                        addresses()
                    entry.setdefault("netmask", "255.0.0.0")  # the pool's addresses span /24s of 127/8
        farm = Farm(parse_config({**data, "devices": devices}, str(source or "<enip_farm>")),
                    http=("127.0.0.1", 0) if http else None)
        try:
            stack.enter_context(farm.running_in_thread())
            return farm
        except BindError as error:  # another process already holds one of these addresses
            if keep_addresses or "already in use" not in str(error) or attempt == 4:
                raise
    raise AssertionError("unreachable")


#: The farms a test started (its report is taken from them once the test has run).
FARMS = pytest.StashKey[list[Farm]]()
#: The sources of the bounds a test asked for (enip_farm/bounds.py): the marker's and the YAML's.
ASKED = ("test", "cell configuration", "device configuration")


@pytest.fixture
def enip_farm(free_address: AddressPool, request: pytest.FixtureRequest) -> Iterator[Callable[..., Farm]]:
    """A factory: enip_farm("cell.yaml"), enip_farm("EIO.cfg"), enip_farm({"devices": [...]}), enip_farm(name="io1",
    model="DSQC1030", addons=["DSQC1031"]); options keep_addresses, discovery, http."""
    farms = request.node.stash.setdefault(FARMS, [])

    def start(*args: Any, **kwargs: Any) -> Farm:
        farm = start_farm(stack, free_address, *args, **kwargs)
        farms.append(farm)
        return farm

    with ExitStack() as stack:
        yield start
    farms.clear()


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.getgroup("enip-farm").addoption(
        "--enip-report", action="store_true", default=None,
        help="attach each test's enip-farm report (the controller under test, measured) to its result")
    parser.addini("enip_report", type="bool", default=False, help="as --enip-report")


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "enip_bounds(**bounds): bounds of the enip-farm report (enip_farm/bounds.py) "
                                       "the test asks for; a cell that breaks one fails the test")


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]) -> Iterator[None]:
    """After a test's call: its farms' reports attached (--enip-report) and held against the bounds it asked for."""
    outcome = yield
    farms = item.stash.get(FARMS, None)
    marker = item.get_closest_marker("enip_bounds")
    attach = item.config.getoption("enip_report") or item.config.getini("enip_report")
    if call.when != "call" or not farms or not (attach or marker):
        return
    result = outcome.get_result()  # type: ignore[attr-defined]
    broken = []
    for farm in farms:
        if not farm.running:
            continue
        report = farm.report(dict(marker.kwargs) if marker is not None else None)
        if attach:  # on the call's result, and on the item for the teardown's (JUnit XML reads that one)
            prop = ("enip_farm_report", json.dumps(report.as_dict()))
            result.user_properties.append(prop)
            item.user_properties.append(prop)
        broken += [f"{where}: {verdict.line}" for where, verdict in report.failed() if verdict.source.startswith(ASKED)]
    if broken and result.passed:
        result.outcome = "failed"
        result.longrepr = "enip-farm: the cell broke bounds the test asked for:\n  " + "\n  ".join(broken)
