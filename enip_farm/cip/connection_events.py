"""What a connection table reports (CIP Networks Library Vol. 1, 3-4 and 3-5; Vol. 5, 2-4), in
the style of aioquic's `quic/events.py`: one frozen class per kind, with typed fields and the time
it happened (`at`, integer nanoseconds of the caller's monotonic clock). A consumer matches on the
class, never on text.

The text the event log, the HTTP API, the SSE stream and the dashboard show is made here and only
here: `kind` (a class constant, the wire's "kind") and `text` (the wire's "detail").
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import ClassVar

from enip_farm.cip.admission import Originator
from enip_farm.cip.connection import Connection
from enip_farm.cip.connection_policy import Refusal
from enip_farm.cip.report import EndWord
from enip_farm.protocol.connection import ForwardOpenRequest
from enip_farm.protocol.status import describe_status


@dataclass(frozen=True, slots=True)
class Worded:
    """The base of a typed event (these and device/events.py's): the wire's `kind`, given by each
    class (`class X(Base, kind="...")`), and its `text`."""

    kind: ClassVar[str] = ""

    def __init_subclass__(cls, kind: str = "") -> None:
        if kind:  # (no super(): dataclass(slots=True) makes a new class, object's takes nothing)
            cls.kind = kind

    @property
    def text(self) -> str:
        """The wire's "detail": one line on what happened."""
        raise NotImplementedError


@dataclass(frozen=True, slots=True)
class ConnectionEvent(Worded):
    """Something that happened to a device's connections at `at` (ns)."""

    at: int


@dataclass(frozen=True, slots=True)
class ConnectionRefused(ConnectionEvent, kind="connection refused"):
    """A Forward Open or Forward Close refused: no connection came of it."""

    reason: str  # the request, who sent it and the status it got

    @property
    def text(self) -> str:
        return self.reason


@dataclass(frozen=True, slots=True)
class OfConnection(ConnectionEvent):
    """Something that happened to one connection; `reason` says why (may be empty)."""

    connection: Connection
    reason: str = ""

    @property
    def text(self) -> str:
        return describe(self.connection) + (f": {self.reason}" if self.reason else "")


class ConnectionOpened(OfConnection, kind="connection opened"):
    """A Forward Open admitted: a new connection, a new watchdog and maybe a new T->O stream."""

    __slots__ = ()


class ConnectionEnded(OfConnection):
    """A connection closed, whatever closed it (the subclasses say what)."""

    __slots__ = ()
    #: How the report words this end (cip/report.py `EndWord`); None: by the close's reason.
    ends: ClassVar[EndWord | None] = None


class ConnectionClosed(ConnectionEnded, kind="connection closed"):
    """Closed on purpose: a Forward Close, its TCP connection, a reset, its producer's close."""

    __slots__ = ()


class ConnectionTimedOut(ConnectionEnded, kind="connection timed out"):
    """Its supervision deadline came (Vol. 1, 3-4.4.9; a Safety Validator's for CIP Safety)."""

    __slots__ = ()
    ends = "timeout"


class ConnectionFaulted(ConnectionEnded, kind="connection faulted"):
    """A CIP Safety connection its Safety Validator faulted (Vol. 5, 2-4.6)."""

    __slots__ = ()
    ends = "safety fault"


class SafeState(OfConnection, kind="safe state"):
    """The end of a safety output connection put the safe outputs in the safe state (all off)."""

    __slots__ = ()


class SafetyCrcFault(OfConnection, kind="safety crc fault"):
    """A safety message failed its integrity checks (size, CRC, redundancy)."""

    __slots__ = ()


class SafetyTimingFault(OfConnection, kind="safety timing fault"):
    """A safety message failed its time checks (timestamp delta, data age)."""

    __slots__ = ()


#: The event of each fault a Safety Validator names (protocol/safety/validator.py, `Consumed.fault`).
SAFETY_FAULTS: Mapping[str, type[OfConnection]] = MappingProxyType({"crc": SafetyCrcFault,
                                                                   "timing": SafetyTimingFault})


class ConnectionShortData(OfConnection, kind="connection short data"):
    """A variable-size connection's first O->T shorter than the assembly (not applied)."""

    __slots__ = ()


def describe(connection: Connection) -> str:
    """A connection in one line: kind, originator, each direction's id, RPI and size, where T->O goes."""
    c = connection
    text = (f"{c.kind.value} from {c.originator_host}: O->T 0x{c.o_t_id:08X} RPI {c.o_t_rpi} us {c.o_t_size} bytes, "
            f"T->O 0x{c.t_o_id:08X} RPI {c.t_o_rpi} us {c.t_o_size} bytes")
    if c.t_o_address is not None:
        text += f" {'multicast ' if c.multicast else ''}to {c.t_o_address[0]}:{c.t_o_address[1]}"
    return text


def refused_open(request: ForwardOpenRequest, originator: Originator, refusal: Refusal) -> str:
    """One line on a refused Forward Open: who asked for what, and the status it got."""
    o_t, t_o = request.o_t_parameters, request.t_o_parameters
    expected = f", {refusal.expected_size} bytes expected" if refusal.expected_size is not None else ""
    return (f"{'Large ' if request.large else ''}Forward Open from {originator.host}: "
            f"{describe_status(refusal.general, refusal.extended)}{expected} "
            f"(class {request.transport_class}, O->T RPI {request.o_t_rpi} us {o_t.size} bytes, "
            f"T->O RPI {request.t_o_rpi} us {t_o.size} bytes, path {request.connection_path.hex(' ')})")
