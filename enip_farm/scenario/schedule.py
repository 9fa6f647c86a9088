"""When each step of a scenario is due, sans-IO: the time is given (`now`, int ns of a monotonic
clock), never read, so a unit test holds the scheduler to the tick. A step is due at the start plus
its `at`, or at the end of the step it comes after plus its `delay`; it ends when the runner says so
(at once for a fault, a clear or a stimulus; when its condition holds for a wait). A step that
failed (a wait that timed out) fails every step that comes after it, and they never run."""

from __future__ import annotations

from enum import Enum

from enip_farm.scenario.model import Step


class StepState(str, Enum):
    PENDING = "pending"
    RUNNING = "running"
    DONE = "done"
    FAILED = "failed"
    SKIPPED = "skipped"  # a step it comes after failed, or the scenario was cancelled


class Schedule:
    """The steps' states and times; the runner asks `due(now)` and reports `ended`/`failed`."""

    def __init__(self, steps: tuple[Step, ...]) -> None:
        self.steps = {step.number: step for step in steps}
        self.state = {step.number: StepState.PENDING for step in steps}
        self.started: dict[int, int] = {}
        self.ended: dict[int, int] = {}
        self.start_ns: int | None = None

    def start(self, now: int) -> None:
        self.start_ns = now

    def due_at(self, number: int) -> int | None:
        """When step `number` is due; None while the step it comes after has not ended."""
        step = self.steps[number]
        if step.at_ns is not None or step.after is None:
            return self.start_ns + (step.at_ns or 0)  # type: ignore[operator]
        end = self.ended.get(step.after)
        return None if end is None else end + step.delay_ns

    def due(self, now: int) -> list[Step]:
        """The pending steps due by `now`, in the order of their due times (then file order); each is
        marked running at its due time (not at `now`: a late look does not move a step's time)."""
        found = []
        for number, state in self.state.items():
            if state is StepState.PENDING:
                due = self.due_at(number)
                if due is not None and due <= now:
                    found.append((due, number))
        for due, number in sorted(found):
            self.state[number] = StepState.RUNNING
            self.started[number] = due
        return [self.steps[number] for _, number in sorted(found)]

    def end(self, number: int, now: int) -> None:
        self.state[number] = StepState.DONE
        self.ended[number] = now

    def fail(self, number: int, now: int) -> None:
        """Step `number` failed at `now`: the steps after it (directly or not) will never run."""
        self.state[number] = StepState.FAILED
        self.ended[number] = now
        changed = True
        while changed:
            changed = False
            for other, step in self.steps.items():
                if self.state[other] is StepState.PENDING and step.after is not None and step.at_ns is None and \
                        self.state[step.after] in (StepState.FAILED, StepState.SKIPPED):
                    self.state[other] = StepState.SKIPPED
                    changed = True

    def cancel(self) -> None:
        for number, state in self.state.items():
            if state in (StepState.PENDING, StepState.RUNNING):
                self.state[number] = StepState.SKIPPED

    @property
    def running(self) -> list[Step]:
        return [self.steps[n] for n, state in self.state.items() if state is StepState.RUNNING]

    @property
    def done(self) -> bool:
        return all(state not in (StepState.PENDING, StepState.RUNNING) for state in self.state.values())

    def next_due(self) -> int | None:
        """The earliest time a pending step is due (None: none is known yet)."""
        times = [due for number, state in self.state.items() if state is StepState.PENDING
                 and (due := self.due_at(number)) is not None]
        return min(times, default=None)
