"""The farm's HTTP API from the outside, for the CLI, FleetClient, the fleets' routers and the tests:
requests with httpx, the event stream (GET /events: server-sent events, WHATWG HTML §9.2) read with
httpx-sse and written back in the same format when several streams are merged."""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator, Iterable, Iterator
from typing import Any

import httpx
from httpx_sse import EventSource, ServerSentEvent, connect_sse

__all__ = ["ApiClient", "ApiError", "ServerSentEvent", "Unreachable", "detail_of", "encode_event", "merge_events"]

KEEPALIVE_S = 15.0  # a merged stream's comment when its sources say nothing (as a farm's own stream does)


class ApiError(Exception):
    """The API answered a request with an error status; `detail` is its reason in one line."""

    def __init__(self, method: str, path: str, status: int, detail: str) -> None:
        super().__init__(f"{method} {path}: {status} {detail}")
        self.status = status
        self.detail = detail


class Unreachable(Exception):
    """No answer from the API at `api`; `reason` is the innermost cause, e.g. `Connection refused`."""

    def __init__(self, api: str, reason: str, connected: bool) -> None:
        super().__init__(f"{api}: {reason}")
        self.api = api
        self.reason = reason
        self.connected = connected  # False: nothing listens there; True: it listened, then did not answer


def bearer(token: str | None) -> dict[str, str]:
    return {"Authorization": f"Bearer {token}"} if token else {}


def reason_of(error: Exception) -> str:
    """The innermost reason of a connection error, e.g. `Connection refused` of `[Errno 111] ...`."""
    text = str(error)
    return text.rsplit("] ", 1)[-1].strip() if text.startswith("[") and "] " in text else text or type(error).__name__


def detail_of(response: httpx.Response) -> str:
    """An error reply's detail in one line: FastAPI's list of validation errors as `field: message`."""
    try:
        detail = response.json().get("detail")
    except (ValueError, AttributeError):
        return response.text
    if isinstance(detail, list):
        return "; ".join(f"{'.'.join(str(p) for p in item.get('loc', ())[1:]) or 'request'}: {item.get('msg', item)}"
                         if isinstance(item, dict) else str(item) for item in detail)
    return str(detail)


class ApiClient:
    """One farm's or fleet's HTTP API (`serve --http`, `--workers N --http`, `fleet-api`), blocking:
    `request` returns the reply's JSON or raises ApiError (an error status) or Unreachable."""

    def __init__(self, api: str, token: str | None = None, timeout: float = 10.0) -> None:
        self.api = api.rstrip("/")
        # certificates are loaded (a fifth of a second) only for an https API: the client asks
        # nothing of any other address (paths only, no redirects followed)
        self.http = httpx.Client(base_url=self.api, headers=bearer(token), timeout=timeout,
                                 verify=self.api.startswith("https:"))

    def request(self, method: str, path: str, **options: Any) -> Any:
        try:
            response = self.http.request(method, path, **options)
        except httpx.ConnectError as error:
            raise Unreachable(self.api, reason_of(error), connected=False) from error
        except httpx.HTTPError as error:
            raise Unreachable(self.api, reason_of(error), connected=True) from error
        if response.status_code >= 400:
            raise ApiError(method, path, response.status_code, detail_of(response))
        return response.json()

    @contextlib.contextmanager
    def events(self, params: Iterable[tuple[str, str]] | dict[str, Any] = (),
               read_timeout: float | None = None) -> Iterator[Iterator[ServerSentEvent]]:
        """GET /events (filtered by `params`: device, kind, exclude_kind) as its events, one
        ServerSentEvent each (`.event`: "message" or "lost", `.json()`), until the farm ends it or
        nothing comes for `read_timeout` seconds (None: wait for ever). Subscribed once open."""
        try:
            with connect_sse(self.http, "GET", "/events", params=params,
                             timeout=httpx.Timeout(self.http.timeout.connect, read=read_timeout)) as source:
                if source.response.status_code >= 400:
                    source.response.read()
                    raise ApiError("GET", "/events", source.response.status_code, detail_of(source.response))
                yield source.iter_sse()
        except httpx.ConnectError as error:
            raise Unreachable(self.api, reason_of(error), connected=False) from error
        except httpx.HTTPError as error:
            raise Unreachable(self.api, reason_of(error), connected=True) from error

    def close(self) -> None:
        self.http.close()

    def __enter__(self) -> ApiClient:
        return self

    def __exit__(self, *_: object) -> None:
        self.close()


def encode_event(event: ServerSentEvent) -> bytes:
    """One event in the stream's own format: `event:` unless a message, one `data:` per line."""
    lines = [] if event.event == "message" else [f"event: {event.event}"]
    lines += [f"id: {event.id}"] if event.id else []
    lines += [f"retry: {event.retry}"] if event.retry is not None else []
    lines += [f"data: {line}" for line in event.data.split("\n")]
    return ("\n".join(lines) + "\n\n").encode()


async def merge_events(streams: list[httpx.Response], greeting: str = "enip-farm fleet event stream",
                       keepalive_s: float = KEEPALIVE_S) -> AsyncIterator[bytes]:
    """Server-sent events of several open streams as one stream, event by event, in the order they
    arrive; a comment every `keepalive_s` of silence; it ends when every stream has ended, and closes them."""
    import asyncio  # here: the CLI's blocking calls do without it (bench/cli_startup.py)

    merged: asyncio.Queue[ServerSentEvent | None] = asyncio.Queue()

    async def pump(stream: httpx.Response) -> None:
        try:
            async for event in EventSource(stream).aiter_sse():
                await merged.put(event)
        except httpx.HTTPError:
            pass  # that source went away: the others go on
        finally:
            await merged.put(None)

    tasks = [asyncio.ensure_future(pump(stream)) for stream in streams]
    try:
        yield f": {greeting}\n\n".encode()
        running = len(tasks)
        while running:
            try:
                item = await asyncio.wait_for(merged.get(), keepalive_s)
            except asyncio.TimeoutError:
                yield b": keep-alive\n\n"
                continue
            if item is None:
                running -= 1
            else:
                yield encode_event(item)
    finally:
        for task in tasks:
            task.cancel()
        for stream in streams:
            await stream.aclose()

