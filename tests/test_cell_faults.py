"""Issue 28, items 2 and 4: the cell's hardware faults (device/cell_fault_kinds.py) on a device or a
group at once, as real originators see them: the `ethernetip` scanner (PyPI) for class 1 and its
Forward Open, raw encapsulation clients and UDP ListIdentity for what answers and what does not.
The kinds differ where hardware differs: after a power loss the Forward Open is answered only after
the boot time and the old TCP connections are reset; a link down keeps the module's state and TCP
connections, and its own watchdog times its connection out."""

from __future__ import annotations

import socket
import time

import httpx
import pytest

from enip_farm.config import ConfigError, parse_config
from enip_farm.device.cell_fault_kinds import FlappingLink
from enip_farm.device.faults import Fault, FaultError
from enip_farm.protocol.encapsulation import Command, encode_frame
from enip_farm.protocol.epath import ElectronicKey
from tests.helpers import ENIP_PORT, RawClient, wait_for
from tests.scanners import Scanner, start_scanner
from tests.test_implicit import forward_close, forward_open

pytestmark = [pytest.mark.integration, pytest.mark.class1_paths]  # both class-1 paths
RPI_MS = 10
BOOT_S = 1.5
SELF_TEST_S = 1.0


def rack(enip_farm, http: bool = False, **device):
    return enip_farm({"devices": [{"name": "r{n}", "count": 2, "model": "DSQC1030", "address": "127.0.0.1",
                                   "implicit": {"first_watchdog_s": 0}, **device}],
                      "groups": [{"name": "rack2", "kind": "rack", "members": ["r*"]}]}, http=http)


def scanner(address: str) -> tuple[Scanner, int]:
    """The ethernetip scanner with a class-1 connection asked (RPI 10 ms, timeout x16: 160 ms), and
    the Forward Open's status (stopped unless 0)."""
    started = start_scanner(address)
    status = started.forward_open(RPI_MS, 2)
    if status != 0:
        started.stop()
    return started, status


def list_identity_answered(address: str, timeout: float = 0.3) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.settimeout(timeout)
        sock.sendto(encode_frame(Command.LIST_IDENTITY), (address, ENIP_PORT))
        try:
            sock.recvfrom(2048)
        except TimeoutError:
            return False
        return True


def unanswered(client: RawClient, timeout: float = 0.3) -> bool:
    """A Get Attribute Single of Identity's vendor gets no reply within `timeout` (the link is silent)."""
    client.sock.settimeout(timeout)
    try:
        client.get(1, 1, 1)
    except TimeoutError:
        return True
    finally:
        client.sock.settimeout(10)
    return False


def test_a_power_loss_of_a_rack_silences_every_member_and_the_forward_open_waits_for_the_boot(enip_farm) -> None:
    farm = rack(enip_farm)
    r1, r2 = farm["r1"], farm["r2"]
    scan, status = scanner(r1.address)
    assert status == 0
    client = RawClient(r2.address, timeout=10)
    client.register()
    try:
        r1.set(DI3=1)
        r2.device.write_image("output", lambda image: image.__setitem__(0, 0xFF))
        assert wait_for(lambda: r1.device.connections)
        assert farm.inject("rack2", "power-loss", boot_time_s=BOOT_S, self_test_s=SELF_TEST_S) == ("r1", "r2")
        for handle in (r1, r2):  # every member at once, its state gone
            assert handle.device.connections == {} and handle.outputs == bytes(len(handle.outputs))
            assert [e.kind for e in handle.events("power lost")] == ["power lost"]
            assert not list_identity_answered(handle.address)
            with pytest.raises(ConnectionRefusedError):
                socket.create_connection((handle.address, ENIP_PORT), timeout=2).close()
        assert r1.get("DI3") == 1  # the field's inputs are the field's
        assert unanswered(client)  # the open TCP connection: silent, not closed
        scan.stop()
        cleared_at = time.monotonic()
        assert farm.clear("rack2", "power-loss") == ["power-loss"]
        assert client.is_closed(timeout=5)  # the rebooted stack resets what it does not know
        while True:  # the scanner tries again and again, as a controller does
            try:
                scan, status = scanner(r1.address)
                break
            except ConnectionRefusedError:
                assert time.monotonic() - cleared_at < BOOT_S + 10
                time.sleep(0.02)
        answered_after = time.monotonic() - cleared_at
        assert status == 0 and BOOT_S <= answered_after <= BOOT_S + 10
        with RawClient(r1.address) as after_boot:  # answering, still self testing, then operational
            after_boot.register()
            assert after_boot.get(1, 1, 8).data == b"\x01"
            assert wait_for(lambda: after_boot.get(1, 1, 8).data == b"\x03", timeout=SELF_TEST_S + 10)
            assert time.monotonic() - cleared_at >= BOOT_S + SELF_TEST_S
        assert [e.kind for e in r1.events() if e.kind in ("power returned", "reset done", "self test done")] == [
            "power returned", "reset done", "self test done"]
        assert wait_for(lambda: list_identity_answered(r2.address))
    finally:
        scan.stop()
        client.close()


def test_a_link_down_keeps_the_module_and_its_own_watchdog_times_the_connection_out(enip_farm) -> None:
    farm = rack(enip_farm)
    r1 = farm["r1"]
    scan, status = scanner(r1.address)
    assert status == 0
    client = RawClient(r1.address, timeout=10)
    session = client.register()
    try:
        r1.set(DI5=1)
        assert wait_for(lambda: r1.device.connections)
        injected_ns = time.monotonic_ns()
        farm.inject("r1", "link-down")
        assert not list_identity_answered(r1.address)
        assert unanswered(client)
        assert wait_for(lambda: r1.counters["connection_timeouts"] == 1, timeout=5)
        (ended,) = r1.events("connection timed out")
        assert ended.monotonic_ns > injected_ns  # its own watchdog, after the link went
        assert r1.get("DI5") == 1 and r1.device.restarts == 0  # nothing else lost
        assert farm["r2"].device.connections == {} or farm["r2"].counters["connection_timeouts"] == 0
        farm.clear("r1")
        assert client.get(1, 1, 1).general_status == 0  # the same TCP connection, the same session
        assert client.session_handle == session and list_identity_answered(r1.address)
        scan.stop()
        scan, status = scanner(r1.address)  # answered at once: no boot
        assert status == 0
    finally:
        scan.stop()
        client.close()


def test_a_flapping_link_goes_down_and_up_as_its_pattern_says(enip_farm) -> None:
    farm = rack(enip_farm)
    farm.inject("rack2", "flapping-link", period_s=0.2, duty=0.5, count=2)
    for name in ("r1", "r2"):
        handle = farm[name]
        assert wait_for(lambda h=handle: len(h.events("link up")) == 2, timeout=5)
        kinds = [e.kind for e in handle.events() if e.kind in ("link down", "link up")]
        assert kinds == ["link down", "link up", "link down", "link up"]
        times = [e.monotonic_ns for e in handle.events() if e.kind in ("link down", "link up")]
        gaps = [b - a for a, b in zip(times, times[1:], strict=False)]
        assert all(gap >= 95_000_000 for gap in gaps)  # each phase 100 ms, never shorter
    assert list_identity_answered(farm["r1"].address)  # up after the count, the fault still set
    assert [f["kind"] for f in farm["r1"].faults] == ["flapping-link"]
    farm.clear("rack2")
    assert farm["r1"].faults == []


def test_random_flapping_is_repeatable_by_its_seed() -> None:
    first = list(FlappingLink(random=True, seed=7, count=5, min_s=0.1, max_s=0.5).phases())
    assert first == list(FlappingLink(random=True, seed=7, count=5, min_s=0.1, max_s=0.5).phases())
    assert first != list(FlappingLink(random=True, seed=8, count=5, min_s=0.1, max_s=0.5).phases())
    assert all(0.1 <= s <= 0.5 for phase in first for s in phase) and len(first) == 5
    assert list(FlappingLink(period_s=2, duty=0.25, count=2).phases()) == [(0.5, 1.5), (0.5, 1.5)]
    with pytest.raises(FaultError, match=r"^max_s: must not be below min_s \(1\), got 0.5$"):
        Fault("flapping-link", random=True, min_s=1, max_s=0.5)
    with pytest.raises(FaultError, match="^remote_mac: must look like"):
        Fault("address-conflict", remote_mac="nope")


def test_with_acd_off_an_address_conflict_is_not_detected_and_the_module_keeps_answering(enip_farm) -> None:
    """SelectAcd 0 (the farm's default, unverified for ABB's modules): in neither phase does the module
    detect the conflict: attributes 1 and 11 stay as they were and it goes on answering (Vol. 2, 5-4)."""
    farm = rack(enip_farm)
    r1 = farm["r1"]
    with RawClient(r1.address) as client:
        client.register()
        assert client.get(0xF5, 1, 10).data == b"\x00"
        for phase in ("ongoing", "probe"):
            farm.inject("r1", "address-conflict", remote_mac="02:00:00:00:00:fe", phase=phase)
            assert client.get(0xF5, 1, 11).data == bytes(35)  # nothing detected
            assert client.get(0xF5, 1, 1).data == (0x01).to_bytes(4, "little")  # no AcdStatus, no AcdFault
            assert client.get(1, 1, 1).data == (75).to_bytes(2, "little") and list_identity_answered(r1.address)
            assert [f["kind"] for f in farm["r1"].faults] == ["address-conflict"]
            farm.clear("r1")
        assert [e.text for e in farm["r1"].events("address conflict")] == [
            "with 02:00:00:00:00:fe: not detected (SelectAcd, TCP/IP attribute 10, is 0)"] * 2


def test_with_acd_on_an_address_conflict_fills_in_attributes_1_and_11_and_a_probe_gives_the_address_up(
        enip_farm) -> None:
    farm = rack(enip_farm, select_acd=True)  # the configured out-of-box SelectAcd
    r1 = farm["r1"]
    mac = bytes.fromhex("0200000000fe")
    ip = socket.inet_aton(r1.address)
    arp = bytes.fromhex("0001 0800 06 04 0002") + mac + ip + r1.device.profile.mac + ip
    with RawClient(r1.address) as client:
        client.register()
        assert client.get(0xF5, 1, 10).data == b"\x01"
        assert client.get(0xF5, 1, 11).data == bytes(35)
        farm.inject("r1", "address-conflict", remote_mac="02:00:00:00:00:fe")  # ongoing: defended
        assert client.get(0xF5, 1, 1).data == (0x01 | 0x40).to_bytes(4, "little")  # AcdStatus
        assert client.get(0xF5, 1, 11).data == b"\x02" + mac + arp
        assert list_identity_answered(r1.address)
        farm.clear("r1")
        assert client.get(0xF5, 1, 1).data == (0x01).to_bytes(4, "little")
        farm.inject("r1", "address-conflict", phase="probe")  # the address given up: silent
        assert unanswered(client) and not list_identity_answered(r1.address)
        farm.clear("r1")
        assert client.get(0xF5, 1, 11).data == b"\x01" + mac + arp  # the last conflict kept: found while probing
        assert client.get(0xF5, 1, 1).data == (0x01).to_bytes(4, "little")
    assert [e.text for e in farm["r1"].events("address conflict")] == [
        "with 02:00:00:00:00:fe: address defended", "with 02:00:00:00:00:fe: address given up"]


def test_acd_set_on_by_a_client_is_what_the_next_conflict_follows(enip_farm) -> None:
    farm = rack(enip_farm)
    r1 = farm["r1"]
    with RawClient(r1.address) as client:
        client.register()
        assert client.set(0xF5, 1, 10, b"\x01").general_status == 0
        assert client.get(0xF5, 1, 10).data == b"\x01"
        farm.inject("r1", "address-conflict", phase="probe")
        assert unanswered(client) and not list_identity_answered(r1.address)
        farm.clear("r1")
        assert client.get(0xF5, 1, 11).data[:7] == b"\x01" + bytes.fromhex("0200000000fe")
        assert client.set(0xF5, 1, 10, b"\x00").general_status == 0
        farm.inject("r1", "address-conflict", phase="probe", remote_mac="02:00:00:00:00:aa")
        assert client.get(0xF5, 1, 11).data[:7] == b"\x01" + bytes.fromhex("0200000000fe")  # as it was
        assert client.get(0xF5, 1, 1).data == (0x01).to_bytes(4, "little")


def test_a_wrong_module_shows_another_identity_until_put_back(enip_farm) -> None:
    farm = rack(enip_farm)
    r1 = farm["r1"]
    code = r1.device.profile.product_code
    with RawClient(r1.address) as client:
        client.register()
        farm.inject("r1", "wrong-module", product_code=4711, major_revision=9, minor_revision=3)
        assert client.get(1, 1, 3).data == (4711).to_bytes(2, "little")
        assert client.get(1, 1, 4).data == bytes([9, 3])
        assert r1.device.identity_item().product_code == 4711
        key = ElectronicKey(75, 7, code, *r1.device.profile.revision, False)  # the module the controller expects
        refused = client.request(forward_open(key=key)[0])
        assert (refused.general_status, refused.additional_status) == (0x01, (0x0114,))  # vendor or product code
        farm.clear("r1")
        message, triad = forward_open(key=key)
        assert client.request(message).general_status == 0  # put back: the key matches again
        assert client.request(forward_close(triad)).general_status == 0
        assert client.get(1, 1, 3).data == code.to_bytes(2, "little")
        assert client.get(1, 1, 4).data == bytes(r1.device.profile.revision)


def test_a_wrong_module_with_other_sizes_refuses_the_scanners_forward_open_until_put_back(enip_farm) -> None:
    farm = rack(enip_farm)
    r1 = farm["r1"]
    code = r1.device.profile.product_code
    farm.inject("r1", "wrong-module", input_size=4, output_size=8)  # the DSQC1030's are 2 and 2
    assert r1.device.identity_item().product_code == code  # sizes given: the identity stays
    scan, status = scanner(r1.address)  # the ethernetip scanner, the module's own sizes (2 and 2)
    assert status == 0x0127  # general status 0x01: invalid O->T size
    with RawClient(r1.address) as client:
        client.register()
        refused = client.request(forward_open(o_t_size=8, t_o_size=4)[0])  # 2 + 4 + 2, 2 + 2: the right module's
        assert (refused.general_status, refused.additional_status) == (0x01, (0x0127, 14))  # 2 + 4 + 8
        refused = client.request(forward_open(o_t_size=14, t_o_size=4)[0])
        assert (refused.general_status, refused.additional_status) == (0x01, (0x0128, 6))  # 2 + 4
        farm.inject("r1", "wrong-module", input_size=4)  # another one, only its inputs differ: O->T fits
        refused = client.request(forward_open(o_t_size=8, t_o_size=4)[0])
        assert (refused.general_status, refused.additional_status) == (0x01, (0x0128, 6))
        farm.clear("r1")
        message, triad = forward_open(o_t_size=8, t_o_size=4)
        assert client.request(message).general_status == 0  # put back: the sizes match again
        assert client.request(forward_close(triad)).general_status == 0
    scan, status = scanner(r1.address)
    try:
        assert status == 0
    finally:
        scan.stop()


def test_a_group_fault_over_http_sets_every_member_and_clears_them(enip_farm) -> None:
    farm = rack(enip_farm, http=True)
    base = f"http://127.0.0.1:{farm.http.port}"
    assert httpx.get(f"{base}/groups").json() == [{"name": "rack2", "kind": "rack", "members": ["r1", "r2"]}]
    answer = httpx.post(f"{base}/groups/rack2/faults", json={"kind": "link-down", "duration_s": 30})
    assert answer.status_code == 201
    assert {name: [f["kind"] for f in faults] for name, faults in answer.json().items()} == {
        "r1": ["link-down"], "r2": ["link-down"]}
    refused = httpx.post(f"{base}/groups/rack2/faults", json={"kind": "power-loss", "boot_time_s": -1})
    assert refused.status_code == 422 and "boot_time_s: must be 0..3600 s, got -1" in refused.text
    assert httpx.post(f"{base}/groups/rack9/faults", json={"kind": "link-down"}).status_code == 404
    assert httpx.delete(f"{base}/groups/rack2/faults").json() == {"cleared": ["link-down"]}
    assert farm["r1"].faults == [] and farm["r2"].faults == []


def test_a_degraded_link_delays_what_the_scanner_sees_and_loss_times_the_connection_out(enip_farm) -> None:
    farm = rack(enip_farm)
    r1 = farm["r1"]
    scan = start_scanner(r1.address)
    try:
        assert scan.forward_open(RPI_MS, 2) == 0
        scan.conn.produce()
        farm.inject("r1", "degraded-link", delay_ms=80, direction="from-device")
        set_at = time.monotonic()
        r1.set(DI1=1)
        assert wait_for(lambda: scan.inputs[0], timeout=5)
        assert time.monotonic() - set_at >= 0.08  # the T->O that carried it was held 80 ms
        assert r1.device.connections  # O->T untouched: the connection lives
        path = r1.device.faults.impairment
        assert path.to_device is None and path.from_device.delayed > 0 and path.from_device.lost == 0
        farm.inject("r1", "degraded-link", loss=1, direction="to-device")  # every O->T lost
        assert wait_for(lambda: r1.counters["connection_timeouts"] == 1, timeout=5)
        assert r1.device.faults.impairment.to_device.lost > 0
    finally:
        scan.stop()
        farm.clear("r1")



def test_two_devices_configured_onto_one_address_the_second_finds_it_taken(enip_farm, free_address) -> None:
    with pytest.raises(ConfigError, match=r"127.0.9.1 is taken by device 'old' \(devices\[0\]\) \(here by 'new'\)"):
        parse_config({"devices": [{"name": "old", "address": "127.0.9.1", "model": "DSQC1030"},
                                  {"name": "new", "address": "127.0.9.1", "model": "DSQC1030"}]})
    address = free_address()
    farm = enip_farm({"devices": [
        {"name": "old", "address": address, "model": "DSQC1030", "identity": {"serial_number": 1111}},
        {"name": "new", "address": address, "model": "DSQC1030", "duplicate_address": True,
         "identity": {"serial_number": 4242}}]}, keep_addresses=True)
    with RawClient(address) as client:  # the address is the old module's
        client.register()
        assert client.get(1, 1, 6).data == (1111).to_bytes(4, "little")
    new = farm.device("new")
    assert [f["kind"] for f in farm["new"].faults] == ["address-conflict"]
    old_mac = farm.device("old").profile.mac
    conflict = new.hardware.objects.tcpip.last_conflict
    assert conflict[0] == 1 and conflict[1:7] == old_mac  # found while probing, the other host the old module
    assert new.hardware.objects.tcpip.acd_bits == 0x40 | 0x80  # AcdStatus, AcdFault: the address given up
    assert [e.text for e in farm["new"].events("address conflict")] == [
        f"with {old_mac.hex(':')}: address given up"]
    assert farm.clear("new") == []  # the address is still the old module's: it stays off
    assert [e.kind for e in farm["new"].events("address still taken")] == ["address still taken"]
    assert [f["kind"] for f in farm["new"].faults] == ["address-conflict"]
