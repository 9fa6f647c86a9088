"""One HTTP API for a cell's shards wherever an engine runs them (`enip-farm fleet-api`): fleet/router.py's
routes over the shards found by DNS, Docker Swarm tasks by `tasks.<service>`, Kubernetes pods by a
headless Service (or over URLs given). Each shard's GET /devices says which slice it serves; a shard
that does not answer is listed as down (its devices with `"shard_up": false`, GET /shards,
`enip_farm_shard_up 0`), never left out."""

from __future__ import annotations

import asyncio
import socket
import time
from collections.abc import Callable

from starlette.applications import Starlette

from enip_farm.config import FarmConfig
from enip_farm.fleet.router import Endpoints, Finder, create_router, static_endpoints
from enip_farm.fleet.slices import split


def dns_discovery(name: str, port: int) -> Endpoints:
    """Every address `name` resolves to (Swarm's `tasks.farm`, a headless Service), as base URLs."""

    async def discover() -> list[str]:
        try:
            infos = await asyncio.get_running_loop().getaddrinfo(name, port, family=socket.AF_INET,
                                                                 type=socket.SOCK_STREAM)
        except socket.gaierror:
            return []
        return sorted({f"http://{info[4][0]}:{port}" for info in infos})

    return discover


def static_discovery(urls: list[str]) -> Endpoints:
    """The shards at these base URLs (`fleet-api --shard-url URL`), each saying which slice it serves."""
    return static_endpoints(urls)


def create_shard_router(config: FarmConfig, shards: int, discover: Endpoints, token: str | None,
                        clock: Callable[[], float] = time.monotonic) -> Starlette:
    """The fleet's HTTP API over the `shards` slices of `config`, served where `discover` finds them.
    `token`: the router's own, for asking the shards what they serve; a client's requests are
    forwarded with the client's Authorization."""
    return create_router(config, split(config, shards), Finder("shard", discover), token, clock)
