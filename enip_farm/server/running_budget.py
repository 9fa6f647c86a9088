"""The cyclic I/O thread's side of its budget's running check (cip/budget.py, `observe`): what the
thread really did each second (the CPU it spent, system calls included; the datagrams it took and
sent; its turns with something due and those more than LAG_LIMIT_NS late), handed to the budget
once a second, and each change of the figure said on the console. The thread's own CPU clock is
read here, once a second."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

from enip_farm.cip.budget import LAG_LIMIT_NS, CyclicBudget

_SECOND_NS = 1_000_000_000
log = logging.getLogger(__name__)


class RunningBudget:
    """Counts one I/O thread's second for `budget` (None: a configured budget, nothing checked)."""

    def __init__(self, budget: CyclicBudget | None, cpu_ns: Callable[[], int] = time.thread_time_ns) -> None:
        self.budget = budget
        self._cpu_ns = cpu_ns  # the calling thread's CPU time (ns)
        self.datagrams = 0  # taken and sent this second (the thread adds them)
        self.turns = 0
        self.late_turns = 0
        self._until: int | None = None  # when this second ends
        self._cpu_at = 0

    def turn(self, lag_ns: int) -> None:
        """A turn that had something due, `lag_ns` after it was due."""
        self.turns += 1
        if lag_ns > LAG_LIMIT_NS:
            self.late_turns += 1

    def tick(self, now: int) -> None:
        """At every turn (`now`, ns): once a second, the second's figures to the budget."""
        until = self._until
        if until is not None and now < until:
            return
        cpu = self._cpu_ns()
        budget = self.budget
        if until is not None and budget is not None:
            # a loop held up (a busy machine) makes the window longer than a second: per second it is
            seconds = (now - until + _SECOND_NS) / _SECOND_NS
            source = budget.source
            budget.observe(round((cpu - self._cpu_at) / seconds), round(self.datagrams / seconds), self.turns,
                           self.late_turns)
            if budget.source != source:  # at most once a second
                log.warning("cyclic I/O budget now %s", budget.describe())
        self._until, self._cpu_at = now + _SECOND_NS, cpu
        self.datagrams = self.turns = self.late_turns = 0
