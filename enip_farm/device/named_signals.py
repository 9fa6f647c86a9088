"""Named signals as RobotWare's EIO_SIGNAL entries define them: a name, a type (DI, DO, GI, GO, AI,
AO) and a device map, the 0-based bit positions of the value in the device's input image (DI, GI,
AI) or output image (DO, GO, AO), least significant bit first ("8-15": bit 8 is the value's bit 0;
"15-8" the reverse). A GI/GO is an unsigned integer over its bits; an AI/AO is unsigned or two's
complement (`enc_type`) and, when the four of min/max logical and min/max bit value are given,
scaled linearly between them as the controller shows it."""

from __future__ import annotations

import math
import re
from typing import NamedTuple

from enip_farm.config import SignalConfig
from enip_farm.device.catalogue import MAX_ASSEMBLY_SIZE

TYPES = ("DI", "DO", "GI", "GO", "AI", "AO")
_RANGE = re.compile(r"^\s*(\d+)\s*(?:-\s*(\d+)\s*)?$")
#: A signal's value has at most this many bits (GI/GO, AI/AO).
MAX_BITS = 32
#: Bits of the largest image an assembly holds: no device map names a bit beyond it.
IMAGE_BITS = 8 * MAX_ASSEMBLY_SIZE


class SignalError(ValueError):
    """A signal that does not exist, cannot be mapped or cannot take a value; the message names it."""


def parse_device_map(text: str) -> tuple[int, ...]:
    """`"0-7,9"` -> (0, 1, ..., 7, 9): bit positions in listed order (descending ranges reversed)."""
    bits: list[int] = []
    for part in text.split(","):
        match = _RANGE.match(part)
        if not match:
            raise SignalError(f"device map {text!r}: {part.strip()!r} is not a bit or a range like 8-15")
        first = int(match[1])
        last = int(match[2]) if match[2] is not None else first
        if max(first, last) >= IMAGE_BITS:
            raise SignalError(f"device map {text!r}: bit {max(first, last)} is beyond the largest image "
                              f"({MAX_ASSEMBLY_SIZE} bytes, bits 0-{IMAGE_BITS - 1})")
        if abs(last - first) >= MAX_BITS:
            raise SignalError(f"device map {text!r}: {part.strip()!r} spans {abs(last - first) + 1} bits; a signal "
                              f"has at most {MAX_BITS}")
        step = 1 if last >= first else -1
        bits.extend(range(first, last + step, step))
    if len(set(bits)) != len(bits):
        raise SignalError(f"device map {text!r} names a bit twice")
    return tuple(bits)


class Scale(NamedTuple):
    """Logical value = min_log + (raw - min_bit) * (max_log - min_log) / (max_bit - min_bit)."""

    min_log: float
    max_log: float
    min_bit: float
    max_bit: float

    def logical(self, raw: int) -> float:
        return self.min_log + (raw - self.min_bit) * (self.max_log - self.min_log) / (self.max_bit - self.min_bit)

    def raw(self, logical: float) -> int:
        return round(self.min_bit + (logical - self.min_log) * (self.max_bit - self.min_bit)
                     / (self.max_log - self.min_log))


class NamedSignal(NamedTuple):
    name: str
    type: str  # DI, DO, GI, GO, AI or AO
    bits: tuple[int, ...]  # 0-based bit positions in the image, the value's least significant first
    invert: bool = False  # DI/DO: the physical bit is the inverse of the value
    signed: bool = False  # AI/AO with enc_type TWO_COMP
    scale: Scale | None = None

    @property
    def role(self) -> str:
        return "input" if self.type[1] == "I" else "output"

    @property
    def digital(self) -> bool:
        return self.type in ("DI", "DO")

    @property
    def count(self) -> int:
        return 1

    @property
    def raw_range(self) -> tuple[int, int]:
        width = len(self.bits)
        return (-(1 << width - 1), (1 << width - 1) - 1) if self.signed else (0, (1 << width) - 1)

    def __str__(self) -> str:
        return self.name

    def read(self, image: bytes | bytearray) -> int | float:
        raw = 0
        for position, bit in enumerate(self.bits):
            raw |= (image[bit // 8] >> bit % 8 & 1) << position
        if self.invert and self.digital:
            raw ^= 1
        if self.signed and raw >> len(self.bits) - 1:
            raw -= 1 << len(self.bits)
        return self.scale.logical(raw) if self.scale else raw

    def encode(self, value: int | float) -> int:
        """The raw value for `value`; SignalError if it does not fit the signal."""
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise SignalError(f"{self.name}: values are numbers, got {value!r}")
        if self.scale is None and not isinstance(value, int):
            raise SignalError(f"{self.name}: values are integers, got {value!r}")
        if isinstance(value, float) and not math.isfinite(value):
            raise SignalError(f"{self.name}: values are finite numbers, got {value!r}")
        try:
            raw = self.scale.raw(value) if self.scale else int(value)
        except OverflowError:  # a finite value whose scaling is beyond any float
            raise SignalError(f"{self.name}: {value!r} is out of range ({self._range_text()})") from None
        low, high = (0, 1) if self.digital else self.raw_range
        if self.scale:  # the controller limits the logical value to its range
            ends = sorted((self.scale.raw(self.scale.min_log), self.scale.raw(self.scale.max_log)))
            low, high = max(low, ends[0]), min(high, ends[1])
        if not low <= raw <= high:
            raise SignalError(f"{self.name}: {value!r} is out of range ({self._range_text()})")
        return raw

    def write(self, image: bytearray, value: int | float) -> None:
        """Write into an image in place (the caller holds the device lock)."""
        raw = self.encode(value)
        if self.invert and self.digital:
            raw ^= 1
        for position, bit in enumerate(self.bits):
            if raw >> position & 1:
                image[bit // 8] |= 1 << bit % 8
            else:
                image[bit // 8] &= ~(1 << bit % 8) & 0xFF

    def _range_text(self) -> str:
        if self.digital:
            return "0 or 1"
        if self.scale:
            return f"{min(self.scale.min_log, self.scale.max_log):g}..{max(self.scale.min_log, self.scale.max_log):g}"
        low, high = self.raw_range
        return f"{low}..{high}"


def named_signal(config: SignalConfig) -> NamedSignal:
    """The signal an EIO_SIGNAL-like configuration entry describes; SignalError if its map does
    not fit its type (DI/DO: one bit; GI/GO up to 32 bits; AI/AO up to 32 bits)."""
    bits = parse_device_map(config.device_map)
    if config.type in ("DI", "DO") and len(bits) != 1:
        raise SignalError(f"signal {config.name}: a {config.type} maps one bit, not {config.device_map!r}")
    if len(bits) > MAX_BITS:
        raise SignalError(f"signal {config.name}: {len(bits)} bits; at most {MAX_BITS}")
    limits = (config.min_log, config.max_log, config.min_bit_val, config.max_bit_val)
    scale = None
    if config.type in ("AI", "AO") and all(limit is not None for limit in limits):
        scale = Scale(*limits)  # type: ignore[arg-type]
        if scale.max_log == scale.min_log or scale.max_bit == scale.min_bit:
            raise SignalError(f"signal {config.name}: min and max of the scaling are equal")
    return NamedSignal(config.name, config.type, bits, invert=config.invert and config.type in ("DI", "DO"),
                       signed=config.enc_type == "TWO_COMP" and config.type in ("AI", "AO"), scale=scale)
