"""The cyclic I/O budget of one I/O thread (a farm, or one worker of it): how many class-1
datagrams per second (O->T consumed plus T->O produced) its connections may need together. A
Forward Open whose connection would take the thread past it is refused with the Connection
Manager's out-of-resources status, 0x01/0x0113 (Vol. 1, 3-5.5.2 and table 3-5.33), so the
connections already open keep their timing instead of every one of them going late.

Shared by every device's connection table of that thread, which reserve and release under their
device locks; the budget has its own lock."""

from __future__ import annotations

import threading
from typing import NamedTuple


class Reservation(NamedTuple):
    """What one connection holds of the budget, datagrams per second."""

    rate: float


class CyclicBudget:
    """`datagrams_per_s` for all the connections of one I/O thread; `source` says where the figure
    came from (configured, or measured at start with the cost per packet)."""

    def __init__(self, datagrams_per_s: float, source: str = "configured") -> None:
        self.datagrams_per_s = float(datagrams_per_s)
        self.source = source
        self.reserved = 0.0
        self.refused = 0  # Forward Opens refused for want of budget
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

    def set(self, datagrams_per_s: float, source: str) -> None:
        """The figure once it is known (measured when the farm starts, or configured)."""
        with self._lock:
            self.datagrams_per_s, self.source = float(datagrams_per_s), source

    def describe(self) -> str:
        """e.g. `96 000 datagrams/s per worker (480 connections at RPI 10 ms; measured at start: ...)`."""
        total, connections = f"{self.datagrams_per_s:,.0f}", f"{self.datagrams_per_s / 200:,.0f}"
        return (f"{total.replace(',', ' ')} datagrams/s per worker ({connections.replace(',', ' ')} connections "
                f"at RPI 10 ms; {self.source})")
