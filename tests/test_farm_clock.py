"""One clock given to the farm (issue 31): `Farm(clock=)` is the time of the devices' events, of a
fault set or cleared (farm/faulting.py), of the report and of the API's image changes, so that a test
that drives the clock sees every one of them at its own time."""

from __future__ import annotations

import pytest

from enip_farm import Farm
from enip_farm.config import parse_config
from enip_farm.device.events import FaultCleared, FaultInjected, ImageChanged

pytestmark = pytest.mark.integration

T0 = 5_000_000_000_000


class Clock:
    """The farm's clock: it moves only when the test says."""

    def __init__(self) -> None:
        self.now = T0

    def __call__(self) -> int:
        return self.now


def test_the_farm_clock_times_faults_the_report_and_image_changes(free_address) -> None:
    clock = Clock()
    farm = Farm(parse_config({"devices": [{"name": "io1", "address": free_address(), "model": "DSQC1030"}],
                              "discovery": False}), clock=clock)
    with farm.running_in_thread():
        io1 = farm["io1"]
        farm.inject("io1", "offline")
        assert [e.monotonic_ns for e in io1.events(FaultInjected)] == [T0]
        clock.now = T0 + 7
        farm.clear("io1")
        assert [e.monotonic_ns for e in io1.events(FaultCleared)] == [T0 + 7]
        clock.now = T0 + 9
        assert farm.report().at_ns == T0 + 9
        changes: list = []
        io1.device.observe(changes.append, ImageChanged)  # image changes are compared while observed
        clock.now = T0 + 11
        io1.set(DI1=1)
        assert [(e.monotonic_ns, e.detail.role) for e in changes] == [(T0 + 11, "input")]
