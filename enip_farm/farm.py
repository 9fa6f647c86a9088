"""A farm: configuration in, running devices out. Builds the devices (`device/build.py`, against the
shipped catalogue unless given another), binds every device's TCP and UDP 44818 (and the discovery
responder), and closes them all again.

When a device resets (Identity Reset, its "reset" event), the farm closes the device's TCP
connections and listener once the reply has been written, and listens again when the device's
reset window ends (`Device.end_reset`, asked at the window's deadline and never before).

Nothing of the farm dies silently: an exception that escapes a callback or task of the event loop
is counted (`loop_errors`) and logged with its traceback (once per kind and 10 s); the cyclic I/O
thread supervises its own loop (server/implicit.py) and the farm checks every second that it
runs: `health()` says so (the HTTP API's /health, /metrics, the container's heartbeat file), and a
thread that has ended fails the farm (`failed` is set: `enip-farm serve` exits 1), never leaving a
farm that answers explicit requests while no device sends T->O."""

from __future__ import annotations

import asyncio
import errno
import gc
import logging
import resource
import threading
import time
from collections.abc import Coroutine, Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any, TypeVar

from enip_farm.capture.recorder import Recorder
from enip_farm.cip.budget import CyclicBudget
from enip_farm.config import ConfigError, FarmConfig, as_config
from enip_farm.control.handle import DeviceHandle
from enip_farm.control.http import HttpApi, bind_problem
from enip_farm.control.wiring import Wiring
from enip_farm.device.build import build_profiles
from enip_farm.device.catalogue import Catalogue
from enip_farm.device.device import Device
from enip_farm.device.events import Event
from enip_farm.device.faults import Disconnect, FaultType
from enip_farm.device.nonvolatile import load_state, save_state
from enip_farm.device.reset import DeviceReset
from enip_farm.eds.reader import eds_catalogue
from enip_farm.protocol.connection import IO_PORT
from enip_farm.protocol.encapsulation import ENIP_PORT
from enip_farm.server.calibrate import DEFAULT_DATAGRAMS_PER_S, measure_budget
from enip_farm.server.implicit import ImplicitIo
from enip_farm.server.limits import RateLimitedLog, TcpLimits
from enip_farm.server.tcp import EncapsulationProtocol
from enip_farm.server.udp import DeviceDatagramProtocol, DiscoveryResponder, udp_socket
from enip_farm.server.waits import os_wait_s

log = logging.getLogger(__name__)
#: Sockets per device at rest: a TCP listener, UDP 44818 and UDP 2222; each client connection adds one.
SOCKETS_PER_DEVICE = 3
#: How often the farm checks its cyclic I/O thread (and touches the heartbeat file while it runs), s.
SUPERVISE_S = 1.0


T = TypeVar("T")


class BindError(Exception):
    """A device's address or port cannot be bound; the message says which and what to do."""


def new_event_loop() -> asyncio.AbstractEventLoop:
    """uvloop when installed, else the standard loop."""
    try:
        import uvloop
    except ImportError:
        return asyncio.new_event_loop()
    return uvloop.new_event_loop()


def freeze_heap() -> None:
    """Move everything built at start into the permanent generation: a full collection then scans
    only new objects, instead of stalling the T->O schedule (47 ms for a 200-device heap, measured)."""
    gc.collect()
    gc.freeze()


def raise_open_file_limit() -> int:
    """Raise the soft RLIMIT_NOFILE to the hard limit; return the limit now in force."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft < hard:
        try:
            resource.setrlimit(resource.RLIMIT_NOFILE, (hard, hard))
            soft = hard
        except (ValueError, OSError):
            pass
    return soft


def _bind_message(device: Device, transport: str, error: OSError, port: int = ENIP_PORT) -> str:
    where = f"device {device.name!r}: cannot bind {transport} {device.profile.address}:{port}"
    if error.errno == errno.EADDRNOTAVAIL:
        return (f"{where}: the address is not assigned to any interface of this host. Add it as an alias, "
                f"e.g. `sudo ip addr add {device.profile.address}/32 dev lo` (every 127.x.y.z address "
                "works on Linux without this).")
    if error.errno == errno.EADDRINUSE:
        return f"{where}: the port is already in use there (another farm or EtherNet/IP stack?)."
    if error.errno == errno.EMFILE:
        return (f"{where}: out of file descriptors (limit {resource.getrlimit(resource.RLIMIT_NOFILE)[0]}); "
                f"each device needs {SOCKETS_PER_DEVICE} plus one per client connection. Raise `ulimit -n`.")
    return f"{where}: {error.strerror}"


class Farm:
    """The devices of one configuration, served from one event loop."""

    def __init__(self, config: FarmConfig | Mapping[str, Any] | str | Path, http: tuple[str, int] | None = None,
                 token: str | None = None, record: str | Path | None = None,
                 catalogue: Catalogue | None = None, heartbeat: str | Path | None = None,
                 state: str | Path | None = None) -> None:
        """`config`: a FarmConfig, a dict as a YAML file holds it, or a file's path; `http`: serve
        the HTTP API on (host, port), port 0 picks a free one (see `http.port`); `record`: write the
        farm's traffic to this pcap file; `catalogue`: the models the devices name (default: the
        shipped catalogue); `heartbeat`: a file whose time the farm sets every second while its
        cyclic I/O runs (docker/healthcheck.sh reads it); `state`: a JSON file of the devices'
        non-volatile state (a safety target's TUNID, configuration and owner), restored now if it
        exists and written at `stop` (device/nonvolatile.py). Raises ConfigError if the configuration
        is invalid or its devices cannot be built, or the state file is not one."""
        self.config = config = as_config(config)
        profiles = build_profiles(config, eds_catalogue(catalogue))
        self.recorder = Recorder(record) if record else None
        self._http_address = http
        self._http_token = token
        self.http: HttpApi | None = None
        self._profiles = profiles
        #: What this farm's cyclic I/O thread admits connections for (set at start: measured or configured).
        self.budget = CyclicBudget(DEFAULT_DATAGRAMS_PER_S, "not started")
        self.devices: dict[str, Device] = {p.name: Device(p, self.budget) for p in profiles}
        self.handles: dict[str, DeviceHandle] = {name: DeviceHandle(self, d) for name, d in self.devices.items()}
        for device in self.devices.values():
            device.recorder = self.recorder
        self.state_file = Path(state) if state is not None else None
        if self.state_file is not None:
            try:
                load_state(self.devices, self.state_file)
            except (ValueError, KeyError, TypeError) as error:
                raise ConfigError(f"state file: {error}") from None
        self.wiring = Wiring(self)
        self._servers: dict[str, asyncio.AbstractServer] = {}
        self._connections: set[EncapsulationProtocol] = set()
        self._tcp_limits: TcpLimits | None = None  # at start, once the open-file limit is raised
        self._datagram_transports: list[asyncio.DatagramTransport] = []
        self._discovery: DiscoveryResponder | None = None
        self._implicit: ImplicitIo | None = None
        self._fault_timers: dict[tuple[str, str], asyncio.TimerHandle] = {}
        self._reset_timers: dict[str, asyncio.TimerHandle] = {}
        self._tasks: set[asyncio.Task] = set()
        for device in self.devices.values():
            device.observe(lambda event, d=device: self._on_device_event(d, event))
        self.loop: asyncio.AbstractEventLoop | None = None
        self.running = False
        self.heartbeat = Path(heartbeat) if heartbeat is not None else None
        self.loop_errors = 0  # exceptions that escaped a callback or task of the event loop
        self.failure: str | None = None  # why the farm failed (it is not serving as it should)
        self.failed: asyncio.Event | None = None  # set when it fails: `enip-farm serve` exits 1
        self._errors = RateLimitedLog(log)
        self._supervisor: asyncio.TimerHandle | None = None
        self._previous_handler: Any = None

    @property
    def tcp_limits(self) -> TcpLimits | None:
        """The TCP connection caps (and their rate-limited log), once the farm has started."""
        return self._tcp_limits

    def device(self, name: str) -> Device:
        return self.devices[name]

    def __getitem__(self, name: str) -> DeviceHandle:
        """The Python API of one device: farm["io1"].set(DI3=1), farm["io1"].get("DO5"), ..."""
        return self.handles[name]

    async def _listen(self, device: Device) -> None:
        loop = asyncio.get_running_loop()
        try:
            self._servers[device.name] = await loop.create_server(
                lambda: EncapsulationProtocol(device, self._connections, self._tcp_limits), host=device.profile.address,
                port=ENIP_PORT, reuse_address=True, backlog=128,
            )
        except OSError as error:
            raise BindError(_bind_message(device, "TCP", error)) from None

    def _close_connections(self, device: Device, kind: Disconnect = Disconnect.CLOSE) -> None:
        for connection in [c for c in self._connections if c.device is device]:
            connection.kill(kind)

    async def start(self) -> None:
        loop = self.loop = asyncio.get_running_loop()
        self.failed = asyncio.Event()
        self._previous_handler = loop.get_exception_handler()
        loop.set_exception_handler(self._loop_exception)
        raise_open_file_limit()
        self._tcp_limits = TcpLimits(self.config.max_tcp_connections, SOCKETS_PER_DEVICE * len(self.devices),
                                     logging.getLogger("enip_farm.server.tcp"))
        endpoints: list[DeviceDatagramProtocol] = []
        try:
            for device in self.devices.values():
                address = device.profile.address
                await self._listen(device)
                try:
                    sock = udp_socket(address)
                except OSError as error:
                    raise BindError(_bind_message(device, "UDP", error)) from None
                transport, endpoint = await loop.create_datagram_endpoint(
                    lambda d=device: DeviceDatagramProtocol(d), sock=sock
                )
                self._datagram_transports.append(transport)
                endpoints.append(endpoint)
            budget = self.config.cyclic_io.budget_datagrams_per_s
            if budget == "auto":
                measured = measure_budget(self._profiles)
                self.budget.set(measured.datagrams_per_s, measured.source)
            else:
                self.budget.set(budget, "configured")
            self._implicit = ImplicitIo()
            for device in self.devices.values():
                try:
                    self._implicit.add(device)
                except OSError as error:
                    raise BindError(_bind_message(device, "UDP", error, IO_PORT)) from None
            self._implicit.start()
            self._supervisor = loop.call_later(SUPERVISE_S, self._supervise)
            if self._http_address is not None:
                host, port = self._http_address
                try:
                    self.http = HttpApi(self, host, port, self._http_token)
                    await self.http.start()
                except OSError as error:
                    raise BindError(bind_problem(host, port, error)) from None
                except ValueError as error:
                    raise BindError(str(error)) from None
            if self.config.discovery:
                try:
                    self._discovery = DiscoveryResponder(loop, endpoints)
                except OSError as error:
                    raise BindError(f"discovery responder: cannot bind UDP 0.0.0.0:{ENIP_PORT}: {error.strerror}. "
                                    "Set `discovery: false` to serve without broadcast ListIdentity.") from None
        except BaseException:
            await self.stop()
            raise
        self.running = True

    async def stop(self) -> None:
        if self._supervisor is not None:
            self._supervisor.cancel()
            self._supervisor = None
        if self.loop is not None and self.loop.get_exception_handler() == self._loop_exception:
            self.loop.set_exception_handler(self._previous_handler)
        if self.http is not None:
            await self.http.stop()
            self.http = None
        if self._implicit is not None:
            self._implicit.close()
            self._implicit = None
        if self._discovery is not None:
            self._discovery.close()
            self._discovery = None
        for transport in self._datagram_transports:
            transport.close()
        self._datagram_transports.clear()
        for timer in [*self._fault_timers.values(), *self._reset_timers.values()]:
            timer.cancel()
        self._fault_timers.clear()
        self._reset_timers.clear()
        for server in self._servers.values():
            server.close()
        for connection in list(self._connections):
            connection.kill(Disconnect.CLOSE)
        for server in self._servers.values():
            await server.wait_closed()
        self._servers.clear()
        if self.recorder is not None:
            self.recorder.close()
        if self.state_file is not None:
            save_state(self.devices, self.state_file)
        self.running = False

    # -- supervision ---------------------------------------------------------------------------

    def health(self) -> dict[str, Any]:
        """Whether the farm serves as it should: `ok` is False while class-1 I/O is not running
        (its thread ended or its loop stalled) or the farm has failed."""
        implicit = self._implicit
        running = implicit is not None and implicit.running(time.monotonic_ns())
        return {"ok": self.running and running and self.failure is None, "failure": self.failure,
                "cyclic_io": {"running": running, "errors": implicit.loop_errors if implicit is not None else 0,
                              "device_errors": sum(d.counters["io_errors"] for d in self.devices.values())},
                "loop_errors": self.loop_errors}

    def cyclic_io_load(self) -> dict[str, Any]:
        """The budget (datagrams/s), what the open connections take of it, Forward Opens refused for
        want of it, and how late the I/O thread runs (worst of the last second, overloads)."""
        implicit = self._implicit
        return {"budget_datagrams_per_s": self.budget.datagrams_per_s, "budget_source": self.budget.source,
                "reserved_datagrams_per_s": self.budget.reserved, "refused": self.budget.refused,
                "lag_s": implicit.lag.worst_ns / 1e9 if implicit is not None else 0.0,
                "overloads": implicit.lag.overloads if implicit is not None else 0}

    def _loop_exception(self, loop: asyncio.AbstractEventLoop, context: dict[str, Any]) -> None:
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
        self._supervisor = None
        if not self.running:
            if self._implicit is not None and self.loop is not None:  # still starting
                self._supervisor = self.loop.call_later(SUPERVISE_S, self._supervise)
            return
        implicit = self._implicit
        if implicit is None or not implicit.thread.is_alive():
            self._fail("the cyclic I/O thread has ended: no device sends T->O")
            return
        try:
            if self.heartbeat is not None and implicit.running(time.monotonic_ns()):
                self.heartbeat.touch()  # creates it, or sets its time
        except OSError as error:
            self._errors.log(logging.WARNING, "heartbeat", time.monotonic(), "heartbeat file %s: %s",
                             self.heartbeat, error.strerror)
        self._supervisor = self.loop.call_later(SUPERVISE_S, self._supervise)  # type: ignore[union-attr]

    def _fail(self, reason: str) -> None:
        """The farm cannot serve as it should: say so once and let `serve` exit non-zero."""
        if self.failure is None:
            self.failure = reason
            log.critical("the farm failed: %s; stopping", reason)
        if self.failed is not None:
            self.failed.set()

    # -- faults (device/faults.py) ---------------------------------------------------------------

    async def inject_fault(self, name: str, fault: FaultType) -> None:
        """Switch a fault on for one device, on the farm's loop; `fault.duration_s` ends it by itself.
        Its hooks (device/fault_type.py) say whether open connections end and TCP stops listening."""
        device = self.devices[name]
        self._cancel_timer(name, fault.name)
        device.faults.set(fault, time.monotonic_ns())
        device.record("fault injected", fault.parameters())
        end = fault.on_tcp_connection()
        if end is not None or not fault.listens():
            self._close_connections(device, end or Disconnect.CLOSE)
        if not fault.listens() and name in self._servers:
            server = self._servers.pop(name)
            server.close()
        if fault.duration_ns is not None:
            self._arm_fault_end(name, fault.name, asyncio.get_running_loop().time() + fault.duration_ns / 1e9)

    def _arm_fault_end(self, name: str, kind: str, end: float) -> None:
        """Clear the fault at `end` (loop time), in bounded steps (server/waits.py)."""
        loop = asyncio.get_running_loop()
        delay = end - loop.time()
        if delay > 0 and os_wait_s(delay) < delay:
            self._fault_timers[name, kind] = loop.call_later(os_wait_s(delay), self._arm_fault_end, name, kind, end)
            return
        self._fault_timers[name, kind] = loop.call_later(
            os_wait_s(delay), lambda: self._spawn(self.clear_faults(name, kind)))

    def _spawn(self, coroutine: Coroutine[Any, Any, Any]) -> None:
        """A task of the farm, kept until it ends; its exception reaches the loop's handler."""
        task = self.loop.create_task(coroutine)  # type: ignore[union-attr]
        self._tasks.add(task)
        task.add_done_callback(self._task_done)

    def _task_done(self, task: asyncio.Task) -> None:
        self._tasks.discard(task)
        if not task.cancelled() and task.exception() is not None and self.loop is not None:
            self.loop.call_exception_handler({"message": "a farm task failed", "exception": task.exception(),
                                              "task": task})

    async def clear_faults(self, name: str, kind: str | None = None) -> list[str]:
        """Switch one fault (or all) off; normal behaviour returns without a restart."""
        device = self.devices[name]
        listens_again = not device.faults.listens and device.faults.listens_without(kind)
        if listens_again and self.running and name not in self._servers and not device.resetting:
            await self._listen(device)  # listening again before the fault is seen gone (a reset's end listens)
        cleared = device.faults.clear(kind)
        for k in cleared:
            self._cancel_timer(name, k)
        if cleared:
            device.record("fault cleared", {"kind": ", ".join(cleared)})
        return cleared

    # -- Identity Reset --------------------------------------------------------------------------

    def _on_device_event(self, device: Device, event: Event) -> None:
        """A device's observer (any thread): a reset is handled on the loop, after the reply."""
        if type(event.detail) is DeviceReset and self.loop is not None and self.running:
            self.loop.call_soon_threadsafe(self._begin_reset, device)

    def _begin_reset(self, device: Device) -> None:
        """On the loop, after the Reset's reply was written: the device's sessions end (its TCP
        connections close) and it takes no connection until its reset window ends."""
        if not self.running:
            return
        self._close_connections(device)
        server = self._servers.pop(device.name, None)
        if server is not None:
            server.close()
        self._arm_reset_end(device)

    def _arm_reset_end(self, device: Device) -> None:
        due = device.reset_window.due()
        timer = self._reset_timers.pop(device.name, None)
        if timer is not None:
            timer.cancel()
        if due is not None and self.loop is not None:
            delay_s = os_wait_s((due - time.monotonic_ns()) / 1e9)
            self._reset_timers[device.name] = self.loop.call_later(delay_s, self._end_reset, device)

    def _end_reset(self, device: Device) -> None:
        self._reset_timers.pop(device.name, None)
        if not device.end_reset(time.monotonic_ns()):
            self._arm_reset_end(device)  # the timer came a little early: wait for the deadline itself
            return
        if self.running and device.faults.listens and device.name not in self._servers:
            self._spawn(self._listen_after_reset(device))

    async def _listen_after_reset(self, device: Device) -> None:
        try:
            await self._listen(device)
        except BindError as error:  # someone took the address meanwhile: say so, keep serving the others
            log.error("%s (after its reset)", error)

    def _cancel_timer(self, name: str, kind: str) -> None:
        timer = self._fault_timers.pop((name, kind), None)
        if timer is not None:
            timer.cancel()

    def run(self, coroutine: Coroutine[Any, Any, T], timeout: float = 30.0) -> T:
        """Run a farm coroutine from another thread (e.g. a synchronous test while the farm runs in
        its background thread). On the farm's own loop, await the coroutine instead."""
        loop = self.loop
        if loop is None or not self.running:
            coroutine.close()
            raise RuntimeError("the farm is not running")
        try:
            running = asyncio.get_running_loop()
        except RuntimeError:
            running = None
        if running is loop:
            coroutine.close()
            raise RuntimeError("on the farm's event loop: await the coroutine instead of Farm.run")
        return asyncio.run_coroutine_threadsafe(coroutine, loop).result(timeout)

    async def __aenter__(self) -> Farm:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()

    @contextmanager
    def running_in_thread(self) -> Iterator[Farm]:
        """Serve from a background thread with its own event loop, for synchronous callers."""
        thread = FarmThread(self)
        thread.start_and_wait()
        try:
            yield self
        finally:
            thread.stop()


async def until_stopped_or_failed(stop: asyncio.Event, farm: Farm) -> None:
    """Wait for `stop` (a signal) or the farm's failure, whichever comes first."""
    waits = [asyncio.ensure_future(stop.wait())]
    if farm.failed is not None:
        waits.append(asyncio.ensure_future(farm.failed.wait()))
    try:
        await asyncio.wait(waits, return_when=asyncio.FIRST_COMPLETED)
    finally:
        for wait in waits:
            wait.cancel()


class FarmThread:
    """Runs a farm's event loop in a daemon thread; start errors are re-raised in the caller."""

    def __init__(self, farm: Farm) -> None:
        self.farm = farm
        self.loop = new_event_loop()
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._stop: asyncio.Event | None = None
        self._thread = threading.Thread(target=self._run, name="enip-farm", daemon=True)

    def _run(self) -> None:
        asyncio.set_event_loop(self.loop)
        try:
            self.loop.run_until_complete(self._main())
        finally:
            self.loop.close()

    async def _main(self) -> None:
        self._stop = asyncio.Event()
        try:
            await self.farm.start()
        except BaseException as error:  # reported to the caller of start_and_wait
            self._error = error
            self._ready.set()
            return
        self._ready.set()
        await self._stop.wait()
        await self.farm.stop()

    def start_and_wait(self, timeout: float = 30.0) -> None:
        self._thread.start()
        if not self._ready.wait(timeout):
            raise TimeoutError("farm did not start in time")
        if self._error is not None:
            self._thread.join()
            raise self._error

    def stop(self, timeout: float = 30.0) -> None:
        if self._thread.is_alive() and self._stop is not None:
            self.loop.call_soon_threadsafe(self._stop.set)
        self._thread.join(timeout)
