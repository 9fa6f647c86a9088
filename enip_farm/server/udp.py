"""UDP 44818 (CIP Networks Library Vol. 2, 2-2.2): a socket per device for unicast ListIdentity
and ListServices, and one discovery responder on 0.0.0.0:44818 that answers a broadcast
ListIdentity for every device, each reply sent from that device's own socket and address. A device
that is offline (a fault) or in its reset window (Identity Reset) answers nothing. Datagrams in and
out are counted in the device's interface counters (Ethernet Link attribute 4)."""

from __future__ import annotations

import asyncio
import ipaddress
import logging
import random
import socket
import struct

from enip_farm.device.device import Device
from enip_farm.protocol.encapsulation import ENIP_PORT
from enip_farm.protocol.session import handle_datagram
from enip_farm.server.waits import os_wait_s

log = logging.getLogger(__name__)

#: Linux's IP_PKTINFO (socket.IP_PKTINFO exists only from Python 3.12).
IP_PKTINFO = getattr(socket, "IP_PKTINFO", 8)
_IN_PKTINFO = struct.Struct("=i4s4s")  # ifindex, spec_dst, addr (the datagram's destination)
_LIMITED_BROADCAST = ipaddress.IPv4Address("255.255.255.255")
_LOOPBACK = ipaddress.IPv4Network("127.0.0.0/8")


def udp_socket(host: str, port: int = ENIP_PORT) -> socket.socket:
    """A UDP socket with SO_REUSEADDR, so device sockets and a wildcard socket share the port."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.setblocking(False)
        sock.bind((host, port))
    except OSError:
        sock.close()
        raise
    return sock


class DeviceDatagramProtocol(asyncio.DatagramProtocol):
    def __init__(self, device: Device) -> None:
        self.device = device
        self.transport: asyncio.DatagramTransport | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        self.device.traffic.received(len(data))
        recorder = self.device.recorder
        if recorder is not None:
            recorder.udp(addr, (self.device.profile.address, ENIP_PORT), data)
        self.answer(data, addr)

    def answer(self, data: bytes, addr: tuple[str, int]) -> None:
        device = self.device
        if not device.faults.answers_udp or device.resetting:
            device.traffic.discarded()
            return
        reply = handle_datagram(device, data)
        if reply is not None and self.transport is not None:
            self.transport.sendto(reply, addr)
            device.traffic.sent(len(reply))
            if device.recorder is not None:
                device.recorder.udp((device.profile.address, ENIP_PORT), addr, reply)

    def error_received(self, exc: Exception) -> None:
        log.debug("%s: UDP error %s", self.device.name, exc)


def broadcast_addresses(device: Device) -> frozenset[ipaddress.IPv4Address]:
    """The destinations a device treats as a broadcast to it."""
    address = ipaddress.IPv4Address(device.profile.address)
    network = ipaddress.IPv4Network(f"{address}/{device.profile.netmask}", strict=False)
    found = {_LIMITED_BROADCAST, network.broadcast_address}
    if address in _LOOPBACK:
        found.add(_LOOPBACK.broadcast_address)
    return frozenset(found)


#: ListIdentity's MaxResponseDelay (Vol. 2, 2-4.2.3, as OpENer reads it: the first UINT of the
#: sender context, milliseconds): 0 means 2000 ms; less than 500 ms counts as 500 ms.
DEFAULT_MAX_RESPONSE_DELAY_MS = 2000
MIN_MAX_RESPONSE_DELAY_MS = 500


def response_delay_s(datagram: bytes, rng: random.Random) -> float:
    """How long a device waits before it answers a broadcast ListIdentity: a random time up to
    the request's MaxResponseDelay, so that a cell of devices does not answer in one burst."""
    max_ms = int.from_bytes(datagram[12:14], "little") if len(datagram) >= 14 else 0
    if max_ms == 0:
        max_ms = DEFAULT_MAX_RESPONSE_DELAY_MS
    max_ms = max(max_ms, MIN_MAX_RESPONSE_DELAY_MS)
    return rng.uniform(0, max_ms / 1000)


class DiscoveryResponder:
    """Reads datagrams sent to 0.0.0.0:44818 with their destination address (IP_PKTINFO) and
    hands each broadcast to the device endpoints it concerns, each after its own random delay."""

    def __init__(self, loop: asyncio.AbstractEventLoop, endpoints: list[DeviceDatagramProtocol]) -> None:
        self.loop = loop
        self._rng = random.Random()
        self._pending: set[asyncio.TimerHandle] = set()
        self.endpoints = [(endpoint, broadcast_addresses(endpoint.device)) for endpoint in endpoints]
        self.sock = udp_socket("0.0.0.0")
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
        self.sock.setsockopt(socket.IPPROTO_IP, IP_PKTINFO, 1)
        loop.add_reader(self.sock.fileno(), self._readable)

    def _readable(self) -> None:
        for _ in range(64):  # bounded batch per wake-up
            try:
                data, ancillary, _flags, addr = self.sock.recvmsg(2048, socket.CMSG_SPACE(_IN_PKTINFO.size))
            except (BlockingIOError, InterruptedError):
                return
            except OSError as error:
                log.debug("discovery: %s", error)
                return
            destination = None
            for level, kind, payload in ancillary:
                if level == socket.IPPROTO_IP and kind == IP_PKTINFO:
                    destination = ipaddress.IPv4Address(_IN_PKTINFO.unpack_from(payload)[2])
            if destination is None:
                continue
            recorded = False
            for endpoint, broadcasts in self.endpoints:
                if not recorded and destination in broadcasts and endpoint.device.recorder is not None:
                    endpoint.device.recorder.udp(addr, (str(destination), ENIP_PORT), data)  # the broadcast, once
                    recorded = True
                if destination in broadcasts:
                    endpoint.device.traffic.received(len(data), unicast=False)
                    self._answer_later(endpoint, data, addr)

    def _answer_later(self, endpoint: DeviceDatagramProtocol, data: bytes, addr: tuple[str, int]) -> None:
        def answer() -> None:
            self._pending.discard(handle)
            endpoint.answer(data, addr)

        handle = self.loop.call_later(os_wait_s(response_delay_s(data, self._rng)), answer)
        self._pending.add(handle)

    def close(self) -> None:
        for handle in self._pending:
            handle.cancel()
        self._pending.clear()
        self.loop.remove_reader(self.sock.fileno())
        self.sock.close()
