"""The farm's report on the controller under test: what every class-1 connection's originator did,
measured from the kernel's receive time of each O->T datagram, judged against bounds (frozen
values; the arithmetic that makes them is cip/o_t_measure.py, the judging cip/verdicts.py).

Figures follow ODVA's and NIST's EtherNet/IP performance definitions: the measured packet interval
of the O->T stream against the connection's O->T API (jitter), and the action latency from a
stimulus to the controller's reaction. Times are integer ns of the farm's monotonic clock.

These frozen dataclasses are the one definition of the report's JSON: pydantic serializes them
(`as_dict()`, `as_json()`; computed figures such as `verdict` are `computed_field`s) and derives
GET /report's schema in /openapi.json from them, every object closed (`extra="forbid"`: a field
the JSON has and the schema lacks fails tests/test_report_surfaces.py).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache
from typing import Annotated, Any, Literal

from pydantic import ConfigDict, Field, PlainSerializer, TypeAdapter, computed_field
from typing_extensions import TypedDict

VerdictWord = Literal["pass", "fail", "too short to judge", "not judged"]
PASS, FAIL, TOO_SHORT, NOT_JUDGED = "pass", "fail", "too short to judge", "not judged"


def worst(verdicts: list[Verdict] | tuple[Verdict, ...] | list[str]) -> VerdictWord:
    """Fail if any failed; else too short if any was; pass if any passed; else not judged."""
    words = {v if isinstance(v, str) else v.verdict for v in verdicts}
    for word in (FAIL, TOO_SHORT, PASS):
        if word in words:
            return word  # type: ignore[return-value]
    return NOT_JUDGED  # type: ignore[return-value]


class _Json:
    """The JSON of a report dataclass, as pydantic serializes it (one adapter per class)."""

    __slots__ = ()
    __pydantic_config__ = ConfigDict(extra="forbid", json_schema_serialization_defaults_required=True)

    def as_dict(self) -> dict[str, Any]:
        return _adapter(type(self)).dump_python(self, mode="json")

    def as_json(self) -> bytes:
        return _adapter(type(self)).dump_json(self)


@cache
def _adapter(cls: type) -> TypeAdapter:
    return TypeAdapter(cls)


@dataclass(frozen=True, slots=True)
class Verdict(_Json):
    """One figure held against its bound: `value` <= `bound` passes (every bound is an upper one);
    fewer than `needs` samples (`have`) is too short to judge."""

    figure: Annotated[str, Field(description="what was measured, e.g. `interval p99`")]
    verdict: VerdictWord
    value: Annotated[float | int | None, Field(description="the figure (None: not measured yet)")]
    bound: Annotated[float | int, Field(description="its upper bound: a value at or below it passes")]
    unit: str
    needs: Annotated[int, Field(description="samples the bound needs before it judges")]
    have: Annotated[int, Field(description="samples measured")]
    source: Annotated[str, Field(description="where the bound comes from: a spec section, a publication, the "
                                             "configuration, the test, or a choice (unverified)")]

    @property
    def line(self) -> str:
        return f"{self.figure} {_number(self.value)} {self.unit} > bound {_number(self.bound)} ({self.source})"


def _number(value: float | int | None) -> str:
    return f"{value:.6g}" if isinstance(value, float) else str(value)


@dataclass(frozen=True, slots=True)
class Histogram(_Json):
    """Counts of intervals by bucket: `counts[i]` holds those up to `bounds_api[i]` x API (and above
    the bound before); the last count the ones above every bound."""

    bounds_api: Annotated[tuple[float, ...], Field(description="each bucket's upper bound, in O->T APIs")]
    counts: Annotated[tuple[int, ...], Field(description="intervals per bucket; the last: above every bound")]


@dataclass(frozen=True, slots=True)
class IntervalFigures(_Json):
    """The measured O->T packet interval against the API (ODVA/NIST: jitter), in ns. p50 and p99 are
    the upper bound of their bucket (clamped to the exact min and max)."""

    api_ns: int
    count: int
    min_ns: int | None
    p50_ns: int | None
    p99_ns: int | None
    max_ns: int | None
    mean_ns: int | None
    late: Annotated[int, Field(description="intervals of 2 API or more")]
    longest_silence_ns: Annotated[int, Field(description="the longest interval, or the time from the last "
                                                         "packet to the end (or now)")]
    histogram: Histogram


@dataclass(frozen=True, slots=True)
class SequenceFigures(_Json):
    """The 32-bit sequence of the O->T packets (Vol. 2, 3-2.1): `packets` that advanced it, `lost`
    sequence numbers skipped in `gaps` jumps, `repeats` of the last one, `stale` older ones."""

    packets: int
    lost: int
    gaps: int
    repeats: int
    stale: int
    last: int | None


@dataclass(frozen=True, slots=True)
class CipSequenceFigures(_Json):
    """The 16-bit CIP sequence count of the packets that advanced the 32-bit one: `new` data (one
    more), the `same` count (no new data), `skipped` (more than one more)."""

    new: int
    same: int
    skipped: int


class RunIdleChange(TypedDict):
    """A run/idle transition: when, and the mode it went to."""

    at_ns: int
    run: bool


def _change(change: tuple[int, bool]) -> RunIdleChange:
    return {"at_ns": change[0], "run": change[1]}


@dataclass(frozen=True, slots=True)
class RunIdle(_Json):
    """The run/idle mode of the O->T data: now, the transitions counted, the last ones with their times."""

    run: bool
    transitions: int
    recent: tuple[Annotated[tuple[int, bool], PlainSerializer(_change, return_type=RunIdleChange)], ...]  # (at_ns, run)


@dataclass(frozen=True, slots=True)
class ElectronicKeyAsked(_Json):
    form: Literal["exact", "compatible", "any"]  # "any": every field zero
    vendor_id: int
    device_type: int
    product_code: int
    major_revision: int
    minor_revision: int


@dataclass(frozen=True, slots=True)
class ForwardOpenAsked(_Json):
    """The Forward Open as the originator asked it (Vol. 1, 3-5.4.1), beside what the device expects."""

    o_t_rpi_us: int
    t_o_rpi_us: int
    expected_o_t_rpi_us: int | None
    expected_t_o_rpi_us: int | None
    timeout_multiplier: int
    timeout_ns: int
    o_t_type: Annotated[str, Field(description="point-to-point, multicast, null")]
    t_o_type: str
    o_t_priority: Annotated[str, Field(description="low, high, scheduled, urgent")]
    t_o_priority: str
    o_t_size: int
    t_o_size: int
    o_t_variable: bool
    t_o_variable: bool
    large: bool
    transport_class: int
    trigger: str
    key: ElectronicKeyAsked | None
    configuration_data: Annotated[bytes | None, PlainSerializer(lambda data: None if data is None else data.hex(),
                                                                return_type=str | None)]  # hex


EndWord = Literal["forward close", "timeout", "tcp gone", "device fault", "device reset", "safety fault", "closed"]


@dataclass(frozen=True, slots=True)
class ConnectionFigures(_Json):
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
    first_o_t_after_ns: Annotated[int | None, Field(description="from the Forward Open to the first O->T packet")]
    forward_open: ForwardOpenAsked | None
    intervals: IntervalFigures
    sequence: SequenceFigures
    cip_sequence: CipSequenceFigures
    run_idle: RunIdle
    verdicts: tuple[Verdict, ...] = ()

    @computed_field
    @property
    def verdict(self) -> VerdictWord:
        return worst(self.verdicts)


ReconnectAfter = Literal["fault cleared", "reset done", "timeout"]


@dataclass(frozen=True, slots=True)
class Reconnection(_Json):
    """After the device came back (`after` a fault cleared or a reset done, at `since_ns`) or a
    connection of this originator timed out: when its next accepted Forward Open came and its
    first O->T after it (None: not yet)."""

    device: str
    originator: str
    after: ReconnectAfter
    since_ns: int
    forward_open_ns: int | None
    first_o_t_ns: int | None

    @computed_field
    @property
    def forward_open_after_ns(self) -> int | None:
        return None if self.forward_open_ns is None else self.forward_open_ns - self.since_ns

    @computed_field
    @property
    def first_o_t_after_ns(self) -> int | None:
        return None if self.first_o_t_ns is None else self.first_o_t_ns - self.since_ns


@dataclass(frozen=True, slots=True)
class DeviceReport(_Json):
    device: str
    connections: Annotated[tuple[ConnectionFigures, ...], Field(description="open ones, then the last that ended")]
    reconnections: tuple[Reconnection, ...] = ()
    verdicts: Annotated[tuple[Verdict, ...], Field(description="the device's own: reconnection times")] = ()

    @computed_field
    @property
    def verdict(self) -> VerdictWord:
        return worst([*self.verdicts, *(c.verdict for c in self.connections)])


@dataclass(frozen=True, slots=True)
class ReactionFigures(_Json):
    """Action latency: from the T->O packet that first carried the stimulus leaving the farm to the
    O->T packet (its kernel receive time) or explicit write that first carried the expected output."""

    name: str
    stimulus: str  # "io1.DI3=1"
    expect: str  # "io2.DO5=1"
    via: Literal["o->t", "explicit", "any"]
    samples_ns: tuple[int, ...]
    timeouts: int
    verdicts: tuple[Verdict, ...] = ()

    @computed_field
    @property
    def count(self) -> int:
        return len(self.samples_ns)

    @computed_field
    @property
    def min_ns(self) -> int | None:
        return min(self.samples_ns) if self.samples_ns else None

    @computed_field
    @property
    def p50_ns(self) -> int | None:
        return self.percentile(0.5)

    @computed_field
    @property
    def p99_ns(self) -> int | None:
        return self.percentile(0.99)

    @computed_field
    @property
    def max_ns(self) -> int | None:
        return max(self.samples_ns) if self.samples_ns else None

    def percentile(self, fraction: float) -> int | None:
        """The nearest-rank percentile of the samples (exact: a reaction keeps every sample)."""
        if not self.samples_ns:
            return None
        ordered = sorted(self.samples_ns)
        rank = max(1, -(-round(fraction * 1_000_000) * len(ordered) // 1_000_000))
        return ordered[min(rank, len(ordered)) - 1]

    @computed_field
    @property
    def verdict(self) -> VerdictWord:
        return worst(self.verdicts)


@dataclass(frozen=True, slots=True)
class FarmReport(_Json):
    """The whole cell (or the devices asked for): every class-1 connection's originator as measured
    and judged, reconnections, reactions."""

    at_ns: Annotated[int, Field(description="when the report was made, ns of the farm's monotonic clock")]
    devices: tuple[DeviceReport, ...]
    reactions: tuple[ReactionFigures, ...] = ()

    @computed_field(description="fail if any bound failed, else too short if any was, else pass")
    @property
    def verdict(self) -> VerdictWord:
        return worst([*(d.verdict for d in self.devices), *(r.verdict for r in self.reactions)])

    @computed_field(description="one line per broken bound: where, the figure and the bound")
    @property
    def failures(self) -> list[str]:
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
