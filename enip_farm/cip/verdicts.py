"""Verdicts: each figure of the report (cip/report.py) held against its bound (enip_farm/bounds.py),
with the figure, the bound and where the bound came from; a figure with fewer samples than its
bound needs is "too short to judge", never passed or failed on too little."""

from __future__ import annotations

import dataclasses

from enip_farm.bounds import P99_NEEDS, ResolvedBounds
from enip_farm.cip.report import (
    FAIL,
    PASS,
    TOO_SHORT,
    ConnectionFigures,
    ReactionFigures,
    Reconnection,
    Verdict,
)


def verdict(figure: str, value: float | int | None, bound: float | int, unit: str, needs: int, have: int,
            source: str) -> Verdict:
    """`value` <= `bound` passes (exactly: figures are not rounded before they are judged); fewer than
    `needs` samples, or no value, is too short to judge."""
    if have < needs or value is None:
        return Verdict(figure, TOO_SHORT, value, bound, unit, needs, have, source)  # type: ignore[arg-type]
    return Verdict(figure, PASS if value <= bound else FAIL, value, bound, unit, needs, have, source)  # type: ignore[arg-type]


def judge_connection(figures: ConnectionFigures, bounds: ResolvedBounds) -> ConnectionFigures:
    """The figures with their verdicts, one per bound set."""
    out: list[Verdict] = []
    i = figures.intervals
    api = i.api_ns
    have, needs = i.count, bounds["min_intervals"]

    def add(name: str, figure: str, value: float | int | None, unit: str, need: int, got: int,
            scale: float = 1.0) -> None:
        bound = bounds[name]
        if bound is not None:
            out.append(verdict(figure, value, bound * scale if scale != 1.0 else bound, unit, need, got,
                               bounds.source(name)))

    add("interval_p99_api", "interval p99", None if i.p99_ns is None else i.p99_ns / api, "API",
        max(P99_NEEDS, needs), have)
    add("interval_max_api", "interval max", None if i.max_ns is None else i.max_ns / api, "API", needs, have)
    add("late_intervals", "intervals of 2 API or more", i.late, "intervals", needs, have)
    s = figures.sequence
    add("lost", "sequence numbers lost", s.lost, "packets", needs, have)
    add("repeats", "sequence numbers repeated", s.repeats, "packets", needs, have)
    add("stale", "stale sequence numbers", s.stale, "packets", needs, have)
    fo = figures.forward_open
    if fo is not None and fo.timeout_ns:
        add("silence_timeout", "longest silence", i.longest_silence_ns / fo.timeout_ns, "timeouts", 0, have)
        for direction, asked in (("o_t", fo.o_t_rpi_us), ("t_o", fo.t_o_rpi_us)):
            expected = getattr(fo, f"expected_{direction}_rpi_us")
            if expected is not None and bounds["rpi_deviation_us"] is not None:
                out.append(verdict(f"{direction.replace('_', '->').upper()} RPI asked vs {expected} us expected",
                                   abs(asked - expected), bounds["rpi_deviation_us"], "us", 0, 1,
                                   bounds.source("rpi_deviation_us")))
    return dataclasses.replace(figures, verdicts=tuple(out))


def judge_reconnection(reconnection: Reconnection, bounds: ResolvedBounds, now: int) -> list[Verdict]:
    """A reconnection's two times against their bounds. One that has not come yet is too short to
    judge until `now` is past its bound, then it fails with the time waited so far."""
    out = []
    r = reconnection
    for name, figure, at in (("reconnect_forward_open_s", "reconnection: next Forward Open", r.forward_open_ns),
                             ("reconnect_first_o_t_s", "reconnection: first O->T", r.first_o_t_ns)):
        bound = bounds[name]
        if bound is None:
            continue
        where = f"{figure} after {reconnection.after} ({reconnection.originator})"
        if at is not None:
            out.append(verdict(where, (at - reconnection.since_ns) / 1e9, bound, "s", 1, 1, bounds.source(name)))
        elif (waited := (now - reconnection.since_ns) / 1e9) > bound:
            out.append(verdict(f"{where}, not yet", waited, bound, "s", 0, 0, bounds.source(name)))
        else:
            out.append(verdict(where, None, bound, "s", 1, 0, bounds.source(name)))
    return out


def judge_reaction(reaction: ReactionFigures, bounds: ResolvedBounds) -> ReactionFigures:
    out = []
    n = reaction.count
    if bounds["reaction_p99_ms"] is not None:
        p99 = reaction.percentile(0.99)
        out.append(verdict("reaction p99", None if p99 is None else p99 / 1e6, bounds["reaction_p99_ms"],
                           "ms", 1, n, bounds.source("reaction_p99_ms")))
    if bounds["reaction_max_ms"] is not None:
        out.append(verdict("reaction max", max(reaction.samples_ns) / 1e6 if n else None,
                           bounds["reaction_max_ms"], "ms", 1, n, bounds.source("reaction_max_ms")))
    if bounds["reaction_timeouts"] is not None:
        out.append(verdict("reactions timed out", reaction.timeouts, bounds["reaction_timeouts"], "repetitions", 1,
                           n + reaction.timeouts, bounds.source("reaction_timeouts")))
    return dataclasses.replace(reaction, verdicts=tuple(out))


__all__ = ["FAIL", "PASS", "TOO_SHORT", "judge_connection", "judge_reaction", "judge_reconnection", "verdict"]
