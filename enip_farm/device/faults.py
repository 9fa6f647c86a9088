"""Fault injection per device: what a misbehaving module does, switched on and off at run time.

| kind | effect |
|---|---|
| delay | replies on TCP are held back `delay_ms` (or a random time up to `max_delay_ms`), in order |
| drop | requests are processed but their replies are not sent |
| close | TCP connections are closed (FIN), existing and new ones |
| reset | TCP connections are reset (RST), existing and new ones |
| offline | like a module without power: TCP refused, UDP unanswered, no T->O, O->T ignored |
| status | requests of one CIP service get a chosen general status |
| stop-io | T->O production stops and O->T is ignored, so a scanner's connection times out |
| identity | the product code changes, so electronic keys stop matching |

A fault lasts until cleared, or for `duration_s`. Clearing restores normal behaviour at once.

Parameters are checked here, once, for the Python API and the HTTP API alike (a `FaultError`, a
ValueError naming the field): `delay_ms` and `max_delay_ms` finite, 0..60 000 ms, `max_delay_ms`
not below `delay_ms`; `service` and `status` 0..0xFF (a CIP service code and general status);
`duration_s` finite and > 0.
"""

from __future__ import annotations

import math
import random
import time
from dataclasses import asdict, dataclass, field
from enum import Enum

MAX_DELAY_MS = 60_000.0  # one minute: longer than any client's timeout, short enough to end on its own


class FaultError(ValueError):
    """A fault parameter out of range; `field` names it."""

    def __init__(self, field: str, message: str, value: object = None) -> None:
        super().__init__(f"{field}: {message}")
        self.field = field
        self.value = value


def _number(field: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise FaultError(field, f"must be a number, got {value!r}", value)
    if not math.isfinite(value):
        raise FaultError(field, f"must be finite, got {value!r}", value)
    return float(value)


def _delay(field: str, value: object) -> float:
    number = _number(field, value)
    if not 0 <= number <= MAX_DELAY_MS:
        raise FaultError(field, f"must be 0..{MAX_DELAY_MS:.0f} ms, got {value!r}", value)
    return number


def _byte(field: str, value: object, what: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 0xFF:
        raise FaultError(field, f"must be {what} 0..255 (0x00..0xFF), got {value!r}", value)
    return value


class FaultKind(str, Enum):
    DELAY = "delay"
    DROP = "drop"
    CLOSE = "close"
    RESET = "reset"
    OFFLINE = "offline"
    STATUS = "status"
    STOP_IO = "stop-io"
    IDENTITY = "identity"


@dataclass
class Fault:
    kind: FaultKind
    delay_ms: float = 0.0
    max_delay_ms: float | None = None  # with it, each reply waits a random time in [delay_ms, max_delay_ms]
    service: int | None = None  # STATUS: the CIP service to answer
    status: int | None = None  # STATUS: the general status to answer it with
    duration_s: float | None = None
    started: float = field(default_factory=time.monotonic)

    def __post_init__(self) -> None:
        try:
            self.kind = FaultKind(self.kind)
        except ValueError:
            kinds = ", ".join(k.value for k in FaultKind)
            raise FaultError("kind", f"{self.kind!r} is not one of {kinds}", self.kind) from None
        self.delay_ms = _delay("delay_ms", self.delay_ms)
        if self.max_delay_ms is not None:
            self.max_delay_ms = _delay("max_delay_ms", self.max_delay_ms)
            if self.max_delay_ms < self.delay_ms:
                raise FaultError("max_delay_ms", f"must not be below delay_ms ({self.delay_ms:g}), "
                                 f"got {self.max_delay_ms:g}", self.max_delay_ms)
        if self.service is not None:
            _byte("service", self.service, "a CIP service code")
        if self.status is not None:
            _byte("status", self.status, "a CIP general status")
        if self.duration_s is not None:
            self.duration_s = _number("duration_s", self.duration_s)
            if self.duration_s <= 0:
                raise FaultError("duration_s", f"must be > 0, got {self.duration_s:g}", self.duration_s)
        if self.kind is FaultKind.STATUS:
            for name in ("service", "status"):
                if getattr(self, name) is None:
                    raise FaultError(name, "a status fault needs a service and a status")
        if self.kind is FaultKind.DELAY and self.delay_ms <= 0 and not self.max_delay_ms:
            raise FaultError("delay_ms", "a delay fault needs delay_ms > 0 (and optionally max_delay_ms)", 0)

    def reply_delay(self) -> float:
        """Seconds to hold one reply back."""
        if self.max_delay_ms is not None and self.max_delay_ms > self.delay_ms:
            return random.uniform(self.delay_ms, self.max_delay_ms) / 1000
        return self.delay_ms / 1000

    def parameters(self) -> dict:
        """The fault as JSON takes it: its kind and the parameters it was given (None left out),
        e.g. {"kind": "delay", "delay_ms": 800.0, "duration_s": 10.0}."""
        out = {k: v for k, v in asdict(self).items() if v is not None and k != "started"}
        out["kind"] = self.kind.value
        if self.kind is not FaultKind.DELAY:
            out.pop("delay_ms", None)  # only a delay holds replies back
        return {"kind": out.pop("kind"), **out}

    def describe(self) -> dict:
        """`parameters` and how long the fault has been on (`age_s`)."""
        return {**self.parameters(), "age_s": round(time.monotonic() - self.started, 3)}


class DeviceFaults:
    """The active faults of one device, with flags the hot paths read without a lookup."""

    def __init__(self) -> None:
        self.active: dict[FaultKind, Fault] = {}
        self.forced_status: dict[int, int] = {}  # service -> general status, read by the message router
        self.offline = False
        self.io_stopped = False
        self.identity_changed = False

    def set(self, fault: Fault) -> None:
        self.active[fault.kind] = fault
        self._update()

    def clear(self, kind: FaultKind | None = None) -> list[FaultKind]:
        kinds = list(self.active) if kind is None else [kind] if kind in self.active else []
        for k in kinds:
            del self.active[k]
        self._update()
        return kinds

    def _update(self) -> None:
        status = self.active.get(FaultKind.STATUS)
        self.forced_status.clear()
        if status is not None:
            self.forced_status[status.service] = status.status  # type: ignore[index]
        self.offline = FaultKind.OFFLINE in self.active
        self.io_stopped = self.offline or FaultKind.STOP_IO in self.active
        self.identity_changed = FaultKind.IDENTITY in self.active

    @property
    def reply_fault(self) -> Fault | None:
        """The fault that changes how TCP replies go out, if any (drop wins over delay)."""
        return self.active.get(FaultKind.DROP) or self.active.get(FaultKind.DELAY)

    @property
    def connection_fault(self) -> FaultKind | None:
        for kind in (FaultKind.RESET, FaultKind.CLOSE):
            if kind in self.active:
                return kind
        return None
