"""Nothing of the farm dies silently: an exception that escapes a callback or task of the event
loop is counted (`loop_errors`) and logged with its traceback (once per kind and 10 s); the cyclic
I/O thread supervises its own loop (server/implicit.py) and the farm checks every SUPERVISE_S that
it runs: `health` says so (the HTTP API's /health, /metrics, the container's heartbeat file), and a
thread that has ended fails the farm (`failed` is set: `enip-farm serve` exits 1), never leaving a
farm that answers explicit requests while no device sends T->O."""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

from enip_farm.cip.budget import CyclicBudget
from enip_farm.device.device import Device
from enip_farm.server.implicit import ImplicitIo
from enip_farm.server.limits import RateLimitedLog

log = logging.getLogger(__name__)
#: How often the farm checks its cyclic I/O thread (and touches the heartbeat file while it runs), s.
SUPERVISE_S = 1.0


class Supervision:
    """The farm's watch over its event loop and its cyclic I/O thread."""

    def __init__(self, heartbeat: Path | None, serving: Callable[[], bool],
                 implicit: Callable[[], ImplicitIo | None]) -> None:
        """`heartbeat`: a file whose time is set every SUPERVISE_S while cyclic I/O runs; `serving`:
        whether the farm has started (and not stopped); `implicit`: its cyclic I/O, once started."""
        self.heartbeat = heartbeat
        self._serving = serving
        self._implicit = implicit
        self.loop_errors = 0  # exceptions that escaped a callback or task of the event loop
        self.failure: str | None = None  # why the farm failed (it is not serving as it should)
        self.failed: asyncio.Event | None = None  # set when it fails: `enip-farm serve` exits 1
        self._errors = RateLimitedLog(log)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._timer: asyncio.TimerHandle | None = None
        self._previous_handler: Any = None

    def install(self, loop: asyncio.AbstractEventLoop) -> None:
        """The farm starts on `loop`: its exception handler is ours until `uninstall`."""
        self._loop = loop
        self.failed = asyncio.Event()
        self._previous_handler = loop.get_exception_handler()
        loop.set_exception_handler(self.loop_exception)

    def start(self) -> None:
        """The cyclic I/O thread runs: check it every SUPERVISE_S."""
        if self._loop is not None:
            self._timer = self._loop.call_later(SUPERVISE_S, self._supervise)

    def uninstall(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        loop = self._loop
        if loop is not None and loop.get_exception_handler() == self.loop_exception:
            loop.set_exception_handler(self._previous_handler)

    def health(self, devices: Iterable[Device]) -> dict[str, Any]:
        """Whether the farm serves as it should: `ok` is False while class-1 I/O is not running
        (its thread ended or its loop stalled) or the farm has failed."""
        implicit = self._implicit()
        running = implicit is not None and implicit.running(time.monotonic_ns())
        return {"ok": self._serving() and running and self.failure is None, "failure": self.failure,
                "cyclic_io": {"running": running, "errors": implicit.loop_errors if implicit is not None else 0,
                              "device_errors": sum(d.counters["io_errors"] for d in devices)},
                "loop_errors": self.loop_errors}

    def cyclic_io_load(self, budget: CyclicBudget) -> dict[str, Any]:
        """The budget (datagrams/s), what the open connections take of it, Forward Opens refused for
        want of it, and how late the I/O thread runs (worst of the last second, overloads)."""
        implicit = self._implicit()
        return {"budget_datagrams_per_s": budget.datagrams_per_s, "budget_source": budget.source,
                "reserved_datagrams_per_s": budget.reserved, "refused": budget.refused,
                "lag_s": implicit.lag.worst_ns / 1e9 if implicit is not None else 0.0,
                "overloads": implicit.lag.overloads if implicit is not None else 0}

    def loop_exception(self, loop: asyncio.AbstractEventLoop, context: dict[str, Any]) -> None:
        """The event loop's exception handler: count, log with the traceback (rate-limited), go on."""
        self.loop_errors += 1
        message = context.get("message", "unexpected error")
        exception = context.get("exception")
        self._errors.log(logging.ERROR, f"loop {message}", time.monotonic(), "event loop: %s (%d so far)%s",
                         message, self.loop_errors, f": {exception!r}" if exception else "",
                         exc_info=exception if isinstance(exception, BaseException) else False)

    def _supervise(self) -> None:
        """Every SUPERVISE_S on the loop: the cyclic I/O thread must be alive; while it runs, the
        heartbeat file's time is set."""
        self._timer = None
        loop, implicit = self._loop, self._implicit()
        if loop is None:
            return
        if not self._serving():
            if implicit is not None:  # still starting
                self._timer = loop.call_later(SUPERVISE_S, self._supervise)
            return
        if implicit is None or not implicit.thread.is_alive():
            self.fail("the cyclic I/O thread has ended: no device sends T->O")
            return
        try:
            if self.heartbeat is not None and implicit.running(time.monotonic_ns()):
                self.heartbeat.touch()  # creates it, or sets its time
        except OSError as error:
            self._errors.log(logging.WARNING, "heartbeat", time.monotonic(), "heartbeat file %s: %s",
                             self.heartbeat, error.strerror)
        self._timer = loop.call_later(SUPERVISE_S, self._supervise)

    def fail(self, reason: str) -> None:
        """The farm cannot serve as it should: say so once and let `serve` exit non-zero."""
        if self.failure is None:
            self.failure = reason
            log.critical("the farm failed: %s; stopping", reason)
        if self.failed is not None:
            self.failed.set()
