"""TCP 44818 (CIP Networks Library Vol. 2, 2-2.1): one protocol instance per connection, feeding
the sans-IO encapsulation session and writing each batch of whole replies with one write.
Injected faults (device/faults.py) delay or drop replies, and close or reset connections."""

from __future__ import annotations

import asyncio
import logging
import socket
import struct
import time

from enip_farm.device.device import Device
from enip_farm.device.faults import FaultKind
from enip_farm.protocol.session import EncapsulationSession

log = logging.getLogger(__name__)
_LINGER_RESET = struct.pack("ii", 1, 0)  # SO_LINGER on, 0 s: close sends RST


class EncapsulationProtocol(asyncio.Protocol):
    __slots__ = ("device", "session", "transport", "connections", "_not_before", "_peer", "_closed_by_us")

    def __init__(self, device: Device, connections: set[EncapsulationProtocol]) -> None:
        self.device = device
        self.session: EncapsulationSession | None = None
        self.transport: asyncio.Transport | None = None
        self.connections = connections  # the farm's open connections, closed at stop
        self._not_before = 0.0  # delayed replies keep their order
        self._peer: tuple[str, int] | None = None
        self._closed_by_us = False

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]
        peer = self._peer = transport.get_extra_info("peername")
        self.session = EncapsulationSession(self.device, peer[0] if peer else "0.0.0.0")
        recorder = self.device.recorder
        if recorder is not None and peer:
            recorder.tcp_opened(self, peer[:2], transport.get_extra_info("sockname")[:2])
        self.connections.add(self)
        self.device.counters["tcp_connections"] += 1
        self.device.record("tcp connected", f"{peer[0]}:{peer[1]}" if peer else "")
        kind = self.device.faults.connection_fault
        if kind is not None:
            self.kill(kind)

    def kill(self, kind: FaultKind) -> None:
        """Close (FIN) or reset (RST) this connection, as an injected fault asks."""
        transport = self.transport
        if transport is None:
            return
        if kind is FaultKind.RESET:
            sock = transport.get_extra_info("socket")
            if sock is not None:
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, _LINGER_RESET)
            transport.abort()
        else:
            transport.close()

    def data_received(self, data: bytes) -> None:
        session = self.session
        started = time.perf_counter()
        recorder = self.device.recorder
        if recorder is not None:
            recorder.tcp_data(self, True, data)
        try:
            replies = session.receive(data, time.monotonic_ns())  # type: ignore[union-attr]
        except Exception:  # last resort: the protocol layers answer errors as values
            log.exception("%s: closing a connection after an internal error", self.device.name)
            self.transport.close()  # type: ignore[union-attr]
            return
        transport = self.transport
        faults = self.device.faults
        if replies:
            out = replies[0] if len(replies) == 1 else b"".join(replies)
            fault = faults.reply_fault if faults.active else None
            if fault is None:
                if recorder is not None:  # recorded first: a farm killed in between leaves the reply on file
                    recorder.tcp_data(self, False, out)
                transport.write(out)  # type: ignore[union-attr]
                self.device.latency.observe(time.perf_counter() - started)
            elif fault.kind is FaultKind.DELAY:
                loop = asyncio.get_running_loop()
                when = max(loop.time() + fault.reply_delay(), self._not_before)
                self._not_before = when
                loop.call_at(when, self._write_late, out, session.closing)  # type: ignore[union-attr]
                return
            else:
                self.device.counters["replies_dropped"] += len(replies)
        if session.closing:  # type: ignore[union-attr]
            self._closed_by_us = True
            transport.close()  # type: ignore[union-attr]

    def _write_late(self, out: bytes, close: bool) -> None:
        if self.transport is None or self.transport.is_closing():
            return
        if self.device.recorder is not None:
            self.device.recorder.tcp_data(self, False, out)
        self.transport.write(out)
        if close:
            self._closed_by_us = True
            self.transport.close()

    def eof_received(self) -> bool:
        return False  # close our side too

    def connection_lost(self, exc: Exception | None) -> None:
        if self.session is not None:
            self.session.connection_lost(time.monotonic_ns())
        self.connections.discard(self)
        self.device.record("tcp closed", "")
        if self.device.recorder is not None:
            self.device.recorder.tcp_closed(self, by_client=not self._closed_by_us)
        self.transport = None
