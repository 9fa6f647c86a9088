"""Connections as the Connection Manager opens them (CIP Networks Library Vol. 1, 3-4 and 3-5):
class-1 I/O connections (exclusive owner, input only, listen only), class-3 explicit
connections and CIP Safety connections (Vol. 5, server and client), with their supervision
deadline (3-4.4.9) and their T->O production stream.

Times are integers in nanoseconds of a monotonic clock that the caller passes in.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum

from enip_farm.cip.budget import Reservation
from enip_farm.cip.o_t_measure import OriginatorMeasure
from enip_farm.protocol.connection import ConnectionTriad
from enip_farm.protocol.safety.multicast import MulticastConsumer, MulticastProducer
from enip_farm.protocol.safety.segment import Unid
from enip_farm.protocol.safety.validator import SafetyConsumer, SafetyProducer


class ConnectionKind(str, Enum):
    EXCLUSIVE_OWNER = "exclusive owner"
    INPUT_ONLY = "input only"
    LISTEN_ONLY = "listen only"
    EXPLICIT = "explicit (class 3)"
    SAFETY_OUTPUT = "safety output (server)"  # CIP Safety: the target consumes the safe outputs
    SAFETY_INPUT = "safety input (client)"  # CIP Safety: the target produces the safe inputs


@dataclass(eq=False)
class Connection:
    kind: ConnectionKind
    triad: ConnectionTriad
    o_t_id: int
    t_o_id: int
    o_t_rpi: int  # microseconds
    t_o_rpi: int
    timeout_multiplier: int
    originator_host: str
    opened_at: int  # ns
    first_watchdog_ns: int = 0  # the watchdog before the first packet is at least this long
    t_o_address: tuple[str, int] | None = None  # where T->O packets go (class 1)
    multicast: bool = False
    o_t_point: int | None = None
    t_o_point: int | None = None
    o_t_run_idle_header: bool = True
    o_t_modeless: bool = False  # O->T data without a run/idle header (an EDS's modeless or zero-length format)
    t_o_run_idle_header: bool = False  # T->O carries the 32-bit run/idle header (an EDS's format 4)
    t_o_heartbeat: bool = False  # T->O carries no data (an EDS's heartbeat format)
    configuration_data: bytes | None = None  # the Forward Open's data segment, for the configuration point
    o_t_variable: bool = False  # the originator may send less data than the assembly holds
    o_t_size: int = 0  # connection sizes from the Forward Open, bytes
    t_o_size: int = 0
    owner: object | None = None  # the encapsulation session of a class-3 connection
    last_received: int | None = None  # ns, the last valid packet consumed
    received: int = 0  # valid packets consumed
    last_sequence: int | None = None  # 32-bit sequence of the last O->T packet consumed
    o_t_port: int | None = None  # the UDP port O->T comes from: the first valid packet's, then only it
    run: bool = False
    short_data_reported: bool = False  # a variable-size O->T shorter than its assembly was reported once
    closed: bool = False
    last_reply: tuple[int, bytes, tuple] | None = None  # class 3: (sequence count, reply, items) for duplicates
    safety: SafetyConsumer | SafetyProducer | MulticastConsumer | None = None  # CIP Safety: its Safety Validator
    instance: int = 0  # CIP Safety: the Safety Validator instance id
    ounid: Unid | None = None  # CIP Safety: the originator's UNID
    t_o_sequence: int = 0  # CIP Safety server: the sequence of its time coordination messages
    reservation: Reservation | None = None  # what it holds of the I/O thread's budget (cip/budget.py)
    measure: OriginatorMeasure | None = None  # the originator's O->T stream measured (cip/o_t_measure.py)
    #: Connection timeout: O->T RPI x 2^(2 + multiplier) (Vol. 1, 3-4.4.9), ns; both are fixed at the Forward Open.
    timeout_ns: int = field(init=False)
    #: When the connection times out unless a valid packet arrives before: the first watchdog (from the
    #: Forward Open) until the first packet, then the last valid packet + the timeout; a CIP Safety
    #: connection's is its Safety Validator's. Moved on with each valid packet (cip/io_packets.py).
    deadline: int = field(init=False)

    def __post_init__(self) -> None:
        self.timeout_ns = self.o_t_rpi * 1000 << (2 + min(self.timeout_multiplier, 7))
        self.deadline = (self.safety.deadline if self.safety is not None
                         else self.opened_at + max(self.timeout_ns, self.first_watchdog_ns))

    @property
    def timeout(self) -> float:
        """The connection timeout in seconds."""
        return self.timeout_ns / 1e9

    @property
    def is_io(self) -> bool:
        return self.kind is not ConnectionKind.EXPLICIT


@dataclass(eq=False)
class Production:
    """One T->O stream: packet n is due at start + n x period (absolute deadlines, no drift). A T->O
    connection id shared by several multicast connections is one stream."""

    connection_id: int
    address: tuple[str, int]
    period_ns: int
    start: int
    count: int = 0  # packets due so far
    sequence: int = 0
    users: int = 1
    late: int = 0  # periods skipped because the producer fell a whole period behind
    safety: SafetyProducer | MulticastProducer | None = None  # CIP Safety client: encodes each packet (class 0)
    point: int | None = None  # the produced assembly (an EDS's connections); None: the input assembly
    header: bytes = b""  # the 32-bit run/idle header before the data (an EDS's T->O format 4)
    heartbeat: bool = False  # no data, the sequence count only (an EDS's heartbeat format)
    due: int = field(init=False)  # when the next packet is due: start + count x period

    def __post_init__(self) -> None:
        self.due = self.start + self.count * self.period_ns
