"""One virtual device: its CIP objects, its I/O image and its encapsulation-level identity.

The assembly bytearrays are the device's I/O image: explicit messaging, and later implicit I/O and
the control API, all read and write these same bytes.
"""

from __future__ import annotations

import random
import threading
import time
from collections import Counter
from collections.abc import Callable
from typing import Protocol

from enip_farm.cip.assembly import AssemblyInstance, AssemblyObject
from enip_farm.cip.connection import Connection, ConnectionKind
from enip_farm.cip.connection_manager import ConnectionManager
from enip_farm.cip.ethernet_link import EthernetLinkObject
from enip_farm.cip.identity import STATUS_NO_IO_CONNECTIONS, IdentityObject
from enip_farm.cip.message_router import MessageRouter
from enip_farm.cip.tcpip_interface import TcpIpInterfaceObject
from enip_farm.device.events import EventLog
from enip_farm.device.faults import DeviceFaults
from enip_farm.device.latency import LatencyHistogram
from enip_farm.device.profile import DeviceProfile
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
from enip_farm.protocol.connection import ConnectionTriad, IoPacket
from enip_farm.protocol.cpf import ItemType, encode_items
from enip_farm.protocol.session import MessageContext

ENIP_PORT = 44818
#: ListIdentity state: 3 = "operational" (Vol. 2, table 2-4.4 refers to the Identity state attribute).
_STATE_OPERATIONAL = 3
#: Identity status (Vol. 1, table 5-2.4): bit 0 owned; bits 4-7 extended device status.
_OWNED = 0x0001
_IO_RUN = 0x0060  # at least one I/O connection in run mode
_IO_IDLE = 0x0070  # I/O connections established, all idle
_HALF = 0x80000000


#: A change of an I/O image: (device, "input" or "output", old bytes, new bytes).
ChangeListener = Callable[["Device", str, bytes, bytes], None]


class ConnectionObserver(Protocol):
    """The server side of connections: produces T->O and supervises timeouts."""

    def opened(self, connection: Connection) -> None: ...

    def closed(self, connection: Connection) -> None: ...


class Device:
    """Implements the encapsulation `Target` protocol for one configured device."""

    def __init__(self, profile: DeviceProfile) -> None:
        self.profile = profile
        writable = profile.implicit.explicit_output_writes_while_owned
        self.assemblies: dict[str, AssemblyInstance] = {
            spec.role: AssemblyInstance(spec.instance_id, spec.size, spec.settable, writable)
            for spec in profile.assemblies
        }
        self.faults = DeviceFaults()
        self.recorder: TrafficTap | None = None  # serve --record
        self.counters: Counter[str] = Counter()
        self.latency = LatencyHistogram()
        self._next_session_handle = 1
        self.sessions: set[int] = set()
        self.events = EventLog(profile.name)
        self.connections: dict[int, Connection] = {}  # by O->T connection id
        self._by_triad: dict[ConnectionTriad, Connection] = {}
        self._next_connection_id = random.getrandbits(32) & 0xFFFF0000
        self.observer: ConnectionObserver | None = None
        # connections are opened and closed on the event loop and consumed in the cyclic I/O thread;
        # the API writes images from any thread. Listeners are called after the lock is released.
        self.lock = threading.Lock()
        self.listeners: list[ChangeListener] = []
        for role, assembly in self.assemblies.items():
            assembly.on_change = lambda old, role=role: self._changed(role, old)
        self.router = MessageRouter()
        self.router.forced_status = self.faults.forced_status
        self.router.on_request = self.events.request
        self.router.replay = {(service, path, data): reply for service, path, data, reply in profile.replay}
        for obj in (
            IdentityObject(
                vendor_id=profile.vendor_id,
                device_type=profile.device_type,
                product_code=lambda: self.product_code,
                revision=profile.revision,
                serial_number=profile.serial_number,
                product_name=profile.product_name,
                status=lambda: self.status,
            ),
            AssemblyObject(list(self.assemblies.values())),
            ConnectionManager(self.router, self),
            TcpIpInterfaceObject(address=profile.address, netmask=profile.netmask, gateway=profile.gateway,
                                 host_name=profile.host_name),
            EthernetLinkObject(mac=profile.mac),
        ):
            self.router.register(obj)
        service = ServiceItem(PROTOCOL_VERSION, CAPABILITY_TCP | CAPABILITY_UDP_CLASS_0_1, "Communications")
        self._list_services = encode_items([(ItemType.LIST_SERVICES, encode_service_item(service))])

    @property
    def name(self) -> str:
        return self.profile.name

    # -- the I/O image --------------------------------------------------------------------------

    @property
    def outputs(self) -> bytes:
        assembly = self.assemblies.get("output")
        return bytes(assembly.data) if assembly else b""

    @property
    def inputs(self) -> bytes:
        assembly = self.assemblies.get("input")
        return bytes(assembly.data) if assembly else b""

    @property
    def product_code(self) -> int:
        """The product code the device shows; an `identity` fault changes it so keys stop matching."""
        code = self.profile.product_code
        return (code + 1) & 0xFFFF if self.faults.identity_changed else code

    @property
    def status(self) -> int:
        """Identity attribute 5, from the device's I/O connections."""
        io = [c for c in self.connections.values() if c.is_io]
        if not io:
            return STATUS_NO_IO_CONNECTIONS
        owned = _OWNED if any(c.kind is ConnectionKind.EXCLUSIVE_OWNER for c in io) else 0
        return owned | (_IO_RUN if any(c.run for c in io) else _IO_IDLE)

    def set_inputs(self, data: bytes) -> None:
        """Set the input image as a sensor would (not subject to `writable_inputs`)."""
        self.write_image("input", lambda image: _replace(image, data, self.name))

    def write_image(self, role: str, change: Callable[[bytearray], None]) -> None:
        """Change an image in place under the device lock (read-modify-write: no write is lost when
        several callers write at once), then tell the listeners."""
        image = self.assemblies[role].data
        with self.lock:
            old = bytes(image)
            change(image)
        self._changed(role, old)

    def _changed(self, role: str, old: bytes) -> None:
        new = bytes(self.assemblies[role].data)
        if new != old:
            for listener in self.listeners:
                listener(self, role, old, new)

    # -- encapsulation Target -------------------------------------------------------------------

    def identity_item(self) -> IdentityItem:
        p = self.profile
        return IdentityItem(PROTOCOL_VERSION, SocketAddress(p.address, ENIP_PORT), p.vendor_id, p.device_type,
                            self.product_code, p.revision[0], p.revision[1], self.status, p.serial_number,
                            p.product_name, _STATE_OPERATIONAL)

    def list_identity_data(self) -> bytes:
        return encode_items([(ItemType.LIST_IDENTITY, encode_identity_item(self.identity_item()))])

    def list_services_data(self) -> bytes:
        return self._list_services

    def list_interfaces_data(self) -> bytes:
        return encode_items([])

    def register_session(self) -> int:
        self.counters["sessions"] += 1
        handle = self._next_session_handle
        self._next_session_handle = handle + 1 if handle < 0xFFFFFFFF else 1
        self.sessions.add(handle)
        self.events.record("session registered", f"handle {handle}")
        return handle

    def unregister_session(self, session_handle: int) -> None:
        self.sessions.discard(session_handle)
        self.events.record("session ended", f"handle {session_handle}")

    def handle_unconnected(self, message: bytes, context: MessageContext) -> bytes:
        return self.router.handle(message, context)

    def handle_connected(self, connection_id: int, sequence_count: int, message: bytes,
                         context: MessageContext) -> tuple[int, bytes] | None:
        connection = self.connections.get(connection_id)
        if connection is None or connection.is_io or connection.owner is not context.owner:
            return None
        connection.last_received = time.monotonic()
        connection.received += 1
        if connection.last_reply is not None and connection.last_reply[0] == sequence_count:
            return connection.t_o_id, connection.last_reply[1]  # a duplicate: the same reply, not re-executed
        reply = self.router.handle(message, context)
        connection.last_reply = (sequence_count, reply)
        return connection.t_o_id, reply

    def session_closed(self, owner: object) -> None:
        for connection in [c for c in self.connections.values() if c.owner is owner]:
            self.close_connection(connection, "TCP connection closed")

    # -- connections ----------------------------------------------------------------------------

    def new_connection_id(self) -> int:
        while True:
            self._next_connection_id = (self._next_connection_id + 1) & 0xFFFFFFFF
            if self._next_connection_id and self._next_connection_id not in self.connections:
                return self._next_connection_id

    def find_connection(self, triad: ConnectionTriad) -> Connection | None:
        return self._by_triad.get(triad)

    def open_connection(self, connection: Connection) -> None:
        with self.lock:
            self.connections[connection.o_t_id] = connection
            self._by_triad[connection.triad] = connection
            if connection.kind is ConnectionKind.EXCLUSIVE_OWNER:
                self.assemblies["output"].owned = True
        self.events.record("connection opened", _describe(connection))
        if self.observer is not None:
            self.observer.opened(connection)

    def close_connection(self, connection: Connection, reason: str) -> None:
        timed_out = reason == "timeout"
        old_outputs = self.outputs
        with self.lock:
            if connection.closed:
                return
            connection.closed = True
            self.connections.pop(connection.o_t_id, None)
            self._by_triad.pop(connection.triad, None)
            if connection.kind is ConnectionKind.EXCLUSIVE_OWNER:
                output = self.assemblies["output"]
                output.owned = False
                policy = self.profile.implicit
                if (policy.fault_state if timed_out else policy.idle_state) == "off":
                    output.data[:] = bytes(len(output.data))
        if connection.kind is ConnectionKind.EXCLUSIVE_OWNER:
            self._changed("output", old_outputs)
        self.events.record("connection timed out" if timed_out else "connection closed",
                           f"{_describe(connection)}: {reason}")
        if self.observer is not None:
            self.observer.closed(connection)
        if connection.multicast and connection.kind is not ConnectionKind.LISTEN_ONLY and not any(
                c.multicast and c.t_o_point == connection.t_o_point and c.kind is not ConnectionKind.LISTEN_ONLY
                for c in self.connections.values()):
            for listener in [c for c in self.connections.values() if c.kind is ConnectionKind.LISTEN_ONLY
                             and c.t_o_point == connection.t_o_point]:
                self.close_connection(listener, "its producing connection closed")

    def consume(self, source_host: str, packet: IoPacket) -> bool:
        """An O->T packet (Vol. 2, 3-2): True if it belonged to a connection and was taken."""
        output = self.assemblies.get("output")
        old = bytes(output.data) if output is not None else b""
        with self.lock:
            taken = self._consume(source_host, packet)
        if output is not None and output.data != old:
            self._changed("output", old)
        return taken

    def _consume(self, source_host: str, packet: IoPacket) -> bool:
        if self.faults.io_stopped:
            return False
        connection = self.connections.get(packet.connection_id)
        if connection is None or not connection.is_io or source_host != connection.originator_host:
            return False
        last = connection.last_sequence
        if last is not None and (packet.sequence - last) & 0xFFFFFFFF >= _HALF:
            return False  # older than what was consumed already
        connection.last_sequence = packet.sequence
        connection.last_received = time.monotonic()
        connection.received += 1
        self.counters["o_t_packets"] += 1
        data = packet.data
        if not connection.o_t_run_idle_header:  # a heartbeat: no data, run/idle header optional
            connection.run = not data or bool(data[0] & 1)
            return True
        if len(data) < 4:
            return False
        output = self.assemblies["output"]
        connection.run = bool(data[0] & 1)
        if connection.run:
            payload = data[4:]
            if len(payload) != len(output.data):
                return False
            output.data[:] = payload
        elif self.profile.implicit.idle_state == "off":
            output.data[:] = bytes(len(output.data))
        return True

    def produced_data(self) -> bytes:
        """T->O data: the input image, modeless."""
        return bytes(self.assemblies["input"].data)


def _describe(connection: Connection) -> str:
    return (f"{connection.kind.value} O->T 0x{connection.o_t_id:08X} T->O 0x{connection.t_o_id:08X} "
            f"from {connection.originator_host}, RPI {connection.o_t_rpi}/{connection.t_o_rpi} us")


def _replace(image: bytearray, data: bytes, name: str) -> None:
    if len(data) != len(image):
        raise ValueError(f"{name}: image is {len(image)} bytes, got {len(data)}")
    image[:] = data
