"""CIP Safety benchmark: cm-ethernetip's CIP Safety originator (from its own venv, with the
producer fix of tests/cm_ethernetip/originator.py) holds a safety connection pair to one farm
DSQC1042 for N seconds at an RPI, safe inputs and outputs toggling every second, then goes silent.

Reports: packets each way; CRC faults seen by the farm (consumer of the safe outputs and of the
time coordination messages) and by the originator (consumer of the safe inputs); timing faults
(the farm's sequence and data-age checks) and safety timeouts; the T->O period the originator saw
(p50, p99, max); the largest data age of the safe outputs the farm consumed; and the time from the
originator's last message to the farm's safe state. The farm runs in this process pinned to CPU 1,
the originator in its own process pinned to CPU 0. Every wait is bounded; traffic stays on
127.0.0.0/8.

    python bench/bench_safety.py --seconds 60 --rpi-ms 10 [--format extended] [--realtime]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from enip_farm.cip.connection_events import (  # noqa: E402
    ConnectionFaulted,
    ConnectionTimedOut,
    SafeState,
    SafetyCrcFault,
    SafetyTimingFault,
)
from enip_farm.config import FarmConfig  # noqa: E402
from enip_farm.farm.farm import Farm  # noqa: E402
from tests.cm_ethernetip import CmOriginator, make_venv, node_address  # noqa: E402

FARM, ORIGINATOR = "127.0.91.1", "127.0.91.2"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--rpi-ms", type=float, default=10.0)
    parser.add_argument("--format", choices=("base", "extended"), default="base")
    parser.add_argument("--nte-ticks", type=int, default=781, help="network time expectation, 128 us ticks")
    parser.add_argument("--realtime", action="store_true", help="run the farm and the originator SCHED_FIFO "
                        "(priority 10; root): other load on the machine cannot stall them")
    parser.add_argument("--venv", default=os.path.join(tempfile.gettempdir(), "enip-farm-cm-ethernetip"))
    args = parser.parse_args()
    if not 1 <= args.seconds <= 600:
        parser.error("--seconds: 1..600")
    python = make_venv(Path(args.venv))
    if hasattr(os, "sched_setaffinity") and os.cpu_count() and os.cpu_count() > 1:  # type: ignore[operator]
        os.sched_setaffinity(0, {1})
    realtime = os.sched_param(10)
    if args.realtime:
        os.sched_setscheduler(0, os.SCHED_FIFO, realtime)  # the farm's threads, started below, inherit it
    config = FarmConfig.model_validate({"devices": [{"name": "s1", "address": FARM, "model": "DSQC1042"}]})
    farm = Farm(config)
    with farm.running_in_thread():
        handle = farm["s1"]
        originator = CmOriginator(python, {
            "mode": "safety", "host": FARM, "local": ORIGINATOR, "snn": "000000000001", "node": node_address(FARM),
            "format": args.format, "rpi_us": round(args.rpi_ms * 1000), "nte": args.nte_ticks, "ping": 100,
            "timeout": 2})
        if hasattr(os, "sched_setaffinity"):
            try:
                os.sched_setaffinity(originator.process.pid, {0})
            except OSError:
                pass
        if args.realtime:
            os.sched_setscheduler(originator.process.pid, os.SCHED_FIFO, realtime)
        try:
            opened = originator.wait("open", timeout=30)
            if opened["event"] != "open":
                raise SystemExit(f"safety open refused: {opened}")
            start = time.monotonic()
            toggles = 0
            while time.monotonic() - start < args.seconds:
                toggles += 1
                handle.set(DI1=toggles % 2, DI12=(toggles + 1) % 2)
                originator.send(cmd="out", data="05" if toggles % 2 else "0a")
                time.sleep(min(1.0, max(0.0, args.seconds - (time.monotonic() - start))))
            originator.send(cmd="stats")
            stats = originator.wait("stats", timeout=30)
            outputs = handle.outputs
            before = dict(handle.counters)
            told = (SafetyCrcFault, SafetyTimingFault, ConnectionFaulted, ConnectionTimedOut)
            faults = [f"{e.monotonic_ns / 1e9 - start:.3f} s {e.kind}: {e.text}" for e in handle.events()
                      if isinstance(e.detail, told)]
            connections = [c for c in farm.devices["s1"].connections.values() if c.safety is not None]
            max_age = max((getattr(c.safety, "max_data_age", 0) for c in connections), default=0)
            originator.send(cmd="silent")
            silent = originator.wait("silent", timeout=30)
            handle.wait_for(lambda io: bool(io.events(SafeState)), timeout=10)
            safe_state = handle.events(SafeState)[-1]
        finally:
            originator.close()
    report = {
        "seconds": args.seconds, "rpi_ms": args.rpi_ms, "format": args.format,
        "network_time_expectation_ms": args.nte_ticks * 0.128, "realtime": args.realtime,
        "load_average": os.getloadavg(),
        "o_t_sent": stats["sent"],
        "o_t_taken_by_farm_data_and_time_coordination": before.get("safety_packets_consumed", 0),
        "t_o_produced_by_farm": before.get("safety_packets_produced", 0), "t_o_received": stats["rx"],
        "crc_faults_farm": before.get("safety_crc_faults", 0), "crc_faults_originator": stats["crc_faults"],
        "timing_faults_farm": before.get("safety_timing_faults", 0),
        "safety_timeouts_before_silence": before.get("safety_timeouts", 0),
        "faults": faults,
        "t_o_period_at_originator": stats["rx_period"], "o_t_period_at_originator": stats["tx_period"],
        "o_t_max_data_age_ms": max_age * 0.128, "outputs_before_silence": outputs.hex(),
        "safe_state_after_last_message_ms": round((safe_state.monotonic_ns - silent["last_sent_ns"]) / 1e6, 3),
        "safe_state_reason": safe_state.text.split(": ", 1)[-1], "outputs_after": handle.outputs.hex(),
    }
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
