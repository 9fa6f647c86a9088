"""The device event log: what happened to a device, with monotonic and wall-clock timestamps."""

from __future__ import annotations

import time
from collections import deque
from typing import NamedTuple


class Event(NamedTuple):
    monotonic: float
    wall: float
    device: str
    kind: str
    detail: str


class EventLog:
    """A bounded log; the oldest events fall off the end."""

    def __init__(self, device: str, size: int = 1000) -> None:
        self.device = device
        self._events: deque[Event] = deque(maxlen=size)

    def record(self, kind: str, detail: str = "") -> Event:
        event = Event(time.monotonic(), time.time(), self.device, kind, detail)
        self._events.append(event)
        return event

    def __iter__(self):
        return iter(list(self._events))

    def of_kind(self, kind: str) -> list[Event]:
        return [event for event in list(self._events) if event.kind == kind]
