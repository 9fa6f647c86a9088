"""Signal names as RobotWare gives them to a scalable I/O device: DI1..DIn and DO1..DOn (bits,
1-based, across the base and its add-ons in slot order), AI1.. and AO1.. (one INT each), the
device's named signals (EIO_SIGNAL entries, `device/named_signals.py`), and `DEVICE.SIGNAL`
endpoints across a cell. Where each numbered signal lives in the assemblies follows the
catalogue's layout (`device/catalogue.yaml`)."""

from __future__ import annotations

import re
import struct
from collections.abc import Mapping
from typing import NamedTuple

from enip_farm.device.named_signals import NamedSignal, SignalError
from enip_farm.device.profile import DeviceProfile

_NAME = re.compile(r"^(DI|DO|AI|AO)(\d+)(?:-(\d+))?$")
_INT = struct.Struct("<h")


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


class SignalInfo(NamedTuple):
    """One signal of a device as listings show it."""

    name: str
    type: str  # DI, DO, AI, AO (numbered) or DI, DO, GI, GO, AI, AO (named)
    role: str  # "input" or "output"
    digital: bool
    bits: tuple[int, ...]  # 0-based bit positions in the image, least significant first


Signal = SignalRange | NamedSignal


class SignalMap:
    """Byte offsets (and bits) of every signal of one device in its input and output assemblies,
    numbered (DI1..) and named."""

    def __init__(self, profile: DeviceProfile) -> None:
        self.named = {signal.name.casefold(): signal for signal in profile.signals}
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
        # an image configured smaller than its modules' channels (assemblies.input_size) ends the numbering
        sizes = {"DI": profile.input_size, "DO": profile.output_size, "AI": profile.input_size,
                 "AO": profile.output_size}
        for kind, bits in self.bits.items():
            bits[:] = [(offset, bit) for offset, bit in bits if offset < sizes[kind]]
        for kind, words in self.words.items():
            words[:] = [offset for offset in words if offset + 2 <= sizes[kind]]

    def lookup(self, text: str) -> Signal:
        """A named signal (case-insensitive, as RAPID names are) or a numbered range (DI3, DO1-16);
        SignalError naming `text` if the device has no such signal."""
        named = self.named.get(text.strip().casefold())
        if named is not None:
            return named
        try:
            signal = parse_signal(text)
        except SignalError:
            raise SignalError(f"{text!r} is neither a signal of this device nor a name like DI3, DO1-16 "
                              "or AI2") from None
        self.check(signal)
        return signal

    def value(self, signal: Signal, image: bytes | bytearray) -> int | float | list[int]:
        """A named signal's value, a numbered signal's value, or a list for a numbered range."""
        if isinstance(signal, NamedSignal):
            return signal.read(image)
        values = self.read(signal, image)
        return values[0] if signal.count == 1 else values

    def values(self, role: str, image: bytes | bytearray) -> dict[str, int | float]:
        """Every signal of one image by name: numbered first (DI1, DI2, ...), then named."""
        out: dict[str, int | float] = {}
        for kind in ("DI", "AI") if role == "input" else ("DO", "AO"):
            count = self.count(kind)
            if count:
                for number, value in enumerate(self.read(SignalRange(kind, 1, count), image), 1):
                    out[f"{kind}{number}"] = value
        for signal in self.named.values():
            if signal.role == role:
                out[signal.name] = signal.read(image)
        return out

    def listing(self) -> list[SignalInfo]:
        """Every signal of the device: numbered first, then named, in configuration order."""
        out = []
        for kind in ("DI", "DO", "AI", "AO"):
            role = "input" if kind in ("DI", "AI") else "output"
            if kind in self.bits:
                out += [SignalInfo(f"{kind}{n}", kind, role, True, (8 * offset + bit,))
                        for n, (offset, bit) in enumerate(self.bits[kind], 1)]
            else:
                out += [SignalInfo(f"{kind}{n}", kind, role, False, tuple(range(8 * offset, 8 * offset + 16)))
                        for n, offset in enumerate(self.words[kind], 1)]
        out += [SignalInfo(s.name, s.type, s.role, s.digital, s.bits) for s in self.named.values()]
        return out

    def count(self, kind: str) -> int:
        return len(self.bits[kind]) if kind in self.bits else len(self.words[kind])

    def check(self, signal: SignalRange) -> None:
        available = self.count(signal.kind)
        if signal.last > available:
            raise SignalError(f"{signal}: this device has {available} {signal.kind} signals")

    def read(self, signal: Signal, image: bytes | bytearray) -> list:
        """The values of a signal as a list (one item for a named signal)."""
        if isinstance(signal, NamedSignal):
            return [signal.read(image)]
        self.check(signal)
        span = slice(signal.first - 1, signal.last)
        if signal.digital:
            return [image[offset] >> bit & 1 for offset, bit in self.bits[signal.kind][span]]
        return [_INT.unpack_from(image, offset)[0] for offset in self.words[signal.kind][span]]

    def write(self, signal: Signal, image: bytearray, values: list) -> None:
        """Write values into an image in place (the caller holds the device lock)."""
        if isinstance(signal, NamedSignal):
            if len(values) != 1:
                raise SignalError(f"{signal}: one value expected, got {len(values)}")
            signal.write(image, values[0])
            return
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


def width(signal: Signal) -> int:
    """How many bits a signal's value spans (wires join signals of the same width)."""
    if isinstance(signal, NamedSignal):
        return len(signal.bits)
    return signal.count if signal.digital else 16 * signal.count


class Endpoint(NamedTuple):
    """A signal of one device of a cell: DEVICE.DOn[-m] or DEVICE.NAME, as wires and rules name them."""

    device: str
    signal: Signal

    def __str__(self) -> str:
        return f"{self.device}.{self.signal}"


def parse_endpoint(text: str, devices: Mapping[str, SignalMap]) -> Endpoint:
    """Raises ValueError (SignalError) naming the endpoint if the device or signal does not exist."""
    name, _, signal_text = text.rpartition(".")
    if name not in devices:
        raise SignalError(f"{text!r}: no device named {name!r}")
    try:
        return Endpoint(name, devices[name].lookup(signal_text))
    except SignalError as error:
        raise SignalError(f"{text!r}: {error}") from None
