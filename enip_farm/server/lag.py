"""How late the cyclic I/O thread (server/implicit.py) runs behind its schedule."""

from __future__ import annotations

#: A wake-up this late is an overload of the farm, not a slow originator.
OVERLOAD_LAG_NS = 5_000_000


class Lag:
    """How late the thread's wake-ups run behind their schedule: the worst of the current second
    (`worst_ns`, shown in /metrics) and the wake-ups later than OVERLOAD_LAG_NS (`overloads`)."""

    def __init__(self) -> None:
        self.worst_ns = 0  # the worst lag of the last whole second
        self.overloads = 0  # wake-ups later than OVERLOAD_LAG_NS
        self._second = 0
        self._worst_now = 0

    def observe(self, lag_ns: int, now: int) -> bool:
        """One wake-up `lag_ns` late at `now`: True when it is an overload."""
        second = now // 1_000_000_000
        if second != self._second:
            self._second, self.worst_ns, self._worst_now = second, self._worst_now, 0
        if lag_ns > self._worst_now:
            self._worst_now = lag_ns
        if lag_ns > OVERLOAD_LAG_NS:
            self.overloads += 1
            return True
        return False
