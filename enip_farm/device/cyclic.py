"""One device's class-1 cyclic I/O, the cyclic I/O thread's side (CIP Networks Library Vol. 2, 3-2
and 3-3; Vol. 1, 3-4.4): O->T datagrams to the connection table, supervision (watchdogs) and T->O
production. Each is one device transaction (device/guard.py); what the table hands out to send
(T->O packets, CIP Safety time coordination replies) is computed in it and sent after it, so a
socket write never holds the lock. A `stop-io` fault or the reset window drops O->T and withholds T->O;
a `degraded-link` fault's path (device/impairment.py) loses, holds and doubles datagrams both ways.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable

from enip_farm.device.faults import DeviceFaults
from enip_farm.device.guard import BOTH_IMAGES, NO_IMAGES, OUTPUT_IMAGE, DeviceGuard
from enip_farm.device.reaction import ReactionProbe
from enip_farm.device.reset import ResetWindow

#: Sends one datagram (the server's socket): data, destination.
SendDatagram = Callable[[bytes, tuple[str, int]], None]


class CyclicIo:
    """Moves one device's class-1 datagrams between the I/O thread and its connection table."""

    def __init__(self, guard: DeviceGuard, faults: DeviceFaults, window: ResetWindow, counters: Counter[str]) -> None:
        self.guard = guard
        self.table = guard.table
        self.faults = faults
        self.window = window
        self.counters = counters
        #: Reaction probes (device/reaction.py) whose stimulus is an input of this device, and those
        #: whose expected output is one of its outputs; replaced whole (copy on write), never edited.
        self.stimuli: tuple[ReactionProbe, ...] = ()
        self.expectations: tuple[ReactionProbe, ...] = ()

    def receive_io(self, data: bytes, source: tuple[str, int], now: int, send: SendDatagram,
                   received_at: int | None = None) -> bool:
        """An O->T datagram from `source` (host, port), received at `now`: True if a connection took it.
        What must answer it at once (CIP Safety time coordination) goes out through `send`, after the lock."""
        if self.faults.io_stopped:
            self.counters["o_t_dropped_io_stopped"] += 1
            return False
        if self.window.deadline is not None:  # resetting (`ResetWindow.active`, without the call)
            self.counters["o_t_dropped_resetting"] += 1
            return False
        if self.faults.safety_tamper is not None:
            send = self._tampered(send)
        path = self.faults.impairment
        if path is not None:  # a degraded link: the datagram may be lost, held, doubled
            if path.from_device is not None:
                send = path.from_device.through(send, now)
            if path.to_device is not None:
                passing = path.to_device.admit(data, source, now)
                if path.to_device.held and self.guard.timer_moved is not None:
                    self.guard.timer_moved()  # what is held is due before the device's own timer, maybe
                taken = [self._take(d, s, now, send, received_at) for d, s in passing]
                return any(taken) or bool(path.to_device.held)
        return self._take(data, source, now, send, received_at)

    def _take(self, data: bytes, source: tuple[str, int], now: int, send: SendDatagram,
              received_at: int | None) -> bool:
        table, output, expectations = self.table, self.guard.output, self.expectations
        with self.guard.transaction(now, OUTPUT_IMAGE):  # O->T changes the outputs only
            old = bytes(output.data) if expectations and output is not None else None
            taken = table.receive_datagram(data, source[0], now, source[1], received_at)
            # the one way out: the answers queued, and whatever T->O is due by now goes with them
            replies = table.datagrams_to_send(now) if table.answers_queued else ()
            if old is not None and output.data != old:  # before the observers hear of the change (O(1) each)
                for probe in expectations:
                    probe.consumed(output.data, now if received_at is None else received_at)
        for packet, address in replies:
            send(packet, address)
        return taken

    def service_io(self, now: int, send: SendDatagram, horizon: int | None = None) -> int | None:
        """Supervise the connections at `now` and hand `send` the T->O packets due by `now` (or by
        `horizon`, the end of the I/O thread's turn), after the lock; the next time something is due."""
        guard, table = self.guard, self.table
        if self.faults.safety_tamper is not None:
            send = self._tampered(send)
        path = self.faults.impairment
        if path is not None:  # a degraded link: what it held is due now, and what is sent goes through it
            if path.from_device is not None:
                for packet, address in path.from_device.due(now):
                    send(packet, address)
                send = path.from_device.through(send, now)
            if path.to_device is not None and not self.faults.io_stopped and not self.window.active:
                for data, source in path.to_device.due(now):
                    self._take(data, source, now, send, None)
        with guard.transaction(now, NO_IMAGES) as transaction:
            if table.supervision_due(now):  # a timeout may change the outputs: look before and after
                transaction.watch(BOTH_IMAGES)
                table.handle_timer(now)
                if self.faults.active:  # the device's fault stopped the I/O: not the originator's timeout
                    for connection in table.ended:
                        measure = connection.measure
                        if measure is not None and measure.ended_at == now and measure.ended == "timeout":
                            measure.ended = "device fault"
            due, timer = table.produce(now, horizon)
            # the inputs the T->O of this turn carried, read in the same transaction
            carried = bytes(table.assemblies["input"].data) if due and self.stimuli else None
        if due and not self.faults.io_stopped:
            for packet, address in due:
                send(packet, address)
            if carried is not None:
                for probe in self.stimuli:
                    probe.produced(carried, now)
        return _earliest(timer, path.next_due()) if path is not None else timer

    def _tampered(self, send: SendDatagram) -> SendDatagram:
        """`send` behind the safety fault's tampering (device/safety_faults.py) that is set."""
        tamper = self.faults.safety_tamper
        data, coordination = self.guard.read(lambda: tamper.streams(self.table.connections.values()))
        return tamper.through(send, data, coordination)

    def get_timer(self) -> int | None:
        timer = self.guard.read(self.table.get_timer)
        path = self.faults.impairment
        return _earliest(timer, path.next_due()) if path is not None else timer


def _earliest(a: int | None, b: int | None) -> int | None:
    return b if a is None else a if b is None else min(a, b)
