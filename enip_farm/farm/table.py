"""The device table that `enip-farm serve` prints once every device listens: fixed columns, so the
rows of several workers (`serve --workers N`) line up under one header, in the configuration's
order. Past a screenful of rows the rest are summarised in one line (a 1000-device cell prints a
screen of rows, not 1000 lines before its banner)."""

from __future__ import annotations

import shutil
from collections import Counter
from collections.abc import Iterable, Sequence

from enip_farm.device.device import Device

_COLUMNS = (("NAME", 10), ("ADDRESS", 15), ("MODEL", 26), ("IN BYTES", 8), ("OUT BYTES", 9))
TABLE_HEADER = "  ".join(title.ljust(width) for title, width in _COLUMNS).rstrip()

#: One device's row: its name, the row as printed, and its model as the MODEL column shows it.
Row = tuple[str, str, str]


def device_rows(devices: Iterable[Device]) -> list[Row]:
    """The rows of these devices. MODEL is what the configuration names: a catalogue model, or a
    profile file's name (a learned profile, an EDS), with the add-ons."""
    rows = []
    for device in devices:
        p = device.profile
        model = "+".join((p.model_file or p.model, *p.addons))
        cells = [p.name, p.address, model, str(p.input_size), str(p.output_size)]
        rows.append((p.name, "  ".join(cell.ljust(width) for cell, (_, width)
                                       in zip(cells, _COLUMNS, strict=True)).rstrip(), model))
    return rows


def screenful() -> int:
    """How many rows fit the terminal with the header and the banner (24 lines where there is none)."""
    return max(10, shutil.get_terminal_size((80, 24)).lines - 6)


def device_table(rows: Sequence[Row], limit: int | None = None) -> str:
    """The header and one line per row; past `limit` rows (default: a screenful), the first ones
    and a line saying how many more there are, of which models."""
    limit = screenful() if limit is None else limit
    if len(rows) <= limit:
        return "\n".join([TABLE_HEADER, *(line for _, line, _ in rows)])
    shown = limit - 1
    models = Counter(model for _, _, model in rows).most_common()
    listed = ", ".join(f"{count} {model}" for model, count in models[:4]) + (", ..." if len(models) > 4 else "")
    return "\n".join([TABLE_HEADER, *(line for _, line, _ in rows[:shown]),
                      f"... and {len(rows) - shown} more devices: {len(rows)} in all ({listed})"])
