"""Profile files: a device model in the catalogue's format (`{"models": {NAME: MODEL}}`, read back
by `Catalogue.with_profile`), written by `eds import`, `learn` and the tests, all through here."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any

import yaml


def profile_text(document: dict[str, Any], origin: str, notes: Iterable[str] = ()) -> str:
    """The file's text: a comment saying where it came from, one comment line per note, the YAML."""
    comments = "".join(f"# {line}\n" for line in [origin, *notes])
    return comments + yaml.safe_dump(document, sort_keys=False, allow_unicode=True)


def write_profile(path: str | Path, document: dict[str, Any], origin: str, notes: Iterable[str] = ()) -> Path:
    path = Path(path)
    path.write_text(profile_text(document, origin, notes), encoding="utf-8")
    return path
