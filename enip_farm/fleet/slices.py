"""Splitting a cell across processes and hosts: `serve --workers N` and `--shard I/N`; and
FleetClient, the device handle's calls for a farm or fleet that runs elsewhere (its HTTP API,
through control/client.py).

Devices joined by wires or rules stay in one slice (they are applied in one process); otherwise
slices are balanced by device count, in configuration order.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any
from urllib.parse import quote

from enip_farm.config import FarmConfig
from enip_farm.control.client import ApiClient, ApiError


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
            # each worker's I/O thread: the budget configured and whether it measures (per worker)
            "cyclic_io": config.cyclic_io.model_dump(mode="json"),
            "bounds": config.bounds.model_dump(mode="json"),
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


class RemoteDevice:
    """One device of a running farm or fleet, driven through its HTTP API, with the calls of the
    pytest fixture's handle: `.set(DI3=1)`, `.get("DO5")`, `.get("goProgramNo")`, `.inputs`,
    `.outputs`, `.wait_for(...)`, `.inject(kind, ...)`, `.clear_faults()`, `.faults`."""

    def __init__(self, client: FleetClient, name: str) -> None:
        self._client = client
        self.name = name

    def _io(self) -> dict[str, Any]:
        return self._client.request("GET", f"/devices/{self.name}/io")

    @property
    def address(self) -> str:
        return self._client.request("GET", f"/devices/{self.name}")["address"]

    @property
    def inputs(self) -> bytes:
        return bytes.fromhex(self._io()["inputs"])

    @property
    def outputs(self) -> bytes:
        return bytes.fromhex(self._io()["outputs"])

    def set_inputs(self, data: bytes) -> None:
        self._client.request("PUT", f"/devices/{self.name}/io", json={"inputs": data.hex()})

    def get(self, name: str) -> int | float | list[int]:
        """A signal's value: numbered (`DI3`, `DO1-8` as a list) or named (`goProgramNo`), as
        RobotWare names them; KeyError naming it if the device has no such signal."""
        try:
            return self._client.request("GET", f"/devices/{self.name}/io/{quote(name, safe='')}")["value"]
        except ApiError as error:
            if error.status == 404:
                raise KeyError(error.detail) from None
            raise

    def set(self, values: dict[str, int | float | list[int]] | None = None,
            **signals: int | float | list[int]) -> None:
        self._client.request("PUT", f"/devices/{self.name}/io", json={"signals": {**(values or {}), **signals}})

    def wait_for(self, predicate: Callable[[RemoteDevice], bool], timeout: float = 5.0,
                 interval: float = 0.05) -> None:
        """Poll until `predicate(device)` holds, else TimeoutError after `timeout` seconds."""
        deadline = time.monotonic() + timeout
        while not predicate(self):
            if time.monotonic() >= deadline:
                raise TimeoutError(f"{self.name}: condition not met within {timeout} s")
            time.sleep(interval)

    def inject(self, kind: str, duration_s: float | None = None, **params: Any) -> None:
        self._client.request("POST", f"/devices/{self.name}/faults", json={"kind": kind, "duration_s": duration_s,
                                                                          **params})

    def clear_faults(self, kind: str | None = None) -> None:
        self._client.request("DELETE", f"/devices/{self.name}/faults", params={"kind": kind} if kind else None)

    @property
    def faults(self) -> list[dict]:
        return self._client.request("GET", f"/devices/{self.name}")["faults"]


class FleetClient:
    """A running farm's or fleet's HTTP API (`serve --http`, `serve --workers N --http`, a
    container's published port) as a Python client: `FleetClient(url, token)["io1"].set(DI3=1)`."""

    def __init__(self, api: str, token: str | None = None, timeout: float = 10.0) -> None:
        self._api = ApiClient(api, token, timeout)

    def request(self, method: str, path: str, **options: Any) -> Any:
        """The reply's JSON; ApiError for an error status, Unreachable when the API does not answer."""
        return self._api.request(method, path, **options)

    def names(self) -> list[str]:
        return [device["name"] for device in self.request("GET", "/devices")]

    def __getitem__(self, name: str) -> RemoteDevice:
        return RemoteDevice(self, name)

    def close(self) -> None:
        self._api.close()

    def __enter__(self) -> FleetClient:
        return self

    def __exit__(self, *_: object) -> None:
        self.close()

