"""Each misbehaviour of bench/cyclic_originator.c against a farm, and the verdicts the farm's report
(Farm.report(), cip/report.py) gave it: every mode must fail exactly the bounds it breaks and pass
every other, its counts must equal what the originator says it made, and its times must lie within
both bounds of what was sent. Prints the table of modes, figures and verdicts (issue 27, item 5).

One farm in this process (a DSQC1030 per mode, named after it; the default bounds:
enip_farm/bounds.py); the modes run at once, each on its own device: one exclusive-owner connection
opened from Python (bench_cyclic.py's Forward Open, timeout multiplier 5: 128 RPI), the C
originator sending its O->T for `--deadlines` RPIs with the mode's flags and then falling silent;
once the farm has taken every datagram it sent, the report is read and the connection closed. The
`reconnect` mode sends a quarter of that, power-cycles its device (Identity Reset type 0, reset
time 0.3 s), polls until the device stops and then again answers TCP, waits its delay (1 s, over
the test's bound of 0.5 s) and Forward Opens anew.
Sizes are chosen so that a busy machine cannot blur a verdict: gaps and bursts make intervals of 3
and 4 RPI (never near 2), the jitter intervals of 1.6 and 0.4 RPI (never near 2, p99 clearly past
1.5), counts come from sequence numbers, not times. The originator runs SCHED_FIFO (--realtime,
root) so that it sends on time; without root it runs without and says so.

    python bench/misbehaviour.py                    # RPI 20 ms, 400 deadlines a mode
    python bench/misbehaviour.py --json out.json    # every figure too

Traffic goes to 127.0.0.0/8 only; every wait is bounded.
"""

from __future__ import annotations

import argparse
import json
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_cyclic import (  # noqa: E402
    O_T_SIZE,
    T_O_SIZE,
    Connection,
    build,
    forward_close,
    forward_open,
    originator_socket,
    read_line,
)

from enip_farm.farm.farm import Farm  # noqa: E402

RPI_MS = 20
DEADLINES = 400
MULTIPLIER = 5  # timeout 128 RPI: the silence after the last deadline until the report is read times nothing out
RESET_TIME_S = 0.3
RECONNECT_DELAY_S = 1.0
RECONNECT_BOUND_S = 0.5  # the test's bound on the reconnection: the delay breaks it
RECONNECT_SLACK_S = 2.0  # seeing the device back (a 10 ms poll) and a Forward Open, on a busy machine
WAIT_S = 10.0


@dataclass(frozen=True)
class Mode:
    """A misbehaviour: the originator's flags, the verdicts (figures) it must fail, the counts it
    makes (from the originator's own `made`, per connection) the report must show."""

    name: str
    flags: tuple[str, ...]
    fails: frozenset[str]
    what: str
    counts: Callable[[dict], dict[str, int]] = field(default=lambda made: {})
    within: tuple[tuple[str, float, float], ...] = (("p99_ns", 0.9, 1.5),)  # interval figures, in APIs: both bounds


def _sequence(made: dict, **extra: int) -> dict[str, int]:
    return {"sequence.packets": made["sent"], "sequence.lost": made["gaps"], "sequence.gaps": made["gap_runs"],
            "sequence.repeats": made["repeats"], "sequence.stale": made["stale"], **extra}


LATE = "intervals of 2 API or more"


def modes(rpi_ms: float, deadlines: int) -> list[Mode]:
    """The modes at this RPI; `deadlines` (300 or more, a multiple of 100) ends outside every gap and burst."""
    every = deadlines * 3 // 8  # 150 of 400: 2 gaps or bursts, under 1 % of the intervals (p99 stays)
    jitter_us = round(rpi_ms * 1000 * 0.6)
    return [
        Mode("none", (), frozenset(), "on time", lambda m: _sequence(m, **{"intervals.late": 0})),
        Mode("jitter", ("--jitter-us", str(jitter_us)), frozenset({"interval p99"}),
             f"odd deadlines {jitter_us / 1000:g} ms late (intervals 1.6 and 0.4 RPI)",
             lambda m: _sequence(m, **{"intervals.late": 0}), (("p99_ns", 1.5, 2.0), ("min_ns", 0.1, 0.6))),
        Mode("gap", ("--gap-every", str(every), "--gap-size", "2"), frozenset({"sequence numbers lost", LATE}),
             f"2 deadlines unsent every {every} (an interval of 3 RPI)",
             lambda m: _sequence(m, **{"intervals.late": m["gap_runs"]}), (("p99_ns", 0.9, 1.5), ("max_ns", 2.5, 3.5))),
        Mode("burst", ("--burst-every", str(every), "--burst-size", "3"), frozenset({LATE}),
             f"3 deadlines held every {every}, sent with the 4th (silence of 4 RPI)",
             lambda m: _sequence(m, **{"intervals.late": m["bursts"]}),
             (("p99_ns", 0.9, 1.5), ("max_ns", 3.5, 4.5), ("min_ns", 0, 0.1))),
        Mode("repeat", ("--repeat-every", "10"), frozenset({"sequence numbers repeated"}),
             "every 10th packet sent twice", lambda m: _sequence(m, **{"intervals.late": 0})),
        Mode("stale", ("--stale-every", "10"), frozenset({"stale sequence numbers"}),
             "every 10th packet followed by one 2 sequence numbers back",
             lambda m: _sequence(m, **{"intervals.late": 0})),
        Mode("idle", ("--idle-every", "50"), frozenset(), "run/idle header toggled every 50 deadlines",
             lambda m: _sequence(m, **{"intervals.late": 0, "run_idle.transitions": m["idle_transitions"] + 1})),
    ]


MODE_NAMES = ("none", "jitter", "gap", "burst", "repeat", "stale", "idle", "reconnect")


def cell(first: str | None = None, names: tuple[str, ...] = MODE_NAMES) -> dict[str, Any]:
    """A DSQC1030 per mode, named after it; addresses from `first` on (none: the caller gives them)."""
    devices = [{"name": name, "model": "DSQC1030", "reset_time_s": RESET_TIME_S, "implicit": {"first_watchdog_s": 0}}
               for name in names]
    if first is not None:
        prefix, last = first.rsplit(".", 1)
        for i, device in enumerate(devices):
            device["address"] = f"{prefix}.{int(last) + i}"
    return {"discovery": False, "devices": devices}


def dig(figures: dict, path: str) -> Any:
    for part in path.split("."):
        figures = figures[part]
    return figures


def connection_report(farm: Farm, device: str, o_t_id: int) -> dict:
    report = farm.report().as_dict()
    for connection in next(d for d in report["devices"] if d["device"] == device)["connections"]:
        if connection["o_t_id"] == o_t_id:
            return connection
    raise LookupError(f"no connection 0x{o_t_id:08X} in the report")


def run_originator(binary: Path, connection: Connection, udp: socket.socket, rpi_ms: float, deadlines: int,
                   flags: tuple[str, ...], realtime: int, work: Path) -> dict:
    """The originator over one connection for `deadlines` RPIs; what it made."""
    listing, out = work / f"{connection.o_t_id}.txt", work / f"{connection.o_t_id}.json"
    listing.write_text(f"{connection.host} {connection.o_t_id} {connection.t_o_id} {round(rpi_ms * 1000)} "
                       f"{O_T_SIZE} {T_O_SIZE}\n")
    seconds = deadlines * rpi_ms / 1000 + 0.1
    process = subprocess.Popen([str(binary), "--connections", str(listing), "--fd", str(udp.fileno()),
                                "--seconds", f"{seconds:.3f}", "--warmup", "0", "--hold", "30",
                                "--realtime", str(realtime), "--stop-after", str(deadlines), *flags,
                                "--json", str(out)],
                               pass_fds=(udp.fileno(),), stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        if read_line(process.stdout, 30) != "start" or read_line(process.stdout, seconds + 30) != "end":
            raise SystemExit("the originator did not run its window")
        process.stdin.close()
        process.wait(30)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait(10)
    (figures,) = json.loads(out.read_text())["per_connection"]
    return figures["made"]


def taken(farm: Farm, device: str, o_t_id: int, made: dict) -> dict:
    """The connection's report once the farm has taken every datagram the originator sent."""
    deadline = time.monotonic() + WAIT_S
    while True:
        figures = connection_report(farm, device, o_t_id)
        s = figures["sequence"]
        if s["packets"] + s["repeats"] + s["stale"] >= made["datagrams"] or time.monotonic() > deadline:
            return figures
        time.sleep(0.02)


def failed(figures: dict) -> set[str]:
    return {v["figure"] for v in figures["verdicts"] if v["verdict"] == "fail"}


def run_mode(farm: Farm, mode: Mode, binary: Path, rpi_ms: float, deadlines: int, realtime: int, work: Path) -> dict:
    """One mode on a fresh connection: the farm's figures, what the originator made, the checks."""
    udp = originator_socket()
    try:
        (connection,), _ = forward_open([farm[mode.name].address], round(rpi_ms * 1000), udp.getsockname()[1],
                                        MULTIPLIER)
        try:
            made = run_originator(binary, connection, udp, rpi_ms, deadlines, mode.flags, realtime, work)
            figures = taken(farm, mode.name, connection.o_t_id, made)
        finally:
            forward_close([connection])
    finally:
        udp.close()
    expected = mode.counts(made)
    counts = {path: dig(figures, path) for path in expected}
    intervals = figures["intervals"]
    times = {name: intervals[name] / intervals["api_ns"] for name, _, _ in mode.within}
    outside = {name: value for (name, low, high), value in zip(mode.within, times.values(), strict=True)
               if not low <= value <= high}
    return {"mode": mode.name, "what": mode.what, "flags": list(mode.flags), "made": made, "figures": figures,
            "failed": sorted(failed(figures)), "expected_fails": sorted(mode.fails), "counts": counts,
            "expected_counts": expected, "times_api": times, "outside": outside,
            "ok": failed(figures) == mode.fails and counts == expected and not outside and
            not any(v["verdict"] == "too short to judge" for v in figures["verdicts"])}


def answers_tcp(host: str) -> bool:
    try:
        with socket.create_connection((host, 44818), timeout=0.2):
            return True
    except OSError:
        return False


def run_reconnect(farm: Farm, binary: Path, rpi_ms: float, deadlines: int, realtime: int, work: Path,
                  delay_s: float = RECONNECT_DELAY_S) -> dict:
    """The originator sends, the device power-cycles; once it answers TCP again the originator waits
    `delay_s`, Forward Opens anew and sends. The reconnection's times lie in [delay, delay + slack]."""
    host = farm["reconnect"].address
    udp = originator_socket()
    try:
        (first,), _ = forward_open([host], round(rpi_ms * 1000), udp.getsockname()[1], MULTIPLIER)
        origin = first.session.sock.getsockname()[0]  # the originator as the farm names it
        run_originator(binary, first, udp, rpi_ms, deadlines // 4, (), realtime, work)
        first.session.sock.close()
        assert farm["reconnect"].reset(0)
        deadline = time.monotonic() + WAIT_S
        while answers_tcp(host) and time.monotonic() < deadline:  # the reset takes the listener away
            time.sleep(0.01)
        while not answers_tcp(host) and time.monotonic() < deadline:  # and brings it back
            time.sleep(0.01)
        back = time.monotonic_ns()
        time.sleep(delay_s)
        asked = time.monotonic_ns()
        (second,), _ = forward_open([host], round(rpi_ms * 1000), udp.getsockname()[1], MULTIPLIER)
        try:
            run_originator(binary, second, udp, rpi_ms, deadlines // 4, (), realtime, work)
            report = farm.report({"reconnect_forward_open_s": RECONNECT_BOUND_S}).as_dict()
        finally:
            forward_close([second])
    finally:
        udp.close()
    device = next(d for d in report["devices"] if d["device"] == "reconnect")
    (reconnection,) = [r for r in device["reconnections"] if r["after"] == "reset done"]
    failures = sorted(v["figure"] for v in device["verdicts"] if v["verdict"] == "fail")
    failures += sorted(f for c in device["connections"] for f in failed(c))
    fo, first_o_t = reconnection["forward_open_after_ns"], reconnection["first_o_t_after_ns"]
    return {"mode": "reconnect", "what": f"Forward Open {delay_s:g} s after the device is back (bound "
            f"{RECONNECT_BOUND_S:g} s)", "reconnection": reconnection, "back_seen_ns": back, "asked_ns": asked,
            "device_verdicts": device["verdicts"], "connections": device["connections"],
            "failed": failures, "expected_fails": [f"reconnection: next Forward Open after reset done ({origin})"],
            "ok": failures == [f"reconnection: next Forward Open after reset done ({origin})"]
            and fo is not None and first_o_t is not None
            and delay_s * 1e9 <= fo <= (delay_s + RECONNECT_SLACK_S) * 1e9 and fo <= first_o_t <= fo + 0.5e9}



def ms(ns: int | None) -> str:
    return "-" if ns is None else f"{ns / 1e6:.2f}"


def table(rows: list[dict]) -> str:
    lines = ["| mode | what it does | packets | lost (gaps) | repeats | stale | run/idle transitions | "
             "intervals ≥ 2 API | interval p50 / p99 / max ms | failed verdicts (value, bound) | as made |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|---|:---:|"]
    for row in rows:
        if row["mode"] == "reconnect":
            r = row["reconnection"]
            verdicts = "; ".join(f"{v['figure']} ({v['value']} s, {v['bound']} s)" for v in row["device_verdicts"]
                                 if v["verdict"] == "fail")
            lines.append(f"| reconnect | {row['what']} | | | | | | | Forward Open {ms(r['forward_open_after_ns'])}, "
                         f"first O->T {ms(r['first_o_t_after_ns'])} after the reset | {verdicts} | "
                         f"{'yes' if row['ok'] else 'NO'} |")
            continue
        f = row["figures"]
        s, i = f["sequence"], f["intervals"]
        verdicts = "; ".join(f"{v['figure']} ({v['value']}, {v['bound']})" for v in f["verdicts"]
                             if v["verdict"] == "fail") or "none"
        lines.append(f"| {row['mode']} | {row['what']} | {s['packets']} | {s['lost']} ({s['gaps']}) | {s['repeats']} | "
                     f"{s['stale']} | {f['run_idle']['transitions']} | {i['late']} | "
                     f"{ms(i['p50_ns'])} / {ms(i['p99_ns'])} / {ms(i['max_ns'])} | {verdicts} | "
                     f"{'yes' if row['ok'] else 'NO'} |")
    return "\n".join(lines)


def run_all(farm: Farm, rpi_ms: float = RPI_MS, deadlines: int = DEADLINES, realtime: int = 10,
            only: set[str] | None = None) -> list[dict]:
    """Every mode (or those in `only`) at once, each on the device named after it."""
    binary = build("cyclic_originator", ("-pthread",))
    with tempfile.TemporaryDirectory(prefix="misbehaviour-") as tmp, ThreadPoolExecutor(len(MODE_NAMES)) as pool:
        work = Path(tmp)
        runs = [pool.submit(run_mode, farm, mode, binary, rpi_ms, deadlines, realtime, work)
                for mode in modes(rpi_ms, deadlines) if only is None or mode.name in only]
        if only is None or "reconnect" in only:
            runs.append(pool.submit(run_reconnect, farm, binary, rpi_ms, deadlines, realtime, work))
        return [run.result() for run in runs]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rpi-ms", type=float, default=RPI_MS)
    parser.add_argument("--deadlines", type=int, default=DEADLINES,
                        help="RPIs each mode sends (a multiple of 100 from 300)")
    parser.add_argument("--address", default="127.0.238.1", help="the first device's address (127.0.0.0/8)")
    parser.add_argument("--realtime", type=int, default=10, help="SCHED_FIFO priority of the originator (0: not)")
    parser.add_argument("--modes", default=None, help="comma-separated modes (default: all)")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    if not args.address.startswith("127.") or args.deadlines % 100 or args.deadlines < 300:
        raise SystemExit("--address must be in 127.0.0.0/8 and --deadlines a multiple of 100 from 300")
    with Farm(cell(args.address)).running_in_thread() as farm:
        rows = run_all(farm, args.rpi_ms, args.deadlines, args.realtime,
                       set(args.modes.split(",")) if args.modes else None)
    print(f"RPI {args.rpi_ms:g} ms, {args.deadlines} deadlines a mode, one connection each, default bounds")
    print(table(rows))
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    if not all(row["ok"] for row in rows):
        wrong = ", ".join(row["mode"] for row in rows if not row["ok"])
        raise SystemExit(f"a mode did not yield exactly its verdicts: {wrong}")


if __name__ == "__main__":
    main()
