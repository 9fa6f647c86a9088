"""Wiring and cell logic: outputs of one device wired to inputs of another, simple rules, and
Python hooks, applied whenever an image changes.

A wire copies bits (DO -> DI) or analog channels (AO -> AI) as soon as the source changes, in the
thread that changed it: for an explicit write that is before the device's reply is sent, so the
wired inputs are set by the time the write is acknowledged. Rules fire on a bit's edge and set
another bit, at once or after a delay (on the farm's event loop). Wires, rules and cycles are
checked when the farm's devices are built (`device/build.py`).
"""

from __future__ import annotations

from enip_farm.control.handle import FarmControl
from enip_farm.device.device import Device
from enip_farm.device.events import Event, ImageChanged, Wired
from enip_farm.device.signals import Endpoint, SignalMap, parse_endpoint


class Wiring:
    """Applies a farm's wires and rules; installed as a change listener on every device."""

    def __init__(self, farm: FarmControl) -> None:
        self.farm = farm
        self.maps = {name: SignalMap(device.profile) for name, device in farm.devices.items()}
        self.wires: dict[tuple[str, str], list[tuple[Endpoint, Endpoint]]] = {}
        self.rules: dict[tuple[str, str], list] = {}
        for wire in farm.config.wires:
            source, target = parse_endpoint(wire.source, self.maps), parse_endpoint(wire.target, self.maps)
            self.wires.setdefault((source.device, "output"), []).append((source, target))
        for rule in farm.config.rules:
            when, target = parse_endpoint(rule.when, self.maps), parse_endpoint(rule.set, self.maps)
            self.rules.setdefault((when.device, when.signal.role), []).append((when, target, rule))
        if self.wires or self.rules:
            for device in farm.devices.values():
                device.observe(lambda event, device=device: self._observe(device, event), ImageChanged)

    def _observe(self, device: Device, event: Event) -> None:
        self.changed(device, *event.detail)  # an ImageChanged: role, old, new

    def changed(self, device: Device, role: str, old: bytes, new: bytes) -> None:
        key = (device.name, role)
        signals = self.maps[device.name]
        for source, target in self.wires.get(key, ()):
            values = signals.read(source.signal, new)
            if values != signals.read(source.signal, old):
                self.write(target, values, f"wire from {source}")
        for when, target, rule in self.rules.get(key, ()):
            before, after = signals.read(when.signal, old)[0], signals.read(when.signal, new)[0]
            if before != after and after == (1 if rule.edge == "rises" else 0):
                cause = f"rule: {when} {rule.edge}"
                if rule.delay_ms:
                    loop = self.farm.loop
                    if loop is not None:
                        loop.call_soon_threadsafe(loop.call_later, rule.delay_ms / 1000, self.write, target,
                                                  [rule.value], f"{cause}, after {rule.delay_ms:g} ms")
                else:
                    self.write(target, [rule.value], cause)

    def write(self, target: Endpoint, values: list, cause: str) -> None:
        """Set the target and record a `Wired` event naming both ends by their signal names, e.g.
        `robot.giRecipe = 77 (wire from plc.goRecipe)` or `robot.DI1 = 1 (rule: plc.doStart rises)`."""
        device = self.farm.devices[target.device]
        signals = self.maps[target.device]
        device.write_image(target.signal.role, lambda image: signals.write(target.signal, image, values))
        device.record(Wired(str(target), tuple(values), cause))
