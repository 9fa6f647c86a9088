"""`enip-farm serve --workers N`: N processes, each serving a slice of the cell (fleet.split).

The parent starts the workers (spawn), waits until every one listens (or one fails, which stops
them all), prints the devices once, forwards SIGINT/SIGTERM and exits 0 when all have stopped.
With --http PORT, worker i serves its slice's HTTP API on PORT + i.
"""

from __future__ import annotations

import asyncio
import multiprocessing
import queue
import signal
import sys
from typing import Any

import click

from enip_farm.config import FarmConfig, parse_config
from enip_farm.farm import BindError, Farm, freeze_heap, new_event_loop
from enip_farm.fleet import split
from enip_farm.table import TABLE_HEADER, device_table

_START_TIMEOUT = 120.0


def _worker(index: int, config_data: dict[str, Any], http: tuple[str, int] | None, token: str | None,
            reports: multiprocessing.Queue) -> None:
    farm = Farm(parse_config(config_data, f"worker {index}"), http=http, token=token)
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
        freeze_heap()
        reports.put((index, "ready", device_table(farm.devices.values(), header=False)))
        try:
            await stop.wait()
        finally:
            await farm.stop()

    try:
        loop.run_until_complete(run())
    finally:
        loop.close()


def serve_workers(config: FarmConfig, count: int, http: tuple[str, int] | None, token: str | None) -> int:
    """Run the workers until a signal; the exit status for the CLI."""
    parts = split(config, count)
    context = multiprocessing.get_context("spawn")
    reports: multiprocessing.Queue = context.Queue()
    processes = []
    for index, part in enumerate(parts):
        address = (http[0], http[1] + index) if http else None
        process = context.Process(target=_worker, name=f"enip-farm-worker-{index}", daemon=False,
                                  args=(index, part.model_dump(mode="json", by_alias=True), address, token, reports))
        process.start()
        processes.append(process)

    stopping = False

    def stop(*_: object) -> None:
        nonlocal stopping
        stopping = True

    previous = {sig: signal.signal(sig, stop) for sig in (signal.SIGINT, signal.SIGTERM)}
    status = 0
    try:
        tables: dict[int, str] = {}
        while len(tables) < len(processes) and not stopping:
            try:
                index, kind, text = reports.get(timeout=_START_TIMEOUT)
            except queue.Empty:
                click.echo("workers did not start in time", err=True)
                status = 1
                break
            if kind == "error":
                click.echo(f"worker {index}: {text}", err=True)
                status = 1
                break
            tables[index] = text
        if status == 0 and not stopping:
            click.echo("\n".join([TABLE_HEADER, *(tables[i] for i in sorted(tables))]))
            click.echo(f"{len(config.devices)} devices in {len(processes)} workers. Ctrl-C to stop.", err=True)
            if http:
                for index in range(len(processes)):
                    click.echo(f"worker {index}: HTTP API on http://{http[0]}:{http[1] + index}", err=True)
            while not stopping and all(p.is_alive() for p in processes):
                for process in processes:
                    process.join(0.2)
            if not stopping:
                click.echo("a worker stopped unexpectedly; stopping the others", err=True)
                status = 1
    finally:
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
