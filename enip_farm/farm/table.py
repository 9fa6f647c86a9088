"""The device table that `enip-farm serve` prints once every device listens: fixed columns, so the
tables of several workers (`serve --workers N`) line up under one header."""

from __future__ import annotations

from collections.abc import Iterable

from enip_farm.device.device import Device

_COLUMNS = (("NAME", 10), ("ADDRESS", 15), ("MODEL", 26), ("IN BYTES", 8), ("OUT BYTES", 9))
TABLE_HEADER = "  ".join(title.ljust(width) for title, width in _COLUMNS).rstrip()


def device_table(devices: Iterable[Device], header: bool = True) -> str:
    """One line per device."""
    lines = [TABLE_HEADER] if header else []
    for device in devices:
        p = device.profile
        cells = [p.name, p.address, "+".join((p.model, *p.addons)), str(p.input_size), str(p.output_size)]
        lines.append("  ".join(cell.ljust(width) for cell, (_, width) in zip(cells, _COLUMNS, strict=True)).rstrip())
    return "\n".join(lines)
