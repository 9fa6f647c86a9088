"""A device's reset as the farm carries it out (Identity Reset, CIP Networks Library Vol. 1,
5-2.4.1; the device's own part is device/reset.py). A device tells its observers of a reset it
performed by a `Reset` event (device/events.py: the Identity object's `ResetRequested`, or the
API's reset button); observing that class, never an event's text, the farm
closes the device's TCP connections and its listener once the reply has been written (the event
loop runs the close after the write), and listens again when the device's reset window ends
(`Device.end_reset`, asked at the window's deadline and never before)."""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable, Coroutine
from typing import Any

from enip_farm.device.device import Device
from enip_farm.device.events import Reset
from enip_farm.device.faults import Disconnect
from enip_farm.farm.listeners import BindError, Listeners
from enip_farm.server.waits import os_wait_s

log = logging.getLogger(__name__)


class FarmResets:
    """Closes and reopens the TCP side of the farm's devices around their resets."""

    def __init__(self, listeners: Listeners, spawn: Callable[[Coroutine[Any, Any, Any]], None]) -> None:
        """`spawn`: runs a coroutine as a task of the farm (its exception reaches the loop's handler)."""
        self.listeners = listeners
        self.spawn = spawn
        self.timers: dict[str, asyncio.TimerHandle] = {}  # each resetting device's end of window
        self.loop: asyncio.AbstractEventLoop | None = None  # while the farm serves (`start`, `stop`)

    def start(self, loop: asyncio.AbstractEventLoop) -> None:
        """The farm serves from `loop`: resets are carried out from now."""
        self.loop = loop

    def stop(self) -> None:
        self.loop = None
        for timer in self.timers.values():
            timer.cancel()
        self.timers.clear()

    def observe(self, device: Device) -> None:
        """Carry out `device`'s resets from now on."""
        device.observe(lambda _: self.on_reset(device), Reset)

    def on_reset(self, device: Device) -> None:
        """A device's observer of its `Reset` events (any thread): the reset is carried out on the
        loop, after the reply."""
        loop = self.loop
        if loop is not None:
            loop.call_soon_threadsafe(self._begin, device)

    def _begin(self, device: Device) -> None:
        """On the loop, after the Reset's reply was written: the device's sessions end (its TCP
        connections close) and it takes no connection until its reset window ends."""
        if self.loop is None:
            return
        self.listeners.close_connections(device)
        self.listeners.stop_listening(device.name)
        self._arm_end(device)

    def power_returned(self, device: Device) -> None:
        """On the loop: a device whose power came back boots (its reset window): the TCP connections it
        had are reset, as a rebooted stack answers their next segment, and it listens once booted."""
        if self.loop is None:
            return
        self.listeners.close_connections(device, Disconnect.RESET)
        self.listeners.stop_listening(device.name)
        self._arm_end(device)

    def _arm_end(self, device: Device) -> None:
        due = device.reset_window.due()
        timer = self.timers.pop(device.name, None)
        if timer is not None:
            timer.cancel()
        if due is not None and self.loop is not None:
            delay_s = os_wait_s((due - device.clock()) / 1e9)
            self.timers[device.name] = self.loop.call_later(delay_s, self._end, device)

    def _end(self, device: Device) -> None:
        self.timers.pop(device.name, None)
        if not device.end_reset():
            self._arm_end(device)  # the timer came a little early: wait for the deadline itself
            return
        self_test_ns = device.hardware.begin_self_test()
        if self_test_ns and self.loop is not None:  # answering, self testing, then operational
            self.timers[f"{device.name} self test"] = self.loop.call_later(
                os_wait_s(self_test_ns / 1e9), self._self_tested, device)
        if self.loop is not None and device.faults.listens and not self.listeners.listening(device.name):
            self.spawn(self._listen_after_reset(device))

    def _self_tested(self, device: Device) -> None:
        self.timers.pop(f"{device.name} self test", None)
        device.hardware.end_self_test()

    async def _listen_after_reset(self, device: Device) -> None:
        try:
            await self.listeners.listen(device)
        except BindError as error:  # someone took the address meanwhile: say so, keep serving the others
            log.error("%s (after its reset)", error)
