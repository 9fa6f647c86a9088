"""A scenario run on a running farm, on the farm's event loop: the schedule (schedule.py) given the
time by `clock`, each due step carried out (a fault on a device or a group, a clear, a stimulus, a
wait for a condition), every device's events recorded while it runs, the expectations judged at the
end (verdict.py). It ends when its steps have, not before its `duration`, every fault it set with a
duration has ended and every `within T of step S` has had its T. However it ends (its steps done, a
wait timed out, cancelled), every fault it set is cleared and every signal it set is put back:
nothing a scenario does outlives it."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable, Mapping
from typing import Any, Protocol

from enip_farm.config import FarmConfig
from enip_farm.device.device import Device
from enip_farm.device.events import ScenarioStep
from enip_farm.device.faults import Fault, FaultType
from enip_farm.device.report import reconnection_figures
from enip_farm.device.signals import SignalMap
from enip_farm.scenario.model import (
    ClearAction,
    FaultAction,
    Reconnected,
    Scenario,
    SetAction,
    SignalWithin,
    Step,
    WaitAction,
)
from enip_farm.scenario.schedule import Schedule, StepState
from enip_farm.scenario.verdict import Recording, ScenarioResult, StepOutcome, judge

TICK_S = 0.002  # how often waits are looked at (and the longest a due step waits for its turn)


class SignalHandle(Protocol):
    """What the runner needs of a device's Python API (control/handle.py's DeviceHandle)."""

    signals: SignalMap

    def get(self, name: str) -> Any: ...

    def set(self, values: Mapping[str, Any] | None = None, **signals: Any) -> None: ...


class ScenarioFarm(Protocol):
    """What the runner needs of a farm (farm/farm.py's Farm)."""

    @property
    def config(self) -> FarmConfig: ...

    @property
    def devices(self) -> Mapping[str, Device]: ...

    def __getitem__(self, name: str) -> SignalHandle: ...

    async def inject_fault(self, name: str, fault: FaultType) -> Any: ...

    async def clear_faults(self, name: str, kind: str | None = None) -> list[str]: ...

    def mark(self, text: str) -> None: ...


async def run_scenario(farm: ScenarioFarm, scenario: Scenario, progress: Callable[[str], None] | None = None,
                       clock: Callable[[], int] = time.monotonic_ns) -> ScenarioResult:
    """Run `scenario` to its end (or its cancellation) and judge it; `progress` gets a line per step."""
    say = progress or (lambda line: None)
    start = clock()
    recording = Recording(start, {name: {"input": farm.devices[name].inputs, "output": farm.devices[name].outputs}
                                  for name in scenario.devices})
    unsubscribe = [farm.devices[name].observe(recording.events.append) for name in scenario.devices]
    schedule = Schedule(scenario.steps)
    schedule.start(start)
    run = _Run(farm, schedule, say, start)
    status = "passed"
    try:
        while not schedule.done or clock() < max(start + scenario.duration_ns, horizon(scenario, schedule)):
            now = clock()
            for step in schedule.due(now):
                await run.carry_out(step, clock())
            for step in schedule.running:
                run.look(step, clock())
            await asyncio.sleep(TICK_S)
    except asyncio.CancelledError:
        status = "cancelled"
        schedule.cancel()
        say(f"{(clock() - start) / 1e9:8.3f} s  cancelled")
    finally:
        await run.undo()
        for stop in unsubscribe:
            stop()
    recording.started, recording.ended = dict(schedule.started), dict(schedule.ended)
    for number, step in schedule.steps.items():  # a fault's step ends when its duration does
        if isinstance(step.action, FaultAction) and step.action.duration_ns and number in schedule.started:
            recording.ended[number] = schedule.started[number] + step.action.duration_ns
    recording.reconnections = {name: reconnection_figures(farm.devices[name]) for name in scenario.devices}
    verdicts = judge(scenario, recording, {name: farm[name].signals for name in scenario.devices})
    if status == "passed" and (any(not v.passed for v in verdicts) or any(
            state is not StepState.DONE for state in schedule.state.values())):
        status = "failed"
    steps = [StepOutcome(n, step.name, str(step.action), schedule.state[n].value,
                         _seconds(schedule.started.get(n), start), _seconds(schedule.ended.get(n), start),
                         run.details.get(n, "")) for n, step in schedule.steps.items()]
    return ScenarioResult(scenario.name, status, steps, verdicts, round((clock() - start) / 1e9, 3))


def _devices_of(farm: ScenarioFarm, step: Step) -> tuple[str, ...]:
    action = step.action
    if isinstance(action, (FaultAction, ClearAction)):
        return farm.config.topology.targets(action.target)
    if isinstance(action, SetAction):
        return tuple(dict.fromkeys(device for device, _, _ in action.values))
    return (action.condition.device,)


def horizon(scenario: Scenario, schedule: Schedule) -> int:
    """The least end of a run whose steps are done: every fault it set with a duration has ended, and
    every `within T of step S` has had its T (so that what is expected has had the time it is given)."""
    ends = [schedule.start_ns or 0]
    for number, step in schedule.steps.items():
        if isinstance(step.action, FaultAction) and step.action.duration_ns and number in schedule.started:
            ends.append(schedule.started[number] + step.action.duration_ns)
    for expectation in scenario.expectations:
        check = expectation.check
        if isinstance(check, (SignalWithin, Reconnected)) and check.step in schedule.started:
            since = schedule.started[check.step]
            step = schedule.steps[check.step]
            if check.end and isinstance(step.action, FaultAction) and step.action.duration_ns:
                since += step.action.duration_ns
            elif check.end:
                since = schedule.ended.get(check.step, since)
            ends.append(since + check.bound_ns)
    return max(ends)


def _seconds(when: int | None, start: int) -> float | None:
    return None if when is None else round((when - start) / 1e9, 6)


class _Run:
    """One run's doings: the faults and signals it set (to undo), the deadlines of its waits."""

    def __init__(self, farm: ScenarioFarm, schedule: Schedule, say: Callable[[str], None], start: int) -> None:
        self.farm = farm
        self.schedule = schedule
        self.say = say
        self.start = start
        self.faults: list[tuple[str, str]] = []
        self.signals: dict[tuple[str, str], Any] = {}  # (device, signal) -> its value before the scenario
        self.deadlines: dict[int, int] = {}
        self.details: dict[int, str] = {}

    def _line(self, step: Step, now: int, text: str) -> None:
        """A progress line; the step in the recording's side file (the farm's `mark`) and in the event
        log of each device it touches (the dashboard's events), as a `ScenarioStep` event."""
        line = f"{step.label}: {text}"
        self.say(f"{(now - self.start) / 1e9:8.3f} s  {line}")
        self.farm.mark(line)
        for device in _devices_of(self.farm, step):
            self.farm.devices[device].record(ScenarioStep(line), now)

    async def carry_out(self, step: Step, now: int) -> None:
        action = step.action
        if isinstance(action, WaitAction):
            self.deadlines[step.number] = self.schedule.started[step.number] + action.timeout_ns
            self._line(step, now, str(action))
            self.look(step, now)
            return
        if isinstance(action, FaultAction):
            fault = Fault(action.kind, duration_s=None if action.duration_ns is None else action.duration_ns / 1e9,
                          **action.params)
            self.faults.append((action.target, action.kind))
            await self.farm.inject_fault(action.target, fault)
        elif isinstance(action, ClearAction):
            await self.farm.clear_faults(action.target, action.kind)
        elif isinstance(action, SetAction):
            for device, signal, value in action.values:
                self.signals.setdefault((device, signal), self.farm[device].get(signal))
                self.farm[device].set({signal: value})
        self.schedule.end(step.number, now)
        self._line(step, now, str(action))

    def look(self, step: Step, now: int) -> None:
        """A running wait: ended when its condition holds, failed at its deadline."""
        action = step.action
        assert isinstance(action, WaitAction)
        condition = action.condition
        if condition.holds(self.farm[condition.device].get(condition.signal)):
            self.schedule.end(step.number, now)
            self._line(step, now, f"{condition}: met")
        elif now >= self.deadlines[step.number]:
            self.schedule.fail(step.number, now)
            self.details[step.number] = f"{condition} not met within {action.timeout_ns / 1e9:g} s"
            self._line(step, now, f"FAILED: {self.details[step.number]}")

    async def undo(self) -> None:
        """Clear every fault the run set and put back every signal it set, whatever happened."""
        for target, kind in reversed(self.faults):
            await self.farm.clear_faults(target, kind)
        for (device, signal), value in self.signals.items():
            self.farm[device].set({signal: value})
