"""The farm's report on the controller under test: what every class-1 connection's originator did,
measured from the kernel's receive time of each O->T datagram, judged against bounds (frozen
values; the arithmetic that makes them is cip/o_t_measure.py, the judging cip/verdicts.py).

Figures follow ODVA's and NIST's EtherNet/IP performance definitions: the measured packet interval
of the O->T stream against the connection's O->T API (jitter), and the action latency from a
stimulus to the controller's reaction. Times are integer ns of the farm's monotonic clock.

`as_dict()` gives JSON-ready dicts. The shape of `FarmReport.as_dict()` (GET /report, the CLI):

    {"at_ns": int,                           # when the report was made (monotonic ns)
     "verdict": "pass" | "fail" | "too short to judge" | "not judged",
     "failures": [str],                      # one line per broken bound
     "devices": [{
         "device": "io1", "verdict": ...,
         "connections": [{                   # open ones first, then the last ones that ended
             "device", "originator", "o_t_id", "t_o_id", "kind", "opened_at_ns",
             "ended_at_ns": int | null, "ended": null | "forward close" | "timeout" | "tcp gone"
                 | "device fault" | "device reset" | "safety fault" | "closed", "end_reason": str,
             "first_o_t_after_ns": int | null,   # from the Forward Open to the first O->T packet
             "forward_open": {"o_t_rpi_us", "t_o_rpi_us", "expected_o_t_rpi_us": int | null,
                 "expected_t_o_rpi_us": int | null, "timeout_multiplier", "timeout_ns",
                 "o_t_type", "t_o_type",         # "point-to-point" | "multicast" | "null"
                 "o_t_priority", "t_o_priority", # "low" | "high" | "scheduled" | "urgent"
                 "o_t_size", "t_o_size", "o_t_variable", "t_o_variable", "large", "transport_class",
                 "trigger", "key": {"form": "none" | "exact" | "compatible" | "any", "vendor_id",
                 "device_type", "product_code", "major_revision", "minor_revision"} | null,
                 "configuration_data": hex str | null},
             "intervals": {"api_ns", "count", "min_ns", "p50_ns", "p99_ns", "max_ns", "mean_ns",
                 "late",                        # intervals of 2 API or more
                 "longest_silence_ns",          # the longest interval, or the time since the last packet
                 "histogram": {"bounds_api": [float], "counts": [int]}},  # counts: one more (overflow)
             "sequence": {"packets", "lost", "gaps", "repeats", "stale", "last": int | null},
             "cip_sequence": {"new", "same", "skipped"},  # the 16-bit sequence count
             "run_idle": {"run": bool, "transitions": int, "recent": [{"at_ns", "run"}]},
             "verdict": ..., "verdicts": [Verdict]}],
         "reconnections": [{"device", "originator", "after", "since_ns", "forward_open_ns": int | null,
             "first_o_t_ns": int | null, "forward_open_after_ns", "first_o_t_after_ns"}],
         "verdicts": [Verdict]}],            # the device's own (reconnection)
     "reactions": [{"name", "stimulus", "expect", "via": "o->t" | "explicit" | "any", "count", "timeouts",
         "min_ns", "p50_ns", "p99_ns", "max_ns", "samples_ns": [int], "verdict": ..., "verdicts": [Verdict]}]}

    Verdict: {"figure", "verdict": "pass" | "fail" | "too short to judge", "value": number | null,
              "bound": number, "unit", "needs": int, "have": int, "source": str}
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

VerdictWord = Literal["pass", "fail", "too short to judge", "not judged"]
PASS, FAIL, TOO_SHORT, NOT_JUDGED = "pass", "fail", "too short to judge", "not judged"


def worst(verdicts: list[Verdict] | tuple[Verdict, ...] | list[str]) -> VerdictWord:
    """Fail if any failed; else too short if any was; pass if any passed; else not judged."""
    words = {v if isinstance(v, str) else v.verdict for v in verdicts}
    for word in (FAIL, TOO_SHORT, PASS):
        if word in words:
            return word  # type: ignore[return-value]
    return NOT_JUDGED  # type: ignore[return-value]


@dataclass(frozen=True, slots=True)
class Verdict:
    """One figure held against its bound: `value` <= `bound` passes (every bound is an upper one);
    fewer than `needs` samples (`have`) is too short to judge."""

    figure: str
    verdict: VerdictWord
    value: float | int | None
    bound: float | int
    unit: str
    needs: int
    have: int
    source: str  # where the bound comes from (a spec section, a publication, "a choice (unverified)", "test")

    def as_dict(self) -> dict[str, Any]:
        return {"figure": self.figure, "verdict": self.verdict, "value": self.value, "bound": self.bound,
                "unit": self.unit, "needs": self.needs, "have": self.have, "source": self.source}

    @property
    def line(self) -> str:
        return f"{self.figure} {_number(self.value)} {self.unit} > bound {_number(self.bound)} ({self.source})"


def _number(value: float | int | None) -> str:
    return f"{value:.6g}" if isinstance(value, float) else str(value)


@dataclass(frozen=True, slots=True)
class Histogram:
    """Counts of intervals by bucket: `counts[i]` holds those up to `bounds_api[i]` x API (and above
    the bound before); the last count the ones above every bound."""

    bounds_api: tuple[float, ...]
    counts: tuple[int, ...]

    def as_dict(self) -> dict[str, Any]:
        return {"bounds_api": list(self.bounds_api), "counts": list(self.counts)}


@dataclass(frozen=True, slots=True)
class IntervalFigures:
    """The measured O->T packet interval against the API. p50 and p99 are the upper bound of their
    bucket (clamped to the exact min and max)."""

    api_ns: int
    count: int
    min_ns: int | None
    p50_ns: int | None
    p99_ns: int | None
    max_ns: int | None
    mean_ns: int | None
    late: int  # intervals of 2 API or more
    longest_silence_ns: int  # the longest interval, or the time from the last packet to the end (or now)
    histogram: Histogram

    def as_dict(self) -> dict[str, Any]:
        out = {name: getattr(self, name) for name in (
            "api_ns", "count", "min_ns", "p50_ns", "p99_ns", "max_ns", "mean_ns", "late", "longest_silence_ns")}
        out["histogram"] = self.histogram.as_dict()
        return out


@dataclass(frozen=True, slots=True)
class SequenceFigures:
    """The 32-bit sequence of the O->T packets (Vol. 2, 3-2.1): `packets` that advanced it, `lost`
    sequence numbers skipped in `gaps` jumps, `repeats` of the last one, `stale` older ones."""

    packets: int
    lost: int
    gaps: int
    repeats: int
    stale: int
    last: int | None

    def as_dict(self) -> dict[str, Any]:
        return {"packets": self.packets, "lost": self.lost, "gaps": self.gaps, "repeats": self.repeats,
                "stale": self.stale, "last": self.last}


@dataclass(frozen=True, slots=True)
class CipSequenceFigures:
    """The 16-bit CIP sequence count of the packets that advanced the 32-bit one: `new` data (one
    more), the `same` count (no new data), `skipped` (more than one more)."""

    new: int
    same: int
    skipped: int

    def as_dict(self) -> dict[str, Any]:
        return {"new": self.new, "same": self.same, "skipped": self.skipped}


@dataclass(frozen=True, slots=True)
class RunIdle:
    """The run/idle mode of the O->T data: now, the transitions counted, the last ones with their times."""

    run: bool
    transitions: int
    recent: tuple[tuple[int, bool], ...]  # (at_ns, run)

    def as_dict(self) -> dict[str, Any]:
        return {"run": self.run, "transitions": self.transitions,
                "recent": [{"at_ns": at, "run": run} for at, run in self.recent]}


@dataclass(frozen=True, slots=True)
class ElectronicKeyAsked:
    form: Literal["exact", "compatible", "any"]  # "any": every field zero
    vendor_id: int
    device_type: int
    product_code: int
    major_revision: int
    minor_revision: int

    def as_dict(self) -> dict[str, Any]:
        return {"form": self.form, "vendor_id": self.vendor_id, "device_type": self.device_type,
                "product_code": self.product_code, "major_revision": self.major_revision,
                "minor_revision": self.minor_revision}


@dataclass(frozen=True, slots=True)
class ForwardOpenAsked:
    """The Forward Open as the originator asked it (Vol. 1, 3-5.4.1), beside what the device expects."""

    o_t_rpi_us: int
    t_o_rpi_us: int
    expected_o_t_rpi_us: int | None
    expected_t_o_rpi_us: int | None
    timeout_multiplier: int
    timeout_ns: int
    o_t_type: str
    t_o_type: str
    o_t_priority: str
    t_o_priority: str
    o_t_size: int
    t_o_size: int
    o_t_variable: bool
    t_o_variable: bool
    large: bool
    transport_class: int
    trigger: str
    key: ElectronicKeyAsked | None
    configuration_data: bytes | None

    def as_dict(self) -> dict[str, Any]:
        out = {name: getattr(self, name) for name in self.__slots__ if name not in ("key", "configuration_data")}
        out["key"] = self.key.as_dict() if self.key is not None else None
        out["configuration_data"] = self.configuration_data.hex() if self.configuration_data is not None else None
        return out


EndWord = Literal["forward close", "timeout", "tcp gone", "device fault", "device reset", "safety fault", "closed"]


@dataclass(frozen=True, slots=True)
class ConnectionFigures:
    """Everything measured of one class-1 connection's originator."""

    device: str
    originator: str
    o_t_id: int
    t_o_id: int
    kind: str
    opened_at_ns: int
    ended_at_ns: int | None
    ended: EndWord | None
    end_reason: str
    first_o_t_after_ns: int | None
    forward_open: ForwardOpenAsked | None
    intervals: IntervalFigures
    sequence: SequenceFigures
    cip_sequence: CipSequenceFigures
    run_idle: RunIdle
    verdicts: tuple[Verdict, ...] = ()

    @property
    def verdict(self) -> VerdictWord:
        return worst(self.verdicts)

    def as_dict(self) -> dict[str, Any]:
        return {"device": self.device, "originator": self.originator, "o_t_id": self.o_t_id, "t_o_id": self.t_o_id,
                "kind": self.kind, "opened_at_ns": self.opened_at_ns, "ended_at_ns": self.ended_at_ns,
                "ended": self.ended, "end_reason": self.end_reason, "first_o_t_after_ns": self.first_o_t_after_ns,
                "forward_open": self.forward_open.as_dict() if self.forward_open is not None else None,
                "intervals": self.intervals.as_dict(), "sequence": self.sequence.as_dict(),
                "cip_sequence": self.cip_sequence.as_dict(), "run_idle": self.run_idle.as_dict(),
                "verdict": self.verdict, "verdicts": [v.as_dict() for v in self.verdicts]}


ReconnectAfter = Literal["fault cleared", "reset done", "timeout"]


@dataclass(frozen=True, slots=True)
class Reconnection:
    """After the device came back (`after` a fault cleared or a reset done, at `since_ns`) or a
    connection of this originator timed out: when its next accepted Forward Open came and its
    first O->T after it (None: not yet)."""

    device: str
    originator: str
    after: ReconnectAfter
    since_ns: int
    forward_open_ns: int | None
    first_o_t_ns: int | None

    @property
    def forward_open_after_ns(self) -> int | None:
        return None if self.forward_open_ns is None else self.forward_open_ns - self.since_ns

    @property
    def first_o_t_after_ns(self) -> int | None:
        return None if self.first_o_t_ns is None else self.first_o_t_ns - self.since_ns

    def as_dict(self) -> dict[str, Any]:
        return {"device": self.device, "originator": self.originator, "after": self.after, "since_ns": self.since_ns,
                "forward_open_ns": self.forward_open_ns, "first_o_t_ns": self.first_o_t_ns,
                "forward_open_after_ns": self.forward_open_after_ns, "first_o_t_after_ns": self.first_o_t_after_ns}


@dataclass(frozen=True, slots=True)
class DeviceReport:
    device: str
    connections: tuple[ConnectionFigures, ...]
    reconnections: tuple[Reconnection, ...] = ()
    verdicts: tuple[Verdict, ...] = ()  # the device's own: reconnection times

    @property
    def verdict(self) -> VerdictWord:
        return worst([*self.verdicts, *(c.verdict for c in self.connections)])

    def as_dict(self) -> dict[str, Any]:
        return {"device": self.device, "verdict": self.verdict,
                "connections": [c.as_dict() for c in self.connections],
                "reconnections": [r.as_dict() for r in self.reconnections],
                "verdicts": [v.as_dict() for v in self.verdicts]}


@dataclass(frozen=True, slots=True)
class ReactionFigures:
    """Action latency: from the T->O packet that first carried the stimulus leaving the farm to the
    O->T packet (its kernel receive time) or explicit write that first carried the expected output."""

    name: str
    stimulus: str  # "io1.DI3=1"
    expect: str  # "io2.DO5=1"
    via: Literal["o->t", "explicit", "any"]
    samples_ns: tuple[int, ...]
    timeouts: int
    verdicts: tuple[Verdict, ...] = ()

    @property
    def count(self) -> int:
        return len(self.samples_ns)

    def percentile(self, fraction: float) -> int | None:
        """The nearest-rank percentile of the samples (exact: a reaction keeps every sample)."""
        if not self.samples_ns:
            return None
        ordered = sorted(self.samples_ns)
        rank = max(1, -(-round(fraction * 1_000_000) * len(ordered) // 1_000_000))
        return ordered[min(rank, len(ordered)) - 1]

    @property
    def verdict(self) -> VerdictWord:
        return worst(self.verdicts)

    def as_dict(self) -> dict[str, Any]:
        return {"name": self.name, "stimulus": self.stimulus, "expect": self.expect, "via": self.via,
                "count": self.count, "timeouts": self.timeouts,
                "min_ns": min(self.samples_ns) if self.samples_ns else None, "p50_ns": self.percentile(0.5),
                "p99_ns": self.percentile(0.99), "max_ns": max(self.samples_ns) if self.samples_ns else None,
                "samples_ns": list(self.samples_ns), "verdict": self.verdict,
                "verdicts": [v.as_dict() for v in self.verdicts]}


@dataclass(frozen=True, slots=True)
class FarmReport:
    """The whole cell: every device's connections and reconnections, and the reactions measured."""

    at_ns: int
    devices: tuple[DeviceReport, ...]
    reactions: tuple[ReactionFigures, ...] = ()
    extra: dict[str, Any] = field(default_factory=dict)  # room for surfaces (a worker's name...)

    @property
    def verdict(self) -> VerdictWord:
        return worst([*(d.verdict for d in self.devices), *(r.verdict for r in self.reactions)])

    @property
    def failures(self) -> list[str]:
        """One line per broken bound: where, the figure and the bound."""
        return [f"{where}: {verdict.line}" for where, verdict in self.failed()]

    def failed(self) -> list[tuple[str, Verdict]]:
        """Every broken bound with where it was broken ("io1 O->T 0x... from 127.0.0.1", "reaction ...")."""
        out = []
        for device in self.devices:
            out += [(device.device, v) for v in device.verdicts if v.verdict == FAIL]
            for c in device.connections:
                where = f"{device.device} O->T 0x{c.o_t_id:08X} from {c.originator}"
                out += [(where, v) for v in c.verdicts if v.verdict == FAIL]
        for reaction in self.reactions:
            out += [(f"reaction {reaction.name}", v) for v in reaction.verdicts if v.verdict == FAIL]
        return out

    def device(self, name: str) -> DeviceReport:
        for device in self.devices:
            if device.device == name:
                return device
        raise KeyError(name)

    def as_dict(self) -> dict[str, Any]:
        return {"at_ns": self.at_ns, "verdict": self.verdict, "failures": self.failures,
                "devices": [d.as_dict() for d in self.devices], "reactions": [r.as_dict() for r in self.reactions],
                **self.extra}
