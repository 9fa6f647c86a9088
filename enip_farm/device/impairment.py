"""A degraded link inside the farm (no root, no netem): per direction, each datagram is lost, passed,
held back (delay, jitter, and for a share an extra hold so that later ones overtake it: reordering)
or duplicated, by a seeded random generator so that a run can be repeated. Sans-IO: the time is
given; what is held comes out of `due(now)`, the I/O thread's timer asks `next_due()`."""

from __future__ import annotations

import heapq
import random
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

Address = Any  # where a datagram comes from or goes to: (host, port)


@dataclass(frozen=True)
class LinkQuality:
    """What one direction does to datagrams: ns held, ns of jitter (either way, never below 0), and
    the shares (0..1) lost, duplicated, and held `reorder_ns` more."""

    delay_ns: int = 0
    jitter_ns: int = 0
    loss: float = 0.0
    duplicate: float = 0.0
    reorder: float = 0.0
    reorder_ns: int = 0


class Direction:
    """One direction of a degraded link, with its counts of what it did."""

    def __init__(self, quality: LinkQuality, rng: random.Random) -> None:
        self.quality = quality
        self.rng = rng
        self.held: list[tuple[int, int, bytes, Address]] = []
        self._order = 0
        self.passed = self.lost = self.duplicated = self.delayed = self.reordered = 0

    def admit(self, data: bytes, address: Address, now: int) -> list[tuple[bytes, Address]]:
        """A datagram at `now`: what goes through at once ([] if lost or held)."""
        q, rng = self.quality, self.rng
        if q.loss and rng.random() < q.loss:
            self.lost += 1
            return []
        copies = 1
        if q.duplicate and rng.random() < q.duplicate:
            copies = 2
            self.duplicated += 1
        out = []
        for _ in range(copies):
            hold = q.delay_ns + (round(rng.uniform(-q.jitter_ns, q.jitter_ns)) if q.jitter_ns else 0)
            if q.reorder and rng.random() < q.reorder:
                hold += q.reorder_ns
                self.reordered += 1
            if hold <= 0:
                out.append((data, address))
                self.passed += 1
            else:
                self._order += 1
                heapq.heappush(self.held, (now + hold, self._order, data, address))
                self.delayed += 1
        return out

    def due(self, now: int) -> list[tuple[bytes, Address]]:
        """The held datagrams due by `now`, in the order they are due."""
        out = []
        while self.held and self.held[0][0] <= now:
            _, _, data, address = heapq.heappop(self.held)
            out.append((data, address))
            self.passed += 1
        return out

    def next_due(self) -> int | None:
        return self.held[0][0] if self.held else None

    def through(self, send: Callable[[bytes, Address], None], now: int) -> Callable[[bytes, Address], None]:
        """`send` behind this direction: what is sent at `now` goes through it."""
        def degraded(data: bytes, address: Address) -> None:
            for packet, destination in self.admit(data, address, now):
                send(packet, destination)
        return degraded


class DegradedPath:
    """Both directions of a module's degraded link: to the device (O->T) and from it (T->O)."""

    def __init__(self, to_device: LinkQuality | None, from_device: LinkQuality | None, seed: int) -> None:
        rng = random.Random(seed)
        self.to_device = Direction(to_device, random.Random(rng.random())) if to_device else None
        self.from_device = Direction(from_device, random.Random(rng.random())) if from_device else None

    def next_due(self) -> int | None:
        times = [d.next_due() for d in (self.to_device, self.from_device) if d is not None]
        return min((t for t in times if t is not None), default=None)
