"""The compose file for a lab: one farm container per shard on a bridge network whose subnet
matches the cell, each adding its devices' addresses as aliases and serving its HTTP API, and a
tester that reads every device with pycomm3. `enip-farm compose` writes it; docker/compose.yaml
is its output for docker/cell.yaml."""

from __future__ import annotations

import ipaddress
import os
from pathlib import Path

import yaml

from enip_farm.config import FarmConfig
from enip_farm.fleet.slices import split
from enip_farm.words import plural

CONFIG_IN_CONTAINER = "/etc/enip-farm/cell.yaml"
API_PORT = 8044  # each farm's HTTP API inside its container
_TOKEN = "${ENIP_FARM_TOKEN:-}"  # empty: the entrypoint makes one up and logs it


class _Dumper(yaml.SafeDumper):
    """Every service spelled out in full: no YAML anchors and aliases for repeated parts."""

    def ignore_aliases(self, data: object) -> bool:
        return True


def pool_size(subnet: ipaddress.IPv4Network, container_range: ipaddress.IPv4Network) -> int:
    """How many containers Docker can place in `container_range`: its first and last addresses,
    the gateway (the subnet's first host) and the subnet's broadcast address are never given out."""
    taken = {container_range.network_address, container_range.broadcast_address, subnet.broadcast_address,
             next(subnet.hosts())}
    return sum(1 for address in container_range if address not in taken)


def _relative(path: Path, start: Path) -> str:
    relative = os.path.relpath(path.resolve(), start.resolve())
    return relative if relative.startswith("..") else f"./{relative}"


def compose_file(config: FarmConfig, config_path: Path, compose_dir: Path, shards: int, subnet: str,
                 container_range: str, api_port: int = 8044, source: Path | None = None) -> str:
    """The compose file, to be written in `compose_dir` (the config is mounted relative to it).
    `source`: the enip-farm source tree to build the image from (else the image must exist).
    `api_port`: farm i's HTTP API is published on the host's 127.0.0.1:api_port+i-1 (0: not)."""
    network = ipaddress.IPv4Network(subnet)
    reserved = ipaddress.IPv4Network(container_range)
    if not reserved.subnet_of(network):
        raise ValueError(f"{container_range} is not inside {subnet}")
    for device in config.devices:
        if device.address not in network or device.address in reserved:
            raise ValueError(f"device {device.name!r} ({device.address}) must be in {subnet} outside {container_range}")
    parts = split(config, shards)
    room = pool_size(network, reserved)
    if len(parts) + 1 > room:
        raise ValueError(f"{len(parts)} farm containers and the tester need {len(parts) + 1} addresses; "
                         f"{container_range} holds {room}: at most {room - 1} shards, or give a larger "
                         "--container-range")
    mount = f"{_relative(config_path, compose_dir)}:{CONFIG_IN_CONTAINER}:ro"
    build = None
    if source is not None:
        build = {"context": _relative(source, compose_dir), "dockerfile": "docker/Dockerfile",
                 # a registry-less machine builds on a local base: ENIP_FARM_BASE=... docker compose build
                 "args": {"BASE": "${ENIP_FARM_BASE:-python:3.11-slim}"}}
    services: dict = {}
    for index in range(1, len(parts) + 1):
        service: dict = {"build": build} if build else {}
        service.update({
            "image": "enip-farm:latest",
            "command": ["serve", "--config", CONFIG_IN_CONTAINER, "--http", f"0.0.0.0:{API_PORT}"],
            "environment": {"ENIP_FARM_SHARD": f"{index}/{len(parts)}", "ENIP_FARM_TOKEN": _TOKEN},
            "cap_add": ["NET_ADMIN"],  # the entrypoint adds the device addresses as aliases
            "volumes": [mount],
            "networks": ["cell"],
            "restart": "unless-stopped",
            # bash connecting to each device's TCP 44818: no interpreter per probe
            "healthcheck": {"test": ["CMD", "/opt/enip-farm/docker/healthcheck.sh"],
                            "interval": "3s", "timeout": "3s", "retries": 3, "start_period": "60s"},
        })
        if api_port:
            service["ports"] = [f"127.0.0.1:{api_port + index - 1}:{API_PORT}"]
        services[f"farm{index}"] = service
    services["tester"] = {
        "image": "enip-farm:latest",
        "entrypoint": ["python", "/opt/enip-farm/docker/tester.py", CONFIG_IN_CONTAINER],
        "volumes": [mount],
        "networks": ["cell"],
        "depends_on": {f"farm{i}": {"condition": "service_healthy"} for i in range(1, len(parts) + 1)},
    }
    document = {
        "services": services,
        "networks": {"cell": {"driver": "bridge", "ipam": {"config": [
            {"subnet": str(network), "ip_range": str(reserved)}]}}},
    }
    apis = (f"# Farm i's HTTP API: http://127.0.0.1:{api_port}+i-1 on the host, http://farmI:{API_PORT} in the\n"
            "# network, with Authorization: Bearer $ENIP_FARM_TOKEN (unset: each farm logs one it made up).\n"
            ) if api_port else ""
    header = (f"# Generated by `enip-farm compose --config {_relative(config_path, compose_dir)} --shards {shards}`.\n"
              f"# {plural(len(config.devices), 'device')} in {len(parts)} farm container(s) on {network};"
              " containers themselves\n"
              f"# take addresses from {reserved} only ({room} of them), so they never collide with a device.\n"
              + apis)
    return header + yaml.dump(document, Dumper=_Dumper, sort_keys=False, width=120)
