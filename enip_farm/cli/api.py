"""The client commands' calls to a running farm's HTTP API (enip_farm/control/client.py), with
the CLI's answer to each problem: one line on stderr and exit 1. Imported when such a command runs."""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any, NoReturn
from urllib.parse import urlsplit

import click

from enip_farm.control.client import ApiClient, ApiError, ServerSentEvent, Unreachable


def _unreachable(api: str, error: Unreachable) -> NoReturn:
    if error.connected:
        click.echo(f"the farm's HTTP API at {api} did not answer: {error.reason}", err=True)
    else:
        port = urlsplit(api).port or 8044
        click.echo(f"cannot reach the farm's HTTP API at {api} ({error.reason}): is the farm running with its "
                   f"HTTP API? Start it with `enip-farm serve --http {port}`, or give the API's address with --api "
                   "(or ENIP_FARM_API).", err=True)
    sys.exit(1)


def call(api: str, token: str | None, method: str, path: str, refused: Callable[[ApiError], None] | None = None,
         **options: Any) -> Any:
    """The JSON of the API's answer; an error answer (after `refused(error)`, which may say it in
    its own words and exit) or none: its line on stderr, exit 1."""
    try:
        with ApiClient(api, token) as client:
            return client.request(method, path, **options)
    except ApiError as error:
        if refused is not None:
            refused(error)
        click.echo(str(error), err=True)
        sys.exit(1)
    except Unreachable as error:
        _unreachable(api, error)


@contextmanager
def events(api: str, token: str | None, params: dict[str, str]) -> Iterator[Iterator[ServerSentEvent]]:
    """The API's event stream (GET /events with `params`) until the farm ends it; a problem: its
    line on stderr, exit 1."""
    try:
        with ApiClient(api, token) as client, client.events(params) as stream:
            yield stream
    except ApiError as error:
        click.echo(str(error), err=True)
        sys.exit(1)
    except Unreachable as error:
        if error.connected:  # it answered, then stopped: the stream ended with the farm
            click.echo("the farm ended the event stream", err=True)
            sys.exit(1)
        _unreachable(api, error)
