"""Signal names as RobotWare gives them to a scalable I/O device: DI1..DIn and DO1..DOn (bits,
1-based, across the base and its add-ons in slot order), AI1.. and AO1.. (one INT each), and
`DEVICE.SIGNAL` endpoints across a cell. Where each signal lives in the assemblies follows the
catalogue's layout (`device/catalogue.yaml`)."""

from __future__ import annotations

import re
import struct
from collections.abc import Mapping
from typing import NamedTuple

from enip_farm.device.profile import DeviceProfile

_NAME = re.compile(r"^(DI|DO|AI|AO)(\d+)(?:-(\d+))?$")
_INT = struct.Struct("<h")


class SignalError(ValueError):
    pass


class SignalRange(NamedTuple):
    kind: str  # DI, DO, AI or AO
    first: int  # 1-based
    last: int

    @property
    def count(self) -> int:
        return self.last - self.first + 1

    @property
    def role(self) -> str:
        return "input" if self.kind in ("DI", "AI") else "output"

    @property
    def digital(self) -> bool:
        return self.kind in ("DI", "DO")

    def __str__(self) -> str:
        return f"{self.kind}{self.first}" + (f"-{self.last}" if self.last != self.first else "")


def parse_signal(text: str) -> SignalRange:
    match = _NAME.match(text.strip().upper())
    if not match:
        raise SignalError(f"{text!r} is not a signal name like DI3, DO1-16 or AI2")
    first = int(match[2])
    last = int(match[3]) if match[3] else first
    if first < 1 or last < first:
        raise SignalError(f"{text!r}: signals are numbered from 1, low to high")
    return SignalRange(match[1], first, last)


class SignalMap:
    """Byte offsets (and bits) of every signal of one device in its input and output assemblies."""

    def __init__(self, profile: DeviceProfile) -> None:
        self.bits: dict[str, list[tuple[int, int]]] = {"DI": [], "DO": []}
        self.words: dict[str, list[int]] = {"AI": [], "AO": []}
        for module in profile.modules:
            io = module.io
            for i in range(io.di):
                self.bits["DI"].append((module.input_offset + i // 8, i % 8))
            for i in range(io.do):
                self.bits["DO"].append((module.output_offset + i // 8, i % 8))
            for i in range(io.ai):
                self.words["AI"].append(module.input_offset + (io.di + 7) // 8 + 2 * i)
            for i in range(io.ao):
                self.words["AO"].append(module.output_offset + (io.do + 7) // 8 + 2 * i)

    def count(self, kind: str) -> int:
        return len(self.bits[kind]) if kind in self.bits else len(self.words[kind])

    def check(self, signal: SignalRange) -> None:
        available = self.count(signal.kind)
        if signal.last > available:
            raise SignalError(f"{signal}: this device has {available} {signal.kind} signals")

    def read(self, signal: SignalRange, image: bytes | bytearray) -> list[int]:
        self.check(signal)
        span = slice(signal.first - 1, signal.last)
        if signal.digital:
            return [image[offset] >> bit & 1 for offset, bit in self.bits[signal.kind][span]]
        return [_INT.unpack_from(image, offset)[0] for offset in self.words[signal.kind][span]]

    def write(self, signal: SignalRange, image: bytearray, values: list[int]) -> None:
        """Write values into an image in place (the caller holds the device lock)."""
        self.check(signal)
        if len(values) != signal.count:
            raise SignalError(f"{signal}: {signal.count} values expected, got {len(values)}")
        span = slice(signal.first - 1, signal.last)
        if signal.digital:
            for (offset, bit), value in zip(self.bits[signal.kind][span], values, strict=True):
                if value:
                    image[offset] |= 1 << bit
                else:
                    image[offset] &= ~(1 << bit) & 0xFF
        else:
            for offset, value in zip(self.words[signal.kind][span], values, strict=True):
                if not -32768 <= value <= 32767:
                    raise SignalError(f"{signal}: {value} does not fit an INT")
                _INT.pack_into(image, offset, value)

    def names(self) -> dict[str, int]:
        return {kind: self.count(kind) for kind in ("DI", "DO", "AI", "AO")}


class Endpoint(NamedTuple):
    """A signal range of one device of a cell: DEVICE.DOn[-m], as wires and rules name them."""

    device: str
    signal: SignalRange

    def __str__(self) -> str:
        return f"{self.device}.{self.signal}"


def parse_endpoint(text: str, devices: Mapping[str, SignalMap]) -> Endpoint:
    """Raises ValueError (SignalError) naming the endpoint if the device or signal does not exist."""
    name, _, signal_text = text.rpartition(".")
    if name not in devices:
        raise SignalError(f"{text!r}: no device named {name!r}")
    signal = parse_signal(signal_text)
    devices[name].check(signal)
    return Endpoint(name, signal)
