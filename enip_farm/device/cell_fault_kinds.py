"""The fault kinds of a cell's hardware (issue 28): power, links, addresses and the module plugged in,
each as a real network or module shows it, one class each (device/fault_type.py says what a kind is;
device/fault_kinds.py lists every kind). A group fault sets one of these on every member at once.

- power-loss: TCP refused (open connections silent, reset when the power returns), UDP and class 1
  silent; the module's state is lost and it boots for `boot_time_s` when the power returns, then
  answers self testing (Identity state 1) for `self_test_s`, then operational (3).
- link-down: TCP, UDP and class 1 silent both ways (nothing received, nothing sent); the module keeps
  its state and its own watchdogs time its connections out.
- flapping-link: link-down in its down phases.
- address-conflict: probe: the address given up (as link-down); ongoing: defended (served); the TCP/IP
  object's attributes 1 and 11 say so if SelectAcd (attribute 10) is 1.
- wrong-module: another product code or revision (ListIdentity, Identity, electronic keys), other
  assembly sizes (a Forward Open's size check: 0x01/0x0127 O->T, 0x0128 T->O, as for any wrong size).
- safety-crc, safety-stale, safety-time-coordination (a CIP Safety target, the DSQC1042): its
  safe-input messages with a wrong CRC, or standing still (the same time stamp), or no time
  coordination answers to the originator's pings (device/safety_faults.py).
- degraded-link: class 1 (O->T and T->O, device/impairment.py) delayed, jittered, lost, duplicated and
  reordered, seeded, one or both directions; explicit (TCP) replies delayed and jittered, a lost
  segment showing as the retransmission time (TCP hides loss, duplication and reordering).

On loopback a closed port answers a SYN with RST, so a powered-off module's TCP port is refused where a
real one's connect times out; a link down keeps the listener (the kernel completes the handshake) but
nothing is read or answered. Defaults nobody has published are marked unverified.
"""

from __future__ import annotations

import random
import re
from collections.abc import Iterator
from itertools import count as forever
from typing import Any, Literal

from pydantic import Field, PrivateAttr, field_validator, model_validator

from enip_farm.device.fault_type import DROP, FaultedDevice, FaultError, FaultType, number
from enip_farm.device.impairment import DegradedPath, LinkQuality
from enip_farm.device.safety_faults import SafetyTamper

#: A lost TCP segment is sent again after the retransmission timeout: Linux's least (RFC 6298 allows 1 s).
TCP_RTO_MS = 200.0

#: ACD activity of attribute 11 (Vol. 2, 5-4.3.2.11): 1 probing the address, 2 ongoing detection.
_ACTIVITY = {"probe": 1, "ongoing": 2}
_MAC = re.compile(r"^([0-9A-Fa-f]{2}[:-]){5}[0-9A-Fa-f]{2}$")


class Silent(FaultType):
    """What is not on the network: nothing is received or answered on TCP, UDP and class 1."""

    def hears(self) -> bool:
        return False

    def on_reply(self) -> int:
        return DROP

    def on_udp_datagram(self) -> bool:
        return False

    def on_io_datagram(self) -> bool:
        return False


class PowerLoss(Silent):
    name = "power-loss"
    summary = ("the supply is gone: nothing answers, connections end without a close; on return the module "
               "boots (boot_time_s of silence, Identity self testing), counters from 0, settings kept")

    boot_time_s: float = Field(2.0, ge=0, le=3600, description="s of silence after the power returns, before the "
                               "module answers (unverified default: a DSQC module's boot time is not published)")

    self_test_s: float = Field(0.5, ge=0, le=3600, description="s after the boot that the module answers self "
                               "testing (Identity attribute 8 = 1) before it is operational (unverified default)")

    @field_validator("boot_time_s", "self_test_s", mode="before")
    @classmethod
    def _boot(cls, value: Any, info: Any) -> Any:
        checked = number(info.field_name, value)
        if not 0 <= checked <= 3600:
            raise FaultError(info.field_name, f"must be 0..3600 s, got {value!r}", value)
        return checked

    def listens(self) -> bool:
        return False

    def on_set(self, device: FaultedDevice, now: int) -> None:
        device.lose_power(now)

    def on_clear(self, device: FaultedDevice, now: int) -> None:
        device.restore_power(round(self.boot_time_s * 1e9), now, round(self.self_test_s * 1e9))


class LinkDown(Silent):
    name = "link-down"
    summary = ("the cable or switch port is down: silence both ways; the module keeps its state and its own "
               "watchdogs time its connections out")


class FlappingLink(LinkDown):
    name = "flapping-link"
    summary = "the link goes down and up: period_s and duty (the share down), count times, or random (seeded)"

    period_s: float = Field(1.0, gt=0, le=3600, description="one down and up, s")
    duty: float = Field(0.5, gt=0, lt=1, description="the share of a period the link is down")
    count: int | None = Field(None, ge=1, description="this many periods, then up (none: until cleared)")
    random: bool = Field(False, description="each down and up phase lasts a random time in [min_s, max_s]")
    min_s: float = Field(0.05, gt=0, le=3600, description="random: the shortest phase, s")
    max_s: float = Field(1.0, gt=0, le=3600, description="random: the longest phase, s")
    seed: int = Field(0, description="random: the seed, so that a run can be repeated")

    @field_validator("period_s", "duty", "min_s", "max_s", mode="before")
    @classmethod
    def _numbers(cls, value: Any, info: Any) -> Any:
        return number(info.field_name, value)

    @model_validator(mode="after")
    def _ordered(self) -> FlappingLink:
        if self.max_s < self.min_s:
            raise FaultError("max_s", f"must not be below min_s ({self.min_s:g}), got {self.max_s:g}", self.max_s)
        return self

    def phases(self) -> Iterator[tuple[float, float]]:
        periods = range(self.count) if self.count is not None else forever()
        if self.random:
            rng = random.Random(self.seed)
            return ((rng.uniform(self.min_s, self.max_s), rng.uniform(self.min_s, self.max_s)) for _ in periods)
        down = self.period_s * self.duty
        return ((down, self.period_s - down) for _ in periods)


class AddressConflict(FaultType):
    """Another host claims the module's address (RFC 826). What the module does follows its SelectAcd
    (TCP/IP attribute 10, Vol. 2, 5-4.3.2.10), read as the fault is set:

    - 1 (ACD on): it detects the conflict; attribute 11 records it, attribute 1 says AcdStatus (and
      AcdFault in the probe phase); probe: it gives the address up (silent); ongoing: it defends it.
    - 0 (ACD off): it detects nothing; attributes 1 and 11 stay as they were and it keeps answering in
      both phases. The fault then changes nothing the module itself can see (on a real network the
      other host would answer some of the traffic meant for it; the farm does not model that host)."""

    name = "address-conflict"
    summary = ("another host claims the module's address: with SelectAcd (TCP/IP attribute 10) 1 the module "
               "detects it (attributes 1 and 11), probe: gives the address up (silent), ongoing: defends it; "
               "with SelectAcd 0 it detects nothing and keeps answering")

    remote_mac: str = Field("02:00:00:00:00:fe", description="the other host's MAC address")
    phase: Literal["probe", "ongoing"] = Field("ongoing", description="probe: found as the module came up; "
                                                "ongoing: another host appeared while it ran")
    _given_up: bool = PrivateAttr(False)  # set by on_set: probe phase and the module detected the conflict

    @field_validator("remote_mac", mode="before")
    @classmethod
    def _mac(cls, value: Any) -> Any:
        if not isinstance(value, str) or not _MAC.match(value):
            raise FaultError("remote_mac", f"must look like 02:00:00:00:00:fe, got {value!r}", value)
        return value

    @property
    def silent(self) -> bool:
        """The module gave the address up (known once the fault is set on it)."""
        return self._given_up

    def hears(self) -> bool:
        return not self.silent

    def on_reply(self) -> int:
        return DROP if self.silent else 0

    def on_udp_datagram(self) -> bool:
        return not self.silent

    def on_io_datagram(self) -> bool:
        return not self.silent

    def on_set(self, device: FaultedDevice, now: int) -> None:
        self._given_up = device.address_conflict(
            _ACTIVITY[self.phase], bytes.fromhex(re.sub("[:-]", "", self.remote_mac)), self.phase == "probe")

    def on_clear(self, device: FaultedDevice, now: int) -> None:
        device.conflict_resolved()


class WrongModule(FaultType):
    name = "wrong-module"
    summary = ("another module is plugged in: its product code, revision and/or assembly sizes until put back "
               "(keys and Forward Open sizes stop matching)")

    product_code: int | None = Field(None, ge=0, le=0xFFFF, description="the other module's product code "
                                     "(none given and no revision: the module's own + 1)")
    major_revision: int | None = Field(None, ge=1, le=0x7F, description="the other module's major revision")
    minor_revision: int | None = Field(None, ge=0, le=0xFF, description="the other module's minor revision")
    input_size: int | None = Field(None, ge=0, le=505, description="the other module's input assembly size "
                                   "(bytes; its T->O data)")
    output_size: int | None = Field(None, ge=0, le=505, description="the other module's output assembly size "
                                    "(bytes; its O->T data)")

    @field_validator("product_code", "major_revision", "minor_revision", "input_size", "output_size", mode="before")
    @classmethod
    def _integers(cls, value: Any, info: Any) -> Any:
        if value is not None and (isinstance(value, bool) or not isinstance(value, int)):
            raise FaultError(info.field_name, f"must be an integer, got {value!r}", value)
        return value

    def on_product_code(self, code: int) -> int:
        if self.product_code is not None:
            return self.product_code
        others = (self.major_revision, self.minor_revision, self.input_size, self.output_size)
        return code if any(value is not None for value in others) else (code + 1) & 0xFFFF

    def on_revision(self, revision: tuple[int, int]) -> tuple[int, int]:
        return (self.major_revision or revision[0],
                revision[1] if self.minor_revision is None else self.minor_revision)

    def on_assembly_size(self, role: str, size: int) -> int:
        other = {"input": self.input_size, "output": self.output_size}.get(role)
        return size if other is None else other


class DegradedLink(FaultType):
    name = "degraded-link"
    summary = ("a bad cable or a busy switch: class-1 datagrams delayed, jittered, lost, duplicated, reordered "
               "(seeded), one or both directions; TCP replies delayed (a lost segment: its retransmission)")

    delay_ms: float = Field(0.0, ge=0, le=10_000, description="each datagram held this long, ms")
    jitter_ms: float = Field(0.0, ge=0, le=10_000, description="and up to this much more or less, ms")
    loss: float = Field(0.0, ge=0, le=1, description="the share of datagrams lost, 0..1")
    duplicate: float = Field(0.0, ge=0, le=1, description="the share of datagrams sent twice, 0..1")
    reorder: float = Field(0.0, ge=0, le=1, description="the share held reorder_ms more, so later ones overtake")
    reorder_ms: float = Field(20.0, ge=0, le=10_000, description="the extra hold of a reordered datagram, ms")
    direction: Literal["both", "to-device", "from-device"] = Field(
        "both", description="to-device: O->T and requests; from-device: T->O and replies")
    seed: int = Field(0, description="the random generator's seed, so that a run can be repeated")
    _rng: random.Random = PrivateAttr()

    @field_validator("delay_ms", "jitter_ms", "loss", "duplicate", "reorder", "reorder_ms", mode="before")
    @classmethod
    def _numbers(cls, value: Any, info: Any) -> Any:
        return number(info.field_name, value)

    def model_post_init(self, context: Any) -> None:
        self._rng = random.Random(self.seed)

    def quality(self) -> LinkQuality:
        return LinkQuality(round(self.delay_ms * 1e6), round(self.jitter_ms * 1e6), self.loss, self.duplicate,
                           self.reorder, round(self.reorder_ms * 1e6))

    def impairment(self) -> DegradedPath | None:
        quality = self.quality()
        return DegradedPath(quality if self.direction != "from-device" else None,
                            quality if self.direction != "to-device" else None, self.seed)

    def on_reply(self) -> int:
        """A turn of TCP replies: its delay; a lost segment adds the retransmission timeout."""
        rng = self._rng
        hold = self.delay_ms + (rng.uniform(-self.jitter_ms, self.jitter_ms) if self.jitter_ms else 0.0)
        if self.loss and rng.random() < self.loss:
            hold += TCP_RTO_MS
        return round(max(hold, 0.0) * 1e6)


class SafetyCrc(FaultType):
    name = "safety-crc"
    summary = "CIP Safety target: its safe-input messages carry a wrong CRC (the originator's consumer drops them)"

    def safety_tamper(self) -> SafetyTamper | None:
        return SafetyTamper("crc")


class SafetyStale(FaultType):
    name = "safety-stale"
    summary = "CIP Safety target: its safe-input messages stand still (the same time stamp and data, valid CRCs)"

    def safety_tamper(self) -> SafetyTamper | None:
        return SafetyTamper("stale")


class SafetyTimeCoordination(FaultType):
    name = "safety-time-coordination"
    summary = "CIP Safety target: no time coordination answers to the originator's pings (its producer times out)"

    def safety_tamper(self) -> SafetyTamper | None:
        return SafetyTamper("time-coordination")
