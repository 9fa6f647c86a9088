"""Admission of a Forward Open or Large Forward Open (CIP Networks Library Vol. 1, 3-5.5.2 and
table 3-5.33): connection path, electronic key (C-1.4.2), transport class and trigger, connection
types, RPI, sizes, ownership and limits; a SafetyOpen (a safety network segment in the path) goes
to the device's safety target if it is one (`SafetyTarget`: cip/safety/admission.py, Vol. 5).
Each refusal carries its extended status and, for sizes, the size the target expects as a second
additional status word (as OpENer sends it). Sans-IO: the time is a parameter; nothing here is
changed, the connection table keeps what is admitted.
"""

from __future__ import annotations

import random
import socket
from collections.abc import Callable, Collection, Mapping
from typing import Any, NamedTuple

from enip_farm.cip.assembly import AssemblyInstance
from enip_farm.cip.connection import Connection, ConnectionKind
from enip_farm.cip.connection_path import (
    KeyIdentity,
    application_segments,
    assembly_points,
    data_segments,
    key_mismatch,
    strip_route,
)
from enip_farm.cip.connection_policy import (
    RUN_IDLE_HEADER_SIZE,
    SEQUENCE_COUNT_SIZE,
    ConnectionPolicy,
    DeclaredConnection,
    Refusal,
    SafetyOpen,
)
from enip_farm.protocol.cip import ClassCode
from enip_farm.protocol.commands import SocketAddress
from enip_farm.protocol.connection import IO_PORT, ConnectionType, ForwardOpenRequest
from enip_farm.protocol.epath import (
    DataSegment,
    ElectronicKey,
    LogicalSegment,
    LogicalType,
    PathError,
    SafetyNetworkSegment,
    decode_epath,
)
from enip_farm.protocol.status import ExtendedStatus as X

_CLASS_1, _CLASS_3 = 0x01, 0x03
_MAX_TIMEOUT_MULTIPLIER = 7  # x512; 8-255 are reserved (Vol. 1, 3-5.4.1.4)


class Originator(NamedTuple):
    """Where a Forward Open came from: its host, the T->O socket address item it carried (if any),
    and the encapsulation session (class-3 connections belong to it)."""

    host: str
    t_o_sockaddr: SocketAddress | None = None
    session: object | None = None


def _check_connection_types(request: ForwardOpenRequest, multicast: bool = True, p2p: bool = True) -> None:
    """O->T point to point; T->O point to point or multicast, as allowed."""
    t_o = request.t_o_parameters.connection_type
    if request.o_t_parameters.connection_type != ConnectionType.POINT_TO_POINT or not (
            (t_o == ConnectionType.MULTICAST and multicast) or (t_o == ConnectionType.POINT_TO_POINT and p2p)):
        raise _refuse(X.INVALID_CONNECTION_TYPE)


def _check_rpis(request: ForwardOpenRequest, low: int, high: int) -> None:
    if not (low <= request.o_t_rpi <= high and low <= request.t_o_rpi <= high):
        raise _refuse(X.RPI_NOT_SUPPORTED)


def _check_o_t_size(request: ForwardOpenRequest, expected: int, header: int | None) -> None:
    """The O->T size: `expected`, or with a variable size at least the `header`; a heartbeat
    (`header` None) carries the sequence count and, optionally, the run/idle header."""
    size = request.o_t_parameters.size
    if header is None:
        fits = size in (SEQUENCE_COUNT_SIZE, SEQUENCE_COUNT_SIZE + RUN_IDLE_HEADER_SIZE)
    else:
        fits = size == expected or (request.o_t_parameters.variable and header <= size <= expected)
    if not fits:
        raise _refuse(X.INVALID_O_T_SIZE, expected)


def _check_t_o_size(request: ForwardOpenRequest, expected: int) -> None:
    if request.t_o_parameters.size != expected:  # T->O sends whole images: the size must hold one
        raise _refuse(X.INVALID_T_O_SIZE, expected)


class _Refused(Exception):
    def __init__(self, refusal: Refusal) -> None:
        super().__init__(refusal.additional_status)
        self.refusal = refusal


def _refuse(extended: int, expected_size: int | None = None) -> _Refused:
    return _Refused(Refusal(extended, expected_size))


class Admission:
    """The checks of one device: its assemblies, its policy and its identity (for keys)."""

    def __init__(self, assemblies: Mapping[str, AssemblyInstance], policy: ConnectionPolicy,
                 identity: Callable[[], KeyIdentity], rng: random.Random | None = None,
                 sizes: Callable[[str, int], int] | None = None) -> None:
        self.assemblies = assemblies
        self.policy = policy
        self.identity = identity
        #: The data size of an assembly ("input", "output") a Forward Open is checked against, from
        #: its own (another module plugged in has others); None: the assemblies' own.
        self.sizes = sizes
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
        """A SafetyOpen (a path with a safety network segment) admitted by the device's safety
        target; None for any other Forward Open. A device that is no safety target refuses it (0x0315)."""
        if 0x50 not in request.connection_path:
            return None
        try:
            segments = decode_epath(request.connection_path)
        except PathError:
            raise _refuse(X.INVALID_SEGMENT) from None
        route = strip_route(segments)
        if not any(isinstance(s, SafetyNetworkSegment) for s in segments):
            return None
        target = self.policy.safety
        if target is None:
            raise _refuse(X.INVALID_SEGMENT)
        output, inputs = self.assemblies["output"], self.assemblies["input"]
        self._initial_rc_offset = (self._initial_rc_offset + 1) & 0xFFFF
        result = target.admit(
            request, segments, route, self._check_key, (len(output.data), len(inputs.data)), originator.host,
            self._point_to_point_address(originator), now, connections, lambda: self._new_connection_id(taken_ids),
            self.policy.first_watchdog_ns, self._initial_rc_offset, (self.policy.multicast_group, IO_PORT))
        if type(result) is Refusal:
            raise _Refused(result)
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
        if request.o_t_parameters.connection_type == request.t_o_parameters.connection_type == ConnectionType.NULL:
            raise _refuse(X.NULL_FORWARD_OPEN_NOT_SUPPORTED)
        transport = request.transport_class
        if transport == _CLASS_3 and request.transport_type_trigger & 0x80:
            return self._admit_explicit(request, originator, now, connections, taken_ids)
        if transport != _CLASS_1 or request.production_trigger != 0 or self.policy.safety is not None:
            raise _refuse(X.TRANSPORT_TRIGGER_NOT_SUPPORTED)  # class 1 cyclic; a safety target: SafetyOpens only
        segments = self._path_segments(request.connection_path)
        points = assembly_points([s for s in segments if not isinstance(s, DataSegment)])
        if points is None:
            raise _refuse(X.INVALID_SEGMENT)
        return self._admit_io(request, points, originator, now, connections, taken_ids)

    def _check_key(self, key: ElectronicKey) -> None:
        mismatch = key_mismatch(key, self.identity())
        if mismatch is not None:
            raise _refuse(mismatch)

    def _path_segments(self, connection_path: bytes) -> list:
        segments = application_segments(connection_path, self.identity())
        if isinstance(segments, int):
            raise _refuse(segments)
        return segments  # type: ignore[return-value]

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
        _check_connection_types(request)
        _check_rpis(request, policy.rpi_min_us, policy.rpi_max_us)
        # O->T: sequence count, 32-bit run/idle header, data; heartbeats carry no data (header optional).
        owner = kind is ConnectionKind.EXCLUSIVE_OWNER
        sized = self.sizes or (lambda role, size: size)
        header = SEQUENCE_COUNT_SIZE + RUN_IDLE_HEADER_SIZE
        _check_o_t_size(request, header + sized("output", len(output.data)) if owner  # type: ignore[union-attr]
                        else SEQUENCE_COUNT_SIZE, header if owner else None)
        _check_t_o_size(request, SEQUENCE_COUNT_SIZE + sized("input", len(inputs.data)))  # modeless
        return self._open_io(request, originator, now, connections, taken_ids, kind, consuming, producing,
                             o_t_run_idle_header=owner)

    def _open_io(self, request: ForwardOpenRequest, originator: Originator, now: int,
                 connections: Collection[Connection], taken_ids: Callable[[int], bool], kind: ConnectionKind,
                 consuming: int, producing: int, shared_owner: bool = False, same_t_o_size: bool = False,
                 **fields: Any) -> Connection:
        """A class-1 connection whose points, types, RPIs and sizes passed: ownership of the
        consumed point, a multicast T->O shared with the connections producing it already (same
        RPI; with `same_t_o_size` the same size), listen-only, the limit; then the connection."""
        policy = self.policy
        o_t, t_o = request.o_t_parameters, request.t_o_parameters
        io_connections = [c for c in connections if c.is_io]
        if kind is ConnectionKind.EXCLUSIVE_OWNER and not shared_owner and any(
                c.kind is ConnectionKind.EXCLUSIVE_OWNER and c.o_t_point == consuming for c in io_connections):
            raise _refuse(X.OWNERSHIP_CONFLICT)
        multicast = t_o.connection_type == ConnectionType.MULTICAST
        shared = next((c for c in io_connections if c.multicast and c.t_o_point == producing
                       and c.kind is not ConnectionKind.LISTEN_ONLY), None) if multicast else None
        if kind is ConnectionKind.LISTEN_ONLY and shared is None:
            raise _refuse(X.NON_LISTEN_ONLY_NOT_OPENED)
        if shared is not None and shared.t_o_rpi != request.t_o_rpi:
            raise _refuse(X.RPI_NOT_SUPPORTED)
        if shared is not None and same_t_o_size and shared.t_o_size != t_o.size:
            raise _refuse(X.INVALID_T_O_SIZE, shared.t_o_size)
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
            o_t_variable=o_t.variable, o_t_size=o_t.size, t_o_size=t_o.size, **fields,
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
        _check_connection_types(request, entry.t_o_multicast, entry.t_o_point_to_point)
        _check_rpis(request, *(entry.rpi_us or (self.policy.rpi_min_us, self.policy.rpi_max_us)))
        _check_o_t_size(request, entry.wire_size("o_t"), None if entry.o_t_format == "heartbeat" else
                        SEQUENCE_COUNT_SIZE + (RUN_IDLE_HEADER_SIZE if entry.o_t_format == "run/idle" else 0))
        _check_t_o_size(request, entry.wire_size("t_o"))
        data = data_segments(request.connection_path)
        configuration_data = data[0] if data else None
        if configuration_data and len(configuration_data) != entry.configuration_size:
            raise _refuse(X.INVALID_CONFIGURATION_PATH)  # data for another configuration than the EDS's
        return self._open_io(
            request, originator, now, connections, taken_ids, entry.kind, entry.o_t, entry.t_o,
            shared_owner=entry.shared_owner, same_t_o_size=True, o_t_run_idle_header=entry.o_t_format == "run/idle",
            o_t_modeless=entry.o_t_format in ("modeless", "zero length") and entry.o_t_size > 0,
            t_o_run_idle_header=entry.t_o_format == "run/idle", t_o_heartbeat=entry.t_o_format == "heartbeat",
            configuration_data=configuration_data if entry.configuration is not None else None)

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
