"""Issue 28, item 2: a degraded link's directions (device/impairment.py), sans-IO, seeded: what is
lost, held, doubled and reordered, each held datagram out at its due time and not a tick before."""

from __future__ import annotations

import random

from enip_farm.device.faults import Fault
from enip_farm.device.impairment import DegradedPath, Direction, LinkQuality

MS = 1_000_000


def test_a_delay_holds_each_datagram_to_its_tick() -> None:
    direction = Direction(LinkQuality(delay_ns=5 * MS), random.Random(0))
    assert direction.admit(b"a", "x", 100) == [] and direction.next_due() == 100 + 5 * MS
    assert direction.admit(b"b", "x", 200) == []
    assert direction.due(100 + 5 * MS - 1) == []
    assert direction.due(100 + 5 * MS) == [(b"a", "x")]
    assert direction.due(10**12) == [(b"b", "x")] and direction.next_due() is None
    assert (direction.passed, direction.delayed, direction.lost) == (2, 2, 0)


def test_loss_duplication_and_reordering_follow_their_shares_and_the_seed() -> None:
    def run(seed: int) -> tuple[list[bytes], tuple[int, ...]]:
        direction = Direction(LinkQuality(delay_ns=MS, loss=0.2, duplicate=0.1, reorder=0.1, reorder_ns=25 * MS),
                              random.Random(seed))
        out: list[bytes] = []
        for i in range(1000):
            out += [d for d, _ in direction.admit(i.to_bytes(2, "big"), "x", i * 10 * MS)]
            out += [d for d, _ in direction.due(i * 10 * MS)]
        out += [d for d, _ in direction.due(10**15)]
        return out, (direction.lost, direction.duplicated, direction.reordered)

    out, (lost, duplicated, reordered) = run(7)
    assert run(7) == (out, (lost, duplicated, reordered)) and run(8)[0] != out  # the seed decides
    assert 150 <= lost <= 250 and 50 <= duplicated <= 130 and 50 <= reordered <= 150
    assert len(out) == 1000 - lost + duplicated
    numbers = [int.from_bytes(d, "big") for d in out]
    assert numbers != sorted(numbers)  # held 25 ms, past the next two: overtaken


def test_a_degraded_link_fault_makes_a_path_one_or_both_ways() -> None:
    both = Fault("degraded-link", delay_ms=3, seed=1).impairment()
    assert isinstance(both, DegradedPath) and both.to_device and both.from_device
    assert both.to_device.quality == LinkQuality(delay_ns=3 * MS, reorder_ns=20 * MS)
    one = Fault("degraded-link", loss=1, direction="to-device").impairment()
    assert one.from_device is None and one.to_device.admit(b"x", "y", 0) == [] and one.to_device.lost == 1
    assert Fault("degraded-link", loss=1, seed=4).on_reply() == 200 * MS  # a lost segment: its retransmission
