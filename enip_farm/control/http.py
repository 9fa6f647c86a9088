"""The farm's HTTP API (FastAPI, served by uvicorn on the farm's own event loop).

GET /devices, GET /devices/{name}, GET and PUT /devices/{name}/io, POST and DELETE
/devices/{name}/faults, GET /events (server-sent events), GET /metrics (Prometheus), and the
OpenAPI schema at /openapi.json. Bound to anything but localhost, every request needs
`Authorization: Bearer <token>`.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import json
from collections.abc import AsyncIterator, Iterator
from typing import Annotated, Any

import uvicorn
from fastapi import Depends, FastAPI, HTTPException, Query, Request
from fastapi.responses import PlainTextResponse, StreamingResponse
from prometheus_client import CollectorRegistry, generate_latest
from prometheus_client.exposition import CONTENT_TYPE_LATEST
from pydantic import BaseModel, Field

from enip_farm.control.handle import FarmControl
from enip_farm.control.metrics import FarmCollector
from enip_farm.device.events import Event
from enip_farm.device.faults import Fault, FaultKind
from enip_farm.device.signals import SignalError

LOCALHOST = frozenset({"127.0.0.1", "localhost", "::1"})
_EVENT_QUEUE = 10000


class IoWrite(BaseModel):
    """Hex images and/or signals, e.g. {"signals": {"DI3": 1, "AI1": 1200}}."""

    inputs: str | None = Field(None, description="the whole input image, hex")
    outputs: str | None = Field(None, description="the whole output image, hex")
    signals: dict[str, int | list[int]] = {}


class FaultRequest(BaseModel):
    kind: FaultKind
    delay_ms: float = 0.0
    max_delay_ms: float | None = None
    service: int | None = Field(None, description="status: the CIP service code, e.g. 14 for Get Attribute Single")
    status: int | None = Field(None, description="status: the general status to answer with")
    duration_s: float | None = Field(None, description="end the fault by itself after this long")


def _io(farm: FarmControl, name: str) -> dict[str, Any]:
    handle = farm[name]
    signals = {}
    for kind, count in handle.signals.names().items():
        if count:
            values = handle.get(f"{kind}1-{count}")
            signals[kind] = values if isinstance(values, list) else [values]
    return {"inputs": handle.inputs.hex(), "outputs": handle.outputs.hex(), "signals": signals}


def _device(farm: FarmControl, name: str, detail: bool = False) -> dict[str, Any]:
    device = farm.devices[name]
    p = device.profile
    out: dict[str, Any] = {
        "name": p.name, "address": p.address, "model": p.model, "addons": list(p.addons),
        "identity": {"vendor_id": p.vendor_id, "device_type": p.device_type, "product_code": device.product_code,
                     "revision": list(p.revision), "serial_number": p.serial_number, "product_name": p.product_name,
                     "status": device.status},
        "input_size": p.input_size, "output_size": p.output_size,
        "connections": [{"kind": c.kind.value, "o_t_id": c.o_t_id, "t_o_id": c.t_o_id, "o_t_rpi_us": c.o_t_rpi,
                         "t_o_rpi_us": c.t_o_rpi, "originator": c.originator_host, "received": c.received,
                         "multicast": c.multicast} for c in list(device.connections.values())],
        "faults": farm[name].faults,
        "unverified": list(p.unverified),
    }
    if detail:
        out["counters"] = farm[name].counters
        out["io"] = _io(farm, name)
    return out


def create_app(farm: FarmControl, token: str | None = None) -> FastAPI:
    app = FastAPI(title="enip-farm", description="Drive and observe a farm of virtual EtherNet/IP devices.")
    registry = CollectorRegistry()
    registry.register(FarmCollector(farm.devices.values()))

    def authorize(request: Request) -> None:
        if token is None:
            return
        given = request.headers.get("authorization", "")
        if not hmac.compare_digest(given.encode(), f"Bearer {token}".encode()):
            raise HTTPException(401, "a bearer token is required", headers={"WWW-Authenticate": "Bearer"})

    def known(name: str) -> str:
        if name not in farm.devices:
            raise HTTPException(404, f"no device named {name!r}")
        return name

    @app.get("/devices", dependencies=[Depends(authorize)])
    def devices() -> list[dict[str, Any]]:
        return [_device(farm, name) for name in farm.devices]

    @app.get("/devices/{name}", dependencies=[Depends(authorize)])
    def device(name: str) -> dict[str, Any]:
        return _device(farm, known(name), detail=True)

    @app.get("/devices/{name}/io", dependencies=[Depends(authorize)])
    def get_io(name: str) -> dict[str, Any]:
        return _io(farm, known(name))

    @app.put("/devices/{name}/io", dependencies=[Depends(authorize)])
    def put_io(name: str, body: IoWrite) -> dict[str, Any]:
        device = farm.devices[known(name)]
        try:
            if body.inputs is not None:
                device.write_image("input", lambda image: _assign(image, bytes.fromhex(body.inputs)))
            if body.outputs is not None:
                device.write_image("output", lambda image: _assign(image, bytes.fromhex(body.outputs)))
            if body.signals:
                farm[name].set(body.signals)
        except (SignalError, ValueError, KeyError) as error:
            raise HTTPException(422, str(error)) from None
        return _io(farm, name)

    @app.post("/devices/{name}/faults", status_code=201, dependencies=[Depends(authorize)])
    async def inject(name: str, body: FaultRequest) -> list[dict]:
        try:
            fault = Fault(**body.model_dump())
        except ValueError as error:
            raise HTTPException(422, str(error)) from None
        await farm.inject_fault(known(name), fault)
        return farm[name].faults

    @app.delete("/devices/{name}/faults", dependencies=[Depends(authorize)])
    async def clear(name: str, kind: FaultKind | None = None) -> dict[str, list[str]]:
        cleared = await farm.clear_faults(known(name), kind)
        return {"cleared": [k.value for k in cleared]}

    @app.get("/events", dependencies=[Depends(authorize)])
    async def events(device: Annotated[list[str], Query()] = [],  # noqa: B006 (FastAPI copies defaults)
                     kind: Annotated[list[str], Query()] = []) -> StreamingResponse:  # noqa: B006
        """Server-sent events: one `data:` line of JSON per event, as they happen."""
        for name in device:
            known(name)
        chosen = [farm.devices[n] for n in device] or list(farm.devices.values())
        return StreamingResponse(_stream(chosen, set(kind)), media_type="text/event-stream")

    @app.get("/metrics", response_class=PlainTextResponse, dependencies=[Depends(authorize)])
    def metrics() -> PlainTextResponse:
        return PlainTextResponse(generate_latest(registry), media_type=CONTENT_TYPE_LATEST)

    return app


def _assign(image: bytearray, data: bytes) -> None:
    if len(data) != len(image):
        raise ValueError(f"image is {len(image)} bytes, got {len(data)}")
    image[:] = data


async def _stream(devices: list, kinds: set[str]) -> AsyncIterator[str]:
    loop = asyncio.get_running_loop()
    queue: asyncio.Queue[Event | int] = asyncio.Queue()
    lost = 0

    def deliver(event: Event) -> None:  # may run in the cyclic I/O thread
        if not kinds or event.kind in kinds:
            loop.call_soon_threadsafe(put, event)

    def put(event: Event) -> None:
        nonlocal lost
        if queue.qsize() >= _EVENT_QUEUE:
            lost += 1  # a slow reader: say how many were lost, never drop silently
        else:
            if lost:
                queue.put_nowait(lost)
                lost = 0
            queue.put_nowait(event)

    unsubscribes = [device.observe(deliver) for device in devices]
    try:
        yield ": enip-farm event stream\n\n"
        while True:
            item = await queue.get()
            if isinstance(item, int):
                yield f"event: lost\ndata: {json.dumps({'lost': item})}\n\n"
            else:
                yield f"data: {json.dumps(item.as_dict())}\n\n"
    finally:
        for unsubscribe in unsubscribes:
            unsubscribe()


class _EmbeddedServer(uvicorn.Server):
    """uvicorn on the farm's loop; the farm, not uvicorn, owns the process's signals."""

    @contextlib.contextmanager
    def capture_signals(self) -> Iterator[None]:
        yield


class HttpApi:
    def __init__(self, farm: FarmControl, host: str, port: int, token: str | None) -> None:
        if host not in LOCALHOST and not token:
            raise ValueError(f"the HTTP API on {host} needs a token (--token or ENIP_FARM_TOKEN); "
                             "only localhost is served without one")
        self.host = host
        self.app = create_app(farm, token)
        self.server = _EmbeddedServer(uvicorn.Config(self.app, host=host, port=port, log_level="warning",
                                                     lifespan="off", access_log=False))
        self.task: asyncio.Task | None = None

    async def start(self) -> None:
        self.task = asyncio.get_running_loop().create_task(self.server.serve())
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
        return f"http://{self.host}:{self.port}"

    async def stop(self) -> None:
        self.server.should_exit = True
        self.server.force_exit = True
        if self.task is not None:
            with contextlib.suppress(Exception):
                await asyncio.wait_for(self.task, 5)
