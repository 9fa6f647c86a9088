"""Class-1 implicit I/O on UDP 2222 (CIP Networks Library Vol. 2, 3-2 and 3-3).

All cyclic traffic of a farm runs in one I/O thread, apart from the event loop, so that neither
delays the other:
- every device address has a UDP 2222 socket (SO_REUSEADDR, so a scanner on the same host can
  still bind 0.0.0.0:2222); the thread reads O->T packets from all of them through epoll and hands
  them to their device;
- the thread sends every T->O packet on absolute deadlines (start + n x RPI, no drift). epoll waits
  in whole milliseconds, so the thread stops waiting on it a millisecond early and sleeps the rest
  with time.sleep (which wakes within a few hundred microseconds here; a Condition.wait with a
  timeout was measured 2.6 ms late at p99). A T->O connection id shared by several multicast
  connections is produced once.
Each connection's watchdog runs on the event loop (timeout = RPI x 2^(2 + multiplier); the first
one no shorter than the device's `first_watchdog_s`).
"""

from __future__ import annotations

import asyncio
import collections
import heapq
import itertools
import logging
import select
import socket
import sys
import threading
import time

from enip_farm.cip.connection import Connection
from enip_farm.device.device import Device
from enip_farm.protocol.connection import decode_io_packet, encode_io_packet
from enip_farm.server.udp import udp_socket

log = logging.getLogger(__name__)
IO_PORT = 2222
_READS_PER_WAKE = 64  # datagrams read from one socket before looking at the schedule again


def io_socket(host: str, port: int = IO_PORT) -> socket.socket:
    """UDP 2222 of one device: SO_REUSEADDR, and multicast sent from the device's own address."""
    sock = udp_socket(host, port)
    sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton(host))
    sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1)
    sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 1)
    return sock


class Production:
    """One T->O stream: a connection id, a destination and a period."""

    __slots__ = ("device", "sock", "connection_id", "address", "period", "start", "count", "sequence",
                 "users", "stopped", "late", "errors")

    def __init__(self, device: Device, sock: socket.socket, connection: Connection) -> None:
        self.device = device
        self.sock = sock
        self.connection_id = connection.t_o_id
        self.address = connection.t_o_address
        self.period = connection.t_o_rpi / 1e6
        self.start = 0.0  # set when the I/O thread takes it up
        self.count = 0  # packets due so far
        self.sequence = 0
        self.users = 1  # connections sharing this stream
        self.stopped = False
        self.late = 0  # periods skipped because the thread fell a whole period behind
        self.errors = 0

    def send(self) -> None:
        if self.device.faults.io_stopped:
            return
        self.sequence += 1
        packet = encode_io_packet(self.connection_id, self.sequence, self.sequence, self.device.produced_data())
        try:
            self.sock.sendto(packet, self.address)
            self.device.counters["t_o_packets"] += 1
            if self.device.recorder is not None:
                self.device.recorder.udp((self.device.profile.address, IO_PORT), self.address, packet)
        except OSError as error:
            self.errors += 1
            log.debug("%s: T->O send failed: %s", self.device.name, error)


class CyclicIoThread(threading.Thread):
    """Reads O->T from every device socket and sends each production at start + n x period."""

    _MAX_WAIT = 0.002  # with productions scheduled: new ones and a stop request are taken up this often
    _IDLE_WAIT = 0.02  # with none: O->T is still read at once (epoll); only a new production waits
    _EPOLL_MARGIN = 0.001  # epoll rounds its timeout up to whole milliseconds

    def __init__(self) -> None:
        super().__init__(name="enip-farm-cyclic-io", daemon=True)
        self._heap: list[tuple[float, int, Production]] = []
        self._order = itertools.count()
        self._pending: collections.deque[Production] = collections.deque()
        self._epoll = select.epoll()
        self._readers: dict[int, DeviceIo] = {}
        self._stopping = False

    def register(self, endpoint: DeviceIo) -> None:
        self._readers[endpoint.sock.fileno()] = endpoint
        self._epoll.register(endpoint.sock.fileno(), select.EPOLLIN)

    def add(self, production: Production) -> None:
        self._pending.append(production)  # deque append and popleft are thread-safe

    def stop(self) -> None:
        self._stopping = True
        if self.is_alive():
            self.join(5)
        self._epoll.close()

    def run(self) -> None:
        heap, pending, order, readers = self._heap, self._pending, self._order, self._readers
        monotonic, sleep, poll = time.monotonic, time.sleep, self._epoll.poll
        while not self._stopping:
            while pending:
                production = pending.popleft()
                production.start = monotonic()
                heapq.heappush(heap, (production.start, next(order), production))
            now = monotonic()
            while heap and heap[0][0] <= now:
                _, _, production = heapq.heappop(heap)
                if production.stopped:
                    continue
                production.send()
                production.count += 1
                due = production.start + production.count * production.period
                behind = monotonic() - due
                if behind > production.period:  # skip whole missed periods rather than burst
                    skipped = int(behind / production.period)
                    production.count += skipped
                    production.late += skipped
                    due += skipped * production.period
                heapq.heappush(heap, (due, next(order), production))
            delay = min(heap[0][0] - monotonic(), self._MAX_WAIT) if heap else self._IDLE_WAIT
            if delay > self._EPOLL_MARGIN:
                events = poll(delay - self._EPOLL_MARGIN)
            else:
                events = poll(0)
                if not events and delay > 0:
                    sleep(delay)
            for fd, _ in events:
                endpoint = readers.get(fd)
                if endpoint is not None:
                    endpoint.read()


class DeviceIo:
    """UDP 2222 of one device, and the server side of its connections (the device's observer)."""

    def __init__(self, device: Device, sock: socket.socket, thread: CyclicIoThread,
                 loop: asyncio.AbstractEventLoop) -> None:
        self.device = device
        self.sock = sock
        self.thread = thread
        self.loop = loop
        self.productions: dict[int, Production] = {}
        self.watchdogs: dict[Connection, asyncio.TimerHandle] = {}
        self.dropped = 0  # datagrams that were no valid O->T packet of a connection of this device
        device.observer = self

    def read(self) -> None:
        """In the I/O thread: consume the datagrams waiting on this device's socket."""
        recvfrom, consume = self.sock.recvfrom, self.device.consume
        for _ in range(_READS_PER_WAKE):
            try:
                data, addr = recvfrom(2048)
            except (BlockingIOError, InterruptedError):
                return
            except OSError as error:
                log.debug("%s: UDP 2222 error %s", self.device.name, error)
                return
            if self.device.recorder is not None:
                self.device.recorder.udp(addr, (self.device.profile.address, IO_PORT), data)
            packet = decode_io_packet(data)
            if packet is None or not consume(addr[0], packet):
                self.dropped += 1

    # -- ConnectionObserver (on the event loop) ---------------------------------------------------

    def opened(self, connection: Connection) -> None:
        first = connection.timeout if not connection.is_io else max(
            connection.timeout, self.device.profile.implicit.first_watchdog_s)
        self._arm(connection, connection.opened_at + first)
        if not connection.is_io:
            return
        production = self.productions.get(connection.t_o_id)
        if production is not None and not production.stopped:
            production.users += 1
            return
        production = Production(self.device, self.sock, connection)
        self.productions[connection.t_o_id] = production
        self.thread.add(production)

    def closed(self, connection: Connection) -> None:
        handle = self.watchdogs.pop(connection, None)
        if handle is not None:
            handle.cancel()
        production = self.productions.get(connection.t_o_id) if connection.is_io else None
        if production is not None:
            production.users -= 1
            if production.users <= 0:
                production.stopped = True
                del self.productions[connection.t_o_id]

    def _arm(self, connection: Connection, deadline: float) -> None:
        self.watchdogs[connection] = self.loop.call_at(
            self.loop.time() + (deadline - time.monotonic()), self._watchdog, connection)

    def _watchdog(self, connection: Connection) -> None:
        self.watchdogs.pop(connection, None)
        if connection.closed:
            return
        if connection.received:
            deadline = connection.last_received + connection.timeout
        else:
            deadline = connection.opened_at + max(connection.timeout, self.device.profile.implicit.first_watchdog_s)
        if time.monotonic() >= deadline:
            self.device.close_connection(connection, "timeout")
        else:
            self._arm(connection, deadline)

    def close(self) -> None:
        for handle in self.watchdogs.values():
            handle.cancel()
        self.watchdogs.clear()
        for production in self.productions.values():
            production.stopped = True
        self.device.observer = None


class ImplicitIo:
    """UDP 2222 of every device of a farm, and the cyclic I/O thread."""

    def __init__(self) -> None:
        self.thread = CyclicIoThread()
        self.endpoints: list[DeviceIo] = []
        self._sockets: list[socket.socket] = []
        if sys.getswitchinterval() > 0.0005:
            sys.setswitchinterval(0.0005)  # bound the I/O thread's wait for the GIL behind loop callbacks

    def add(self, device: Device) -> None:
        sock = io_socket(device.profile.address)
        self._sockets.append(sock)
        endpoint = DeviceIo(device, sock, self.thread, asyncio.get_running_loop())
        self.thread.register(endpoint)
        self.endpoints.append(endpoint)

    def start(self) -> None:
        self.thread.start()

    def close(self) -> None:
        self.thread.stop()
        for endpoint in self.endpoints:
            endpoint.close()
        self.endpoints.clear()
        for sock in self._sockets:
            sock.close()
        self._sockets.clear()
