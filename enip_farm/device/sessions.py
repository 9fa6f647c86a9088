"""The session handles of one device (CIP Networks Library Vol. 2, 2-4.4 RegisterSession, 2-4.5
UnRegisterSession): each client connection's RegisterSession gets a handle no open session holds,
up to the profile's `limits.max_sessions`; a restart numbers them from 1 again."""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable

from enip_farm.device.events import DeviceEvent, SessionEnded, SessionRegistered

_LAST = 0xFFFFFFFF


class SessionHandles:
    """Hands out and takes back one device's session handles, counting them (`sessions`,
    `sessions_refused`) and recording each (`SessionRegistered`, `SessionEnded`)."""

    def __init__(self, max_sessions: int, counters: Counter[str], record: Callable[[DeviceEvent], None]) -> None:
        self.max_sessions = max_sessions
        self.open: set[int] = set()
        self._counters = counters
        self._record = record
        self._next = 1

    def register(self, peer_host: str = "") -> int | None:
        """A new session handle, or None when the device holds `max_sessions` already."""
        if len(self.open) >= self.max_sessions:
            self._counters["sessions_refused"] += 1
            return None  # the session layer answers 0x0002, which the server reports
        self._counters["sessions"] += 1
        handle = self._next
        while handle in self.open:
            handle = handle + 1 if handle < _LAST else 1
        self._next = handle + 1 if handle < _LAST else 1
        self.open.add(handle)
        self._record(SessionRegistered(handle, peer_host))
        return handle

    def unregister(self, session_handle: int) -> None:
        self.open.discard(session_handle)
        self._record(SessionEnded(session_handle))

    def restart(self) -> None:
        """The device restarted: handles are numbered from 1 again."""
        self._next = 1
