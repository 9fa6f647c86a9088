"""A device's reset (Identity Reset, CIP Networks Library Vol. 1, 5-2.4.1), sans-IO: what a restart
does to the device's state, and its reset window.

The Identity object answers an accepted Reset with the effect `ResetRequested(type)`; the device
performs it right after the request that asked for it has been answered (its reply is built; the
server sends it before anything else of the device's), and the API's reset performs the same
without a request: every class-1 and class-3 connection closes, the output and configuration images
go to their power-up state (all zero), the input image keeps what the field (the API, wires, rules)
holds, the link counters clear, a type-1 reset also restores the configured TCP/IP and Ethernet
Link settings, a safety target's types 1 and 2 clear its safety configuration, and a `Reset` event
(device/events.py: the request and the quiet time) is published with the transaction's: the farm
matches it by class (farm/resets.py) and closes the device's TCP connections and listener.

A reset device does not answer (no TCP listener, UDP dropped) until its reset time has passed since
the reset, then answers again (`restarts` moves on: a session of an earlier count has ended). Time
is a parameter (int ns of the device's monotonic clock; None at the API's edge: the clock the device
is given, device/guard.py): the farm asks `due()` when to look again and calls `end(now)`, which
ends the window at its deadline, not a nanosecond before."""

from __future__ import annotations

from enip_farm.cip.identity import RESET_OUT_OF_BOX, ResetRequested
from enip_farm.device.events import RESET_KINDS, Reset, ResetDone
from enip_farm.device.guard import DeviceGuard, Transaction
from enip_farm.device.objects import ObjectModel
from enip_farm.device.sessions import SessionHandles


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


class Resets:
    """Runs one device's resets, requested by its Identity object or from outside CIP."""

    def __init__(self, objects: ObjectModel, guard: DeviceGuard, sessions: SessionHandles, reset_time_s: float) -> None:
        self.objects = objects
        self.guard = guard
        self.sessions = sessions
        self.quiet_s = reset_time_s
        self.window = ResetWindow(round(reset_time_s * 1e9))

    def perform(self, request: ResetRequested, transaction: Transaction) -> None:
        """In a device transaction: what a restart does to the device's state, and its `Reset` event."""
        now = transaction.now
        kind = request.type
        objects = self.objects
        table = objects.table
        for connection in list(table.connections.values()):
            table.close(connection, f"identity reset (type {kind})", now, ends="device reset")
        for role in ("output", "configuration"):  # power-up state; the inputs are the field's
            assembly = objects.assemblies.get(role)
            if assembly is not None:
                assembly.data[:] = bytes(len(assembly.data))
        if kind == RESET_OUT_OF_BOX:
            objects.tcpip.restore_defaults()
            objects.link.restore_defaults()
        if table.policy.safety is not None:
            table.policy.safety.state.identity_reset(kind)
        objects.link.clear_counters()
        self.sessions.restart()
        self.window.start(now)
        transaction.emit(Reset(request, self.quiet_s))

    def reset(self, kind: int, now: int | None = None) -> bool:
        """A reset from outside CIP (a test engineer's power switch or reset button) at `now` (ns;
        None: the device's clock): as an Identity Reset of type `kind`, without a request to answer.
        False if the device is in its reset window already (nothing happens); ValueError for an
        unknown type."""
        if kind not in RESET_KINDS:
            raise ValueError(f"reset type {kind}: one of {', '.join(map(str, RESET_KINDS))}")
        with self.guard.transaction(now) as transaction:
            if self.window.active:
                return False
            self.perform(ResetRequested(kind), transaction)
        return True

    def end(self, now: int | None = None) -> bool:
        """End the reset window if its deadline has come (`now`, ns; None: the device's clock;
        never before): True if the device answers again from now, with a `ResetDone` event."""
        now = self.guard.clock() if now is None else now
        if not self.window.end(now):
            return False
        self.guard.record(ResetDone(), now)
        return True
