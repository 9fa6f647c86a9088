"""Batched UDP for the cyclic I/O thread (server/implicit.py): the datagrams waiting on the device
sockets that epoll reported ready, read in one call (recvmmsg per socket) each with the kernel's
receive time (`SO_TIMESTAMPNS`, set on the sockets by server/implicit.py), and every T->O packet
due in one tick sent in one call (sendmmsg from one socket, each packet with its device's source
address as IP_PKTINFO's ipi_spec_dst, so it leaves from DEVICE:2222 as if its own socket sent it).

The system calls are made by the small extension `_mmsg` (enip_farm/server/_mmsg.c, built by pip
where a compiler exists); without it `Datagrams` reads one datagram per ready socket (epoll is
level-triggered: the rest are reported again) and sends each packet from its device's own socket.

The receive time: the kernel stamps a datagram on CLOCK_REALTIME as it queues it (SO_TIMESTAMPNS);
the farm's times are CLOCK_MONOTONIC (time.monotonic_ns). Both paths turn a stamp into monotonic ns
with the offset between the two clocks read once per call, right after the datagrams are read (the
wall clock between two monotonic reads, against their midpoint: `clock_offset`), so a
step or slew of the wall clock moves at most the stamps of the datagrams read in that one call (and
a stamp is never later than the read). SO_TIMESTAMPING has no monotonic source for software receive
stamps, so it would need the same conversion.
"""

from __future__ import annotations

import errno
import socket
import struct
import time
from collections.abc import Mapping

try:
    from enip_farm.server import _mmsg
except ImportError:  # no compiler where the package was built: the pure-Python path
    _mmsg = None

#: Whether the native batch calls are there.
NATIVE = _mmsg is not None
#: Datagrams read from one socket per call. One: a wake-up reads one datagram from every socket that
#: has some and then services what is due; a socket with more is reported again at the next turn
#: (epoll is level-triggered), so a backlog on some sockets cannot hold back every device's T->O.
RECEIVE_LIMIT = 1
#: The same for the native engine (server/native.py): its datagrams cost so little that a turn that
#: came late reads what queued meanwhile rather than leaving it to overflow the socket (at RPI 2 ms a
#: turn 3 ms late finds two); a datagram it hands to Python still costs as RECEIVE_LIMIT's do.
NATIVE_RECEIVE_LIMIT = 4
#: A message to send: payload, destination (4-byte IPv4 address + 2-byte port, network order), source address.
Message = tuple[bytes, bytes, bytes]
#: Linux's SO_TIMESTAMPNS (= SCM_TIMESTAMPNS; the socket module does not name it).
SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)
_TIMESPEC = struct.Struct("@qq")
_ANCILLARY = socket.CMSG_SPACE(_TIMESPEC.size)


def sockaddr(host: str, port: int) -> bytes:
    """A destination as `Message` carries it."""
    return socket.inet_aton(host) + port.to_bytes(2, "big")


class Datagrams:
    """Receives from and sends through the device sockets of one I/O thread."""

    def __init__(self, native: bool = NATIVE) -> None:
        self.native = native and _mmsg is not None
        self.sockets: dict[int, socket.socket] = {}  # by file descriptor
        self._by_source: dict[bytes, socket.socket] = {}  # by the 4-byte address each is bound to
        self._sender: int | None = None  # the socket the native path sends every packet from

    def add(self, sock: socket.socket) -> None:
        self.sockets[sock.fileno()] = sock
        self._by_source[socket.inet_aton(sock.getsockname()[0])] = sock
        if self._sender is None:
            self._sender = sock.fileno()

    def receive(self, fds: list[int]) -> list[tuple[int, bytes, str, int, int]]:
        """The datagrams waiting on these sockets: (fd, payload, source host, source port, the
        kernel's receive time in monotonic ns or 0 where the socket gave none)."""
        if self.native:
            return _mmsg.recv_batch(fds, RECEIVE_LIMIT)  # type: ignore[union-attr]
        read = []
        sockets: Mapping[int, socket.socket] = self.sockets
        for fd in fds:
            try:
                data, ancillary, _flags, (host, port) = sockets[fd].recvmsg(2048, _ANCILLARY)
            except (BlockingIOError, InterruptedError, KeyError):
                continue
            except OSError:  # an ICMP error reported on the socket: nothing to read
                continue
            read.append((fd, data, host, port, wall_stamp(ancillary)))
        if not read:
            return []
        offset, now = clock_offset()
        return [(fd, data, host, port, min(stamp - offset, now) if stamp else 0)
                for fd, data, host, port, stamp in read]

    def send(self, messages: list[Message]) -> list[tuple[int, int]]:
        """Send every message; the (index, errno) of those that failed."""
        if self.native and self._sender is not None:
            return _mmsg.send_batch(self._sender, messages)  # type: ignore[union-attr]
        failures = []
        for index, (payload, destination, source) in enumerate(messages):
            sock = self._by_source.get(source)
            if sock is None:
                failures.append((index, errno.EADDRNOTAVAIL))
                continue
            try:
                sock.sendto(payload, (socket.inet_ntoa(destination[:4]), int.from_bytes(destination[4:], "big")))
            except OSError as error:
                failures.append((index, error.errno or errno.EIO))
        return failures


def wall_stamp(ancillary: list[tuple[int, int, bytes]]) -> int:
    """The kernel's receive time (SCM_TIMESTAMPNS) of a datagram, CLOCK_REALTIME ns; 0 if it has none."""
    for level, kind, data in ancillary:
        if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS and len(data) >= _TIMESPEC.size:
            seconds, nanoseconds = _TIMESPEC.unpack_from(data)
            return seconds * 1_000_000_000 + nanoseconds
    return 0


def clock_offset() -> tuple[int, int]:
    """(CLOCK_REALTIME - CLOCK_MONOTONIC, monotonic now) in ns: the wall clock read between two reads
    of the monotonic one, against their midpoint (off by at most half the time between them)."""
    before = time.monotonic_ns()
    wall = time.time_ns()
    after = time.monotonic_ns()
    return wall - (before + after) // 2, after
