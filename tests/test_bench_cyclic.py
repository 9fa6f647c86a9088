"""bench/bench_cyclic.py still builds and runs: its two C programs compile with the system compiler,
and a short smoke run (3 connections at RPI 10 ms, a 2 s window, against the farm and the C
responder) counts every datagram both ways. Figures belong to the benchmark; this only holds the
counts to what the schedule makes exact. The originator runs without SCHED_FIFO and the connections
with timeout multiplier 5 (1.28 s): a stall of a busy machine neither lets the originator hog a core
nor times a connection out; the benchmark's defaults stay SCHED_FIFO and multiplier 2 (160 ms)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
CONNECTIONS, RPI_MS, SECONDS = 3, 10, 2
PER_CONNECTION = int(SECONDS * 1000 / RPI_MS)  # deadlines of one connection in the window


@pytest.mark.system
@pytest.mark.skipif(not (os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")), reason="no C compiler")
def test_the_cyclic_bench_builds_and_counts_every_datagram(tmp_path: Path) -> None:
    out = tmp_path / "cyclic.json"
    run = subprocess.run([sys.executable, str(ROOT / "bench" / "bench_cyclic.py"), "--rows", f"{CONNECTIONS}@{RPI_MS}",
                          "--seconds", str(SECONDS), "--warmup", "0.5", "--workers", "1", "--realtime", "0",
                          "--timeout-multiplier", "5",
                          "--first-address", "127.0.239.1", "--json", str(out), "--per-connection"],
                         cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-3000:]
    assert "| conns | RPI ms | O->T expected |" in run.stdout
    row = json.loads(out.read_text())["rows"][0]
    farm, c = row["farm"], row["c"]
    assert (farm["offered"], farm["admitted"], farm["refused"]) == (CONNECTIONS, CONNECTIONS, 0)
    for side in (farm, c):
        # O->T: the originator's schedule has exactly SECONDS / RPI deadlines per connection in the window
        assert side["o_t_sent_window"] == CONNECTIONS * PER_CONNECTION
        assert side["send_errors"] == 0
        assert side["t_o_expected_window"] == CONNECTIONS * PER_CONNECTION
        assert side["peer_socket_drops"] == side["originator_socket_drops"] == 0
        assert side["o_t_received_window"] == side["o_t_sent_window"]
        # T->O: every packet in sequence, none twice, none foreign or malformed
        assert side["lost"] == side["duplicates"] == side["reordered"] == 0
        assert side["unknown"] == side["malformed"] == side["wrong_size"] == 0
        for connection in side["per_connection"]:
            assert connection["o_t_sent"] == PER_CONNECTION
            # one stream at the RPI: the window holds its 200 packets, one more at most where its edges cut
            # the stream; a peer stalled by a busy machine skips the RPIs it missed (as the farm does), and the
            # intervals say how many (an interval of 1.5 RPI or more counts as a missed RPI, so a jittery
            # stream can only seem to miss more, never fewer)
            assert PER_CONNECTION // 2 <= connection["received"] <= PER_CONNECTION + 1, connection
            assert connection["received"] + connection["missed"] >= PER_CONNECTION - 3, connection
        assert side["intervals"] == side["t_o_received_window"]  # each follows one from the warm-up or the window
        assert 0 <= side["err_p50_ms"] <= side["err_p99_ms"] <= side["err_max_ms"] < 1000
        assert side["err_p50_ms"] < 5  # the median interval is near the RPI even on a busy machine
        assert side["peer_cpu_percent"] >= 0 and side["originator_cpu_percent"] >= 0
    assert farm["timeouts"] == farm["close_errors"] == 0
    assert farm["pairs_per_cpu_s"] > 0  # the C responder's few pairs may take less than one clock tick
    # the C responder took every O->T datagram the originator sent (it drains its sockets when it stops)
    assert c["responder"]["o_t_received"] == c["o_t_sent_total"]
    assert c["responder"]["o_t_bad"] == c["responder"]["send_errors"] == 0
    assert c["responder"]["sockets"] == CONNECTIONS


@pytest.mark.system
@pytest.mark.skipif(not (os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")), reason="no C compiler")
def test_refusals_are_counted_by_status_and_the_originator_spreads_over_threads(tmp_path: Path) -> None:
    """Two workers with a budget of 500 datagrams/s each (two connections at 10 ms, 200/s each, and
    not a third): of 6 devices, 3 per worker, 4 admitted and 2 refused 0x01/0x0113, the banner's
    budget beside them; the originator's two pairs of threads (a socket each) count every datagram."""
    out = tmp_path / "cyclic.json"
    run = subprocess.run([sys.executable, str(ROOT / "bench" / "bench_cyclic.py"), "--rows", f"6@{RPI_MS}",
                          "--seconds", "1", "--warmup", "0.5", "--workers", "2", "--realtime", "0",
                          "--timeout-multiplier", "5", "--budget", "500", "--originator-threads", "2",
                          "--no-responder", "--first-address", "127.0.238.1", "--json", str(out), "--per-connection"],
                         cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-3000:]
    assert "refused: 2 0x01/0x0113; worker 0 cyclic I/O budget: 500 datagrams/s per worker" in run.stderr
    farm = json.loads(out.read_text())["rows"][0]["farm"]
    assert (farm["offered"], farm["admitted"], farm["refused"], farm["refusals"]) == (6, 4, 2, {"0x01/0x0113": 2})
    assert farm["threads"] == 2
    assert farm["o_t_sent_window"] == 4 * 100 and farm["send_errors"] == 0
    assert farm["o_t_received_window"] == farm["o_t_sent_window"]
    assert farm["lost"] == farm["duplicates"] == farm["reordered"] == farm["unknown"] == farm["malformed"] == 0
    for connection in farm["per_connection"]:  # each connection's T->O reached the thread of its socket
        assert 50 <= connection["received"] <= 101, connection
    assert farm["timeouts"] == farm["close_errors"] == 0
