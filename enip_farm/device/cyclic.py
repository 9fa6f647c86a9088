"""One device's class-1 cyclic I/O, the cyclic I/O thread's side (CIP Networks Library Vol. 2, 3-2
and 3-3; Vol. 1, 3-4.4): O->T datagrams to the connection table, supervision (watchdogs) and T->O
production. Each is one device transaction (device/guard.py): what the table hands out to send
(T->O packets, CIP Safety time coordination replies) is computed under the lock and sent after it,
so a socket write never holds the lock. A `stop-io` fault or the reset window drops O->T and
withholds T->O.
"""

from __future__ import annotations

from collections import Counter

from enip_farm.device.faults import DeviceFaults
from enip_farm.device.guard import BOTH_IMAGES, NO_IMAGES, OUTPUT_IMAGE, DeviceGuard, SendDatagram
from enip_farm.device.reset import ResetWindow

__all__ = ["CyclicIo", "SendDatagram"]


class CyclicIo:
    """Moves one device's class-1 datagrams between the I/O thread and its connection table."""

    def __init__(self, guard: DeviceGuard, faults: DeviceFaults, window: ResetWindow, counters: Counter[str]) -> None:
        self.guard = guard
        self.table = guard.table
        self.faults = faults
        self.window = window
        self.counters = counters

    def receive_io(self, data: bytes, source: tuple[str, int], now: int, send: SendDatagram) -> bool:
        """An O->T datagram from `source` (host, port), received at `now`: True if a connection took it.
        What must answer it at once (CIP Safety time coordination) goes out through `send`, after the lock."""
        if self.faults.io_stopped:
            self.counters["o_t_dropped_io_stopped"] += 1
            return False
        if self.window.active:
            self.counters["o_t_dropped_resetting"] += 1
            return False
        table = self.table
        with self.guard.transaction(now, OUTPUT_IMAGE) as transaction:  # O->T changes the outputs only
            taken = table.receive_datagram(data, source[0], now, source[1])
            if table.answers_queued:  # the one way out: the answers, and whatever T->O is due by now
                transaction.send_after(table.datagrams_to_send(now), send)
        return taken

    def service_io(self, now: int, send: SendDatagram, horizon: int | None = None) -> int | None:
        """Supervise the connections at `now` and hand `send` the T->O packets due by `now` (or by
        `horizon`, the end of the I/O thread's turn), after the lock; the next time something is due."""
        table = self.table
        with self.guard.transaction(now, NO_IMAGES) as transaction:
            if table.supervision_due(now):  # a timeout may change the outputs: look before and after
                transaction.watch(BOTH_IMAGES)
                table.handle_timer(now)
            due, timer = table.produce(now, horizon)
            if due and not self.faults.io_stopped:
                transaction.send_after(due, send)
        return timer

    def get_timer(self) -> int | None:
        return self.guard.read(self.table.get_timer)
