"""I/O changes by signal name, for the event stream's "io" events: which signals of a device an
image change touched, with their values before and after.

Image changes arrive as `ImageChanged` events (device/events.py: the role and the
whole image before and after). `SignalDiff` names the signals whose bytes differ and whose value
changed, numbered (DI1.., DO1.., AI1.., AO1..) and named (device/signals.py `SignalMap`), in the
map's listing order. `coalesce` merges the changes of one batch per device and image: the image
before the first and after the last, so that a signal set and cleared within one batch is no
change, and a device changing at any rate costs one "io" event per batch.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any, NamedTuple

from enip_farm.device.events import Event, ImageChanged
from enip_farm.device.signals import Signal, SignalMap

IO_KIND = "io"


class IoChange(NamedTuple):
    """The detail of an "io" event."""

    role: str  # "input" or "output"
    signals: dict[str, tuple[int | float, int | float]]  # name -> (old, new), listing order
    changes: int  # image changes merged into this one

    kind = IO_KIND

    @property
    def text(self) -> str:
        return f"{self.role} " + ", ".join(f"{name} {old} -> {new}" for name, (old, new) in self.signals.items())

    def __str__(self) -> str:
        return self.text

    def as_dict(self, event: Event) -> dict[str, Any]:
        return {"time": event.wall_ns / 1e9, "monotonic": event.monotonic_ns / 1e9, "device": event.device,
                "kind": IO_KIND, "role": self.role, "signals": {name: {"old": old, "new": new}
                                               for name, (old, new) in self.signals.items()},
                "changes": self.changes, "detail": self.text}


class SignalDiff:
    """The signals of one device by the bytes they occupy in each image."""

    def __init__(self, signals: SignalMap) -> None:
        self.signals = signals
        self._by_byte: dict[str, dict[int, list[int]]] = {"input": {}, "output": {}}
        self._entries: list[tuple[str, Signal]] = []
        for info in signals.listing():
            index = len(self._entries)
            self._entries.append((info.name, signals.lookup(info.name)))
            for byte in sorted({bit // 8 for bit in info.bits}):
                self._by_byte[info.role].setdefault(byte, []).append(index)

    def changes(self, role: str, old: bytes, new: bytes) -> dict[str, tuple[int | float, int | float]]:
        """The signals of image `role` whose value differs between `old` and `new` (equal lengths)."""
        by_byte = self._by_byte[role]
        touched: set[int] = set()
        for byte, (before, after) in enumerate(zip(old, new, strict=True)):
            if before != after and byte in by_byte:
                touched.update(by_byte[byte])
        out: dict[str, tuple[int | float, int | float]] = {}
        for index in sorted(touched):
            name, signal = self._entries[index]
            before_value = self.signals.value(signal, old)
            after_value = self.signals.value(signal, new)
            if before_value != after_value:
                out[name] = (before_value, after_value)  # type: ignore[assignment]  # one signal, one value
        return out


def coalesce(events: Iterable[Event], diff_of: Any) -> list[Event]:
    """`events` in order, with each device's `ImageChanged` events merged per image into one "io"
    event at the place of the last of them (none when no signal's value changed in the end).
    `diff_of(device_name)` gives that device's `SignalDiff`."""
    events = list(events)
    merged: dict[tuple[str, str], list] = {}  # (device, role) -> [old, new, count, index of the last]
    for index, event in enumerate(events):
        change = event.detail
        if isinstance(change, ImageChanged):
            key = (event.device, change.role)
            entry = merged.get(key)
            if entry is None:
                merged[key] = [change.old, change.new, 1, index]
            else:
                entry[1], entry[2], entry[3] = change.new, entry[2] + 1, index
    if not merged:
        return events
    last = {entry[3]: (key, entry) for key, entry in merged.items()}
    out: list[Event] = []
    for index, event in enumerate(events):
        if not isinstance(event.detail, ImageChanged):
            out.append(event)
        elif index in last:
            (device, role), (old, new, count, _) = last[index]
            signals = diff_of(device).changes(role, old, new) if len(old) == len(new) else {}
            if signals:
                out.append(Event(event.monotonic_ns, event.wall_ns, device, IoChange(role, signals, count)))
    return out
