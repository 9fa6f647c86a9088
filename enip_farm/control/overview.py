"""The dashboard's overview of a plant: every device's state in one cheap answer (GET /overview),
and the farm's recent events, so that a page opened now shows what happened before it.

A device is in exactly one state, the first that holds of:
- `faulted`: a fault is injected (device/faults.py), whatever its connections do;
- `running`: a class-1 (I/O) connection is open (Vol. 2, 3-4: exclusive owner, input only, listen
  only, CIP Safety);
- `timed_out`: none is open and the last class-1 connection to end ended by a timeout (its
  connection's watchdog, Vol. 1, 3-4.4.2), until another opens or one closes normally;
- `idle`: otherwise.

How the last class-1 connection ended is learnt from the devices' events as they happen, by their
classes (an observer of the connection events and the device's other events, not of explicit
requests and image changes, that keeps the device's last ending and a bounded list of the recent
events); everything else is read when asked, so a poll costs a few microseconds per device and
nothing runs between polls. The observer is called in whatever thread made the event (the cyclic
I/O thread included): an append and a dict store.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Iterable
from typing import Any

from enip_farm.cip.connection import ConnectionKind
from enip_farm.cip.connection_events import ConnectionEnded, ConnectionEvent, ConnectionTimedOut
from enip_farm.device.device import Device
from enip_farm.device.events import Event, Happened

STATES = ("idle", "running", "timed_out", "faulted")
RECENT = 500  # events kept for a page that opens now
#: Not kept as recent: too many and too small (the stream carries them, coalesced, live).


class Overview:
    """Observes `devices` from construction until `close`."""

    def __init__(self, devices: Iterable[Device], recent: int = RECENT) -> None:
        self.devices = list(devices)
        self.recent: deque[Event] = deque(maxlen=recent)
        self._timed_out: dict[str, bool] = {}  # device -> whether its last class-1 connection timed out
        #: Not kept as recent: requests and image changes, too many and too small (the stream
        #: carries them, coalesced, live); so observed: the connection events and the device's others.
        self._unobserve = [device.observe(self._observe, ConnectionEvent, Happened) for device in self.devices]

    def _observe(self, event: Event) -> None:
        self.recent.append(event)
        ended = event.detail
        if isinstance(ended, ConnectionEnded) and ended.connection.kind is not ConnectionKind.EXPLICIT:
            self._timed_out[event.device] = isinstance(ended, ConnectionTimedOut)

    def close(self) -> None:
        for unobserve in self._unobserve:
            unobserve()
        self._unobserve = []

    def describe(self, device: Device) -> dict[str, Any]:
        """One device as a tile shows it."""
        p = device.profile
        io = sum(connection.is_io for connection in device.connections.values())
        faults = list(device.faults.active)  # one atomic copy: the loop changes it
        if faults:
            state = "faulted"
        elif io:
            state = "running"
        else:
            state = "timed_out" if self._timed_out.get(device.name) else "idle"
        return {"name": p.name, "address": p.address, "model": p.model, "addons": list(p.addons), "state": state,
                "io_connections": io, "timeouts": device.counters["connection_timeouts"], "faults": faults}

    def snapshot(self, events: int = 0) -> dict[str, Any]:
        """Every device (configuration order), the count in each state, and the last `events` recent
        events, oldest first, as GET /events sends them."""
        devices = [self.describe(device) for device in self.devices]
        counts = dict.fromkeys(STATES, 0)
        for device in devices:
            counts[device["state"]] += 1
        recent = list(self.recent)[-events:] if events > 0 else []
        return {"monotonic": time.monotonic(), "counts": counts, "devices": devices,
                "events": [event.as_dict() for event in recent]}
