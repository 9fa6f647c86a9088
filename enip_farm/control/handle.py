"""The Python API of one running device: its I/O as bytes, as RobotWare-style signals (DI1.., DO1..,
AI1.., AO1.., and the device's named signals such as diGripperClosed or goProgramNo), waiting for a
condition, counters, events, faults and an output-change hook.
Thread-safe: images are written under the device lock, so concurrent callers lose no write."""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Callable, Coroutine, Mapping
from typing import Any, Protocol, TypeVar, runtime_checkable

from enip_farm.config import FarmConfig
from enip_farm.device.device import Device, replace_image
from enip_farm.device.events import Event, ImageChanged
from enip_farm.device.faults import Fault, FaultKind, FaultType
from enip_farm.device.named_signals import NamedSignal
from enip_farm.device.report import FarmReport, TestBounds
from enip_farm.device.signals import Signal, SignalError, SignalMap

T = TypeVar("T")


@runtime_checkable
class FarmControl(Protocol):
    """What the control layer needs of a farm (`enip_farm.farm.farm.Farm` provides it): its devices and
    their handles, its event loop, and faults switched on the loop."""

    @property
    def config(self) -> FarmConfig: ...

    @property
    def devices(self) -> Mapping[str, Device]: ...

    @property
    def loop(self) -> asyncio.AbstractEventLoop | None: ...

    def __getitem__(self, name: str) -> DeviceHandle: ...

    def run(self, coroutine: Coroutine[Any, Any, T], timeout: float = ...) -> T: ...

    async def inject_fault(self, name: str, fault: FaultType) -> None: ...

    async def clear_faults(self, name: str, kind: str | None = None) -> list[str]: ...

    def mark(self, text: str) -> None: ...

    def health(self) -> dict[str, Any]: ...

    def cyclic_io_load(self) -> dict[str, Any]: ...

    def report(self, bounds: TestBounds = None) -> FarmReport: ...


class DeviceHandle:
    def __init__(self, farm: FarmControl, device: Device) -> None:
        self.farm = farm
        self.device = device
        self.signals = SignalMap(device.profile)
        self._changed = threading.Condition()

    def _notify(self, _: Event) -> None:
        """An observer of image changes while a `wait_for` waits."""
        with self._changed:
            self._changed.notify_all()

    # -- identity and images ----------------------------------------------------------------------

    @property
    def name(self) -> str:
        return self.device.name

    @property
    def address(self) -> str:
        return self.device.profile.address

    @property
    def inputs(self) -> bytes:
        return self.device.inputs

    @property
    def outputs(self) -> bytes:
        return self.device.outputs

    def set_inputs(self, data: bytes) -> None:
        self.device.set_inputs(data)

    # -- signals ------------------------------------------------------------------------------------

    def get(self, name: str) -> int | float | list[int]:
        """One signal's value (DI3 -> 0/1, AI2 -> INT, goProgramNo -> the integer over its bits, a
        scaled analog signal -> its logical value), or a list for a range (DI1-8)."""
        signal = self.signals.lookup(name)
        return self.signals.value(signal, self.device.inputs if signal.role == "input" else self.device.outputs)

    def set(self, values: Mapping[str, int | float | list[int]] | None = None,
            **signals: int | float | list[int]) -> None:
        """Set signals as a sensor (inputs) or a forcing test (outputs) would: set(DI3=1, AI1=1200),
        set(diGripperClosed=1) or set({"DI1-4": [1, 0, 1, 1]}). All or nothing (see `update`)."""
        self.update(signals={**(values or {}), **signals})

    def signal(self, name: str) -> dict[str, Any]:
        """One signal as `signal_table` shows it, looked up as `get` does: {"name", "type", "role",
        "value"}; for a numbered range (DI1-8) the value is a list. SignalError if there is none."""
        signal = self.signals.lookup(name)
        image = self.device.inputs if signal.role == "input" else self.device.outputs
        kind = signal.type if isinstance(signal, NamedSignal) else signal.kind
        return {"name": str(signal), "type": kind, "role": signal.role, "value": self.signals.value(signal, image)}

    def signal_table(self) -> list[dict[str, Any]]:
        """Every signal with its value: numbered (DI1.., DO1.., AI1.., AO1..) first, then named."""
        values = {**self.signals.values("input", self.device.inputs),
                  **self.signals.values("output", self.device.outputs)}
        return [{"name": info.name, "type": info.type, "role": info.role, "value": values[info.name]}
                for info in self.signals.listing()]

    def update(self, inputs: bytes | None = None, outputs: bytes | None = None,
               signals: Mapping[str, int | float | list[int]] | None = None) -> None:
        """Replace whole images and/or set signals, all or nothing: every change is first tried on
        copies of the images, so a bad signal name, value or image size (ValueError naming it)
        writes nothing; then each image changes in one locked step."""
        edits: dict[str, list[Callable[[bytearray], object]]] = {"input": [], "output": []}
        for role, data in (("input", inputs), ("output", outputs)):
            if data is not None:
                edits[role].append(lambda image, data=data, field=f"{role}s": replace_image(image, data, field))
        for name, value in (signals or {}).items():
            signal = self.signals.lookup(name)
            values = list(value) if isinstance(value, list) else [value] * signal.count
            _check_values(signal, values)
            edits[signal.role].append(lambda image, signal=signal, values=values:
                                      self.signals.write(signal, image, values))
        changes = {role: _chain(steps) for role, steps in edits.items() if steps}
        for role, change in changes.items():  # validate everything before writing anything
            change(bytearray(self.device.inputs if role == "input" else self.device.outputs))
        for role, change in changes.items():
            self.device.write_image(role, change)

    def wait_for(self, predicate: Callable[[DeviceHandle], bool], timeout: float = 5.0) -> None:
        """Block until predicate(handle) is true; raise TimeoutError after `timeout` seconds."""
        deadline = time.monotonic() + timeout
        unobserve = self.device.observe(self._notify, ImageChanged)  # only while waiting: the hot paths compare
        try:                                                          # no image while nobody waits
            with self._changed:
                while not predicate(self):
                    remaining = deadline - time.monotonic()
                    if remaining <= 0:
                        raise TimeoutError(f"{self.name}: condition not met within {timeout} s")
                    self._changed.wait(min(remaining, 0.01))  # other state (connections) is polled
        finally:
            unobserve()

    async def until(self, predicate: Callable[[DeviceHandle], bool], timeout: float = 5.0) -> None:
        """wait_for for async tests: waits in a worker thread, so the test's own loop keeps running."""
        await asyncio.to_thread(self.wait_for, predicate, timeout)

    # -- observation --------------------------------------------------------------------------------

    @property
    def counters(self) -> dict[str, Any]:
        out: dict[str, Any] = dict(self.device.counters)
        out["requests"] = {f"0x{s:02X}/0x{st:02X}": n for (s, st), n in self.device.router.request_counts.items()}
        out["open_connections"] = len(self.device.connections)
        return out

    def events(self, kind: str | type | None = None) -> list[Event]:
        """The device's events, oldest first: all, those of a class (device/events.py,
        cip/connection_events.py) or those of a kind as the API names it (`"tcp closed"`)."""
        if kind is None:
            return list(self.device.events)
        return self.device.events.of_type(kind) if isinstance(kind, type) else self.device.events.of_kind(kind)

    def on_output_change(self, callback: Callable[[DeviceHandle, bytes, bytes], None]) -> None:
        """callback(handle, old, new) after every change of the output image, in the thread that
        changed it (the farm's event loop or its cyclic I/O thread): keep it short."""
        def listener(event: Event) -> None:
            change: ImageChanged = event.detail
            if change.role == "output":
                callback(self, change.old, change.new)
        self.device.observe(listener, ImageChanged)

    # -- reset ----------------------------------------------------------------------------------------

    def reset(self, kind: int = 0) -> bool:
        """Reset the device as an Identity Reset of type `kind` does (0: power cycle, 1: out-of-box
        configuration, 2: out-of-box but the communication parameters): its TCP connections drop,
        its CIP connections close, it answers nothing for its `reset_time_s`, Identity attribute 8
        says self-testing meanwhile. False if it is resetting already."""
        return self.device.reset(kind)

    # -- faults -------------------------------------------------------------------------------------

    def inject(self, kind: FaultKind | str, duration_s: float | None = None, **params: Any) -> None:
        """Inject a fault now (see device/faults.py), for `duration_s` or until cleared. A parameter
        out of range raises `FaultError` (a ValueError) naming it, and nothing is injected."""
        self.farm.run(self.farm.inject_fault(self.name, Fault(kind, duration_s=duration_s, **params)))

    def clear_faults(self, kind: FaultKind | str | None = None) -> None:
        self.farm.run(self.farm.clear_faults(self.name, FaultKind(kind) if kind else None))

    @property
    def faults(self) -> list[dict]:
        return self.device.faults.describe(self.device.clock())


def _chain(steps: list[Callable[[bytearray], object]]) -> Callable[[bytearray], None]:
    def change(image: bytearray) -> None:
        for step in steps:
            step(image)
    return change


def _check_values(signal: Signal, values: list) -> None:
    if isinstance(signal, NamedSignal):
        if len(values) != 1:
            raise SignalError(f"{signal}: one value expected, got {len(values)}")
        signal.encode(values[0])
        return
    for value in values:
        if not isinstance(value, int):
            raise SignalError(f"{signal}: values are integers, got {value!r}")
        if signal.digital and value not in (0, 1):
            raise SignalError(f"{signal}: a digital signal is 0 or 1, got {value!r}")
