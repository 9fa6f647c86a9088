"""A cell for a command: loaded, checked, sliced, made a Farm; a problem is one line and exit 2.
Imported by the commands when they run (it brings pydantic, the catalogue and the farm)."""

from __future__ import annotations

import re
import sys
from pathlib import Path
from typing import Any

import click
import yaml

from enip_farm.config import ConfigError, FarmConfig, default_config_path, load_config, parse_config
from enip_farm.config_errors import locate
from enip_farm.device.build import build_profiles
from enip_farm.device.catalogue import Catalogue
from enip_farm.eds.reader import eds_catalogue
from enip_farm.farm.farm import Farm
from enip_farm.fleet.slices import shard


def load_cell(path: Path | None, build: bool = True) -> FarmConfig:
    """The configuration, checked by building its devices (models, add-ons, profile files, wiring)
    unless the caller builds a Farm of it at once (`build=False`, then see `make_farm`)."""
    catalogue = eds_catalogue()
    try:
        try:
            config = load_config(path or default_config_path(), known=(catalogue.bases(), catalogue.addons()))
        except ConfigError as error:
            raise ConfigError(_and_what_building_tells(str(error), path, catalogue) if path and build
                              else str(error)) from None
        if build:
            try:
                build_profiles(config, catalogue)
            except ConfigError as error:  # what only building tells (profile files, signals, wiring): at its line
                text = Path(config.source).read_text()
                raise ConfigError(locate(str(error), config.source, text, yaml.safe_load(text))) from None
    except ConfigError as error:
        click.echo(str(error), err=True)
        sys.exit(2)
    return config


_ENTRY = re.compile(r"\(devices\[(\d+)\]\)|: devices\[(\d+)\]")


def _and_what_building_tells(told: str, path: Path, catalogue: Catalogue) -> str:
    """The problems of the devices' entries (`told`), and what building the other devices tells
    (profile files, signals, wiring), in the file's order: every problem in one pass. Wires and
    rules to a device with a problem wait for it; a problem outside the devices' entries (a YAML
    error, a top-level key) is told alone."""
    matches = [_ENTRY.search(line) for line in told.splitlines()]
    if not all(matches):
        return told
    text = path.read_text()
    data = yaml.safe_load(text)  # it was read: `told` names its entries
    if not isinstance(data, dict) or not isinstance(data.get("devices"), list):
        return told
    bad = {int(m[1] or m[2]) for m in matches if m}
    kept = [i for i in range(len(data["devices"])) if i not in bad]
    names = [re.escape(str(e.get("name"))).replace(re.escape("{n}"), r"\d+") for i, e in enumerate(data["devices"])
             if i in bad and isinstance(e, dict)]
    waits = re.compile(rf"(?:{'|'.join(names)})\.") if names else None
    partial = {**data, "devices": [data["devices"][i] for i in kept]}
    for key, ends in (("wires", ("from", "to")), ("rules", ("when", "set"))):
        if isinstance(data.get(key), list) and waits is not None:
            partial[key] = [item for item in data[key] if not isinstance(item, dict)
                            or not any(waits.match(str(item.get(end))) for end in ends)]
    try:
        config = parse_config(partial, str(path), path.parent)
    except ConfigError:
        return told  # no device left to build, or what is left has problems of its own: told when these are fixed
    for device in config.devices:
        device._entry = kept[device.entry]  # messages name the file's entries
    try:
        build_profiles(config, catalogue)
    except ConfigError as error:
        lines = told.splitlines() + locate(str(error), str(path), text, data).splitlines()
        return "\n".join(sorted(dict.fromkeys(lines), key=lambda line: _line_number(line, str(path))))
    return told


def _line_number(line: str, source: str) -> int:
    number = line.removeprefix(f"{source}:").split(":", 1)[0]
    return int(number) if number.isdigit() else 0


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
