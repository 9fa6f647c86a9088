"""Splitting a cell across processes and hosts: `serve --workers N` and `--shard I/N`.

Devices joined by wires or rules stay in one slice (they are applied in one process); otherwise
slices are balanced by device count, in configuration order.
"""

from __future__ import annotations

from enip_farm.config import FarmConfig


def _groups(config: FarmConfig) -> list[list[str]]:
    """Devices in connected groups (by wires and rules), in configuration order."""
    parent = {device.name: device.name for device in config.devices}

    def find(name: str) -> str:
        while parent[name] != name:
            parent[name] = parent[parent[name]]
            name = parent[name]
        return name

    links = [(w.source, w.target) for w in config.wires] + [(r.when, r.set) for r in config.rules]
    for a, b in links:
        parent[find(a.rpartition(".")[0])] = find(b.rpartition(".")[0])
    groups: dict[str, list[str]] = {}
    for device in config.devices:
        groups.setdefault(find(device.name), []).append(device.name)
    return list(groups.values())


def split(config: FarmConfig, count: int) -> list[FarmConfig]:
    """`count` configurations that together serve every device of `config` once."""
    if count < 1:
        raise ValueError("a cell splits into at least one slice")
    slices: list[list[str]] = [[] for _ in range(count)]
    for group in _groups(config):  # each group goes to the slice with the fewest devices so far
        min(slices, key=len).extend(group)
    parts = []
    for names in slices:
        members = set(names)
        parts.append(FarmConfig.model_validate({
            "devices": [d for d in config.devices if d.name in members],
            "discovery": config.discovery,
            "wires": [w for w in config.wires if w.source.rpartition(".")[0] in members],
            "rules": [r for r in config.rules if r.when.rpartition(".")[0] in members],
        }) if names else None)
    return [p for p in parts if p is not None]


def shard(config: FarmConfig, spec: str) -> FarmConfig:
    """The slice `I/N` (1-based) of a cell, for N farm instances started from one config."""
    index_text, _, count_text = spec.partition("/")
    if not (index_text.isdigit() and count_text.isdigit()) or not 1 <= int(index_text) <= int(count_text):
        raise ValueError(f"--shard {spec!r}: expected I/N with 1 <= I <= N")
    parts = split(config, int(count_text))
    index = int(index_text) - 1
    if index >= len(parts):
        raise ValueError(f"--shard {spec}: the cell has fewer device groups than shards")
    return parts[index]
