"""The report on the controller under test (cip/report.py) for a cell of devices: each device's
measured connections (open ones, then the last ones that ended) and reconnections, judged against
the bounds in force for it (enip_farm/bounds.py: the defaults, the cell's, the device's, the test's)."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Mapping
from typing import Any

from enip_farm.bounds import BoundsConfig, ResolvedBounds, resolve
from enip_farm.cip.connection import Connection
from enip_farm.cip.report import ConnectionFigures, DeviceReport, FarmReport, ReactionFigures, Reconnection
from enip_farm.cip.verdicts import judge_connection, judge_reaction, judge_reconnection
from enip_farm.config import FarmConfig
from enip_farm.device.device import Device

TestBounds = BoundsConfig | Mapping[str, Any] | None
__all__ = ["CellBounds", "FarmReport", "TestBounds", "device_bounds", "device_report", "farm_report",
           "reconnection_figures"]


class CellBounds:
    """The bounds in force for each device of `config` under the report's `test` bounds, for one
    report: the devices' entries found by name, the test's bounds validated once, and the devices
    without bounds of their own sharing one resolution (linear in devices, not quadratic)."""

    def __init__(self, config: FarmConfig, test: TestBounds = None) -> None:
        self.entries = {device.name: device.bounds for device in config.devices if device.bounds.model_fields_set}
        self.cell = ("cell configuration", config.bounds)
        self.test = ("test", _validated(test))
        self.shared = resolve(self.cell, self.test)

    def of(self, name: str, *own: TestBounds) -> ResolvedBounds:
        """The defaults, the cell's, device `name`'s entry's, each of `own` (a reaction's), the test's."""
        entry = self.entries.get(name)
        if entry is None and not any(level is not None for level in own):
            return self.shared
        return resolve(self.cell, (f"device configuration ({name})", entry), *(("test", level) for level in own),
                       self.test)


def _validated(bounds: TestBounds) -> BoundsConfig | None:
    return bounds if bounds is None or isinstance(bounds, BoundsConfig) else BoundsConfig.model_validate(dict(bounds))


def device_bounds(config: FarmConfig, name: str, *tests: TestBounds) -> ResolvedBounds:
    """The bounds in force for device `name`: the defaults, the cell's, the device's entry's, then
    each of the test's (a reaction's own, then the report's)."""
    return CellBounds(config).of(name, *tests)


def connection_figures(device: Device, connection: Connection, now: int) -> ConnectionFigures:
    return connection.measure.figures(now, device.name, connection.originator_host, connection.o_t_id,  # type: ignore[union-attr]
                                      connection.t_o_id, connection.kind.value)


def reconnection_figures(device: Device) -> list[Reconnection]:
    """The device's reconnections (cip/reconnection.py), as its report has them; under its lock."""
    return device.guard.read(lambda: device.table.reconnections.figures(device.name))


def device_report(device: Device, now: int, bounds: ResolvedBounds) -> DeviceReport:
    """One device's measured connections, judged; under its lock (the I/O thread writes the figures)."""
    def read() -> tuple[list[ConnectionFigures], list]:
        table = device.table
        measured = [c for c in table.connections.values() if c.measure is not None] + list(table.ended)
        return [connection_figures(device, c, now) for c in measured], table.reconnections.figures(device.name)
    figures, reconnections = device.guard.read(read)
    expected = (bounds["expected_o_t_rpi_us"], bounds["expected_t_o_rpi_us"])
    judged = []
    for f in figures:
        if f.forward_open is not None and expected != (None, None):
            f = dataclasses.replace(f, forward_open=dataclasses.replace(
                f.forward_open, expected_o_t_rpi_us=expected[0], expected_t_o_rpi_us=expected[1]))
        judged.append(judge_connection(f, bounds))
    verdicts = tuple(v for r in reconnections for v in judge_reconnection(r, bounds, now))
    return DeviceReport(device.name, tuple(judged), tuple(reconnections), verdicts)


def farm_report(config: FarmConfig, devices: Iterable[Device], now: int,
                reactions: Iterable[tuple[ReactionFigures, TestBounds]] = (), test: TestBounds = None) -> FarmReport:
    """The cell's report at `now`; `test`: bounds over the configuration's (a test's own). Each
    reaction is judged by its stimulus device's bounds, then its own, then `test`."""
    bounds = CellBounds(config, test)
    reports = tuple(device_report(d, now, bounds.of(d.name)) for d in devices)
    return FarmReport(now, reports, tuple(
        judge_reaction(r, bounds.of(r.stimulus.split(".", 1)[0], own)) for r, own in reactions))
