"""The farm's HTTP API (FastAPI, served by uvicorn on the farm's own event loop).

GET /devices, GET /devices/{name}, GET and PUT /devices/{name}/io, GET /devices/{name}/io/{signal}
(one signal by its number or name), POST and DELETE /devices/{name}/faults, GET /fault-kinds (each
kind and its parameters' JSON Schema, from device/fault_kinds.py), GET /state (what the dashboard
shows of each device: signals, connections, counters, faults), GET /overview (every device's state
in one answer, and recent events: control/overview.py), GET /events (server-sent events,
control/stream.py), GET /metrics (Prometheus), GET /report and GET /devices/{name}/timeline (what the
farm measured of the controller: control/measured.py),
the dashboard at / (control/dashboard.py),
and the OpenAPI schema at /openapi.json with /docs and /redoc served from assets shipped in the
package (no CDN). Bound to a loopback address (localhost, 127.x.y.z, ::1) the API may run without
a token; bound to any other address it needs one, and every request then carries `Authorization:
Bearer <token>` (so does every request when a token is set on loopback). Host, token and body size
are checked before FastAPI sees a request (control/guard.py).
Fault parameters are checked by `Fault` itself (device/faults.py); an image write is all or
nothing (`DeviceHandle.update`).
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import socket
import time
from collections.abc import Iterable, Iterator
from typing import Annotated, Any

import uvicorn
from fastapi import FastAPI, HTTPException, Query
from fastapi.responses import JSONResponse, PlainTextResponse
from fastapi_offline import FastAPIOffline
from prometheus_client import CollectorRegistry, generate_latest
from prometheus_client.exposition import CONTENT_TYPE_LATEST
from pydantic import BaseModel, Field, field_validator

from enip_farm.control.dashboard import mount_dashboard
from enip_farm.control.fault_routes import FaultRequest, group_routes, requested_fault
from enip_farm.control.guard import Guard, needs_token
from enip_farm.control.handle import FarmControl
from enip_farm.control.measured import mount_measured
from enip_farm.control.metrics import FarmCollector
from enip_farm.control.overview import RECENT, Overview
from enip_farm.control.scenario_routes import scenario_routes
from enip_farm.control.stream import EventHub, EventStream
from enip_farm.control.timeline import Timelines
from enip_farm.device.device import Device
from enip_farm.device.faults import FaultKind, fault_kinds
from enip_farm.device.signals import SignalError


class IoWrite(BaseModel):
    """Hex images and/or signals, e.g. {"signals": {"DI3": 1, "AI1": 1200}}."""

    inputs: str | None = Field(None, description="the whole input image, hex")
    outputs: str | None = Field(None, description="the whole output image, hex")
    signals: dict[str, int | float | list[int]] = Field({}, description="numbered (DI3, DO1-4) or named "
                                                         "signals (diGripperClosed, goProgramNo)")

    @field_validator("signals", mode="before")
    @classmethod
    def _json_numbers(cls, value: Any) -> Any:
        """Values as JSON numbers, never coerced: "1" or true is refused, not taken as 1."""
        if isinstance(value, dict):
            for name, given in value.items():
                items = given if isinstance(given, list) else [given]
                if not items or any(isinstance(item, bool) or not isinstance(item, (int, float)) for item in items) or (
                        isinstance(given, list) and any(isinstance(item, float) for item in items)):
                    raise ValueError(f"{name}: expected a number, or a list of integers for a range, got {given!r}")
        return value


class FaultKindInfo(BaseModel):
    """One fault kind (device/fault_kinds.py): its name, what it does, its parameters' JSON Schema."""

    kind: str
    summary: str
    parameters: dict[str, Any]


class ResetRequest(BaseModel):
    type: int = Field(0, ge=0, le=2, description="0 power cycle, 1 out-of-box configuration, "
                      "2 out-of-box configuration but the communication parameters (Identity Reset types)")


def no_such_device(name: str, known: Iterable[str], shown: int = 20) -> str:
    """A 404's detail: the name asked for and the names there are (the first `shown` of many)."""
    names = list(known)
    listed = ", ".join(names[:shown]) + (f", ... ({len(names)} in all)" if len(names) > shown else "")
    return f"no device named {name!r}; known: {listed or 'none'}"


def _io(farm: FarmControl, name: str) -> dict[str, Any]:
    handle = farm[name]
    signals = {}
    for kind, count in handle.signals.names().items():
        if count:
            values = handle.get(f"{kind}1-{count}")
            signals[kind] = values if isinstance(values, list) else [values]
    named = {signal.name: handle.get(signal.name) for signal in handle.signals.named.values()}
    return {"inputs": handle.inputs.hex(), "outputs": handle.outputs.hex(), "signals": signals, "named": named}


def _connections(device: Device) -> list[dict[str, Any]]:
    return [{"kind": c.kind.value, "o_t_id": c.o_t_id, "t_o_id": c.t_o_id, "o_t_rpi_us": c.o_t_rpi,
             "t_o_rpi_us": c.t_o_rpi, "originator": c.originator_host, "received": c.received,
             "multicast": c.multicast} for c in device.connections.values()]


STATE_COUNTERS = ("o_t_packets", "t_o_packets", "connection_timeouts", "tcp_connections", "sessions")


def _state(farm: FarmControl, name: str) -> dict[str, Any]:
    """One device as the dashboard shows it. `monotonic` is read before the images: an "io" event
    of the stream with an earlier `monotonic` is already in `signals`."""
    handle = farm[name]
    device = handle.device
    monotonic = time.monotonic()
    connections = _connections(device)
    return {
        "name": name, "monotonic": monotonic, "signals": handle.signal_table(), "status": device.status,
        "owners": sorted({c["originator"] for c in connections if c["kind"] == "exclusive owner"}),
        "connections": connections,
        "open": {"tcp": device.tcp_open, "sessions": len(device.session_handles.open)},  # now, beside the totals
        "counters": {key: device.counters.get(key, 0) for key in STATE_COUNTERS},  # since start
        "faults": handle.faults,
    }


def _device(farm: FarmControl, name: str, detail: bool = False) -> dict[str, Any]:
    device = farm.devices[name]
    p = device.profile
    out: dict[str, Any] = {
        "name": p.name, "address": p.address, "model": p.model, "addons": list(p.addons),
        "identity": {"vendor_id": p.vendor_id, "device_type": p.device_type, "product_code": device.product_code,
                     "revision": list(p.revision), "serial_number": p.serial_number, "product_name": p.product_name,
                     "status": device.status, "state": device.identity_state},
        "restarts": device.restarts,  # resets begun (Identity Reset, the reset API); state 1 while resetting
        "input_size": p.input_size, "output_size": p.output_size,
        "connections": _connections(device),
        "faults": farm[name].faults,
        "unverified": list(p.unverified),
    }
    if detail:
        out["counters"] = farm[name].counters
        out["io"] = _io(farm, name)
    return out


def create_app(farm: FarmControl, hub: EventHub | None = None, overview: Overview | None = None,
               timelines: Timelines | None = None) -> FastAPI:
    """The API's routes; `HttpApi` serves them behind `Guard` (Host, token, body size)."""
    app = FastAPIOffline(title="enip-farm", description="Drive and observe a farm of virtual EtherNet/IP devices. "
                         "The dashboard is at /.")
    registry = CollectorRegistry()
    registry.register(FarmCollector(farm.devices.values(), farm.health, farm.cyclic_io_load, farm.report))
    hub = hub if hub is not None else EventHub(farm.devices.values())
    overview = overview if overview is not None else Overview(farm.devices.values())

    def known(name: str) -> str:
        if name not in farm.devices:
            raise HTTPException(404, no_such_device(name, farm.devices))
        return name

    @app.get("/devices")
    def devices() -> list[dict[str, Any]]:
        return [_device(farm, name) for name in farm.devices]

    @app.get("/devices/{name}")
    def device(name: str) -> dict[str, Any]:
        return _device(farm, known(name), detail=True)

    @app.get("/devices/{name}/io")
    def get_io(name: str) -> dict[str, Any]:
        return _io(farm, known(name))

    @app.get("/devices/{name}/io/{signal}")
    def get_signal(name: str, signal: str) -> dict[str, Any]:
        """One signal by name: numbered (DI3, DO1-8, AI2) or named (goProgramNo); 404 naming it if the
        device has no such signal."""
        handle = farm[known(name)]
        try:
            return handle.signal(signal)
        except SignalError as error:
            raise HTTPException(404, f"device {name!r}: {error}") from None

    @app.put("/devices/{name}/io")
    def put_io(name: str, body: IoWrite) -> dict[str, Any]:
        """All or nothing: if any part is refused (422 naming it), nothing is written."""
        handle = farm[known(name)]
        try:
            handle.update(inputs=_hex("inputs", body.inputs), outputs=_hex("outputs", body.outputs),
                          signals=body.signals)
        except (ValueError, KeyError) as error:
            raise HTTPException(422, str(error)) from None
        return _io(farm, name)

    @app.get("/fault-kinds", response_model=list[FaultKindInfo])
    def kinds() -> list[dict[str, Any]]:
        """The fault kinds POST /devices/{name}/faults takes, each with a one-line summary and the
        JSON Schema of its parameters (the CLI and the dashboard build their forms from it)."""
        return fault_kinds()

    @app.post("/devices/{name}/faults", status_code=201)
    async def inject(name: str, body: FaultRequest) -> list[dict]:
        known(name)
        await farm.inject_fault(name, requested_fault(body))
        return farm[name].faults

    @app.delete("/devices/{name}/faults")
    async def clear(name: str, kind: FaultKind | None = None) -> dict[str, list[str]]:
        cleared = await farm.clear_faults(known(name), kind)
        return {"cleared": cleared}

    @app.post("/devices/{name}/reset")
    def reset(name: str, body: ResetRequest) -> dict[str, Any]:
        """Power-cycle (type 0) or reset (type 1: out-of-box, 2: out-of-box but the communication
        parameters) a device, as its Identity Reset does; 409 while it is resetting already."""
        if not farm[known(name)].reset(body.type):
            raise HTTPException(409, f"device {name!r} is resetting already")
        return {"device": name, "type": body.type, "reset_time_s": farm.devices[name].profile.reset_time_s}

    @app.get("/state")
    def state(device: Annotated[list[str], Query()] = []) -> list[dict[str, Any]]:  # noqa: B006
        """What the dashboard shows of each device (all, or those named by `device`): every signal
        with its value, the connections and their owners, packet and timeout counters, faults."""
        return [_state(farm, known(name)) for name in device or farm.devices]

    @app.get("/overview")
    def plant(events: Annotated[int, Query(ge=0, le=RECENT)] = 0) -> dict[str, Any]:
        """Every device (configuration order) with its state (`idle`, `running`: a class-1 connection
        open, `timed_out`: its last class-1 connection timed out and none runs, `faulted`: a fault
        injected; the first that holds, so each device is in one), its class-1 connection count,
        timeout counter and fault kinds; the count of devices in each state; and the last `events`
        events other than requests and image changes, oldest first, as GET /events sends them."""
        return overview.snapshot(events)

    @app.get("/events", responses={200: {"content": {"text/event-stream": {}}},
                                    503: {"description": "too many event streams are open"}})
    async def events(device: Annotated[list[str], Query()] = [],  # noqa: B006 (FastAPI copies defaults)
                     kind: Annotated[list[str], Query()] = [],  # noqa: B006
                     exclude_kind: Annotated[list[str], Query()] = []) -> EventStream:  # noqa: B006
        """Server-sent events: one `data:` line of JSON per event, as they happen; `event: lost` with
        a count where a slow reader's queue overflowed. 503 when too many streams are open. I/O
        changes come as `io` events (role, and each changed signal's old and new value), one per
        device and image every 20 ms at most."""
        for name in device:
            known(name)
        return EventStream(hub, device, kind, exclude_kind)

    @app.get("/health", responses={503: {"description": "class-1 I/O is not running, or the farm failed"}})
    def health() -> JSONResponse:
        """Whether the farm serves: `ok`, and whether its cyclic I/O thread runs (`cyclic_io.running`)
        with the errors it met and went on from; 503 while it does not serve as it should."""
        answer = farm.health()
        return JSONResponse(answer, status_code=200 if answer["ok"] else 503)

    app.include_router(group_routes(farm))
    app.include_router(scenario_routes(farm))

    @app.get("/metrics", response_class=PlainTextResponse)
    def metrics() -> PlainTextResponse:
        return PlainTextResponse(generate_latest(registry), media_type=CONTENT_TYPE_LATEST)

    mount_measured(app, timelines if timelines is not None else Timelines(farm.devices), known, farm.report)
    mount_dashboard(app)
    return app


def _hex(field: str, text: str | None) -> bytes | None:
    if text is None:
        return None
    try:
        return bytes.fromhex(text)
    except ValueError as error:
        raise ValueError(f"{field}: {error}") from None


def listening_socket(host: str, port: int) -> socket.socket:
    """A listening TCP socket for an HTTP server, bound here so that an address that cannot be
    bound is an OSError the caller explains in one line (`bind_problem`), not uvicorn's exit."""
    host = host.removeprefix("[").removesuffix("]")
    sock = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_STREAM)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind((host, port))
        sock.listen(128)
        sock.setblocking(False)
    except OSError:
        sock.close()
        raise
    return sock


def bind_problem(host: str, port: int, error: OSError) -> str:
    """One line on why the HTTP API cannot listen on host:port, and what to do."""
    where = f"the HTTP API cannot listen on {host}:{port}"
    if error.errno == errno.EADDRINUSE:
        return (f"{where}: the port is already in use (another farm's HTTP API?); choose another port "
                f"(--http {port + 1 if port < 65535 else 8044}), or --http 0 for any free one")
    if error.errno == errno.EADDRNOTAVAIL:
        return f"{where}: the address is not assigned to any interface of this host"
    if error.errno == errno.EACCES:
        return f"{where}: permission denied (ports below 1024 need root); choose a port from 1024 up"
    return f"{where}: {error.strerror or error}"


class _EmbeddedServer(uvicorn.Server):
    """uvicorn on the farm's loop; the farm, not uvicorn, owns the process's signals."""

    @contextlib.contextmanager
    def capture_signals(self) -> Iterator[None]:
        yield


class HttpApi:
    def __init__(self, farm: FarmControl, host: str, port: int, token: str | None) -> None:
        if needs_token(host) and not token:
            raise ValueError(f"the HTTP API on {host} needs a token (--token or ENIP_FARM_TOKEN); "
                             "only loopback (localhost, 127.x.y.z, ::1) is served without one")
        self.host = host
        self._port = port
        self.hub = EventHub(farm.devices.values())
        self.overview = Overview(farm.devices.values())
        self.timelines = Timelines(farm.devices)
        self.app = create_app(farm, self.hub, self.overview, self.timelines)
        self.server = _EmbeddedServer(uvicorn.Config(Guard(self.app, host, token), host=host, port=port,
                                                     log_level="warning",
                                                     lifespan="off", access_log=False))
        self.task: asyncio.Task | None = None

    async def start(self) -> None:
        """Serve; OSError when the address cannot be bound."""
        sock = listening_socket(self.host, self._port)
        self.task = asyncio.get_running_loop().create_task(self.server.serve(sockets=[sock]))
        while not self.server.started:
            if self.task.done():  # e.g. the port is taken
                self.task.result()
                raise OSError("the HTTP API did not start")
            await asyncio.sleep(0.01)

    @property
    def port(self) -> int:
        sockets = self.server.servers[0].sockets if self.server.servers else []
        return sockets[0].getsockname()[1] if sockets else 0

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host and not self.host.startswith("[") else self.host
        return f"http://{host}:{self.port}"

    async def stop(self) -> None:
        self.hub.close()
        self.overview.close()
        self.timelines.close()
        self.server.should_exit = True
        self.server.force_exit = True
        if self.task is not None:
            with contextlib.suppress(Exception):
                await asyncio.wait_for(self.task, 5)
