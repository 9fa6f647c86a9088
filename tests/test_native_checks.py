"""Issue 29: defects found in the native class-1 path (enip_farm/server/_class1.c, server/native.py),
each pinned by the case that showed it, sans-IO unless it needs the cyclic I/O thread."""

from __future__ import annotations

import pytest

from enip_farm.server.native import BUILT
from tests.test_cip_services_unit import MS
from tests.test_native_differential import T0
from tests.test_native_fuzz import Driver

pytestmark = pytest.mark.skipif(not BUILT, reason="the native class-1 extension is not built")


def test_a_class3_connection_times_out_while_the_engine_runs_the_class1_one() -> None:
    """The engine held only the class-1 connections' deadlines: a silent class-3 connection of a
    native device never timed out (its 400 ms) while the class-1 one ran."""
    paths = Driver(False), Driver(True)
    for path in paths:
        path.step(("open",), T0)
        path.step(("class3",), T0)
        for n in range(60):  # the class-1 originator goes on, the class-3 one is silent
            now = T0 + MS + n * 10 * MS
            path.step(("o_t", "next", "run", "scanner", None, 0, b"\x01\x00"), now)
            path.step(("turn",), now + MS)
    python, native = paths
    assert native.path.engine.native(native.path.handle.slot)
    assert python.path.device.counters["connection_timeouts"] == 1
    assert native.path.state(T0 + 600 * MS) == python.path.state(T0 + 600 * MS)
    assert native.path.device.counters["connection_timeouts"] == 1
