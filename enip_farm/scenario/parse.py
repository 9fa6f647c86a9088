"""A scenario file (YAML) parsed and checked before anything runs: every defect one line,
`file:line: reason` (an unknown device, group, signal or fault kind, a parameter a kind refuses, a
step that waits for a step that does not exist or for itself, an expectation of a step that does
not exist, a clear of what no step sets).

    name: switch of rack 2 lost
    steps:
      - at: 2 s                       # from the start; or `after: STEP` (number or id) and `delay:`
        id: loss
        fault: link-down              # a kind of GET /fault-kinds, on a device or a group
        target: rack2
        duration: 4 s                 # optional; `params: {...}` the kind's parameters
      - after: loss
        set: {io1.DI3: 1}             # stimuli: inputs (or outputs) by signal
      - wait: io1.DO5 == 0            # a condition, `timeout:` (default 10 s)
      - clear: rack2                  # `kind:` one kind; default every fault
    expect:
      - io1.DO5 == 0 within 100 ms of step 1
      - rack2 reconnected within 3 s of end of step loss   # a fault's end: its duration's
      - no connection timed out outside rack2
      - count(connection timed out, rack2) == 2

A step with neither `at` nor `after` comes after the step before it (the first: at the start). The
run ends when every step has, and not before `duration:` (a top-level key) from the start."""

from __future__ import annotations

import re
from collections.abc import Callable, Mapping
from typing import Any

import yaml
from pydantic import ValidationError

from enip_farm.config import FarmConfig
from enip_farm.config_errors import Location, line_map, line_of, yaml_problem
from enip_farm.device.faults import Fault, FaultError
from enip_farm.device.signals import SignalError, SignalMap
from enip_farm.scenario.document import (
    ScenarioDocument,
    StepDocument,
    duration_ns,
    problems,
    step_document,
)
from enip_farm.scenario.model import (
    OPERATORS,
    Action,
    ClearAction,
    Condition,
    EventCount,
    Expectation,
    FaultAction,
    NoTimeouts,
    Reconnected,
    Scenario,
    SetAction,
    SignalWithin,
    Step,
    WaitAction,
)

#: Why a device has no such signal (None: it has): (device, signal) -> reason.
SignalCheck = Callable[[str, str], str | None]
_OP = r"(==|!=|<=|>=|<|>)"
_CONDITION = re.compile(rf"^\s*([A-Za-z0-9_.{{}}-]+?)\.([A-Za-z][A-Za-z0-9_-]*)\s*{_OP}\s*(-?\d+(?:\.\d+)?)\s*$")
_OF_STEP = r"within\s+(?P<bound>\S+(?:\s*(?:ms|s|min))?)\s+of\s+(?P<end>end\s+of\s+)?step\s+(?P<step>\S+)"
_SIGNAL_WITHIN = re.compile(rf"^(?P<condition>.+?)\s+{_OF_STEP}$", re.I)
_RECONNECTED = re.compile(rf"^(?P<target>\S+)\s+reconnected\s+{_OF_STEP}$", re.I)
_NO_TIMEOUTS = re.compile(r"^no\s+connection\s+timed\s+out(?:\s+(?P<where>outside|in)\s+(?P<target>\S+))?$", re.I)
_COUNT = re.compile(rf"^count\(\s*(?P<kind>[^,)]+?)\s*(?:,\s*(?P<target>[^)]+?)\s*)?\)\s*(?P<op>{_OP})\s*(?P<n>\d+)$")
__all__ = ["ScenarioError", "SignalCheck", "duration_ns", "load_scenario", "parse_scenario", "signal_check"]


class ScenarioError(ValueError):
    """A scenario that cannot run; one line per defect, `file:line: reason`."""

    def __init__(self, problems: list[str]) -> None:
        super().__init__("\n".join(problems))
        self.problems = problems


def signal_check(maps: Mapping[str, SignalMap]) -> SignalCheck:
    """The SignalCheck of devices' signal maps: a signal of the device, one (not a range)."""
    def check(device: str, name: str) -> str | None:
        try:
            signal = maps[device].lookup(name)
        except SignalError as error:
            return f"device {device!r}: {error}"
        return None if signal.count == 1 else f"{name} is a range: a condition or a stimulus names one signal"
    return check


def load_scenario(path: str, config: FarmConfig, check_signal: SignalCheck) -> Scenario:
    try:
        with open(path, encoding="utf-8") as file:
            text = file.read()
    except OSError as error:
        raise ScenarioError([f"{path}: cannot read: {error.strerror}"]) from None
    return parse_scenario(text, path, config, check_signal)


def parse_scenario(text: str, source: str, config: FarmConfig, check_signal: SignalCheck) -> Scenario:
    """The scenario of `text` against the cell `config`; ScenarioError listing every defect at its
    line (config_errors.line_map, as a configuration's)."""
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as error:
        raise ScenarioError([yaml_problem(source, error)]) from None
    return _Parser(source, config, check_signal, line_map(text)).scenario(data)


class _Parser:
    def __init__(self, source: str, config: FarmConfig, check_signal: SignalCheck, lines: dict[Location, int]
                 ) -> None:
        self.source = source
        self.config = config
        self.check_signal = check_signal
        self.lines = lines
        self.top = min(lines.values(), default=1)  # the document's first key
        self.problems: list[tuple[int, str]] = []
        self.names: dict[str, int] = {}
        self._count = 0

    def problem(self, line: int, message: str) -> None:
        self.problems.append((line, message))

    def line(self, where: Location) -> int:
        return line_of(self.lines, where) or self.top

    def scenario(self, data: Any) -> Scenario:
        if not isinstance(data, dict):
            raise ScenarioError([f"{self.source}:1: a scenario is a mapping with steps: and expect:"])
        lasting = None
        try:
            lasting = ScenarioDocument.model_validate(data).duration
        except ValidationError as error:
            for where, message in problems(error, ()):
                self.problem(self.line(where), message)
        raw_steps = data["steps"] if isinstance(data.get("steps"), list) else []
        self._count = len(raw_steps)
        for number, raw in enumerate(raw_steps, 1):  # names first: a step may wait for a later one
            if isinstance(raw, dict) and raw.get("id") is not None:
                name = str(raw["id"])
                if name in self.names or name.isdigit():
                    self.problem(self.line(("steps", number - 1)), f"id {name!r}: " + (
                        f"taken by step {self.names[name]}" if name in self.names else "a number names a step already"))
                self.names.setdefault(name, number)
        steps = []
        for number, raw in enumerate(raw_steps, 1):
            document = step_document(raw, number)
            if isinstance(document, list):
                for where, message in document:
                    self.problem(self.line(where), message)
                continue
            step = self.step(number, document, self.line(("steps", number - 1)))
            if step is not None:
                steps.append(step)
        self.cycles(steps)
        self.clears(steps)
        raw_expect = data["expect"] if isinstance(data.get("expect"), list) else []
        expectations = []
        for index, text in enumerate(raw_expect):
            where = self.line(("expect", index))
            if not isinstance(text, str):
                self.problem(where, f"an expectation is a line of text, got {text!r}")
                continue
            check = self.expectation(text.strip(), where, len(raw_steps))
            if check is not None:
                expectations.append(Expectation(text.strip(), where, check))
        if self.problems:
            raise ScenarioError([f"{self.source}:{line}: {message}" for line, message in sorted(
                self.problems, key=lambda problem: problem[0])])
        return Scenario(str(data.get("name") or self.source), self.source, tuple(steps), tuple(expectations),
                        tuple(device.name for device in self.config.devices), lasting or 0)

    # -- steps ---------------------------------------------------------------------------------------

    def step(self, number: int, document: StepDocument, line: int) -> Step | None:
        """A step whose keys are right (scenario/document.py), checked against the cell."""
        before = len(self.problems)
        after = None
        if "after" in document.model_fields_set:
            after = self.reference(document.after, line, f"step {number}: after")
            if after == number:
                self.problem(line, f"step {number}: waits for itself (after: {document.after})")
        elif document.at is None and number > 1:
            after = number - 1
        action = getattr(self, f"_{document.action}")(number, document, line)
        if len(self.problems) > before or action is None:
            return None
        return Step(number, line, action, document.id, document.at, after, document.delay)

    def _fault(self, number: int, step: StepDocument, line: int) -> Action | None:
        self.target(step.target, line, f"step {number}: target")
        try:
            Fault(str(step.fault), duration_s=step.duration / 1e9 if step.duration else None, **step.params)
        except FaultError as error:
            self.problem(line, f"step {number}: fault {step.fault}: {error}")
            return None
        return FaultAction(str(step.target), str(step.fault), step.duration, step.params)

    def _clear(self, number: int, step: StepDocument, line: int) -> Action | None:
        self.target(step.clear, line, f"step {number}: clear")
        if step.kind is not None:
            try:
                Fault(step.kind)
            except FaultError as error:
                if error.field == "kind":
                    self.problem(line, f"step {number}: kind: {error}")
        return ClearAction(str(step.clear), step.kind)

    def _set(self, number: int, step: StepDocument, line: int) -> Action | None:
        out = []
        for name, value in step.set.items():
            device, _, signal = name.rpartition(".")
            if self.signal(device, signal, line, f"step {number}: set {name}"):
                out.append((device, signal, value))
        return SetAction(tuple(out))

    def _wait(self, number: int, step: StepDocument, line: int) -> Action | None:
        condition = self.condition(str(step.wait), line, f"step {number}: wait")
        return None if condition is None else WaitAction(condition, step.timeout)

    def cycles(self, steps: list[Step]) -> None:
        """A step waiting (through others) for itself can never happen."""
        by_number = {step.number: step for step in steps}
        for step in steps:
            seen, current = [step.number], step.after
            while current is not None and current not in seen and current in by_number:
                seen.append(current)
                current = by_number[current].after
            if current == step.number and len(seen) > 1:
                self.problem(step.line, f"{step.label} can never happen: steps {', '.join(map(str, seen))} "
                                        "wait for each other")

    def clears(self, steps: list[Step]) -> None:
        """A clear of a kind on a target that no step sets a fault of."""
        set_kinds = {(s.action.target, s.action.kind) for s in steps if isinstance(s.action, FaultAction)}
        for step in steps:
            action = step.action
            if isinstance(action, ClearAction) and not any(
                    target == action.target and action.kind in (None, kind) for target, kind in set_kinds):
                what = action.kind or "a fault"
                self.problem(step.line, f"{step.label}: clears {what} on {action.target}, which no step sets")

    # -- pieces -------------------------------------------------------------------------------------

    def duration(self, value: Any, line: int, what: str) -> int | None:
        checked = duration_ns(value)
        if checked is None:
            self.problem(line, f"{what}: {value!r} is not a duration (100 ms, 2 s, 1.5, 1 min)")
        return checked

    def reference(self, value: Any, line: int, what: str) -> int | None:
        text = str(value)
        if text.isdigit() and 1 <= int(text) <= self.step_count():
            return int(text)
        if text in self.names:
            return self.names[text]
        self.problem(line, f"{what}: no step {text!r} (steps 1..{self.step_count()}"
                           + (f", or {', '.join(self.names)}" if self.names else "") + ")")
        return None

    def step_count(self) -> int:
        return self._count

    def target(self, name: Any, line: int, what: str) -> tuple[str, ...]:
        try:
            return self.config.topology.targets(str(name))
        except KeyError:
            groups = ", ".join(self.config.topology.groups) or "none"
            self.problem(line, f"{what}: {name!r} is neither a device nor a group of the cell (groups: {groups})")
            return ()

    def signal(self, device: str, signal: str, line: int, what: str) -> bool:
        if device not in self.config.topology.devices:
            self.problem(line, f"{what}: no device {device!r} in the cell")
            return False
        why = self.check_signal(device, signal)
        if why is not None:
            self.problem(line, f"{what}: {why}")
            return False
        return True

    def condition(self, text: str, line: int, what: str) -> Condition | None:
        match = _CONDITION.match(text)
        if not match:
            self.problem(line, f"{what}: {text!r} is not a condition (DEVICE.SIGNAL OP NUMBER, OP one of "
                               f"{' '.join(OPERATORS)})")
            return None
        device, signal, op, value = match.groups()
        return Condition(device, signal, op, float(value)) if self.signal(device, signal, line, what) else None

    def expectation(self, text: str, line: int, count: int) -> Any:
        for pattern, make in ((_RECONNECTED, self._reconnected), (_SIGNAL_WITHIN, self._within),
                              (_NO_TIMEOUTS, self._no_timeouts), (_COUNT, self._count_of)):
            match = pattern.match(text)
            if match:
                return make(match, line)
        self.problem(line, f"{text!r} is not an expectation (CONDITION within T of step S; TARGET reconnected "
                           "within T of step S; no connection timed out [in|outside TARGET]; count(KIND[, TARGET]) "
                           "OP N)")
        return None

    def _of_step(self, match: re.Match, line: int) -> tuple[int, int] | None:
        bound = self.duration(match["bound"], line, "within")
        step = self.reference(match["step"], line, "of step")
        return None if bound is None or step is None else (bound, step)

    def _within(self, match: re.Match, line: int) -> Any:
        condition = self.condition(match["condition"], line, "expect")
        of = self._of_step(match, line)
        return None if condition is None or of is None else SignalWithin(condition, *of, bool(match["end"]))

    def _reconnected(self, match: re.Match, line: int) -> Any:
        devices = self.target(match["target"], line, "reconnected")
        of = self._of_step(match, line)
        return None if not devices or of is None else Reconnected(match["target"], devices, *of, bool(match["end"]))

    def _no_timeouts(self, match: re.Match, line: int) -> Any:
        every = self.config.topology.devices
        if match["target"] is None:
            return NoTimeouts(every)
        named = self.target(match["target"], line, f"no connection timed out {match['where']}")
        return NoTimeouts(named if match["where"].lower() == "in" else tuple(d for d in every if d not in named))

    def _count_of(self, match: re.Match, line: int) -> Any:
        devices = self.target(match["target"], line, "count") if match["target"] else self.config.topology.devices
        return EventCount(match["kind"], devices, match["op"], int(match["n"]))
