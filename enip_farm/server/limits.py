"""Guards of the farm's TCP side: caps on TCP connections per device and for the whole farm (the
latter also bounded by the process's open-file limit), and log lines that cannot flood the log
(`RateLimitedLog`, which the console uses too)."""

from __future__ import annotations

import logging
import resource
import threading
from collections import Counter

#: Descriptors kept free for everything that is not a client connection (listeners, UDP sockets,
#: the HTTP API, log and capture files).
RESERVED_DESCRIPTORS = 64


class RateLimitedLog:
    """At most `burst` lines per key and interval (a window opened by the key's first line). Lines
    held back are never lost: the next line of that key says how many there were, or, when no other
    line comes, `flush` shows the last of them with the count of the others once the window is over.
    Thread-safe; `now` is a monotonic time in seconds."""

    def __init__(self, logger: logging.Logger, interval_s: float = 10.0, burst: int = 1) -> None:
        self.logger = logger
        self.interval_s = interval_s
        self.burst = burst
        self._windows: dict[str, list[float]] = {}  # key -> [window start, lines shown in it]
        self._held: dict[str, tuple[int, int, str, tuple]] = {}  # key -> (count, level, message, args) of the last
        self._lock = threading.Lock()

    def log(self, level: int, key: str, now: float, message: str, *args: object,
            exc_info: bool | BaseException = False) -> bool:
        """Log the line unless its key has had `burst` lines in this window; True if it was shown.
        `exc_info`: a line shown carries the exception being handled, or the one given (a line held
        back does not)."""
        with self._lock:
            window = self._windows.get(key)
            held = None
            if window is None or now - window[0] >= self.interval_s:
                window = self._windows[key] = [now, 0]
                held = self._held.pop(key, None)
            if window[1] >= self.burst:
                count = self._held[key][0] + 1 if key in self._held else 1
                self._held[key] = (count, level, message, args)
                return False
            window[1] += 1
        if held is not None:
            message += f" ({held[0]} more like this since the last line)"
        self.logger.log(level, message, *args, exc_info=exc_info)
        return True

    def warning(self, key: str, now: float, message: str, *args: object) -> bool:
        return self.log(logging.WARNING, key, now, message, *args)

    def flush(self, now: float) -> int:
        """Show what each key whose window is over held back: its last line, with the count of the
        others. Returns how many lines were shown."""
        with self._lock:
            due = [(key, held) for key, held in self._held.items() if now - self._windows[key][0] >= self.interval_s]
            for key, _ in due:
                del self._held[key]
                self._windows[key] = [now, 1]  # the line shown now opens the next window
        for _, (count, level, message, args) in due:
            others = f" ({count - 1} more like this held back)" if count > 1 else ""
            self.logger.log(level, message + others, *args)
        return len(due)

    @property
    def holding(self) -> int:
        """Lines held back and not yet told."""
        with self._lock:
            return sum(held[0] for held in self._held.values())


class TcpLimits:
    """Counts the TCP connections of every device and says whether one more may be served."""

    def __init__(self, farm_cap: int, sockets_at_rest: int, logger: logging.Logger) -> None:
        soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
        self.open_file_limit, self.open_file_hard_limit = soft, hard
        self.descriptor_cap = max(1, soft - sockets_at_rest - RESERVED_DESCRIPTORS)
        self.farm_cap = min(farm_cap, self.descriptor_cap)
        self.total = 0
        self.per_device: Counter[str] = Counter()
        self.log = RateLimitedLog(logger)
        self._descriptors_reported = False

    def admit(self, device: str, device_cap: int, now: float) -> bool:
        """Count a new connection of `device` in, or say (in the log) why it is refused."""
        if self.per_device[device] >= device_cap:
            self.log.warning(f"device:{device}", now, "%s: %d TCP connections open, its limit "
                             "(limits.max_tcp_connections): refusing new ones", device, device_cap)
            return False
        if self.total >= self.farm_cap:
            if self.farm_cap == self.descriptor_cap and not self._descriptors_reported:
                self._descriptors_reported = True
                self.log.logger.error(
                    "out of file descriptors: %d TCP connections open, the open-file limit is %d (hard limit %d); "
                    "new connections are refused until some close. Raise it with `ulimit -n` (up to the hard "
                    "limit) or in the service's LimitNOFILE=.", self.total, self.open_file_limit,
                    self.open_file_hard_limit)
            else:
                self.log.warning("farm", now, "%d TCP connections open, the farm's limit (max_tcp_connections): "
                                 "refusing new ones", self.farm_cap)
            return False
        self.per_device[device] += 1
        self.total += 1
        return True

    def release(self, device: str) -> None:
        self.per_device[device] -= 1
        self.total -= 1
