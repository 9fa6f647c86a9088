"""UDP 2222 of one device (CIP Networks Library Vol. 2, 3-2 and 3-3): the cyclic I/O thread's
(server/implicit.py) hand on it, which moves its datagrams between the socket and the device, and
its place in the native engine where it has one (server/native.py)."""

from __future__ import annotations

import ipaddress
import logging
import socket
import time
from typing import Protocol

from enip_farm.device.device import Device
from enip_farm.protocol.connection import IO_PORT
from enip_farm.server.batch import sockaddr
from enip_farm.server.limits import RateLimitedLog
from enip_farm.server.native import NativeDevice

log = logging.getLogger("enip_farm.server.implicit")
_RETRY_NS = 10_000_000  # a device whose service raised is serviced again this much later


class IoThread(Protocol):
    """What a device's endpoint uses of the cyclic I/O thread (server/implicit.py CyclicIoThread)."""

    outbox: list[tuple[bytes, bytes, bytes]]
    outbox_from: list[DeviceIo]
    errors: RateLimitedLog

    def reschedule(self, endpoint: DeviceIo) -> None: ...


class DeviceIo:
    """UDP 2222 of one device: moves its datagrams between the socket and the device."""

    def __init__(self, device: Device, sock: socket.socket, thread: IoThread) -> None:
        self.device = device
        self.sock = sock
        self.thread = thread
        self.scheduled: int | None = None  # the wake-up the thread holds for this device (ns)
        self.source = socket.inet_aton(device.profile.address)
        self._address = (device.profile.address, IO_PORT)
        self._destinations: dict[tuple[str, int], tuple[bytes, bool]] = {}  # -> (sockaddr, unicast)
        self.native: NativeDevice | None = None  # its place in the native engine (server/native.py)
        device.timer_moved = self._timer_moved

    def _timer_moved(self) -> None:
        """A connection opened (a new stream and a new watchdog): the device's timer may be earlier."""
        self.thread.reschedule(self)

    def take(self, data: bytes, host: str, port: int, now: int, received_at: int | None = None) -> None:
        """In the I/O thread: one O->T datagram from host:port, read at `now` (`received_at`: the
        kernel's receive time), to the device."""
        device = self.device
        traffic = device.io_traffic
        traffic.received(len(data))
        recorder = device.recorder
        if recorder is not None:
            recorder.udp((host, port), self._address, data)
        try:
            taken = device.receive_io(data, (host, port), now, self.send, received_at)
        except Exception:  # last resort: the other devices' cyclic I/O goes on
            self._failed("taking an O->T datagram", now)
            taken = False
        if not taken:
            traffic.discarded()

    def service(self, now: int, horizon: int | None = None, python: bool = False) -> int | None:
        """In the I/O thread: the device's timer has come (by `horizon`); the next one. A device the
        native engine runs is served there, unless the engine hands it over (`python`: a timeout)."""
        if not python and self.native is not None and self.native.active:
            return None
        try:
            return self.device.service_io(now, self.send, horizon)
        except Exception:  # last resort: the other devices' cyclic I/O goes on
            self._failed("servicing its connections", now)
            return now + _RETRY_NS

    def timer(self) -> int | None:
        """In the I/O thread: when the device next wants servicing."""
        if self.native is not None and self.native.active:
            return self.native.timer()
        try:
            return self.device.get_timer()
        except Exception:  # last resort: the other devices' cyclic I/O goes on
            now = time.monotonic_ns()
            self._failed("computing its timer", now)
            return now + _RETRY_NS

    def _failed(self, what: str, now: int) -> None:
        """Count and log (rate-limited, with the traceback) an exception of this device's I/O."""
        self.device.counters["io_errors"] += 1
        self.thread.errors.log(logging.ERROR, f"io error {self.device.name}", now / 1e9,
                               "%s: cyclic I/O error %s", self.device.name, what, exc_info=True)

    def send(self, packet: bytes, destination: tuple[str, int]) -> None:
        """Queue a T->O packet (counted and recorded now): the thread sends a turn's packets together."""
        known = self._destinations.get(destination)
        if known is None:
            known = self._destinations[destination] = (
                sockaddr(*destination), not ipaddress.IPv4Address(destination[0]).is_multicast)
        device = self.device
        device.io_traffic.sent(len(packet), known[1])
        if device.recorder is not None:
            device.recorder.udp(self._address, destination, packet)
        thread = self.thread
        thread.outbox.append((packet, known[0], self.source))
        thread.outbox_from.append(self)

    def send_failed(self) -> None:
        self.device.counters["t_o_send_errors"] += 1
        self.device.io_traffic.send_failed()
        log.debug("%s: a T->O packet could not be sent", self.device.name)

    def close(self) -> None:
        if self.native is not None:
            self.native.detach()
        if self.device.timer_moved == self._timer_moved:
            self.device.timer_moved = None
