"""One HTTP API for a cell's shards wherever an engine runs them (`enip-farm fleet-api`): Docker
Swarm tasks found by `tasks.<service>` DNS, Kubernetes pods by a headless Service. Each shard's
GET /devices says which slice it serves; a device's requests go to its shard; GET /devices,
/state, /events and /metrics merge every shard's answer; a shard that does not answer is listed
as down (its devices with `"shard_up": false`, GET /shards, `enip_farm_shard_up 0`), never left out.
It stands behind the farm API's own Guard (Host, token, body size)."""

from __future__ import annotations

import asyncio
import contextlib
import socket
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
from enip_farm.fleet.api import Upstream, merge_metrics
from enip_farm.fleet.slices import split

_PROBE_TIMEOUT = 3.0
_VIEW_TTL = 1.0  # seconds a view of the shards serves device requests before it is looked up again

Discover = Callable[[], Awaitable[list[str]]]


def dns_discovery(name: str, port: int) -> Discover:
    """Every address `name` resolves to (Swarm's `tasks.farm`, a headless Service), as base URLs."""

    async def discover() -> list[str]:
        try:
            infos = await asyncio.get_running_loop().getaddrinfo(name, port, family=socket.AF_INET,
                                                                 type=socket.SOCK_STREAM)
        except socket.gaierror:
            return []
        return sorted({f"http://{info[4][0]}:{port}" for info in infos})

    return discover


def static_discovery(urls: list[str]) -> Discover:
    async def discover() -> list[str]:
        return list(urls)

    return discover


@dataclass
class Shard:
    index: int  # 1-based, as in --shard I/N
    devices: list[str]
    endpoint: str | None = None
    listing: list[dict[str, Any]] = field(default_factory=list)  # its GET /devices while up

    @property
    def up(self) -> bool:
        return self.endpoint is not None


class ShardView:
    """Which endpoint serves which slice, from the shards' own GET /devices."""

    def __init__(self, config: FarmConfig, shards: int) -> None:
        self.shards = [Shard(i + 1, [d.name for d in part.devices]) for i, part in enumerate(split(config, shards))]
        self.owner = {name: shard for shard in self.shards for name in shard.devices}
        self.order = {device.name: position for position, device in enumerate(config.devices)}
        self.config = {device.name: device for device in config.devices}
        self.count = shards
        self.taken = 0.0

    def learn(self, listings: dict[str, list[dict[str, Any]]], now: float) -> None:
        """`listings`: endpoint -> its GET /devices, for the endpoints that answered."""
        for shard in self.shards:
            shard.endpoint, shard.listing = None, []
        for endpoint, listing in sorted(listings.items()):
            names = [device.get("name") for device in listing]
            shard = self.owner.get(names[0]) if names else None
            if shard is not None and not shard.up and set(names) == set(shard.devices):
                shard.endpoint, shard.listing = endpoint, listing
        self.taken = now

    def down(self, shard: Shard) -> str:
        return f"shard {shard.index}/{self.count} (devices {shard.devices[0]}..{shard.devices[-1]}) is down"

    def shard_states(self) -> list[dict[str, Any]]:
        return [{"shard": s.index, "up": s.up, "endpoint": s.endpoint, "devices": s.devices} for s in self.shards]

    def devices(self) -> list[dict[str, Any]]:
        merged = []
        for shard in self.shards:
            if shard.up:
                merged.extend({**device, "shard": shard.index, "shard_up": True} for device in shard.listing)
            else:
                for name in shard.devices:
                    device = self.config[name]
                    merged.append({"name": name, "address": str(device.address), "model": device.model,
                                   "addons": list(device.addons), "identity": {}, "input_size": 0,
                                   "output_size": 0, "connections": [], "faults": [], "unverified": [],
                                   "shard": shard.index, "shard_up": False})
        merged.sort(key=lambda device: self.order.get(device["name"], len(self.order)))
        return merged


def down_state(name: str, shard: int) -> dict[str, Any]:
    """A device of a shard that is down, in GET /state's shape: nothing connected, no signals known."""
    return {"name": name, "monotonic": 0.0, "signals": [], "status": 0, "owners": [], "connections": [],
            "counters": {}, "faults": [], "shard": shard, "shard_up": False}


def create_shard_router(config: FarmConfig, shards: int, discover: Discover, token: str | None,
                        clock: Callable[[], float] = time.monotonic) -> Starlette:
    """The fleet's HTTP API over the shards `discover` finds. `token`: the router's own, for asking
    the shards what they serve; a client's requests are forwarded with the client's Authorization."""
    view = ShardView(config, shards)
    own = {"Authorization": f"Bearer {token}"} if token else {}
    upstream = Upstream()
    headers_of, response_of = upstream.headers_of, upstream.response_of
    lock: dict[str, asyncio.Lock] = {}

    def client() -> httpx.AsyncClient:
        return upstream.client

    async def refresh(force: bool) -> ShardView:
        if "lock" not in lock:
            lock["lock"] = asyncio.Lock()
        async with lock["lock"]:
            if force or clock() - view.taken >= _VIEW_TTL:
                endpoints = await discover()

                async def listing(endpoint: str) -> tuple[str, list[dict[str, Any]] | None]:
                    try:
                        reply = await client().get(endpoint + "/devices", headers=own, timeout=_PROBE_TIMEOUT)
                    except httpx.HTTPError:
                        return endpoint, None
                    return endpoint, reply.json() if reply.status_code == 200 else None

                answers = await asyncio.gather(*(listing(endpoint) for endpoint in endpoints))
                view.learn({endpoint: answer for endpoint, answer in answers if answer is not None}, clock())
        return view

    forward = upstream.forward

    def unknown(name: str) -> Response:
        return JSONResponse({"detail": no_such_device(name, view.order)}, status_code=404)

    def unavailable(shard: Shard) -> Response:
        return JSONResponse({"detail": view.down(shard)}, status_code=503)

    async def devices(request: Request) -> Response:
        return JSONResponse((await refresh(force=True)).devices())

    async def shard_list(request: Request) -> Response:
        return JSONResponse((await refresh(force=True)).shard_states())

    async def device(request: Request) -> Response:
        name = request.path_params["name"]
        if name not in view.owner:
            return unknown(name)
        shard = (await refresh(force=False)).owner[name]
        if not shard.up:
            shard = (await refresh(force=True)).owner[name]
        if not shard.up:
            return unavailable(shard)
        try:
            return await forward(request, shard.endpoint or "")
        except httpx.TransportError:  # the shard went away since the last look: look again, once
            shard = (await refresh(force=True)).owner[name]
            if not shard.up:
                return unavailable(shard)
            return await forward(request, shard.endpoint or "")

    async def metrics(request: Request) -> Response:
        up = [shard for shard in (await refresh(force=True)).shards if shard.up]
        replies = await asyncio.gather(*(client().get(f"{shard.endpoint}/metrics", headers=headers_of(request))
                                         for shard in up), return_exceptions=True)
        texts, labels = [], []
        states = {shard.index: shard.up for shard in view.shards}
        for shard, reply in zip(up, replies, strict=True):
            if isinstance(reply, httpx.Response) and reply.status_code == 200:
                texts.append(reply.text)
                labels.append({"shard": str(shard.index)})
            elif isinstance(reply, httpx.Response) and reply.status_code in (401, 403):
                return response_of(reply)
            else:
                states[shard.index] = False
        gauge = GaugeMetricFamily("enip_farm_shard_up", "1 if the shard answers, 0 if it is down", labels=["shard"])
        for index, state in states.items():
            gauge.add_metric([str(index)], 1.0 if state else 0.0)
        return Response(merge_metrics(texts, labels, [gauge]), media_type="text/plain; version=0.0.4; charset=utf-8")

    async def state(request: Request) -> Response:
        names = request.query_params.getlist("device")
        for name in names:
            if name not in view.owner:
                return unknown(name)
        await refresh(force=True)
        wanted = set(names) if names else set(view.owner)
        shards = [shard for shard in view.shards if wanted & set(shard.devices)]
        up = [shard for shard in shards if shard.up]
        replies = await asyncio.gather(*(client().get(f"{shard.endpoint}/state", headers=headers_of(request), params=[
            ("device", name) for name in names if name in shard.devices]) for shard in up), return_exceptions=True)
        merged: list[dict[str, Any]] = []
        answered = set()
        for shard, reply in zip(up, replies, strict=True):
            if isinstance(reply, httpx.Response) and reply.status_code == 200:
                merged.extend({**device, "shard": shard.index, "shard_up": True} for device in reply.json())
                answered.add(shard.index)
            elif isinstance(reply, httpx.Response):
                return response_of(reply)
        for shard in shards:
            if shard.index not in answered:
                merged.extend(down_state(name, shard.index) for name in shard.devices if name in wanted)
        position = {name: i for i, name in enumerate(names)} if names else view.order
        merged.sort(key=lambda device: position.get(device.get("name"), len(position)))
        return JSONResponse(merged)

    async def events(request: Request) -> Response:
        names = request.query_params.getlist("device")
        for name in names:
            if name not in view.owner:
                return unknown(name)
        kinds = [(key, value) for key, value in request.query_params.multi_items()
                 if key in ("kind", "exclude_kind")]
        await refresh(force=True)
        shards = [shard for shard in view.shards if shard.up and (not names or set(names) & set(shard.devices))]
        streams = []
        for shard in shards:
            params = [("device", n) for n in names if n in shard.devices] + kinds
            try:
                reply = await client().send(client().build_request("GET", f"{shard.endpoint}/events", params=params,
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

    async def other(request: Request) -> Response:  # the dashboard's page, /docs: every shard has the same
        up = [shard for shard in (await refresh(force=False)).shards if shard.up]
        if not up:
            return JSONResponse({"detail": f"no shard of {shards} answers"}, status_code=503)
        return await forward(request, up[0].endpoint or "")

    @contextlib.asynccontextmanager
    async def lifespan(_: Starlette) -> AsyncIterator[None]:
        yield
        await upstream.aclose()

    methods = ["GET", "PUT", "POST", "DELETE", "PATCH"]
    return Starlette(routes=[
        Route("/devices", devices, methods=["GET"]),
        Route("/shards", shard_list, methods=["GET"]),
        Route("/devices/{name}", device, methods=methods),
        Route("/devices/{name}/{rest:path}", device, methods=methods),
        Route("/metrics", metrics, methods=["GET"]),
        Route("/events", events, methods=["GET"]),
        Route("/state", state, methods=["GET"]),
        Route("/{rest:path}", other, methods=methods),
    ], lifespan=lifespan)
