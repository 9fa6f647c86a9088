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
from enip_farm.cip.connection import Connection
from enip_farm.cip.connection_table import ConnectionEvent, ConnectionTable
from enip_farm.cip.message_router import Handled
from enip_farm.device.events import Event, EventLog, ImageChange

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

    def observe(self, observer: Observer) -> Callable[[], None]:
        """Call `observer(event)` for everything that happens to the device, after the device lock
        is released, in the thread that made it happen (keep it short). Returns the unsubscribe."""
        self.observers = [*self.observers, observer]  # copy on write: publishing never locks

        def unsubscribe() -> None:
            self.observers = [o for o in self.observers if o is not observer]
        return unsubscribe

    def record(self, kind: str, detail: object = "", at: float | None = None) -> None:
        """Log an event and tell the observers."""
        event = self.events.record(kind, detail, at)
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

    def publish(self, before: Snapshot, after: Snapshot, requests: Iterable[Handled] = (),
                connections: Iterable[ConnectionEvent] = ()) -> None:
        """After the lock: log and tell what happened inside it."""
        observers = self.observers
        for handled in requests:
            entry = self.events.request(handled)
            if observers:
                event = self.events.event(entry)
                for observer in observers:
                    observer(event)
        for change in connections:
            if change.connection is None:  # a refusal: the reason says it all
                self.record(change.kind, change.reason, change.at / 1e9)
            else:
                self.record(change.kind, describe(change.connection) + (f": {change.reason}" if change.reason else ""),
                            change.at / 1e9)
        for role, old, new in (("output", before[0], after[0]), ("input", before[1], after[1])):
            if old != new and self.observers:
                event = Event(time.monotonic(), time.time(), self.name, "image changed", ImageChange(role, old, new))
                for observer in self.observers:
                    observer(event)

    def write_image(self, role: str, change: Callable[[bytearray], object]) -> None:
        """Change an image in one locked step: `change` edits a copy, which replaces the image only
        if it returns without an error. No reader sees half of it, no concurrent writer loses a write."""
        image = self.assemblies[role].data
        with self.lock:
            before = self.snapshot()
            edited = bytearray(image)
            change(edited)
            if len(edited) != len(image):
                raise ValueError(f"{self.name}: the {role} image is {len(image)} bytes")
            image[:] = edited
            after = self.snapshot()
        self.publish(before, after)

    def locked(self, operation: Callable[[], object]) -> None:
        """Run `operation` on the table under the lock, then publish what it changed."""
        with self.lock:
            before = self.snapshot()
            operation()
            connections = self.table.pop_events()
            after = self.snapshot()
        self.publish(before, after, (), connections)


def describe(connection: Connection) -> str:
    """A connection in one line: kind, originator, each direction's id, RPI and size, where T->O goes."""
    c = connection
    text = (f"{c.kind.value} from {c.originator_host}: O->T 0x{c.o_t_id:08X} RPI {c.o_t_rpi} us {c.o_t_size} bytes, "
            f"T->O 0x{c.t_o_id:08X} RPI {c.t_o_rpi} us {c.t_o_size} bytes")
    if c.t_o_address is not None:
        text += f" {'multicast ' if c.multicast else ''}to {c.t_o_address[0]}:{c.t_o_address[1]}"
    return text


def replace_image(image: bytearray, data: bytes, what: str) -> None:
    """A `write_image` change that replaces the whole image; ValueError (naming `what`) on a size mismatch."""
    if len(data) != len(image):
        raise ValueError(f"{what}: the image is {len(image)} bytes, got {len(data)}")
    image[:] = data
