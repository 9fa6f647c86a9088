"""The cyclic I/O thread's scheduling policy (Linux sched(7)): SCHED_FIFO at a priority, so that the
host's other load (the farm's event loop, other processes, a scanner under test on the same host)
does not hold a turn back, as a soft PLC's I/O task runs. It needs root or CAP_SYS_NICE; without
them the thread runs at the normal policy and says why."""

from __future__ import annotations

import os


def run_realtime(priority: int) -> str | None:
    """Make the calling thread SCHED_FIFO at `priority` (1-99; 0: leave it as it is). None when
    done (or not asked), else why not, for the caller to tell."""
    if priority <= 0:
        return None
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (OSError, AttributeError) as error:  # no privilege, or no SCHED_FIFO on this system
        return f"cannot run the cyclic I/O thread SCHED_FIFO at priority {priority}: {error}"
    return None
