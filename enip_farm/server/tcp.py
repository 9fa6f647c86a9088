"""TCP 44818 (CIP Networks Library Vol. 2, 2-2.1): one protocol instance per connection, feeding
the sans-IO encapsulation session and writing each batch of whole replies with one write."""

from __future__ import annotations

import asyncio
import logging

from enip_farm.device.device import Device
from enip_farm.protocol.session import EncapsulationSession

log = logging.getLogger(__name__)


class EncapsulationProtocol(asyncio.Protocol):
    __slots__ = ("device", "session", "transport", "connections")

    def __init__(self, device: Device, connections: set[EncapsulationProtocol]) -> None:
        self.device = device
        self.session: EncapsulationSession | None = None
        self.transport: asyncio.Transport | None = None
        self.connections = connections  # the farm's open connections, closed at stop

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]
        peer = transport.get_extra_info("peername")
        self.session = EncapsulationSession(self.device, peer[0] if peer else "0.0.0.0")
        self.connections.add(self)

    def data_received(self, data: bytes) -> None:
        session = self.session
        try:
            replies = session.receive(data)
        except Exception:  # last resort: the protocol layers answer errors as values
            log.exception("%s: closing a connection after an internal error", self.device.name)
            self.transport.close()  # type: ignore[union-attr]
            return
        transport = self.transport
        if replies:
            transport.write(replies[0] if len(replies) == 1 else b"".join(replies))  # type: ignore[union-attr]
        if session.closing:
            transport.close()  # type: ignore[union-attr]

    def eof_received(self) -> bool:
        return False  # close our side too

    def connection_lost(self, exc: Exception | None) -> None:
        if self.session is not None:
            self.session.connection_lost()
        self.connections.discard(self)
        self.transport = None
