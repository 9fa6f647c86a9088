"""The talking console of `enip-farm serve`: one log line per thing that happened to a device, taken
from the devices' events (`Device.observe`, device/events.py), as `DEVICE ADDRESS: KIND: DETAIL`.
How loud a line is depends on the event's class; the console observes only the classes its
logger's level shows (so a quiet farm makes no Event per request and compares no image for it).

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

from enip_farm.cip.connection_events import (
    ConnectionEvent,
    ConnectionFaulted,
    ConnectionRefused,
    ConnectionTimedOut,
    SafeState,
    SafetyCrcFault,
    SafetyTimingFault,
)
from enip_farm.device.device import Device
from enip_farm.device.events import (
    EncapsulationIgnored,
    EncapsulationRefused,
    Event,
    FaultInjected,
    Happened,
    ImageChanged,
    RequestHandled,
    Wired,
)
from enip_farm.protocol.cip import Service
from enip_farm.protocol.status import describe_status
from enip_farm.server.limits import RateLimitedLog

LOGGER = "enip_farm.farm.console"
#: Log line format of `serve` (configure_logging).
LOG_FORMAT = "%(asctime)s %(levelname)s %(message)s"

_LEVELS: Mapping[type, int] = MappingProxyType({
    ConnectionTimedOut: logging.WARNING, ConnectionRefused: logging.WARNING,
    EncapsulationRefused: logging.WARNING, EncapsulationIgnored: logging.WARNING,
    FaultInjected: logging.WARNING,
    # CIP Safety (cip/connection_table.py): a faulted safety connection and its safe state
    ConnectionFaulted: logging.WARNING, SafetyCrcFault: logging.WARNING,
    SafetyTimingFault: logging.WARNING, SafeState: logging.WARNING,
    ImageChanged: logging.DEBUG, Wired: logging.DEBUG,
})  # every other class: INFO (a request: DEBUG, or INFO when refused)
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
        classes = self._classes()
        if classes is not None:
            for device in self.devices:
                self._unsubscribe.append(device.observe(self._observer(device), *classes))
        return self

    def _classes(self) -> tuple[type, ...] | None:
        """The event classes the logger's level shows: () every class, None none."""
        logger = self.logger
        if logger.isEnabledFor(logging.DEBUG):
            return ()
        if logger.isEnabledFor(logging.INFO):  # not the image changes (DEBUG)
            return RequestHandled, ConnectionEvent, Happened
        loud = tuple(cls for cls, level in _LEVELS.items() if level > logging.INFO and logger.isEnabledFor(level))
        return loud or None

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
            detail = event.detail
            if type(detail) is RequestHandled:  # the hot path: most requests succeed and are told at DEBUG only
                status = detail.status
                if status == 0:
                    if debug:
                        log.log(logging.DEBUG, detail.kind, time.monotonic(), "%s%s: %s", prefix, detail.kind,
                                request_text(detail))
                    return
                if info and not detail.relayed and (detail.service, status) not in _TOLD_ELSEWHERE:
                    log.log(logging.INFO, "request refused", time.monotonic(), "%srequest refused: %s", prefix,
                            request_text(detail))
                return
            level = _LEVELS.get(type(detail), logging.INFO)
            if level == logging.DEBUG and not debug:
                return
            kind = detail.kind
            log.log(level, kind, time.monotonic(), "%s%s: %s", prefix, kind, detail.text)

        return observe
