"""One device's lock discipline and its one observer mechanism.

The device lock is held around every read and every write of the I/O image and of the connection
table (explicit requests, O->T consumption, T->O production, supervision, the Python and HTTP
APIs), so no reader sees half a write and no writer loses one. What happened inside the lock
(requests, connection events, image changes) is published to the device's observers after the
lock is released, in the thread that made it happen, and kept in the device's event log
(device/events.py). Nothing is sent on a socket under the lock.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterable

from enip_farm.cip.assembly import AssemblyInstance
from enip_farm.cip.connection_events import ConnectionEvent, ConnectionOpened, describe
from enip_farm.cip.connection_table import ConnectionTable
from enip_farm.cip.message_router import Handled
from enip_farm.device.events import Event, EventLog, ImageChange

__all__ = ["DeviceGuard", "Observer", "Snapshot", "describe", "replace_image"]

#: An observer of a device: called with every event (log entries, connection events, image changes).
Observer = Callable[[Event], None]
#: The output and input images at one moment (b"" for an image the device does not have).
Snapshot = tuple[bytes, bytes]


class DeviceGuard:
    """The lock, the observers and the event log of one device, around its images and its table."""

    def __init__(self, name: str, assemblies: dict[str, AssemblyInstance], table: ConnectionTable) -> None:
        self.name = name
        self.lock = threading.Lock()
        self.events = EventLog(name)
        self.observers: list[Observer] = []
        self.assemblies = assemblies
        self.table = table
        self.output = assemblies.get("output")
        self.input = assemblies.get("input")
        #: The cyclic I/O thread's (server/implicit.py): called, after the lock, when a connection
        #: opened (a new T->O stream and watchdog), so the table's timer may be earlier than the thread's.
        self.timer_moved: Callable[[], None] | None = None

    def observe(self, observer: Observer) -> Callable[[], None]:
        """Call `observer(event)` for everything that happens to the device, after the device lock
        is released, in the thread that made it happen (keep it short). Returns the unsubscribe."""
        self.observers = [*self.observers, observer]  # copy on write: publishing never locks

        def unsubscribe() -> None:
            self.observers = [o for o in self.observers if o is not observer]
        return unsubscribe

    def record(self, kind: str, detail: object = "", now: int | None = None) -> None:
        """Log an event that happened at `now` (ns, monotonic; None: the clock's now, for the
        server's and the API's events) and tell the observers."""
        event = self.events.record(kind, detail, time.monotonic_ns() if now is None else now)
        for observer in self.observers:
            observer(event)

    def snapshot(self) -> Snapshot:
        """Under the lock: the images as they stand."""
        output, inputs = self.output, self.input
        return (bytes(output.data) if output is not None else b"", bytes(inputs.data) if inputs is not None else b"")

    def image(self, role: str) -> bytes:
        """One image (b"" if the device has none), read under the lock."""
        assembly = self.assemblies.get(role)
        with self.lock:
            return bytes(assembly.data) if assembly is not None else b""

    def publish(self, before: Snapshot, after: Snapshot, now: int, requests: Iterable[Handled] = (),
                connections: Iterable[ConnectionEvent] = ()) -> None:
        """After the lock: log and tell what happened inside it, at `now` (ns); the connection events
        as their classes word them (cip/connection_events.py). A connection opened re-arms the
        cyclic I/O thread's timer (`timer_moved`)."""
        observers = self.observers
        for handled in requests:
            entry = self.events.request(handled, now)
            if observers:
                event = self.events.event(entry)
                for observer in observers:
                    observer(event)
        opened = False
        for change in connections:
            self.record(change.kind, change.text, change.at)
            opened = opened or isinstance(change, ConnectionOpened)
        if opened and self.timer_moved is not None:
            self.timer_moved()
        for role, old, new in (("output", before[0], after[0]), ("input", before[1], after[1])):
            if old != new and self.observers:
                event = self.events.event((now, "image changed", ImageChange(role, old, new)))
                for observer in self.observers:
                    observer(event)

    def write_image(self, role: str, change: Callable[[bytearray], object], now: int | None = None) -> None:
        """Change an image in one locked step: `change` edits a copy, which replaces the image only
        if it returns without an error. No reader sees half of it, no concurrent writer loses a write.
        `now` (ns): when; None: the clock's now (the Python and HTTP APIs' edge)."""
        image = self.assemblies[role].data
        with self.lock:
            before = self.snapshot()
            edited = bytearray(image)
            change(edited)
            if len(edited) != len(image):
                raise ValueError(f"{self.name}: the {role} image is {len(image)} bytes")
            image[:] = edited
            after = self.snapshot()
        self.publish(before, after, time.monotonic_ns() if now is None else now)

    def locked(self, operation: Callable[[], object], now: int) -> None:
        """Run `operation` on the table under the lock at `now` (ns), then publish what it changed."""
        with self.lock:
            before = self.snapshot()
            operation()
            connections = self.table.pop_events()
            after = self.snapshot()
        self.publish(before, after, now, (), connections)


def replace_image(image: bytearray, data: bytes, what: str) -> None:
    """A `write_image` change that replaces the whole image; ValueError (naming `what`) on a size mismatch."""
    if len(data) != len(image):
        raise ValueError(f"{what}: the image is {len(image)} bytes, got {len(data)}")
    image[:] = data
