"""UDP 44818: ListIdentity and ListServices per device (unicast), broadcast discovery answered by
every device from its own address, and no reply to other commands."""

from __future__ import annotations

import socket
import time

from pycomm3 import CIPDriver

from enip_farm.protocol.commands import decode_identity_item, decode_service_item
from enip_farm.protocol.cpf import ItemType, decode_items
from enip_farm.protocol.encapsulation import Command, decode_frame, encode_frame


def _udp(timeout: float = 10.0) -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.settimeout(timeout)
    return sock


def test_list_identity_and_services_unicast(make_farm) -> None:
    farm = make_farm({"name": "a", "model": "DSQC1030"}, {"name": "b", "model": "DSQC1030"})
    for device in farm.devices.values():
        address = device.profile.address
        with _udp() as sock:
            sock.sendto(encode_frame(Command.LIST_IDENTITY, sender_context=b"udp-ctx!"), (address, 44818))
            data, source = sock.recvfrom(2048)
            assert source == (address, 44818)
            frame = decode_frame(data)
            assert frame.header.sender_context == b"udp-ctx!"
            (item,) = decode_items(frame.data)
            assert item.type_id == ItemType.LIST_IDENTITY
            identity = decode_identity_item(item.data)
            assert identity.socket_address.host == address and identity.socket_address.port == 44818
            assert identity.serial_number == device.profile.serial_number

            sock.sendto(encode_frame(Command.LIST_SERVICES), (address, 44818))
            (item,) = decode_items(decode_frame(sock.recvfrom(2048)[0]).data)
            assert decode_service_item(item.data).name == "Communications"


def test_other_commands_get_no_reply_over_udp(dsqc1030: str) -> None:
    with _udp() as sock:
        sock.sendto(encode_frame(Command.REGISTER_SESSION, b"\x01\x00\x00\x00"), (dsqc1030, 44818))
        sock.sendto(encode_frame(0x00C8), (dsqc1030, 44818))
        sock.sendto(b"\x63\x00", (dsqc1030, 44818))  # truncated
        sock.sendto(encode_frame(Command.LIST_IDENTITY, sender_context=b"marker!!"), (dsqc1030, 44818))
        data, _ = sock.recvfrom(2048)
        assert decode_frame(data).header.sender_context == b"marker!!"  # the only reply


def test_broadcast_list_identity_answered_by_every_device(make_farm) -> None:
    farm = make_farm(*({"name": f"d{i}", "model": "DSQC1030"} for i in range(5)), discovery=True)
    expected = {d.profile.address: d.profile.serial_number for d in farm.devices.values()}
    seen: dict[str, int] = {}
    with _udp() as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
        # sender context: MaxResponseDelay 500 ms (first UINT), then anything
        sent_at = time.monotonic()
        sock.sendto(encode_frame(Command.LIST_IDENTITY, sender_context=b"\xf4\x01covers"), ("127.255.255.255", 44818))
        deadline = time.monotonic() + 10  # done as soon as every device has answered
        while seen.keys() != expected.keys() and (remaining := deadline - time.monotonic()) > 0:
            sock.settimeout(remaining)
            try:
                data, (host, port) = sock.recvfrom(2048)
            except TimeoutError:
                break
            frame = decode_frame(data)
            identity = decode_identity_item(decode_items(frame.data)[0].data)
            if host in expected:  # another farm on this host may answer too
                assert port == 44818 and identity.socket_address.host == host  # from its own address
                assert host not in seen  # once per device
                seen[host] = identity.serial_number
                assert frame.header.sender_context == b"\xf4\x01covers"
                assert time.monotonic() - sent_at < 0.5 + 5.0  # within the delay asked for (+ a busy machine)
    assert seen == expected


def test_broadcast_replies_wait_a_random_time_up_to_the_max_response_delay() -> None:
    import random

    from enip_farm.server.udp import response_delay_s

    rng = random.Random(7)

    def delays(max_ms: int) -> list[float]:
        request = encode_frame(Command.LIST_IDENTITY, sender_context=max_ms.to_bytes(2, "little") + bytes(6))
        return [response_delay_s(request, rng) for _ in range(2000)]

    for max_ms, bound in ((0, 2.0), (100, 0.5), (1000, 1.0), (5000, 5.0)):
        spread = delays(max_ms)
        assert 0 <= min(spread) < bound / 10 and bound * 0.9 < max(spread) <= bound


def test_pycomm3_discover(make_farm, monkeypatch) -> None:
    # pycomm3 broadcasts from each address its host name resolves to; pin that to loopback
    monkeypatch.setattr(socket, "gethostname", lambda: "localhost")
    farm = make_farm({"name": "a", "model": "DSQC1030"}, {"name": "b", "model": "DSQC1030"}, discovery=True)
    expected = {d.profile.address for d in farm.devices.values()}
    found: set[str] = set()
    for _ in range(10):  # each device answers after a random delay of up to 2 s (the spec's default),
        found |= {d["ip_address"] for d in CIPDriver.discover("127.255.255.255")}  # and pycomm3 stops
        if expected <= found:  # listening after 1 s of silence: ask again, as a test engineer would
            break
    assert expected <= found
