"""One device's lock discipline and its one observer mechanism: the device transaction.

Every change of the I/O image or of the connection table (explicit requests, O->T consumption,
T->O production, supervision, resets, the Python and HTTP APIs) is one `transaction(now)`: it takes
the device lock, lets the work run, collects what happened as typed events (the requests answered,
the table's connection events, the image changes, the events the work emits) and, once the lock is
released, publishes them once, in order, to the device's observers and its event log
(device/events.py). So no reader sees half a write, no writer loses one, and an observer sees a
transaction's events together, after it; what the work has to send (T->O, replies) its caller
sends after the with statement, never under the lock. Readers take the same lock (`read`, `image`).

An exception in the work: the lock is released and what the transaction collected by then is
published, once (an image or a connection that changed before the error stays changed, and
observers must not miss it); the events are not carried over to another transaction, and the
exception goes on to the caller.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterable
from typing import Protocol, TypeVar

from enip_farm.cip.assembly import AssemblyInstance
from enip_farm.cip.connection_events import ConnectionEvent, ConnectionOpened, describe
from enip_farm.cip.connection_table import ConnectionTable
from enip_farm.cip.message_router import Handled
from enip_farm.device.events import DeviceEvent, EventLog, ImageChanged
from enip_farm.device.observers import Observer, Observers

__all__ = ["BOTH_IMAGES", "INPUT_IMAGE", "NO_IMAGES", "OUTPUT_IMAGE", "Clock", "DeviceGuard", "Observer",
           "Transaction", "describe", "replace_image"]

#: The clock a device is given: monotonic time in integer ns (time.monotonic_ns unless a test drives it).
Clock = Callable[[], int]
#: Which images a transaction compares, before and after (bit flags).
NO_IMAGES, OUTPUT_IMAGE, INPUT_IMAGE, BOTH_IMAGES = 0, 1, 2, 3

T = TypeVar("T")


class NativeHooks(Protocol):
    """The native class-1 path's hold on a device (server/native.py): under the device lock,
    `enter` takes the state back at a transaction's start, `exit` hands it over again at its end,
    `sync` writes it back for a reader."""

    def enter(self) -> None: ...

    def exit(self) -> None: ...

    def sync(self) -> None: ...


class Transaction:
    """One locked step of a device (`DeviceGuard.transaction`). The work sets `requests` (the
    router's answered requests) and `emit`s its own events; what it has to send, it returns, and
    its caller sends after the with statement."""

    __slots__ = ("guard", "now", "images", "before_output", "before_input", "requests", "emitted", "_pending",
                 "_release")

    def __init__(self, guard: DeviceGuard) -> None:
        self.guard = guard
        self.now = 0
        self.images = NO_IMAGES
        self.before_output: bytes = b""
        self.before_input: bytes = b""
        self.requests: list[Handled] | tuple[()] = ()
        self.emitted: list[DeviceEvent] = []
        self._pending = guard.table.pending_events  # the table's events not yet popped (never replaced)
        self._release = guard.lock.release

    def watch(self, images: int) -> None:
        """Compare these images too, from now on (their copies before are taken now). Image changes
        are told, not logged: while nobody observes the device, nothing is compared."""
        guard = self.guard
        if not guard.observers.of_images:
            return
        if images & OUTPUT_IMAGE and not self.images & OUTPUT_IMAGE and guard.output is not None:
            self.before_output = bytes(guard.output.data)
            self.images |= OUTPUT_IMAGE
        if images & INPUT_IMAGE and not self.images & INPUT_IMAGE and guard.input is not None:
            self.before_input = bytes(guard.input.data)
            self.images |= INPUT_IMAGE

    def emit(self, event: DeviceEvent) -> None:
        """Publish `event` with this transaction's, after its image changes (logged, at its `now`)."""
        self.emitted.append(event)

    def __enter__(self) -> Transaction:
        return self

    def __exit__(self, exc_type: object, exc: object, traceback: object) -> None:
        native = self.guard.native
        if native is not None:  # the device to the native path again, if it qualifies, before the lock goes
            native.exit()
        if self._pending or self.images or self.requests or self.emitted:
            self._end()
        else:
            self._release()  # the per-packet path, mostly: nothing to tell

    def _end(self) -> None:
        guard = self.guard
        now, requests, emitted, images = self.now, self.requests, self.emitted, self.images
        try:
            connections = guard.table.pop_events() if self._pending else ()
            changes = []
            if images:  # the watched images (`watch`: they exist) that changed
                output, inputs = guard.output, guard.input
                if output is not None and images & OUTPUT_IMAGE and output.data != self.before_output:
                    changes.append(ImageChanged("output", self.before_output, bytes(output.data)))
                if inputs is not None and images & INPUT_IMAGE and inputs.data != self.before_input:
                    changes.append(ImageChanged("input", self.before_input, bytes(inputs.data)))
                self.images = NO_IMAGES
            if requests:
                self.requests = ()
            if emitted:
                self.emitted = []
        finally:
            self._release()
        if requests or connections or changes or emitted:
            guard.publish(now, requests, connections, changes, emitted)


class DeviceGuard:
    """The lock, the observers, the event log and the clock of one device, around its images and its table."""

    def __init__(self, name: str, assemblies: dict[str, AssemblyInstance], table: ConnectionTable,
                 clock: Clock = time.monotonic_ns) -> None:
        self.name = name
        #: Taken by `transaction` and `read` only: everything else goes through them.
        self.lock = threading.Lock()
        self._acquire = self.lock.acquire
        self.clock = clock
        self.events = EventLog(name)
        self.observers = Observers()
        self.assemblies = assemblies
        self.table = table
        self.output = assemblies.get("output")
        self.input = assemblies.get("input")
        #: The cyclic I/O thread's (server/implicit.py): called, after the lock, when a connection
        #: opened (a new T->O stream and watchdog), so the table's timer may be earlier than the thread's.
        self.timer_moved: Callable[[], None] | None = None
        #: The native class-1 path's hooks while it may run the device (server/native.py), else None.
        self.native: NativeHooks | None = None
        self._transaction = Transaction(self)

    def observe(self, observer: Observer, *classes: type) -> Callable[[], None]:
        """Call `observer(event)` for every event of `classes` (their subclasses too; none given:
        every event) that happens to the device, after the device lock is released, in the thread
        that made it happen (keep it short). Returns the unsubscribe."""
        return self.observers.add(observer, classes)

    # -- the transaction ----------------------------------------------------------------------------

    def transaction(self, now: int | None = None, images: int = BOTH_IMAGES) -> Transaction:
        """One locked step at `now` (ns; None: the device's clock), comparing `images` (bit flags;
        OUTPUT_IMAGE where only the outputs can change, NO_IMAGES and `Transaction.watch` where the
        work decides). Use it only as `with guard.transaction(now) as tx:`: it takes the lock at
        once (the one Transaction of the device is then this caller's; no allocation per packet),
        and the with statement's end releases it and publishes."""
        if now is None:
            now = self.clock()
        self._acquire()
        native = self.native
        if native is not None:  # the state the native path held, back in the objects the work reads
            native.enter()
        transaction = self._transaction
        transaction.now = now
        if images and self.observers.of_images:
            transaction.watch(images)
        return transaction

    def read(self, reading: Callable[[], T]) -> T:
        """`reading()` under the lock: a whole view of the images and the table (the native path
        lets the device go for it, as for a transaction: nothing changes under a reader)."""
        with self.lock:
            native = self.native
            if native is None:
                return reading()
            native.enter()
            try:
                return reading()
            finally:
                native.exit()

    def image(self, role: str) -> bytes:
        """One image (b"" if the device has none), read under the lock."""
        assembly = self.assemblies.get(role)
        with self.lock:
            return bytes(assembly.data) if assembly is not None else b""

    def write_image(self, role: str, change: Callable[[bytearray], object], now: int | None = None) -> None:
        """Change an image in one transaction: `change` edits a copy, which replaces the image only
        if it returns without an error. No reader sees half of it, no concurrent writer loses a write.
        `now` (ns): when; None: the device's clock (the Python and HTTP APIs' edge)."""
        image = self.assemblies[role].data
        with self.transaction(now, OUTPUT_IMAGE if role == "output" else INPUT_IMAGE if role == "input" else 0):
            edited = bytearray(image)
            change(edited)
            if len(edited) != len(image):
                raise ValueError(f"{self.name}: the {role} image is {len(image)} bytes")
            image[:] = edited

    # -- publishing ---------------------------------------------------------------------------------

    def record(self, event: DeviceEvent, now: int | None = None) -> None:
        """Log an event that happened outside a transaction (a TCP connection, a session, a fault,
        a wire) at `now` (ns; None: the device's clock) and tell its observers."""
        logged = self.events.record(event, self.clock() if now is None else now)
        for observer in self.observers.of(type(event)):
            observer(logged)

    def publish(self, now: int, requests: Iterable[Handled], connections: Iterable[ConnectionEvent],
                changes: Iterable[ImageChanged], emitted: Iterable[DeviceEvent]) -> None:
        """After a transaction's lock: log and tell what happened inside it, in this order: the
        requests, the connection events (at their own time), the image changes (told, not logged),
        the events the work emitted. A connection opened re-arms the cyclic I/O thread's timer."""
        log, observers = self.events, self.observers
        if requests:
            of_requests = observers.of_requests
            for handled in requests:
                entry = log.request(handled, now)
                if of_requests:
                    event = log.event(entry)
                    for observer in of_requests:
                        observer(event)
        opened = False
        for change in connections:
            event = log.record(change, change.at)
            for observer in observers.of(type(change)):
                observer(event)
            opened = opened or isinstance(change, ConnectionOpened)
        if opened and self.timer_moved is not None:
            self.timer_moved()
        for image_change in changes:  # (compared only while someone observes them)
            event = log.event((now, image_change))
            for observer in observers.of_images:
                observer(event)
        for happened in emitted:
            event = log.record(happened, now)
            for observer in observers.of(type(happened)):
                observer(event)


def replace_image(image: bytearray, data: bytes, what: str) -> None:
    """A `write_image` change that replaces the whole image; ValueError (naming `what`) on a size mismatch."""
    if len(data) != len(image):
        raise ValueError(f"{what}: the image is {len(image)} bytes, got {len(data)}")
    image[:] = data
