"""`enip-farm serve --workers N`: N processes, each serving a slice of the cell (fleet.split).

The parent starts the workers (spawn), waits until every one listens (or one fails, which stops
them all), prints the devices once, forwards SIGINT/SIGTERM and exits 0 when all have stopped.
With --http [HOST:]PORT the parent serves one HTTP API for the whole fleet there: each worker
serves its slice's API on a port of 127.0.0.1 it picks (with the same token), and the parent
routes a request for a device to the worker that serves it; GET /devices, /events and /metrics
merge every worker's answer. The token is checked by the parent (with the farm API's Host and
body-size guard) and again by the workers (fleet/api.py, over the routes of fleet/router.py).
"""

from __future__ import annotations

import asyncio
import contextlib
import multiprocessing
import queue
import signal
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import click

from enip_farm.config import FarmConfig, parse_config
from enip_farm.control.guard import needs_token
from enip_farm.farm.console import Console, configure_logging
from enip_farm.farm.farm import BindError, Farm, freeze_heap, new_event_loop, until_stopped_or_failed
from enip_farm.farm.table import Row, device_rows, device_table
from enip_farm.fleet.api import START_TIMEOUT, create_worker_router, router_port, serving_router
from enip_farm.fleet.slices import split


def _worker(index: int, config_data: dict[str, Any], http: bool, token: str | None,
            reports: multiprocessing.Queue, log_level: str = "info", quiet: bool = False,
            heartbeat: str | None = None) -> None:
    configure_logging(log_level, quiet)
    farm = Farm(parse_config(config_data, f"worker {index}"), http=("127.0.0.1", 0) if http else None, token=token,
                heartbeat=f"{heartbeat}.{index}" if heartbeat else None)
    loop = new_event_loop()
    asyncio.set_event_loop(loop)

    async def run() -> None:
        stop = asyncio.Event()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)
        try:
            await farm.start()
        except BindError as error:
            reports.put((index, "error", str(error)))
            return
        console = Console(farm.devices.values(), also_flush=[farm.tcp_limits.log] if farm.tcp_limits else [])
        console.start(loop)
        freeze_heap()
        reports.put((index, "ready", (device_rows(farm.devices.values()),
                                      farm.http.port if farm.http is not None else 0, farm.budget.describe())))
        try:
            await until_stopped_or_failed(stop, farm)
        finally:
            console.close()
            await farm.stop()

    try:
        loop.run_until_complete(run())
    finally:
        loop.close()
    if farm.failure is not None:
        sys.exit(1)  # the parent sees a worker end and stops the others (exit 1)


def serve_workers(config: FarmConfig, count: int, http: tuple[str, int] | None, token: str | None,
                  log_level: str = "info", quiet: bool = False, heartbeat: str | Path | None = None,
                  banner: Callable[[str | None], list[str]] = lambda url: []) -> int:
    """Run the workers (and the fleet's HTTP API if `http`) until a signal; the exit status for the CLI.
    `banner(url)`: what to say once all listen, given the fleet API's URL (None without one)."""
    if http and needs_token(http[0]) and not token:
        click.echo(f"the HTTP API on {http[0]} needs a token (--token or ENIP_FARM_TOKEN); "
                   "only loopback (localhost, 127.x.y.z, ::1) is served without one", err=True)
        return 2
    parts = split(config, count)
    context = multiprocessing.get_context("spawn")
    reports: multiprocessing.Queue = context.Queue()
    processes = []
    for index, part in enumerate(parts):
        process = context.Process(target=_worker, name=f"enip-farm-worker-{index}", daemon=False,
                                  args=(index, part.model_dump(mode="json", by_alias=True), http is not None,
                                        token, reports, log_level, quiet,
                                        str(heartbeat) if heartbeat else None))
        process.start()
        processes.append(process)

    stopping = False

    def stop(*_: object) -> None:
        nonlocal stopping
        stopping = True

    previous = {sig: signal.signal(sig, stop) for sig in (signal.SIGINT, signal.SIGTERM)}
    status = 0
    try:
        tables: dict[int, list[Row]] = {}
        ports: dict[int, int] = {}
        budgets: dict[int, str] = {}
        while len(tables) < len(processes) and not stopping:
            try:
                index, kind, payload = reports.get(timeout=START_TIMEOUT)
            except queue.Empty:
                click.echo("workers did not start in time", err=True)
                status = 1
                break
            if kind == "error":
                click.echo(f"worker {index}: {payload}", err=True)
                status = 1
                break
            tables[index], ports[index], budgets[index] = payload
        if status == 0 and not stopping:
            apis = [f"http://127.0.0.1:{ports[i]}" for i in range(len(processes))]
            with contextlib.ExitStack() as stack:
                router = None
                if http:
                    try:
                        router = stack.enter_context(serving_router(create_worker_router(config, parts, apis, token),
                                                                 *http, token))
                    except OSError as error:
                        click.echo(error.strerror or str(error), err=True)
                        status = 1
                if status == 0:
                    url = f"http://{http[0]}:{router_port(router)}" if http and router is not None else None
                    rows = {row[0]: row for part in tables.values() for row in part}
                    status = _run(processes, [rows[device.name] for device in config.devices], banner(url),
                                  lambda: stopping, budgets)
    finally:
        status = _stop(processes, previous, status)
    return status


def _run(processes: list, rows: list[Row], banner: list[str], stopping: Callable[[], bool],
         budgets: dict[int, str]) -> int:
    """Every worker listens: print the table (in the configuration's order) and the banner, wait
    for a signal or a worker's end."""
    click.echo(device_table(rows))
    for line in banner:
        click.echo(line, err=True)
    for index in sorted(budgets):
        click.echo(f"worker {index} cyclic I/O budget: {budgets[index]}", err=True)
    while not stopping() and all(p.is_alive() for p in processes):
        for process in processes:
            process.join(0.2)
    if not stopping():
        click.echo("a worker stopped unexpectedly; stopping the others", err=True)
        return 1
    return 0


def _stop(processes: list, previous: dict, status: int) -> int:
    """Stop every worker still running (SIGTERM, then SIGKILL after 30 s); restore the signals."""
    for process in processes:
        if process.is_alive():
            process.terminate()  # SIGTERM: the worker stops its farm cleanly
    for process in processes:
        process.join(30)
        if process.is_alive():
            process.kill()
            status = 1
    for sig, handler in previous.items():
        signal.signal(sig, handler)
    return status


if __name__ == "__main__":  # pragma: no cover
    sys.exit("run through `enip-farm serve --workers N`")
