"""What a device accepts of a Forward Open (CIP Networks Library Vol. 1, 3-5.4 and 7-3.6.11),
built from its profile: limits and RPI ranges (`ConnectionPolicy`), the connections its EDS
declares (`DeclaredConnection`) and, for a CIP Safety target, what admits a SafetyOpen
(`SafetyTarget`: cip/safety/admission.py implements it; Vol. 5). And what an admission answers:
a `Refusal` with its extended status, or a `SafetyOpen` with its application reply.
"""

from __future__ import annotations

from collections.abc import Callable, Collection
from dataclasses import dataclass
from typing import NamedTuple, Protocol

from enip_farm.cip.connection import Connection, ConnectionKind
from enip_farm.protocol.connection import ForwardOpenRequest
from enip_farm.protocol.epath import ElectronicKey
from enip_farm.protocol.status import GeneralStatus

SEQUENCE_COUNT_SIZE = 2
RUN_IDLE_HEADER_SIZE = 4


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
    safety: SafetyTarget | None = None  # a CIP Safety target: SafetyOpens admitted, class-1 refused
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


class SafetyOpen(NamedTuple):
    """A SafetyOpen admitted: its connection and the application reply of its Forward Open reply."""

    connection: Connection
    application_reply: bytes


class SafetyTarget(Protocol):
    """A CIP Safety target's admission of a SafetyOpen (cip/safety/admission.py's SafetyPolicy).
    `segments`: the connection path after the route to this device (`route_size` bytes); `sizes`:
    the output and input images' sizes; `check_key` raises the admission's refusal for a key
    mismatch; `new_id()` a free connection id; `t_o_address` where single-cast T->O goes,
    `multicast_address` where multicast T->O goes."""

    def admit(self, request: ForwardOpenRequest, segments: list, route_size: int,
              check_key: Callable[[ElectronicKey], None], sizes: tuple[int, int], originator_host: str,
              t_o_address: tuple[str, int], now: int, connections: Collection[Connection],
              new_id: Callable[[], int], first_watchdog_ns: int, initial_rc_offset: int,
              multicast_address: tuple[str, int]) -> SafetyOpen | Refusal: ...


