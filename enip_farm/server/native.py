"""The native class-1 path (CIP Networks Library Vol. 2, 3-2 and 3-3): which devices the extension
`_class1` (enip_farm/server/_class1.c and the sources beside it) runs, and the moves of their state
between it and Python (this side of _class1_state.c).

A device is in native mode when the extension is built and on (`cyclic_io.native`, and not
ENIP_FARM_NATIVE=0), no fault is active on it, it is not resetting, nothing records or probes it
(no recorder or reaction probes; image observers are told each change of the output image that the
engine makes, `publish_changes`, as the Python path's transactions tell them), every T->O fits
the engine's packet (MAX_T_O_PAYLOAD bytes of header and data) and every I/O connection is a plain
class-1 one of the formats the engine serves: O->T with the 32-bit run/idle header and fixed-size
data (or the heartbeat of an input-only or listen-only connection), T->O point to point (the input
assembly, an EDS point with or without its run/idle header, or a heartbeat). Then the engine holds
its hot state (sequences, deadlines, the streams, the counters, the originator measurement) and
works on the assemblies' own bytearrays; Python stays authoritative for everything else through
the device lock (device/guard.py):
- a transaction takes the state back (`enter`: the engine's values written into the Connection,
  Production, OriginatorMeasure objects and the counters; the device is Python's) and, before it
  lets the lock go, hands it over again if the device still qualifies (`exit`);
- a reader under the lock (`DeviceGuard.read`) takes it back and hands it over as a transaction does;
  `sync` writes the values back for the readers without the lock (the engine keeps the device);
- a change of what qualifies outside a transaction (a fault, an observer, a probe) takes the
  device back at once (`park`, under the GIL), and its next transaction decides again.
What the engine does not do (a run/idle change, an unknown connection, a malformed datagram, a
supervision deadline reached) it hands to the Python path before changing anything.
"""

from __future__ import annotations

import ipaddress
import os
import socket
from collections.abc import Callable
from typing import Any

from enip_farm.cip.connection import ConnectionKind
from enip_farm.device.device import Device
from enip_farm.device.events import ImageChanged

try:
    from enip_farm.server import _class1
except ImportError:  # no compiler where the package was built: the pure-Python path
    _class1 = None

#: Whether the extension is built.
BUILT = _class1 is not None
#: The most bytes of run/idle header and data a T->O of the engine carries: a longer one stays on the Python path.
MAX_T_O_PAYLOAD: int = _class1.MAX_T_O_PAYLOAD if _class1 is not None else 0
#: Set to 0 (or off) to run every connection on the Python path, whatever the configuration says.
ENVIRONMENT = "ENIP_FARM_NATIVE"


def native_wanted(setting: str | bool = "auto") -> bool:
    """Whether the native path runs: built, `setting` not off (nor false: YAML's bare off) and
    ENIP_FARM_NATIVE not 0."""
    return (BUILT and setting not in ("off", False)
            and os.environ.get(ENVIRONMENT, "").lower() not in ("0", "off", "false"))


def new_engine() -> Any:
    """The engine of one cyclic I/O thread (the extension must be built)."""
    assert _class1 is not None
    return _class1.Engine()


def _unicast(address: tuple[str, int]) -> bool:
    return not ipaddress.IPv4Address(address[0]).is_multicast


def plan(device: Device) -> tuple[list[tuple], list[tuple], bool, int | None] | None:
    """What the engine would hold of `device` (its connections and streams, the idle policy and the
    earliest supervision deadline of the connections Python keeps: class 3), or None when the device
    must stay on the Python path. Called under the device lock."""
    faults, cyclic, guard, table = device.faults, device.cyclic, device.guard, device.table
    if not table.connections:
        return None  # nothing to run (most explicit requests' devices)
    if (faults.active or faults.io_stopped or faults.impairment is not None or faults.safety_tamper is not None
            or device.reset_window.deadline is not None or device.recorder is not None or cyclic.stimuli
            or cyclic.expectations):
        return None
    observed = bool(guard.observers.of_images)  # each change of the output image told (`publish_changes`)
    if table.answers_queued or table.schedule.safety_consumers:
        return None
    conns = []
    watch = None
    for connection in table.connections.values():
        if connection.kind is ConnectionKind.EXPLICIT:  # its timeout is Python's: the engine hands it over then
            watch = connection.deadline if watch is None else min(watch, connection.deadline)
            continue
        if (connection.safety is not None or connection.o_t_modeless or connection.o_t_variable
                or connection.multicast):
            return None
        assembly = table.packets.consumed_assembly(connection)
        if assembly is None:
            return None
        conns.append((connection, connection.measure, assembly.data, socket.inet_aton(connection.originator_host),
                      not connection.o_t_run_idle_header,  # without it: a heartbeat (input only, listen only)
                      observed and assembly is guard.output))  # the image the Python path's transaction compares
    if not conns:
        return None
    streams = []
    inputs = table.assemblies.get("input")
    points = table.packets._points  # noqa: SLF001 - the table's assemblies by instance
    for production in table.productions.values():
        if production.safety is not None or production.users != 1 or not _unicast(production.address):
            return None
        if production.heartbeat:
            data, header = None, b""
        elif production.point is None:
            if inputs is None:
                return None
            data, header = inputs.data, b""
        else:
            assembly = points.get(production.point)
            data, header = (assembly.data if assembly is not None else None), production.header
        if len(header) + (len(data) if data is not None else 0) > MAX_T_O_PAYLOAD:
            return None  # more than the engine's packet holds
        host, port = production.address
        streams.append((production, socket.inet_aton(host) + port.to_bytes(2, "big"), data, header, True))
    return conns, streams, table.policy.outputs_off_on_idle, watch


def publish_changes(changes: list[tuple[int, int, bytes, bytes]], device_of: Callable[[int], Device],
                    failed: Callable[[int, int], None] | None = None) -> None:
    """The engine's output image changes (`Engine.changes`: slot, now, before, after), taken and
    published in order as the Python path's O->T transaction publishes them (device/guard.py): an
    ImageChanged of the output at the turn's `now`, told to the image observers. In the I/O thread,
    after the engine's `receive` or `consume` and before the datagrams it left to Python. An
    observer's exception goes to `failed(slot, now)` where given (the others are told all the same)."""
    pending = changes[:]
    changes.clear()
    for slot, now, before, after in pending:
        try:
            device_of(slot).guard.publish(now, (), (), (ImageChanged("output", before, after),), ())
        except Exception:
            if failed is None:
                raise
            failed(slot, now)


class NativeDevice:
    """One device's place in the engine: the hooks its guard calls (device/guard.py `NativeHooks`).
    The engine's flag is the one truth of whether it runs the device (each call on it is atomic
    under the GIL); `park` may come from any thread at any time, so a hand-over that a park
    overtook is taken back at once (`_parks`)."""

    __slots__ = ("engine", "slot", "device", "_reschedule", "_store", "_load", "_resume", "_native", "_was", "_parks",
                 "_turns", "_turn", "_entered")

    def __init__(self, engine: Any, fd: int, device: Device, reschedule: Callable[[], None]) -> None:
        self.engine = engine
        self.device = device
        self.slot: int = engine.add(fd, socket.inet_aton(device.profile.address), device.counters, device.io_traffic)
        self._reschedule = reschedule  # the device's timer to the I/O thread's heap (from any thread)
        self._store, self._load, self._resume, self._native = engine.store, engine.load, engine.resume, engine.native
        self._was = False
        self._parks = 0
        self._turns = engine.turns
        self._turn = 0
        self._entered = 0  # the parks counted when the transaction began

    @property
    def active(self) -> bool:
        """Whether the engine runs the device now."""
        return self._native(self.slot)

    def attach(self) -> None:
        guard = self.device.guard
        guard.native = self
        guard.observers.changed = self.park
        self.device.faults.changed = self.park

    def detach(self) -> None:
        guard = self.device.guard
        with guard.lock:
            self._release()
            if guard.native is self:
                guard.native = None
            guard.observers.changed = None
            self.device.faults.changed = None

    def _release(self) -> bool:
        try:
            return self._store(self.slot, True)
        except Exception:  # the engine let the device go with what Python had
            return True

    def enter(self) -> None:
        """The device lock was just taken for a transaction: the state back to Python."""
        self._turn = self._turns()
        self._entered = self._parks
        self._was = self._release()

    def exit(self) -> None:
        """The transaction's end, the lock still held: to the engine again if the device qualifies."""
        parks = self._parks
        try:
            if self._was and parks == self._entered and self._unchanged() and self._resume(self.slot):
                pass  # nothing of its class-1 state changed (an explicit request): as it was
            elif (planned := plan(self.device)) is not None:
                self._load(self.slot, *planned)
                if parks != self._parks:  # a park came while this was decided: it wins
                    self._release()
        except Exception:  # the Python path runs it: never lose the lock's release over this
            self._release()
        if self._native(self.slot):
            if not self._was or self._turn != self._turns():  # the I/O thread may wait past its deadlines
                self._reschedule()
        elif self._was:
            self._reschedule()  # the Python path produces its T->O from now on
        self._was = False

    def _unchanged(self) -> bool:
        """Whether what `plan` looks at outside the class-1 state kept no change this transaction
        (the engine checks that state itself, `resume`): no connection event, nothing probing or recording."""
        device = self.device
        return not (device.table.pending_events or device.cyclic.stimuli or device.cyclic.expectations
                    or device.recorder is not None or device.reset_window.deadline is not None)

    def sync(self) -> None:
        """The engine's values written back (`settle`, `counters`); the engine keeps the device."""
        try:
            self._store(self.slot, False)
        except Exception:
            pass  # the engine let the device go: Python's values stand

    def park(self) -> None:
        """What qualifies may have changed (a fault, an observer, a probe): the device is Python's
        until its next transaction decides again. Under the GIL, from any thread."""
        self._parks += 1
        if self._release():
            self._reschedule()

    def timer(self) -> int | None:
        return self.engine.timer(self.slot)
