"""What every fault kind is: a pydantic model of its parameters, their checks, and its effects as
hooks that the paths of the farm call generically (device/faults.py gathers them per device).

A kind overrides only the hooks it needs; each default is "no effect". `on_reply`, `on_product_code`,
`on_revision` and `on_assembly_size` are asked on every use; the others when a fault is set or cleared (device/faults.py
keeps their answers for the fast paths), so their answer depends on the parameters, not on the moment:

| hook | called by | returns |
|---|---|---|
| `on_tcp_connection()` | server/tcp.py on accept; the farm on inject, for the open ones | `Disconnect` or None |
| `on_reply()` | server/tcp.py, per turn of replies | ns to hold them back, `DROP`, or 0 |
| `on_request_statuses()` | the message router (cip/message_router.py, `forced_status`) | service -> general status |
| `on_udp_datagram()` | server/udp.py (ListIdentity, ListServices ...) | False: unanswered |
| `on_io_datagram()` | the device's class-1 paths (O->T taken, T->O produced) | False: I/O stops both ways |
| `listens()` | the farm: TCP 44818 listens while every active fault says so | False: no listener |
| `on_product_code(code)` | the Identity object's product code (electronic keys) | the code shown |
| `on_revision(revision)` | the Identity object's revision (electronic keys) | the revision shown |
| `on_assembly_size(role, size)` | a Forward Open's size checks (cip/admission.py), per assembly role | the data size |
| `hears()` | server/tcp.py, per read | False: requests are not received (no power, no link) |
| `phases()` | the farm, on inject | (down s, up s) pairs: the effects come and go (a flapping link) |
| `impairment()` | device/faults.py, when set | a DegradedPath the class-1 datagrams go through |
| `safety_tamper()` | device/faults.py, when set | a SafetyTamper the CIP Safety datagrams go through |
| `on_set(device, now)` / `on_clear(device, now)` | the farm, as the fault is set and cleared | None |

`on_set` and `on_clear` act on the device itself (`FaultedDevice`: a power loss loses its state, an
address conflict fills in the TCP/IP object's attribute 11); they run on the farm's loop, before the
fault's other hooks are asked (what `on_set` finds may decide them: an address conflict that ACD detects).

Parameter problems are `FaultError`s (a ValueError naming the field), raised by the model's own
validators; `Fault(kind, **params)` (device/faults.py) hands them on unwrapped.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from enum import Enum
from typing import Any, ClassVar, Protocol

from pydantic import BaseModel, ConfigDict, Field, field_validator

MAX_DELAY_MS = 60_000.0  # one minute: longer than any client's timeout, short enough to end on its own
DROP = -1  # `on_reply`: the replies are not sent


class FaultError(ValueError):
    """A fault parameter out of range; `field` names it."""

    def __init__(self, field: str, message: str, value: object = None) -> None:
        super().__init__(f"{field}: {message}")
        self.field = field
        self.value = value


class Disconnect(str, Enum):
    """How a fault ends TCP connections: FIN or RST."""

    CLOSE = "close"
    RESET = "reset"


def number(field: str, value: object) -> float:
    """A finite JSON number (not a bool), as a float."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise FaultError(field, f"must be a number, got {value!r}", value)
    if not math.isfinite(value):
        raise FaultError(field, f"must be finite, got {value!r}", value)
    return float(value)


def delay_ms(field: str, value: object) -> float:
    """A delay in milliseconds, 0..MAX_DELAY_MS."""
    checked = number(field, value)
    if not 0 <= checked <= MAX_DELAY_MS:
        raise FaultError(field, f"must be 0..{MAX_DELAY_MS:.0f} ms, got {value!r}", value)
    return checked


def byte(field: str, value: object, what: str) -> int:
    """An integer 0..255 (a CIP service code or general status)."""
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 0xFF:
        raise FaultError(field, f"must be {what} 0..255 (0x00..0xFF), got {value!r}", value)
    return value


class FaultedDevice(Protocol):
    """What `on_set` and `on_clear` may touch of a device (device/device.py's Device)."""

    def lose_power(self, now: int) -> None: ...

    def restore_power(self, boot_ns: int, now: int, self_test_ns: int = 0) -> None: ...

    def address_conflict(self, activity: int, remote_mac: bytes, probing: bool) -> bool: ...

    def conflict_resolved(self) -> None: ...


class FaultType(BaseModel):
    """One fault kind: subclass it with `name`, `summary`, the parameters as fields and the hooks
    it needs (device/fault_kinds.py). An instance is one fault, its parameters checked."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    name: ClassVar[str]
    summary: ClassVar[str]

    duration_s: float | None = Field(None, gt=0, description="end the fault by itself after this long, s (> 0)")

    @field_validator("duration_s", mode="before")
    @classmethod
    def _duration(cls, value: Any) -> Any:
        if value is None:
            return None
        checked = number("duration_s", value)
        if checked <= 0:
            raise FaultError("duration_s", f"must be > 0, got {checked:g}", checked)
        return checked

    @property
    def duration_ns(self) -> int | None:
        return None if self.duration_s is None else round(self.duration_s * 1e9)

    def parameters(self) -> dict[str, Any]:
        """The fault as JSON takes it: its kind and the parameters it was given (None left out),
        e.g. {"kind": "delay", "delay_ms": 800.0, "duration_s": 10.0}."""
        given = self.model_dump(exclude_none=True, exclude={"duration_s"})
        return {"kind": self.name, **given, **({} if self.duration_s is None else {"duration_s": self.duration_s})}

    @classmethod
    def describe_kind(cls) -> dict[str, Any]:
        """The kind as GET /fault-kinds lists it: name, summary, its parameters' JSON Schema."""
        return {"kind": cls.name, "summary": cls.summary, "parameters": cls.model_json_schema()}

    # -- effects: each default is "no effect" ------------------------------------------------------

    def on_tcp_connection(self) -> Disconnect | None:
        return None

    def on_reply(self) -> int:
        return 0

    def on_request_statuses(self) -> dict[int, int]:
        return {}

    def on_udp_datagram(self) -> bool:
        return True

    def on_io_datagram(self) -> bool:
        return True

    def listens(self) -> bool:
        return True

    def on_product_code(self, code: int) -> int:
        return code

    def on_revision(self, revision: tuple[int, int]) -> tuple[int, int]:
        return revision

    def on_assembly_size(self, role: str, size: int) -> int:
        return size

    def hears(self) -> bool:
        return True

    def phases(self) -> Iterator[tuple[float, float]] | None:
        return None

    def safety_tamper(self) -> Any:
        """A new SafetyTamper (device/safety_faults.py) for a safety target's class-0 datagrams, or None."""
        return None

    def impairment(self) -> Any:
        """A new degraded path (device/impairment.py's DegradedPath) for the class-1 datagrams, or None."""
        return None

    def on_set(self, device: FaultedDevice, now: int) -> None:
        return None

    def on_clear(self, device: FaultedDevice, now: int) -> None:
        return None
