"""Class-1 implicit I/O on UDP 2222 (CIP Networks Library Vol. 2, 3-2 and 3-3): the sockets and
the one thread that moves the datagrams. The connections themselves (consumption, production
schedule, supervision) are the devices' sans-IO connection tables (cip/connection_table.py).

All cyclic traffic of a farm (of a worker) runs in one I/O thread, apart from the event loop, so
that neither delays the other, and it is the only place that sleeps. Its cost is per packet, not
per device:
- every device address has a UDP 2222 socket (SO_REUSEADDR, so a scanner on the same host can
  still bind 0.0.0.0:2222); epoll says which have datagrams, and those are read in one call
  (server/batch.py: recvmmsg per socket) and handed to their device with the time they were read;
- one heap of wake-ups, one entry per device at the time its table asks for (`get_timer`); the
  thread runs in turns at most `TURN_NS` apart: a turn first reads what is waiting (a packet that
  came in time counts, however late the thread is), then lets every device whose timer falls
  before the next turn supervise its connections at the turn's time and produce the T->O packets
  due by the next turn (`Device.service_io`), and sends them all in one call (sendmmsg from one
  socket with each device's source address); a Forward Open on the event loop wakes the thread
  through a pipe. epoll waits in whole milliseconds, so the thread stops waiting on it a
  millisecond early and sleeps the rest with time.sleep;
- every datagram in and out is counted in the device's interface counters (Ethernet Link
  attribute 4), by this thread alone (`Device.io_traffic`);
- how late it runs is watched (`lag`): a wake-up later than `OVERLOAD_LAG_NS` is an overload of
  the farm (the CPU, or more connections than its budget), counted, shown in /metrics and as a
  console warning with the lag, never blamed on an originator; once a second, what the thread
  really spent (its CPU, system calls included), the datagrams it moved and its late turns go to
  a measured budget's running check (server/running_budget.py, cip/budget.py);
- one device's bug does not stop the others: an exception while it takes a datagram or services
  its connections is counted (`io_errors`) and logged with its traceback (rate-limited per device,
  `RateLimitedLog`), and its timer is tried again `_RETRY_NS` later;
- nothing stops the thread itself: an unexpected exception of the loop is counted (`loop_errors`),
  logged once per 10 s with its traceback, and the loop goes on; every wait it hands epoll or sleep
  is bounded (server/waits.py); `running` says whether the loop turned within `_STALL_NS`, which the
  farm's health (the API's /health, the container's health check) reports.
"""

from __future__ import annotations

import collections
import heapq
import itertools
import logging
import os
import select
import socket
import sys
import threading
import time
from collections.abc import Callable

from enip_farm.cip.budget import CyclicBudget
from enip_farm.device.device import Device
from enip_farm.protocol.connection import IO_PORT
from enip_farm.server.batch import NATIVE_RECEIVE_LIMIT, SO_TIMESTAMPNS, Datagrams, Message
from enip_farm.server.device_io import DeviceIo as DeviceIo
from enip_farm.server.lag import OVERLOAD_LAG_NS as OVERLOAD_LAG_NS
from enip_farm.server.lag import Lag
from enip_farm.server.limits import RateLimitedLog
from enip_farm.server.native import NativeDevice, native_wanted, new_engine, publish_changes
from enip_farm.server.realtime import run_realtime
from enip_farm.server.running_budget import RunningBudget
from enip_farm.server.udp import udp_socket
from enip_farm.server.waits import os_wait_ns

log = logging.getLogger(__name__)


def io_socket(host: str, port: int = IO_PORT) -> socket.socket:
    """UDP 2222 of one device: SO_REUSEADDR, multicast sent from the device's own address, and each
    datagram stamped with the kernel's receive time (SO_TIMESTAMPNS: the report measures the
    originator by it, so the farm's own scheduling never counts against the controller)."""
    sock = udp_socket(host, port)
    sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
    sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton(host))
    sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1)
    sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 1)
    return sock


class CyclicIoThread(threading.Thread):
    """Reads O->T from every device socket and runs each device's connection timer."""

    _IDLE_WAIT = 0.5  # with no timer: O->T is read at once (epoll), a new timer wakes the thread
    _EPOLL_MARGIN_NS = 1_000_000  # epoll rounds its timeout up to whole milliseconds
    _STALL_NS = 5_000_000_000  # a loop that has not turned for this long is not running
    #: One turn of the thread: it runs at most this often, reading every socket that has datagrams
    #: and producing every T->O due before its next turn (so a packet leaves up to TURN_NS before
    #: its deadline, never later for the thread's sake; deadlines stay absolute). Coalescing the
    #: wake-ups is what makes the cost per packet rather than per wake-up.
    TURN_NS = 1_000_000
    #: How often the native engine writes its state into the Python objects that readers without the
    #: device lock look at (the lock's readers and transactions get it at once: server/native.py).
    NATIVE_SYNC_NS = 100_000_000
    #: Sockets a turn reads at most with the native engine (server/native.py): a turn's reading is
    #: one system call per ready socket (several us each), bounded so that T->O keep their time.
    #: A turn that leaves some unread supervises nothing (a datagram still unread may feed a
    #: deadline), unless the turns before it left some unread for a whole round (`skip_rounds`).
    NATIVE_TURN_SOCKETS = 128

    @property
    def native_sync_slice(self) -> int:
        """Devices the engine writes back a turn, for a whole round every NATIVE_SYNC_NS."""
        return -(-len(self._slots) * self.TURN_NS // self.NATIVE_SYNC_NS)

    @property
    def skip_rounds(self) -> int:
        """Turns in a row that may leave sockets unread and skip supervision and the Python path's
        devices: epoll hands its ready sockets on in turn, so after these every socket that was
        ready when they began has been read, and the next turn serves and supervises what is due."""
        return max(1, -(-len(self._readers) // self.NATIVE_TURN_SOCKETS))

    def __init__(self, datagrams: Datagrams | None = None, budget: CyclicBudget | None = None,
                 native: bool = False, realtime_priority: int = 0) -> None:
        super().__init__(name="enip-farm-cyclic-io", daemon=True)
        self.realtime_priority = realtime_priority  # SCHED_FIFO's, 0: the normal policy (server/realtime.py)
        #: The native class-1 engine (server/native.py) of this thread's devices, None: all on Python's path.
        self.native = new_engine() if native else None
        self.native_timer: int | None = None  # the engine's earliest deadline after its last turn
        self.running_budget = RunningBudget(budget)  # budget: a measured one, checked while it runs
        self.datagrams = datagrams if datagrams is not None else Datagrams()
        self._heap: list[tuple[int, int, DeviceIo]] = []
        self._order = itertools.count()
        self._requests: collections.deque[DeviceIo] = collections.deque()  # timers that may have moved
        self._epoll = select.epoll()
        self._readers: dict[int, DeviceIo] = {}
        self._slots: dict[int, DeviceIo] = {}  # by the native engine's slot
        self._wake_read, self._wake_write = os.pipe()
        os.set_blocking(self._wake_read, False)
        os.set_blocking(self._wake_write, False)
        self._epoll.register(self._wake_read, select.EPOLLIN)
        self._stopping = False
        self.outbox: list[Message] = []  # T->O due this wake-up, sent in one call
        self.outbox_from: list[DeviceIo] = []  # the device of each
        self.errors = RateLimitedLog(log)  # one line per device and 10 s with the traceback, the rest counted
        self.overload_log = RateLimitedLog(log)
        self.loop_errors = 0  # unexpected exceptions of the loop itself (it goes on)
        self.lag = Lag()
        #: Called with the time each turn's T->O are handed to the kernel (copy on write; `watch_flush`).
        self.flush_watchers: tuple[Callable[[int], None], ...] = ()
        self.turned_at = time.monotonic_ns()  # when the loop last went round

    def watch_flush(self, watcher: Callable[[int], None]) -> Callable[[], None]:
        """From any thread: `watcher(at)` with the time each turn's T->O packets go to the kernel,
        just before the send call; returns the unsubscribe."""
        self.flush_watchers = (*self.flush_watchers, watcher)

        def unsubscribe() -> None:
            self.flush_watchers = tuple(w for w in self.flush_watchers if w is not watcher)
        return unsubscribe

    def register(self, endpoint: DeviceIo) -> None:
        self._readers[endpoint.sock.fileno()] = endpoint
        if self.native is not None:
            endpoint.native = NativeDevice(self.native, endpoint.sock.fileno(), endpoint.device,
                                           lambda: self.reschedule(endpoint))
            endpoint.native.attach()
            self._slots[endpoint.native.slot] = endpoint
        self.datagrams.add(endpoint.sock)
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
        problem = run_realtime(self.realtime_priority)
        if problem is not None:
            log.warning("%s; it runs at the normal policy", problem)
        while not self._stopping:
            try:
                self._loop()
            except Exception:  # supervised: count, log once per 10 s with the traceback, go on
                self.loop_errors += 1
                self.outbox.clear()
                self.outbox_from.clear()
                now = time.monotonic_ns()
                self.errors.log(logging.ERROR, "cyclic io loop", now / 1e9,
                                "cyclic I/O thread: unexpected error (%d so far); the thread goes on",
                                self.loop_errors, exc_info=True)
                time.sleep(0.001)  # a fault that repeats at once cannot spin the core

    def _loop(self) -> None:
        heap, requests, readers = self._heap, self._requests, self._readers
        monotonic_ns, sleep, poll = time.monotonic_ns, time.sleep, self._epoll.poll
        receive, wake_read, outbox, lag = self.datagrams.receive, self._wake_read, self.outbox, self.lag
        turn_ns, margin_ns = self.TURN_NS, self._EPOLL_MARGIN_NS
        running = self.running_budget
        native, slots = self.native, self._slots
        native_receive = native.receive if native is not None else None
        native_produce = native.produce if native is not None else None
        native_changes = native.changes if native is not None else None  # (its image changes: observers told)
        most = self.NATIVE_TURN_SOCKETS + 1 if native is not None else -1  # epoll's events a turn (+ the pipe)
        if native is not None:
            epoll_poll = poll

            def poll(timeout: float) -> list[tuple[int, int]]:
                return epoll_poll(timeout, most)
        last = skipped = 0
        while not self._stopping:
            while requests:
                endpoint = requests.popleft()
                self._schedule(endpoint, endpoint.timer())
            gap = last + turn_ns - monotonic_ns()
            if gap > 0:  # turns at most every TURN_NS: what comes meanwhile waits in the sockets for it
                sleep(gap / 1e9)
            first = heap[0][0] if heap else None
            if self.native_timer is not None and (first is None or self.native_timer < first):
                first = self.native_timer
            wait = (first - turn_ns - monotonic_ns()) if first is not None else None  # until the next turn that is due
            if wait is None or wait > margin_ns + self._IDLE_WAIT * 1e9:
                events = poll(self._IDLE_WAIT)  # nothing due soon: look again after the idle wait at most
            elif wait > margin_ns:
                events = poll(os_wait_ns(wait - margin_ns))
            else:
                events = poll(0)
                if not events and wait > 0:
                    sleep(os_wait_ns(wait))
                    events = poll(0)
            # with the native engine a turn reads at most NATIVE_TURN_SOCKETS sockets (epoll hands the
            # others on next time, in turn), so that one late turn does not make the next one longer
            # (reading is per ready socket); while some are left unread nothing is timed out, for a
            # round of turns at most (then a turn serves and supervises what is due all the same)
            unread = len(events) == most and skipped < self.skip_rounds
            skipped = skipped + 1 if unread else 0
            now = last = self.turned_at = monotonic_ns()
            if events:  # first what came in: a packet that came in time counts, however late the thread is
                fds = []
                for fd, _ in events:
                    if fd == wake_read:
                        try:
                            os.read(wake_read, 4096)
                        except BlockingIOError:
                            pass
                    else:
                        fds.append(fd)
                if fds:
                    if native_receive is not None:  # the native devices' datagrams taken there, the rest here
                        received, taken = native_receive(fds, NATIVE_RECEIVE_LIMIT, now)
                        running.datagrams += taken
                        if native_changes:  # told before what it left to Python, as that path would have
                            publish_changes(native_changes, self._device_of, self._publish_failed)
                    else:
                        received = receive(fds)
                    running.datagrams += len(received)
                    for fd, data, host, port, received_at in received:
                        endpoint = readers.get(fd)
                        if endpoint is not None:
                            endpoint.take(data, host, port, now, received_at or now)
            horizon = now + turn_ns  # what falls due before the next turn is served in this one
            first = heap[0][0] if heap and heap[0][0] <= horizon else None
            if native_produce is not None:  # the native devices' T->O (sent), their timeouts to Python
                python, self.native_timer, served, sent, _ = native_produce(now, horizon, False, not unread)
                running.datagrams += sent
                if served is not None and (first is None or served < first):
                    first = served
                for slot in python:
                    endpoint = slots[slot]
                    self._schedule(endpoint, endpoint.service(now, horizon, True))
                native.sync(self.native_sync_slice)  # a few devices a turn: a whole round every NATIVE_SYNC_NS
            if unread:  # the Python path's devices wait for a turn that read every socket (supervision)
                first = served if native_produce is not None else None
            if first is not None:
                late = now - first  # <= 0 on time: the lag still starts its next second (worst_ns)
                running.turn(late)
                if lag.observe(late, now):
                    self._overloaded(late, now)
                due = []
                while heap and heap[0][0] <= horizon and not unread:
                    when, _, endpoint = heapq.heappop(heap)
                    if when == endpoint.scheduled:  # else superseded by an earlier wake-up
                        endpoint.scheduled = None
                        due.append(endpoint)
                for endpoint in due:  # a timer they ask for within this turn (a deadline after now) is the next turn's
                    self._schedule(endpoint, endpoint.service(now, horizon))
            if outbox:
                running.datagrams += len(outbox)
                self._flush()
            running.tick(now)

    def _device_of(self, slot: int) -> Device:
        return self._slots[slot].device

    def _publish_failed(self, slot: int, now: int) -> None:
        self._slots[slot]._failed("telling an output image change", now)  # noqa: SLF001 - as DeviceIo.take's

    def _flush(self) -> None:
        """Send every T->O of this turn in one call; a packet that could not be sent is counted as
        an error of its device (each was counted as sent when queued, as ifOutUcastPkts counts what
        was requested to be sent)."""
        outbox, senders = self.outbox, self.outbox_from
        watchers = self.flush_watchers
        if watchers:  # a reaction being measured: when this turn's T->O leave (device/reaction.py)
            at = time.monotonic_ns()
            for watcher in watchers:
                watcher(at)
        try:
            for index, _ in self.datagrams.send(outbox):
                senders[index].send_failed()
        finally:
            outbox.clear()
            senders.clear()

    def _overloaded(self, lag_ns: int, now: int) -> None:
        self.overload_log.log(logging.WARNING, "overload", now / 1e9,
                              "cyclic I/O runs %.1f ms behind its schedule: the farm is overloaded (CPU, or more "
                              "connections than its budget), not the originators late", lag_ns / 1e6)


class ImplicitIo:
    """UDP 2222 of every device of a farm, and the cyclic I/O thread."""

    def __init__(self, budget: CyclicBudget | None = None, native: str | bool = "auto",
                 realtime_priority: int = 0) -> None:
        # a measured budget: checked while the thread runs; native: server/native.py, where built and wanted
        self.thread = CyclicIoThread(budget=budget, native=native_wanted(native), realtime_priority=realtime_priority)
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

    @property
    def lag(self) -> Lag:
        return self.thread.lag

    def close(self) -> None:
        self.thread.stop()
        for endpoint in self.endpoints:
            endpoint.close()
        self.endpoints.clear()
        for sock in self._sockets:
            sock.close()
        self._sockets.clear()
