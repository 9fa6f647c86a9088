"""What a scenario file holds, parsed and checked (parse.py makes these): steps with their timing and
action, expectations with the step they are measured from. Times are integer nanoseconds."""

from __future__ import annotations

import operator
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

#: The comparisons a condition may use.
OPERATORS: Mapping[str, Callable[[Any, Any], bool]] = MappingProxyType({
    "==": operator.eq, "!=": operator.ne, "<=": operator.le, ">=": operator.ge, "<": operator.lt, ">": operator.gt})


@dataclass(frozen=True)
class Condition:
    """DEVICE.SIGNAL OP VALUE, e.g. io1.DO5 == 0."""

    device: str
    signal: str
    op: str
    value: float

    def holds(self, value: float) -> bool:
        return OPERATORS[self.op](value, self.value)

    def __str__(self) -> str:
        return f"{self.device}.{self.signal} {self.op} {self.value:g}"


@dataclass(frozen=True)
class FaultAction:
    target: str  # a device or a group
    kind: str
    duration_ns: int | None
    params: Mapping[str, Any]

    def __str__(self) -> str:
        lasting = f" for {self.duration_ns / 1e9:g} s" if self.duration_ns is not None else ""
        given = "".join(f" {k}={v}" for k, v in self.params.items())
        return f"{self.kind} on {self.target}{lasting}{given}"


@dataclass(frozen=True)
class ClearAction:
    target: str
    kind: str | None

    def __str__(self) -> str:
        return f"clear {self.kind or 'every fault'} on {self.target}"


@dataclass(frozen=True)
class SetAction:
    values: tuple[tuple[str, str, Any], ...]  # (device, signal, value)

    def __str__(self) -> str:
        return "set " + ", ".join(f"{d}.{s}={v}" for d, s, v in self.values)


@dataclass(frozen=True)
class WaitAction:
    condition: Condition
    timeout_ns: int

    def __str__(self) -> str:
        return f"wait until {self.condition} (at most {self.timeout_ns / 1e9:g} s)"


Action = FaultAction | ClearAction | SetAction | WaitAction


@dataclass(frozen=True)
class Step:
    """Step `number` (1-based, file order): at `at_ns` from the start, or `delay_ns` after step `after`
    has ended (None with no `at_ns`: the start)."""

    number: int
    line: int
    action: Action
    name: str | None = None
    at_ns: int | None = None
    after: int | None = None
    delay_ns: int = 0

    @property
    def label(self) -> str:
        return f"step {self.number}" + (f" ({self.name})" if self.name else "")


@dataclass(frozen=True)
class SignalWithin:
    """CONDITION within BOUND of step S (its start, or its end)."""

    condition: Condition
    bound_ns: int
    step: int
    end: bool = False


@dataclass(frozen=True)
class Reconnected:
    """TARGET reconnected within BOUND of step S: every device of it has its class-1 connections back
    (each originator it lost: its first O->T after its next accepted Forward Open, as the report
    measures a reconnection; where no originator was lost, a class-1 connection opened)."""

    target: str
    devices: tuple[str, ...]
    bound_ns: int
    step: int
    end: bool = False


@dataclass(frozen=True)
class NoTimeouts:
    """No connection timed out (in TARGET's devices, or outside them)."""

    devices: tuple[str, ...]  # the devices the expectation looks at


@dataclass(frozen=True)
class EventCount:
    """count(KIND[, TARGET]) OP N: how many events of a kind the devices recorded during the run."""

    kind: str
    devices: tuple[str, ...]
    op: str
    count: int


Check = SignalWithin | Reconnected | NoTimeouts | EventCount


@dataclass(frozen=True)
class Expectation:
    text: str
    line: int
    check: Check


@dataclass(frozen=True)
class Scenario:
    name: str
    source: str
    steps: tuple[Step, ...]
    expectations: tuple[Expectation, ...]
    devices: tuple[str, ...] = field(default=())  # every device of the cell
    duration_ns: int = 0  # the run lasts at least this long from the start (time for what is expected)
