"""Issue 23's measure of the code's shape: no Python module of enip_farm/ is longer than 400 lines
(small modules with one job)."""

from __future__ import annotations

from tests.helpers import ROOT

MAX_LINES = 400


def test_no_module_of_the_package_is_longer_than_400_lines() -> None:
    lengths = {str(path.relative_to(ROOT)): len(path.read_text().splitlines())
               for path in sorted((ROOT / "enip_farm").rglob("*.py"))}
    assert {path: lines for path, lines in lengths.items() if lines > MAX_LINES} == {}
