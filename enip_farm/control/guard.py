"""What every request to the HTTP API passes before FastAPI sees it (a plain ASGI middleware).

- **Host** must name the address the API is bound to, or localhost when it is bound to loopback
  (421 otherwise), so that a web page whose DNS name is rebound to 127.0.0.1 cannot reach a
  token-less API from a browser. Bound to a wildcard address (0.0.0.0, ::) any Host is taken: a
  token is required there, and a rebinding page does not have it.
- **Token**: when one is set, every path needs it (the OpenAPI schema and /docs too), as
  `Authorization: Bearer <token>` with the scheme in any case (RFC 9110 11.1); 401 otherwise.
  Only GET and HEAD of the dashboard's static page and assets (`PUBLIC_PAGE` and what is under
  `PUBLIC_PREFIX`: no farm data in them) and of the health check (`PUBLIC_HEALTH`: whether the farm
  serves, counts only, for orchestrators' probes) pass without it, since a browser cannot send the header
  when it opens a page; the page sends it on every request it makes (control/dashboard.py).
- **Body size**: at most `MAX_BODY` bytes (413, and the connection is closed). A larger
  Content-Length is refused before any of the body is read; a chunked body is read up to the limit
  and refused there, so no request holds more than `MAX_BODY` bytes in memory.
"""

from __future__ import annotations

import hmac
import ipaddress
from typing import Any

from starlette.responses import JSONResponse
from starlette.types import ASGIApp, Message, Receive, Scope, Send

MAX_BODY = 1 << 20  # 1 MiB: an image write is a few hundred bytes
LOCALHOST_NAMES = frozenset({"localhost", "127.0.0.1", "::1"})
WILDCARDS = frozenset({"", "0.0.0.0", "::"})
#: The dashboard's page and its static assets (control/dashboard.py): served without the token.
PUBLIC_PAGE = "/"
PUBLIC_PREFIX = "/dashboard/"
#: Whether the farm serves (control/http.py): served without the token, for health probes.
PUBLIC_HEALTH = "/health"


def public(scope: Scope) -> bool:
    """A request for the dashboard's static page or assets, or the health check: no farm data."""
    path = scope.get("path", "")
    return scope.get("method") in ("GET", "HEAD") and (path in (PUBLIC_PAGE, PUBLIC_HEALTH) or (
        path.startswith(PUBLIC_PREFIX) and ".." not in path))


def _normal(host: str) -> str:
    return host.strip().lower().rstrip(".").removeprefix("[").removesuffix("]")


def host_name(header: str) -> str:
    """The host part of a Host header, lower case, without port, brackets or a trailing dot."""
    text = header.strip().lower()
    if text.startswith("["):
        end = text.find("]")
        return text[1:end] if end > 0 else text
    if text.count(":") == 1:
        text = text.partition(":")[0]
    return text.rstrip(".")


def is_loopback(bound: str) -> bool:
    """Whether an API bound to `bound` is reachable from this host only (localhost, 127.0.0.0/8, ::1)."""
    host = _normal(bound)
    try:
        return host == "localhost" or ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def needs_token(bound: str) -> bool:
    """An API bound anywhere but loopback must be given a token: others on the network reach it."""
    return not is_loopback(bound)


def allowed_hosts(bound: str) -> frozenset[str] | None:
    """The Host names a request may carry for an API bound to `bound`; None: any (a wildcard)."""
    host = _normal(bound)
    if host in WILDCARDS:
        return None
    return frozenset({host, *LOCALHOST_NAMES}) if is_loopback(host) else frozenset({host})


class Guard:
    def __init__(self, app: ASGIApp, bound_host: str, token: str | None, max_body: int = MAX_BODY) -> None:
        self.app = app
        self.hosts = allowed_hosts(bound_host)
        self.token = token.encode() if token else None
        self.max_body = max_body

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            if scope["type"] == "websocket":  # the API has none; refuse before FastAPI sees one
                await send({"type": "websocket.close", "code": 1008})
                return
            await self.app(scope, receive, send)
            return
        headers: list[tuple[bytes, bytes]] = scope["headers"]
        refusal = self._check(headers, public(scope))
        if refusal is not None:
            await refusal(scope, receive, send)
            return
        messages = await self._read_body(receive)
        if messages is None:
            await _answer(413, f"the request body is over {self.max_body} bytes", close=True)(scope, receive, send)
            return

        async def replay() -> Message:
            return messages.pop(0) if messages else await receive()

        await self.app(scope, replay, send)

    def _check(self, headers: list[tuple[bytes, bytes]], public_path: bool = False) -> JSONResponse | None:
        if self.hosts is not None:
            hosts = [value.decode("latin-1") for key, value in headers if key == b"host"]
            if len(hosts) > 1 or (hosts and host_name(hosts[0]) not in self.hosts):
                return _answer(421, f"Host {', '.join(hosts)!r} is not this API's address "
                                    f"({' or '.join(sorted(self.hosts))})")
        if self.token is not None and not public_path:
            given = next((value for key, value in headers if key == b"authorization"), b"")
            scheme, _, credentials = given.strip().partition(b" ")
            if scheme.lower() != b"bearer" or not hmac.compare_digest(credentials.strip(), self.token):
                return _answer(401, "a bearer token is required (Authorization: Bearer <token>)",
                               headers={"WWW-Authenticate": "Bearer"})
        lengths = [value for key, value in headers if key == b"content-length"]
        if lengths:
            try:
                length = int(lengths[0])
            except ValueError:
                return _answer(400, "Content-Length is not a number", close=True)
            if length > self.max_body:
                return _answer(413, f"the request body is over {self.max_body} bytes ({length})", close=True)
        return None

    async def _read_body(self, receive: Receive) -> list[Message] | None:
        """The request's body as one message (or the disconnect), None when it is over the limit."""
        chunks: list[bytes] = []
        size = 0
        while True:
            message = await receive()
            if message["type"] != "http.request":
                return [message]
            chunk = message.get("body", b"")
            size += len(chunk)
            if size > self.max_body:
                return None
            chunks.append(chunk)
            if not message.get("more_body", False):
                return [{"type": "http.request", "body": b"".join(chunks), "more_body": False}]


def _answer(status: int, detail: str, close: bool = False, headers: dict[str, Any] | None = None) -> JSONResponse:
    headers = dict(headers or {})
    if close:
        headers["Connection"] = "close"
    return JSONResponse({"detail": detail}, status_code=status, headers=headers)
