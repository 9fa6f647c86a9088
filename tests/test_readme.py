"""The README's example test passes as written: it is cut out of README.md and run by pytest."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

README = Path(__file__).resolve().parent.parent / "README.md"


@pytest.mark.system
def test_readme_example_passes(tmp_path: Path) -> None:
    match = re.search(r"<!-- example-test -->\s*```python\n(.*?)```", README.read_text(), re.S)
    assert match, "README.md has no example test"
    example = tmp_path / "test_example.py"
    example.write_text(match[1])
    # cwd is tmp_path: the plugin and the package come from the tree under test through PYTHONPATH (conftest)
    result = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(example)],
                            capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "1 passed" in result.stdout
