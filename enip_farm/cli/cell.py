"""A cell for a command: loaded, checked, sliced, made a Farm; a problem is one line and exit 2.
Imported by the commands when they run (it brings pydantic, the catalogue and the farm)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import click

from enip_farm.config import ConfigError, FarmConfig, default_config_path, load_config
from enip_farm.eds.reader import eds_catalogue
from enip_farm.farm.cell import check_cell
from enip_farm.farm.farm import Farm
from enip_farm.fleet.slices import shard


def load_cell(path: Path | None, build: bool = True) -> FarmConfig:
    """The configuration, checked in one pass with building its devices (farm/cell.py: models,
    add-ons, profile files, signals, wiring) unless the caller builds a Farm of it at once
    (`build=False`, then see `make_farm`)."""
    catalogue = eds_catalogue()
    path = path or default_config_path()
    try:
        if build:
            return check_cell(path, catalogue)[0]
        return load_config(path, known=(catalogue.bases(), catalogue.addons()))
    except ConfigError as error:
        click.echo(str(error), err=True)
        sys.exit(2)


def make_farm(config: FarmConfig, **options: Any) -> Farm:
    try:
        return Farm(config, **options)
    except ConfigError as error:
        click.echo(str(error), err=True)
        sys.exit(2)


def select(config: FarmConfig, shard_spec: str | None) -> FarmConfig:
    """Slice I/N of the cell (--shard), or all of it."""
    if not shard_spec:
        return config
    try:
        return shard(config, shard_spec)
    except ValueError as error:
        raise click.BadParameter(str(error), param_hint="--shard") from None
