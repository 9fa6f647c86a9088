"""Connection Manager, class 0x06 (CIP Networks Library Vol. 1, 3-5.5): Unconnected Send (0x52)
addressed to this device. The embedded request is answered by the message router and its reply
returned as it is (Vol. 1, 3-5.5.2.2). Forward Open and Forward Close belong to implicit I/O and
are not implemented here: they get 0x08."""

from __future__ import annotations

from enip_farm.cip.message_router import MessageRouter
from enip_farm.cip.object import CipClass, CipInstance, ServiceResult
from enip_farm.protocol.cip import CipDecodeError, Service, decode_unconnected_send
from enip_farm.protocol.epath import PathError, PortSegment, RequestPath, decode_epath
from enip_farm.protocol.status import ExtendedStatus, GeneralStatus

#: Route paths that mean "this device": none, or the backplane port 1 to slot 0.
_SELF = PortSegment(1, b"\x00")


class ConnectionManager(CipClass):
    class_id = 0x06
    revision = 1

    def __init__(self, router: MessageRouter) -> None:
        super().__init__()
        self.router = router
        self.instances[1] = CipInstance({})
        self.handlers[Service.UNCONNECTED_SEND] = self.unconnected_send

    def unconnected_send(self, instance: CipInstance, path: RequestPath, data: bytes) -> ServiceResult | bytes:
        try:
            request = decode_unconnected_send(data)
            route = decode_epath(request.route_path)
        except (CipDecodeError, PathError) as error:
            return ServiceResult(error.status)
        route_words = bytes((len(request.route_path) // 2,))
        if any(not isinstance(segment, PortSegment) for segment in route):
            return ServiceResult(GeneralStatus.PATH_SEGMENT_ERROR, route_words)
        if len(route) > 1 or (route and route[0].port != _SELF.port):
            return ServiceResult(GeneralStatus.CONNECTION_FAILURE, route_words, (ExtendedStatus.INVALID_PORT,))
        if route and route[0].link_address != _SELF.link_address:
            return ServiceResult(GeneralStatus.CONNECTION_FAILURE, route_words,
                                 (ExtendedStatus.INVALID_LINK_ADDRESS,))
        if not request.message:
            return ServiceResult(GeneralStatus.NOT_ENOUGH_DATA)
        return self.router.handle(request.message)
