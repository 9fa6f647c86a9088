"""Faults switched on and off on the farm's loop, for one device or a group at once (the kinds:
device/fault_kinds.py and device/cell_fault_kinds.py; a group: enip_farm/topology.py).

A fault is set on every member in one turn of the loop, at one `now`: its hooks say whether open TCP
connections end (`on_tcp_connection`), whether TCP listens (`listens`) and whether what is open goes
silent (`hears`); `on_set` and `on_clear` act on the module itself (its power, its address); a kind
with `phases` (a flapping link) has its effects switched off and on by a task; `duration_s` ends it
by a timer. A device that restarts as its fault clears (power back) has its open TCP connections
reset, as a rebooted stack answers their next segment, and listens again when it has booted
(farm/resets.py)."""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Coroutine, Iterable, Iterator, Mapping
from typing import Any

from enip_farm.device.device import Device
from enip_farm.device.events import AddressStillTaken, FaultCleared, FaultInjected, LinkDown, LinkUp
from enip_farm.device.faults import Disconnect, FaultType
from enip_farm.farm.listeners import BindError, Listeners
from enip_farm.farm.resets import FarmResets
from enip_farm.server.waits import os_wait_s


class FarmFaults:
    """The faults of the farm's devices: set, timed, flapped and cleared on the farm's loop."""

    def __init__(self, devices: Mapping[str, Device], listeners: Listeners, resets: FarmResets,
                 spawn: Callable[[Coroutine[Any, Any, Any]], None], running: Callable[[], bool],
                 clock: Callable[[], int]) -> None:
        self.devices = devices
        self.listeners = listeners
        self.resets = resets
        self.spawn = spawn
        self.running = running
        self.clock = clock  # the farm's: when a fault was set or cleared
        self.timers: dict[tuple[str, str], asyncio.TimerHandle] = {}
        self.flaps: dict[tuple[str, str], asyncio.Task] = {}
        self.off_network: set[str] = set()  # configured onto another device's address (duplicate_address)

    def stop(self) -> None:
        for timer in self.timers.values():
            timer.cancel()
        self.timers.clear()
        for task in self.flaps.values():
            task.cancel()
        self.flaps.clear()

    async def inject(self, names: Iterable[str], fault: FaultType) -> None:
        """Switch `fault` on for every device of `names` at once (one `now`, one turn of the loop)."""
        loop = asyncio.get_running_loop()
        now = self.clock()
        end = None if fault.duration_ns is None else loop.time() + fault.duration_ns / 1e9
        for name in names:
            device = self.devices[name]
            self._forget(name, fault.name)
            previous = device.faults.active.get(fault.name)
            if previous is not None:
                previous.on_clear(device.hardware, now)
            device.record(FaultInjected(fault.parameters()), now)
            fault.on_set(device.hardware, now)  # first: what it finds may decide its hooks (ACD)
            device.faults.set(fault, now)
            ends = fault.on_tcp_connection()
            if ends is not None or (not fault.listens() and fault.hears()):
                self.listeners.close_connections(device, ends or Disconnect.CLOSE)
            if not fault.listens():
                self.listeners.stop_listening(name)
            phases = fault.phases()
            if phases is not None:
                task = loop.create_task(self._flap(device, fault.name, phases))
                self.flaps[name, fault.name] = task
            if end is not None:
                self._arm_end(name, fault.name, end)

    async def _flap(self, device: Device, kind: str, phases: Iterator[tuple[float, float]]) -> None:
        """Down (the fault's effects on) and up (off) by `phases`, then up until the fault is cleared."""
        for down_s, up_s in phases:
            device.faults.suspend(kind, False)
            device.record(LinkDown(kind, down_s))
            await asyncio.sleep(os_wait_s(down_s))
            device.faults.suspend(kind, True)
            device.record(LinkUp(kind, up_s))
            await asyncio.sleep(os_wait_s(up_s))
        device.faults.suspend(kind, True)

    def _arm_end(self, name: str, kind: str, end: float) -> None:
        """Clear the fault at `end` (loop time), in bounded steps (server/waits.py)."""
        loop = asyncio.get_running_loop()
        delay = end - loop.time()
        if delay > 0 and os_wait_s(delay) < delay:
            self.timers[name, kind] = loop.call_later(os_wait_s(delay), self._arm_end, name, kind, end)
            return
        self.timers[name, kind] = loop.call_later(os_wait_s(delay), lambda: self.spawn(self.clear(name, kind)))

    def _forget(self, name: str, kind: str) -> None:
        timer = self.timers.pop((name, kind), None)
        if timer is not None:
            timer.cancel()
        task = self.flaps.pop((name, kind), None)
        if task is not None:
            task.cancel()

    async def clear(self, name: str, kind: str | None = None) -> list[str]:
        """Switch one fault (or all) of one device off; normal behaviour returns (after a boot, where
        the fault took the power). A device configured onto another's address keeps its conflict."""
        device = self.devices[name]
        faults = device.faults
        now = self.clock()
        kinds = [k for k in faults.active if kind is None or k == kind]
        if name in self.off_network and "address-conflict" in kinds:
            kinds.remove("address-conflict")
            device.record(AddressStillTaken("configured onto another device's address"), now)
        listens_again = not faults.listens and all(
            fault.listens() for k, fault in faults.active.items() if k not in kinds and k not in faults.suspended)
        booting = device.resetting
        for k in kinds:
            faults.active[k].on_clear(device.hardware, now)
        if device.resetting and not booting:  # the module restarts (power back): its TCP peers are stale
            self.resets.power_returned(device)
        if listens_again and self.running() and not self.listeners.listening(name) and not device.resetting:
            try:
                await self.listeners.listen(device)  # listening again before the fault is seen gone
            except BindError as error:  # someone took the address meanwhile: say so, keep serving the others
                device.record(AddressStillTaken(str(error)), now)
        cleared = [k for k in kinds for _ in faults.clear(k)]
        for k in cleared:
            self._forget(name, k)
        if cleared:
            device.record(FaultCleared(tuple(cleared)), now)
        return cleared
