"""Fresh loopback addresses for a farm that serves only this machine (the pytest fixture's devices,
`golden`'s own farm): a block of 127/8 per process, never one address twice, so such a farm never
collides with one serving the cell's own addresses (`enip-farm serve`) or with another process's."""

from __future__ import annotations

import itertools


class LoopbackPool:
    """Calling the pool gives the next address of its block: 127.BLOCK.x.y (the second octet is the
    block; 250 hosts per /24, skipping .0 and .255)."""

    def __init__(self, block: int) -> None:
        if not 1 <= block <= 254:
            raise ValueError(f"block {block}: the second octet of 127.x is 1..254")
        self.block = block
        self._next = itertools.count(1)

    def __call__(self) -> str:
        n = next(self._next)
        return f"127.{self.block}.{n // 250 % 250}.{n % 250 + 1}"
