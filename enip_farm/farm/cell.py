"""A cell configuration file checked in one pass: every problem at once, each at its line, in the
file's order. The entries and keys (config.py, pydantic) with the catalogue's model and add-on
names, then what only building the devices tells (device/build.py: profile files, signals,
wiring) of every device whose entry is right: a problem elsewhere (a top-level key, a group, a
wire) is told with them, and a wire or a rule to a device with a problem waits for it. A YAML error
is told alone: nothing else of the file can be read. `enip_farm.load_config`, `Farm(path)` and the
command line load a file this way."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import yaml

from enip_farm.config import ConfigError, FarmConfig, parse_config
from enip_farm.config import load_config as read_config
from enip_farm.config_errors import locate, place
from enip_farm.device.build import build_profiles
from enip_farm.device.catalogue import Catalogue
from enip_farm.device.profile import DeviceProfile
from enip_farm.eds.reader import eds_catalogue

_ENTRIES = ("devices", "groups", "wires", "rules")


def load_config(path: str | Path, catalogue: Catalogue | None = None) -> FarmConfig:
    """The configuration of a file, checked in one pass with building its devices from `catalogue`
    (default: the shipped one, reading EDS files named as a model); ConfigError telling every problem."""
    return check_cell(path, eds_catalogue(catalogue))[0]


def check_cell(path: str | Path, catalogue: Catalogue) -> tuple[FarmConfig, list[DeviceProfile]]:
    """The configuration of a file and its devices' profiles, or a ConfigError telling every problem."""
    path = Path(path)
    known = (catalogue.bases(), catalogue.addons())
    try:
        config = read_config(path, known)
    except ConfigError as error:
        raise ConfigError(_and_what_building_tells(str(error), path, catalogue, known)) from None
    try:
        return config, build_profiles(config, catalogue)
    except ConfigError as error:  # what only building tells (profile files, signals, wiring): at its line
        text = path.read_text()
        raise ConfigError(locate(str(error), config.source, text, yaml.safe_load(text))) from None


def _and_what_building_tells(told: str, path: Path, catalogue: Catalogue, known: tuple[list[str], list[str]]) -> str:
    """`told` (the entries' and keys' problems) and what building the devices of the right entries
    tells, without the keys and entries that have problems; `told` alone where the file is no
    YAML, or what is left has problems of its own (told once these are fixed)."""
    try:
        text = path.read_text()
        data = yaml.safe_load(text)
    except (OSError, yaml.YAMLError):
        return told
    if not isinstance(data, dict) or not isinstance(data.get("devices"), list):
        return told
    source = str(path)
    bad: dict[str, set[int]] = {key: set() for key in _ENTRIES}
    partial: dict[str, Any] = dict(data)
    for line in told.splitlines():
        where = place(re.sub(rf"^{re.escape(source)}(?::\d+)?: ", "", line), data)
        if where is None:
            return told
        if where[0] in bad and len(where) > 1 and isinstance(where[1], int):
            bad[str(where[0])].add(where[1])
        else:
            partial.pop(str(where[0]), None)  # a top-level key: its default
    names = [re.escape(str(e.get("name"))).replace(re.escape("{n}"), r"\d+") for i, e in enumerate(data["devices"])
             if i in bad["devices"] and isinstance(e, dict)]
    waits = re.compile(rf"(?:{'|'.join(names)})\.") if names else None
    kept = [i for i in range(len(data["devices"])) if i not in bad["devices"]]
    for key in _ENTRIES:
        if isinstance(partial.get(key), list):
            partial[key] = [item for i, item in enumerate(partial[key]) if i not in bad[key]]
    for key, ends in (("wires", ("from", "to")), ("rules", ("when", "set"))):
        if isinstance(partial.get(key), list) and waits is not None:
            partial[key] = [item for item in partial[key] if not isinstance(item, dict)
                            or not any(waits.match(str(item.get(end))) for end in ends)]
    try:
        config = parse_config(partial, source, path.parent, known=known)
    except ConfigError:
        return told
    for device in config.devices:
        device._entry = kept[device.entry]  # messages name the file's entries
    try:
        build_profiles(config, catalogue)
    except ConfigError as error:
        lines = told.splitlines() + locate(str(error), source, text, data).splitlines()
        return "\n".join(sorted(dict.fromkeys(lines), key=lambda line: _line_number(line, source)))
    return told


def _line_number(line: str, source: str) -> int:
    number = line.removeprefix(f"{source}:").split(":", 1)[0]
    return int(number) if number.isdigit() else 0
