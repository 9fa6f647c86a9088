"""A scenario's expectations judged from what its devices recorded while it ran (their events: image
changes with the images' bytes, connections opened and timed out) and the times of its steps; the
result as a verdict table, as JSON and as JUnit XML. Times are the events' own (int ns, monotonic)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from typing import Any

from enip_farm.cip.connection_events import ConnectionOpened, ConnectionTimedOut
from enip_farm.cip.report import Reconnection
from enip_farm.device.events import Event, ImageChanged
from enip_farm.device.signals import SignalMap
from enip_farm.scenario.model import (
    OPERATORS,
    Condition,
    EventCount,
    Expectation,
    NoTimeouts,
    Reconnected,
    Scenario,
    SignalWithin,
)


@dataclass
class Recording:
    """What the runner kept: each device's images at the start, the devices' events, the steps' times."""

    start_ns: int
    images: dict[str, dict[str, bytes]]  # device -> role -> image at the start
    events: list[Event] = field(default_factory=list)
    started: dict[int, int] = field(default_factory=dict)
    ended: dict[int, int] = field(default_factory=dict)
    #: Each device's reconnection figures at the end (cip/reconnection.py, the report's): when each
    #: originator's Forward Open and first O->T came after the device came back.
    reconnections: dict[str, list[Reconnection]] = field(default_factory=dict)

    def of_type(self, cls: type, devices: tuple[str, ...], since: int | None = None) -> list[Event]:
        """The events of class `cls` of these devices (from `since`)."""
        return [e for e in self.events if isinstance(e.detail, cls) and e.device in devices
                and (since is None or e.monotonic_ns >= since)]

    def of_kind(self, kind: str, devices: tuple[str, ...]) -> list[Event]:
        """The events of these devices whose wire kind is `kind` (the scenario's `count(KIND)`)."""
        return [e for e in self.events if e.kind == kind and e.device in devices]


@dataclass
class Verdict:
    expectation: str
    line: int
    passed: bool
    figure: str

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class StepOutcome:
    number: int
    name: str | None
    action: str
    state: str
    started_s: float | None
    ended_s: float | None
    detail: str = ""


@dataclass
class ScenarioResult:
    name: str
    status: str  # passed, failed, cancelled
    steps: list[StepOutcome]
    verdicts: list[Verdict]
    duration_s: float

    @property
    def passed(self) -> bool:
        return self.status == "passed"

    def as_dict(self) -> dict[str, Any]:
        return {"name": self.name, "status": self.status, "passed": self.passed, "duration_s": self.duration_s,
                "steps": [asdict(step) for step in self.steps], "verdicts": [v.as_dict() for v in self.verdicts]}

    def table(self) -> str:
        """The verdict table the CLI prints: each expectation, PASS or FAIL, and its figure."""
        rows = [("PASS" if v.passed else "FAIL", v.expectation, v.figure) for v in self.verdicts]
        rows += [("FAIL", f"{'step'} {s.number}" + (f" ({s.name})" if s.name else "") + f": {s.action}",
                  f"{s.state}: {s.detail}") for s in self.steps if s.state in ("failed",)]
        width = max((len(r[1]) for r in rows), default=10)
        lines = [f"{verdict}  {text:{width}}  {figure}" for verdict, text, figure in rows]
        return "\n".join([*lines, f"{self.name}: {self.status.upper()} ({self.duration_s:.3f} s)"])

    def junit(self) -> Any:
        """A junitparser JUnitXml: one test suite, a case per expectation and per failed step."""
        from junitparser import Failure, JUnitXml, Skipped, TestCase, TestSuite

        suite = TestSuite(f"scenario: {self.name}")
        for verdict in self.verdicts:
            case = TestCase(verdict.expectation, f"scenario.{self.name}")
            if not verdict.passed:
                case.result = [Failure(verdict.figure, "expectation not met")]
            case.system_out = verdict.figure
            suite.add_testcase(case)
        for step in self.steps:
            case = TestCase(f"step {step.number}: {step.action}", f"scenario.{self.name}.steps")
            if step.state == "failed":
                case.result = [Failure(step.detail or "failed", "step failed")]
            elif step.state != "done":
                case.result = [Skipped(step.state)]
            suite.add_testcase(case)
        suite.update_statistics()
        xml = JUnitXml(f"enip-farm scenario {self.name}")
        xml.add_testsuite(suite)
        xml.update_statistics()
        return xml


def judge(scenario: Scenario, recording: Recording, signals: Mapping[str, SignalMap]) -> list[Verdict]:
    return [_judge(expectation, recording, signals) for expectation in scenario.expectations]


def _ms(ns: int) -> str:
    return f"{ns / 1e6:.1f} ms"


def _reference(recording: Recording, step: int, end: bool) -> int | None:
    return (recording.ended if end else recording.started).get(step)


def _judge(expectation: Expectation, recording: Recording, signals: Mapping[str, SignalMap]) -> Verdict:
    check = expectation.check

    def verdict(passed: bool, figure: str) -> Verdict:
        return Verdict(expectation.text, expectation.line, passed, figure)

    if isinstance(check, (SignalWithin, Reconnected)):
        since = _reference(recording, check.step, check.end)
        if since is None:
            return verdict(False, f"step {check.step} {'never ended' if check.end else 'never ran'}")
        if isinstance(check, SignalWithin):
            when = first_true(check.condition, since, recording, signals[check.condition.device])
            if when is None:
                return verdict(False, f"never (bound {_ms(check.bound_ns)})")
            return verdict(when - since <= check.bound_ns, f"after {_ms(when - since)} (bound {_ms(check.bound_ns)})")
        late, how = {}, {}
        for device in check.devices:
            late[device], how[device] = _reconnected(recording, device, since)
        missing = [d for d, t in late.items() if t is None]
        if missing:
            return verdict(False, f"not reconnected: {', '.join(f'{d}{how[d]}' for d in missing)} "
                                  f"(bound {_ms(check.bound_ns)})")
        worst = max(late, key=lambda d: late[d])  # type: ignore[arg-type, return-value]
        return verdict(late[worst] <= check.bound_ns,  # type: ignore[operator]
                       f"last {worst} after {_ms(late[worst])}{how[worst]} (bound {_ms(check.bound_ns)})")  # type: ignore[arg-type]
    if isinstance(check, NoTimeouts):
        found = recording.of_type(ConnectionTimedOut, check.devices)
        return verdict(not found, "none" if not found else f"{len(found)}: " + ", ".join(
            sorted({e.device for e in found})))
    assert isinstance(check, EventCount)
    count = len(recording.of_kind(check.kind, check.devices))
    return verdict(OPERATORS[check.op](count, check.count), f"{count} {check.kind}")


def _reconnected(recording: Recording, device: str, since: int) -> tuple[int | None, str]:
    """When `device` was reconnected after `since` (ns after it) and how that was measured. From the
    report's reconnection figures where the run has them (each originator expected back: its first
    O->T after its next accepted Forward Open, the last originator's), else from the first
    "connection opened" event."""
    figures = [r for r in recording.reconnections.get(device, ()) if r.since_ns >= recording.start_ns
               and (r.forward_open_ns is None or r.forward_open_ns >= since)]
    if not figures:
        opened = recording.of_type(ConnectionOpened, (device,), since)
        return (opened[0].monotonic_ns - since, "") if opened else (None, "")
    first: dict[str, Reconnection] = {}
    for figure in figures:  # the done ones come first, oldest first: an originator's first one
        first.setdefault(figure.originator, figure)
    waiting = [o for o, r in first.items() if r.first_o_t_ns is None]
    if waiting:
        return None, f" ({', '.join(waiting)}: no first O->T after a Forward Open)"
    last = max(first.values(), key=lambda r: r.first_o_t_ns)  # type: ignore[arg-type, return-value]
    return last.first_o_t_ns - since, (  # type: ignore[operator]
        f" ({last.originator}: first O->T {_ms(last.first_o_t_after_ns)}, Forward Open "  # type: ignore[arg-type]
        f"{_ms(last.forward_open_after_ns)} after it came back)")  # type: ignore[arg-type]


def first_true(condition: Condition, since: int, recording: Recording, signals: SignalMap) -> int | None:
    """The first time at or after `since` the condition held, from the images' changes."""
    signal = signals.lookup(condition.signal)
    role = signal.role
    image = recording.images[condition.device][role]
    changes = [e for e in recording.events if isinstance(e.detail, ImageChanged) and e.device == condition.device
               and e.detail.role == role]
    for event in changes:
        if event.monotonic_ns > since:
            break
        image = event.detail.new
    if condition.holds(signals.value(signal, image)):
        return since
    for event in changes:
        if event.monotonic_ns > since and condition.holds(signals.value(signal, event.detail.new)):
            return event.monotonic_ns
    return None
