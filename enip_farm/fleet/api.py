"""One HTTP API for a fleet of workers (`serve --workers N --http`): the parent routes a request
for a device to the worker that serves it, and merges GET /devices, /state, /events, /metrics and
/report from every worker; the rest (/docs, the dashboard's page) comes from the first worker. It stands
behind the farm API's own Guard (Host, token, body size)."""

from __future__ import annotations

import asyncio
import contextlib
import threading
from collections.abc import AsyncIterator, Iterator

import httpx
import uvicorn
from prometheus_client import CollectorRegistry, generate_latest
from prometheus_client.metrics_core import Metric
from prometheus_client.parser import text_string_to_metric_families
from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import JSONResponse, Response, StreamingResponse
from starlette.routing import Route

from enip_farm.cip.report import worst
from enip_farm.control.client import merge_events
from enip_farm.control.guard import Guard
from enip_farm.control.http import bind_problem, listening_socket, no_such_device

START_TIMEOUT = 120.0
_FORWARD_TIMEOUT = 30.0
_HOP_HEADERS = frozenset({"connection", "keep-alive", "transfer-encoding", "content-length", "content-encoding",
                          "host", "upgrade", "te", "trailer", "proxy-authorization", "proxy-authenticate"})


def merge_metrics(texts: list[str], labels: list[dict[str, str]] | None = None,
                  extra: list[Metric] | None = None) -> str:
    """Prometheus text of several farms as one exposition, parsed and written by prometheus_client:
    each family once (HELP and TYPE from the first that has it) with every farm's samples, each
    given `labels[i]` (e.g. its shard) if given, then the families in `extra`."""
    families: dict[str, Metric] = {}
    for index, text in enumerate(texts):
        for family in text_string_to_metric_families(text):
            merged = families.get(family.name)
            if merged is None:
                merged = families[family.name] = Metric(family.name, family.documentation, family.type, family.unit)
            added = labels[index] if labels else {}
            merged.samples.extend(sample._replace(labels={**sample.labels, **added}) for sample in family.samples)

    class Merged:
        def collect(self) -> list[Metric]:
            return [*families.values(), *(extra or [])]

    registry = CollectorRegistry(auto_describe=False)
    registry.register(Merged())
    return generate_latest(registry).decode()


class Upstream:
    """A router's HTTP client toward the farms behind it (fleet_api.py, shard_api.py), made on the
    router's own event loop at its first use: a request goes on with its client's headers but the
    hop-by-hop ones (Authorization too: the farms check the token), and an answer comes back as it came."""

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


def create_router(owners: dict[str, int], apis: list[str]) -> Starlette:
    """The fleet's HTTP API: `owners` maps each device (in configuration order) to the index of the
    worker serving it, `apis[i]` is worker i's base URL. Requests are forwarded with their
    Authorization header; the workers answer (and check the token)."""
    order = {name: position for position, name in enumerate(owners)}
    upstream = Upstream()  # per router instance, its client made on the router's loop
    headers_of, response_of = upstream.headers_of, upstream.response_of

    def client() -> httpx.AsyncClient:
        return upstream.client

    async def forward(request: Request, worker: int) -> Response:
        return await upstream.forward(request, apis[worker])

    async def gather(request: Request, workers: list[int]) -> list[httpx.Response] | Response:
        replies = await asyncio.gather(*(client().get(apis[i] + request.url.path, headers=headers_of(request),
                                                      params=request.query_params.multi_items())
                                         for i in workers))
        failed = [reply for reply in replies if reply.status_code != 200]
        return response_of(failed[0]) if failed else list(replies)

    async def devices(request: Request) -> Response:
        replies = await gather(request, list(range(len(apis))))
        if isinstance(replies, Response):
            return replies
        merged = [device for reply in replies for device in reply.json()]
        merged.sort(key=lambda device: order.get(device.get("name"), len(order)))
        return JSONResponse(merged)

    async def device(request: Request) -> Response:
        name = request.path_params["name"]
        if name not in owners:
            return JSONResponse({"detail": no_such_device(name, owners)}, status_code=404)
        return await forward(request, owners[name])

    async def metrics(request: Request) -> Response:
        replies = await gather(request, list(range(len(apis))))
        if isinstance(replies, Response):
            return replies
        return Response(merge_metrics([reply.text for reply in replies]),
                        media_type=replies[0].headers.get("content-type", "text/plain"))

    async def events(request: Request) -> Response:
        names = request.query_params.getlist("device")
        for name in names:
            if name not in owners:
                return JSONResponse({"detail": no_such_device(name, owners)}, status_code=404)
        kinds = [(key, value) for key, value in request.query_params.multi_items()
                 if key in ("kind", "exclude_kind")]
        workers = sorted({owners[name] for name in names}) if names else list(range(len(apis)))
        streams = []
        for worker in workers:
            params = [("device", n) for n in names if owners[n] == worker] + kinds
            reply = await client().send(client().build_request("GET", apis[worker] + "/events", params=params,
                                                               headers=headers_of(request)), stream=True)
            streams.append(reply)
            if reply.status_code != 200:
                await reply.aread()
                for opened in streams:
                    await opened.aclose()
                return response_of(reply)
        return StreamingResponse(merge_events(streams), media_type="text/event-stream")

    async def state(request: Request) -> Response:
        names = request.query_params.getlist("device")
        for name in names:
            if name not in owners:
                return JSONResponse({"detail": no_such_device(name, owners)}, status_code=404)
        workers = sorted({owners[name] for name in names}) if names else list(range(len(apis)))
        replies = await asyncio.gather(*(client().get(apis[i] + "/state", headers=headers_of(request), params=[
            ("device", name) for name in names if owners[name] == i]) for i in workers))
        failed = [reply for reply in replies if reply.status_code != 200]
        if failed:
            return response_of(failed[0])
        merged = [device for reply in replies for device in reply.json()]
        wanted = {name: position for position, name in enumerate(names)} if names else order
        merged.sort(key=lambda device: wanted.get(device.get("name"), len(wanted)))
        return JSONResponse(merged)

    async def report(request: Request) -> Response:
        """Every worker's report (of the devices asked for) as one: devices in configuration order (or
        the order asked), reactions one after the other, the verdict the worst, `at_ns` the latest (one
        host, one monotonic clock)."""
        names = request.query_params.getlist("device")
        for name in names:
            if name not in owners:
                return JSONResponse({"detail": no_such_device(name, owners)}, status_code=404)
        workers = sorted({owners[name] for name in names}) if names else list(range(len(apis)))
        replies = await asyncio.gather(*(client().get(apis[i] + "/report", headers=headers_of(request), params=[
            ("device", name) for name in names if owners[name] == i]) for i in workers))
        failed = [reply for reply in replies if reply.status_code != 200]
        if failed:
            return response_of(failed[0])
        answers = [reply.json() for reply in replies]
        merged = [device for answer in answers for device in answer["devices"]]
        wanted = {name: position for position, name in enumerate(names)} if names else order
        merged.sort(key=lambda device: wanted.get(device["device"], len(wanted)))
        reactions = [reaction for answer in answers for reaction in answer["reactions"]]
        return JSONResponse({"at_ns": max(answer["at_ns"] for answer in answers),
                             "verdict": worst([answer["verdict"] for answer in answers]),
                             "failures": [line for answer in answers for line in answer["failures"]],
                             "devices": merged, "reactions": reactions})

    async def health(request: Request) -> Response:
        """Every worker's /health; 503 unless every worker answers ok (a worker that does not
        answer is not ok)."""
        async def one(api: str) -> dict:
            try:
                reply = await client().get(api + "/health", timeout=2.0)
                return reply.json()
            except (httpx.HTTPError, ValueError) as error:
                return {"ok": False, "failure": f"no answer: {error!r}"}
        workers = await asyncio.gather(*(one(api) for api in apis))
        ok = all(worker.get("ok") for worker in workers)
        return JSONResponse({"ok": ok, "workers": workers}, status_code=200 if ok else 503)

    async def other(request: Request) -> Response:  # /openapi.json, /docs: every worker has the same
        return await forward(request, 0)

    @contextlib.asynccontextmanager
    async def lifespan(_: Starlette) -> AsyncIterator[None]:
        yield
        await upstream.aclose()

    methods = ["GET", "PUT", "POST", "DELETE", "PATCH"]
    return Starlette(routes=[
        Route("/devices", devices, methods=["GET"]),
        Route("/devices/{name}", device, methods=methods),
        Route("/devices/{name}/{rest:path}", device, methods=methods),
        Route("/metrics", metrics, methods=["GET"]),
        Route("/events", events, methods=["GET"]),
        Route("/state", state, methods=["GET"]),
        Route("/report", report, methods=["GET"]),
        Route("/health", health, methods=["GET"]),
        Route("/{rest:path}", other, methods=methods),
    ], lifespan=lifespan)


class RouterServer(uvicorn.Server):
    """uvicorn in a thread of the parent; the parent, not uvicorn, owns the process's signals."""

    @contextlib.contextmanager
    def capture_signals(self) -> Iterator[None]:
        yield

    async def shutdown(self, sockets: list | None = None) -> None:
        await super().shutdown(sockets)
        if self.force_exit:  # uvicorn skips the app's lifespan then, which ends cancelled, with a traceback
            await self.lifespan.shutdown()


@contextlib.contextmanager
def serving_router(app: Starlette, host: str, port: int, token: str | None) -> Iterator[RouterServer]:
    """Serve `app` on (host, port) from a thread until the block ends, behind the farm API's own
    Guard (Host, token, body size), so the fleet's port refuses what a farm's port refuses."""
    try:
        sock = listening_socket(host, port)
    except OSError as error:
        raise OSError(error.errno, bind_problem(host, port, error)) from None
    server = RouterServer(uvicorn.Config(Guard(app, host, token), host=host, port=port, log_level="warning",
                                          access_log=False, lifespan="on", timeout_graceful_shutdown=2))
    thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, name="enip-farm-fleet-api", daemon=True)
    thread.start()
    try:
        deadline = START_TIMEOUT
        while not server.started and thread.is_alive() and deadline > 0:
            thread.join(0.05)
            deadline -= 0.05
        if not server.started:
            raise OSError(f"the fleet's HTTP API could not listen on {host}:{port}")
        yield server
    finally:
        server.should_exit = True
        server.force_exit = True  # open event streams end with the router
        thread.join(10)


def router_port(server: RouterServer) -> int:
    sockets = server.servers[0].sockets if server.servers else []
    return sockets[0].getsockname()[1] if sockets else 0
