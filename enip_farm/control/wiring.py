"""Wiring and cell logic: outputs of one device wired to inputs of another, simple rules, and
Python hooks, applied whenever an image changes.

A wire copies bits (DO -> DI) or analog channels (AO -> AI) as soon as the source changes, in the
thread that changed it: for an explicit write that is before the device's reply is sent, so the
wired inputs are set by the time the write is acknowledged. Rules fire on a bit's edge and set
another bit, at once or after a delay (on the farm's event loop). Cycles are refused at load.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

from enip_farm.control.signals import SignalMap, SignalRange, parse_signal

if TYPE_CHECKING:
    from enip_farm.config import FarmConfig
    from enip_farm.device.device import Device
    from enip_farm.device.events import Event
    from enip_farm.farm import Farm


class Endpoint(NamedTuple):
    device: str
    signal: SignalRange

    def __str__(self) -> str:
        return f"{self.device}.{self.signal}"


def parse_endpoint(text: str, devices: dict[str, SignalMap]) -> Endpoint:
    name, _, signal_text = text.rpartition(".")
    if name not in devices:
        raise ValueError(f"{text!r}: no device named {name!r}")
    signal = parse_signal(signal_text)
    devices[name].check(signal)
    return Endpoint(name, signal)


def check_wiring(config: FarmConfig) -> None:
    """Validate wires and rules against the devices' signals, and refuse cycles."""
    if not config.wires and not config.rules:
        return
    from enip_farm.device.profile import resolve

    maps = {device.name: SignalMap(resolve(device)) for device in config.devices}
    edges: dict[tuple[str, str], set[tuple[str, str]]] = {}
    for wire in config.wires:
        source, target = parse_endpoint(wire.source, maps), parse_endpoint(wire.target, maps)
        if source.signal.role != "output" or target.signal.role != "input":
            raise ValueError(f"wire {source} -> {target}: wires go from outputs (DO, AO) to inputs (DI, AI)")
        if source.signal.digital != target.signal.digital or source.signal.count != target.signal.count:
            raise ValueError(f"wire {source} -> {target}: both ends need the same kind and number of signals")
        edges.setdefault((source.device, "output"), set()).add((target.device, "input"))
    for rule in config.rules:
        when, target = parse_endpoint(rule.when, maps), parse_endpoint(rule.set, maps)
        if when.signal.count != 1 or target.signal.count != 1 or not (when.signal.digital and target.signal.digital):
            raise ValueError(f"rule {when} -> {target}: a rule watches one bit and sets one bit")
        edges.setdefault((when.device, when.signal.role), set()).add((target.device, target.signal.role))
    _refuse_cycles(edges)


def _refuse_cycles(edges: dict[tuple[str, str], set[tuple[str, str]]]) -> None:
    state: dict[tuple[str, str], int] = {}  # 1 visiting, 2 done

    def visit(node: tuple[str, str], path: list[tuple[str, str]]) -> None:
        state[node] = 1
        for following in edges.get(node, ()):
            if state.get(following) == 1:
                cycle = path[path.index(following):] + [following] if following in path else [node, following]
                raise ValueError("wiring cycle: " + " -> ".join(f"{d}.{r}s" for d, r in cycle))
            if following not in state:
                visit(following, path + [following])
        state[node] = 2

    for node in list(edges):
        if node not in state:
            visit(node, [node])


class Wiring:
    """Applies a farm's wires and rules; installed as a change listener on every device."""

    def __init__(self, farm: Farm) -> None:
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
                device.observe(lambda event, device=device: self._observe(device, event))

    def _observe(self, device: Device, event: Event) -> None:
        if event.kind == "image changed":
            self.changed(device, *event.detail)

    def changed(self, device: Device, role: str, old: bytes, new: bytes) -> None:
        key = (device.name, role)
        signals = self.maps[device.name]
        for source, target in self.wires.get(key, ()):
            values = signals.read(source.signal, new)
            if values != signals.read(source.signal, old):
                self.write(target, values)
        for when, target, rule in self.rules.get(key, ()):
            before, after = signals.read(when.signal, old)[0], signals.read(when.signal, new)[0]
            if before != after and after == (1 if rule.edge == "rises" else 0):
                if rule.delay_ms:
                    loop = self.farm.loop
                    if loop is not None:
                        loop.call_soon_threadsafe(loop.call_later, rule.delay_ms / 1000, self.write, target,
                                                  [rule.value])
                else:
                    self.write(target, [rule.value])

    def write(self, target: Endpoint, values: list[int]) -> None:
        device = self.farm.devices[target.device]
        signals = self.maps[target.device]
        device.write_image(target.signal.role, lambda image: signals.write(target.signal, image, values))
        device.record("wired", f"{target} = {values if len(values) > 1 else values[0]}")
