"""One virtual device: the parts that do its jobs, put together, and the one face the servers, the
APIs and the farm see (the encapsulation `Target` of protocol/session.py among them).

- device/objects.py builds its CIP objects, I/O image and connection table from the profile;
- device/guard.py holds its lock and publishes what happened to its observers and event log;
- device/sessions.py hands out its session handles;
- device/target.py answers the encapsulation layer (ListIdentity, explicit requests);
- device/cyclic.py moves its class-1 datagrams (the cyclic I/O thread);
- device/reset.py runs its resets (Identity Reset's `ResetRequested`, the API's reset button).
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable

from enip_farm.cip.budget import CyclicBudget
from enip_farm.cip.connection import Connection
from enip_farm.cip.connection_table import TABLE_COUNTERS
from enip_farm.cip.ethernet_link import InterfaceCounters
from enip_farm.cip.identity import STATE_OPERATIONAL, STATE_SELF_TESTING
from enip_farm.cip.object import ReplyItems
from enip_farm.device.cyclic import CyclicIo, SendDatagram
from enip_farm.device.events import DeviceEvent, Event, FaultCleared, ResetDone
from enip_farm.device.faults import DeviceFaults
from enip_farm.device.guard import NO_IMAGES, Clock, DeviceGuard, Observer, describe, replace_image
from enip_farm.device.hardware import ModuleHardware
from enip_farm.device.latency import LatencyHistogram
from enip_farm.device.objects import build_objects
from enip_farm.device.profile import DeviceProfile
from enip_farm.device.reset import Resets
from enip_farm.device.sessions import SessionHandles
from enip_farm.device.tap import TrafficTap
from enip_farm.device.target import EncapsulationTarget
from enip_farm.protocol.commands import IdentityItem
from enip_farm.protocol.connection import ConnectionTriad
from enip_farm.protocol.session import MessageContext, ReplyWithItems

__all__ = ["COUNTERS", "Clock", "Device", "Observer", "SendDatagram", "describe", "replace_image"]

#: Every counter of a device, present (at 0) from the start: TCP, sessions, replies, class 1 (the table's).
COUNTERS = ("tcp_connections", "tcp_refused", "tcp_write_paused", "tcp_inactivity_closed", "sessions",
            "sessions_refused", "replies_dropped", "t_o_send_errors", "tcp_refused_resetting", "o_t_dropped_resetting",
            "io_errors", *TABLE_COUNTERS)


class Device:
    """One configured device; implements the encapsulation `Target` protocol."""

    def __init__(self, profile: DeviceProfile, budget: CyclicBudget | None = None,
                 clock: Clock = time.monotonic_ns) -> None:
        """`budget`: the cyclic I/O budget this device's connections share with the other devices of
        its I/O thread (None: no limit but each device's connection counts); `clock`: the monotonic
        time (int ns) its API's edge takes when not given a `now` (the farm's; a test's to drive it)."""
        self.profile = profile
        self.faults = DeviceFaults()
        self.recorder: TrafficTap | None = None  # serve --record
        self._counters: Counter[str] = Counter(dict.fromkeys(COUNTERS, 0))
        self.tcp_open = 0  # TCP connections open now (server/tcp.py counts them in and out; counters: since start)
        self.latency = LatencyHistogram()
        objects = build_objects(profile, self._counters, budget, product_code=lambda: self.product_code,
                                revision=lambda: self.revision,
                                identity_state=lambda: self.identity_state, resetting=lambda: self.resetting,
                                forced_status=self.faults.forced_status, assembly_size=self.faults.assembly_size)
        self.assemblies, self.table, self.router, self.link = (objects.assemblies, objects.table, objects.router,
                                                               objects.link)
        self._tcpip = objects.tcpip
        self.guard = guard = DeviceGuard(profile.name, objects.assemblies, objects.table, clock)
        self.clock, self.events = clock, guard.events
        self.session_handles = SessionHandles(profile.limits.max_sessions, self._counters, guard.record)
        self.resets = Resets(objects, guard, self.session_handles, profile.reset_time_s)
        self.reset_window = self.resets.window
        self.target = EncapsulationTarget(profile, guard, objects.router, self.resets,
                                          lambda: self.product_code, lambda: self.identity_state,
                                          lambda: self.revision)
        self.cyclic = CyclicIo(guard, self.faults, self.reset_window, self._counters)
        #: What faults do to the module itself: its power, its address (device/hardware.py).
        self.hardware = ModuleHardware(objects, guard, self.session_handles, self.reset_window, profile.address,
                                       profile.mac)
        #: Interface counters (Ethernet Link attribute 4): the event loop's sockets (TCP and UDP
        #: 44818) count into `traffic`, the cyclic I/O thread's (UDP 2222) into `io_traffic`.
        self.traffic: InterfaceCounters = self.link.new_counters()
        self.io_traffic: InterfaceCounters = self.link.new_counters()
        guard.observe(self._came_back, FaultCleared, ResetDone)

    def _came_back(self, event: Event) -> None:
        """A fault cleared or a reset done: the table expects its originators back (the report's
        reconnections, which name what the device came back after by the event's kind)."""
        with self.guard.transaction(event.monotonic_ns, NO_IMAGES):
            self.table.device_back(event.detail.kind, event.monotonic_ns)

    @property
    def name(self) -> str:
        return self.profile.name

    # -- observers (device/guard.py) ------------------------------------------------------------

    def observe(self, observer: Observer, *classes: type) -> Callable[[], None]:
        """Call `observer(event)` for every event of `classes` (device/events.py,
        cip/connection_events.py; their subclasses too; none given: every event) that happens to
        the device, after the device lock is released, in the thread that made it happen (keep it
        short). Returns the unsubscribe."""
        return self.guard.observe(observer, *classes)

    def record(self, event: DeviceEvent, now: int | None = None) -> None:
        """Log an event (device/events.py) that happened at `now` (ns, monotonic; None: the device's
        clock) and tell the observers."""
        self.guard.record(event, now)

    @property
    def counters(self) -> Counter[str]:
        """The device's counters; those the native class-1 path keeps written in first (server/native.py)."""
        native = self.guard.native
        if native is not None:
            native.sync()
        return self._counters

    @property
    def timer_moved(self) -> Callable[[], None] | None:
        """The cyclic I/O thread's: called when a connection opened (its timer may be earlier)."""
        return self.guard.timer_moved

    @timer_moved.setter
    def timer_moved(self, callback: Callable[[], None] | None) -> None:
        self.guard.timer_moved = callback

    # -- the I/O image and the connections --------------------------------------------------------

    @property
    def outputs(self) -> bytes:
        return self.guard.image("output")

    @property
    def inputs(self) -> bytes:
        return self.guard.image("input")

    def set_inputs(self, data: bytes, now: int | None = None) -> None:
        """Set the input image as a sensor would (not subject to `writable_inputs`)."""
        self.write_image("input", lambda image: replace_image(image, data, self.name), now)

    def write_image(self, role: str, change: Callable[[bytearray], object], now: int | None = None) -> None:
        """Change an image in one device transaction: `change` edits a copy, which replaces the image only
        if it returns without an error. No reader sees half of it, no concurrent writer loses a write.
        `now` (ns): when; None: the device's clock (the Python and HTTP APIs' edge)."""
        self.guard.write_image(role, change, now)

    @property
    def encapsulation_inactivity_timeout_s(self) -> int:
        """TCP/IP Interface attribute 13 as it stands (clients may set it): 0 = never."""
        return self._tcpip.inactivity_timeout_s

    @property
    def identity_state(self) -> int:
        """Identity attribute 8 and ListIdentity's state: 1 (self testing) while resetting and in the self
        test after a power loss's boot (device/hardware.py), else 3."""
        return STATE_SELF_TESTING if self.reset_window.active or self.hardware.self_testing else STATE_OPERATIONAL

    @property
    def product_code(self) -> int:
        """The product code the device shows; an `identity` fault changes it so keys stop matching."""
        return self.faults.product_code(self.profile.product_code)

    @property
    def revision(self) -> tuple[int, int]:
        """The revision the device shows; a `wrong-module` fault changes it."""
        return self.faults.revision(self.profile.revision)

    @property
    def status(self) -> int:
        """Identity attribute 5, from the device's I/O connections."""
        return self.guard.read(lambda: self.table.status)

    @property
    def connections(self) -> dict[int, Connection]:
        """The open connections by O->T connection id (a copy)."""
        return self.guard.read(lambda: dict(self.table.connections))

    def find_connection(self, triad: ConnectionTriad) -> Connection | None:
        return self.guard.read(lambda: self.table.find(triad))

    # -- encapsulation Target (device/target.py, device/sessions.py) ------------------------------

    @property
    def sessions(self) -> set[int]:
        """The session handles registered now."""
        return self.session_handles.open

    def identity_item(self) -> IdentityItem:
        return self.target.identity_item()

    def list_identity_data(self) -> bytes:
        return self.target.list_identity_data()

    def list_services_data(self) -> bytes:
        return self.target.list_services_data()

    def list_interfaces_data(self) -> bytes:
        return self.target.list_interfaces_data()

    def register_session(self, peer_host: str = "") -> int | None:
        """A new session handle, or None when the device holds `limits.max_sessions` already."""
        return self.session_handles.register(peer_host)

    def unregister_session(self, session_handle: int) -> None:
        self.session_handles.unregister(session_handle)

    def handle_unconnected(self, message: bytes, context: MessageContext) -> ReplyWithItems:
        return self.target.handle_unconnected(message, context)

    def handle_connected(self, connection_id: int, sequence_count: int, message: bytes,
                         context: MessageContext) -> tuple[int, bytes, ReplyItems] | None:
        return self.target.handle_connected(connection_id, sequence_count, message, context)

    def session_closed(self, session: object, now: int) -> None:
        with self.guard.transaction(now):
            self.table.session_closed(session, now)

    # -- resets (device/reset.py) -----------------------------------------------------------------

    @property
    def restarts(self) -> int:
        """How many resets the device has begun: a session of an earlier count has ended."""
        return self.reset_window.resets

    @property
    def resetting(self) -> bool:
        """The device is in its reset window: it does not answer."""
        return self.reset_window.active

    def reset(self, kind: int, now: int | None = None) -> bool:
        """A reset from outside CIP (the API, the CLI, the dashboard) at `now` (ns; None: the
        device's clock): as an Identity Reset of type `kind` (0 power cycle, 1 out-of-box, 2
        out-of-box but the communication parameters). False if the device is in its reset window
        already; ValueError for an unknown type."""
        return self.resets.reset(kind, now)

    def end_reset(self, now: int | None = None) -> bool:
        """End the reset window if its deadline has come (never before): True if the device
        answers again from now, with a `ResetDone` event."""
        return self.resets.end(now)

    # -- class-1 I/O (device/cyclic.py, the cyclic I/O thread) -------------------------------------

    def receive_io(self, data: bytes, source: tuple[str, int], now: int, send: SendDatagram,
                   received_at: int | None = None) -> bool:
        """An O->T datagram from `source` (host, port), taken at `now` (`received_at`: the kernel's
        receive time, which the report measures by): True if a connection took it."""
        return self.cyclic.receive_io(data, source, now, send, received_at)

    def service_io(self, now: int, send: SendDatagram, horizon: int | None = None) -> int | None:
        """Supervise the connections at `now` and send the T->O packets due by `now` (or `horizon`);
        the next time something is due."""
        return self.cyclic.service_io(now, send, horizon)

    def get_timer(self) -> int | None:
        return self.cyclic.get_timer()
