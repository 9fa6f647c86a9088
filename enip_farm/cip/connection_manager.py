"""Connection Manager, class 0x06 (CIP Networks Library Vol. 1, 3-5.5).

- Unconnected Send (0x52) addressed to this device: the embedded request is answered by the
  message router and its reply returned as it is (3-5.5.2).
- Forward Open (0x54) and Large Forward Open (0x5B): class-1 I/O connections to the device's
  assemblies (exclusive owner, input only, listen only) and class-3 explicit connections to the
  message router, each refusal with the extended status of table 3-5.33.
- Forward Close (0x4E).
"""

from __future__ import annotations

import socket
from typing import TYPE_CHECKING

from enip_farm.cip.connection import Connection, ConnectionKind
from enip_farm.cip.message_router import MessageRouter
from enip_farm.cip.object import CipClass, CipInstance, ServiceResult
from enip_farm.protocol.cip import CipDecodeError, Service, decode_unconnected_send
from enip_farm.protocol.commands import SocketAddress, decode_sockaddr, encode_sockaddr
from enip_farm.protocol.connection import (
    ConnectionType,
    DecodeError,
    ForwardOpenReply,
    ForwardOpenRequest,
    decode_forward_close,
    decode_forward_open,
    encode_connection_failure,
    encode_forward_close_reply,
    encode_forward_open_reply,
)
from enip_farm.protocol.cpf import ItemType
from enip_farm.protocol.epath import (
    DataSegment,
    ElectronicKey,
    LogicalSegment,
    LogicalType,
    PathError,
    PortSegment,
    RequestPath,
    decode_epath,
)
from enip_farm.protocol.session import MessageContext
from enip_farm.protocol.status import ExtendedStatus as X
from enip_farm.protocol.status import GeneralStatus

if TYPE_CHECKING:
    from enip_farm.device.device import Device

#: Route paths that mean "this device": none, or the backplane port 1 to slot 0.
_SELF = PortSegment(1, b"\x00")
IO_PORT = 2222
_CLASS_1 = 0x01
_CLASS_3 = 0x03
_ASSEMBLY = 0x04
_MESSAGE_ROUTER = 0x02
SEQUENCE_COUNT_SIZE = 2
RUN_IDLE_HEADER_SIZE = 4


class Refusal(Exception):
    def __init__(self, extended: int, general: int = GeneralStatus.CONNECTION_FAILURE) -> None:
        super().__init__(f"0x{extended:04X}")
        self.extended = extended
        self.general = general


class ConnectionManager(CipClass):
    class_id = 0x06
    revision = 1

    def __init__(self, router: MessageRouter, device: Device) -> None:
        super().__init__()
        self.router = router
        self.device = device
        self.instances[1] = CipInstance({})
        self.handlers[Service.UNCONNECTED_SEND] = self.unconnected_send
        self.handlers[Service.FORWARD_OPEN] = self.forward_open
        self.handlers[Service.LARGE_FORWARD_OPEN] = self.large_forward_open
        self.handlers[Service.FORWARD_CLOSE] = self.forward_close

    # -- Unconnected Send -----------------------------------------------------------------------

    def unconnected_send(self, instance: CipInstance, path: RequestPath, data: bytes,
                         context: MessageContext) -> ServiceResult | bytes:
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
        return self.router.handle(request.message, context)

    # -- Forward Open -----------------------------------------------------------------------------

    def forward_open(self, instance: CipInstance, path: RequestPath, data: bytes,
                     context: MessageContext, large: bool = False) -> ServiceResult:
        try:
            request = decode_forward_open(data, large)
        except DecodeError:
            return ServiceResult(GeneralStatus.NOT_ENOUGH_DATA)
        try:
            connection = self._admit(request, context)
        except Refusal as refusal:
            return ServiceResult(refusal.general, encode_connection_failure(request.triad), (refusal.extended,))
        self.device.open_connection(connection)
        if connection.multicast:  # the originator learns the group from the reply (Vol. 2, 3-3.9.4)
            context.reply_items.append(
                (ItemType.SOCKADDR_T_O, encode_sockaddr(SocketAddress(*connection.t_o_address))))  # type: ignore[misc]
        reply = ForwardOpenReply(connection.o_t_id, connection.t_o_id, request.triad, request.o_t_rpi,
                                 request.t_o_rpi)
        return ServiceResult(GeneralStatus.SUCCESS, encode_forward_open_reply(reply))

    def large_forward_open(self, instance: CipInstance, path: RequestPath, data: bytes,
                           context: MessageContext) -> ServiceResult:
        """As Forward Open, with 32-bit network connection parameters."""
        return self.forward_open(instance, path, data, context, large=True)

    def _admit(self, request: ForwardOpenRequest, context: MessageContext) -> Connection:
        device = self.device
        if device.find_connection(request.triad) is not None:
            raise Refusal(X.CONNECTION_IN_USE)
        o_t_type = request.o_t_parameters.connection_type
        t_o_type = request.t_o_parameters.connection_type
        if o_t_type == ConnectionType.NULL and t_o_type == ConnectionType.NULL:
            raise Refusal(X.NULL_FORWARD_OPEN_NOT_SUPPORTED)
        transport = request.transport_class
        if transport == _CLASS_3 and request.transport_type_trigger & 0x80:
            return self._admit_explicit(request, context)
        if transport != _CLASS_1 or request.production_trigger != 0:  # class 1, cyclic
            raise Refusal(X.TRANSPORT_TRIGGER_NOT_SUPPORTED)
        points = self._io_points(request.connection_path)
        return self._admit_io(request, points, context)

    def _check_key(self, key: ElectronicKey) -> None:
        p = self.device.profile
        if ((key.vendor_id and key.vendor_id != p.vendor_id)
                or (key.product_code and key.product_code != self.device.product_code)):
            raise Refusal(X.VENDOR_OR_PRODUCT_MISMATCH)
        if key.device_type and key.device_type != p.device_type:
            raise Refusal(X.DEVICE_TYPE_MISMATCH)
        major, minor = p.revision
        if key.major_revision:
            if key.compatibility:  # any revision that can emulate the requested one
                if key.major_revision != major or (key.minor_revision and key.minor_revision > minor):
                    raise Refusal(X.REVISION_MISMATCH)
            elif key.major_revision != major or (key.minor_revision and key.minor_revision != minor):
                raise Refusal(X.REVISION_MISMATCH)

    def _path_segments(self, connection_path: bytes) -> list:
        try:
            segments = decode_epath(connection_path)
        except PathError:
            raise Refusal(X.INVALID_SEGMENT) from None
        while segments and segments[0] == _SELF:  # a route to this device itself
            segments.pop(0)
        if segments and isinstance(segments[0], ElectronicKey):
            self._check_key(segments.pop(0))
        return segments

    def _io_points(self, connection_path: bytes) -> tuple[int | None, int, int]:
        """(configuration, consuming O->T, producing T->O) points of an assembly connection path."""
        segments = [s for s in self._path_segments(connection_path) if not isinstance(s, DataSegment)]
        if not segments or segments[0] != LogicalSegment(LogicalType.CLASS_ID, _ASSEMBLY):
            raise Refusal(X.INVALID_SEGMENT)
        values = []
        for segment in segments[1:]:
            if not isinstance(segment, LogicalSegment) or segment.type not in (
                    LogicalType.INSTANCE_ID, LogicalType.CONNECTION_POINT):
                raise Refusal(X.INVALID_SEGMENT)
            values.append(segment.value)
        if len(values) == 3:
            return values[0], values[1], values[2]
        if len(values) == 2:
            return None, values[0], values[1]
        raise Refusal(X.INVALID_SEGMENT)

    def _admit_io(self, request: ForwardOpenRequest, points: tuple[int | None, int, int],
                  context: MessageContext) -> Connection:
        device = self.device
        profile = device.profile
        policy = profile.implicit
        configuration, consuming, producing = points
        config_assembly = device.assemblies.get("configuration")
        if configuration is not None and (config_assembly is None or configuration != config_assembly.instance_id):
            raise Refusal(X.INVALID_CONFIGURATION_PATH)
        output = device.assemblies.get("output")
        inputs = device.assemblies.get("input")
        if output is not None and consuming == output.instance_id:
            kind = ConnectionKind.EXCLUSIVE_OWNER
        elif consuming == profile.input_only_point:
            kind = ConnectionKind.INPUT_ONLY
        elif consuming == profile.listen_only_point:
            kind = ConnectionKind.LISTEN_ONLY
        else:
            raise Refusal(X.INVALID_CONSUMING_PATH)
        if inputs is None or producing != inputs.instance_id:
            raise Refusal(X.INVALID_PRODUCING_PATH)
        o_t, t_o = request.o_t_parameters, request.t_o_parameters
        if o_t.connection_type != ConnectionType.POINT_TO_POINT or t_o.connection_type not in (
                ConnectionType.POINT_TO_POINT, ConnectionType.MULTICAST):
            raise Refusal(X.INVALID_CONNECTION_TYPE)
        for rpi in (request.o_t_rpi, request.t_o_rpi):
            if not policy.rpi_min_us <= rpi <= policy.rpi_max_us:
                raise Refusal(X.RPI_NOT_SUPPORTED)
        # O->T: sequence count, 32-bit run/idle header, data; heartbeats carry no data (header optional)
        if kind is ConnectionKind.EXCLUSIVE_OWNER:
            accepted = {SEQUENCE_COUNT_SIZE + RUN_IDLE_HEADER_SIZE + len(output.data)}  # type: ignore[union-attr]
        else:
            accepted = {SEQUENCE_COUNT_SIZE, SEQUENCE_COUNT_SIZE + RUN_IDLE_HEADER_SIZE}
        if not (o_t.size in accepted or (o_t.variable and o_t.size >= min(accepted))):
            raise Refusal(X.INVALID_O_T_SIZE)
        expected_t_o = SEQUENCE_COUNT_SIZE + len(inputs.data)  # modeless
        if not (t_o.size == expected_t_o or (t_o.variable and t_o.size >= expected_t_o)):
            raise Refusal(X.INVALID_T_O_SIZE)

        io_connections = [c for c in device.connections.values() if c.is_io]
        if kind is ConnectionKind.EXCLUSIVE_OWNER and any(
                c.kind is ConnectionKind.EXCLUSIVE_OWNER and c.o_t_point == consuming for c in io_connections):
            raise Refusal(X.OWNERSHIP_CONFLICT)
        multicast = t_o.connection_type == ConnectionType.MULTICAST
        shared = next((c for c in io_connections if c.multicast and c.t_o_point == producing
                       and c.kind is not ConnectionKind.LISTEN_ONLY), None) if multicast else None
        if kind is ConnectionKind.LISTEN_ONLY and shared is None:
            raise Refusal(X.NON_LISTEN_ONLY_NOT_OPENED)
        if shared is not None and shared.t_o_rpi != request.t_o_rpi:
            raise Refusal(X.RPI_NOT_SUPPORTED)
        if len(io_connections) >= policy.max_class1_connections:
            raise Refusal(X.OUT_OF_CONNECTIONS)

        if multicast:
            t_o_id = shared.t_o_id if shared else device.new_connection_id()
            t_o_address = (profile.multicast_group, IO_PORT)
        else:
            t_o_id = request.t_o_connection_id
            t_o_address = self._point_to_point_address(context)
        return Connection(
            kind=kind, triad=request.triad, o_t_id=device.new_connection_id(), t_o_id=t_o_id,
            o_t_rpi=request.o_t_rpi, t_o_rpi=request.t_o_rpi, timeout_multiplier=request.timeout_multiplier,
            originator_host=context.peer_host, t_o_address=t_o_address, multicast=multicast,
            o_t_point=consuming, t_o_point=producing,
            o_t_run_idle_header=kind is ConnectionKind.EXCLUSIVE_OWNER,
        )

    @staticmethod
    def _point_to_point_address(context: MessageContext) -> tuple[str, int]:
        """The originator's T->O socket-address item, where given (address 0: the originator)."""
        host, port = context.peer_host, IO_PORT
        for item in context.items:
            if item.type_id == ItemType.SOCKADDR_T_O:
                address = decode_sockaddr(item.data)
                if address.family == socket.AF_INET and address.port:
                    port = address.port
                if address.host != "0.0.0.0":
                    host = address.host
        return host, port

    def _admit_explicit(self, request: ForwardOpenRequest, context: MessageContext) -> Connection:
        segments = self._path_segments(request.connection_path)
        if segments[:2] != [LogicalSegment(LogicalType.CLASS_ID, _MESSAGE_ROUTER),
                            LogicalSegment(LogicalType.INSTANCE_ID, 1)] or len(segments) != 2:
            raise Refusal(X.INVALID_SEGMENT)
        if (request.o_t_parameters.connection_type != ConnectionType.POINT_TO_POINT
                or request.t_o_parameters.connection_type != ConnectionType.POINT_TO_POINT):
            raise Refusal(X.INVALID_CONNECTION_TYPE)
        device = self.device
        explicit = [c for c in device.connections.values() if not c.is_io]
        if len(explicit) >= device.profile.implicit.max_class3_connections:
            raise Refusal(X.OUT_OF_CONNECTIONS)
        return Connection(
            kind=ConnectionKind.EXPLICIT, triad=request.triad, o_t_id=device.new_connection_id(),
            t_o_id=request.t_o_connection_id, o_t_rpi=request.o_t_rpi, t_o_rpi=request.t_o_rpi,
            timeout_multiplier=request.timeout_multiplier, originator_host=context.peer_host, owner=context.owner,
        )

    # -- Forward Close ----------------------------------------------------------------------------

    def forward_close(self, instance: CipInstance, path: RequestPath, data: bytes,
                      context: MessageContext) -> ServiceResult:
        try:
            request = decode_forward_close(data)
        except DecodeError:
            return ServiceResult(GeneralStatus.NOT_ENOUGH_DATA)
        connection = self.device.find_connection(request.triad)
        if connection is None:
            return ServiceResult(GeneralStatus.CONNECTION_FAILURE, encode_connection_failure(request.triad),
                                 (X.CONNECTION_NOT_FOUND,))
        self.device.close_connection(connection, "forward close")
        return ServiceResult(GeneralStatus.SUCCESS, encode_forward_close_reply(request.triad))
