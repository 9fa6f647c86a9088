"""Where the cell's devices sit on the network: whether a device's addresses fit its subnet, and the
cell's topology, named groups of devices that fail together (a rack, the switch its modules hang
on, their 24 V power feed, a ring, a network), pure schema like the rest of the configuration
(enip_farm/config.py checks a group's members against its devices).

A member is a device's name, a glob pattern of names (`rack2-*`), an address, an address range
(`192.168.1.10-192.168.1.20`) or a subnet (`192.168.2.0/24`); each must stand for at least one device.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from fnmatch import fnmatchcase
from ipaddress import IPv4Address, IPv4Network
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

#: What a group stands for in the cell; the farm treats every kind alike (a fault hits every member).
GroupKind = Literal["rack", "switch", "power_feed", "ring", "network"]


class GroupConfig(BaseModel):
    """One group: its name (not a device's), its kind and its members."""

    model_config = ConfigDict(extra="forbid")
    name: str = Field(pattern=r"^[A-Za-z0-9_.-]{1,64}$")
    kind: GroupKind = "rack"
    members: list[str] = Field(min_length=1, description="device names, glob patterns, addresses, "
                               "ranges first-last, subnets a.b.c.d/n")


@dataclass(frozen=True)
class Topology:
    """The groups resolved: each group's device names, in configuration order."""

    groups: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    devices: tuple[str, ...] = ()

    def members(self, group: str) -> tuple[str, ...]:
        """The devices of `group` (KeyError if there is no such group)."""
        return self.groups[group]

    def targets(self, name: str) -> tuple[str, ...]:
        """The devices a device's or a group's name stands for (KeyError if neither)."""
        if name in self.groups:
            return self.groups[name]
        if name in self.devices:
            return (name,)
        raise KeyError(name)

    def groups_of(self, device: str) -> tuple[str, ...]:
        """The groups `device` belongs to."""
        return tuple(name for name, members in self.groups.items() if device in members)


#: A problem of a group: where (its index and the field's path in it), what, and the value.
GroupProblem = tuple[int, tuple[Any, ...], str, Any]


def resolve(groups: Iterable[GroupConfig], devices: Iterable[tuple[str, IPv4Address]]
            ) -> tuple[Topology, list[GroupProblem]]:
    """The topology of `groups` over `devices` (name, address), and every problem, one each."""
    devices = list(devices)
    names = [name for name, _ in devices]
    resolved: dict[str, tuple[str, ...]] = {}
    problems: list[GroupProblem] = []
    for index, group in enumerate(groups):
        if group.name in names:
            problems.append((index, ("name",), f"{group.name!r} is a device's name too: a group needs its own",
                             group.name))
        if group.name in resolved:
            problems.append((index, ("name",), f"group {group.name!r} is defined twice", group.name))
        chosen: set[str] = set()
        for number, member in enumerate(group.members):
            matched = member_devices(member, devices)
            if isinstance(matched, str):
                problems.append((index, ("members", number), matched, member))
            else:
                chosen.update(matched)
        resolved.setdefault(group.name, tuple(name for name in names if name in chosen))
    return Topology(resolved, tuple(names)), problems


def member_devices(member: str, devices: list[tuple[str, IPv4Address]]) -> list[str] | str:
    """The devices one member stands for, or why it stands for none."""
    text = member.strip()
    try:
        if "/" in text:
            network = IPv4Network(text, strict=False)
            found, what = [n for n, a in devices if a in network], f"subnet {network}"
        elif re.fullmatch(r"[0-9.]+-[0-9.]+", text):
            first, last = (IPv4Address(part) for part in text.split("-"))
            if last < first:
                return f"address range {text}: the last address is below the first"
            found, what = [n for n, a in devices if first <= a <= last], f"address range {text}"
        elif re.fullmatch(r"[0-9.]+", text):
            found, what = [n for n, a in devices if a == IPv4Address(text)], f"address {text}"
        elif any(c in text for c in "*?["):
            found, what = [n for n, _ in devices if fnmatchcase(n, text)], f"pattern {text!r}"
        else:
            found = [n for n, _ in devices if n == text]
            return found or f"{text!r} is not a device of the configuration (nor a pattern, an address or a range)"
    except ValueError as error:
        return f"{text!r} is neither a device, a pattern, an address, a range nor a subnet: {error}"
    return found or f"{what}: no device of the configuration is in it"


def subnet_problem(first: IPv4Address, count: int, netmask: IPv4Address) -> str | None:
    """Why the addresses first .. first + count - 1 cannot all be hosts of first's subnet, if they
    cannot: a network or broadcast address, or a range that runs past the subnet. /31 and /32 have
    neither (RFC 3021), so any address of theirs is a host."""
    network = IPv4Network(f"{first}/{netmask}", strict=False)
    if network.prefixlen >= 31:
        return None
    last = first + count - 1
    subnet = f"the subnet {network} (netmask {netmask})"
    for address, what in ((network.network_address, "network"), (network.broadcast_address, "broadcast")):
        if count == 1 and first == address:
            return (f"address {first} is the {what} address of {subnet}: no device can have it; "
                    f"choose a host address ({network.network_address + 1} .. {network.broadcast_address - 1})")
    if first == network.network_address:
        return f"count {count} from {first} starts at the network address of {subnet}: start at {first + 1}"
    if last >= network.broadcast_address:
        return (f"count {count} from {first} runs past {subnet}: the addresses would end at {last}, the last "
                f"host is {network.broadcast_address - 1}; start lower, use fewer, or widen the netmask "
                "(e.g. netmask: 255.255.0.0)")
    return None
