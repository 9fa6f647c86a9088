"""What a device keeps across a farm restart when the farm is given a state file (`Farm(state=...)`,
`enip-farm serve --state FILE`): like a module's non-volatile memory, a CIP Safety target's TUNID,
safety configuration (SCID and data), configuration owner (CFUNID), lock and password
(cip/safety/state.py). Read when the farm is built, written when it stops; one JSON object keyed
by device name, so devices added or removed in between keep or lose only their own entries."""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path

from enip_farm.device.device import Device

VERSION = 1


def load_state(devices: Mapping[str, Device], path: Path) -> list[str]:
    """Restore each device's saved state from `path` (nothing if it does not exist); the names of
    the devices restored. Raises ValueError for a file that is not such a state file."""
    if not path.exists():
        return []
    saved = json.loads(path.read_text())
    if not isinstance(saved, dict) or saved.get("version") != VERSION or not isinstance(saved.get("devices"), dict):
        raise ValueError(f"{path}: not an enip-farm state file (version {VERSION})")
    restored = []
    for name, state in saved["devices"].items():
        device = devices.get(name)
        safety = device.table.policy.safety if device is not None else None
        if safety is not None and isinstance(state, dict) and "safety" in state:
            safety.state.restore(state["safety"])
            restored.append(name)
    return restored


def save_state(devices: Mapping[str, Device], path: Path) -> None:
    """Write every device's state to `path` (atomically: a temporary file, then a rename), keeping
    the entries of devices this farm does not serve."""
    previous: dict = {}
    if path.exists():
        try:
            previous = json.loads(path.read_text()).get("devices", {})
        except (ValueError, AttributeError):
            previous = {}
    entries = dict(previous)
    for name, device in devices.items():
        safety = device.table.policy.safety
        if safety is not None:
            entries[name] = {"safety": device.guard.read(safety.state.snapshot)}
    temporary = path.with_name(path.name + ".tmp")
    temporary.write_text(json.dumps({"version": VERSION, "devices": entries}, indent=1, sort_keys=True))
    temporary.replace(path)
