"""The fault kinds: what a misbehaving module does, one class each (device/fault_type.py says
what a kind is and which hooks it may override).

To add a kind, write one class here (or beside it: device/cell_fault_kinds.py holds the cell's hardware
faults) (its `name`, a one-line `summary`, its parameters as pydantic
fields with `before` validators raising `FaultError`, the hooks it needs) and list it in `KINDS`:
the Python API, the HTTP API (POST /devices/{name}/faults, GET /fault-kinds), the CLI and the
dashboard take it from there.
"""

from __future__ import annotations

import random
from typing import Any

from pydantic import ConfigDict, Field, field_validator, model_validator

from enip_farm.device.cell_fault_kinds import (
    AddressConflict,
    DegradedLink,
    FlappingLink,
    LinkDown,
    PowerLoss,
    SafetyCrc,
    SafetyStale,
    SafetyTimeCoordination,
    WrongModule,
)
from enip_farm.device.fault_type import DROP, MAX_DELAY_MS, Disconnect, FaultError, FaultType, byte, delay_ms


class Delay(FaultType):
    name = "delay"
    summary = "TCP replies are held back delay_ms (or a random time up to max_delay_ms), in order"

    delay_ms: float = Field(0.0, ge=0, le=MAX_DELAY_MS, description="ms to hold each reply, 0..60000")
    max_delay_ms: float | None = Field(None, ge=0, le=MAX_DELAY_MS,
                                       description="each reply waits a random time in [delay_ms, max_delay_ms]")

    @field_validator("delay_ms", "max_delay_ms", mode="before")
    @classmethod
    def _delays(cls, value: Any, info: Any) -> Any:
        return None if value is None and info.field_name == "max_delay_ms" else delay_ms(info.field_name, value)

    @model_validator(mode="after")
    def _ordered(self) -> Delay:
        if self.max_delay_ms is not None and self.max_delay_ms < self.delay_ms:
            raise FaultError("max_delay_ms", f"must not be below delay_ms ({self.delay_ms:g}), "
                             f"got {self.max_delay_ms:g}", self.max_delay_ms)
        if self.delay_ms <= 0 and not self.max_delay_ms:
            raise FaultError("delay_ms", "a delay fault needs delay_ms > 0 (and optionally max_delay_ms)", 0)
        return self

    def on_reply(self) -> int:
        if self.max_delay_ms is not None and self.max_delay_ms > self.delay_ms:
            return round(random.uniform(self.delay_ms, self.max_delay_ms) * 1e6)
        return round(self.delay_ms * 1e6)


class Drop(FaultType):
    name = "drop"
    summary = "requests are processed but their replies are not sent"

    def on_reply(self) -> int:
        return DROP


class Close(FaultType):
    name = "close"
    summary = "TCP connections are closed (FIN), existing and new ones"

    def on_tcp_connection(self) -> Disconnect | None:
        return Disconnect.CLOSE


class Reset(FaultType):
    name = "reset"
    summary = "TCP connections are reset (RST), existing and new ones"

    def on_tcp_connection(self) -> Disconnect | None:
        return Disconnect.RESET


class Offline(FaultType):
    name = "offline"
    summary = "like a module without power: TCP refused, UDP unanswered, no T->O, O->T ignored"

    def listens(self) -> bool:
        return False

    def on_udp_datagram(self) -> bool:
        return False

    def on_io_datagram(self) -> bool:
        return False


class Status(FaultType):
    name = "status"
    summary = "requests of one CIP service get a chosen general status"
    model_config = ConfigDict(json_schema_extra={"required": ["service", "status"]})

    service: int | None = Field(None, ge=0, le=0xFF, description="the CIP service code, e.g. 14 (0x0E) for "
                                "Get Attribute Single")
    status: int | None = Field(None, ge=0, le=0xFF, description="the general status to answer it with, e.g. 8")

    @field_validator("service", "status", mode="before")
    @classmethod
    def _bytes(cls, value: Any, info: Any) -> Any:
        what = "a CIP service code" if info.field_name == "service" else "a CIP general status"
        return None if value is None else byte(info.field_name, value, what)

    @model_validator(mode="after")
    def _both(self) -> Status:
        for name in ("service", "status"):
            if getattr(self, name) is None:
                raise FaultError(name, "a status fault needs a service and a status")
        return self

    def on_request_statuses(self) -> dict[int, int]:
        return {self.service: self.status}  # type: ignore[dict-item]  # both checked


class StopIo(FaultType):
    name = "stop-io"
    summary = "T->O production stops and O->T is ignored, so a scanner's connection times out"

    def on_io_datagram(self) -> bool:
        return False


class Identity(FaultType):
    name = "identity"
    summary = "the product code changes, so electronic keys stop matching"

    def on_product_code(self, code: int) -> int:
        return (code + 1) & 0xFFFF


#: Every fault kind, in the order the API, the CLI and the dashboard list them.
KINDS: tuple[type[FaultType], ...] = (Delay, Drop, Close, Reset, Offline, Status, StopIo, Identity, PowerLoss,
                                      LinkDown, FlappingLink, DegradedLink, AddressConflict, WrongModule,
                                      SafetyCrc, SafetyStale, SafetyTimeCoordination)
