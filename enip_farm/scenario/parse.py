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

from enip_farm.config import FarmConfig
from enip_farm.device.faults import Fault, FaultError
from enip_farm.device.signals import SignalError, SignalMap
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
DEFAULT_WAIT_NS = 10_000_000_000
_STEP_KEYS = frozenset({"id", "at", "after", "delay", "fault", "target", "duration", "params", "clear", "kind", "set",
                        "wait", "timeout", "note"})
_ACTIONS = ("fault", "clear", "set", "wait")
_DURATION = re.compile(r"^\s*(\d+(?:\.\d+)?)\s*(ms|s|min)?\s*$")
_UNITS = {"ms": 1_000_000, "s": 1_000_000_000, "min": 60_000_000_000, None: 1_000_000_000}
_OP = r"(==|!=|<=|>=|<|>)"
_CONDITION = re.compile(rf"^\s*([A-Za-z0-9_.{{}}-]+?)\.([A-Za-z][A-Za-z0-9_-]*)\s*{_OP}\s*(-?\d+(?:\.\d+)?)\s*$")
_OF_STEP = r"within\s+(?P<bound>\S+(?:\s*(?:ms|s|min))?)\s+of\s+(?P<end>end\s+of\s+)?step\s+(?P<step>\S+)"
_SIGNAL_WITHIN = re.compile(rf"^(?P<condition>.+?)\s+{_OF_STEP}$", re.I)
_RECONNECTED = re.compile(rf"^(?P<target>\S+)\s+reconnected\s+{_OF_STEP}$", re.I)
_NO_TIMEOUTS = re.compile(r"^no\s+connection\s+timed\s+out(?:\s+(?P<where>outside|in)\s+(?P<target>\S+))?$", re.I)
_COUNT = re.compile(rf"^count\(\s*(?P<kind>[^,)]+?)\s*(?:,\s*(?P<target>[^)]+?)\s*)?\)\s*(?P<op>{_OP})\s*(?P<n>\d+)$")


class ScenarioError(ValueError):
    """A scenario that cannot run; one line per defect, `file:line: reason`."""

    def __init__(self, problems: list[str]) -> None:
        super().__init__("\n".join(problems))
        self.problems = problems


class _Lines(list):
    lines: list[int]


class _LineLoader(yaml.SafeLoader):
    """Keeps the line of each mapping (`__line__`) and of each item of a sequence (`.lines`)."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        mapping = super().construct_mapping(node, deep=True)
        mapping["__line__"] = node.start_mark.line + 1
        return mapping



def _sequence(loader: _LineLoader, node: yaml.SequenceNode) -> _Lines:
    items = _Lines(loader.construct_sequence(node, deep=True))
    items.lines = [child.start_mark.line + 1 for child in node.value]
    return items


_LineLoader.add_constructor("tag:yaml.org,2002:seq", _sequence)


def signal_check(maps: Mapping[str, SignalMap]) -> SignalCheck:
    """The SignalCheck of devices' signal maps: a signal of the device, one (not a range)."""
    def check(device: str, name: str) -> str | None:
        try:
            signal = maps[device].lookup(name)
        except SignalError as error:
            return f"device {device!r}: {error}"
        return None if signal.count == 1 else f"{name} is a range: a condition or a stimulus names one signal"
    return check


def duration_ns(value: Any) -> int | None:
    """"100 ms", "3 s", "2 min", 1.5 (s) as ns; None if it is none of these."""
    if isinstance(value, bool):
        return None
    if isinstance(value, (int, float)):
        return round(value * 1e9) if value >= 0 else None
    match = _DURATION.match(str(value))
    return round(float(match[1]) * _UNITS[match[2]]) if match else None


def load_scenario(path: str, config: FarmConfig, check_signal: SignalCheck) -> Scenario:
    try:
        with open(path, encoding="utf-8") as file:
            text = file.read()
    except OSError as error:
        raise ScenarioError([f"{path}: cannot read: {error.strerror}"]) from None
    return parse_scenario(text, path, config, check_signal)


def parse_scenario(text: str, source: str, config: FarmConfig, check_signal: SignalCheck) -> Scenario:
    """The scenario of `text` against the cell `config`; ScenarioError listing every defect."""
    try:
        data = yaml.load(text, Loader=_LineLoader)  # noqa: S506 (a SafeLoader)
    except yaml.YAMLError as error:
        mark = getattr(error, "problem_mark", None)
        raise ScenarioError([f"{source}:{mark.line + 1 if mark else 1}: not valid YAML: "
                             f"{getattr(error, 'problem', error)}"]) from None
    return _Parser(source, config, check_signal).scenario(data)


class _Parser:
    def __init__(self, source: str, config: FarmConfig, check_signal: SignalCheck) -> None:
        self.source = source
        self.config = config
        self.check_signal = check_signal
        self.problems: list[tuple[int, str]] = []
        self.names: dict[str, int] = {}

    def problem(self, line: int, message: str) -> None:
        self.problems.append((line, message))

    def scenario(self, data: Any) -> Scenario:
        if not isinstance(data, dict):
            raise ScenarioError([f"{self.source}:1: a scenario is a mapping with steps: and expect:"])
        line = data.get("__line__", 1)
        for key in sorted(set(data) - {"name", "steps", "expect", "duration", "__line__"}, key=str):
            self.problem(line, f"{key}: not a key of a scenario (name, duration, steps, expect)")
        lasting = self.duration(data.get("duration", 0), line, "duration")
        raw_steps = data.get("steps")
        if not isinstance(raw_steps, list) or not raw_steps:
            self.problem(line, "steps: a list of at least one step is needed")
            raw_steps = _Lines()
            raw_steps.lines = []
        self._count = len(raw_steps)
        for number, raw in enumerate(raw_steps, 1):  # names first: a step may wait for a later one
            if isinstance(raw, dict) and raw.get("id") is not None:
                name = str(raw["id"])
                if name in self.names or name.isdigit():
                    self.problem(raw["__line__"], f"id {name!r}: " + (
                        f"taken by step {self.names[name]}" if name in self.names else "a number names a step already"))
                self.names.setdefault(name, number)
        steps = [self.step(number, raw, getattr(raw_steps, "lines", [line] * len(raw_steps))[number - 1])
                 for number, raw in enumerate(raw_steps, 1)]
        steps = [step for step in steps if step is not None]
        self.cycles(steps)
        self.clears(steps)
        raw_expect = data.get("expect", [])
        expectations = []
        if not isinstance(raw_expect, list):
            self.problem(line, "expect: a list of expectations")
        else:
            for index, text in enumerate(raw_expect):
                where = raw_expect.lines[index]
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

    # -- steps --------------------------------------------------------------------------------------

    def step(self, number: int, raw: Any, line: int) -> Step | None:
        if not isinstance(raw, dict):
            self.problem(line, f"step {number}: a mapping (at:/after:, and one of {', '.join(_ACTIONS)})")
            return None
        line = raw["__line__"]
        before = len(self.problems)
        for key in sorted(set(raw) - _STEP_KEYS - {"__line__"}, key=str):
            self.problem(line, f"step {number}: {key}: not a key of a step")
        actions = [key for key in _ACTIONS if key in raw]
        if len(actions) != 1:
            self.problem(line, f"step {number}: one action of {', '.join(_ACTIONS)}, got "
                               f"{', '.join(actions) or 'none'}")
            return None
        at_ns = after = None
        if "at" in raw and "after" in raw:
            self.problem(line, f"step {number}: at and after both given: one or the other")
        if "at" in raw:
            at_ns = self.duration(raw["at"], line, f"step {number}: at")
            if "delay" in raw:
                self.problem(line, f"step {number}: delay goes with after, not with at")
        elif "after" in raw:
            after = self.reference(raw["after"], line, f"step {number}: after")
            if after == number:
                self.problem(line, f"step {number}: waits for itself (after: {raw['after']})")
        elif number > 1:
            after = number - 1
        delay = self.duration(raw.get("delay", 0), line, f"step {number}: delay") or 0
        action = getattr(self, f"_{actions[0]}")(number, raw, line)
        if len(self.problems) > before or action is None:
            return None
        return Step(number, line, action, None if raw.get("id") is None else str(raw["id"]), at_ns, after, delay)

    def _fault(self, number: int, raw: dict, line: int) -> Action | None:
        kind, target = raw["fault"], raw.get("target")
        self.target(target, line, f"step {number}: target")
        params = raw.get("params", {}) or {}
        if not isinstance(params, dict):
            self.problem(line, f"step {number}: params: a mapping of the kind's parameters")
            return None
        params = {k: v for k, v in params.items() if k != "__line__"}
        lasting = None
        if "duration" in raw:
            lasting = self.duration(raw["duration"], line, f"step {number}: duration")
            if lasting == 0:
                self.problem(line, f"step {number}: duration: must be > 0 (leave it out: until cleared)")
        try:
            Fault(str(kind), duration_s=lasting / 1e9 if lasting else None, **params)
        except FaultError as error:
            self.problem(line, f"step {number}: fault {kind}: {error}")
            return None
        return FaultAction(str(target), str(kind), lasting, params)

    def _clear(self, number: int, raw: dict, line: int) -> Action | None:
        target, kind = raw["clear"], raw.get("kind")
        self.target(target, line, f"step {number}: clear")
        if kind is not None:
            try:
                Fault(str(kind))
            except FaultError as error:
                if error.field == "kind":
                    self.problem(line, f"step {number}: kind: {error}")
        return ClearAction(str(target), None if kind is None else str(kind))

    def _set(self, number: int, raw: dict, line: int) -> Action | None:
        values = raw["set"]
        if not isinstance(values, dict) or len(values) <= 1:
            self.problem(line, f"step {number}: set: a mapping of DEVICE.SIGNAL: value")
            return None
        out = []
        for name, value in values.items():
            if name == "__line__":
                continue
            device, _, signal = str(name).rpartition(".")
            if self.signal(device, signal, line, f"step {number}: set {name}"):
                out.append((device, signal, value))
        return SetAction(tuple(out))

    def _wait(self, number: int, raw: dict, line: int) -> Action | None:
        condition = self.condition(str(raw["wait"]), line, f"step {number}: wait")
        timeout = self.duration(raw.get("timeout", DEFAULT_WAIT_NS / 1e9), line, f"step {number}: timeout")
        return None if condition is None or timeout is None else WaitAction(condition, timeout)

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

    _count = 0
