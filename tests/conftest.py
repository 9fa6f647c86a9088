"""The project's tests use the pytest plugin's `enip_farm` fixture (enip_farm/pytest_plugin.py)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest

from enip_farm.farm import Farm


@pytest.fixture
def make_farm(enip_farm: Callable[..., Farm]) -> Callable[..., Farm]:
    """Several device dicts at once: make_farm({"name": "a", "model": "DSQC1030"}, ..., discovery=True)."""

    def factory(*devices: dict[str, Any], discovery: bool = False) -> Farm:
        return enip_farm({"devices": list(devices)}, discovery=discovery)

    return factory


@pytest.fixture
def dsqc1030(enip_farm: Callable[..., Farm]) -> str:
    """The address of one fresh DSQC1030."""
    return enip_farm(name="io1", model="DSQC1030")["io1"].address
