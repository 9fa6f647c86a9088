"""One virtual device: its CIP objects, its I/O image, its connection table and its
encapsulation-level identity (the `Target` of protocol/session.py).

Identity Reset (cip/identity.py) is performed here, right after the request that asked for it has
been answered (its reply is built; the server sends it before anything else of the device's):
every class-1 and class-3 connection closes, the output and configuration images go to their
power-up state (all zero), the input image keeps what the field (the API, wires, rules) holds, the
link counters clear, a type-1 reset also restores the configured TCP/IP and Ethernet Link
settings, and a "reset" event is recorded. The sessions of the device end with that reply
(`restarts` moves on) and the device does not answer until its reset window ends
(device/reset.py; the farm closes its TCP connections and listener meanwhile).

One lock discipline: the device lock is held around every read and every write of the images and
of the connection table (explicit requests, O->T consumption, T->O production, supervision, the
Python and HTTP APIs), so no reader sees half a write and no writer loses one. What happened
inside the lock (requests, connection events, image changes) is published to the device's
observers after the lock is released, in the thread that made it happen: one observer mechanism.
"""

from __future__ import annotations

import threading
import time
from collections import Counter
from collections.abc import Callable, Iterable, Mapping
from types import MappingProxyType

from enip_farm.cip.admission import ConnectionPolicy, DeclaredConnection, KeyIdentity
from enip_farm.cip.assembly import AssemblyInstance, AssemblyObject
from enip_farm.cip.budget import CyclicBudget
from enip_farm.cip.connection import Connection, ConnectionKind
from enip_farm.cip.connection_manager import ConnectionManager
from enip_farm.cip.connection_table import TABLE_COUNTERS, ConnectionEvent, ConnectionTable
from enip_farm.cip.ethernet_link import EthernetLinkObject, InterfaceCounters
from enip_farm.cip.identity import RESET_OUT_OF_BOX, STATE_OPERATIONAL, STATE_SELF_TESTING, IdentityObject
from enip_farm.cip.message_router import Handled, MessageRouter
from enip_farm.cip.object import Attribute, ReplyItems
from enip_farm.cip.parameter import ParameterObject, ParameterSpec
from enip_farm.cip.safety.admission import SafetyPolicy
from enip_farm.cip.safety.objects import SafetyValidatorObject
from enip_farm.cip.safety.segment import Unid
from enip_farm.cip.safety.supervisor import SafetySupervisor
from enip_farm.cip.tcpip_interface import TcpIpInterfaceObject
from enip_farm.device.catalogue import ConnectionEntry
from enip_farm.device.events import Event, EventLog, ImageChange
from enip_farm.device.faults import DeviceFaults
from enip_farm.device.latency import LatencyHistogram
from enip_farm.device.profile import DeviceProfile
from enip_farm.device.reset import ResetWindow
from enip_farm.device.tap import TrafficTap
from enip_farm.protocol.commands import (
    CAPABILITY_TCP,
    CAPABILITY_UDP_CLASS_0_1,
    PROTOCOL_VERSION,
    IdentityItem,
    ServiceItem,
    SocketAddress,
    encode_identity_item,
    encode_service_item,
)
from enip_farm.protocol.connection import ConnectionTriad
from enip_farm.protocol.cpf import ItemType, encode_items
from enip_farm.protocol.encapsulation import ENIP_PORT
from enip_farm.protocol.session import MessageContext, ReplyWithItems

_RESET_KINDS: Mapping[int, str] = MappingProxyType({0: "power cycle", 1: "out-of-box configuration",
                                                    2: "out-of-box configuration but the communication parameters"})

#: Every counter of a device, present (at 0) from the start: TCP, sessions, replies, class 1 (the table's).
COUNTERS = ("tcp_connections", "tcp_refused", "tcp_write_paused", "tcp_inactivity_closed", "sessions",
            "sessions_refused", "replies_dropped", "t_o_send_errors", "tcp_refused_resetting", "o_t_dropped_resetting",
            "io_errors", *TABLE_COUNTERS)

#: An observer of a device: called with every event (log entries, connection events, image changes).
Observer = Callable[[Event], None]
#: Sends one datagram (the server's socket): data, destination.
SendDatagram = Callable[[bytes, tuple[str, int]], None]


def _safety_policy(profile: DeviceProfile) -> SafetyPolicy | None:
    safety, output, inputs = profile.safety, profile.assembly("output"), profile.assembly("input")
    if safety is None or output is None or inputs is None:
        return None
    configuration = profile.assembly("configuration")
    return SafetyPolicy(
        vendor_id=profile.vendor_id, serial_number=profile.serial_number, tunid=Unid(safety.snn, safety.node_address),
        scid=safety.scid, output_point=output.instance_id, input_point=inputs.instance_id,
        configuration_point=configuration.instance_id if configuration else safety.null_point,
        null_point=safety.null_point, max_connections=safety.max_connections)


def _policy(profile: DeviceProfile) -> ConnectionPolicy:
    implicit = profile.implicit
    return ConnectionPolicy(
        rpi_min_us=implicit.rpi_min_us, rpi_max_us=implicit.rpi_max_us,
        max_class1_connections=implicit.max_class1_connections,
        max_class3_connections=implicit.max_class3_connections,
        outputs_off_on_idle=implicit.idle_state == "off", outputs_off_on_fault=implicit.fault_state == "off",
        first_watchdog_ns=round(implicit.first_watchdog_s * 1e9),
        input_only_point=profile.input_only_point, listen_only_point=profile.listen_only_point,
        multicast_group=profile.multicast_group, safety=_safety_policy(profile),
        class3_rpi_min_us=implicit.class3_rpi_min_us, class3_rpi_max_us=implicit.class3_rpi_max_us,
        declared=tuple(_declared(entry) for entry in profile.connections),
    )


_DECLARED_KINDS: Mapping[str, ConnectionKind] = MappingProxyType({
    "exclusive owner": ConnectionKind.EXCLUSIVE_OWNER, "redundant owner": ConnectionKind.EXCLUSIVE_OWNER,
    "input only": ConnectionKind.INPUT_ONLY, "listen only": ConnectionKind.LISTEN_ONLY})


def _declared(entry: ConnectionEntry) -> DeclaredConnection:
    """An EDS's connection entry as admission holds Forward Opens against it."""
    return DeclaredConnection(
        kind=_DECLARED_KINDS[entry.kind], configuration=entry.configuration, o_t=entry.o_t, t_o=entry.t_o,
        o_t_size=entry.o_t_size, t_o_size=entry.t_o_size, o_t_format=entry.o_t_format, t_o_format=entry.t_o_format,
        o_t_variable=entry.o_t_variable, t_o_variable=entry.t_o_variable, t_o_multicast=entry.t_o_multicast,
        t_o_point_to_point=entry.t_o_point_to_point, configuration_size=entry.configuration_size,
        rpi_us=entry.rpi_us, shared_owner=entry.kind == "redundant owner", name=entry.name)


class Device:
    """Implements the encapsulation `Target` protocol for one configured device."""

    def __init__(self, profile: DeviceProfile, budget: CyclicBudget | None = None) -> None:
        """`budget`: the cyclic I/O budget this device's connections share with the other devices of
        its I/O thread (None: no limit but each device's connection counts)."""
        self.profile = profile
        writable = profile.implicit.explicit_output_writes_while_owned
        self.assemblies: dict[str, AssemblyInstance] = {
            spec.role: AssemblyInstance(spec.instance_id, spec.size, spec.settable, writable)
            for spec in profile.assemblies
        }
        configuration = self.assemblies.get("configuration")
        if configuration is not None and len(profile.configuration_data) == len(configuration.data):
            configuration.data[:] = profile.configuration_data
        self.faults = DeviceFaults()
        self.recorder: TrafficTap | None = None  # serve --record
        self.counters: Counter[str] = Counter(dict.fromkeys(COUNTERS, 0))
        self.latency = LatencyHistogram()
        self._next_session_handle = 1
        self.sessions: set[int] = set()
        self.events = EventLog(profile.name)
        self._observers: list[Observer] = []
        self.lock = threading.Lock()
        self.table = ConnectionTable(self.assemblies, _policy(profile), self._key_identity, self.counters,
                                     budget=budget)
        self.reset_window = ResetWindow(round(profile.reset_time_s * 1e9))
        self._reset_requested: int | None = None  # the type of an Identity Reset being answered
        self._tcpip = TcpIpInterfaceObject(address=profile.address, netmask=profile.netmask, gateway=profile.gateway,
                                           host_name=profile.host_name,
                                           inactivity_timeout_s=profile.encapsulation_inactivity_timeout_s,
                                           multicast_group=profile.multicast_group,
                                           multicast_configured=profile.multicast_configured,
                                           safety_network_number=profile.safety.snn if profile.safety else None)
        self.link = EthernetLinkObject(mac=profile.mac)
        #: Interface counters (Ethernet Link attribute 4): the event loop's sockets (TCP and UDP
        #: 44818) count into `traffic`, the cyclic I/O thread's (UDP 2222) into `io_traffic`.
        self.traffic: InterfaceCounters = self.link.new_counters()
        self.io_traffic: InterfaceCounters = self.link.new_counters()
        implicit, safety_profile = profile.implicit, profile.safety
        self.router = MessageRouter(
            multiple_service_packet=profile.routing.multiple_service_packet,
            max_connections=implicit.max_class1_connections + implicit.max_class3_connections + (
                safety_profile.max_connections if safety_profile else 0),
            active_connections=lambda: len(self.table.connections))
        self.router.forced_status = self.faults.forced_status
        self.router.replay = {(service, path, data): reply for service, path, data, reply in profile.replay}
        for obj in (
            IdentityObject(
                vendor_id=profile.vendor_id,
                device_type=profile.device_type,
                product_code=lambda: self.product_code,
                revision=profile.revision,
                serial_number=profile.serial_number,
                product_name=profile.product_name,
                status=lambda: self.table.status,
                state=lambda: self.identity_state,
                reset=self._request_reset,
            ),
            AssemblyObject(list(self.assemblies.values())),
            *([ParameterObject([ParameterSpec(p.instance, p.name, p.descriptor, p.data_type, p.size, p.minimum,
                                              p.maximum, p.default, bytes.fromhex(p.link_path))
                                for p in profile.parameters])] if profile.parameters else []),
            ConnectionManager(self.router, self.table, unconnected_send=profile.routing.unconnected_send),
            self._tcpip,
            self.link,
        ):
            self.router.register(obj)
        safety = self.table.policy.safety
        if safety is not None:
            def open_connections() -> list[Connection]:
                return list(self.table.connections.values())
            def close_safety_connections(reason: str, now: int) -> None:
                for connection in [c for c in self.table.connections.values() if c.safety is not None]:
                    self.table.close(connection, reason, now)

            self.router.register(SafetySupervisor(safety, open_connections, close_safety_connections,
                                                  lambda: self.reset_window.active))
            state = safety.state
            self._tcpip.instances[1].attributes[7] = Attribute(lambda: state.tunid.snn)  # follows Apply_TUNID
            self.router.register(SafetyValidatorObject(open_connections, lambda: self.counters["safety_faulted"]))
        service = ServiceItem(PROTOCOL_VERSION, CAPABILITY_TCP | CAPABILITY_UDP_CLASS_0_1, "Communications")
        self._list_services = encode_items([(ItemType.LIST_SERVICES, encode_service_item(service))])
        self._output = self.assemblies.get("output")
        self._input = self.assemblies.get("input")

    @property
    def name(self) -> str:
        return self.profile.name

    def _key_identity(self) -> KeyIdentity:
        p = self.profile
        return KeyIdentity(p.vendor_id, p.device_type, self.product_code, p.revision)

    # -- observers ------------------------------------------------------------------------------

    def observe(self, observer: Observer) -> Callable[[], None]:
        """Call `observer(event)` for everything that happens to the device, after the device lock
        is released, in the thread that made it happen (keep it short). Returns the unsubscribe."""
        self._observers = [*self._observers, observer]  # copy on write: publishing never locks

        def unsubscribe() -> None:
            self._observers = [o for o in self._observers if o is not observer]
        return unsubscribe

    def record(self, kind: str, detail: object = "", at: float | None = None) -> None:
        """Log an event and tell the observers."""
        event = self.events.record(kind, detail, at)
        for observer in self._observers:
            observer(event)

    def _snapshot(self) -> tuple[bytes, bytes]:
        output, inputs = self._output, self._input
        return (bytes(output.data) if output is not None else b"", bytes(inputs.data) if inputs is not None else b"")

    def _publish(self, before: tuple[bytes, bytes], after: tuple[bytes, bytes],
                 requests: Iterable[Handled] = (), connections: Iterable[ConnectionEvent] = ()) -> None:
        observers = self._observers
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
            if old != new and self._observers:
                event = Event(time.monotonic(), time.time(), self.name, "image changed", ImageChange(role, old, new))
                for observer in self._observers:
                    observer(event)

    # -- the I/O image --------------------------------------------------------------------------

    @property
    def outputs(self) -> bytes:
        with self.lock:
            return bytes(self._output.data) if self._output is not None else b""

    @property
    def inputs(self) -> bytes:
        with self.lock:
            return bytes(self._input.data) if self._input is not None else b""

    @property
    def encapsulation_inactivity_timeout_s(self) -> int:
        """TCP/IP Interface attribute 13 as it stands (clients may set it): 0 = never."""
        return self._tcpip.inactivity_timeout_s

    @property
    def identity_state(self) -> int:
        """Identity attribute 8 and ListIdentity's state: 1 (self testing) while resetting, else 3."""
        return STATE_SELF_TESTING if self.reset_window.active else STATE_OPERATIONAL

    @property
    def product_code(self) -> int:
        """The product code the device shows; an `identity` fault changes it so keys stop matching."""
        code = self.profile.product_code
        return self.faults.product_code(code)

    @property
    def status(self) -> int:
        """Identity attribute 5, from the device's I/O connections."""
        with self.lock:
            return self.table.status

    @property
    def connections(self) -> dict[int, Connection]:
        """The open connections by O->T connection id (a copy)."""
        with self.lock:
            return dict(self.table.connections)

    def find_connection(self, triad: ConnectionTriad) -> Connection | None:
        with self.lock:
            return self.table.find(triad)

    def set_inputs(self, data: bytes) -> None:
        """Set the input image as a sensor would (not subject to `writable_inputs`)."""
        self.write_image("input", lambda image: replace_image(image, data, self.name))

    def write_image(self, role: str, change: Callable[[bytearray], object]) -> None:
        """Change an image in one locked step: `change` edits a copy, which replaces the image only
        if it returns without an error. No reader sees half of it, no concurrent writer loses a write."""
        image = self.assemblies[role].data
        with self.lock:
            before = self._snapshot()
            edited = bytearray(image)
            change(edited)
            if len(edited) != len(image):
                raise ValueError(f"{self.name}: the {role} image is {len(image)} bytes")
            image[:] = edited
            after = self._snapshot()
        self._publish(before, after)

    # -- encapsulation Target -------------------------------------------------------------------

    def identity_item(self) -> IdentityItem:
        p = self.profile
        with self.lock:
            status = self.table.status
        return IdentityItem(PROTOCOL_VERSION, SocketAddress(p.address, ENIP_PORT), p.vendor_id, p.device_type,
                            self.product_code, p.revision[0], p.revision[1], status, p.serial_number,
                            p.product_name, self.identity_state)

    def list_identity_data(self) -> bytes:
        return encode_items([(ItemType.LIST_IDENTITY, encode_identity_item(self.identity_item()))])

    def list_services_data(self) -> bytes:
        return self._list_services

    def list_interfaces_data(self) -> bytes:
        return encode_items([])

    def register_session(self, peer_host: str = "") -> int | None:
        """A new session handle, or None when the device holds `limits.max_sessions` already."""
        if len(self.sessions) >= self.profile.limits.max_sessions:
            self.counters["sessions_refused"] += 1
            return None  # the session layer answers 0x0002, which the server reports
        self.counters["sessions"] += 1
        handle = self._next_session_handle
        while handle in self.sessions:
            handle = handle + 1 if handle < 0xFFFFFFFF else 1
        self._next_session_handle = handle + 1 if handle < 0xFFFFFFFF else 1
        self.sessions.add(handle)
        self.record("session registered", f"handle {handle}" + (f" from {peer_host}" if peer_host else ""))
        return handle

    def unregister_session(self, session_handle: int) -> None:
        self.sessions.discard(session_handle)
        self.record("session ended", f"handle {session_handle}")

    def handle_unconnected(self, message: bytes, context: MessageContext) -> ReplyWithItems:
        router = self.router
        with self.lock:
            before = self._snapshot()
            reply = router.dispatch(message, context)
            reset = self._reset_requested
            if reset is not None:
                self._reset(reset, context.now)
            requests = router.pop_handled()
            connections = self.table.pop_events() if self.table.has_events else ()
            after = self._snapshot()
        if connections or before != after or self._observers or reset is not None:
            self._publish(before, after, requests, connections)
            if reset is not None:
                self._record_reset(reset)
        else:  # the hot path: a request that changed nothing, nobody listening
            for handled in requests:
                self.events.request(handled)
        return reply

    def handle_connected(self, connection_id: int, sequence_count: int, message: bytes,
                         context: MessageContext) -> tuple[int, bytes, ReplyItems] | None:
        with self.lock:
            connection = self.table.receive_connected(connection_id, context.session, context.now)
            if connection is None:
                return None
            if connection.last_reply is not None and connection.last_reply[0] == sequence_count:
                return connection.t_o_id, connection.last_reply[1], connection.last_reply[2]  # a duplicate
            before = self._snapshot()
            reply, items = self.router.dispatch(message, context)
            connection.last_reply = (sequence_count, reply, items)
            reset = self._reset_requested
            if reset is not None:
                self._reset(reset, context.now)
            requests = self.router.pop_handled()
            connections = self.table.pop_events()
            after = self._snapshot()
        self._publish(before, after, requests, connections)
        if reset is not None:
            self._record_reset(reset)
        return connection.t_o_id, reply, items

    # -- Identity Reset ---------------------------------------------------------------------------

    @property
    def restarts(self) -> int:
        """How many resets the device has begun: a session of an earlier count has ended."""
        return self.reset_window.resets

    @property
    def resetting(self) -> bool:
        """The device is in its reset window: it does not answer."""
        return self.reset_window.active

    def _request_reset(self, kind: int) -> None:
        """Identity Reset was accepted (the Identity object calls this while building its reply)."""
        self._reset_requested = kind

    def _reset(self, kind: int, now: int) -> None:
        """Under the lock: what a restart does to the device's state."""
        self._reset_requested = None
        table = self.table
        for connection in list(table.connections.values()):
            table.close(connection, f"identity reset (type {kind})", now)
        for role in ("output", "configuration"):  # power-up state; the inputs are the field's
            assembly = self.assemblies.get(role)
            if assembly is not None:
                assembly.data[:] = bytes(len(assembly.data))
        if kind == RESET_OUT_OF_BOX:
            self._tcpip.restore_defaults()
            self.link.restore_defaults()
        if table.policy.safety is not None:
            table.policy.safety.state.identity_reset(kind)
        self.link.clear_counters()
        self._next_session_handle = 1
        self.reset_window.start(now)

    def reset(self, kind: int, now: int) -> bool:
        """A reset from outside CIP (the API, the CLI, the dashboard: a test engineer's power switch
        or reset button): as an Identity Reset of type `kind` (0 power cycle, 1 out-of-box, 2 out-of-box
        but the communication parameters), without a request to answer. False if the device is in
        its reset window already (nothing happens); ValueError for an unknown type."""
        if kind not in _RESET_KINDS:
            raise ValueError(f"reset type {kind}: one of {', '.join(map(str, _RESET_KINDS))}")
        with self.lock:
            if self.reset_window.active:
                return False
            before = self._snapshot()
            self._reset(kind, now)
            connections = self.table.pop_events()
            after = self._snapshot()
        self._publish(before, after, (), connections)
        self._record_reset(kind)
        return True

    def _record_reset(self, kind: int) -> None:
        self.record("reset", f"type {kind} ({_RESET_KINDS[kind]}): not answering for "
                    f"{self.profile.reset_time_s:g} s")

    def end_reset(self, now: int) -> bool:
        """End the reset window if its deadline has come (never before): True if the device
        answers again from now, with a "reset done" event."""
        if not self.reset_window.end(now):
            return False
        self.record("reset done", "answering again")
        return True

    def session_closed(self, session: object, now: int) -> None:
        self._locked(lambda: self.table.session_closed(session, now))

    def _locked(self, operation: Callable[[], object]) -> None:
        with self.lock:
            before = self._snapshot()
            operation()
            connections = self.table.pop_events()
            after = self._snapshot()
        self._publish(before, after, (), connections)

    # -- class-1 I/O (the cyclic I/O thread) --------------------------------------------------------

    def receive_io(self, data: bytes, source: tuple[str, int], now: int, send: SendDatagram) -> bool:
        """An O->T datagram from `source` (host, port), received at `now`: True if a connection took it.
        What must answer it at once (CIP Safety time coordination) goes out through `send`."""
        if self.faults.io_stopped:
            self.counters["o_t_dropped_io_stopped"] += 1
            return False
        if self.reset_window.active:
            self.counters["o_t_dropped_resetting"] += 1
            return False
        table, output = self.table, self._output
        with self.lock:  # O->T changes the outputs only: the inputs need no snapshot
            old = bytes(output.data) if output is not None else b""
            taken = table.receive_datagram(data, source[0], now, source[1])
            if table.has_replies:
                for packet, address in table.pop_replies():
                    send(packet, address)
            connections = table.pop_events() if table.has_events else ()
            changed = output is not None and output.data != old
            new = bytes(output.data) if changed else old
        if connections or changed:
            self._publish((old, b""), (new, b""), (), connections)
        return taken

    def service_io(self, now: int, send: SendDatagram, horizon: int | None = None) -> int | None:
        """Supervise the connections at `now` and hand `send` the T->O packets due by `now` (or by
        `horizon`, the end of the I/O thread's turn); the next time something is due. `send` takes
        them inside the lock: the I/O thread queues them and sends a turn's packets together."""
        table = self.table
        with self.lock:
            expiring = table.supervision_due(now)
            if expiring:  # a timeout may change the outputs: look before and after
                before = self._snapshot()
                table.handle_timer(now)
            due, timer = table.produce(now, horizon)
            if due and not self.faults.io_stopped:
                for packet, address in due:
                    send(packet, address)
            if expiring:
                connections = table.pop_events()
                after = self._snapshot()
        if expiring and connections:
            self._publish(before, after, (), connections)
        return timer

    def get_timer(self) -> int | None:
        with self.lock:
            return self.table.get_timer()


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
