"""One HTTP API for a fleet of workers (`serve --workers N --http`): fleet/router.py's routes over
the workers' own APIs, on ports of 127.0.0.1 known when they start; and the serving of a fleet's
router (this one, or the shards' of fleet/shard_api.py) from a thread, behind the farm API's own
Guard (Host, token, body size)."""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Iterator

import uvicorn
from starlette.applications import Starlette

from enip_farm.config import FarmConfig
from enip_farm.control.guard import Guard
from enip_farm.control.http import bind_problem, listening_socket
from enip_farm.fleet.router import Finder, create_router, static_endpoints

START_TIMEOUT = 120.0


def create_worker_router(config: FarmConfig, slices: list[FarmConfig], apis: list[str], token: str | None) -> Starlette:
    """The fleet's HTTP API: `apis[i]` is the base URL of the worker serving `slices[i]`; a worker
    that does not answer is down (`"worker_up": false`, 503 for its devices), the others served."""
    return create_router(config, slices, Finder("worker", static_endpoints(apis)), token)


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
