"""The HTTP routes of what the farm saw the controller do (issue 27): GET /report (the report on
the controller under test: cip/report.py, judged against the bounds in force) and GET
/devices/{name}/timeline (a device's signals over the last N seconds with the controller's writes
and the test's stimuli marked: control/timeline.py)."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Annotated, Any

from fastapi import FastAPI, Query, Response

from enip_farm.cip.report import FarmReport
from enip_farm.control.timeline import MAX_SECONDS, Timelines

DEFAULT_SECONDS = 30.0


def only(report: FarmReport, names: list[str]) -> FarmReport:
    """The report of the devices named (all when none): its verdict and failures theirs alone."""
    if not names:
        return report
    wanted = set(names)
    return dataclasses.replace(report, devices=tuple(d for d in report.devices if d.device in wanted))


def mount_measured(app: FastAPI, timelines: Timelines, known: Callable[[str], str],
                   report: Callable[[], FarmReport]) -> None:
    @app.get("/report", response_model=FarmReport)
    def get_report(device: Annotated[list[str], Query()] = []) -> Response:  # noqa: B006 (FastAPI copies)
        """The report on the controller under test: every class-1 connection's originator as the farm
        measured it (O->T packet intervals against the API, the 32-bit sequence, run/idle, the Forward
        Open as asked, how it ended), reconnections and reactions, each figure judged against its
        bound (the configuration's `bounds:`, with the defaults and their sources); `device` (repeat
        it) keeps those devices. `enip-farm report` shows it as a table, `--junit FILE` as JUnit XML."""
        for name in device:
            known(name)
        return Response(only(report(), device).as_json(), media_type="application/json")

    @app.get("/devices/{name}/timeline")
    def timeline(name: str, seconds: Annotated[float, Query(gt=0, le=MAX_SECONDS)] = DEFAULT_SECONDS
                 ) -> dict[str, Any]:
        """The device's signals over the last `seconds` (30; at most 600) as steps: each signal's
        `values` are [time, value] pairs (seconds of the farm's monotonic clock, as `now`), the
        first at the window's `start`; `marks` say when an image changed, which signals and `by`
        whom: `o->t` (class-1 data), `explicit` (a request), `stimulus` (inputs set through the API),
        or the connection event that changed the outputs (e.g. `connection timed out`). A device's
        changes are recorded from the first time its timeline is asked for (`recording_since`)."""
        name = known(name)
        return timelines.timeline(name, seconds, timelines.devices[name].clock())
