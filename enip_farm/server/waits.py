"""Waits handed to the OS, bounded: every epoll timeout, event-loop timer and sleep of the farm
goes through `os_wait_s`. A time the core computes from what a peer sent (a connection timeout of
25 days from RPI 0xFFFFFFFF us x 512, a fault lasting a century) must never reach epoll (a C int
of milliseconds), libuv or `time.sleep` unbounded: a clamped wait only wakes early, and every
caller looks at its deadline again when it wakes and waits anew."""

from __future__ import annotations

import math

#: The longest single wait handed to the OS, seconds. Longer deadlines are waited for in steps.
MAX_WAIT_S = 3600.0


def os_wait_s(seconds: float) -> float:
    """`seconds` clamped to [0, MAX_WAIT_S]; NaN and negative waits are 0."""
    if not seconds > 0:  # also NaN
        return 0.0
    if math.isinf(seconds) or seconds > MAX_WAIT_S:
        return MAX_WAIT_S
    return seconds


def os_wait_ns(nanoseconds: int) -> float:
    """A wait of integer nanoseconds (the core's clock) as bounded seconds for the OS."""
    return os_wait_s(nanoseconds / 1e9)
