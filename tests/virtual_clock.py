"""A virtual clock for the farm's timers: an event loop whose `time()` the test sets, a farm (built,
not serving: no sockets) running a scenario on it (the `on_virtual_clock` fixture of conftest.py),
and `at()` to move the clock and let what is due run."""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Coroutine
from typing import Any

from enip_farm.farm.farm import Farm


class VirtualClockLoop(asyncio.SelectorEventLoop):
    """An event loop whose clock the test sets: timers fire when `now` reaches them, not before."""

    def __init__(self) -> None:
        super().__init__()
        self.now = 1_000.0

    def time(self) -> float:
        return self.now


Scenario = Callable[[Farm, VirtualClockLoop], Coroutine[Any, Any, None]]


def run_on(loop: VirtualClockLoop, scenario: Scenario, address: str = "127.0.0.1") -> None:
    """Run `scenario` with a farm of one DSQC1030 at `address` whose loop is `loop`."""
    farm = Farm({"devices": [{"name": "io1", "model": "DSQC1030", "address": address}]})

    async def main() -> None:
        farm.loop = loop  # the loop its timers and tasks run on
        await scenario(farm, loop)

    loop.run_until_complete(main())


async def at(loop: VirtualClockLoop, when: float) -> None:
    """Move the clock to `when` and let what is due run (timers, then the tasks they start)."""
    loop.now = when
    for _ in range(4):
        await asyncio.sleep(0)
