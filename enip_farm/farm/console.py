"""The talking console of `enip-farm serve`: one log line per thing that happened to a device, taken
from the devices' events (`Device.observe`, device/events.py), as `DEVICE ADDRESS: KIND: DETAIL`.

- WARNING: connection timed out; connection refused (a Forward Open or Close, with the general and
  extended status in hex and words); encapsulation refused (with the encapsulation status);
  encapsulation ignored (a request that carried a non-zero status, Vol. 2, 2-3.5); fault
  injected; CIP Safety: safety crc fault, safety timing fault, connection faulted, safe state.
- INFO: tcp connected, closed, inactive; session registered, ended; connection opened (originator,
  RPI and sizes), closed, short data; request refused (its CIP status); fault cleared.
- DEBUG: every other request; image changed; wired.

Lines are rate-limited per kind (`RateLimitedLog`, server/limits.py): at most `burst` lines of one
kind per `interval_s`; what is held back is counted into the next line of that kind, or shown by
the periodic `flush` with the count of the others, so a flood of connections costs a bounded
number of lines and no event goes untold.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable, Iterable, Mapping
from types import MappingProxyType

from enip_farm.device.device import Device
from enip_farm.device.events import Event
from enip_farm.protocol.cip import Service
from enip_farm.protocol.status import describe_status
from enip_farm.server.limits import RateLimitedLog

LOGGER = "enip_farm.farm.console"
#: Log line format of `serve` (configure_logging).
LOG_FORMAT = "%(asctime)s %(levelname)s %(message)s"

_LEVELS: Mapping[str, int] = MappingProxyType({
    "connection timed out": logging.WARNING, "connection refused": logging.WARNING,
    "encapsulation refused": logging.WARNING, "encapsulation ignored": logging.WARNING,
    "fault injected": logging.WARNING,
    # CIP Safety (cip/connection_table.py): a faulted safety connection and its safe state
    "connection faulted": logging.WARNING, "safety crc fault": logging.WARNING,
    "safety timing fault": logging.WARNING, "safe state": logging.WARNING,
    "image changed": logging.DEBUG, "wired": logging.DEBUG,
})
#: Refusals the console leaves to another line: a Forward Open/Close refused by the connection
#: table (its "connection refused" event says more), a Multiple Service Packet whose embedded
#: requests failed (each is told).
_TOLD_ELSEWHERE: frozenset[tuple[int, int]] = frozenset({
    (Service.FORWARD_OPEN, 0x01), (Service.LARGE_FORWARD_OPEN, 0x01), (Service.FORWARD_CLOSE, 0x01),
    (Service.MULTIPLE_SERVICE_PACKET, 0x1E)})


def configure_logging(level: str = "info", quiet: bool = False) -> None:
    """Log lines of `serve` to stderr: `level` (debug, info, warning, error), or warnings and
    errors only with `quiet`. The HTTP server's own chatter, and the HTTP client's (a line per
    request the fleet's router forwards), stay at warnings."""
    logging.basicConfig(level=logging.WARNING if quiet else level.upper(), format=LOG_FORMAT, force=True)
    for chatty in ("uvicorn.error", "httpx", "httpcore"):
        logging.getLogger(chatty).setLevel(max(logging.WARNING, logging.getLogger().level))


def service_name(service: int) -> str:
    """A CIP service as the spec names it: `Get Attribute Single (0x0E)`."""
    try:
        words = Service(service).name.replace("_", " ").title()
    except ValueError:
        return f"service 0x{service:02X}"
    return f"{words} (0x{service:02X})"


def request_text(handled: tuple) -> str:
    """An explicit request as the router answered it: service, path and status in hex and words."""
    service, path, status, extended = handled[:4]
    return f"{service_name(service)} path {path.hex(' ') or '-'}: {describe_status(status, extended)}"


class Console:
    """Logs the events of `devices` while attached; see the module's table for what and how loud."""

    def __init__(self, devices: Iterable[Device], logger: logging.Logger | None = None, interval_s: float = 1.0,
                 burst: int = 20, also_flush: Iterable[RateLimitedLog] = ()) -> None:
        self.devices = list(devices)
        self.logger = logger or logging.getLogger(LOGGER)
        self.log = RateLimitedLog(self.logger, interval_s, burst)
        self._also_flush = list(also_flush)
        self._unsubscribe: list[Callable[[], None]] = []
        self._timer: asyncio.TimerHandle | None = None
        self._loop: asyncio.AbstractEventLoop | None = None

    def attach(self) -> Console:
        """Start telling the devices' events (those below the logger's level cost a check each)."""
        for device in self.devices:
            self._unsubscribe.append(device.observe(self._observer(device)))
        return self

    def start(self, loop: asyncio.AbstractEventLoop) -> None:
        """Attach, and flush what was held back once per interval on `loop`."""
        self.attach()
        self._loop = loop
        self._timer = loop.call_later(self.log.interval_s, self._tick)

    def _tick(self) -> None:
        self.flush()
        if self._loop is not None:
            self._timer = self._loop.call_later(self.log.interval_s, self._tick)

    def flush(self, now: float | None = None) -> int:
        """Show the lines held back whose interval is over (this console's and `also_flush`'s)."""
        now = time.monotonic() if now is None else now
        return sum(log.flush(now) for log in (self.log, *self._also_flush))

    def close(self) -> None:
        """Detach; the lines still held back are shown."""
        for unsubscribe in self._unsubscribe:
            unsubscribe()
        self._unsubscribe.clear()
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        self._loop = None
        self.flush(float("inf"))

    def _observer(self, device: Device) -> Callable[[Event], None]:
        prefix = f"{device.name} {device.profile.address}: "
        logger, log = self.logger, self.log
        debug = logger.isEnabledFor(logging.DEBUG)
        info = logger.isEnabledFor(logging.INFO)

        def observe(event: Event) -> None:
            kind = event.kind
            if kind == "request":  # the hot path: most requests succeed and are told at DEBUG only
                handled = event.detail
                status = handled[2]
                if status == 0:
                    if debug:
                        log.log(logging.DEBUG, "request", time.monotonic(), "%s%s: %s", prefix, kind,
                                request_text(handled))
                    return
                if info and not handled[4] and (handled[0], status) not in _TOLD_ELSEWHERE:
                    log.log(logging.INFO, "request refused", time.monotonic(), "%srequest refused: %s", prefix,
                            request_text(handled))
                return
            level = _LEVELS.get(kind, logging.INFO)
            if level == logging.DEBUG and not debug:
                return
            log.log(level, kind, time.monotonic(), "%s%s: %s", prefix, kind, event.text)

        return observe
