"""A cell configuration from a controller's EIO.cfg: every EtherNet/IP device the controller scans
(`ETHERNETIP_DEVICE`) becomes a farm device with the identity, assembly instances and sizes the
controller expects, so that its electronic key and connection sizes match what the device answers;
the file's `EIO_SIGNAL` entries become each device's named signals.

The entries are read by eio/ethernetip_device.py (devices, their catalogue model) and
eio/eio_signal.py (signals), into eio/cell.py's state; this module runs them over the file and
writes the YAML.

Nothing unknown is fatal: attributes the farm does not use go to the device's or signal's
`extra` (and `eio export` writes them back); entries the farm cannot serve (other kinds of
devices, their signals, cross connections, unknown sections) are kept as comments in the YAML;
every such decision is reported as a warning naming the file and line.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from ipaddress import IPv4Address
from typing import Any

import yaml

from enip_farm.config import parse_config
from enip_farm.device.catalogue import Catalogue
from enip_farm.eio.cell import CellImport
from enip_farm.eio.cfg import CfgFile, Entry
from enip_farm.eio.eio_signal import SIGNAL_SECTION, import_signal
from enip_farm.eio.ethernetip_device import (
    ETHERNETIP_SECTIONS,
    GENERIC_MODEL,
    import_device,
    is_device_section,
    reads_as_ethernetip,
)

__all__ = ["GENERIC_MODEL", "EioError", "EioImportWarning", "ImportResult", "import_eio"]

#: Sections seen in public files that the farm does not import (kept as comments, reported without
#: calling them unknown).
KNOWN_SECTIONS = frozenset({"INDUSTRIAL_NETWORK", "EIO_CROSS", "EIO_ACCESS", "SYSSIG_IN"})
_DUMPER = getattr(yaml, "CSafeDumper", yaml.SafeDumper)  # libyaml's emitter when PyYAML has it: 10x faster


class EioImportWarning(UserWarning):
    """A warning of `import_eio` (the file and line, and what the farm did about it), raised as a
    Python warning where the import is not a command's (the pytest fixture)."""


class EioError(ValueError):
    """Nothing the farm can serve in the file (or it is not an EIO file); the message is one line,
    `warnings` say what was found instead."""

    def __init__(self, message: str, warnings: list[str] | None = None) -> None:
        super().__init__(message)
        self.warnings = warnings or []


@dataclass
class ImportResult:
    document: dict[str, Any]  # the cell configuration, in the format of `enip_farm.config`
    warnings: list[str]
    yaml: str  # the document with comments: where each device came from, what was not imported

    @property
    def device_count(self) -> int:
        return len(self.document["devices"])

    @property
    def signal_count(self) -> int:
        return sum(len(device.get("signals", ())) for device in self.document["devices"])


def import_eio(cfg: CfgFile, catalogue: Catalogue, base_address: IPv4Address | None = None) -> ImportResult:
    """The cell of a parsed EIO.cfg. `base_address` renumbers the devices consecutively from it
    (skipping host numbers 0 and 255), in file order; by default they keep the controller's.
    Raises EioError if the file is not an EIO file or holds no EtherNet/IP device to serve."""
    if cfg.domain != "EIO":
        raise EioError(f"{cfg.where(1)}: a {cfg.domain} configuration file, not EIO (the I/O configuration)")
    return _run(CellImport(cfg, catalogue, base_address))


def _run(cell: CellImport) -> ImportResult:
    """Devices first (signals name them), then the signals; the other sections are reported."""
    signals: list[Entry] = []
    others: dict[str, list[Entry]] = {}
    for entry in cell.cfg.entries:
        if entry.section in ETHERNETIP_SECTIONS or reads_as_ethernetip(cell, entry):
            import_device(cell, entry)
        elif entry.section == SIGNAL_SECTION:
            signals.append(entry)
        else:
            if is_device_section(entry.section) and isinstance(entry.get("Name"), str):
                cell.other_devices[str(entry.get("Name")).casefold()] = entry.section
            others.setdefault(entry.section, []).append(entry)
            cell.not_imported.append(entry)
    for section, entries in others.items():
        line = cell.cfg.sections.get(section, entries[0].line)
        count = f"{len(entries)} entr{'y' if len(entries) == 1 else 'ies'}"
        if is_device_section(section):
            what = "devices that are not EtherNet/IP devices the controller scans"
        elif section in KNOWN_SECTIONS:
            what = "not used by the farm, which serves devices and their signals"
        else:
            what = "an unknown section"
        cell.warnings.append((line, f"{cell.cfg.where(line)}: {section} ({count}): {what}: not imported, "
                                    "kept as comments"))
    for entry in signals:
        import_signal(cell, entry)
    warnings = [text for _, text in sorted(cell.warnings, key=lambda warning: warning[0])]
    if not cell.devices:
        raise EioError(f"{cell.cfg.source}: no EtherNet/IP device (ETHERNETIP_DEVICE entry) the farm can "
                       "serve: nothing to import", warnings)
    document: dict[str, Any] = {"devices": [device.config for device in cell.devices.values()]}
    groups = network_groups(cell, others.get("INDUSTRIAL_NETWORK", []))
    if groups:
        document["groups"] = groups
    parse_config(document, cell.cfg.source)  # the pieces were checked one by one; this cannot fail
    return ImportResult(document, warnings, _yaml(cell, document, warnings))


def network_groups(cell: CellImport, networks: list[Entry]) -> list[dict[str, Any]]:
    """A group (kind network) per network the devices are on: a device's -Network, else the file's one
    EtherNet/IP network (INDUSTRIAL_NETWORK; its only network), else none. Named as the network,
    made a valid group name."""
    named = [str(n.get("Name")) for n in networks if isinstance(n.get("Name"), str)]
    ethernetip = [name for name in named if "ethernetip" in name.casefold()] or named
    default = ethernetip[0] if len(ethernetip) == 1 else None
    taken = {device.config["name"] for device in cell.devices.values()}
    members: dict[str, list[str]] = {}
    for device in cell.devices.values():
        network = device.entry.get("Network")
        network = str(network) if isinstance(network, str) and network.strip() else default
        if network is not None:
            members.setdefault(network, []).append(device.config["name"])
    groups = []
    for network, names in members.items():
        name = re.sub(r"[^A-Za-z0-9_.-]", "_", network)[:56] or "network"
        while name in taken:
            name += "-net"
        taken.add(name)
        groups.append({"name": name, "kind": "network", "members": names})
    return groups


def _yaml(cell: CellImport, document: dict[str, Any], warnings: list[str]) -> str:
    """The document with comments: where each device came from, the warnings, what was not imported."""
    out = [f"# Imported by `enip-farm eio import` from {cell.cfg.source} ({cell.cfg.header}).",
           "# Each device is an EtherNet/IP device the controller scans, with the identity, assemblies and",
           "# sizes the controller expects; its signals are the file's EIO_SIGNAL entries for it."]
    if cell.base_address is not None:
        out.append(f"# Addresses renumbered from {cell.base_address} (--base-address); each device's comment "
                   "gives the controller's.")
    else:
        out.append("# Devices keep the controller's addresses (--base-address renumbers them for a desk run).")
    if warnings:
        out += ["#", "# Warnings:"] + [f"#   {warning}" for warning in warnings]
    if cell.not_imported:
        out += ["#", "# Not imported (as the file had them):"]
        out += [f"#   {cell.cfg.where(entry.line)} {entry.section}: {entry.text()}"
                for entry in sorted(cell.not_imported, key=lambda e: e.line)]
    out.append("devices:")
    for device, config in zip(cell.devices.values(), document["devices"], strict=True):
        origin = f"{cell.cfg.where(device.entry.line)} {device.entry.section} {config['name']!r}"
        if device.controller_address and device.controller_address != config["address"]:
            origin += f", controller address {device.controller_address}"
        out.append(f"  # {origin}")
        out += [f"  # {note}" for note in device.notes]
        dumped = yaml.dump([config], Dumper=_DUMPER, sort_keys=False, default_flow_style=None, width=110,
                           allow_unicode=True)
        out += ["  " + line for line in dumped.splitlines()]
    if "groups" in document:
        out.append("# The networks the devices are on (a fault or a scenario names a group to hit them all):")
        dumped = yaml.dump({"groups": document["groups"]}, Dumper=_DUMPER, sort_keys=False,
                           default_flow_style=None, width=110)
        out += dumped.splitlines()
    return "\n".join(out) + "\n"
