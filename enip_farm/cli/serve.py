"""`enip-farm serve`: its options; the serving is running.py's, imported when the command runs."""

from __future__ import annotations

from pathlib import Path

import click

from enip_farm.cli.options import http_address


@click.command()
@click.option("--config", "config_path", type=click.Path(path_type=Path), default=None,
              help="cell configuration (YAML); default: the shipped default cell")
@click.option("--log-level", default="info", show_default=True,
              type=click.Choice(["debug", "info", "warning", "error"]),
              help="info: one line per connection, session, Forward Open/Close, timeout, fault and refusal; "
                   "debug: also every request and I/O change")
@click.option("-q", "--quiet", is_flag=True, help="only warnings and errors (timeouts, refusals, faults)")
@click.option("--http", "http", default=None, metavar="[HOST:]PORT",
              help="serve the HTTP API and dashboard (localhost unless a host is given; an address that is not "
                   "loopback needs --token)")
@click.option("--token", envvar="ENIP_FARM_TOKEN", default=None, help="bearer token for the HTTP API")
@click.option("--workers", type=click.IntRange(1, 256), default=1, show_default=True,
              help="processes, each serving a slice of the devices (worker i's HTTP API on PORT + i)")
@click.option("--shard", "shard_spec", envvar="ENIP_FARM_SHARD", default=None, metavar="I/N",
              help="serve only slice I of N (N farms started from one config, e.g. one per host; "
                   "or ENIP_FARM_SHARD)")
@click.option("--record", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="write every TCP and UDP exchange to this pcap file")
@click.option("--heartbeat", envvar="ENIP_FARM_HEARTBEAT", type=click.Path(dir_okay=False, path_type=Path),
              default=None, help="set this file's time every second while cyclic I/O runs (worker i: FILE.i); "
                                 "docker/healthcheck.sh reads it (or ENIP_FARM_HEARTBEAT)")
@click.option("--state", "state", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="keep the devices' non-volatile state (a safety target's TUNID, configuration, owner) in this "
                   "JSON file across restarts: read at start, written at stop")
def serve(config_path: Path | None, log_level: str, quiet: bool, http: str | None, token: str | None, workers: int,
          shard_spec: str | None, record: Path | None, heartbeat: Path | None, state: Path | None) -> None:
    """Serve every device of a cell until Ctrl-C or SIGTERM, logging what happens to them."""
    address = http_address(http)
    from enip_farm.cli.running import run

    run(config_path, log_level, quiet, address, token, workers, shard_spec, record, heartbeat, state)


COMMANDS = (serve,)
