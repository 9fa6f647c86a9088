"""Admission of a SafetyOpen: a Forward Open whose connection path carries a safety network
segment (CIP Networks Library Vol. 5, 3-5.3 and 3-5.4; the order of checks and the extended
statuses are those of table 3-5.33 of Vol. 1 extended by Vol. 5, as the HMS CIP Safety target
stack applies them): CPCRC, TUNID, duplicate, electronic key, connection parameters (transport,
network parameters, sizes, RPIs, safety parameters), application paths, SCID, ownership, limits.

Type 1 and Type 2 SafetyOpen (Vol. 5, chapter 3): a Type 1 carries the safety configuration in a data
segment before the safety segment and configures the target: its SCID must be non-zero with an
SCCRC equal to CRC-S4 over the configuration data (else 0x080C), the target must not be owned by
another originator (CFUNID other than the OUNID: 0x0105), and a configuration other than the one
held cannot be applied while other safety connections are open (0x080F). Admitted, the OUNID becomes
the configuration owner (CFUNID) and the SCID and data are stored. A Type 2 (no data) configures
nothing: a non-zero SCID must equal the one held (0x080C); a zero SCID asks for no check.

Two connection types (transport type/trigger, class 0, application triggered):
0xA0 "server": the target consumes safe outputs O->T and answers with time coordination T->O
(single-cast: max consumer number 1);
0x20 "client": the target produces safe inputs T->O and consumes time coordination O->T, single-cast
or multicast (T->O multicast, max consumer number 1..15, the time correction appended to each data
message: time correction network parameters 0; the time correction EPI and connection id are not
checked). A multicast client SafetyOpen for a point already produced joins that producer (same
T->O connection id, group and Safety Validator instance) when its ping interval EPI multiplier
(0x0815), max consumer number (0x0816), format (0x0817) and RPIs (0x0112, with the producer's RPIs)
match, and gets the lowest free consumer number; none free: general status 0x02, no extended
status (as the HMS target stack answers). protocol/safety/multicast.py produces it.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Collection
from dataclasses import dataclass, field

from enip_farm.cip.connection import Connection, ConnectionKind
from enip_farm.cip.connection_path import assembly_points
from enip_farm.cip.connection_policy import Refusal, SafetyOpen
from enip_farm.cip.safety.state import SafetyState
from enip_farm.protocol.connection import ConnectionType, ForwardOpenRequest, NetworkParameters, encode_forward_open
from enip_farm.protocol.epath import DataSegment, ElectronicKey, SafetyNetworkSegment
from enip_farm.protocol.safety.crc import Seeds, crc_s4
from enip_farm.protocol.safety.messages import TCOO_SIZE, TIME_CORRECTION_SIZE, data_length, wire_size
from enip_farm.protocol.safety.multicast import MAX_CONSUMERS, MulticastProducer
from enip_farm.protocol.safety.segment import (
    NOT_USED,
    TIME_CORRECTION_NOT_USED,
    SafetySegment,
    SegmentError,
    Unid,
    compute_cpcrc,
    decode_segment,
)
from enip_farm.protocol.safety.validator import SafetyConsumer, SafetyProducer
from enip_farm.protocol.status import ExtendedStatus as X
from enip_farm.protocol.status import GeneralStatus

SERVER, CLIENT = 0xA0, 0x20  # transport type/trigger of a safety connection (Vol. 5, 3-5.4)
_HIGH, _SCHEDULED = 1, 2  # network connection priority of a safety connection
_MAX_PIEM = 999
_MAX_TCOO_MIN_MULTIPLIER = 7813  # 1 s in 128 us ticks
_MAX_NTE_MULTIPLIER = 45313  # 5.8 s
_MAX_CONNECTION_TIMEOUT_MULTIPLIER = 7
_MIN_RPI_US, _MAX_RPI_BASE_US, _MAX_RPI_EXTENDED_US = 1_000, 100_000, 1_000_000
_MAX_RPI_TCOO_US = 10_000_000
_REQUIRED = 4  # acceptable RPI type of extended status 0x0112: the RPI required


@dataclass(frozen=True)
class SafetyPolicy:
    """What a safety target is: its identity for the CRC seeds, its TUNID and SCID, its safety
    assemblies (the same instances as its output and input images) and its limits."""

    vendor_id: int
    serial_number: int
    tunid: Unid
    scid: bytes  # SCCRC + SCTS; all zero: no configuration signature is held
    output_point: int  # consumed by server connections (the safe outputs)
    input_point: int  # produced by client connections (the safe inputs)
    configuration_point: int
    null_point: int  # the connection point a server does not produce / a client does not consume
    max_connections: int = 8
    #: the TUNID, SCID and configuration owner as they stand (the Safety Supervisor changes them);
    #: `tunid` and `scid` above are the configured, initial values
    state: SafetyState = field(default=None, compare=False)  # type: ignore[assignment]

    def __post_init__(self) -> None:
        if self.state is None:
            object.__setattr__(self, "state", SafetyState(self.tunid, self.scid))

    @property
    def tunid_set(self) -> bool:
        return self.state.tunid_set

    def admit(self, request: ForwardOpenRequest, segments: list, route_size: int,
              check_key: Callable[[ElectronicKey], None], sizes: tuple[int, int], originator_host: str,
              t_o_address: tuple[str, int], now: int, connections: Collection[Connection],
              new_id: Callable[[], int], first_watchdog_ns: int, initial_rc_offset: int,
              multicast_address: tuple[str, int]) -> SafetyOpen | Refusal:
        """A SafetyOpen admitted, or refused (cip/connection_policy.py's `SafetyTarget` says what the
        arguments are; `t_o_address`: where single-cast T->O goes, `multicast_address` multicast)."""
        policy = self
        used = {c.instance for c in connections if c.safety is not None}  # the Safety Validator instances

        def instance_id() -> int:
            return next(i for i in range(1, len(used) + 2) if i not in used)

        raw = safety_segment_of(segments)
        assert raw is not None
        application = segments[:segments.index(raw)]
        configuration_data = None
        if application and isinstance(application[-1], DataSegment):  # a Type 1 SafetyOpen
            configuration_data = application.pop().data
        try:
            segment = decode_segment(raw.raw)
        except SegmentError as error:
            return Refusal(X.INVALID_SAFETY_FORMAT if error.format_error else X.INVALID_SEGMENT)
        if segments[-1] is not raw:
            return Refusal(X.INVALID_SEGMENT)  # nothing may follow the safety segment
        application_path = request.connection_path[route_size:len(request.connection_path) - len(raw.raw)]
        fixed = encode_forward_open(request._replace(connection_path=b""))
        fixed = fixed[:-1] + bytes(((len(application_path) + len(raw.raw)) // 2,))
        if compute_cpcrc(fixed, application_path, raw.raw) != segment.cpcrc:
            return Refusal(X.INVALID_CPCRC)
        if not policy.tunid_set:
            return Refusal(X.TUNID_NOT_SET)
        state = policy.state
        if segment.tunid != state.tunid:
            return Refusal(X.TUNID_MISMATCH)
        if any(c.triad == request.triad for c in connections):
            return Refusal(X.CONNECTION_IN_USE)
        if application and isinstance(application[0], ElectronicKey):
            check_key(application.pop(0))
        refusal = _parameters(request, segment, sizes)
        if refusal is not None:
            return refusal
        server = request.transport_type_trigger == SERVER
        points = assembly_points(application)
        if points is None or points[0] is None:
            return Refusal(X.INVALID_SEGMENT)
        configuration, consuming, producing = points
        if configuration not in (policy.configuration_point, policy.null_point):
            return Refusal(X.INVALID_CONFIGURATION_PATH)
        if server:
            if producing != policy.null_point:
                return Refusal(X.INVALID_PRODUCING_PATH)
            if consuming != policy.output_point:
                return Refusal(X.INVALID_CONSUMING_PATH)
        else:
            if consuming != policy.null_point:
                return Refusal(X.INVALID_CONSUMING_PATH)
            if producing != policy.input_point:
                return Refusal(X.INVALID_PRODUCING_PATH)
        safety = [c for c in connections if c.safety is not None]
        if configuration_data is not None:
            if configuration != policy.configuration_point:
                return Refusal(X.INVALID_CONFIGURATION_PATH)
            if state.cfunid is not None and state.cfunid != segment.ounid:
                return Refusal(X.CONFIGURATION_OWNED)
            if not any(segment.scid) or crc_s4(configuration_data) != segment.sccrc:
                return Refusal(X.SCID_MISMATCH)
            if segment.scid != state.scid and safety:
                return Refusal(X.CONFIGURATION_OPERATION_NOT_ALLOWED)
        elif any(segment.scid) and segment.scid != state.scid:
            return Refusal(X.SCID_MISMATCH)
        if server and any(c.kind is ConnectionKind.SAFETY_OUTPUT for c in safety):
            return Refusal(X.OWNERSHIP_CONFLICT)  # one owner of the safe outputs
        multicast = is_multicast(request)
        shared = next((c for c in safety if c.multicast and c.t_o_point == producing), None) if multicast else None
        if shared is not None:
            refusal = _join_refusal(shared, request, segment)
            if refusal is not None:
                return refusal
        elif len({c.instance for c in safety}) >= policy.max_connections:  # Safety Validator instances
            return Refusal(X.OUT_OF_CONNECTIONS)
        originator = Seeds.of(request.triad.originator_vendor_id, request.triad.originator_serial,
                              request.triad.connection_serial)
        if multicast:
            return _multicast(request, segment, shared, policy, sizes[1], originator, consuming, producing,
                              originator_host, multicast_address, now, new_id, instance_id, first_watchdog_ns,
                              configuration_data)
        if configuration_data is not None:  # admitted: the originator owns the configuration
            state.configure(segment.ounid, segment.scid, configuration_data)

        instance = instance_id()
        target = Seeds.of(policy.vendor_id, policy.serial_number, instance)
        if server:
            validator: SafetyConsumer | SafetyProducer = SafetyConsumer(
                segment, sizes[0], pid=originator, cid=target, now=now, first_watchdog_ns=first_watchdog_ns,
                initial_rc_offset=initial_rc_offset)
            initial = (validator.initial_timestamp, validator.initial_rollover)
        else:
            validator = SafetyProducer(segment, sizes[1], pid=target, cid=originator, epi_ns=request.t_o_rpi * 1000,
                                       now=now, first_watchdog_ns=first_watchdog_ns)
            initial = (segment.initial_timestamp, segment.initial_rollover_value)
        # application reply (Vol. 5, 3-5.4.2): consumer number (0xFFFF: single-cast), target vendor id,
        # serial number and connection serial number (the Safety Validator instance); extended format:
        # initial timestamp and initial rollover value
        reply = _application_reply(0xFFFF, policy, instance, initial if segment.extended else None)
        connection = Connection(
            kind=ConnectionKind.SAFETY_OUTPUT if server else ConnectionKind.SAFETY_INPUT, triad=request.triad,
            o_t_id=new_id(), t_o_id=request.t_o_connection_id, o_t_rpi=request.o_t_rpi, t_o_rpi=request.t_o_rpi,
            timeout_multiplier=request.timeout_multiplier, originator_host=originator_host, opened_at=now,
            first_watchdog_ns=first_watchdog_ns, t_o_address=t_o_address, o_t_point=consuming, t_o_point=producing,
            o_t_run_idle_header=False, safety=validator, instance=instance, ounid=segment.ounid,
        )
        return SafetyOpen(connection, reply)


def safety_segment_of(segments: list) -> SafetyNetworkSegment | None:
    return next((s for s in segments if isinstance(s, SafetyNetworkSegment)), None)


def _application_reply(consumer_number: int, policy: SafetyPolicy, instance: int,
                       initial: tuple[int, int] | None) -> bytes:
    """Vol. 5, 3-5.4.2: consumer number (0xFFFF: single-cast), target vendor id, serial number and
    connection serial number (the Safety Validator instance); extended format: initial timestamp
    and initial rollover value."""
    reply = struct.pack("<HHIH", consumer_number, policy.vendor_id, policy.serial_number, instance)
    return reply + (struct.pack("<HH", *initial) if initial is not None else b"")


def _join_refusal(shared: Connection, request: ForwardOpenRequest, segment: SafetySegment) -> Refusal | None:
    """A multicast SafetyOpen joining a producer must ask for what it produces (the checks and
    statuses of the HMS target stack): ping interval EPI multiplier, max consumer number, format,
    then the RPIs (0x0112 with the acceptable RPI types, 4 = required, and the producer's RPIs)."""
    producer = shared.safety.producer  # type: ignore[union-attr]
    if segment.ping_interval_epi_multiplier != producer.ping_interval_epi_multiplier:
        return Refusal(X.MULTICAST_PING_INTERVAL_EPI_MULTIPLIER)
    if segment.max_consumer_number != producer.max_consumers:
        return Refusal(X.MULTICAST_MAX_CONSUMER_NUMBER)
    if segment.extended != producer.extended:
        return Refusal(X.MULTICAST_SAFETY_FORMAT)
    if (request.o_t_rpi, request.t_o_rpi) != (shared.o_t_rpi, shared.t_o_rpi):
        types = (_REQUIRED if request.o_t_rpi != shared.o_t_rpi else 0) | (
            _REQUIRED << 8 if request.t_o_rpi != shared.t_o_rpi else 0)
        return Refusal(X.RPI_NOT_ACCEPTABLE, more=(types, *struct.unpack("<HHHH", struct.pack(
            "<II", shared.o_t_rpi, shared.t_o_rpi))))
    return None


def _multicast(request: ForwardOpenRequest, segment: SafetySegment, shared: Connection | None, policy: SafetyPolicy,
               length: int, originator: Seeds, consuming: int, producing: int, originator_host: str,
               address: tuple[str, int], now: int, new_id: Callable[[], int], instance_id: Callable[[], int],
               first_watchdog_ns: int, configuration_data: bytes | None) -> SafetyOpen | Refusal:
    """A consumer of the multicast producer of the safe inputs: a new producer, or `shared`'s."""
    if shared is not None:
        producer, instance, t_o_id = shared.safety.producer, shared.instance, shared.t_o_id  # type: ignore[union-attr]
    else:
        instance, t_o_id = instance_id(), new_id()
        producer = MulticastProducer(segment, length, Seeds.of(policy.vendor_id, policy.serial_number, instance),
                                     request.t_o_rpi * 1000, now, first_watchdog_ns)
    consumer = producer.join(segment, originator, now)
    if consumer is None:  # every consumer number taken
        return Refusal(None, general=GeneralStatus.RESOURCE_UNAVAILABLE)
    if configuration_data is not None:
        policy.state.configure(segment.ounid, segment.scid, configuration_data)
    reply = _application_reply(consumer.number, policy, instance, producer.initial_values if segment.extended else None)
    connection = Connection(
        kind=ConnectionKind.SAFETY_INPUT, triad=request.triad, o_t_id=new_id(), t_o_id=t_o_id, o_t_rpi=request.o_t_rpi,
        t_o_rpi=request.t_o_rpi, timeout_multiplier=request.timeout_multiplier, originator_host=originator_host,
        opened_at=now, first_watchdog_ns=first_watchdog_ns, t_o_address=address, multicast=True, o_t_point=consuming,
        t_o_point=producing, o_t_run_idle_header=False, safety=consumer, instance=instance, ounid=segment.ounid,
    )
    return SafetyOpen(connection, reply)


def _network_ok(p: NetworkParameters, size: int | None, multicast: bool = False) -> bool:
    """Point to point (a multicast client's data: multicast), high or scheduled priority, fixed
    size (Vol. 5, 3-5.4.1)."""
    kind = ConnectionType.MULTICAST if multicast else ConnectionType.POINT_TO_POINT
    return (p.connection_type == kind and p.priority in (_HIGH, _SCHEDULED)
            and not p.variable and not p.redundant_owner and (size is None or p.size == size))


def is_multicast(request: ForwardOpenRequest) -> bool:
    """A client SafetyOpen whose safe input data goes T->O multicast."""
    return (request.transport_type_trigger == CLIENT
            and request.t_o_parameters.connection_type == ConnectionType.MULTICAST)


def _parameters(request: ForwardOpenRequest, segment: SafetySegment, sizes: tuple[int, int]) -> Refusal | None:
    """Connection and safety parameters (Vol. 5, 3-5.4.1), in the order a target checks them."""
    if request.timeout_multiplier > _MAX_CONNECTION_TIMEOUT_MULTIPLIER:
        return Refusal(X.INVALID_SAFETY_TIMEOUT_MULTIPLIER)
    transport = request.transport_type_trigger
    if transport not in (SERVER, CLIENT):
        return Refusal(X.TRANSPORT_TRIGGER_NOT_SUPPORTED)
    server = transport == SERVER
    multicast = is_multicast(request)
    data, tcoo = (request.o_t_parameters, request.t_o_parameters) if server else (
        request.t_o_parameters, request.o_t_parameters)
    if not _network_ok(data, None, multicast) or not _network_ok(tcoo, TCOO_SIZE):
        return Refusal(X.INVALID_CONNECTION_TYPE)
    if segment.time_correction_parameters != 0:  # multicast too: no separate time correction connection
        return Refusal(X.INVALID_TIME_CORRECTION_PARAMETERS)
    appended = TIME_CORRECTION_SIZE if multicast else 0  # each multicast data message ends with one
    length = data_length(data.size - appended)
    if length is None:
        return Refusal(X.INVALID_SAFETY_CONNECTION_SIZE)
    expected = sizes[0] if server else sizes[1]
    if length != expected:
        return Refusal(X.INVALID_O_T_SIZE if server else X.INVALID_T_O_SIZE, wire_size(expected) + appended)
    data_rpi, tcoo_rpi = (request.o_t_rpi, request.t_o_rpi) if server else (request.t_o_rpi, request.o_t_rpi)
    max_rpi = _MAX_RPI_EXTENDED_US if segment.extended else _MAX_RPI_BASE_US
    if not (_MIN_RPI_US <= data_rpi <= max_rpi and _MIN_RPI_US <= tcoo_rpi <= _MAX_RPI_TCOO_US):
        return Refusal(X.RPI_NOT_SUPPORTED)
    if segment.time_correction_epi != 0 and not multicast:
        return Refusal(X.MISCELLANEOUS)
    piem_min = min(segment.timeout_multiplier, 4) * segment.max_consumer_number + MAX_CONSUMERS
    if not piem_min <= segment.ping_interval_epi_multiplier <= _MAX_PIEM or (
            data_rpi * segment.ping_interval_epi_multiplier > 100_000_000):
        return Refusal(X.INVALID_PING_INTERVAL_EPI_MULTIPLIER)
    if segment.time_coord_msg_min_multiplier > _MAX_TCOO_MIN_MULTIPLIER:
        return Refusal(X.INVALID_TIME_COORD_MSG_MIN_MULTIPLIER)
    if not 1 <= segment.network_time_expectation_multiplier <= _MAX_NTE_MULTIPLIER:
        return Refusal(X.INVALID_NETWORK_TIME_EXPECTATION_MULTIPLIER)
    if segment.timeout_multiplier < 1 or (not segment.extended and segment.timeout_multiplier > 4):
        return Refusal(X.INVALID_SAFETY_TIMEOUT_MULTIPLIER)
    if not 1 <= segment.max_consumer_number <= (MAX_CONSUMERS if multicast else 1):
        return Refusal(X.INVALID_MAX_CONSUMER_NUMBER)
    if not multicast and segment.time_correction_connection_id != TIME_CORRECTION_NOT_USED:
        return Refusal(X.INVALID_TIME_CORRECTION_CONNECTION_ID)
    if segment.extended:
        if segment.max_fault_number > 255:
            return Refusal(X.MISCELLANEOUS)
        if (server or multicast) and (segment.initial_timestamp, segment.initial_rollover_value) != (
                NOT_USED, NOT_USED):  # the producer of a multicast picks them
            return Refusal(X.PARAMETER_ERROR)
    return None
