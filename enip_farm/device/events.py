"""The device event log: what happened to a device, with monotonic and wall-clock timestamps.

Request events keep their raw (service, path, status) and are formatted only when read, so that
logging every request stays cheap. Subscribers (the HTTP event stream) are called on record.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable, Iterator
from typing import Any, NamedTuple


class Event(NamedTuple):
    monotonic: float
    wall: float
    device: str
    kind: str
    detail: Any  # a string, or for "request" a (service, path bytes, general status) tuple

    @property
    def text(self) -> str:
        if self.kind == "request" and isinstance(self.detail, tuple):
            service, path, status = self.detail
            return f"service 0x{service:02X} path {path.hex(' ')} status 0x{status:02X}"
        return str(self.detail)

    def as_dict(self) -> dict[str, Any]:
        return {"time": self.wall, "monotonic": self.monotonic, "device": self.device, "kind": self.kind,
                "detail": self.text}


class EventLog:
    """A bounded log; the oldest events fall off the end."""

    def __init__(self, device: str, size: int = 10000) -> None:
        self.device = device
        self._events: deque[Event] = deque(maxlen=size)
        self.subscribers: list[Callable[[Event], None]] = []

    def record(self, kind: str, detail: Any = "") -> Event:
        event = Event(time.monotonic(), time.time(), self.device, kind, detail)
        self._events.append(event)
        for subscriber in self.subscribers:
            subscriber(event)
        return event

    def __iter__(self) -> Iterator[Event]:
        return iter(list(self._events))

    def of_kind(self, kind: str) -> list[Event]:
        return [event for event in list(self._events) if event.kind == kind]
