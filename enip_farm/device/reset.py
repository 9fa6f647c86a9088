"""The reset window of a device (Identity Reset, CIP Networks Library Vol. 1, 5-2.4.1), sans-IO: a
reset device does not answer (no TCP listener, UDP dropped) until its reset time has passed since
the reset, then answers again. Time is a parameter (int ns of a monotonic clock), never read here:
the farm asks `due()` when to look again and calls `end(now)`, which ends the window at its
deadline, not a nanosecond before."""

from __future__ import annotations


class ResetWindow:
    __slots__ = ("duration_ns", "deadline", "resets")

    def __init__(self, duration_ns: int) -> None:
        if duration_ns < 0:
            raise ValueError("a reset time is not negative")
        self.duration_ns = duration_ns
        self.deadline: int | None = None  # while resetting: when the device answers again
        self.resets = 0  # how many resets began

    @property
    def active(self) -> bool:
        """The device is resetting: it does not answer."""
        return self.deadline is not None

    def start(self, now: int) -> int:
        """A reset begins at `now`: the time the device answers again."""
        self.resets += 1
        self.deadline = now + self.duration_ns
        return self.deadline

    def due(self) -> int | None:
        """When `end` may end the window; None when not resetting."""
        return self.deadline

    def end(self, now: int) -> bool:
        """End the window if its deadline has come: True if the device answers again from now."""
        if self.deadline is None or now < self.deadline:
            return False
        self.deadline = None
        return True
