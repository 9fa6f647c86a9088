"""Options several commands share, and the words they print (light: click and the standard library)."""

from __future__ import annotations

from pathlib import Path

import click

#: Where the CLI's client commands look for the farm's HTTP API (serve --http 8044).
DEFAULT_API = "http://127.0.0.1:8044"

api_option = click.option("--api", envvar="ENIP_FARM_API", default=DEFAULT_API, show_default=True,
                          help="the farm's HTTP API (or ENIP_FARM_API)")
token_option = click.option("--token", envvar="ENIP_FARM_TOKEN", default=None,
                            help="bearer token (or ENIP_FARM_TOKEN)")
config_option = click.option("--config", "config_path", type=click.Path(path_type=Path), default=None,
                             help="cell configuration (YAML); default: the shipped default cell")
shard_option = click.option("--shard", "shard_spec", envvar="ENIP_FARM_SHARD", default=None, metavar="I/N",
                            help="only slice I of N (or ENIP_FARM_SHARD)")


def table(rows: list[list[str]], headers: list[str]) -> str:
    widths = [max(len(str(row[i])) for row in [headers, *rows]) for i in range(len(headers))]
    lines = ["  ".join(str(cell).ljust(width) for cell, width in zip(row, widths, strict=True)).rstrip()
             for row in [headers, *rows]]
    return "\n".join(lines)


def http_address(text: str | None) -> tuple[str, int] | None:
    """--http [HOST:]PORT: (host, port), localhost when no host is given; a port out of 0..65535 or
    text that is no port is refused (click's usage error, exit 2)."""
    if not text:
        return None
    host, _, port = text.rpartition(":")
    host = host.removeprefix("[").removesuffix("]")
    if not port.isdigit():
        raise click.BadParameter(f"{text!r}: expected [HOST:]PORT, e.g. 8044 or 127.0.0.1:8044", param_hint="--http")
    if not 0 <= int(port) <= 65535:
        raise click.BadParameter(f"{text!r}: the port {int(port)} is out of range (0..65535; 0 picks a free one)",
                                 param_hint="--http")
    return host or "127.0.0.1", int(port)
