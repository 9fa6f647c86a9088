"""How a cell configuration's problems are told: one line each, `cell.yaml:12: device 'io1'
(devices[0]), model: ...`, all of them at once.

A YAML file's lines are found only when there is a problem to tell (`line_map`, from PyYAML's
nodes: a key's line for its value, an item's first line), and pydantic's error locations
(`("devices", 0, "identity", "vendor_id")`) are mapped to them; the messages of later checks
(device/build.py: models, add-ons, signals, wiring) name `devices[i]`, a wire or a rule, and
`locate` finds those lines too. A YAML error points at its line and column in the file (PyYAML's
marks); an unknown key gets a "did you mean" (difflib) or the keys allowed there.
"""

from __future__ import annotations

import difflib
import re
import typing
from collections.abc import Iterable
from ipaddress import IPv4Address
from typing import Any

import yaml
from pydantic import BaseModel

#: A value's place in the document, as pydantic gives it: keys and list indices.
Location = tuple[str | int, ...]

_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)  # libyaml's parser where PyYAML has it
_NAMED = re.compile(r"(?:\(|^)(devices|groups|wires|rules)\[(\d+)\]\)?(?:, ([\w.]+):)?")
_WIRE_OR_RULE = re.compile(r"^(wire|rule) (\S+) -> (\S+):")


def device_location(index: int, name: str | None = None) -> str:
    """How messages name a device: by its entry in the configuration's `devices` list."""
    return f"device {name!r} (devices[{index}])" if name else f"devices[{index}]"


def did_you_mean(word: str, choices: Iterable[str]) -> str:
    """` (did you mean X?)` for the closest of `choices`, or nothing."""
    close = difflib.get_close_matches(word, list(choices), n=1, cutoff=0.6)
    return f" (did you mean {close[0]}?)" if close else ""


def yaml_problem(source: str, error: yaml.YAMLError) -> str:
    """A YAML error as one line at the file's line and column (PyYAML names the text it was given,
    `<unicode string>`, not the file)."""
    mark = getattr(error, "problem_mark", None) or getattr(error, "context_mark", None)
    problem = getattr(error, "problem", None) or str(error)
    context = getattr(error, "context", None)
    where = f"{source}:{mark.line + 1}:{mark.column + 1}" if mark is not None else source
    return f"{where}: not valid YAML: " + (f"{context}: {problem}" if context else problem)


def not_a_cell(source: str, data: Any) -> str | None:
    """Why a document is no configuration at all (empty, or not a mapping), or None."""
    shape = "a mapping whose devices: lists the devices (see configs/default-cell.yaml)"
    if data is None:
        return f"{source}: the file is empty: a cell configuration is {shape}"
    if not isinstance(data, dict):
        return f"{source}:1: a cell configuration is {shape}, not a {type(data).__name__}"
    return None


def line_map(text: str) -> dict[Location, int]:
    """The 1-based line of every key's value and every list item of a YAML document."""
    lines: dict[Location, int] = {}
    try:
        root = yaml.compose(text, Loader=_LOADER)
    except yaml.YAMLError:
        return lines
    pending: list[tuple[yaml.Node, Location]] = [(root, ())] if root is not None else []
    seen: set[int] = set()
    while pending:
        node, where = pending.pop()
        if id(node) in seen:  # an alias: its anchor's place is told
            continue
        seen.add(id(node))
        if isinstance(node, yaml.MappingNode):
            for key, value in node.value:
                place = (*where, key.value if isinstance(key, yaml.ScalarNode) else str(key.start_mark.line))
                lines[place] = key.start_mark.line + 1
                pending.append((value, place))
        elif isinstance(node, yaml.SequenceNode):
            for index, item in enumerate(node.value):
                lines[(*where, index)] = item.start_mark.line + 1
                pending.append((item, (*where, index)))
    return lines


def line_of(lines: dict[Location, int], location: Location) -> int | None:
    """The line of a location, or of the nearest place above it that the file has."""
    for end in range(len(location), 0, -1):
        if location[:end] in lines:
            return lines[location[:end]]
    return None


def keys_at(model: type[BaseModel], location: Location) -> list[str]:
    """The keys a configuration takes at `location` (an unknown key's place), walking the models."""
    current: Any = model
    for part in location[:-1]:
        if isinstance(part, int):
            continue
        field = current.model_fields.get(part) or next(
            (f for f in current.model_fields.values() if f.alias == part), None)
        current = _model_in(field.annotation) if field is not None else None
        if current is None:
            return []
    return [f.alias or name for name, f in current.model_fields.items()]


def _model_in(annotation: Any) -> type[BaseModel] | None:
    """The pydantic model an annotation holds: itself, or its list's, dict's or union's."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    for argument in typing.get_args(annotation):
        found = _model_in(argument)
        if found is not None:
            return found
    return None


def describe(error: dict[str, Any], data: Any, model: type[BaseModel]) -> str:
    """One pydantic error in the farm's words: where (the device or group, the field), what."""
    location = list(error["loc"])
    where = ""
    if len(location) >= 2 and location[0] in ("devices", "groups") and isinstance(location[1], int):
        index, part = location[1], location[0]
        name = None
        if isinstance(data, dict) and isinstance(data.get(part), list) and index < len(data[part]):
            entry = data[part][index]
            name = entry.get("name") if isinstance(entry, dict) else None
        where = device_location(index, name) if part == "devices" else (
            f"group {name!r} (groups[{index}])" if name else f"groups[{index}]")
        location = location[2:]
    elif len(location) >= 2 and isinstance(location[1], int):  # wires[1], rules[0]
        where, location = f"{location[0]}[{location[1]}]", location[2:]
    field = ".".join(str(part) for part in location)
    message = error["msg"].removeprefix("Value error, ")
    if error["type"] == "missing":
        message = "missing: the key is required here"
    if error["type"] == "extra_forbidden":
        known = keys_at(model, tuple(error["loc"]))
        hint = did_you_mean(str(error["loc"][-1]), known)
        message = f"unknown key{hint}" + ("" if hint or not known else f"; the keys here: {', '.join(known)}")
    if isinstance(error.get("input"), bool) and error["type"] == "literal_error":  # YAML 1.1 booleans
        words = "on, yes" if error["input"] else "off, no"
        message += f" (YAML reads an unquoted {words} as {str(error['input']).lower()}: quote the value, e.g. \"off\")"
    return ", ".join(part for part in (where, field) if part) + f": {message}" if (where or field) else message


def duplicates(data: Any) -> list[tuple[Location, str]]:
    """Devices of a document with a name or an address taken by an earlier one, as the schema
    says it once every device is valid: for a document with other problems, told with them."""
    entries = data.get("devices") if isinstance(data, dict) else None
    found: list[tuple[Location, str]] = []
    seen: dict[str, dict[Any, tuple[int, str]]] = {"name": {}, "address": {}}
    for index, entry in enumerate(entries if isinstance(entries, list) else ()):
        if not isinstance(entry, dict) or not isinstance(entry.get("name"), str):
            continue
        count = entry.get("count", 1) if isinstance(entry.get("count", 1), int) else 1
        try:
            first: IPv4Address | None = IPv4Address(str(entry.get("address")))
        except ValueError:
            first = None  # told as the entry's own problem
        for n in range(max(1, min(count, 65536))):
            device = entry["name"].replace("{n}", str(n + 1))
            for field, value in (("name", device), ("address", first + n if first is not None else None)):
                earlier = seen[field].setdefault(value, (index, device)) if value is not None else (index, device)
                if earlier != (index, device):
                    message = f"{value} is taken by {device_location(earlier[0], earlier[1])}" + (
                        f" (here by {device!r})" if field == "address" else "")
                    found.append((("devices", index, field), message))
    return found


def locate(message: str, source: str, text: str, data: Any) -> str:
    """A ConfigError's lines (`SOURCE: ...`) with the file's line of what each one names:
    `SOURCE:LINE: ...`; lines that name nothing found in the file stay as they are."""
    lines = line_map(text)
    out = []
    for line in message.splitlines():
        rest = line.removeprefix(f"{source}: ")
        where = place(rest, data) if rest != line else None
        number = line_of(lines, where) if where else None
        out.append(f"{source}:{number}: {rest}" if number is not None else line)
    return "\n".join(out)


def place(message: str, data: Any) -> Location | None:
    """The location a message names: a device's or group's entry and field, a wire, a rule."""
    named = _NAMED.search(message)
    if named:
        return (named[1], int(named[2]), *(named[3].split(".") if named[3] else ()))
    wire_or_rule = _WIRE_OR_RULE.match(message)
    if wire_or_rule and isinstance(data, dict):
        kind, first, second = wire_or_rule.groups()
        key, ends = ("wires", ("from", "to")) if kind == "wire" else ("rules", ("when", "set"))
        for index, entry in enumerate(data.get(key) or ()):
            if isinstance(entry, dict) and (str(entry.get(ends[0])), str(entry.get(ends[1]))) == (first, second):
                return (key, index)
        return (key,)
    top = message.split(":", 1)[0].split(".")[0]
    return (top,) if isinstance(data, dict) and top in data else None
