"""`enip-farm serve` once its options are read: one farm in this process until Ctrl-C or SIGTERM,
or `--workers N` processes (workers.py); the banner either way. Imported when `serve` runs."""

from __future__ import annotations

import asyncio
import signal
import sys
from pathlib import Path

import click

from enip_farm.cli.cell import load_cell, make_farm, select
from enip_farm.cli.options import DEFAULT_API
from enip_farm.config import FarmConfig
from enip_farm.farm.console import Console, configure_logging
from enip_farm.farm.farm import BindError, Farm, freeze_heap, new_event_loop, until_stopped_or_failed
from enip_farm.farm.table import device_rows, device_table
from enip_farm.protocol.encapsulation import ENIP_PORT
from enip_farm.words import plural


def banner(devices: int, source: str, http_url: str | None, workers: int = 1) -> list[str]:
    """What `serve` says once every device listens: the configuration it loaded, where the HTTP API
    and the dashboard are (or how to get them)."""
    served = f" in {workers} workers" if workers > 1 else ""
    lines = [f"{plural(devices, 'device')} listening on TCP and UDP {ENIP_PORT}{served}, from {source}. "
             "Ctrl-C to stop."]
    if http_url:
        every = "both" if workers == 2 else f"all {workers}"
        lines += [f"HTTP API on {http_url}" + (f" (the devices of {every} workers)" if workers > 1 else ""),
                  f"dashboard on {http_url}/ and API docs on {http_url}/docs; `enip-farm io` and `enip-farm fault` "
                  "use this API" + ("" if http_url == DEFAULT_API else f" with --api {http_url}")]
    else:
        lines.append("no HTTP API: `enip-farm io`, `enip-farm fault` and the dashboard need one (serve --http 8044)")
    return lines


def source_of(config: FarmConfig, config_path: Path | None) -> str:
    return f"{config.source} (the default cell)" if config_path is None else config.source


def run(config_path: Path | None, log_level: str, quiet: bool, address: tuple[str, int] | None, token: str | None,
        workers: int, shard_spec: str | None, record: Path | None, heartbeat: Path | None,
        state: Path | None) -> None:
    """Serve the cell (or its slice) until a signal; exit 1 if the farm failed or could not bind."""
    configure_logging(log_level, quiet)
    config = select(load_cell(config_path, build=bool(shard_spec) or workers > 1), shard_spec)
    if workers > 1:
        if record or state:
            raise click.UsageError("--record and --state write one file: use them with --workers 1")
        from enip_farm.fleet.workers import serve_workers

        source = source_of(config, config_path)
        sys.exit(serve_workers(config, workers, address, token, log_level, quiet, heartbeat,
                               lambda url: banner(len(config.devices), source, url, workers)))
    farm = make_farm(config, http=address, token=token, record=record, heartbeat=heartbeat, state=state)
    loop = new_event_loop()
    asyncio.set_event_loop(loop)
    try:
        loop.run_until_complete(_serve(farm, config_path))
    except BindError as error:
        click.echo(str(error), err=True)
        sys.exit(1)
    finally:
        loop.close()
    if farm.failure is not None:
        sys.exit(1)


async def _serve(farm: Farm, config_path: Path | None) -> None:
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    await farm.start()
    console = Console(farm.devices.values(), also_flush=[farm.tcp_limits.log] if farm.tcp_limits else [])
    console.start(loop)
    freeze_heap()
    try:
        click.echo(device_table(device_rows(farm.devices.values())))
        for line in banner(len(farm.devices), source_of(farm.config, config_path),
                           farm.http.url if farm.http is not None else None):
            click.echo(line, err=True)
        click.echo(f"cyclic I/O budget: {farm.budget.describe()}", err=True)
        await until_stopped_or_failed(stop, farm)
    finally:
        console.close()
        await farm.stop()
