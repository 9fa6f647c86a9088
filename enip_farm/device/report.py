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
__all__ = ["FarmReport", "TestBounds", "device_bounds", "device_report", "farm_report", "reconnection_figures"]


def device_bounds(config: FarmConfig, name: str, *tests: TestBounds) -> ResolvedBounds:
    """The bounds in force for device `name`: the defaults, the cell's, the device's entry's, then
    each of the test's (a reaction's own, then the report's)."""
    entry = next((d for d in config.devices if d.name == name), None)
    return resolve(("cell configuration", config.bounds),
                   (f"device configuration ({name})", entry.bounds if entry is not None else None),
                   *(("test", test) for test in tests))


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
    reports = tuple(device_report(d, now, device_bounds(config, d.name, test)) for d in devices)
    return FarmReport(now, reports, tuple(
        judge_reaction(r, device_bounds(config, r.stimulus.split(".", 1)[0], own, test)) for r, own in reactions))
