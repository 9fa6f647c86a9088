"""Guards of the farm's TCP side: caps on TCP connections per device and for the whole farm (the
latter also bounded by the process's open-file limit), and log lines that cannot flood the log."""

from __future__ import annotations

import logging
import resource
from collections import Counter

#: Descriptors kept free for everything that is not a client connection (listeners, UDP sockets,
#: the HTTP API, log and capture files).
RESERVED_DESCRIPTORS = 64


class RateLimitedLog:
    """At most one line per key and interval; the lines held back are counted into the next one."""

    def __init__(self, logger: logging.Logger, interval_s: float = 10.0) -> None:
        self.logger = logger
        self.interval_s = interval_s
        self._last: dict[str, float] = {}
        self._held: Counter[str] = Counter()

    def warning(self, key: str, now: float, message: str, *args: object) -> None:
        last = self._last.get(key)
        if last is not None and now - last < self.interval_s:
            self._held[key] += 1
            return
        held = self._held.pop(key, 0)
        self._last[key] = now
        if held:
            message += f" ({held} more like this since the last line)"
        self.logger.warning(message, *args)


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
