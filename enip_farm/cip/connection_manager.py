"""Connection Manager, class 0x06 (CIP Networks Library Vol. 1, 3-5.5): the services; the
connections themselves live in the device's sans-IO `ConnectionTable` (cip/connection_table.py).

- Unconnected Send (0x52) addressed to this device: the embedded request is answered by the
  message router and its reply returned as it is (3-5.5.2); unless the device's profile says it
  does not route (0x08, as a non-routing adapter such as OpENer answers).
- Forward Open (0x54) and Large Forward Open (0x5B): admitted or refused by the table, each
  refusal with the extended status of table 3-5.33 (and the expected size for 0x0127/0x0128).
- Forward Close (0x4E).
"""

from __future__ import annotations

import socket

from enip_farm.cip.admission import Originator
from enip_farm.cip.attribute import CipInstance
from enip_farm.cip.connection_table import ConnectionTable, Opened
from enip_farm.cip.message_router import MAX_NESTING, MessageRouter
from enip_farm.cip.object import CipClass, Reply, ServiceResult
from enip_farm.protocol.cip import CipDecodeError, ClassCode, Service, decode_unconnected_send
from enip_farm.protocol.commands import SocketAddress, decode_sockaddr
from enip_farm.protocol.connection import (
    DecodeError,
    ForwardOpenReply,
    decode_forward_close,
    decode_forward_open,
    encode_connection_failure,
    encode_forward_close_reply,
    encode_forward_open_reply,
)
from enip_farm.protocol.cpf import ItemType
from enip_farm.protocol.epath import PathError, PortSegment, RequestPath, decode_epath
from enip_farm.protocol.session import MessageContext
from enip_farm.protocol.status import ExtendedStatus as X
from enip_farm.protocol.status import GeneralStatus

#: Route paths that mean "this device": none, or the backplane port 1 to slot 0.
_SELF = PortSegment(1, b"\x00")


class ConnectionManager(CipClass):
    class_id = ClassCode.CONNECTION_MANAGER
    revision = 1

    def __init__(self, router: MessageRouter, table: ConnectionTable, unconnected_send: bool = True) -> None:
        super().__init__()
        self.router = router
        self.table = table
        self.instances[1] = CipInstance()
        if unconnected_send:
            self.handlers[Service.UNCONNECTED_SEND] = self.unconnected_send
        self.handlers[Service.FORWARD_OPEN] = self.forward_open
        self.handlers[Service.LARGE_FORWARD_OPEN] = self.large_forward_open
        self.handlers[Service.FORWARD_CLOSE] = self.forward_close

    # -- Unconnected Send -----------------------------------------------------------------------

    def unconnected_send(self, instance: CipInstance, path: RequestPath, data: bytes,
                         context: MessageContext) -> ServiceResult | Reply:
        if context.depth >= MAX_NESTING:
            return ServiceResult(GeneralStatus.RESOURCE_UNAVAILABLE)
        try:
            request = decode_unconnected_send(data)
            route = decode_epath(request.route_path)
        except (CipDecodeError, PathError) as error:
            return ServiceResult(error.status)
        route_words = bytes((len(request.route_path) // 2,))
        if any(not isinstance(segment, PortSegment) for segment in route):
            return ServiceResult(GeneralStatus.PATH_SEGMENT_ERROR, route_words)
        if len(route) > 1 or (route and route[0].port != _SELF.port):
            return ServiceResult(GeneralStatus.CONNECTION_FAILURE, route_words, (X.INVALID_PORT,))
        if route and route[0].link_address != _SELF.link_address:
            return ServiceResult(GeneralStatus.CONNECTION_FAILURE, route_words, (X.INVALID_LINK_ADDRESS,))
        if not request.message:
            return ServiceResult(GeneralStatus.NOT_ENOUGH_DATA)
        return Reply(*self.router.dispatch(request.message, context.nested()))

    # -- Forward Open -----------------------------------------------------------------------------

    def forward_open(self, instance: CipInstance, path: RequestPath, data: bytes,
                     context: MessageContext, large: bool = False) -> ServiceResult:
        try:
            request = decode_forward_open(data, large)
        except DecodeError:
            return ServiceResult(GeneralStatus.NOT_ENOUGH_DATA)
        result = self.table.forward_open(request, _originator(context), context.now)
        if type(result) is not Opened:
            return ServiceResult(result.general, encode_connection_failure(request.triad),
                                 result.additional_status)
        connection = result.connection
        reply = ForwardOpenReply(connection.o_t_id, connection.t_o_id, request.triad, request.o_t_rpi,
                                 request.t_o_rpi, result.application_reply)
        return ServiceResult(GeneralStatus.SUCCESS, encode_forward_open_reply(reply), (), result.reply_items)

    def large_forward_open(self, instance: CipInstance, path: RequestPath, data: bytes,
                           context: MessageContext) -> ServiceResult:
        """As Forward Open, with 32-bit network connection parameters."""
        return self.forward_open(instance, path, data, context, large=True)

    # -- Forward Close ----------------------------------------------------------------------------

    def forward_close(self, instance: CipInstance, path: RequestPath, data: bytes,
                      context: MessageContext) -> ServiceResult:
        try:
            request = decode_forward_close(data)
        except DecodeError:
            return ServiceResult(GeneralStatus.NOT_ENOUGH_DATA)
        if self.table.forward_close(request.triad, context.now, context.peer_host) is None:
            return ServiceResult(GeneralStatus.CONNECTION_FAILURE, encode_connection_failure(request.triad),
                                 (X.CONNECTION_NOT_FOUND,))
        return ServiceResult(GeneralStatus.SUCCESS, encode_forward_close_reply(request.triad))


def _originator(context: MessageContext) -> Originator:
    """The originator of a Forward Open: its host, its T->O socket-address item, its session."""
    t_o: SocketAddress | None = None
    for item in context.items:
        if item.type_id == ItemType.SOCKADDR_T_O:
            address = decode_sockaddr(item.data)
            if address.family == socket.AF_INET:
                t_o = address
    return Originator(context.peer_host, t_o, context.session)
