"""A network fuzz run against a running farm (`enip-farm serve` in a subprocess) while class-1
connections run on other devices of it (tests/network_fuzz.py): structure-aware frames on TCP
44818 of two devices, every reply checked; mutated class-1 datagrams and random datagrams on UDP
2222 and 44818 of every device; an explicit prober's latency; and every class-1 connection keeps
its T->O at its RPI for the whole run, and none is timed out by the farm.

About 25 s (ENIP_FARM_NETWORK_FUZZ_S). The seed is printed; ENIP_FARM_FUZZ_SEED=N replays a run
(each TCP stream's frames depend on the seed alone). bench/network_fuzz.py runs millions of frames.
"""

from __future__ import annotations

import os
import random
import statistics
from pathlib import Path

import pytest

from tests.network_fuzz import fuzz_farm, percentile

pytestmark = pytest.mark.system

SECONDS = float(os.environ.get("ENIP_FARM_NETWORK_FUZZ_S", "25"))


def test_network_fuzz_leaves_every_class1_connection_running(free_address, tmp_path: Path) -> None:
    seed = int(os.environ.get("ENIP_FARM_FUZZ_SEED", random.SystemRandom().getrandbits(32)))
    print(f"network fuzz seed {seed} (replay: ENIP_FARM_FUZZ_SEED={seed})")
    report = fuzz_farm(tmp_path, [free_address() for _ in range(5)], SECONDS, seed)
    print("\n".join(report.lines()))
    assert report.frames >= 500 and report.replies >= 300, "the fuzz run did too little to count"

    # every class-1 connection ran for the whole run, at its RPI, and was never timed out by the farm
    assert report.close_statuses == [0, 0, 0], "a class-1 connection was timed out by the farm"
    originator = report.originator
    rpi_ms = originator.rpi_us / 1000
    expected = (originator.stopped_ns - originator.started_ns) / 1e6 / rpi_ms
    for stream in originator.streams:
        gaps = [(b - a) / 1e6 for a, b in zip(stream.arrivals, stream.arrivals[1:], strict=False)]
        assert 0.9 * expected <= len(stream.arrivals) <= expected + 2, (stream.host, len(stream.arrivals), expected)
        assert statistics.median(gaps) == pytest.approx(rpi_ms, abs=1.0)
        assert max(gaps) < 500, f"a {max(gaps):.0f} ms gap in {stream.host}'s T->O"
        assert stream.arrivals[-1] >= originator.stopped_ns - 500_000_000  # still producing at the end

    # the explicit prober was answered every time, correctly (Prober checks the bytes)
    latencies = report.latencies_ms
    assert latencies and percentile(latencies, 0.99) < 1000 and max(latencies) < 5000

    # the farm is alive, healthy, went through it without an error, and dropped nothing silently
    assert report.farm_alive
    assert report.health["ok"] is True, report.health
    assert report.health["cyclic_io"] == {"running": True, "errors": 0, "device_errors": 0}
    assert report.health["loop_errors"] == 0
    dropped = sum(v for counters in report.cyclic_counters.values() for k, v in counters.items()
                  if k.startswith("o_t_dropped_"))
    assert dropped == report.datagrams_to_cyclic, "every datagram sent to their UDP 2222 is counted as not taken"
    assert all(counters["connection_timeouts"] == 0 for counters in report.cyclic_counters.values())
    log = report.farm_log
    assert "Traceback" not in log and " ERROR " not in log and " CRITICAL " not in log, log[-3000:]
