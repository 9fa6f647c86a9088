"""`enip-farm learn` never misleads, and `golden` and `learn` refuse a file that is not a capture.
Each defect found on main 913aed5 is reproduced here with the farm's own recorder and real
clients, and pinned: reads of 100 and 101 on a DSQC1030+DSQC1032 gave `input: 100` (not marked
unverified), 101 in the replay table, 80 DI / 80 DO, and a clone that refused a write to 100; a
capture of two devices was merged; an empty capture gave a profile and exit 0; a file that is not a
capture ended in a traceback."""

from __future__ import annotations

import socket
import subprocess
from pathlib import Path

import dpkt
import pytest
import yaml
from pycomm3 import CIPDriver, Services

from enip_farm.capture.learn import LearnError, learn
from enip_farm.capture.packets import CaptureError
from enip_farm.config import parse_config
from enip_farm.device.profile_file import write_profile
from enip_farm.farm.farm import Farm
from enip_farm.protocol.encapsulation import Command, encode_frame
from enip_farm.pytest_plugin import AddressPool
from tests.helpers import CLI, ROOT, RawClient, forward_open_message

SEED = ROOT / "captures" / "dsqc1030_explicit_session.pcap"


def _recording(path: Path, devices: list[dict]) -> Farm:
    return Farm(parse_config({"devices": devices, "discovery": False}), record=path)


def _read(driver: CIPDriver, instance: int, attribute: int = 3) -> bytes:
    reply = driver.generic_message(service=Services.get_attribute_single, class_code=4, instance=instance,
                                   attribute=attribute, connected=False, route_path=False)
    assert reply.error is None, reply.error
    return reply.value


@pytest.mark.integration
def test_reads_of_100_and_101_learn_sizes_not_roles(free_address: AddressPool, tmp_path: Path) -> None:
    capture, address = tmp_path / "reads.pcap", free_address()
    with _recording(capture, [{"name": "io", "address": address, "model": "DSQC1030",
                               "addons": ["DSQC1032"]}]).running_in_thread():
        with CIPDriver(address) as driver:
            assert [len(_read(driver, 100)), len(_read(driver, 101))] == [10, 10]  # 16 DO + 4 AO, 16 DI + 4 AI
    (profile,) = learn(capture)
    model = profile.model
    assert profile.device == address
    assert model["assemblies"] == {"output": 100, "input": 101, "configuration": 1}
    assert model["sizes"] == {"output": 10, "input": 10, "configuration": 0}
    assert model["io"] == {}  # no 80 DI / 80 DO: the layout is not in the capture
    assert model["replay"] == []  # 101 is the input assembly, not a replayed request
    assert model["unverified"] == [
        "identity.vendor_id", "identity.device_type", "identity.product_code", "identity.revision",
        "identity.product_name", "assemblies.output", "assemblies.input", "assemblies.configuration",
        "sizes.configuration", "io layout"]
    clone = tmp_path / "clone.yaml"
    write_profile(clone, profile.document, "learned by the test", profile.notes)
    clone_address = free_address()
    with Farm(parse_config({"devices": [{"name": "clone", "address": clone_address, "model": str(clone)}],
                            "discovery": False})).running_in_thread():
        with RawClient(clone_address) as client:
            client.register()
            assert client.set(4, 100, 3, bytes(range(10))).general_status == 0  # not "attribute not settable"
            assert client.get(4, 100, 3).data == bytes(range(10))
            assert client.get(4, 101, 3).data == bytes(10)
            assert client.set(4, 101, 3, bytes(10)).general_status == 0x0E  # the input stays read-only


@pytest.mark.integration
def test_roles_from_a_set_and_a_forward_open(free_address: AddressPool, tmp_path: Path) -> None:
    """A Set on 100 makes it the output; a class-1 Forward Open gives configuration, output and input
    with their sizes, and an input-only heartbeat point; attribute 4 the configuration's size:
    nothing of them is unverified."""
    capture, address = tmp_path / "io.pcap", free_address()
    with _recording(capture, [{"name": "io", "address": address, "model": "DSQC1030", "addons": ["DSQC1031"],
                               "implicit": {"first_watchdog_s": 30}}]).running_in_thread():
        with RawClient(address) as client:
            client.register()
            assert client.set(4, 100, 3, b"\x01\x00\x00\x00").general_status == 0
            owner = forward_open_message(bytes.fromhex("20 04 24 01 2C 64 2C 65"), 2 + 4 + 4, 2 + 4, 20_000, 1)
            assert client.request(owner).general_status == 0
            heartbeat = forward_open_message(bytes.fromhex("20 04 24 01 2C C6 2C 65"), 2, 2 + 4, 20_000, 2)
            assert client.request(heartbeat).general_status == 0
            assert client.get(1, 1, service=0x01).general_status == 0  # Get Attributes All: the identity
            assert client.get(4, 1, 4).data == b"\x00\x00"  # the configuration assembly's size
    (profile,) = learn(capture)
    model = profile.model
    assert model["assemblies"] == {"output": 100, "input": 101, "configuration": 1, "input_only": 198}
    assert model["sizes"] == {"output": 4, "input": 4, "configuration": 0}
    assert model["identity"]["product_name"] == "DSQC1030" and profile.name == "DSQC1030_learned"
    assert model["unverified"] == ["io layout"] and profile.notes == ()


@pytest.mark.integration
def test_refused_requests_are_no_evidence_and_contradictions_are_noted(free_address: AddressPool,
                                                                       tmp_path: Path) -> None:
    """A Forward Open the device refused (a scanner sized for 10 output bytes) is not evidence; an
    accepted variable-size one that sized the output for 1 byte contradicts the 2 bytes read: the
    read wins, the size is unverified and the note says why."""
    capture, address = tmp_path / "odd.pcap", free_address()
    with _recording(capture, [{"name": "io", "address": address, "model": "DSQC1030",
                               "implicit": {"first_watchdog_s": 30}}]).running_in_thread():
        with RawClient(address) as client:
            client.register()
            path = bytes.fromhex("20 04 24 01 2C 64 2C 65")
            assert client.request(forward_open_message(path, 2 + 4 + 10, 2 + 2, 20_000, 1)).additional_status == (
                0x0127, 8)
            variable = forward_open_message(path, 2 + 4 + 1, 2 + 2, 20_000, 2, variable=True)
            assert client.request(variable).general_status == 0
            assert len(client.get(4, 100, 3).data) == 2
    (profile,) = learn(capture)
    assert profile.model["assemblies"] == {"output": 100, "input": 101, "configuration": 1}
    assert profile.model["sizes"] == {"output": 2, "input": 2, "configuration": 0}
    assert "sizes.output" in profile.model["unverified"] and "assemblies.output" not in profile.model["unverified"]
    assert profile.notes == ("assembly 100: read or written 2 bytes, connection sized for 1",)


@pytest.mark.integration
def test_one_profile_per_captured_device(free_address: AddressPool, tmp_path: Path) -> None:
    capture, first, second = tmp_path / "two.pcap", free_address(), free_address()
    devices = [{"name": "a", "address": first, "model": "DSQC1030", "identity": {"serial_number": 0xA}},
               {"name": "b", "address": second, "model": "DSQC1030", "addons": ["DSQC1031"],
                "identity": {"serial_number": 0xB}}]
    with _recording(capture, devices).running_in_thread():
        for address in (first, second):
            with CIPDriver(address) as driver:
                driver.generic_message(service=Services.get_attributes_all, class_code=1, instance=1,
                                       connected=False, route_path=False)
                _read(driver, 101)
    profiles = learn(capture)
    assert [(p.device, p.name) for p in profiles] == [
        (first, f"DSQC1030_{first.replace('.', '_')}"), (second, f"DSQC1030_{second.replace('.', '_')}")]
    assert [p.model["identity"]["serial_number"] for p in profiles] == [0xA, 0xB]  # never merged
    assert [p.model["sizes"]["input"] for p in profiles] == [2, 4]
    (only,) = learn(capture, device=second, name="SECOND")
    assert (only.name, only.model["identity"]["serial_number"]) == ("SECOND", 0xB)
    with pytest.raises(LearnError, match=f"holds 2 devices \\({first}, {second}\\): --name names one"):
        learn(capture, name="X")
    with pytest.raises(LearnError, match=f"no device 127.1.2.3; the capture holds {first}, {second}$"):
        learn(capture, device="127.1.2.3")


@pytest.mark.system
def test_learn_cli_with_several_devices(free_address: AddressPool, tmp_path: Path) -> None:
    capture, first, second = tmp_path / "two.pcap", free_address(), free_address()
    with _recording(capture, [{"name": "a", "address": first, "model": "DSQC1030"},
                              {"name": "b", "address": second, "model": "DSQC1030"}]).running_in_thread():
        for address in (first, second):
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as udp:
                udp.settimeout(10)
                udp.sendto(encode_frame(Command.LIST_IDENTITY), (address, 44818))
                udp.recv(1024)
    one_file = subprocess.run([*CLI, "learn", str(capture), "-o", str(tmp_path / "p.yaml")], capture_output=True,
                              text=True, timeout=120)
    assert one_file.returncode == 2 and not (tmp_path / "p.yaml").exists()
    assert one_file.stderr == (f"{capture} holds 2 devices ({first}, {second}): give -o a directory for one "
                               "profile each, or --device IP\n")
    each = subprocess.run([*CLI, "learn", str(capture), "-o", str(tmp_path / "learned")], capture_output=True,
                          text=True, timeout=120)
    assert each.returncode == 0, each.stderr
    files = sorted(p.name for p in (tmp_path / "learned").iterdir())
    assert files == sorted(f"DSQC1030_{a.replace('.', '_')}.yaml" for a in (first, second))
    picked = subprocess.run([*CLI, "learn", str(capture), "-o", str(tmp_path / "b.yaml"), "--device", second],
                            capture_output=True, text=True, timeout=120)
    assert picked.returncode == 0, picked.stderr
    assert yaml.safe_load((tmp_path / "b.yaml").read_text())["models"]["DSQC1030_learned"]["description"] == (
        f"learned from two.pcap (device {second})")


def _not_captures(tmp_path: Path) -> list[tuple[Path, str]]:
    empty = tmp_path / "empty.pcap"
    empty.write_bytes(b"")
    header_only = tmp_path / "header.pcap"
    with open(header_only, "wb") as handle:
        dpkt.pcap.Writer(handle)  # a valid capture with no packet
    cut = tmp_path / "cut.pcap"
    cut.write_bytes(SEED.read_bytes()[:30])
    return [(empty, f"{empty}: not a pcap or pcapng capture (an empty file)"),
            (ROOT / "README.md", f"{ROOT / 'README.md'}: not a pcap or pcapng capture (invalid tcpdump header)"),
            (cut, f"{cut}: capture cut short after 0 packets (got 6, 16 needed at least)"),
            (tmp_path / "missing.pcap", f"{tmp_path / 'missing.pcap'}: No such file or directory"),
            (header_only, None)]


@pytest.mark.system
def test_learn_and_golden_refuse_a_file_that_is_not_a_capture(tmp_path: Path) -> None:
    for path, message in _not_captures(tmp_path):
        learned = subprocess.run([*CLI, "learn", str(path), "-o", str(tmp_path / "p.yaml")], capture_output=True,
                                 text=True, timeout=120)
        golden = subprocess.run([*CLI, "golden", str(path), "--address", "127.0.0.1"], capture_output=True,
                                text=True, timeout=120)
        if message is None:  # a capture without EtherNet/IP traffic
            assert learned.stderr == f"{path}: no EtherNet/IP traffic on port 44818 in 0 packets\n"
            assert golden.stderr == f"{path}: no EtherNet/IP exchanges on port 44818\n"
        else:
            assert learned.stderr == golden.stderr == message + "\n"
        assert learned.returncode == golden.returncode == 2 and golden.stdout == learned.stdout == ""
        assert not (tmp_path / "p.yaml").exists()


def test_learn_raises_one_line_errors(tmp_path: Path) -> None:
    for path, message in _not_captures(tmp_path):
        with pytest.raises(LearnError if message is None else CaptureError) as error:
            learn(path)
        assert str(error.value) == (message or f"{path}: no EtherNet/IP traffic on port 44818 in 0 packets")
