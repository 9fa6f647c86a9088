"""The cell an EIO.cfg import builds (`enip-farm eio import`): the devices imported so far, the
entries left as comments, the names of devices not imported or of other networks, the next farm
address (--base-address) and the warnings, each naming the file and line (eio/cfg.py's
`file:line`)."""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from ipaddress import IPv4Address
from typing import Any

from enip_farm.device.catalogue import Catalogue
from enip_farm.device.profile import DeviceProfile
from enip_farm.eio.cfg import CfgFile, Entry


@dataclass
class ImportedDevice:
    """An ETHERNETIP_DEVICE entry made a farm device: its configuration, the controller's address
    and the comment lines the YAML gives it."""

    entry: Entry
    config: dict[str, Any]
    controller_address: str | None
    notes: list[str] = field(default_factory=list)  # comment lines for the YAML
    profile: DeviceProfile | None = None


class CellImport:
    """The state of one import; `warn` records a warning about an entry."""

    def __init__(self, cfg: CfgFile, catalogue: Catalogue, base_address: IPv4Address | None) -> None:
        self.cfg = cfg
        self.catalogue = catalogue
        self.warnings: list[tuple[int, str]] = [(line_of(w), w) for w in cfg.warnings]
        self.not_imported: list[Entry] = []
        self.devices: dict[str, ImportedDevice] = {}
        self.skipped_devices: set[str] = set()
        self.other_devices: dict[str, str] = {}  # device name -> its section
        self.next_address = int(base_address) if base_address is not None else None
        self.base_address = base_address

    def warn(self, entry: Entry, message: str) -> None:
        self.warnings.append((entry.line, f"{self.cfg.where(entry.line)}: {entry.describe()}: {message}"))

    def skip(self, entry: Entry, name: str) -> None:
        """A device entry not imported: kept as a comment, its signals not imported either."""
        self.skipped_devices.add(name.casefold())
        self.not_imported.append(entry)


def line_of(warning: str) -> int:
    """The line a `file:line: ...` message names (0 if none)."""
    match = re.match(r"^.*?:(\d+): ", warning)
    return int(match[1]) if match else 0
