"""The device event log: what happened to a device, with monotonic and wall-clock timestamps in
integer nanoseconds (the core's one time unit); the JSON form (`as_dict`) says seconds, as the API,
the event stream and the dashboard always have.

Request events keep their raw (service, path, status) and are formatted only when read, so that
logging every request stays cheap. The device tells its observers (guard.py, `Device.observe`);
the log only keeps what happened.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Iterator
from typing import Any, NamedTuple


class ImageChange(NamedTuple):
    """The detail of an "image changed" event: which image, its bytes before and after."""

    role: str  # "input" or "output"
    old: bytes
    new: bytes

    def __str__(self) -> str:
        return f"{self.role} {self.old.hex()} -> {self.new.hex()}"


class Event(NamedTuple):
    monotonic_ns: int  # when it happened, ns of the monotonic clock the core is given
    wall_ns: int  # the same moment, ns since the epoch
    device: str
    kind: str
    detail: Any  # a string; a dict (faults); for "request" the router's (service, path, status, extended, relayed)

    @property
    def text(self) -> str:
        detail = self.detail
        if self.kind == "request" and isinstance(detail, tuple):
            service, path, status, extended = detail[:4]
            text = f"service 0x{service:02X} path {path.hex(' ')} status 0x{status:02X}"
            return text if extended is None else f"{text} extended 0x{extended:04X}"
        if isinstance(detail, dict):  # e.g. a fault: "delay (delay_ms 800, duration_s 10)"
            rest = {key: value for key, value in detail.items() if key != "kind"}
            parameters = ", ".join(f"{key} {value:g}" if isinstance(value, float) else f"{key} {value}"
                                   for key, value in rest.items())
            head = str(detail.get("kind", ""))
            return f"{head} ({parameters})" if head and parameters else head or parameters
        return str(detail)

    def as_dict(self) -> dict[str, Any]:
        """The event as JSON takes it: a dict detail (a fault's parameters) stays a dict."""
        detail = self.detail
        return {"time": self.wall_ns / 1e9, "monotonic": self.monotonic_ns / 1e9, "device": self.device,
                "kind": self.kind, "detail": dict(detail) if isinstance(detail, dict) else self.text}


class EventLog:
    """A bounded log; the oldest events fall off the end. Entries are stored as plain tuples and
    become Events (with a wall-clock time) only when read or streamed: recording a request costs
    well under a microsecond."""

    def __init__(self, device: str, size: int = 10000) -> None:
        self.device = device
        self._entries: deque[tuple[int, str, Any]] = deque(maxlen=size)
        self._wall_offset_ns = time.time_ns() - time.monotonic_ns()  # monotonic -> wall clock

    @property
    def wall_offset_ns(self) -> int:
        """Wall-clock time minus monotonic time (ns): an Event's `wall_ns` is its `monotonic_ns` plus this."""
        return self._wall_offset_ns

    def record(self, kind: str, detail: Any, now: int) -> Event:
        """Keep an event that happened at `now` (ns, monotonic)."""
        entry = (now, kind, detail)
        self._entries.append(entry)
        return self._event(entry)

    def request(self, handled: tuple, now: int) -> tuple[int, str, Any]:
        """One explicit request answered at `now` (ns), as the message router answered it (its
        `Handled` tuple); the raw entry (`event` makes it an Event), so that logging a request costs
        no more than a tuple."""
        entry = (now, "request", handled)
        self._entries.append(entry)
        return entry

    def event(self, entry: tuple[int, str, Any]) -> Event:
        """An Event of an entry (now, kind, detail), whether kept in the log or not."""
        return self._event(entry)

    def _event(self, entry: tuple[int, str, Any]) -> Event:
        monotonic_ns, kind, detail = entry
        return Event(monotonic_ns, monotonic_ns + self._wall_offset_ns, self.device, kind, detail)

    def __iter__(self) -> Iterator[Event]:
        return iter([self._event(entry) for entry in list(self._entries)])

    def of_kind(self, kind: str) -> list[Event]:
        return [self._event(entry) for entry in list(self._entries) if entry[1] == kind]
