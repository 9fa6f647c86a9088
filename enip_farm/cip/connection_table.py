"""The connection table of one device, sans-IO (CIP Networks Library Vol. 1, 3-4 and 3-5.5;
Vol. 2, 3-2 and 3-3), in the style of aioquic's `QuicConnection`:

- admission: Forward Open / Large Forward Open checks (path, electronic key, transport, types,
  RPI, sizes, ownership, limits), each refusal with the extended status of Vol. 1 table 3-5.33 and,
  for sizes, the size the target expects as a second additional status word;
- the table itself, Forward Close and the close cascade of listen-only connections;
- consumption of O->T packets (`receive_datagram`): originator, sequence window, run/idle, size;
- production of T->O packets on absolute deadlines (`datagrams_to_send`);
- supervision (`get_timer`, `handle_timer`): the first watchdog, then exactly the last valid
  packet + RPI x 2^(2 + multiplier).

Time is always a parameter (integer nanoseconds of a monotonic clock), never read here. The
caller holds the device lock around every call: the table reads and writes the assemblies' bytes.
What happened is returned (`pop_events`), never called back.
"""

from __future__ import annotations

import random
import socket
from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import NamedTuple

from enip_farm.cip.assembly import AssemblyInstance
from enip_farm.cip.connection import Connection, ConnectionKind, Production
from enip_farm.protocol.commands import SocketAddress, encode_sockaddr
from enip_farm.protocol.connection import (
    ConnectionTriad,
    ConnectionType,
    ForwardOpenRequest,
    decode_io_packet,
    encode_io_packet,
)
from enip_farm.protocol.cpf import ItemType
from enip_farm.protocol.epath import (
    DataSegment,
    ElectronicKey,
    LogicalSegment,
    LogicalType,
    PathError,
    PortSegment,
    decode_epath,
)
from enip_farm.protocol.status import ExtendedStatus as X
from enip_farm.protocol.status import GeneralStatus

IO_PORT = 2222
SEQUENCE_COUNT_SIZE = 2
RUN_IDLE_HEADER_SIZE = 4
_SELF = PortSegment(1, b"\x00")  # a route to this device itself: backplane port 1, slot 0
_CLASS_1, _CLASS_3 = 0x01, 0x03
_ASSEMBLY, _MESSAGE_ROUTER = 0x04, 0x02
_HALF = 0x80000000
#: Identity status (Vol. 1, table 5-2.4): bit 0 owned; bits 4-7 extended device status.
_OWNED = 0x0001
_NO_IO = 0x0030  # no I/O connection established
_IO_RUN = 0x0060  # at least one I/O connection in run mode
_IO_IDLE = 0x0070  # I/O connections established, all idle


@dataclass(frozen=True)
class ConnectionPolicy:
    """What a device accepts; built from its profile."""

    rpi_min_us: int
    rpi_max_us: int
    max_class1_connections: int
    max_class3_connections: int
    outputs_off_on_idle: bool  # idle_state "off": outputs cleared on Idle and on Forward Close
    outputs_off_on_fault: bool  # fault_state "off": outputs cleared when a connection times out
    first_watchdog_ns: int
    input_only_point: int | None
    listen_only_point: int | None
    multicast_group: str


class KeyIdentity(NamedTuple):
    """The identity an electronic key is checked against (Vol. 1, C-1.4.2)."""

    vendor_id: int
    device_type: int
    product_code: int
    revision: tuple[int, int]


class Originator(NamedTuple):
    """Where a Forward Open came from: its host, the T->O socket address item it carried (if any),
    and the encapsulation session (class-3 connections belong to it)."""

    host: str
    t_o_sockaddr: SocketAddress | None = None
    session: object | None = None


class Refusal(NamedTuple):
    """A Forward Open refused: general status, extended status, and for sizes the expected size."""

    extended: int
    expected_size: int | None = None
    general: int = GeneralStatus.CONNECTION_FAILURE

    @property
    def additional_status(self) -> tuple[int, ...]:
        return (self.extended,) if self.expected_size is None else (self.extended, self.expected_size)


class Opened(NamedTuple):
    connection: Connection
    reply_items: tuple[tuple[int, bytes], ...]  # e.g. the multicast group (0x8001) of Vol. 2, 3-3.9.4


class ConnectionEvent(NamedTuple):
    kind: str  # "connection opened", "connection closed", "connection timed out"
    connection: Connection
    reason: str
    at: int  # ns


class _Refused(Exception):
    def __init__(self, refusal: Refusal) -> None:
        super().__init__(hex(refusal.extended))
        self.refusal = refusal


def _refuse(extended: int, expected_size: int | None = None) -> _Refused:
    return _Refused(Refusal(extended, expected_size))


class ConnectionTable:
    """The CIP connections of one device. Every method takes the time, none reads a clock."""

    def __init__(self, assemblies: Mapping[str, AssemblyInstance], policy: ConnectionPolicy,
                 identity: Callable[[], KeyIdentity], counters: Counter[str] | None = None,
                 rng: random.Random | None = None) -> None:
        self.assemblies = assemblies
        self.policy = policy
        self.identity = identity
        self.counters: Counter[str] = counters if counters is not None else Counter()
        self.connections: dict[int, Connection] = {}  # by O->T connection id
        self.productions: dict[int, Production] = {}  # by T->O connection id
        self._by_triad: dict[ConnectionTriad, Connection] = {}
        self._events: list[ConnectionEvent] = []
        self._rng = rng or random.Random()
        self._short_data_reported: set[int] = set()

    # -- what the table says -------------------------------------------------------------------

    @property
    def has_events(self) -> bool:
        return bool(self._events)

    def pop_events(self) -> list[ConnectionEvent]:
        events, self._events = self._events, []
        return events

    def find(self, triad: ConnectionTriad) -> Connection | None:
        return self._by_triad.get(triad)

    @property
    def status(self) -> int:
        """Identity attribute 5 as the I/O connections make it."""
        io = [c for c in self.connections.values() if c.is_io]
        if not io:
            return _NO_IO
        owned = _OWNED if any(c.kind is ConnectionKind.EXCLUSIVE_OWNER for c in io) else 0
        return owned | (_IO_RUN if any(c.run for c in io) else _IO_IDLE)

    def get_timer(self) -> int | None:
        """The earliest time something is due: a T->O packet or a supervision deadline."""
        times = [p.due for p in self.productions.values()]
        times += [c.deadline for c in self.connections.values()]
        return min(times, default=None)

    # -- Forward Open, Forward Close -------------------------------------------------------------

    def forward_open(self, request: ForwardOpenRequest, originator: Originator, now: int) -> Opened | Refusal:
        try:
            connection = self._admit(request, originator, now)
        except _Refused as refused:
            return refused.refusal
        self.connections[connection.o_t_id] = connection
        self._by_triad[connection.triad] = connection
        items: tuple[tuple[int, bytes], ...] = ()
        if connection.is_io:
            if connection.kind is ConnectionKind.EXCLUSIVE_OWNER:
                self.assemblies["output"].owned = True
            production = self.productions.get(connection.t_o_id)
            if production is not None:
                production.users += 1
            else:
                self.productions[connection.t_o_id] = Production(
                    connection.t_o_id, connection.t_o_address, connection.t_o_rpi * 1000, now)  # type: ignore[arg-type]
            if connection.multicast:
                items = ((ItemType.SOCKADDR_T_O, encode_sockaddr(SocketAddress(*connection.t_o_address))),)  # type: ignore[misc]
        self._events.append(ConnectionEvent("connection opened", connection, "", now))
        return Opened(connection, items)

    def forward_close(self, triad: ConnectionTriad, now: int) -> Connection | None:
        """Close the connection of this triad; None if there is none (0x0107)."""
        connection = self._by_triad.get(triad)
        if connection is not None:
            self.close(connection, "forward close", now)
        return connection

    def session_closed(self, session: object, now: int) -> None:
        """The TCP connection of a session ended: its class-3 connections end with it."""
        for connection in [c for c in self.connections.values() if c.owner is session]:
            self.close(connection, "TCP connection closed", now)

    def close_all(self, reason: str, now: int) -> None:
        for connection in list(self.connections.values()):
            self.close(connection, reason, now)

    def close(self, connection: Connection, reason: str, now: int, timed_out: bool = False) -> None:
        if connection.closed:
            return
        connection.closed = True
        self.connections.pop(connection.o_t_id, None)
        self._by_triad.pop(connection.triad, None)
        self._short_data_reported.discard(connection.o_t_id)
        if connection.is_io:
            production = self.productions.get(connection.t_o_id)
            if production is not None:
                production.users -= 1
                if production.users <= 0:
                    del self.productions[connection.t_o_id]
        if connection.kind is ConnectionKind.EXCLUSIVE_OWNER:
            output = self.assemblies["output"]
            output.owned = False
            if self.policy.outputs_off_on_fault if timed_out else self.policy.outputs_off_on_idle:
                output.data[:] = bytes(len(output.data))
        kind = "connection timed out" if timed_out else "connection closed"
        self._events.append(ConnectionEvent(kind, connection, reason, now))
        if connection.multicast and connection.kind is not ConnectionKind.LISTEN_ONLY and not any(
                c.multicast and c.t_o_point == connection.t_o_point and c.kind is not ConnectionKind.LISTEN_ONLY
                for c in self.connections.values()):
            for listener in [c for c in self.connections.values()
                             if c.kind is ConnectionKind.LISTEN_ONLY and c.t_o_point == connection.t_o_point]:
                self.close(listener, "its producing connection closed", now)

    # -- supervision -----------------------------------------------------------------------------

    def handle_timer(self, now: int) -> None:
        """Close every connection whose deadline has come (at the deadline, not a tick before)."""
        for connection in [c for c in self.connections.values() if c.deadline <= now]:
            self.counters["connection_timeouts"] += 1
            self.close(connection, f"no packet for {connection.timeout_ns / 1e6:g} ms", now, timed_out=True)

    # -- class-1 consumption and production --------------------------------------------------------

    def receive_datagram(self, data: bytes, host: str, now: int) -> bool:
        """An O->T datagram on UDP 2222 (Vol. 2, 3-2): True if it was a valid packet of one of the
        table's connections. Every other datagram is counted by why it was not taken."""
        packet = decode_io_packet(data)
        if packet is None:
            return self._drop("malformed")
        connection = self.connections.get(packet.connection_id)
        if connection is None or not connection.is_io:
            return self._drop("unknown_connection")
        if host != connection.originator_host:
            return self._drop("wrong_originator")
        last = connection.last_sequence
        if last is not None and not 0 < (packet.sequence - last) & 0xFFFFFFFF < _HALF:
            return self._drop("stale")  # a duplicate or older than what was consumed (Vol. 2, 3-2.1)
        payload = packet.data
        if connection.o_t_run_idle_header:
            if len(payload) < RUN_IDLE_HEADER_SIZE:
                return self._drop("wrong_size")
            output = self.assemblies["output"]
            run = bool(payload[0] & 1)
            image = payload[RUN_IDLE_HEADER_SIZE:]
            if len(image) != len(output.data) and not (connection.o_t_variable and len(image) < len(output.data)):
                return self._drop("wrong_size")
        elif payload and len(payload) != RUN_IDLE_HEADER_SIZE:  # a heartbeat: nothing, or a run/idle header
            return self._drop("wrong_size")
        else:
            run = not payload or bool(payload[0] & 1)
            image = None
        connection.last_sequence = packet.sequence
        connection.last_received = now
        connection.received += 1
        connection.run = run
        self.counters["o_t_packets"] += 1
        if image is None:
            return True
        output = self.assemblies["output"]
        if not run:
            if self.policy.outputs_off_on_idle:
                output.data[:] = bytes(len(output.data))
        elif len(image) == len(output.data):
            output.data[:] = image
        else:  # variable size, shorter than the assembly: the assembly takes whole images only
            self.counters["o_t_short_data"] += 1
            if connection.o_t_id not in self._short_data_reported:
                self._short_data_reported.add(connection.o_t_id)
                self._events.append(ConnectionEvent(
                    "connection short data", connection,
                    f"{len(image)} of {len(output.data)} bytes: not applied to the outputs", now))
        return True

    def _drop(self, reason: str) -> bool:
        self.counters[f"o_t_dropped_{reason}"] += 1
        return False

    def datagrams_to_send(self, now: int) -> list[tuple[bytes, tuple[str, int]]]:
        """The T->O packets due by `now`, one per stream; a stream that fell a whole period behind
        skips the missed periods rather than bursting."""
        due = [p for p in self.productions.values() if p.due <= now]
        if not due:
            return []
        data = bytes(self.assemblies["input"].data)
        out = []
        for production in due:
            production.sequence += 1
            out.append((encode_io_packet(production.connection_id, production.sequence, production.sequence, data),
                        production.address))
            production.count += 1
            behind = now - production.due
            if behind >= 0:  # the next one is already due: skip to the first deadline after now
                skipped = behind // production.period_ns + 1
                production.count += skipped
                production.late += skipped
        self.counters["t_o_packets"] += len(out)
        return out

    # -- class-3 consumption -----------------------------------------------------------------------

    def receive_connected(self, connection_id: int, session: object, now: int) -> Connection | None:
        """A class-3 request on a connection of this session (Vol. 2, 2-6.2): the connection, its
        watchdog fed; None when the connection is not this session's."""
        connection = self.connections.get(connection_id)
        if connection is None or connection.is_io or connection.owner is not session:
            return None
        connection.last_received = now
        connection.received += 1
        return connection

    # -- admission -------------------------------------------------------------------------------

    def _new_connection_id(self) -> int:
        while True:
            candidate = self._rng.getrandbits(32)
            if candidate and candidate not in self.connections and candidate not in self.productions:
                return candidate

    def _admit(self, request: ForwardOpenRequest, originator: Originator, now: int) -> Connection:
        if request.triad in self._by_triad:
            raise _refuse(X.CONNECTION_IN_USE)
        o_t_type = request.o_t_parameters.connection_type
        t_o_type = request.t_o_parameters.connection_type
        if o_t_type == ConnectionType.NULL and t_o_type == ConnectionType.NULL:
            raise _refuse(X.NULL_FORWARD_OPEN_NOT_SUPPORTED)
        transport = request.transport_class
        if transport == _CLASS_3 and request.transport_type_trigger & 0x80:
            return self._admit_explicit(request, originator, now)
        if transport != _CLASS_1 or request.production_trigger != 0:  # class 1, cyclic
            raise _refuse(X.TRANSPORT_TRIGGER_NOT_SUPPORTED)
        return self._admit_io(request, self._io_points(request.connection_path), originator, now)

    def _check_key(self, key: ElectronicKey) -> None:
        identity = self.identity()
        if ((key.vendor_id and key.vendor_id != identity.vendor_id)
                or (key.product_code and key.product_code != identity.product_code)):
            raise _refuse(X.VENDOR_OR_PRODUCT_MISMATCH)
        if key.device_type and key.device_type != identity.device_type:
            raise _refuse(X.DEVICE_TYPE_MISMATCH)
        major, minor = identity.revision
        if key.major_revision:
            if key.compatibility:  # any revision that can emulate the requested one
                if key.major_revision != major or (key.minor_revision and key.minor_revision > minor):
                    raise _refuse(X.REVISION_MISMATCH)
            elif key.major_revision != major or (key.minor_revision and key.minor_revision != minor):
                raise _refuse(X.REVISION_MISMATCH)

    def _path_segments(self, connection_path: bytes) -> list:
        try:
            segments = decode_epath(connection_path)
        except PathError:
            raise _refuse(X.INVALID_SEGMENT) from None
        while segments and segments[0] == _SELF:
            segments.pop(0)
        if segments and isinstance(segments[0], ElectronicKey):
            self._check_key(segments.pop(0))
        return segments

    def _io_points(self, connection_path: bytes) -> tuple[int | None, int, int]:
        """(configuration, consuming O->T, producing T->O) points of an assembly connection path."""
        segments = [s for s in self._path_segments(connection_path) if not isinstance(s, DataSegment)]
        if not segments or segments[0] != LogicalSegment(LogicalType.CLASS_ID, _ASSEMBLY):
            raise _refuse(X.INVALID_SEGMENT)
        values = []
        for segment in segments[1:]:
            if not isinstance(segment, LogicalSegment) or segment.type not in (
                    LogicalType.INSTANCE_ID, LogicalType.CONNECTION_POINT):
                raise _refuse(X.INVALID_SEGMENT)
            values.append(segment.value)
        if len(values) == 3:
            return values[0], values[1], values[2]
        if len(values) == 2:
            return None, values[0], values[1]
        raise _refuse(X.INVALID_SEGMENT)

    def _admit_io(self, request: ForwardOpenRequest, points: tuple[int | None, int, int],
                  originator: Originator, now: int) -> Connection:
        policy = self.policy
        configuration, consuming, producing = points
        config_assembly = self.assemblies.get("configuration")
        if configuration is not None and (config_assembly is None or configuration != config_assembly.instance_id):
            raise _refuse(X.INVALID_CONFIGURATION_PATH)
        output, inputs = self.assemblies.get("output"), self.assemblies.get("input")
        if output is not None and consuming == output.instance_id:
            kind = ConnectionKind.EXCLUSIVE_OWNER
        elif consuming == policy.input_only_point:
            kind = ConnectionKind.INPUT_ONLY
        elif consuming == policy.listen_only_point:
            kind = ConnectionKind.LISTEN_ONLY
        else:
            raise _refuse(X.INVALID_CONSUMING_PATH)
        if inputs is None or producing != inputs.instance_id:
            raise _refuse(X.INVALID_PRODUCING_PATH)
        o_t, t_o = request.o_t_parameters, request.t_o_parameters
        if o_t.connection_type != ConnectionType.POINT_TO_POINT or t_o.connection_type not in (
                ConnectionType.POINT_TO_POINT, ConnectionType.MULTICAST):
            raise _refuse(X.INVALID_CONNECTION_TYPE)
        for rpi in (request.o_t_rpi, request.t_o_rpi):
            if not policy.rpi_min_us <= rpi <= policy.rpi_max_us:
                raise _refuse(X.RPI_NOT_SUPPORTED)
        # O->T: sequence count, 32-bit run/idle header, data; heartbeats carry no data (header optional).
        # A variable size is accepted when the data fits: at least the header, at most the whole image.
        if kind is ConnectionKind.EXCLUSIVE_OWNER:
            expected = SEQUENCE_COUNT_SIZE + RUN_IDLE_HEADER_SIZE + len(output.data)  # type: ignore[union-attr]
            fits = o_t.size == expected or (o_t.variable and SEQUENCE_COUNT_SIZE + RUN_IDLE_HEADER_SIZE
                                            <= o_t.size <= expected)
        else:
            expected = SEQUENCE_COUNT_SIZE
            fits = o_t.size in (SEQUENCE_COUNT_SIZE, SEQUENCE_COUNT_SIZE + RUN_IDLE_HEADER_SIZE)
        if not fits:
            raise _refuse(X.INVALID_O_T_SIZE, expected)
        expected_t_o = SEQUENCE_COUNT_SIZE + len(inputs.data)  # modeless
        if t_o.size != expected_t_o:  # a variable T->O gets whole images: it must hold one
            raise _refuse(X.INVALID_T_O_SIZE, expected_t_o)

        io_connections = [c for c in self.connections.values() if c.is_io]
        if kind is ConnectionKind.EXCLUSIVE_OWNER and any(
                c.kind is ConnectionKind.EXCLUSIVE_OWNER and c.o_t_point == consuming for c in io_connections):
            raise _refuse(X.OWNERSHIP_CONFLICT)
        multicast = t_o.connection_type == ConnectionType.MULTICAST
        shared = next((c for c in io_connections if c.multicast and c.t_o_point == producing
                       and c.kind is not ConnectionKind.LISTEN_ONLY), None) if multicast else None
        if kind is ConnectionKind.LISTEN_ONLY and shared is None:
            raise _refuse(X.NON_LISTEN_ONLY_NOT_OPENED)
        if shared is not None and shared.t_o_rpi != request.t_o_rpi:
            raise _refuse(X.RPI_NOT_SUPPORTED)
        if len(io_connections) >= policy.max_class1_connections:
            raise _refuse(X.OUT_OF_CONNECTIONS)

        if multicast:
            t_o_id = shared.t_o_id if shared else self._new_connection_id()
            t_o_address = (policy.multicast_group, IO_PORT)
        else:
            t_o_id = request.t_o_connection_id
            t_o_address = self._point_to_point_address(originator)
        return Connection(
            kind=kind, triad=request.triad, o_t_id=self._new_connection_id(), t_o_id=t_o_id,
            o_t_rpi=request.o_t_rpi, t_o_rpi=request.t_o_rpi, timeout_multiplier=request.timeout_multiplier,
            originator_host=originator.host, opened_at=now, first_watchdog_ns=policy.first_watchdog_ns,
            t_o_address=t_o_address, multicast=multicast, o_t_point=consuming, t_o_point=producing,
            o_t_run_idle_header=kind is ConnectionKind.EXCLUSIVE_OWNER, o_t_variable=o_t.variable,
        )

    @staticmethod
    def _point_to_point_address(originator: Originator) -> tuple[str, int]:
        """The originator's T->O socket-address item, where given (address 0: the originator)."""
        host, port = originator.host, IO_PORT
        address = originator.t_o_sockaddr
        if address is not None and address.family == socket.AF_INET:
            if address.port:
                port = address.port
            if address.host != "0.0.0.0":
                host = address.host
        return host, port

    def _admit_explicit(self, request: ForwardOpenRequest, originator: Originator, now: int) -> Connection:
        segments = self._path_segments(request.connection_path)
        if segments != [LogicalSegment(LogicalType.CLASS_ID, _MESSAGE_ROUTER),
                        LogicalSegment(LogicalType.INSTANCE_ID, 1)]:
            raise _refuse(X.INVALID_SEGMENT)
        if (request.o_t_parameters.connection_type != ConnectionType.POINT_TO_POINT
                or request.t_o_parameters.connection_type != ConnectionType.POINT_TO_POINT):
            raise _refuse(X.INVALID_CONNECTION_TYPE)
        if sum(not c.is_io for c in self.connections.values()) >= self.policy.max_class3_connections:
            raise _refuse(X.OUT_OF_CONNECTIONS)
        return Connection(
            kind=ConnectionKind.EXPLICIT, triad=request.triad, o_t_id=self._new_connection_id(),
            t_o_id=request.t_o_connection_id, o_t_rpi=request.o_t_rpi, t_o_rpi=request.t_o_rpi,
            timeout_multiplier=request.timeout_multiplier, originator_host=originator.host, opened_at=now,
            owner=originator.session,
        )
