"""What the faults' survivors of issue 32's mutation rerun asked for (device/faults.py's `_update`,
farm/faulting.py's flap, `clear` and `stop`): a degraded link's and a safety fault's effects built
as they start, a flapping link up once its count is done, a cleared flap silent, an address conflict
cleared unless the device sits on another's address, a listener that cannot bind again reported,
the fault timers cancelled by `stop`. Time is a virtual clock (an event loop whose `time()` the test
sets); no socket is opened but the one that takes an address."""

from __future__ import annotations

import socket

import pytest

from enip_farm.device.faults import DeviceFaults, Fault
from enip_farm.device.impairment import DegradedPath, LinkQuality
from enip_farm.device.safety_faults import SafetyTamper
from enip_farm.farm.farm import Farm
from enip_farm.protocol.encapsulation import ENIP_PORT
from tests.virtual_clock import VirtualClockLoop, at

NOW = 7_000_000_000


# -- device/faults.py: _update ------------------------------------------------------------------


def test_a_degraded_link_builds_its_path_as_it_starts_and_keeps_it_while_other_kinds_come_and_go() -> None:
    faults = DeviceFaults()
    assert faults.impairment is None
    faults.set(Fault("degraded-link", delay_ms=4, loss=0.25, direction="to-device", seed=3), NOW)
    path = faults.impairment
    assert isinstance(path, DegradedPath)
    assert path.to_device is not None and path.from_device is None
    assert path.to_device.quality == LinkQuality(delay_ns=4_000_000, loss=0.25, reorder_ns=20_000_000)
    faults.set(Fault("identity"), NOW + 1)
    faults.clear("identity")
    assert faults.impairment is path  # the same fault keeps what its path holds
    assert faults.clear("degraded-link") == ["degraded-link"]
    assert faults.impairment is None


@pytest.mark.parametrize(("kind", "mode"), [("safety-crc", "crc"), ("safety-stale", "stale"),
                                            ("safety-time-coordination", "time-coordination")])
def test_a_safety_fault_builds_its_tamper_as_it_starts_and_keeps_it_while_other_kinds_come_and_go(
        kind: str, mode: str) -> None:
    faults = DeviceFaults()
    faults.set(Fault("identity"), NOW)
    assert faults.safety_tamper is None
    faults.set(Fault(kind), NOW + 1)
    tamper = faults.safety_tamper
    assert isinstance(tamper, SafetyTamper) and tamper.mode == mode
    tamper.tampered = 5
    faults.clear("identity")  # another kind goes: the same tamper, its counts kept
    assert faults.safety_tamper is tamper and tamper.tampered == 5
    faults.clear(kind)
    assert faults.safety_tamper is None


# -- farm/faulting.py --------------------------------------------------------------------------------


def link_events(farm: Farm) -> list[str]:
    return [e.kind for e in farm.devices["io1"].events if e.kind in ("link down", "link up")]


def test_a_flapping_link_is_up_once_its_count_is_done(on_virtual_clock) -> None:
    async def scenario(farm: Farm, loop: VirtualClockLoop) -> None:
        faults = farm.devices["io1"].faults
        start = loop.now
        await farm.inject_fault("io1", Fault("flapping-link", period_s=1.0, duty=0.25, count=2))
        await at(loop, start)
        assert "flapping-link" not in faults.suspended and not faults.hears  # down
        await at(loop, start + 0.25)
        assert "flapping-link" in faults.suspended and faults.hears  # up
        await at(loop, start + 1.0)
        assert "flapping-link" not in faults.suspended and not faults.hears  # down again
        await at(loop, start + 1.25)
        await at(loop, start + 2.0)  # the count done: up until cleared
        assert "flapping-link" in faults.suspended and faults.hears and not faults.io_stopped
        await at(loop, start + 50.0)
        assert "flapping-link" in faults.suspended and faults.hears
        assert link_events(farm) == ["link down", "link up", "link down", "link up"]
        assert list(faults.active) == ["flapping-link"]

    on_virtual_clock(scenario)


def test_a_flapping_link_cleared_flaps_no_more(on_virtual_clock) -> None:
    async def scenario(farm: Farm, loop: VirtualClockLoop) -> None:
        start = loop.now
        await farm.inject_fault("io1", Fault("flapping-link", period_s=1.0, duty=0.5, duration_s=10.0))
        await at(loop, start + 0.25)
        assert await farm.clear_faults("io1", "flapping-link") == ["flapping-link"]
        assert farm.faults.flaps == {} and farm.faults.timers == {}
        for when in (0.5, 1.0, 1.5, 2.0, 10.0):
            await at(loop, start + when)
        assert link_events(farm) == ["link down"]
        assert [e.kind for e in farm.devices["io1"].events if e.kind.startswith("fault")] == [
            "fault injected", "fault cleared"]

    on_virtual_clock(scenario)


def test_stop_cancels_the_fault_timers(on_virtual_clock) -> None:
    async def scenario(farm: Farm, loop: VirtualClockLoop) -> None:
        faults = farm.devices["io1"].faults
        start = loop.now
        await farm.inject_fault("io1", Fault("drop", duration_s=1.0))
        farm.faults.stop()
        assert farm.faults.timers == {}
        await at(loop, start + 1.0)
        await at(loop, start + 2.0)
        assert list(faults.active) == ["drop"]  # nothing ends it once the farm stopped
        assert [e.kind for e in farm.devices["io1"].events if e.kind.startswith("fault")] == ["fault injected"]

    on_virtual_clock(scenario)


def test_an_address_conflict_clears_unless_the_device_sits_on_another_ones_address(on_virtual_clock) -> None:
    async def scenario(farm: Farm, loop: VirtualClockLoop) -> None:
        device = farm.devices["io1"]
        await farm.inject_fault("io1", Fault("address-conflict", phase="ongoing"))
        await farm.inject_fault("io1", Fault("identity"))
        assert await farm.clear_faults("io1", "address-conflict") == ["address-conflict"]
        assert [e.kind for e in device.events if e.kind == "address still taken"] == []
        farm.faults.off_network.add("io1")  # configured onto another device's address
        assert await farm.clear_faults("io1", "identity") == ["identity"]  # other kinds: as always
        await farm.inject_fault("io1", Fault("address-conflict", phase="ongoing"))
        assert await farm.clear_faults("io1") == []
        assert list(device.faults.active) == ["address-conflict"]
        assert [e.kind for e in device.events if e.kind == "address still taken"] == ["address still taken"]

    on_virtual_clock(scenario)


@pytest.mark.integration  # one socket: the one that takes the address
def test_a_listener_that_cannot_bind_again_is_reported_and_the_fault_still_clears(on_virtual_clock,
                                                                                  free_address) -> None:
    address = free_address()
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as taker:
        taker.bind((address, ENIP_PORT))
        taker.listen(1)  # someone took the address while the device was offline

        async def scenario(farm: Farm, loop: VirtualClockLoop) -> None:
            device = farm.devices["io1"]
            farm.running = True  # serving (its listener gone offline)
            await farm.inject_fault("io1", Fault("offline"))
            assert not device.faults.listens and not farm.listeners.listening("io1")
            assert await farm.clear_faults("io1", "offline") == ["offline"]
            assert not farm.listeners.listening("io1")
            taken = [e for e in device.events if e.kind == "address still taken"]
            assert len(taken) == 1 and f"{address}" in taken[0].text, taken
            assert device.faults.active == {} and device.faults.listens
            farm.running = False

        on_virtual_clock(scenario, address)
