"""What happens to a device, as typed events in the style of aioquic's `quic/events.py`: one class
per kind with typed fields. A consumer matches on the class (`isinstance`, `match`), never on text.
The connection table's events are cip/connection_events.py's classes; this module has the others:
explicit requests, image changes, sessions, resets, TCP connections, faults and wires.

The wire's words are made here and only here (and in cip/connection_events.py for the connection
events): `kind` (a class constant: the HTTP API's, the SSE stream's, the dashboard's and the log
line's "kind") and `text` (their "detail"); a fault's JSON detail is its parameters (`parameters`).

`Event` is what observers and the log hand out: one of these with its device and its time, in
integer nanoseconds of the monotonic clock the device is given and of the wall clock (`as_dict`, the
JSON form, says seconds as the API always has). The log (`EventLog`) keeps plain tuples and makes
Events only when read, so that logging every request stays cheap.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, ClassVar, NamedTuple, Protocol

from enip_farm.cip.connection_events import Worded
from enip_farm.cip.identity import ResetRequested
from enip_farm.protocol.encapsulation import command_name, describe_encapsulation_status


class DeviceEvent(Protocol):
    """What every event class has (the connection events' too): its wire words."""

    kind: ClassVar[str]

    @property
    def text(self) -> str: ...


class RequestHandled(NamedTuple):
    """An explicit request answered, as the message router answered it (cip/message_router.py `Handled`)."""

    service: int
    path: bytes
    status: int  # general status
    extended: int | None
    relayed: bool  # embedded in a Multiple Service Packet

    kind = "request"

    @property
    def text(self) -> str:
        text = f"service 0x{self.service:02X} path {self.path.hex(' ')} status 0x{self.status:02X}"
        return text if self.extended is None else f"{text} extended 0x{self.extended:04X}"


class ImageChanged(NamedTuple):
    """An image changed in one device transaction: which image, its bytes before and after."""

    role: str  # "input" or "output"
    old: bytes
    new: bytes

    kind = "image changed"

    @property
    def text(self) -> str:
        return f"{self.role} {self.old.hex()} -> {self.new.hex()}"


@dataclass(frozen=True, slots=True)
class Happened(Worded):
    """The base of the events below (not the connection table's): `class X(Happened, kind="...")`."""


@dataclass(frozen=True, slots=True)
class Told(Happened):
    """An event that is one line of words (a scenario's step, why an address is still taken)."""

    line: str

    @property
    def text(self) -> str:
        return self.line


@dataclass(frozen=True, slots=True)
class SessionRegistered(Happened, kind="session registered"):
    handle: int
    peer_host: str = ""

    @property
    def text(self) -> str:
        return f"handle {self.handle}" + (f" from {self.peer_host}" if self.peer_host else "")


@dataclass(frozen=True, slots=True)
class SessionEnded(Happened, kind="session ended"):
    handle: int

    @property
    def text(self) -> str:
        return f"handle {self.handle}"


#: What each reset type does (Identity Reset, Vol. 1, 5-2.4.1), as the events say it.
RESET_KINDS: Mapping[int, str] = MappingProxyType({
    0: "power cycle", 1: "out-of-box configuration", 2: "out-of-box configuration but the communication parameters"})


@dataclass(frozen=True, slots=True)
class Reset(Happened, kind="reset"):
    """A device performed a reset (device/reset.py): the request, and how long it does not answer.
    The farm closes the device's TCP side on this class (farm/resets.py)."""

    request: ResetRequested
    quiet_s: float

    @property
    def text(self) -> str:
        kind = self.request.type
        return f"type {kind} ({RESET_KINDS[kind]}): not answering for {self.quiet_s:g} s"


@dataclass(frozen=True, slots=True)
class ResetDone(Happened, kind="reset done"):
    """The reset window ended: the device answers again."""

    text = "answering again"


@dataclass(frozen=True, slots=True)
class TcpConnected(Happened, kind="tcp connected"):
    peer: str  # "host:port", "" if unknown

    @property
    def text(self) -> str:
        return self.peer


@dataclass(frozen=True, slots=True)
class TcpInactive(Happened, kind="tcp inactive"):
    """Closed by the farm: no whole request for the encapsulation inactivity timeout (TCP/IP attribute 13)."""

    peer: str  # "host:port", "" if unknown
    timeout_s: int

    @property
    def text(self) -> str:
        if not self.peer:
            return ""
        return f"{self.peer}: no whole request for {self.timeout_s} s, closed (TCP/IP attribute 13)"


@dataclass(frozen=True, slots=True)
class TcpClosed(Happened, kind="tcp closed"):
    peer: str  # "host:port", "?" if unknown
    by_client: bool
    after_s: float  # how long it was open

    @property
    def text(self) -> str:
        return f"{self.peer} closed by {'the client' if self.by_client else 'the farm'} after {self.after_s:.1f} s"


@dataclass(frozen=True, slots=True)
class OfEncapsulation(Happened):
    """A request of `command` from `peer` whose encapsulation `status` the subclass tells."""

    command: int
    peer: str
    status: int


@dataclass(frozen=True, slots=True)
class EncapsulationRefused(OfEncapsulation, kind="encapsulation refused"):
    """A request answered with an encapsulation error status (Vol. 2, 2-3.3)."""

    @property
    def text(self) -> str:
        return (f"{command_name(self.command)} from {self.peer}: encapsulation status "
                f"{describe_encapsulation_status(self.status)}")


@dataclass(frozen=True, slots=True)
class EncapsulationIgnored(OfEncapsulation, kind="encapsulation ignored"):
    """A request that carried a non-zero status: not answered (Vol. 2, 2-3.5)."""

    @property
    def text(self) -> str:
        return (f"{command_name(self.command)} from {self.peer} carried status 0x{self.status:08X}; "
                "a request's status must be 0 (Vol. 2, 2-3.5): no reply")


@dataclass(frozen=True, slots=True)
class PowerLost(Happened, kind="power lost"):
    """The module's supply is gone (device/hardware.py): its volatile state with it."""

    text = "no answer on TCP, UDP or class 1; connections end without a close"


@dataclass(frozen=True, slots=True)
class SelfTestDone(Happened, kind="self test done"):
    """After its boot the module's self test ended: Identity attribute 8 goes from 1 to 3 (operational)."""

    text = "operational"


@dataclass(frozen=True, slots=True)
class PowerReturned(Happened, kind="power returned"):
    boot_s: float  # how long it boots, not answering

    @property
    def text(self) -> str:
        return f"booting: not answering for {self.boot_s:g} s"


@dataclass(frozen=True, slots=True)
class AddressConflict(Happened, kind="address conflict"):
    """Another host claims the module's address (RFC 826; TCP/IP attribute 11 keeps its ARP PDU)."""

    remote_mac: bytes
    detected: bool  # False: SelectAcd (TCP/IP attribute 10) is 0
    silent: bool  # the module gives the address up

    @property
    def text(self) -> str:
        outcome = (("address given up" if self.silent else "address defended") if self.detected
                   else "not detected (SelectAcd, TCP/IP attribute 10, is 0)")
        return f"with {self.remote_mac.hex(':')}: {outcome}"


@dataclass(frozen=True, slots=True)
class ScenarioStep(Told, kind="scenario step"):
    """A scenario's step began or ended (scenario/run.py): its label and what it did."""


@dataclass(frozen=True, slots=True)
class AddressStillTaken(Told, kind="address still taken"):
    """An address-conflict fault cleared, but the device's address is not its own again: why."""


@dataclass(frozen=True, slots=True)
class LinkPhase(Happened):
    """A flapping fault's phase: its effects on (`LinkDown`) or off (`LinkUp`) for `for_s`."""

    fault: str
    for_s: float

    @property
    def text(self) -> str:
        return f"{self.fault}: for {self.for_s:.3f} s"


@dataclass(frozen=True, slots=True)
class LinkDown(LinkPhase, kind="link down"):
    pass


@dataclass(frozen=True, slots=True)
class LinkUp(LinkPhase, kind="link up"):
    pass


@dataclass(frozen=True, slots=True)
class Wired(Happened, kind="wired"):
    """A wire or a rule set a signal (control/wiring.py): both ends by their signal names."""

    target: str  # e.g. "robot.giRecipe"
    values: tuple[int | float, ...]
    cause: str  # e.g. "wire from plc.goRecipe", "rule: plc.doStart rises"

    @property
    def text(self) -> str:
        value = list(self.values) if len(self.values) > 1 else self.values[0]
        return f"{self.target} = {value} ({self.cause})"


@dataclass(frozen=True, slots=True)
class FaultEvent(Happened):
    """A fault switched on or off; its JSON detail is `parameters` (a dict), its text says them."""

    @property
    def parameters(self) -> dict[str, Any]:
        raise NotImplementedError

    @property
    def text(self) -> str:  # e.g. "delay (delay_ms 800, duration_s 10)"
        given = self.parameters
        rest = {key: value for key, value in given.items() if key != "kind"}
        parameters = ", ".join(f"{key} {value:g}" if isinstance(value, float) else f"{key} {value}"
                               for key, value in rest.items())
        head = str(given.get("kind", ""))
        return f"{head} ({parameters})" if head and parameters else head or parameters


@dataclass(frozen=True, slots=True)
class FaultInjected(FaultEvent, kind="fault injected"):
    fault: Mapping[str, Any]  # the fault's kind and parameters (device/fault_type.py `parameters`)

    @property
    def parameters(self) -> dict[str, Any]:
        return dict(self.fault)


@dataclass(frozen=True, slots=True)
class FaultCleared(FaultEvent, kind="fault cleared"):
    kinds: tuple[str, ...]

    @property
    def parameters(self) -> dict[str, Any]:
        return {"kind": ", ".join(self.kinds)}


class Event(NamedTuple):
    """An event of one device at one time: `detail` is the typed event (match on its class)."""

    monotonic_ns: int  # when it happened, ns of the monotonic clock the device is given
    wall_ns: int  # the same moment, ns since the epoch
    device: str
    detail: Any  # a DeviceEvent: one of this module's classes or cip/connection_events.py's

    @property
    def kind(self) -> str:
        """The wire's kind."""
        return self.detail.kind

    @property
    def text(self) -> str:
        """The wire's detail, as a log line says it."""
        return self.detail.text

    def as_dict(self) -> dict[str, Any]:
        """The event as JSON takes it: a fault's detail is its parameters (a dict)."""
        detail = self.detail
        return {"time": self.wall_ns / 1e9, "monotonic": self.monotonic_ns / 1e9, "device": self.device,
                "kind": detail.kind, "detail": detail.parameters if isinstance(detail, FaultEvent) else detail.text}


class EventLog:
    """A bounded log; the oldest events fall off the end. Entries are stored as plain tuples (a
    request as the router's own tuple) and become Events (with a wall-clock time) only when read or
    streamed: recording a request costs well under a microsecond."""

    def __init__(self, device: str, size: int = 10000) -> None:
        self.device = device
        self._entries: deque[tuple[int, Any]] = deque(maxlen=size)
        self._wall_offset_ns = time.time_ns() - time.monotonic_ns()  # monotonic -> wall clock

    @property
    def wall_offset_ns(self) -> int:
        """Wall-clock time minus monotonic time (ns): an Event's `wall_ns` is its `monotonic_ns` plus this."""
        return self._wall_offset_ns

    def record(self, detail: DeviceEvent, now: int) -> Event:
        """Keep an event that happened at `now` (ns, monotonic)."""
        entry = (now, detail)
        self._entries.append(entry)
        return self.event(entry)

    def request(self, handled: tuple, now: int) -> tuple[int, tuple]:
        """One explicit request answered at `now` (ns), as the message router's `Handled` tuple;
        the raw entry (`event` makes it an Event of a RequestHandled), so that logging a request
        costs no more than a tuple."""
        entry = (now, handled)
        self._entries.append(entry)
        return entry

    def event(self, entry: tuple[int, Any]) -> Event:
        """An Event of an entry (now, detail), whether kept in the log or not."""
        now, detail = entry
        if type(detail) is tuple:  # a request as the router's tuple
            detail = RequestHandled._make(detail)
        return Event(now, now + self._wall_offset_ns, self.device, detail)

    def __iter__(self) -> Iterator[Event]:
        return iter([self.event(entry) for entry in list(self._entries)])

    def of_type(self, *classes: type) -> list[Event]:
        """The events of these classes (or their subclasses), oldest first."""
        events = [self.event(entry) for entry in list(self._entries)]
        return [event for event in events if isinstance(event.detail, classes)]

    def of_kind(self, kind: str) -> list[Event]:
        """The events whose wire kind is `kind` (a name the API was given: `request`, `wired`, ...)."""
        return [event for event in self if event.kind == kind]
