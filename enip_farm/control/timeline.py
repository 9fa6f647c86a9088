"""A device's signal timeline, as a logic analyser shows it: every DI/DO/AI/AO (and named signal)
of the device over the last N seconds as steps, with each image change marked by who made it:
`o->t` (the controller's class-1 data), `explicit` (the controller's Set_Attribute, a request
answered at the same instant), a connection event's kind (e.g. `connection timed out`: the outputs
fell to their fault state), or `stimulus` (the input image, set by the test through the Python or
HTTP API, or by the wiring). A test that forces outputs through the API shows as `o->t`: the farm
cannot tell the two apart without a source on the image change. A running scenario's steps
(`scenario step` events of the devices a step touches) come as `steps`, each with its line.

Recording is lazy: a device's changes are kept from the first time its timeline is asked for (the
dashboard asks when a timeline is opened), at most `MAX_CHANGES` of them and none older than
`KEEP_NS`, so that a farm of many devices pays nothing for the ones nobody looks at, and memory
stays bounded whatever the controller writes.
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Mapping
from typing import Any

from enip_farm.device.device import Device
from enip_farm.device.events import Event, ImageChanged, RequestHandled, ScenarioStep
from enip_farm.device.signals import SignalMap

MAX_CHANGES = 4096  # per device
KEEP_NS = 600 * 1_000_000_000  # the longest window a timeline shows
MAX_SECONDS = KEEP_NS // 1_000_000_000


class DeviceRecorder:
    """One device's image changes, each with who made it; `observe` runs in the thread that made it."""

    def __init__(self, device: Device, now_ns: int) -> None:
        self.device = device
        self.since_ns = now_ns
        self.signals = SignalMap(device.profile)
        self.changes: deque[tuple[int, str, bytes, bytes, str]] = deque(maxlen=MAX_CHANGES)
        self.steps: deque[tuple[int, str]] = deque(maxlen=MAX_CHANGES)  # a scenario's steps: (when, line)
        self._last: tuple[int, Any] = (-1, None)  # the last other event: (when, what)
        self.unobserve = device.observe(self.observe)

    def observe(self, event: Event) -> None:
        change = event.detail
        if not isinstance(change, ImageChanged):
            self._last = (event.monotonic_ns, change)
            if isinstance(change, ScenarioStep):
                self.steps.append((event.monotonic_ns, change.line))
            return
        if change.role == "input":
            by = "stimulus"
        elif self._last[0] == event.monotonic_ns:  # made by what happened at the same instant: its kind
            by = "explicit" if isinstance(self._last[1], RequestHandled) else self._last[1].kind
        else:
            by = "o->t"
        self.changes.append((event.monotonic_ns, change.role, change.old, change.new, by))

    def timeline(self, seconds: float, now_ns: int) -> dict[str, Any]:
        """The last `seconds` up to `now_ns`: each signal's value at the window's start and each
        change after it ([t, value], t in seconds of the monotonic clock), and the marks."""
        start = max(now_ns - int(seconds * 1e9), self.since_ns)
        changes = [c for c in list(self.changes) if start <= c[0] <= now_ns]
        images = {"input": self.device.inputs, "output": self.device.outputs}
        for role in images:  # the image at the window's start: before the first change after it
            first = next((c for c in changes if c[1] == role), None)
            if first is not None:
                images[role] = first[2]
        listing = self.signals.listing()
        values = {**self.signals.values("input", images["input"]), **self.signals.values("output", images["output"])}
        traces: dict[str, list[list[Any]]] = {info.name: [[start / 1e9, values[info.name]]] for info in listing}
        marks = []
        for at, role, _old, new, by in changes:
            now_values = self.signals.values(role, new)
            changed = [name for name, value in now_values.items() if values.get(name) != value]
            for name in changed:
                traces[name].append([at / 1e9, now_values[name]])
                values[name] = now_values[name]
            if changed:
                marks.append({"at": at / 1e9, "role": role, "by": by, "signals": changed})
        return {"device": self.device.name, "now": now_ns / 1e9, "start": start / 1e9,
                "recording_since": self.since_ns / 1e9, "seconds": seconds,
                "signals": [{"name": info.name, "type": info.type, "role": info.role, "values": traces[info.name]}
                            for info in listing],
                "marks": marks,
                "steps": [{"at": at / 1e9, "text": line} for at, line in list(self.steps) if start <= at <= now_ns]}


class Timelines:
    """The recorders of the devices whose timeline was asked for."""

    def __init__(self, devices: Mapping[str, Device]) -> None:
        self.devices = devices
        self._recorders: dict[str, DeviceRecorder] = {}
        self._lock = threading.Lock()

    def timeline(self, name: str, seconds: float, now_ns: int) -> dict[str, Any]:
        device = self.devices[name]
        with self._lock:
            recorder = self._recorders.get(name)
            if recorder is None or recorder.device is not device:  # a device replaced: record it anew
                if recorder is not None:
                    recorder.unobserve()
                recorder = self._recorders[name] = DeviceRecorder(device, now_ns)
        return recorder.timeline(seconds, now_ns)

    def close(self) -> None:
        with self._lock:
            for recorder in self._recorders.values():
                recorder.unobserve()
            self._recorders.clear()
