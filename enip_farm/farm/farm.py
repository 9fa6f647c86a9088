"""A farm: configuration in, running devices out. Builds the devices (`device/build.py`, against the
shipped catalogue unless given another), binds every device's TCP and UDP 44818 (and the discovery
responder), and closes them all again.

Its other jobs, each in a module beside this one: the devices' TCP listeners and connections
(listeners.py), carrying out a device's reset (resets.py), watching the event loop and
the cyclic I/O thread (supervision.py), and the loop it serves from (loop.py). Faults are
switched on and off here, on the farm's loop (their kinds: device/fault_kinds.py)."""

from __future__ import annotations

import asyncio
import logging
import time
from collections import deque
from collections.abc import Callable, Coroutine, Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any, TypeVar

from enip_farm.capture.recorder import Recorder
from enip_farm.cip.budget import CyclicBudget
from enip_farm.cip.report import ReactionFigures
from enip_farm.cip.verdicts import judge_reaction
from enip_farm.config import ConfigError, FarmConfig, as_config
from enip_farm.control.handle import DeviceHandle
from enip_farm.control.http import HttpApi, bind_problem
from enip_farm.control.reaction import SignalValue, measure_reaction
from enip_farm.control.wiring import Wiring
from enip_farm.device.build import build_profiles
from enip_farm.device.catalogue import Catalogue
from enip_farm.device.device import Clock, Device
from enip_farm.device.faults import Disconnect, Fault, FaultType
from enip_farm.device.nonvolatile import load_state, save_state
from enip_farm.device.report import FarmReport, TestBounds, device_bounds, farm_report
from enip_farm.eds.reader import eds_catalogue
from enip_farm.farm.cell import check_cell
from enip_farm.farm.faulting import FarmFaults
from enip_farm.farm.listeners import SOCKETS_PER_DEVICE, BindError, Listeners, bind_message, raise_open_file_limit
from enip_farm.farm.loop import FarmThread, freeze_heap, new_event_loop, until_stopped_or_failed
from enip_farm.farm.resets import FarmResets
from enip_farm.farm.supervision import SUPERVISE_S, Supervision
from enip_farm.protocol.connection import IO_PORT
from enip_farm.protocol.encapsulation import ENIP_PORT
from enip_farm.scenario.model import Scenario
from enip_farm.scenario.parse import load_scenario, signal_check
from enip_farm.scenario.run import run_scenario
from enip_farm.scenario.verdict import ScenarioResult
from enip_farm.server.calibrate import DEFAULT_DATAGRAMS_PER_S, measure_budget
from enip_farm.server.implicit import ImplicitIo
from enip_farm.server.limits import TcpLimits
from enip_farm.server.native import native_wanted
from enip_farm.server.udp import DeviceDatagramProtocol, DiscoveryResponder, udp_socket

#: What callers import from here (the serve command, the workers, the tests).
__all__ = ["SOCKETS_PER_DEVICE", "SUPERVISE_S", "BindError", "Farm", "FarmThread", "freeze_heap", "new_event_loop",
           "until_stopped_or_failed"]


T = TypeVar("T")


class Farm:
    """The devices of one configuration, served from one event loop."""

    def __init__(self, config: FarmConfig | Mapping[str, Any] | str | Path, http: tuple[str, int] | None = None,
                 token: str | None = None, record: str | Path | None = None,
                 catalogue: Catalogue | None = None, heartbeat: str | Path | None = None,
                 state: str | Path | None = None, clock: Clock = time.monotonic_ns) -> None:
        """`config`: a FarmConfig, a dict as a YAML file holds it, or a file's path; `http`: serve
        the HTTP API on (host, port), port 0 picks a free one (see `http.port`); `record`: write the
        farm's traffic to this pcap file; `catalogue`: the models the devices name (default: the
        shipped catalogue); `heartbeat`: a file whose time the farm sets every second while its
        cyclic I/O runs (docker/healthcheck.sh reads it); `state`: a JSON file of the devices'
        non-volatile state (a safety target's TUNID, configuration and owner), restored now if it
        exists and written at `stop` (device/nonvolatile.py); `clock`: the monotonic time (int ns) the
        devices' API edge takes when not given a time (a test's, to drive it). Raises ConfigError if
        the configuration is invalid or its devices cannot be built, or the state file is not one."""
        models = eds_catalogue(catalogue)
        if isinstance(config, (str, Path)):  # a file: every problem in one pass, at its line (farm/cell.py)
            config, profiles = check_cell(config, models)
        else:
            config = as_config(config)
            profiles = build_profiles(config, models)
        self.config = config
        self.recorder = Recorder(record) if record else None
        self._http_address = http
        self._http_token = token
        self.http: HttpApi | None = None
        self._profiles = profiles
        #: What this farm's cyclic I/O thread admits connections for (set at start: measured or configured).
        self.budget = CyclicBudget(DEFAULT_DATAGRAMS_PER_S, "not started")
        self.clock = clock
        self.devices: dict[str, Device] = {p.name: Device(p, self.budget, clock) for p in profiles}
        self.handles: dict[str, DeviceHandle] = {name: DeviceHandle(self, d) for name, d in self.devices.items()}
        for device in self.devices.values():
            device.recorder = self.recorder
            device.table.measuring = config.cyclic_io.measure
        #: The last reactions measured, each with the bounds its test gave, for the report.
        self.reactions: deque[tuple[ReactionFigures, TestBounds]] = deque(maxlen=32)
        self.state_file = Path(state) if state is not None else None
        if self.state_file is not None:
            try:
                load_state(self.devices, self.state_file)
            except (ValueError, KeyError, TypeError) as error:
                raise ConfigError(f"state file: {error}") from None
        self.wiring = Wiring(self)
        self.listeners = Listeners()
        self._servers = self.listeners.servers  # by device name
        self._datagram_transports: list[asyncio.DatagramTransport] = []
        self._discovery: DiscoveryResponder | None = None
        self._implicit: ImplicitIo | None = None
        self._tasks: set[asyncio.Task] = set()
        self.resets = FarmResets(self.listeners, self._spawn)
        #: A device configured onto an earlier device's address -> that device (config `duplicate_address`).
        self.address_owners: dict[str, str] = {}
        owners: dict[str, str] = {}
        for entry in config.devices:
            owner = owners.setdefault(str(entry.address), entry.name)
            if owner != entry.name:
                self.address_owners[entry.name] = owner
        self.faults = FarmFaults(self.devices, self.listeners, self.resets, self._spawn, lambda: self.running,
                                 clock)
        for device in self.devices.values():
            self.resets.observe(device)
        self.loop: asyncio.AbstractEventLoop | None = None
        self.running = False
        self.supervision = Supervision(Path(heartbeat) if heartbeat is not None else None, lambda: self.running,
                                       lambda: self._implicit)

    @property
    def tcp_limits(self) -> TcpLimits | None:
        """The TCP connection caps (and their rate-limited log), once the farm has started."""
        return self.listeners.tcp_limits

    @property
    def loop_errors(self) -> int:
        """Exceptions that escaped a callback or task of the event loop."""
        return self.supervision.loop_errors

    @property
    def failure(self) -> str | None:
        """Why the farm failed (it is not serving as it should), or None."""
        return self.supervision.failure

    @property
    def failed(self) -> asyncio.Event | None:
        """Set when the farm fails: `enip-farm serve` exits 1."""
        return self.supervision.failed

    def device(self, name: str) -> Device:
        return self.devices[name]

    def __getitem__(self, name: str) -> DeviceHandle:
        """The Python API of one device: farm["io1"].set(DI3=1), farm["io1"].get("DO5"), ..."""
        return self.handles[name]

    async def _listen(self, device: Device) -> None:
        await self.listeners.listen(device)

    def _close_connections(self, device: Device, kind: Disconnect = Disconnect.CLOSE) -> None:
        self.listeners.close_connections(device, kind)

    async def start(self) -> None:
        loop = self.loop = asyncio.get_running_loop()
        self.supervision.install(loop)
        raise_open_file_limit()
        self.listeners.tcp_limits = TcpLimits(self.config.max_tcp_connections,
                                              SOCKETS_PER_DEVICE * len(self.devices),
                                              logging.getLogger("enip_farm.server.tcp"))
        endpoints: list[DeviceDatagramProtocol] = []
        try:
            for device in self.devices.values():
                if device.name in self.address_owners:
                    continue  # configured onto another device's address: it does not take it (below)
                address = device.profile.address
                await self._listen(device)
                try:
                    sock = udp_socket(address)
                except OSError as error:
                    raise BindError(bind_message(device, "UDP", error)) from None
                transport, endpoint = await loop.create_datagram_endpoint(
                    lambda d=device: DeviceDatagramProtocol(d), sock=sock
                )
                self._datagram_transports.append(transport)
                endpoints.append(endpoint)
            budget = self.config.cyclic_io.budget_datagrams_per_s
            if budget == "auto":
                measured = measure_budget(self._profiles, native_wanted(self.config.cyclic_io.native))
                self.budget.set(measured.datagrams_per_s, measured.source, measured.ceiling)
            else:
                self.budget.set(budget, "configured")
            self._implicit = ImplicitIo(self.budget if budget == "auto" else None, self.config.cyclic_io.native,
                                        self.config.cyclic_io.realtime_priority)
            for device in self.devices.values():
                if device.name in self.address_owners:
                    continue
                try:
                    self._implicit.add(device)
                except OSError as error:
                    raise BindError(bind_message(device, "UDP", error, IO_PORT)) from None
            self._implicit.start()
            await self._address_conflicts()
            self.supervision.start()
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
        self.resets.start(loop)

    async def _address_conflicts(self) -> None:
        """Each device configured onto an earlier device's address (`duplicate_address`) detects the
        conflict as it comes up (Address Conflict Detection, its SelectAcd on) and does not take the
        address: an `address-conflict` fault in its probe phase, the other host the address's owner."""
        for name, owner in self.address_owners.items():
            device = self.devices[name]
            device.hardware.objects.tcpip.settings.select_acd = 1
            self.faults.off_network.add(name)
            mac = self.devices[owner].profile.mac.hex(":")
            await self.faults.inject((name,), Fault("address-conflict", phase="probe", remote_mac=mac))

    async def stop(self) -> None:
        self.resets.stop()
        self.supervision.uninstall()
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
        self.faults.stop()
        await self.listeners.close()
        if self.recorder is not None:
            self.recorder.close()
        if self.state_file is not None:
            save_state(self.devices, self.state_file)
        self.running = False

    # -- supervision (supervision.py) -------------------------------------------------------

    def health(self) -> dict[str, Any]:
        """Whether the farm serves as it should: `ok` is False while class-1 I/O is not running
        (its thread ended or its loop stalled) or the farm has failed."""
        return self.supervision.health(self.devices.values())

    def cyclic_io_load(self) -> dict[str, Any]:
        """The budget (datagrams/s), what the open connections take of it, Forward Opens refused for
        want of it, and how late the I/O thread runs (worst of the last second, overloads)."""
        return self.supervision.cyclic_io_load(self.budget)

    def report(self, bounds: TestBounds = None) -> FarmReport:
        """The report on the controller under test (cip/report.py: `as_dict()` for JSON): every
        device's class-1 connections as measured, its reconnections and the reactions measured,
        judged against the bounds (the configuration's, then `bounds`, a test's own)."""
        return farm_report(self.config, self.devices.values(), self.clock(), list(self.reactions), bounds)

    def reaction(self, set: SignalValue, expect: SignalValue, timeout: float = 1.0, repeat: int = 1,
                 reset: int | float | None = None, bounds: TestBounds = None, name: str | None = None
                 ) -> ReactionFigures:
        """The controller's reaction time (action latency), `repeat` times, judged against the bounds
        (the stimulus device's, then `bounds`): farm.reaction(set=("io1", "DI3", 1), expect=("io2",
        "DO5", 1), timeout=1, repeat=20). Blocks (not on the farm's loop); control/reaction.py."""
        implicit = self._implicit
        figures = measure_reaction(self.handles, set, expect, timeout, repeat, reset, name,
                                   implicit.thread.watch_flush if implicit is not None else None)
        self.reactions.append((figures, bounds))
        return judge_reaction(figures, device_bounds(self.config, set[0], bounds))

    # -- faults (device/faults.py; farm/faulting.py) ---------------------------------------------

    async def inject_fault(self, name: str, fault: FaultType) -> tuple[str, ...]:
        """Switch a fault on for a device, or for every device of a group at once, on the farm's loop;
        `fault.duration_s` ends it by itself. The devices it was set on."""
        names = self.config.topology.targets(name)
        await self.faults.inject(names, fault)
        return names

    async def clear_faults(self, name: str, kind: str | None = None) -> list[str]:
        """Switch one fault kind (or all) off for a device or a group's devices: the kinds cleared."""
        cleared: list[str] = []
        for device in self.config.topology.targets(name):
            cleared += [k for k in await self.faults.clear(device, kind) if k not in cleared]
        return cleared

    def inject(self, target: str, kind: str, duration_s: float | None = None, **params: Any) -> tuple[str, ...]:
        """A fault on a device or a group (every member at once), from another thread:
        farm.inject("rack2", "power-loss", duration_s=4, boot_time_s=2). KeyError for an unknown
        target, `FaultError` (a ValueError naming the field) for a bad parameter: nothing is set."""
        self.config.topology.targets(target)  # KeyError before anything runs
        return self.run(self.inject_fault(target, Fault(kind, duration_s=duration_s, **params)))

    def clear(self, target: str, kind: str | None = None) -> list[str]:
        """End one fault kind (or all) on a device or a group, from another thread."""
        return self.run(self.clear_faults(target, kind))

    # -- scenarios (enip_farm/scenario/) --------------------------------------------------------------

    def load_scenario(self, path: str | Path) -> Scenario:
        """A scenario file parsed and checked against this farm's cell (ScenarioError: every defect)."""
        return load_scenario(str(path), self.config, signal_check({n: h.signals for n, h in self.handles.items()}))

    def run_scenario(self, scenario: str | Path | Scenario, progress: Callable[[str], None] | None = None,
                     timeout: float = 3600.0) -> ScenarioResult:
        """Run a scenario (a file or a parsed one) on the running farm, from another thread, and return
        its result (`passed`, `verdicts`, `table()`); whatever it set is undone when it ends."""
        parsed = scenario if isinstance(scenario, Scenario) else self.load_scenario(scenario)
        return self.run(run_scenario(self, parsed, progress, self.clock), timeout)

    def mark(self, text: str) -> None:
        """A scenario's step, in the recording's side file (`--record FILE`: FILE.steps, a line of wall-clock
        time and text per step, to find it among the packets' time stamps), written off the event loop
        by the recorder's thread (capture/recorder.py); nothing when not recording."""
        if self.recorder is not None:
            self.recorder.mark(text)

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
