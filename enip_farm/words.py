"""The words the farm prints about counts: `1 device`, `8 devices`."""

from __future__ import annotations


def plural(count: int, noun: str, nouns: str | None = None) -> str:
    """The count and the noun it takes: `plural(1, "device")` is `1 device`, `plural(0, "entry", "entries")`
    is `0 entries`."""
    return f"{count} {noun if count == 1 else nouns or noun + 's'}"
