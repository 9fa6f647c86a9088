"""Admission of a Forward Open or Large Forward Open (CIP Networks Library Vol. 1, 3-5.5.2 and
table 3-5.33): connection path, electronic key (C-1.4.2), transport class and trigger, connection
types, RPI, sizes, ownership and limits; a SafetyOpen (a safety network segment in the path) goes
to cip/safety/admission.py (Vol. 5). Each refusal carries its extended status and, for sizes,
the size the target expects as a second additional status word (as OpENer sends it). Sans-IO:
the time is a parameter; nothing here is changed, the connection table keeps what is admitted.
"""

from __future__ import annotations

import random
import socket
from collections.abc import Callable, Collection, Mapping
from dataclasses import dataclass
from typing import NamedTuple

from enip_farm.cip.assembly import AssemblyInstance
from enip_farm.cip.connection import Connection, ConnectionKind
from enip_farm.cip.safety.admission import SafetyOpen, SafetyPolicy, admit_safety, safety_segment_of
from enip_farm.protocol.cip import ClassCode
from enip_farm.protocol.commands import SocketAddress
from enip_farm.protocol.connection import IO_PORT, ConnectionType, ForwardOpenRequest
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

SEQUENCE_COUNT_SIZE = 2
RUN_IDLE_HEADER_SIZE = 4
_SELF = PortSegment(1, b"\x00")  # a route to this device itself: backplane port 1, slot 0
_CLASS_1, _CLASS_3 = 0x01, 0x03
_MAX_TIMEOUT_MULTIPLIER = 7  # x512; 8-255 are reserved (Vol. 1, 3-5.4.1.4)


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
    safety: SafetyPolicy | None = None  # a CIP Safety target: SafetyOpens admitted, class-1 refused
    class3_rpi_min_us: int = 1_000  # class-3 RPIs accepted (the connection timeout's base)
    class3_rpi_max_us: int = 60_000_000
    declared: tuple[DeclaredConnection, ...] = ()  # an EDS's connections: only these are admitted


@dataclass(frozen=True)
class DeclaredConnection:
    """A class-1 connection a device's EDS declares (Vol. 1, 7-3.6.11): its points, its application
    data sizes (without the sequence count and a run/idle header), real-time formats ("modeless",
    "zero length", "heartbeat", "run/idle"), the T->O connection types it allows and its RPI range."""

    kind: ConnectionKind
    configuration: int | None
    o_t: int
    t_o: int
    o_t_size: int
    t_o_size: int
    o_t_format: str = "run/idle"
    t_o_format: str = "modeless"
    o_t_variable: bool = False
    t_o_variable: bool = False
    t_o_multicast: bool = True
    t_o_point_to_point: bool = True
    configuration_size: int = 0
    rpi_us: tuple[int, int] | None = None
    shared_owner: bool = False  # a redundant owner: several owners may consume the point
    name: str = ""

    def wire_size(self, direction: str) -> int:
        """The connection size a Forward Open gives: sequence count, run/idle header, data."""
        size, form = (self.o_t_size, self.o_t_format) if direction == "o_t" else (self.t_o_size, self.t_o_format)
        if form == "heartbeat":
            return SEQUENCE_COUNT_SIZE
        return SEQUENCE_COUNT_SIZE + (RUN_IDLE_HEADER_SIZE if form == "run/idle" else 0) + size


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
    """A Forward Open refused: general status, extended status (None: none), for sizes the expected
    size, and any further additional status words."""

    extended: int | None
    expected_size: int | None = None
    general: int = GeneralStatus.CONNECTION_FAILURE
    more: tuple[int, ...] = ()

    @property
    def additional_status(self) -> tuple[int, ...]:
        if self.extended is None:
            return ()
        return ((self.extended,) if self.expected_size is None else (self.extended, self.expected_size)) + self.more


def _data_segments(connection_path: bytes) -> list[DataSegment]:
    try:
        return [s for s in decode_epath(connection_path) if isinstance(s, DataSegment)]
    except PathError:
        return []


class _Refused(Exception):
    def __init__(self, refusal: Refusal) -> None:
        super().__init__(refusal.additional_status)
        self.refusal = refusal


def _refuse(extended: int, expected_size: int | None = None) -> _Refused:
    return _Refused(Refusal(extended, expected_size))


class Admission:
    """The checks of one device: its assemblies, its policy and its identity (for keys)."""

    def __init__(self, assemblies: Mapping[str, AssemblyInstance], policy: ConnectionPolicy,
                 identity: Callable[[], KeyIdentity], rng: random.Random | None = None) -> None:
        self.assemblies = assemblies
        self.policy = policy
        self.identity = identity
        self._rng = rng or random.SystemRandom()  # connection ids nobody can predict
        self._initial_rc_offset = 0  # CIP Safety: Initial_RC_Offset, one more per consuming connection

    def admit(self, request: ForwardOpenRequest, originator: Originator, now: int,
              connections: Collection[Connection],
              taken_ids: Callable[[int], bool]) -> Connection | SafetyOpen | Refusal:
        """The connection a Forward Open asks for (a SafetyOpen: with its application reply), or
        why not. `connections`: those open now; `taken_ids(id)`: whether a connection id is in use."""
        try:
            safety = self._safety(request, originator, now, connections, taken_ids)
            if safety is not None:
                return safety
            return self._admit(request, originator, now, connections, taken_ids)
        except _Refused as refused:
            return refused.refusal

    def _safety(self, request: ForwardOpenRequest, originator: Originator, now: int,
                connections: Collection[Connection], taken_ids: Callable[[int], bool]) -> SafetyOpen | None:
        """A SafetyOpen (a path with a safety network segment) admitted by cip/safety/admission.py;
        None for any other Forward Open. A device that is no safety target refuses it (0x0315)."""
        if 0x50 not in request.connection_path:
            return None
        try:
            segments = decode_epath(request.connection_path)
        except PathError:
            raise _refuse(X.INVALID_SEGMENT) from None
        route = 0
        while segments and segments[0] == _SELF:
            segments.pop(0)
            route += 2
        if safety_segment_of(segments) is None:
            return None
        policy = self.policy.safety
        if policy is None:
            raise _refuse(X.INVALID_SEGMENT)
        output, inputs = self.assemblies["output"], self.assemblies["input"]
        self._initial_rc_offset = (self._initial_rc_offset + 1) & 0xFFFF
        used = {c.instance for c in connections if c.safety is not None}
        result = admit_safety(
            request, segments, route, policy, self._check_key, (len(output.data), len(inputs.data)), originator.host,
            self._point_to_point_address(originator), now, connections, lambda: self._new_connection_id(taken_ids),
            lambda: next(i for i in range(1, len(used) + 2) if i not in used), self.policy.first_watchdog_ns,
            self._initial_rc_offset, (self.policy.multicast_group, IO_PORT))
        if not isinstance(result, SafetyOpen):
            raise _Refused(Refusal(*result))
        return result

    def _new_connection_id(self, taken_ids: Callable[[int], bool]) -> int:
        while True:
            candidate = self._rng.getrandbits(32)
            if candidate and not taken_ids(candidate):
                return candidate

    def _admit(self, request: ForwardOpenRequest, originator: Originator, now: int,
               connections: Collection[Connection], taken_ids: Callable[[int], bool]) -> Connection:
        if any(c.triad == request.triad for c in connections):
            raise _refuse(X.CONNECTION_IN_USE)
        if request.timeout_multiplier > _MAX_TIMEOUT_MULTIPLIER:  # reserved: no timeout can be computed
            raise _refuse(X.PARAMETER_ERROR)
        o_t_type = request.o_t_parameters.connection_type
        t_o_type = request.t_o_parameters.connection_type
        if o_t_type == ConnectionType.NULL and t_o_type == ConnectionType.NULL:
            raise _refuse(X.NULL_FORWARD_OPEN_NOT_SUPPORTED)
        transport = request.transport_class
        if transport == _CLASS_3 and request.transport_type_trigger & 0x80:
            return self._admit_explicit(request, originator, now, connections, taken_ids)
        if transport != _CLASS_1 or request.production_trigger != 0 or self.policy.safety is not None:
            raise _refuse(X.TRANSPORT_TRIGGER_NOT_SUPPORTED)  # class 1 cyclic; a safety target: SafetyOpens only
        return self._admit_io(request, self._io_points(request.connection_path), originator, now, connections,
                              taken_ids)

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
        if not segments or segments[0] != LogicalSegment(LogicalType.CLASS_ID, ClassCode.ASSEMBLY):
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

    def _admit_io(self, request: ForwardOpenRequest, points: tuple[int | None, int, int], originator: Originator,
                  now: int, connections: Collection[Connection], taken_ids: Callable[[int], bool]) -> Connection:
        if self.policy.declared:
            return self._admit_declared(request, points, originator, now, connections, taken_ids)
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

        io_connections = [c for c in connections if c.is_io]
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
            t_o_id = shared.t_o_id if shared else self._new_connection_id(taken_ids)
            t_o_address = (policy.multicast_group, IO_PORT)
        else:
            t_o_id = request.t_o_connection_id
            t_o_address = self._point_to_point_address(originator)
        return Connection(
            kind=kind, triad=request.triad, o_t_id=self._new_connection_id(taken_ids), t_o_id=t_o_id,
            o_t_rpi=request.o_t_rpi, t_o_rpi=request.t_o_rpi, timeout_multiplier=request.timeout_multiplier,
            originator_host=originator.host, opened_at=now, first_watchdog_ns=policy.first_watchdog_ns,
            t_o_address=t_o_address, multicast=multicast, o_t_point=consuming, t_o_point=producing,
            o_t_run_idle_header=kind is ConnectionKind.EXCLUSIVE_OWNER, o_t_variable=o_t.variable,
            o_t_size=o_t.size, t_o_size=t_o.size,
        )

    def _admit_declared(self, request: ForwardOpenRequest, points: tuple[int | None, int, int],
                        originator: Originator, now: int, connections: Collection[Connection],
                        taken_ids: Callable[[int], bool]) -> Connection:
        """A class-1 Forward Open held against the connections the device's EDS declares: the entry
        of its points (the configuration point may be left out where the entry has none), then
        that entry's connection types, RPI range and sizes. Where several entries share the points
        the first that fits is taken; else the first one's refusal is given."""
        configuration, consuming, producing = points
        declared = self.policy.declared
        same = [d for d in declared if d.o_t == consuming and d.t_o == producing]
        if not same:
            if any(d.o_t == consuming for d in declared):
                raise _refuse(X.INVALID_PRODUCING_PATH)
            raise _refuse(X.INVALID_CONSUMING_PATH)
        candidates = ([d for d in same if d.configuration == configuration]
                      + [d for d in same if d.configuration != configuration
                         and (d.configuration is None or configuration is None)])
        if not candidates:
            raise _refuse(X.INVALID_CONFIGURATION_PATH)
        first: _Refused | None = None
        for entry in candidates:
            try:
                return self._admit_entry(entry, request, originator, now, connections, taken_ids)
            except _Refused as refused:
                first = first or refused
        raise first  # type: ignore[misc]

    def _admit_entry(self, entry: DeclaredConnection, request: ForwardOpenRequest, originator: Originator,
                     now: int, connections: Collection[Connection], taken_ids: Callable[[int], bool]) -> Connection:
        policy = self.policy
        o_t, t_o = request.o_t_parameters, request.t_o_parameters
        multicast = t_o.connection_type == ConnectionType.MULTICAST
        if o_t.connection_type != ConnectionType.POINT_TO_POINT or t_o.connection_type not in (
                ConnectionType.POINT_TO_POINT, ConnectionType.MULTICAST) or (
                multicast and not entry.t_o_multicast) or (not multicast and not entry.t_o_point_to_point):
            raise _refuse(X.INVALID_CONNECTION_TYPE)
        low, high = entry.rpi_us or (policy.rpi_min_us, policy.rpi_max_us)
        for rpi in (request.o_t_rpi, request.t_o_rpi):
            if not low <= rpi <= high:
                raise _refuse(X.RPI_NOT_SUPPORTED)
        expected = entry.wire_size("o_t")
        if entry.o_t_format == "heartbeat":
            fits = o_t.size in (SEQUENCE_COUNT_SIZE, SEQUENCE_COUNT_SIZE + RUN_IDLE_HEADER_SIZE)
        else:
            header = SEQUENCE_COUNT_SIZE + (RUN_IDLE_HEADER_SIZE if entry.o_t_format == "run/idle" else 0)
            fits = o_t.size == expected or (o_t.variable and header <= o_t.size <= expected)
        if not fits:
            raise _refuse(X.INVALID_O_T_SIZE, expected)
        expected_t_o = entry.wire_size("t_o")
        if t_o.size != expected_t_o:  # T->O sends whole images: the size must hold one
            raise _refuse(X.INVALID_T_O_SIZE, expected_t_o)
        data = [s.data for s in _data_segments(request.connection_path)]
        configuration_data = data[0] if data else None
        if configuration_data and len(configuration_data) != entry.configuration_size:
            raise _refuse(X.INVALID_CONFIGURATION_PATH)  # data for another configuration than the EDS's
        kind = entry.kind
        io_connections = [c for c in connections if c.is_io]
        if kind is ConnectionKind.EXCLUSIVE_OWNER and not entry.shared_owner and any(
                c.kind is ConnectionKind.EXCLUSIVE_OWNER and c.o_t_point == entry.o_t for c in io_connections):
            raise _refuse(X.OWNERSHIP_CONFLICT)
        shared = next((c for c in io_connections if c.multicast and c.t_o_point == entry.t_o
                       and c.kind is not ConnectionKind.LISTEN_ONLY), None) if multicast else None
        if kind is ConnectionKind.LISTEN_ONLY and shared is None:
            raise _refuse(X.NON_LISTEN_ONLY_NOT_OPENED)
        if shared is not None and (shared.t_o_rpi != request.t_o_rpi or shared.t_o_size != t_o.size):
            raise _refuse(X.RPI_NOT_SUPPORTED if shared.t_o_rpi != request.t_o_rpi else X.INVALID_T_O_SIZE,
                          None if shared.t_o_rpi != request.t_o_rpi else shared.t_o_size)
        if len(io_connections) >= policy.max_class1_connections:
            raise _refuse(X.OUT_OF_CONNECTIONS)
        if multicast:
            t_o_id = shared.t_o_id if shared else self._new_connection_id(taken_ids)
            t_o_address = (policy.multicast_group, IO_PORT)
        else:
            t_o_id = request.t_o_connection_id
            t_o_address = self._point_to_point_address(originator)
        return Connection(
            kind=kind, triad=request.triad, o_t_id=self._new_connection_id(taken_ids), t_o_id=t_o_id,
            o_t_rpi=request.o_t_rpi, t_o_rpi=request.t_o_rpi, timeout_multiplier=request.timeout_multiplier,
            originator_host=originator.host, opened_at=now, first_watchdog_ns=policy.first_watchdog_ns,
            t_o_address=t_o_address, multicast=multicast, o_t_point=entry.o_t, t_o_point=entry.t_o,
            o_t_run_idle_header=entry.o_t_format == "run/idle",
            o_t_modeless=entry.o_t_format in ("modeless", "zero length") and entry.o_t_size > 0,
            t_o_run_idle_header=entry.t_o_format == "run/idle", t_o_heartbeat=entry.t_o_format == "heartbeat",
            o_t_variable=o_t.variable, o_t_size=o_t.size, t_o_size=t_o.size,
            configuration_data=configuration_data if entry.configuration is not None else None,
        )

    @staticmethod
    def _point_to_point_address(originator: Originator) -> tuple[str, int]:
        """Where point-to-point T->O goes: always the originator's own address (so a Forward Open
        cannot aim the device's packets at a third host), to the port of its T->O socket-address
        item when it gives one (Vol. 2, 3-3.9.4), else 2222."""
        address = originator.t_o_sockaddr
        port = address.port if address is not None and address.family == socket.AF_INET and address.port else IO_PORT
        return originator.host, port

    def _admit_explicit(self, request: ForwardOpenRequest, originator: Originator, now: int,
                        connections: Collection[Connection], taken_ids: Callable[[int], bool]) -> Connection:
        segments = self._path_segments(request.connection_path)
        if segments != [LogicalSegment(LogicalType.CLASS_ID, ClassCode.MESSAGE_ROUTER),
                        LogicalSegment(LogicalType.INSTANCE_ID, 1)]:
            raise _refuse(X.INVALID_SEGMENT)
        if (request.o_t_parameters.connection_type != ConnectionType.POINT_TO_POINT
                or request.t_o_parameters.connection_type != ConnectionType.POINT_TO_POINT):
            raise _refuse(X.INVALID_CONNECTION_TYPE)
        policy = self.policy
        for rpi in (request.o_t_rpi, request.t_o_rpi):  # RPI 0 included: the timeout would be 0
            if not policy.class3_rpi_min_us <= rpi <= policy.class3_rpi_max_us:
                raise _refuse(X.RPI_NOT_SUPPORTED)
        if sum(not c.is_io for c in connections) >= policy.max_class3_connections:
            raise _refuse(X.OUT_OF_CONNECTIONS)
        return Connection(
            kind=ConnectionKind.EXPLICIT, triad=request.triad, o_t_id=self._new_connection_id(taken_ids),
            t_o_id=request.t_o_connection_id, o_t_rpi=request.o_t_rpi, t_o_rpi=request.t_o_rpi,
            timeout_multiplier=request.timeout_multiplier, originator_host=originator.host, opened_at=now,
            owner=originator.session, o_t_size=request.o_t_parameters.size, t_o_size=request.t_o_parameters.size,
        )
