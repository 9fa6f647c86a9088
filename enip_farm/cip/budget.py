"""The cyclic I/O budget of one I/O thread (a farm, or one worker of it): how many class-1
datagrams per second (O->T consumed plus T->O produced) its connections may need together. A
Forward Open whose connection would take the thread past it is refused with the Connection
Manager's out-of-resources status, 0x01/0x0113 (Vol. 1, 3-5.5.2 and table 3-5.33), so the
connections already open keep their timing instead of every one of them going late.

A budget measured at start (`auto`) is then checked against what the I/O thread really does, once a
second (`observe`, sans-IO: the figures are passed in): lowered to what the thread's real CPU per
datagram allows (its system calls included), and held at what is taken in a second in which the
thread's turns ran more than `LAG_LIMIT_NS` late; it rises again (never past the figure measured
at start) only after `CALM_SECONDS` seconds on time since it was last lowered. Only a second of
`MIN_DATAGRAMS` or more counts: the check is for a thread near its budget, not for a few
connections on a busy machine. A configured budget is the operator's and is never moved.

Shared by every device's connection table of that thread, which reserve and release under their
device locks; the budget has its own lock."""

from __future__ import annotations

import threading
from typing import NamedTuple

from enip_farm.config import BUDGET_UTILISATION

#: The promise to the connections admitted: their T->O no later than this (period error p99 2 ms).
LAG_LIMIT_NS = 2_000_000
#: Fewer datagrams than this in a second (100 connections at 10 ms) say too little of the cost per
#: datagram (the turns' own cost is most of it) and are far from any budget.
MIN_DATAGRAMS = 20_000
#: Seconds on time before a lowered budget may rise again.
CALM_SECONDS = 10


class Reservation(NamedTuple):
    """What one connection holds of the budget, datagrams per second."""

    rate: float


class CyclicBudget:
    """`datagrams_per_s` for all the connections of one I/O thread; `source` says where the figure
    came from (configured, or measured at start with the cost per packet, or lowered running)."""

    def __init__(self, datagrams_per_s: float, source: str = "configured", ceiling: float | None = None) -> None:
        self.datagrams_per_s = float(datagrams_per_s)
        self.source = source
        self.reserved = 0.0
        self.refused = 0  # Forward Opens refused for want of budget
        self.lowered = 0  # times the running check took the figure down
        #: the ceiling of any rise: the figure measured at start, or what the CPU cost alone allows
        #: where the machine gave the measuring thread less of a core than the budget is for
        self.ceiling = float(ceiling if ceiling is not None else datagrams_per_s)
        self._measured = self.ceiling
        self._start = self.datagrams_per_s  # the figure set at start
        self._measured_source = source
        self._calm = 0  # seconds on time in a row
        self._lock = threading.Lock()

    @staticmethod
    def rate(o_t_rpi_us: int, t_o_rpi_us: int | None) -> float:
        """Datagrams per second of a connection: its O->T, and its T->O when it starts a stream."""
        return 1e6 / max(o_t_rpi_us, 1) + (1e6 / max(t_o_rpi_us, 1) if t_o_rpi_us else 0.0)

    def reserve(self, rate: float) -> Reservation | None:
        """Take `rate` from the budget; None (nothing taken) when it would go past it."""
        with self._lock:
            if self.reserved + rate > self.datagrams_per_s:
                self.refused += 1
                return None
            self.reserved += rate
            return Reservation(rate)

    def release(self, reservation: Reservation) -> None:
        with self._lock:
            self.reserved = max(0.0, self.reserved - reservation.rate)

    def set(self, datagrams_per_s: float, source: str, ceiling: float | None = None) -> None:
        """The figure once it is known (measured when the farm starts, or configured), and the
        ceiling of any rise (default: the figure)."""
        with self._lock:
            self.datagrams_per_s, self.source = float(datagrams_per_s), source
            self.ceiling = float(ceiling if ceiling is not None else datagrams_per_s)
            self._measured, self._measured_source, self._calm = self.ceiling, source, 0
            self._start = self.datagrams_per_s

    def observe(self, cpu_ns: int, datagrams: int, turns: int, late_turns: int) -> None:
        """One second of the I/O thread: the CPU it spent (its system calls included), the datagrams
        it took and sent, its turns with something due and how many of them ran more than
        LAG_LIMIT_NS late. Only a thread that moves or has taken MIN_DATAGRAMS a second is judged
        (a few connections' cost is the turns', not the packets'; and a thread starved of the CPU
        moves fewer than it has taken). More than 1 % of the turns late: the budget is held at what
        is taken (nothing more admitted); else, with MIN_DATAGRAMS moved, it is what
        BUDGET_UTILISATION of a core carries at the CPU per datagram seen, when that is lower than
        the figure; after CALM_SECONDS seconds on time it may rise again: up to the ceiling when busy,
        to the start figure when idle (never stuck at what was taken when everything closed)."""
        with self._lock:
            if max(datagrams, self.reserved) < MIN_DATAGRAMS:  # little to do: on time, back to the start figure
                self._calm += 1
                self._rise(self._start, "")
                return
            if late_turns * 100 > turns:
                self._calm = 0
                if self.reserved < self.datagrams_per_s:
                    self._lower(self.reserved, f"held at what is taken: {late_turns} of {turns} turns of the I/O "
                                f"thread in a second ran more than {LAG_LIMIT_NS / 1e6:g} ms late")
                return
            self._calm += 1
            carried, cost = self._measured, ""
            if datagrams >= MIN_DATAGRAMS and cpu_ns > 0:
                carried = round(BUDGET_UTILISATION * 1e9 * datagrams / cpu_ns, -2)
                cost = f"{cpu_ns / datagrams / 1000:.2f} us of CPU per datagram in the I/O thread"
                if carried < self.datagrams_per_s:
                    self._lower(carried, f"lowered running: {cost}, for {BUDGET_UTILISATION:.0%} of a core")
                    return
            self._rise(carried, cost)

    def _rise(self, carried: float, cost: str) -> None:
        """After CALM_SECONDS on time, up to what `carried` allows, never past the ceiling."""
        if self._calm >= CALM_SECONDS and self.datagrams_per_s < min(self._measured, carried):
            self.datagrams_per_s = min(self._measured, carried)
            back = self.datagrams_per_s == self._start
            self.source = self._measured_source if back else (
                f"raised running: {cost or 'the I/O thread'}, {CALM_SECONDS} s on time")

    def _lower(self, datagrams_per_s: float, source: str) -> None:
        self.datagrams_per_s, self.source = float(datagrams_per_s), source
        self.lowered += 1
        self._calm = 0  # a rise counts its seconds on time from the last lowering

    def describe(self) -> str:
        """e.g. `96 000 datagrams/s per worker (480 connections at RPI 10 ms; measured at start: ...)`."""
        total, connections = f"{self.datagrams_per_s:,.0f}", f"{self.datagrams_per_s / 200:,.0f}"
        return (f"{total.replace(',', ' ')} datagrams/s per worker ({connections.replace(',', ' ')} connections "
                f"at RPI 10 ms; {self.source})")
