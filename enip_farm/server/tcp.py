"""TCP 44818 (CIP Networks Library Vol. 2, 2-2.1): one protocol instance per connection, feeding
the sans-IO encapsulation session and writing each batch of whole replies with one write.

- Fair service: at most `BATCH_FRAMES` requests of one connection are answered per turn of the
  event loop; the rest wait (reading paused) for the next turn, after every other connection's.
- Backpressure: while the replies not yet sent exceed `WRITE_HIGH_WATER` (the peer does not
  read), the connection is not read; it is read again below `WRITE_LOW_WATER`. Memory per
  connection is bounded: one read (at most 256 KiB with uvloop) plus one partial frame (at most
  4096 + 24 bytes: the data of a longer message is dropped as it arrives, Vol. 2, 2-3.3) waiting,
  and at most the high-water mark plus one batch of replies unsent.
- Limits (server/limits.py): caps on TCP connections per device and for the farm; a connection
  over a cap is closed at once.
- Encapsulation inactivity timeout (TCP/IP Interface attribute 13): a connection with no whole
  request for that long is closed, whether it sent nothing or half a header.
Injected faults act through their hooks (device/fault_type.py): `on_reply` holds replies back or
drops them, `on_tcp_connection` closes or resets a new connection, `hears` (False: no power, no link)
discards what arrives unread. A device
in its reset window (Identity Reset) takes no connection. Every read and write is counted in the
device's interface counters (Ethernet Link attribute 4)."""

from __future__ import annotations

import asyncio
import logging
import socket
import struct
import time

from enip_farm.device.device import Device
from enip_farm.device.events import EncapsulationIgnored, EncapsulationRefused, TcpClosed, TcpConnected, TcpInactive
from enip_farm.device.faults import DROP, Disconnect
from enip_farm.protocol.session import EncapsulationSession
from enip_farm.server.limits import TcpLimits
from enip_farm.server.waits import os_wait_s

log = logging.getLogger(__name__)
_LINGER_RESET = struct.pack("ii", 1, 0)  # SO_LINGER on, 0 s: close sends RST
BATCH_FRAMES = 16
WRITE_HIGH_WATER = 64 * 1024
WRITE_LOW_WATER = 16 * 1024
_RECHECK_S = 5.0  # with the inactivity timeout off (0), how often to look whether it was set


class EncapsulationProtocol(asyncio.Protocol):
    __slots__ = ("device", "session", "transport", "connections", "limits", "_not_before", "_peer", "_closed_by_us",
                 "_admitted", "_scheduled", "_write_paused", "_reading_paused", "_opened_at", "_inactivity")

    def __init__(self, device: Device, connections: set[EncapsulationProtocol], limits: TcpLimits) -> None:
        self.device = device
        self.session: EncapsulationSession | None = None
        self.transport: asyncio.Transport | None = None
        self.connections = connections  # the farm's open connections, closed at stop
        self.limits = limits
        self._not_before = 0.0  # delayed replies keep their order
        self._peer: tuple[str, int] | None = None
        self._closed_by_us = False
        self._admitted = False
        self._scheduled = False  # a turn is queued for the frames still waiting
        self._write_paused = False
        self._reading_paused = False
        self._opened_at = 0
        self._inactivity: asyncio.TimerHandle | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]
        device = self.device
        if device.resetting:  # accepted just before the reset closed the listener
            device.counters["tcp_refused_resetting"] += 1
            self._closed_by_us = True
            transport.close()
            return
        if not self.limits.admit(device.name, device.profile.limits.max_tcp_connections, time.monotonic()):
            device.counters["tcp_refused"] += 1
            self._closed_by_us = True
            transport.close()
            return
        self._admitted = True
        peer = self._peer = transport.get_extra_info("peername")
        self.session = EncapsulationSession(device, peer[0] if peer else "0.0.0.0")
        self._opened_at = time.monotonic_ns()
        transport.set_write_buffer_limits(WRITE_HIGH_WATER, WRITE_LOW_WATER)  # type: ignore[attr-defined]
        recorder = device.recorder
        if recorder is not None and peer:
            recorder.tcp_opened(self, peer[:2], transport.get_extra_info("sockname")[:2])
        self.connections.add(self)
        device.counters["tcp_connections"] += 1
        device.tcp_open += 1
        device.record(TcpConnected(f"{peer[0]}:{peer[1]}" if peer else ""))
        self._arm_inactivity(device.encapsulation_inactivity_timeout_s or _RECHECK_S)
        end = device.faults.on_tcp_connection()
        if end is not None:
            self.kill(end)

    def kill(self, kind: Disconnect) -> None:
        """Close (FIN) or reset (RST) this connection, as an injected fault (or the farm's stop) asks."""
        transport = self.transport
        if transport is None:
            return
        self._closed_by_us = True
        if kind is Disconnect.RESET:
            sock = transport.get_extra_info("socket")
            if sock is not None:
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, _LINGER_RESET)
            transport.abort()
        else:
            transport.close()

    # -- requests in, replies out -----------------------------------------------------------------

    def data_received(self, data: bytes) -> None:
        if self.session is None:  # refused at connection_made
            return
        device = self.device
        if not device.faults.hears:  # no power or no link: nothing arrives
            device.traffic.discarded()
            return
        device.traffic.received(len(data))
        recorder = device.recorder
        if recorder is not None:
            recorder.tcp_data(self, True, data)
        self._serve(data)

    def _next_turn(self) -> None:
        self._scheduled = False
        if self.transport is not None and not self.transport.is_closing():
            self._serve(b"")

    def _serve(self, data: bytes) -> None:
        """Answer at most one batch of requests; queue a turn for the rest, reading paused."""
        session = self.session
        transport = self.transport
        started = time.perf_counter()
        try:
            replies = session.receive(data, time.monotonic_ns(), BATCH_FRAMES)  # type: ignore[union-attr]
        except Exception:  # last resort: the protocol layers answer errors as values
            log.exception("%s: closing a connection after an internal error", self.device.name)
            transport.close()  # type: ignore[union-attr]
            return
        closing = session.closing  # type: ignore[union-attr]
        if session.refusals or session.ignored:  # type: ignore[union-attr]
            self._report_refusals()
        if replies:
            out = replies[0] if len(replies) == 1 else b"".join(replies)
            faults = self.device.faults
            hold_ns = faults.on_reply() if faults.active else None
            if hold_ns is None:
                recorder = self.device.recorder
                if recorder is not None:  # recorded first: a farm killed in between leaves the reply on file
                    recorder.tcp_data(self, False, out)
                transport.write(out)  # type: ignore[union-attr]
                self.device.traffic.sent(len(out))
                self.device.latency.observe(time.perf_counter() - started)
            elif hold_ns != DROP:
                loop = asyncio.get_running_loop()
                when = max(loop.time() + os_wait_s(hold_ns / 1e9), self._not_before)
                self._not_before = when
                loop.call_at(when, self._write_late, out, closing)
                closing = False  # closed after the late write
            else:
                self.device.counters["replies_dropped"] += len(replies)
        if closing:
            self._closed_by_us = True
            transport.close()  # type: ignore[union-attr]
            return
        backlog = session.backlog  # type: ignore[union-attr]
        if backlog and not self._write_paused and not self._scheduled:
            self._scheduled = True
            asyncio.get_running_loop().call_soon(self._next_turn)
        self._set_reading(paused=backlog or self._write_paused)

    def _report_refusals(self) -> None:
        """An event per request answered with an encapsulation error status, and per request
        ignored for the non-zero status it carried (Vol. 2, 2-3.5)."""
        session = self.session
        peer = self._peer_text()
        for command, status in session.refusals:  # type: ignore[union-attr]
            self.device.record(EncapsulationRefused(command, peer, status))
        session.refusals.clear()  # type: ignore[union-attr]
        for command, status in session.ignored:  # type: ignore[union-attr]
            self.device.record(EncapsulationIgnored(command, peer, status))
        session.ignored.clear()  # type: ignore[union-attr]

    def _peer_text(self) -> str:
        return f"{self._peer[0]}:{self._peer[1]}" if self._peer else "?"

    def _set_reading(self, paused: bool) -> None:
        if paused == self._reading_paused or self.transport is None or self.transport.is_closing():
            return
        self._reading_paused = paused
        if paused:
            self.transport.pause_reading()
        else:
            self.transport.resume_reading()

    def pause_writing(self) -> None:
        """The peer does not read its replies: stop reading its requests."""
        self._write_paused = True
        self.device.counters["tcp_write_paused"] += 1
        self._set_reading(paused=True)

    def resume_writing(self) -> None:
        self._write_paused = False
        session = self.session
        if session is not None and session.backlog:
            if not self._scheduled:
                self._scheduled = True
                asyncio.get_running_loop().call_soon(self._next_turn)
        else:
            self._set_reading(paused=False)

    def _write_late(self, out: bytes, close: bool) -> None:
        if self.transport is None or self.transport.is_closing():
            return
        if self.device.recorder is not None:
            self.device.recorder.tcp_data(self, False, out)
        self.transport.write(out)
        self.device.traffic.sent(len(out))
        if close:
            self._closed_by_us = True
            self.transport.close()

    # -- encapsulation inactivity timeout (TCP/IP Interface attribute 13) ---------------------------

    def _arm_inactivity(self, delay_s: float) -> None:
        self._inactivity = asyncio.get_running_loop().call_later(max(os_wait_s(delay_s), 0.001), self._check_inactivity)

    def _check_inactivity(self) -> None:
        self._inactivity = None
        if self.transport is None or self.transport.is_closing() or self.session is None:
            return
        timeout_s = self.device.encapsulation_inactivity_timeout_s  # clients may have set it meanwhile
        if not timeout_s:
            self._arm_inactivity(_RECHECK_S)
            return
        last = max(self.session.last_frame_at, self._opened_at)
        idle_s = (time.monotonic_ns() - last) / 1e9
        if idle_s < timeout_s:
            self._arm_inactivity(timeout_s - idle_s)
            return
        self.device.counters["tcp_inactivity_closed"] += 1
        self.device.record(TcpInactive(f"{self._peer[0]}:{self._peer[1]}" if self._peer else "", timeout_s))
        self._closed_by_us = True
        self.transport.close()

    # -- the end ------------------------------------------------------------------------------------

    def eof_received(self) -> bool:
        return False  # close our side too

    def connection_lost(self, exc: Exception | None) -> None:
        if not self._admitted:
            self.transport = None
            return
        self.limits.release(self.device.name)
        self.device.tcp_open -= 1
        if self._inactivity is not None:
            self._inactivity.cancel()
            self._inactivity = None
        if self.session is not None:
            self.session.connection_lost(time.monotonic_ns())
        self.connections.discard(self)
        self.device.record(TcpClosed(self._peer_text(), not self._closed_by_us,
                                     (time.monotonic_ns() - self._opened_at) / 1e9))
        if self.device.recorder is not None:
            self.device.recorder.tcp_closed(self, by_client=not self._closed_by_us)
        self.transport = None
