"""Fault injection per device: what a misbehaving module does, switched on and off at run time.

The kinds are classes (device/fault_kinds.py, one each; device/fault_type.py says what a kind is):
`FAULT_TYPES` maps a name to its class, `Fault(kind, **params)` makes one fault with its parameters
checked, and `DeviceFaults` holds a device's active faults and gathers their effects (hooks) into
what the hot paths read without a lookup.

A fault lasts until cleared, or for `duration_s`. Clearing restores normal behaviour at once.
Parameters are checked once, for the Python API and the HTTP API alike (a `FaultError`, a
ValueError naming the field). A parameter that only other kinds take is ignored (a `delay_ms` of
0 given to a `drop`), one that no kind takes is refused. Times are integer nanoseconds of the
monotonic clock, passed in.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from enum import Enum
from types import MappingProxyType
from typing import Any

from pydantic import ValidationError

from enip_farm.device.fault_kinds import KINDS
from enip_farm.device.fault_type import DROP, MAX_DELAY_MS, Disconnect, FaultError, FaultType

__all__ = ["DROP", "FAULT_TYPES", "MAX_DELAY_MS", "DeviceFaults", "Disconnect", "Fault", "FaultError", "FaultKind",
           "FaultType", "fault_kinds"]

#: The registry: each kind's name -> its class.
FAULT_TYPES: Mapping[str, type[FaultType]] = MappingProxyType({kind.name: kind for kind in KINDS})
#: The kinds' names as an enum (the HTTP API's `kind`), e.g. FaultKind.STOP_IO == "stop-io".
FaultKind = Enum("FaultKind", {name.upper().replace("-", "_"): name for name in FAULT_TYPES}, type=str)  # type: ignore[misc]
_PARAMETERS = frozenset(field for kind in KINDS for field in kind.model_fields)


def fault_kinds() -> list[dict[str, Any]]:
    """Every kind as GET /fault-kinds lists it: name, summary, JSON Schema of its parameters."""
    return [kind.describe_kind() for kind in KINDS]


def Fault(kind: str, **params: Any) -> FaultType:  # noqa: N802 (it reads as the constructor it replaces)
    """One fault of `kind` with its parameters checked, e.g. Fault("delay", delay_ms=800)."""
    fault_type = FAULT_TYPES.get(kind) if isinstance(kind, str) else None
    if fault_type is None:
        raise FaultError("kind", f"{kind!r} is not one of {', '.join(FAULT_TYPES)}", kind)
    for name in params:
        if name not in _PARAMETERS:
            raise FaultError(name, f"is not a parameter of any fault kind ({', '.join(sorted(_PARAMETERS))})")
    try:
        return fault_type(**{name: value for name, value in params.items() if name in fault_type.model_fields})
    except ValidationError as error:
        first = error.errors()[0]
        cause = first.get("ctx", {}).get("error")
        if isinstance(cause, FaultError):
            raise cause from None
        field = str(first["loc"][0]) if first["loc"] else "kind"
        raise FaultError(field, first["msg"], first.get("input")) from None


class DeviceFaults:
    """The active faults of one device (one per kind), with their effects gathered for the hot
    paths: `forced_status` (the message router's), `io_stopped`, `answers_udp`, `listens`."""

    def __init__(self) -> None:
        self.active: dict[str, FaultType] = {}
        self.started_ns: dict[str, int] = {}
        self.forced_status: dict[int, int] = {}  # service -> general status, read by the message router
        self.io_stopped = False
        self.answers_udp = True
        self.listens = True
        self.hears = True
        self.suspended: set[str] = set()  # kinds whose effects are off for now (a flapping link's up phases)
        #: The class-1 datagrams' degraded path (a degraded-link fault), read by the cyclic I/O thread.
        self.impairment: Any = None
        self._impaired_by: FaultType | None = None
        #: A safety fault's SafetyTamper of the class-0 datagrams, read by the cyclic I/O thread.
        self.safety_tamper: Any = None
        self._tampered_by: FaultType | None = None
        self._replies: tuple[FaultType, ...] = ()  # the faults that change how TCP replies go out
        self._disconnect: Disconnect | None = None
        #: Told after each change of the faults' effects (server/native.py: a faulted device leaves the native path).
        self.changed: Callable[[], None] | None = None

    def set(self, fault: FaultType, now: int) -> None:
        """Switch `fault` on at `now` (ns), in place of a fault of its kind."""
        self.active[fault.name] = fault
        self.started_ns[fault.name] = now
        self._update()

    def clear(self, kind: str | None = None) -> list[str]:
        """Switch one kind (or all) off; the kinds cleared."""
        cleared = [name for name in self.active if kind is None or name == kind]
        for name in cleared:
            del self.active[name]
            self.started_ns.pop(name, None)
            self.suspended.discard(name)
        self._update()
        return cleared

    def suspend(self, kind: str, suspended: bool) -> None:
        """Switch the effects of active fault `kind` off (True) or on again (False), the fault kept."""
        if kind in self.active:
            (self.suspended.add if suspended else self.suspended.discard)(kind)
            self._update()

    def listens_without(self, kind: str | None) -> bool:
        """Whether TCP would listen once `kind` (None: every kind) is cleared."""
        return kind is None or all(fault.listens() for name, fault in self.active.items()
                                   if name != kind and name not in self.suspended)

    def _update(self) -> None:
        faults = [fault for name, fault in self.active.items() if name not in self.suspended]
        self.forced_status.clear()
        for fault in faults:
            self.forced_status.update(fault.on_request_statuses())
        self.io_stopped = not all(fault.on_io_datagram() for fault in faults)
        self.answers_udp = all(fault.on_udp_datagram() for fault in faults)
        self.listens = all(fault.listens() for fault in faults)
        self.hears = all(fault.hears() for fault in faults)
        impairing = next((f for f in faults if type(f).impairment is not FaultType.impairment), None)
        if impairing is not self._impaired_by:  # a new one starts afresh; the same one keeps what it holds
            self._impaired_by = impairing
            self.impairment = impairing.impairment() if impairing is not None else None
        tampering = next((f for f in faults if type(f).safety_tamper is not FaultType.safety_tamper), None)
        if tampering is not self._tampered_by:
            self._tampered_by = tampering
            self.safety_tamper = tampering.safety_tamper() if tampering is not None else None
        self._replies = tuple(f for f in faults if type(f).on_reply is not FaultType.on_reply)
        # a list in the faults' order, not a set: the choice never rests on a hash order (issue 32)
        ends = [end for end in (fault.on_tcp_connection() for fault in faults) if end is not None]
        self._disconnect = Disconnect.RESET if Disconnect.RESET in ends else ends[0] if ends else None
        if self.changed is not None:
            self.changed()

    def on_reply(self) -> int | None:
        """Nanoseconds to hold this turn's TCP replies back (in order after the ones held before), or
        `DROP` (drop wins); None: no fault changes how replies go out."""
        if not self._replies:
            return None
        holds = [fault.on_reply() for fault in self._replies]
        return DROP if DROP in holds else max(holds)

    def on_tcp_connection(self) -> Disconnect | None:
        """How a new TCP connection ends at once, if it does (reset wins over close)."""
        return self._disconnect

    def product_code(self, code: int) -> int:
        """The product code the Identity object shows."""
        for name, fault in list(self.active.items()):
            if name not in self.suspended:
                code = fault.on_product_code(code)
        return code

    def revision(self, revision: tuple[int, int]) -> tuple[int, int]:
        """The revision the Identity object shows."""
        for name, fault in list(self.active.items()):
            if name not in self.suspended:
                revision = fault.on_revision(revision)
        return revision

    def assembly_size(self, role: str, size: int) -> int:
        """The data size of assembly `role` ("input", "output") a Forward Open is checked against."""
        for name, fault in list(self.active.items()):
            if name not in self.suspended:
                size = fault.on_assembly_size(role, size)
        return size

    def describe(self, now: int) -> list[dict[str, Any]]:
        """Each active fault's `parameters` and how long it has been on at `now` (`age_s`)."""
        return [{**fault.parameters(), "age_s": round((now - self.started_ns.get(name, now)) / 1e9, 3)}
                for name, fault in list(self.active.items())]
