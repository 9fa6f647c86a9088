"""One device as the encapsulation layer sees it (the `Target` of protocol/session.py; CIP Networks
Library Vol. 2, 2-4): ListIdentity, ListServices and ListInterfaces data, and explicit requests,
unconnected (SendRRData) and on class-3 connections (SendUnitData, Vol. 1, 3-4.3), each dispatched
by the Message Router in one device transaction (device/guard.py). An effect a service returns (the
Identity object's `ResetRequested`) is performed in the same transaction once the whole request is
answered, so a reset in a Multiple Service Packet comes after every request of the packet; what
happened is published after the lock."""

from __future__ import annotations

from collections.abc import Callable

from enip_farm.cip.identity import ResetRequested
from enip_farm.cip.message_router import MessageRouter
from enip_farm.cip.object import Effect, ReplyItems
from enip_farm.device.guard import DeviceGuard, Transaction
from enip_farm.device.profile import DeviceProfile
from enip_farm.device.reset import Resets
from enip_farm.protocol.commands import (
    CAPABILITY_TCP,
    CAPABILITY_UDP_CLASS_0_1,
    PROTOCOL_VERSION,
    IdentityItem,
    ServiceItem,
    SocketAddress,
    encode_identity_item,
    encode_service_item,
)
from enip_farm.protocol.cpf import ItemType, encode_items
from enip_farm.protocol.encapsulation import ENIP_PORT
from enip_farm.protocol.session import MessageContext, ReplyWithItems


class EncapsulationTarget:
    """The encapsulation-level identity and the explicit messaging of one device."""

    def __init__(self, profile: DeviceProfile, guard: DeviceGuard, router: MessageRouter, resets: Resets,
                 product_code: Callable[[], int], identity_state: Callable[[], int],
                 revision: Callable[[], tuple[int, int]] | None = None) -> None:
        self.profile = profile
        self.guard = guard
        self.router = router
        self.table = guard.table
        self.resets = resets
        self.product_code = product_code
        self.identity_state = identity_state
        self.revision = revision or (lambda: profile.revision)
        service = ServiceItem(PROTOCOL_VERSION, CAPABILITY_TCP | CAPABILITY_UDP_CLASS_0_1, "Communications")
        self._list_services = encode_items([(ItemType.LIST_SERVICES, encode_service_item(service))])

    def identity_item(self) -> IdentityItem:
        p = self.profile
        status = self.guard.read(lambda: self.table.status)
        major, minor = self.revision()
        return IdentityItem(PROTOCOL_VERSION, SocketAddress(p.address, ENIP_PORT), p.vendor_id, p.device_type,
                            self.product_code(), major, minor, status, p.serial_number,
                            p.product_name, self.identity_state())

    def list_identity_data(self) -> bytes:
        return encode_items([(ItemType.LIST_IDENTITY, encode_identity_item(self.identity_item()))])

    def list_services_data(self) -> bytes:
        return self._list_services

    def list_interfaces_data(self) -> bytes:
        return encode_items([])

    def _perform(self, effects: list[Effect], transaction: Transaction) -> None:
        """In the transaction, once the request is answered: its effects; of several resets in one
        request, the last, as one restart."""
        reset = None
        for effect in effects:
            if type(effect) is ResetRequested:
                reset = effect
        if reset is not None:
            self.resets.perform(reset, transaction)

    def handle_unconnected(self, message: bytes, context: MessageContext) -> ReplyWithItems:
        router = self.router
        with self.guard.transaction(context.now) as transaction:
            reply = router.dispatch(message, context)
            if router.effects:
                self._perform(router.pop_effects(), transaction)
            transaction.requests = router.pop_handled()
        return reply

    def handle_connected(self, connection_id: int, sequence_count: int, message: bytes,
                         context: MessageContext) -> tuple[int, bytes, ReplyItems] | None:
        router, table = self.router, self.table
        with self.guard.transaction(context.now) as transaction:
            connection = table.receive_connected(connection_id, context.session, context.now)
            if connection is None:
                return None
            if connection.last_reply is not None and connection.last_reply[0] == sequence_count:
                return connection.t_o_id, connection.last_reply[1], connection.last_reply[2]  # a duplicate
            reply, items = router.dispatch(message, context)
            connection.last_reply = (sequence_count, reply, items)
            if router.effects:
                self._perform(router.pop_effects(), transaction)
            transaction.requests = router.pop_handled()
        return connection.t_o_id, reply, items
