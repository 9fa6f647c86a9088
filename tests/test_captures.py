"""Captures: the seed's session rebuilt as pcap, golden replay against the farm, recording the
farm's traffic (checked by tshark), and learning a profile from a capture."""

from __future__ import annotations

import shutil
import subprocess
import sys
import zlib
from pathlib import Path

import dpkt
import pytest
import yaml
from pycomm3 import CIPDriver, Services

from enip_farm.capture.exchanges import load_exchanges
from enip_farm.capture.learn import learn
from enip_farm.capture.packets import read_capture
from enip_farm.capture.recorder import Recorder
from enip_farm.config import parse_config
from enip_farm.farm.farm import Farm
from enip_farm.protocol.cip import encode_request
from enip_farm.protocol.commands import IdentityItem, SocketAddress, encode_identity_item, encode_send_rr_data
from enip_farm.protocol.cpf import ItemType, encode_items
from enip_farm.protocol.encapsulation import HEADER, Command, encode_frame
from enip_farm.protocol.epath import encode_request_path
from enip_farm.pytest_plugin import AddressPool
from tests.helpers import CLI, ROOT, STARTUP_S, RawClient, serving

SEED = ROOT / "captures" / "dsqc1030_explicit_session.pcap"
SEED_LENGTHS = [66, 60, 54, 82, 86, 104, 102, 102, 104, 78, 54, 60]  # frames 4-15, seed-facts.md


def _config(tmp_path: Path, devices: list[dict], name: str = "cell.yaml") -> Path:
    path = tmp_path / name
    path.write_text(yaml.safe_dump({"devices": devices, "discovery": False}))
    return path


def _golden(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([*CLI, "golden", *args], capture_output=True, text=True, timeout=120)


@pytest.mark.system
def test_seed_capture_is_rebuilt_from_the_data_file(tmp_path: Path) -> None:
    rebuilt = tmp_path / "seed.pcap"
    subprocess.run([sys.executable, str(ROOT / "captures" / "build_seed_capture.py"), str(rebuilt)], check=True,
                   capture_output=True, timeout=60)
    assert rebuilt.read_bytes() == SEED.read_bytes()
    with open(SEED, "rb") as handle:
        frames = [buf for _, buf in dpkt.pcap.Reader(handle)]
    assert [len(f) for f in frames] == SEED_LENGTHS
    captured = yaml.safe_load((ROOT / "captures" / "seed_session.yaml").read_text())["captured"]
    assert frames[1] == bytes.fromhex(captured[5]) and frames[4] == bytes.fromhex(captured[8])


@pytest.mark.system
def test_golden_seed_against_a_default_dsqc1030(free_address: AddressPool, tmp_path: Path) -> None:
    config = _config(tmp_path, [{"name": "io1", "address": free_address(), "model": "DSQC1030"}])
    result = _golden(str(SEED), "--config", str(config), "--device", "io1")
    assert result.returncode == 0, result.stdout + result.stderr
    assert result.stdout.count("PASS") == 4 and "4 exchanges: 4 passed, 0 failed" in result.stdout


def _with_damaged_frames(path: Path) -> Path:
    """The seed capture with three damaged frames between its own: one cut inside its Ethernet
    header, one whose IPv4 header is cut, one whose TCP header is cut."""
    with open(SEED, "rb") as handle:
        frames = list(dpkt.pcap.Reader(handle))
    ethernet = frames[0][1][:14]
    ip = dpkt.ip.IP(src=b"\x7f\0\0\x01", dst=b"\x7f\0\0\x02", p=dpkt.ip.IP_PROTO_TCP, data=b"\x01\x02\x03")
    ip.len = len(ip)
    damaged = [ethernet[:5], ethernet + bytes(ip)[:10], ethernet + bytes(ip)]
    with open(path, "wb") as handle:
        writer = dpkt.pcap.Writer(handle)
        for index, (timestamp, buf) in enumerate(frames):
            writer.writepkt(buf, timestamp)
            if index < len(damaged):
                writer.writepkt(damaged[index], timestamp)
    return path


def test_damaged_frames_are_skipped_and_counted(tmp_path: Path) -> None:
    capture = read_capture(_with_damaged_frames(tmp_path / "damaged.pcap"))
    assert capture.damaged == 3  # was skipped uncounted
    assert capture.packets == read_capture(SEED).packets and read_capture(SEED).damaged == 0
    [profile] = learn(tmp_path / "damaged.pcap")
    assert profile.notes[-1] == ("3 damaged frames of the capture skipped (dpkt could not decode them): what they "
                                 "held is not learned")
    assert not any("damaged" in note for note in learn(SEED)[0].notes)


@pytest.mark.system
def test_golden_summary_counts_damaged_frames(free_address: AddressPool, tmp_path: Path) -> None:
    config = _config(tmp_path, [{"name": "io1", "address": free_address(), "model": "DSQC1030"}])
    capture = _with_damaged_frames(tmp_path / "damaged.pcap")
    result = _golden(str(capture), "--config", str(config), "--device", "io1")
    assert result.returncode == 0, result.stdout + result.stderr
    assert result.stdout.splitlines()[-1] == "4 exchanges: 4 passed, 0 failed, 3 damaged frames skipped"


@pytest.mark.system
def test_golden_names_the_field_that_differs(free_address: AddressPool, tmp_path: Path) -> None:
    with open(SEED, "rb") as handle:
        frames = [(ts, bytearray(buf)) for ts, buf in dpkt.pcap.Reader(handle)]
    frames[8][1][-2] = 0x11  # frame 12: the Get reply's data 10 00 -> 11 00
    edited = tmp_path / "edited.pcap"
    with open(edited, "wb") as handle:
        writer = dpkt.pcap.Writer(handle)
        for ts, buf in frames:
            writer.writepkt(bytes(buf), ts=ts)
    config = _config(tmp_path, [{"name": "io1", "address": free_address(), "model": "DSQC1030"}])
    result = _golden(str(edited), "--config", str(config), "--device", "io1")
    assert result.returncode == 1
    assert "FAIL  tcp stream 1 #3 SEND_RR_DATA  cip.data: captured 11 00 != farm 10 00" in result.stdout
    assert "3 passed, 1 failed" in result.stdout


def _record_a_session(free_address: AddressPool, tmp_path: Path) -> tuple[Path, list[str]]:
    addresses = [free_address(), free_address()]
    recording = tmp_path / "farm.pcap"
    config = parse_config({"devices": [{"name": n, "address": a, "model": "DSQC1030"}
                                       for n, a in zip(("a", "b"), addresses, strict=True)], "discovery": False})
    farm = Farm(config, record=recording)
    with farm.running_in_thread():
        with CIPDriver(addresses[0]) as driver:
            driver.generic_message(service=Services.set_attribute_single, class_code=4, instance=100, attribute=3,
                                   request_data=b"\x10\x00", connected=False, route_path=False)
            driver.generic_message(service=Services.get_attribute_single, class_code=4, instance=100, attribute=3,
                                   connected=False, route_path=False)
            driver.generic_message(service=Services.get_attributes_all, class_code=1, instance=1, connected=False,
                                   route_path=False)
            driver.generic_message(service=Services.get_attribute_single, class_code=4, instance=77, attribute=3,
                                   connected=False, route_path=False)  # an error reply is golden too
        with RawClient(addresses[1]) as c:
            c.register()
            c.get(0xF5, 1, 5)
            c.send(encode_frame(Command.NOP))
        import socket

        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as udp:
            udp.settimeout(10)
            udp.sendto(encode_frame(Command.LIST_IDENTITY, sender_context=b"recorded"), (addresses[1], 44818))
            udp.recv(1024)
    return recording, addresses


@pytest.mark.system
def test_recording_replays_as_golden_against_the_farm(free_address: AddressPool, tmp_path: Path, enip_farm) -> None:
    recording, addresses = _record_a_session(free_address, tmp_path)
    groups = load_exchanges(recording)
    assert [g[0].transport for g in groups] == ["tcp", "tcp", "udp"]
    same = _config(tmp_path, [{"name": n, "address": a, "model": "DSQC1030"}
                              for n, a in zip(("a", "b"), addresses, strict=True)])
    result = _golden(str(recording), "--config", str(same), "--map", f"{addresses[0]}=a", "--map",
                     f"{addresses[1]}=b")
    assert result.returncode == 0, result.stdout + result.stderr
    # beside a farm serving those addresses: golden moves to its own, with the same serial numbers
    enip_farm(str(same), keep_addresses=True)
    beside = _golden(str(recording), "--config", str(same), "--map", f"{addresses[0]}=a", "--map",
                     f"{addresses[1]}=b")
    assert (beside.returncode, beside.stdout) == (0, result.stdout), beside.stdout + beside.stderr
    # the same capture, answered by farm devices on other addresses (the socket address is masked)
    serials = [zlib.crc32(bytes(map(int, a.split(".")))) for a in addresses]  # the originals' default serials
    moved = _config(tmp_path, [{"name": n, "address": free_address(), "model": "DSQC1030",
                                "identity": {"serial_number": serial}}
                               for n, serial in zip(("x", "y"), serials, strict=True)], "moved.yaml")
    result = _golden(str(recording), "--config", str(moved), "--map", f"{addresses[0]}=x", "--map",
                     f"{addresses[1]}=y")
    assert result.returncode == 0, result.stdout + result.stderr
    assert "passed, 0 failed" in result.stdout


@pytest.mark.system
@pytest.mark.skipif(shutil.which("tshark") is None, reason="tshark (Debian) is not installed; .ci/run installs it")
def test_tshark_finds_nothing_wrong_in_a_recording(free_address: AddressPool, tmp_path: Path) -> None:
    recording, _ = _record_a_session(free_address, tmp_path)
    expert = subprocess.run(["tshark", "-r", str(recording), "-q", "-z", "expert"], capture_output=True, text=True,
                            timeout=120)
    assert expert.returncode == 0, expert.stderr
    assert "Errors (" not in expert.stdout and "Warnings (" not in expert.stdout, expert.stdout
    listing = subprocess.run(["tshark", "-r", str(recording)], capture_output=True, text=True, timeout=120).stdout
    assert "Malformed" not in listing and "Register Session (Rsp)" in listing and "List Identity (Rsp)" in listing
    assert "Success: Assembly - Set Attribute Single" in listing


@pytest.mark.system
def test_learned_seed_profile_replays_the_seed_byte_for_byte(free_address: AddressPool, tmp_path: Path) -> None:
    profile = tmp_path / "learned.yaml"
    learned = subprocess.run([*CLI, "learn", str(SEED), "-o", str(profile)], capture_output=True, text=True,
                             timeout=120)
    assert learned.returncode == 0, learned.stderr
    model = next(iter(yaml.safe_load(profile.read_text())["models"].values()))
    assert model["assemblies"]["output"] == 100 and model["sizes"]["output"] == 2
    assert "identity.vendor_id" in model["unverified"] and "sizes.input" in model["unverified"]
    address = free_address()
    config = _config(tmp_path, [{"name": "io1", "address": address, "model": "learned.yaml"}])
    farm = Farm(parse_config(yaml.safe_load(config.read_text()), str(config), tmp_path))
    (stream,) = load_exchanges(SEED)
    with farm.running_in_thread(), RawClient(address) as client:
        for exchange in stream:
            client.send(exchange.raw_request)
            if exchange.reply is not None:
                live, captured = client.recv_frame(), exchange.reply
                assert HEADER.pack(*live.header) + live.data == HEADER.pack(*captured.header) + captured.data
    golden = _golden(str(SEED), "--config", str(config), "--device", "io1")
    assert golden.returncode == 0, golden.stdout


@pytest.mark.system
def test_learn_identity_assemblies_and_replay_table(free_address: AddressPool, tmp_path: Path) -> None:
    """A synthetic capture of a device with an object the model lacks (class 0x300)."""
    capture = tmp_path / "other.pcap"
    device, client = ("192.168.125.77", 44818), ("192.168.125.5", 50000)  # data in a file, never a target
    recorder = Recorder(capture)
    identity = IdentityItem(1, SocketAddress(device[0], 44818), 75, 12, 9999, 3, 4, 0x30, 0xC0FFEE, "MYDEV", 3)
    recorder.udp(client, device, encode_frame(Command.LIST_IDENTITY))
    recorder.udp(device, client, encode_frame(Command.LIST_IDENTITY,
                                              encode_items([(ItemType.LIST_IDENTITY, encode_identity_item(identity))])))
    recorder.tcp_opened("s", client, device)
    exchanges = [
        (encode_frame(Command.REGISTER_SESSION, b"\x01\x00\x00\x00"),
         encode_frame(Command.REGISTER_SESSION, b"\x01\x00\x00\x00", 1)),
        (encode_send_rr_data(encode_request(0x0E, encode_request_path(0x300, 1, 1)), 1),
         encode_send_rr_data(bytes.fromhex("8e 00 00 00 ab cd"), 1)),
        (encode_send_rr_data(encode_request(0x10, encode_request_path(4, 150, 3), b"\x01\x02\x03\x04"), 1),
         encode_send_rr_data(bytes.fromhex("90 00 00 00"), 1)),
    ]
    for request, reply in exchanges:
        recorder.tcp_data("s", True, request)
        recorder.tcp_data("s", False, reply)
    recorder.tcp_closed("s", by_client=True)
    recorder.close()

    profile = tmp_path / "mydev.yaml"
    assert subprocess.run([*CLI, "learn", str(capture), "-o", str(profile)], capture_output=True,
                          timeout=120).returncode == 0
    model = yaml.safe_load(profile.read_text())["models"]["MYDEV"]
    assert model["identity"] == {"vendor_id": 75, "device_type": 12, "product_code": 9999, "revision": [3, 4],
                                 "product_name": "MYDEV", "serial_number": 0xC0FFEE}
    assert model["assemblies"]["output"] == 150 and model["sizes"]["output"] == 4
    assert model["replay"] == [{"service": 0x0E, "path": encode_request_path(0x300, 1, 1).hex(), "data": "",
                                "reply": "8e000000abcd"}]
    config = _config(tmp_path, [{"name": "d", "address": free_address(), "model": str(profile)}])
    result = _golden(str(capture), "--config", str(config), "--device", "d")
    assert result.returncode == 0, result.stdout + result.stderr
    assert "udp #1 LIST_IDENTITY" in result.stdout


@pytest.mark.system
def test_a_killed_farm_leaves_a_readable_recording(free_address: AddressPool, tmp_path: Path) -> None:
    import signal

    address = free_address()
    config = _config(tmp_path, [{"name": "io1", "address": address, "model": "DSQC1030"}])
    recording = tmp_path / "killed.pcap"
    with serving(["serve", "--config", str(config), "--record", str(recording)], table_rows=1) as (server, _):
        with RawClient(address) as client:
            client.register()
            assert client.get(4, 100, 3).general_status == 0
            server.send_signal(signal.SIGKILL)  # no chance to close the file
            server.wait(timeout=STARTUP_S)
    (stream,) = load_exchanges(recording)
    assert [e.request.header.command for e in stream] == [Command.REGISTER_SESSION, Command.SEND_RR_DATA]
    assert all(e.reply is not None for e in stream)


@pytest.mark.system
@pytest.mark.skipif(shutil.which("editcap") is None, reason="editcap (Debian, with tshark) is not installed")
def test_golden_reads_pcapng_and_replays_against_a_running_farm(tmp_path: Path, enip_farm) -> None:
    pcapng = tmp_path / "seed.pcapng"
    subprocess.run(["editcap", "-F", "pcapng", str(SEED), str(pcapng)], check=True, capture_output=True, timeout=60)
    assert pcapng.read_bytes()[:4] == b"\x0a\x0d\x0d\x0a"
    address = enip_farm(name="io1", model="DSQC1030")["io1"].address  # a farm already running
    result = _golden(str(pcapng), "--address", address)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "4 exchanges: 4 passed, 0 failed" in result.stdout
