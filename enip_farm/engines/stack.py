"""The Docker Swarm stack for a cell (`docker stack deploy`): one farm service whose N replicas each
serve the slice of their task slot, on a swarm-scoped macvlan network on the NIC toward the
controller; the fleet's one HTTP API (finding the shards by `tasks.farm` DNS on an overlay
network); a one-shot tester. `enip-farm stack` writes it; docker/stack.yaml is its output for
docker/cell.yaml with 3 shards."""

from __future__ import annotations

import ipaddress
import os
from pathlib import Path

import yaml

from enip_farm.config import FarmConfig
from enip_farm.engines.compose import API_PORT, CONFIG_IN_CONTAINER, pool_size
from enip_farm.fleet.slices import split
from enip_farm.words import plural

TOKEN_IN_CONTAINER = "/run/secrets/enip_farm_token"
CELL_NETWORK = "enip-cell"
HEALTHCHECK = {"test": ["CMD", "/opt/enip-farm/docker/healthcheck.sh"],
               "interval": "3s", "timeout": "3s", "retries": 3, "start_period": "60s"}


class _Dumper(yaml.SafeDumper):
    """Every service spelled out in full: no YAML anchors and aliases for repeated parts."""

    def ignore_aliases(self, data: object) -> bool:
        return True


def check_cell(config: FarmConfig, shards: int, subnet: str, reserved_range: str, others: int) -> list[FarmConfig]:
    """The slices of a cell for `shards` instances on `subnet`, whose `reserved_range` holds the
    addresses of the engine's own containers or pods (`others` besides the shards); ValueError with
    one line saying why for a device outside the subnet or inside the range, more shards than
    groups of devices, or a range too small. Slices never overlap (fleet.split)."""
    network = ipaddress.IPv4Network(subnet)
    reserved = ipaddress.IPv4Network(reserved_range)
    if not reserved.subnet_of(network):
        raise ValueError(f"{reserved_range} is not inside {subnet}")
    for device in config.devices:
        if device.address not in network:
            raise ValueError(f"device {device.name!r} ({device.address}) is outside the controller's subnet {subnet}")
        if device.address in reserved:
            raise ValueError(f"device {device.name!r} ({device.address}) is inside {reserved_range}, "
                             "where the engine places its containers")
    parts = split(config, shards)
    if len(parts) < shards:
        raise ValueError(f"{shards} shards for {len(parts)} groups of devices (devices joined by wires or rules "
                         f"stay together): at most {len(parts)} shards")
    room = pool_size(network, reserved)
    if shards + others > room:
        raise ValueError(f"{shards} shards and {others} other container(s) need {shards + others} addresses; "
                         f"{reserved_range} holds {room}")
    return parts


def network_commands(subnet: str, container_range: str, parent: str) -> list[str]:
    """The swarm-scoped macvlan network the stack's containers join, on the NIC toward the controller:
    on every node its own part of `container_range` (each node's engine gives out addresses by itself),
    then the network, once, on a manager."""
    return [f"docker network create --config-only --subnet {ipaddress.IPv4Network(subnet)} "
            f"--ip-range PART-OF-{ipaddress.IPv4Network(container_range)} -o parent={parent} {CELL_NETWORK}-node",
            f"docker network create -d macvlan --scope swarm --attachable --config-from {CELL_NETWORK}-node "
            f"{CELL_NETWORK}"]


def stack_file(config: FarmConfig, config_path: Path, stack_dir: Path, shards: int, subnet: str,
               container_range: str, parent: str = "eth1", api_port: int = 8044) -> str:
    """The stack file, to be written in `stack_dir` (the cell's config and the token's secret are
    files relative to it). `parent`: the NIC toward the controller, the same name on every node,
    for the macvlan network the header's command makes; `api_port`: the fleet API's port published
    on the node that runs it (0: not published)."""
    check_cell(config, shards, subnet, container_range, others=1)  # the tester
    halves = list(ipaddress.IPv4Network(container_range).subnets(prefixlen_diff=1))
    relative = os.path.relpath(config_path.resolve(), stack_dir.resolve())
    cell = {"source": "cell", "target": CONFIG_IN_CONTAINER, "mode": 0o444}
    farm = {
        "image": "enip-farm:latest",
        "command": ["serve", "--config", CONFIG_IN_CONTAINER, "--http", f"0.0.0.0:{API_PORT}"],
        "environment": {"ENIP_FARM_SHARD": f"{{{{.Task.Slot}}}}/{shards}", "ENIP_FARM_TOKEN_FILE": TOKEN_IN_CONTAINER},
        "cap_add": ["NET_ADMIN"],  # the entrypoint adds the slice's addresses as aliases on the cell's interface
        "configs": [cell],
        "secrets": ["enip_farm_token"],
        "networks": ["cell", "fleet"],
        "healthcheck": HEALTHCHECK,
        "deploy": {
            "replicas": shards,
            "endpoint_mode": "dnsrr",  # tasks.farm: one address per task, no virtual IP
            "placement": {"max_replicas_per_node": shards},
            "restart_policy": {"condition": "any", "delay": "2s"},
            "update_config": {"order": "stop-first"},  # one slice's addresses are never served twice
        },
    }
    api: dict = {
        "image": "enip-farm:latest",
        "command": ["fleet-api", "--config", CONFIG_IN_CONTAINER, "--shards", str(shards),
                    "--discover", f"tasks.farm:{API_PORT}", "--http", f"0.0.0.0:{API_PORT}"],
        "environment": {"ENIP_FARM_TOKEN_FILE": TOKEN_IN_CONTAINER},
        "configs": [cell],
        "secrets": ["enip_farm_token"],
        "networks": ["fleet"],
        # the image's health check looks for device addresses, which the API has none of: its port instead
        "healthcheck": {"test": ["CMD", "bash", "-c", f"exec 3<>/dev/tcp/127.0.0.1/{API_PORT}"],
                        "interval": "5s", "timeout": "3s", "retries": 3, "start_period": "30s"},
        "deploy": {"replicas": 1, "restart_policy": {"condition": "any", "delay": "2s"}},
    }
    if api_port:
        api["ports"] = [{"target": API_PORT, "published": api_port, "protocol": "tcp", "mode": "host"}]
    tester = {
        "image": "enip-farm:latest",
        # ListIdentity until every device answers (up to 3 minutes), then the tester's passes
        "entrypoint": ["python", "/opt/enip-farm/docker/tester.py", CONFIG_IN_CONTAINER, "--wait", "180"],
        "configs": [cell],
        "networks": ["cell"],
        "healthcheck": {"disable": True},
        "deploy": {"restart_policy": {"condition": "none"}},  # one shot: its exit status is the verdict
    }
    document = {
        "version": "3.8",
        "services": {"farm": farm, "api": api, "tester": tester},
        "networks": {
            # a stack file cannot give an IPAM range: the network is made once per swarm (network_commands)
            "cell": {"external": True, "name": CELL_NETWORK},
            "fleet": {"driver": "overlay"},
        },
        "configs": {"cell": {"file": relative}},
        "secrets": {"enip_farm_token": {"file": "${ENIP_FARM_TOKEN_FILE:-./token}"}},
    }
    header = (
        f"# Generated by `enip-farm stack --config {relative} --shards {shards}`.\n"
        f"# {plural(len(config.devices), 'device')} in {plural(shards, 'shard')}:"
        " the tasks of service `farm`, task slot I serving\n"
        f"# slice I/{shards}, on the macvlan network {CELL_NETWORK} on {parent} (the NIC toward the controller,\n"
        f"# {subnet}); containers take addresses from {container_range} only. The network, on each node\n"
        f"# (its own part of the range, e.g. {' and '.join(map(str, halves))} on two nodes), then on a manager:\n"
        + "".join(f"#   {command}\n" for command in network_commands(subnet, container_range, parent)) +
        "# The token: a file, ${ENIP_FARM_TOKEN_FILE:-./token} (openssl rand -hex 16 > token). Deploy from\n"
        "# this directory:  docker stack deploy -c stack.yaml enip\n"
        + (f"# The fleet's HTTP API: http://NODE:{api_port} on the node that runs service `api`.\n" if api_port else "")
    )
    return header + yaml.dump(document, Dumper=_Dumper, sort_keys=False, width=120)
