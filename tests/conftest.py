"""Farm fixtures: devices on fresh 127.x addresses, served from a background thread."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import ExitStack
from typing import Any

import pytest

from enip_farm.config import parse_config
from enip_farm.farm import Farm
from tests.helpers import next_address


@pytest.fixture
def make_farm() -> Iterator[Callable[..., Farm]]:
    """Start a farm of the given device dicts (address filled in when absent); stopped at teardown."""
    with ExitStack() as stack:

        def factory(*devices: dict[str, Any], discovery: bool = False) -> Farm:
            entries = [{"address": next_address(), **device} for device in devices]
            farm = Farm(parse_config({"devices": entries, "discovery": discovery}))
            stack.enter_context(farm.running_in_thread())
            return farm

        yield factory


@pytest.fixture
def dsqc1030(make_farm: Callable[..., Farm]) -> str:
    """The address of one fresh DSQC1030."""
    farm = make_farm({"name": "io1", "model": "DSQC1030"})
    return farm.device("io1").profile.address
