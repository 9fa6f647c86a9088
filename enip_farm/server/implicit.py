"""Class-1 implicit I/O on UDP 2222 (CIP Networks Library Vol. 2, 3-2 and 3-3): the sockets and
the one thread that moves the datagrams. The connections themselves (consumption, production
schedule, supervision) are the devices' sans-IO connection tables (cip/connection_table.py).

All cyclic traffic of a farm runs in one I/O thread, apart from the event loop, so that neither
delays the other, and it is the only place that sleeps:
- every device address has a UDP 2222 socket (SO_REUSEADDR, so a scanner on the same host can
  still bind 0.0.0.0:2222); the thread reads O->T datagrams from all of them through epoll and
  hands them to their device with the time they were read;
- every datagram in and out is counted in the device's interface counters (Ethernet Link
  attribute 4), by this thread alone (`Device.io_traffic`);
- it keeps one timer per device, the one its table asks for (`get_timer`): at that time it lets
  the device supervise its connections and send the T->O packets due (`Device.service_io`). A
  Forward Open on the event loop wakes the thread through a pipe. epoll waits in whole
  milliseconds, so the thread stops waiting on it a millisecond early and sleeps the rest with
  time.sleep (which wakes within a few hundred microseconds here; a Condition.wait with a timeout
  was measured 2.6 ms late at p99).
- one device's bug does not stop the others: an exception while it takes a datagram or services
  its connections is counted (`io_errors`) and logged with its traceback (rate-limited per device,
  `RateLimitedLog`), and its timer is tried again `_RETRY_NS` later.
- nothing stops the thread itself: an unexpected exception of the loop is counted (`loop_errors`),
  logged once per 10 s with its traceback, and the loop goes on; every wait it hands epoll or sleep
  is bounded (server/waits.py); `running` says whether the loop turned within `_STALL_NS`, which the
  farm's health (the API's /health, the container's health check) reports.
"""

from __future__ import annotations

import collections
import heapq
import ipaddress
import itertools
import logging
import os
import select
import socket
import sys
import threading
import time

from enip_farm.device.device import Device
from enip_farm.device.events import Event
from enip_farm.server.limits import RateLimitedLog
from enip_farm.server.udp import udp_socket
from enip_farm.server.waits import os_wait_ns

log = logging.getLogger(__name__)
IO_PORT = 2222
_READS_PER_WAKE = 64  # datagrams read from one socket before looking at the schedule again
_RETRY_NS = 10_000_000  # a device whose service raised is serviced again this much later


def io_socket(host: str, port: int = IO_PORT) -> socket.socket:
    """UDP 2222 of one device: SO_REUSEADDR, and multicast sent from the device's own address."""
    sock = udp_socket(host, port)
    sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton(host))
    sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1)
    sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 1)
    return sock


class CyclicIoThread(threading.Thread):
    """Reads O->T from every device socket and runs each device's connection timer."""

    _IDLE_WAIT = 0.5  # with no timer: O->T is read at once (epoll), a new timer wakes the thread
    _EPOLL_MARGIN_NS = 1_000_000  # epoll rounds its timeout up to whole milliseconds
    _STALL_NS = 5_000_000_000  # a loop that has not turned for this long is not running

    def __init__(self) -> None:
        super().__init__(name="enip-farm-cyclic-io", daemon=True)
        self._heap: list[tuple[int, int, DeviceIo]] = []
        self._order = itertools.count()
        self._requests: collections.deque[DeviceIo] = collections.deque()  # timers that may have moved
        self._epoll = select.epoll()
        self._readers: dict[int, DeviceIo] = {}
        self._wake_read, self._wake_write = os.pipe()
        os.set_blocking(self._wake_read, False)
        os.set_blocking(self._wake_write, False)
        self._epoll.register(self._wake_read, select.EPOLLIN)
        self._stopping = False
        self.errors = RateLimitedLog(log)  # one line per device and 10 s with the traceback, the rest counted
        self.loop_errors = 0  # unexpected exceptions of the loop itself (it goes on)
        self.turned_at = time.monotonic_ns()  # when the loop last went round

    def register(self, endpoint: DeviceIo) -> None:
        self._readers[endpoint.sock.fileno()] = endpoint
        self._epoll.register(endpoint.sock.fileno(), select.EPOLLIN)

    def reschedule(self, endpoint: DeviceIo) -> None:
        """From any thread: the device's timer may now be earlier than the one the thread holds."""
        self._requests.append(endpoint)  # deque append and popleft are thread-safe
        self._wake()

    def _wake(self) -> None:
        try:
            os.write(self._wake_write, b"\0")
        except BlockingIOError:  # the pipe is full: the thread has wake-ups pending anyway
            pass

    def stop(self) -> None:
        self._stopping = True
        self._wake()
        if self.is_alive():
            self.join(5)
        self._epoll.close()
        os.close(self._wake_read)
        os.close(self._wake_write)

    def _schedule(self, endpoint: DeviceIo, timer: int | None) -> None:
        if timer is None or (endpoint.scheduled is not None and endpoint.scheduled <= timer):
            return  # nothing due, or an earlier wake-up is queued already (it asks the device again)
        endpoint.scheduled = timer
        heapq.heappush(self._heap, (timer, next(self._order), endpoint))

    def running(self, now: int) -> bool:
        """Whether the loop is alive and went round within `_STALL_NS` of `now` (ns)."""
        return self.is_alive() and not self._stopping and now - self.turned_at < self._STALL_NS

    def run(self) -> None:
        while not self._stopping:
            try:
                self._loop()
            except Exception:  # supervised: count, log once per 10 s with the traceback, go on
                self.loop_errors += 1
                now = time.monotonic_ns()
                self.errors.log(logging.ERROR, "cyclic io loop", now / 1e9,
                                "cyclic I/O thread: unexpected error (%d so far); the thread goes on",
                                self.loop_errors, exc_info=True)
                time.sleep(0.001)  # a fault that repeats at once cannot spin the core

    def _loop(self) -> None:
        heap, requests, readers = self._heap, self._requests, self._readers
        monotonic_ns, sleep, poll = time.monotonic_ns, time.sleep, self._epoll.poll
        wake_read = self._wake_read
        while not self._stopping:
            while requests:
                endpoint = requests.popleft()
                self._schedule(endpoint, endpoint.timer())
            now = self.turned_at = monotonic_ns()
            while heap and heap[0][0] <= now:
                when, _, endpoint = heapq.heappop(heap)
                if when != endpoint.scheduled:
                    continue  # superseded by an earlier wake-up
                endpoint.scheduled = None
                self._schedule(endpoint, endpoint.service(now))
                now = monotonic_ns()
            delay = (heap[0][0] - monotonic_ns()) if heap else None
            if delay is None or delay > self._EPOLL_MARGIN_NS + self._IDLE_WAIT * 1e9:
                events = poll(self._IDLE_WAIT)  # nothing due soon: look again after the idle wait at most
            elif delay > self._EPOLL_MARGIN_NS:
                events = poll(os_wait_ns(delay - self._EPOLL_MARGIN_NS))
            else:
                events = poll(0)
                if not events and delay > 0:
                    sleep(os_wait_ns(delay))
            for fd, _ in events:
                if fd == wake_read:
                    try:
                        os.read(wake_read, 4096)
                    except BlockingIOError:
                        pass
                    continue
                endpoint = readers.get(fd)
                if endpoint is not None:
                    endpoint.read()


class DeviceIo:
    """UDP 2222 of one device: moves its datagrams between the socket and the device."""

    def __init__(self, device: Device, sock: socket.socket, thread: CyclicIoThread) -> None:
        self.device = device
        self.sock = sock
        self.thread = thread
        self.scheduled: int | None = None  # the wake-up the thread holds for this device (ns)
        self._multicast: dict[str, bool] = {}  # T->O destination host -> whether it is a multicast group
        self._unsubscribe = device.observe(self._observe)

    def _observe(self, event: Event) -> None:
        if event.kind == "connection opened":  # a new stream and a new watchdog: the timer moved
            self.thread.reschedule(self)

    def read(self) -> None:
        """In the I/O thread: hand the datagrams waiting on this device's socket to the device."""
        recvfrom, receive, send = self.sock.recvfrom, self.device.receive_io, self.send
        traffic = self.device.io_traffic
        address = (self.device.profile.address, IO_PORT)
        for _ in range(_READS_PER_WAKE):
            try:
                data, addr = recvfrom(2048)
            except (BlockingIOError, InterruptedError):
                return
            except OSError as error:
                log.debug("%s: UDP 2222 error %s", self.device.name, error)
                return
            now = time.monotonic_ns()
            traffic.received(len(data))
            recorder = self.device.recorder
            if recorder is not None:
                recorder.udp(addr, address, data)
            try:
                taken = receive(data, addr, now, send)
            except Exception:  # last resort: the other devices' cyclic I/O goes on
                self._failed("taking an O->T datagram", now)
                taken = False
            if not taken:
                traffic.discarded()

    def service(self, now: int) -> int | None:
        """In the I/O thread: the device's timer has come; the next one."""
        try:
            return self.device.service_io(now, self.send)
        except Exception:  # last resort: the other devices' cyclic I/O goes on
            self._failed("servicing its connections", now)
            return now + _RETRY_NS

    def timer(self) -> int | None:
        """In the I/O thread: when the device next wants servicing."""
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
        try:
            self.sock.sendto(packet, destination)
        except OSError as error:
            self.device.counters["t_o_send_errors"] += 1
            self.device.io_traffic.send_failed()
            log.debug("%s: T->O send failed: %s", self.device.name, error)
            return
        multicast = self._multicast.get(destination[0])
        if multicast is None:
            multicast = self._multicast[destination[0]] = ipaddress.IPv4Address(destination[0]).is_multicast
        self.device.io_traffic.sent(len(packet), unicast=not multicast)
        recorder = self.device.recorder
        if recorder is not None:
            recorder.udp((self.device.profile.address, IO_PORT), destination, packet)

    def close(self) -> None:
        self._unsubscribe()


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
        endpoint = DeviceIo(device, sock, self.thread)
        self.thread.register(endpoint)
        self.endpoints.append(endpoint)
        self.thread.reschedule(endpoint)

    def start(self) -> None:
        self.thread.start()

    def running(self, now: int) -> bool:
        """Whether class-1 I/O runs: the cyclic I/O thread is alive and its loop turns."""
        return self.thread.running(now)

    @property
    def loop_errors(self) -> int:
        return self.thread.loop_errors

    def close(self) -> None:
        self.thread.stop()
        for endpoint in self.endpoints:
            endpoint.close()
        self.endpoints.clear()
        for sock in self._sockets:
            sock.close()
        self._sockets.clear()
