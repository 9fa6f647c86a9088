"""The one HTTP API in front of a cell's farms, whichever they are: the workers of `serve --workers N
--http` (fleet/api.py) and the shards that an engine runs (`enip-farm fleet-api`, fleet/shard_api.py).

Each farm is asked what it serves (GET /devices); a device's requests go to the farm serving its
part of the cell; GET /devices, /state, /events, /metrics, /report, /overview and /health merge
every farm's answer (fleet/reports.py the report's, the overview's and the metrics'); a farm that
does not answer is **down, not missing**: its devices are listed with `"<part>_up":
false`, a request for one gets 503 `<part> I/N (devices A..B) is down`, `enip_farm_<part>_up` is 0,
GET /<part>s lists each part, its endpoint and whether it is up. The routes are the same for both;
the one difference is a `Finder`: where the farms may be (workers: their ports, known at start;
shards: an engine's DNS) and what a part is called ("worker", "shard")."""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import AsyncIterator, Awaitable, Callable
from dataclasses import dataclass, field
from typing import Any

import httpx
from prometheus_client.metrics_core import GaugeMetricFamily
from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import JSONResponse, Response, StreamingResponse
from starlette.routing import Route

from enip_farm.config import FarmConfig
from enip_farm.control.client import merge_events
from enip_farm.control.http import no_such_device
from enip_farm.fleet.reports import down_device, merge_metrics, merge_overviews, merge_reports

_FORWARD_TIMEOUT = 30.0
_PROBE_TIMEOUT = 3.0
_VIEW_TTL = 1.0  # seconds a view of the parts serves device requests before it is looked up again
_HOP_HEADERS = frozenset({"connection", "keep-alive", "transfer-encoding", "content-length", "content-encoding",
                          "host", "upgrade", "te", "trailer", "proxy-authorization", "proxy-authenticate"})

Endpoints = Callable[[], Awaitable[list[str]]]


@dataclass(frozen=True)
class Finder:
    """The one difference between the fleet's routers: what a part of the cell is called (`label`:
    its devices' `"<label>"` and `"<label>_up"`, GET /<label>s, `enip_farm_<label>_up`, the 503's
    words) and where the farms serving the parts may be (`endpoints`: base URLs; each says which
    part it serves through its own GET /devices)."""

    label: str
    endpoints: Endpoints


def static_endpoints(urls: list[str]) -> Endpoints:
    async def endpoints() -> list[str]:
        return list(urls)

    return endpoints


class Upstream:
    """The router's HTTP client toward the farms behind it, made on the router's own event loop at
    its first use: a request goes on with its client's headers but the hop-by-hop ones
    (Authorization goes on: the farms check the token), and an answer comes back as it came."""

    def __init__(self, timeout: float = _FORWARD_TIMEOUT) -> None:
        self.timeout = timeout
        self._client: httpx.AsyncClient | None = None

    @property
    def client(self) -> httpx.AsyncClient:
        if self._client is None:
            self._client = httpx.AsyncClient(timeout=self.timeout)
        return self._client

    @staticmethod
    def headers_of(request: Request) -> dict[str, str]:
        return {k: v for k, v in request.headers.items() if k.lower() not in _HOP_HEADERS}

    @staticmethod
    def response_of(reply: httpx.Response) -> Response:
        headers = {k: v for k, v in reply.headers.items() if k.lower() not in _HOP_HEADERS}
        return Response(reply.content, status_code=reply.status_code, headers=headers)

    async def forward(self, request: Request, base: str) -> Response:
        """`request` as it came, to the farm at `base`; its answer."""
        reply = await self.client.request(request.method, base + request.url.path,
                                          params=request.query_params.multi_items(),
                                          headers=self.headers_of(request), content=await request.body())
        return self.response_of(reply)

    async def aclose(self) -> None:
        if self._client is not None:
            await self._client.aclose()
            self._client = None


@dataclass
class Part:
    index: int  # 1-based, as in --shard I/N
    devices: list[str]  # configuration order
    endpoint: str | None = None  # where it answered at the last look; None: down
    listing: list[dict[str, Any]] = field(default_factory=list)  # its GET /devices while up

    @property
    def up(self) -> bool:
        return self.endpoint is not None


class View:
    """Which endpoint serves which part, from the farms' own GET /devices."""

    def __init__(self, config: FarmConfig, slices: list[FarmConfig], label: str) -> None:
        self.parts = [Part(i + 1, [d.name for d in part.devices]) for i, part in enumerate(slices)]
        self.owner = {name: part for part in self.parts for name in part.devices}
        self.order = {device.name: position for position, device in enumerate(config.devices)}
        self.config = {device.name: device for device in config.devices}
        self.label = label
        self.taken = 0.0
        self.looked = False

    def learn(self, listings: dict[str, list[dict[str, Any]]], now: float) -> None:
        """`listings`: endpoint -> its GET /devices, for the endpoints that answered."""
        for part in self.parts:
            part.endpoint, part.listing = None, []
        for endpoint, listing in sorted(listings.items()):
            names = [device.get("name") for device in listing]
            part = self.owner.get(names[0]) if names else None
            if part is not None and not part.up and set(names) == set(part.devices):
                part.endpoint, part.listing = endpoint, listing
        self.taken, self.looked = now, True

    def down(self, part: Part) -> str:
        return (f"{self.label} {part.index}/{len(self.parts)} (devices {part.devices[0]}..{part.devices[-1]}) "
                "is down")

    def marks(self, part: Part, up: bool) -> dict[str, Any]:
        return {self.label: part.index, f"{self.label}_up": up}

    def part_states(self) -> list[dict[str, Any]]:
        return [{self.label: p.index, "up": p.up, "endpoint": p.endpoint, "devices": p.devices} for p in self.parts]

    def devices(self) -> list[dict[str, Any]]:
        merged = []
        for part in self.parts:
            if part.up:
                merged.extend({**device, **self.marks(part, True)} for device in part.listing)
            else:
                for name in part.devices:
                    device = self.config[name]
                    merged.append({"name": name, "address": str(device.address), "model": device.model,
                                   "addons": list(device.addons), "identity": {}, "input_size": 0,
                                   "output_size": 0, "connections": [], "faults": [], "unverified": [],
                                   **self.marks(part, False)})
        merged.sort(key=lambda device: self.order.get(device["name"], len(self.order)))
        return merged

    def down_tile(self, name: str, part: Part) -> dict[str, Any]:
        """A device of a part that is down, as GET /overview shows it: faulted, by its part's being down."""
        device = self.config[name]
        return {"name": name, "address": str(device.address), "model": device.model, "addons": list(device.addons),
                "state": "faulted", "io_connections": 0, "timeouts": 0, "faults": [f"{self.label} down"],
                **self.marks(part, False)}

    def down_state(self, name: str, part: Part) -> dict[str, Any]:
        """A device of a part that is down, in GET /state's shape: nothing connected, no signals known."""
        return {"name": name, "monotonic": 0.0, "signals": [], "status": 0, "owners": [], "connections": [],
                "counters": {}, "faults": [], **self.marks(part, False)}


def create_router(config: FarmConfig, slices: list[FarmConfig], finder: Finder, token: str | None,
                  clock: Callable[[], float] = time.monotonic) -> Starlette:
    """The fleet's HTTP API over the farms serving `slices` of `config`, found by `finder`. `token`:
    the router's own, for asking the farms what they serve; a client's requests are forwarded with
    the client's Authorization, and the farms check it."""
    view = View(config, slices, finder.label)
    own = {"Authorization": f"Bearer {token}"} if token else {}
    upstream = Upstream()
    headers_of, response_of, forward = upstream.headers_of, upstream.response_of, upstream.forward
    lock: dict[str, asyncio.Lock] = {}

    def client() -> httpx.AsyncClient:
        return upstream.client

    async def refresh(force: bool) -> View:
        if "lock" not in lock:
            lock["lock"] = asyncio.Lock()
        async with lock["lock"]:
            if force or not view.looked or clock() - view.taken >= _VIEW_TTL:
                endpoints = await finder.endpoints()

                async def listing(endpoint: str) -> tuple[str, list[dict[str, Any]] | None]:
                    try:
                        reply = await client().get(endpoint + "/devices", headers=own, timeout=_PROBE_TIMEOUT)
                    except httpx.HTTPError:
                        return endpoint, None
                    return endpoint, reply.json() if reply.status_code == 200 else None

                answers = await asyncio.gather(*(listing(endpoint) for endpoint in endpoints))
                view.learn({endpoint: answer for endpoint, answer in answers if answer is not None}, clock())
        return view

    def asked(request: Request) -> list[str] | Response:
        """The devices a request names with `?device=` (404 for one the cell does not have)."""
        names = request.query_params.getlist("device")
        unknown = next((name for name in names if name not in view.owner), None)
        if unknown is not None:
            return JSONResponse({"detail": no_such_device(unknown, view.order)}, status_code=404)
        return names

    async def devices(request: Request) -> Response:
        return JSONResponse((await refresh(force=True)).devices())

    async def part_list(request: Request) -> Response:
        return JSONResponse((await refresh(force=True)).part_states())

    async def device(request: Request) -> Response:
        name = request.path_params["name"]
        if name not in view.owner:
            return JSONResponse({"detail": no_such_device(name, view.order)}, status_code=404)
        part = (await refresh(force=False)).owner[name]
        looks = 0
        while looks < 2:  # down at the last look, or gone since: look again, once
            if not part.up:
                part, looks = (await refresh(force=True)).owner[name], looks + 1
            if not part.up:
                break
            try:
                return await forward(request, part.endpoint or "")
            except httpx.TransportError:
                part.endpoint = None
        return JSONResponse({"detail": view.down(part)}, status_code=503)

    async def metrics(request: Request) -> Response:
        up = [part for part in (await refresh(force=True)).parts if part.up]
        replies = await asyncio.gather(*(client().get(f"{part.endpoint}/metrics", headers=headers_of(request))
                                         for part in up), return_exceptions=True)
        texts, labels = [], []
        states = {part.index: part.up for part in view.parts}
        for part, reply in zip(up, replies, strict=True):
            if isinstance(reply, httpx.Response) and reply.status_code == 200:
                texts.append(reply.text)
                labels.append({view.label: str(part.index)})
            elif isinstance(reply, httpx.Response) and reply.status_code in (401, 403):
                return response_of(reply)
            else:
                states[part.index] = False
        gauge = GaugeMetricFamily(f"enip_farm_{view.label}_up", f"1 if the {view.label} answers, 0 if it is down",
                                  labels=[view.label])
        for index, state in states.items():
            gauge.add_metric([str(index)], 1.0 if state else 0.0)
        return Response(merge_metrics(texts, labels, [gauge]), media_type="text/plain; version=0.0.4; charset=utf-8")

    async def ask_parts(request: Request, path: str, names: list[str], extra: tuple[tuple[str, str], ...] = ()
                        ) -> tuple[set[str], list[Part], list[tuple[Part, Any]]] | Response:
        """GET `path` of every part up that serves one of `names` (none: every device), at once: the
        names wanted, the parts serving them, and (part, JSON) of those that answered 200; a part's
        other answer is the reply (one that did not answer counts as down). `extra`: more parameters."""
        await refresh(force=True)
        wanted = set(names) if names else set(view.owner)
        parts = [part for part in view.parts if wanted & set(part.devices)]
        up = [part for part in parts if part.up]
        replies = await asyncio.gather(*(client().get(f"{part.endpoint}/{path}", headers=headers_of(request), params=[
            ("device", name) for name in names if name in part.devices] + list(extra)) for part in up),
            return_exceptions=True)
        answers: list[tuple[Part, Any]] = []
        for part, reply in zip(up, replies, strict=True):
            if isinstance(reply, httpx.Response) and reply.status_code == 200:
                answers.append((part, reply.json()))
            elif isinstance(reply, httpx.Response):
                return response_of(reply)
        return wanted, parts, answers

    async def state(request: Request) -> Response:
        names = asked(request)
        if isinstance(names, Response):
            return names
        asking = await ask_parts(request, "state", names)
        if isinstance(asking, Response):
            return asking
        wanted, parts, answers = asking
        merged = [{**device, **view.marks(part, True)} for part, listing in answers for device in listing]
        answered = {part.index for part, _ in answers}
        for part in parts:
            if part.index not in answered:
                merged.extend(view.down_state(name, part) for name in part.devices if name in wanted)
        position = {name: i for i, name in enumerate(names)} if names else view.order
        merged.sort(key=lambda device: position.get(device.get("name"), len(position)))
        return JSONResponse(merged)

    async def report(request: Request) -> Response:
        names = asked(request)
        if isinstance(names, Response):
            return names
        asking = await ask_parts(request, "report", names)
        if isinstance(asking, Response):
            return asking
        wanted, parts, answers = asking
        answered = {part.index for part, _ in answers}
        down = [down_device(name, view.marks(part, False)) for part in parts if part.index not in answered
                for name in part.devices if name in wanted]
        position = {name: i for i, name in enumerate(names)} if names else view.order
        return JSONResponse(merge_reports([(report, view.marks(part, True)) for part, report in answers], down,
                                          position))

    async def overview(request: Request) -> Response:
        asking = await ask_parts(request, "overview", [], tuple(request.query_params.multi_items()))
        if isinstance(asking, Response):
            return asking
        _, parts, answers = asking
        answered = {part.index for part, _ in answers}
        down = [view.down_tile(name, part) for part in parts if part.index not in answered for name in part.devices]
        return JSONResponse(merge_overviews([(answer, view.marks(part, True)) for part, answer in answers], down,
                                            view.order, int(request.query_params.get("events", 0))))

    async def events(request: Request) -> Response:
        names = asked(request)
        if isinstance(names, Response):
            return names
        kinds = [(key, value) for key, value in request.query_params.multi_items()
                 if key in ("kind", "exclude_kind")]
        await refresh(force=True)
        streams = []
        for part in view.parts:
            if not part.up or (names and not set(names) & set(part.devices)):
                continue
            params = [("device", n) for n in names if n in part.devices] + kinds
            try:
                reply = await client().send(client().build_request("GET", f"{part.endpoint}/events", params=params,
                                                                   headers=headers_of(request)), stream=True)
            except httpx.TransportError:
                continue  # gone since the look: its events are not there to merge
            streams.append(reply)
            if reply.status_code != 200:
                await reply.aread()
                for opened in streams:
                    await opened.aclose()
                return response_of(reply)
        return StreamingResponse(merge_events(streams), media_type="text/event-stream")

    async def health(request: Request) -> Response:
        """Every part's /health; 503 unless every one answers ok (a part that is down is not ok)."""
        await refresh(force=True)

        async def one(part: Part) -> dict[str, Any]:
            if not part.up:
                return {**view.marks(part, False), "ok": False, "failure": view.down(part)}
            try:
                reply = await client().get(f"{part.endpoint}/health", timeout=_PROBE_TIMEOUT)
                return {**view.marks(part, True), **reply.json()}
            except (httpx.HTTPError, ValueError) as error:
                return {**view.marks(part, False), "ok": False, "failure": f"no answer: {error!r}"}

        answers = await asyncio.gather(*(one(part) for part in view.parts))
        ok = all(answer.get("ok") for answer in answers)
        return JSONResponse({"ok": ok, f"{view.label}s": answers}, status_code=200 if ok else 503)

    async def other(request: Request) -> Response:  # the dashboard's page, /docs: every farm has the same
        up = [part for part in (await refresh(force=False)).parts if part.up]
        if not up:
            return JSONResponse({"detail": f"no {view.label} of {len(view.parts)} answers"}, status_code=503)
        return await forward(request, up[0].endpoint or "")

    @contextlib.asynccontextmanager
    async def lifespan(_: Starlette) -> AsyncIterator[None]:
        yield
        await upstream.aclose()

    methods = ["GET", "PUT", "POST", "DELETE", "PATCH"]
    return Starlette(routes=[
        Route("/devices", devices, methods=["GET"]),
        Route(f"/{view.label}s", part_list, methods=["GET"]),
        Route("/devices/{name}", device, methods=methods),
        Route("/devices/{name}/{rest:path}", device, methods=methods),
        Route("/metrics", metrics, methods=["GET"]),
        Route("/events", events, methods=["GET"]),
        Route("/state", state, methods=["GET"]),
        Route("/report", report, methods=["GET"]),
        Route("/overview", overview, methods=["GET"]),
        Route("/health", health, methods=["GET"]),
        Route("/{rest:path}", other, methods=methods),
    ], lifespan=lifespan)
