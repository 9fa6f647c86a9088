"""Layers point one way: no module hides an import of the package under `TYPE_CHECKING` (the
import-linter contract in pyproject.toml, run by `lint-imports` in CI, checks the direction of
every other import, lazy ones included), and the farm provides what control/ asks of it."""

from __future__ import annotations

import ast
import inspect
from pathlib import Path

from enip_farm.config import parse_config
from enip_farm.control.handle import FarmControl
from enip_farm.farm.farm import Farm

PACKAGE = Path(__file__).resolve().parent.parent / "enip_farm"

def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _package_imports(node: ast.AST) -> list[str]:
    names = []
    for child in ast.walk(node):
        if isinstance(child, ast.ImportFrom) and (child.level or (child.module or "").split(".")[0] == "enip_farm"):
            names.append("." * child.level + (child.module or ""))
        elif isinstance(child, ast.Import):
            names += [alias.name for alias in child.names if alias.name.split(".")[0] == "enip_farm"]
    return names


def _type_checking_imports(path: Path) -> list[str]:
    tree = ast.parse(path.read_text(), str(path))
    return [name for node in ast.walk(tree) if isinstance(node, ast.If) and _is_type_checking(node.test)
            for name in _package_imports(ast.Module(body=node.body, type_ignores=[]))]


def test_no_type_checking_imports_of_the_package() -> None:
    found = {str(path.relative_to(PACKAGE)): names for path in sorted(PACKAGE.rglob("*.py"))
             if (names := _type_checking_imports(path))}
    assert found == {}


def test_the_check_finds_what_it_looks_for(tmp_path: Path) -> None:
    module = tmp_path / "m.py"
    module.write_text("import typing\nif typing.TYPE_CHECKING:\n    from enip_farm.farm.farm import Farm\n"
                      "    import os\nif TYPE_CHECKING:\n    from .x import y\n")
    assert _type_checking_imports(module) == ["enip_farm.farm.farm", ".x"]


def test_farm_provides_farm_control() -> None:
    farm = Farm(parse_config({"devices": [{"name": "io", "address": "127.0.0.5", "model": "DSQC1030"}]}))
    assert isinstance(farm, FarmControl)
    for name, member in vars(FarmControl).items():
        if inspect.isfunction(member) and name not in ("__init__", "__subclasshook__"):
            wanted, given = inspect.signature(member), inspect.signature(getattr(Farm, name))
            assert list(wanted.parameters) == list(given.parameters), name
            assert inspect.iscoroutinefunction(member) == inspect.iscoroutinefunction(getattr(Farm, name)), name
