"""The HTTP routes of what the farm saw the controller do (issue 27): GET /devices/{name}/timeline
(a device's signals over the last N seconds with the controller's writes and the test's stimuli
marked: control/timeline.py)."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Annotated, Any

from fastapi import FastAPI, Query

from enip_farm.control.timeline import MAX_SECONDS, Timelines

DEFAULT_SECONDS = 30.0


def mount_measured(app: FastAPI, timelines: Timelines, known: Callable[[str], str]) -> None:
    @app.get("/devices/{name}/timeline")
    def timeline(name: str, seconds: Annotated[float, Query(gt=0, le=MAX_SECONDS)] = DEFAULT_SECONDS
                 ) -> dict[str, Any]:
        """The device's signals over the last `seconds` (30; at most 600) as steps: each signal's
        `values` are [time, value] pairs (seconds of the farm's monotonic clock, as `now`), the
        first at the window's `start`; `marks` say when an image changed, which signals and `by`
        whom: `o->t` (class-1 data), `explicit` (a request), `stimulus` (inputs set through the API),
        or the connection event that changed the outputs (e.g. `connection timed out`). A device's
        changes are recorded from the first time its timeline is asked for (`recording_since`)."""
        return timelines.timeline(known(name), seconds, time.monotonic_ns())
