"""Message Router, class 0x02 (CIP Networks Library Vol. 1, 5-3 and 2-4): decodes each explicit
request, dispatches it by class id, and answers Multiple Service Packet (0x0A) unless the device's
profile says it does not (a non-routing adapter such as OpENer answers 0x08).

Instance 1 attributes (Vol. 1, 5-3): 1 object list (UINT count, class ids), 2 number available
(UINT: the maximum number of connections supported), 3 number active (UINT: connections open now)."""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Callable

from enip_farm.cip.attribute import Attribute, CipInstance
from enip_farm.cip.data_types import UINT, UINT_LIST
from enip_farm.cip.object import CipClass, Effect, Reply, ReplyItems, ServiceResult
from enip_farm.protocol.cip import (
    REPLY_BIT,
    CipDecodeError,
    ClassCode,
    Service,
    decode_multiple_service_request,
    decode_request,
    encode_multiple_service,
    encode_reply,
)
from enip_farm.protocol.epath import PathError, RequestPath, decode_request_path
from enip_farm.protocol.session import MessageContext
from enip_farm.protocol.status import GeneralStatus

_PATH_CACHE_SIZE = 4096
#: Requests may be embedded in Multiple Service Packets and Unconnected Sends this deep, no deeper:
#: a deeper one is answered 0x02 (resource unavailable), at a bounded cost.
MAX_NESTING = 4
#: Replies by which the model says it does not implement a request: unknown object, service, attribute.
_NOT_IMPLEMENTED = (0x05, 0x08, 0x14)
log = logging.getLogger(__name__)
#: One request as answered: (service, request path, general status, first extended status word or
#: None, relayed) where `relayed` says the reply is an embedded request's, passed on as it is
#: (Unconnected Send), so its status was counted for that request already.
Handled = tuple[int, bytes, int, "int | None", bool]


class MessageRouter(CipClass):
    """The message router object and the dispatcher of every unconnected request of one device."""

    class_id = ClassCode.MESSAGE_ROUTER
    revision = 1
    #: Get Attributes All of the class: revision, the optional attribute and service lists, the
    #: highest ids (the layout Wireshark's CIP dissector decodes for the message router)
    class_get_all = (1, 4, 5, 6, 7)

    def __init__(self, multiple_service_packet: bool = True, max_connections: int = 0,
                 active_connections: Callable[[], int] = lambda: 0) -> None:
        super().__init__()
        self.objects: dict[int, CipClass] = {self.class_id: self}
        self.forced_status: dict[int, int] = {}  # fault injection: service -> general status
        self.request_counts: Counter[tuple[int, int]] = Counter()  # (service, general status)
        self.handled: list[Handled] = []  # since pop_handled
        self.effects: list[Effect] = []  # what the services answered since pop_effects asked of the device
        self.replay: dict[tuple[int, bytes, bytes], bytes] = {}  # a learned profile's replay table
        self._paths: dict[bytes, RequestPath | int] = {}
        if multiple_service_packet:
            self.handlers[Service.MULTIPLE_SERVICE_PACKET] = self.multiple_service_packet
        self.instances[1] = CipInstance((
            Attribute(1, UINT_LIST, lambda: tuple(sorted(self.objects))),
            Attribute(2, UINT, value=max_connections),
            Attribute(3, UINT, active_connections),
        ))

    def register(self, obj: CipClass) -> None:
        self.objects[obj.class_id] = obj

    def handle(self, message: bytes, context: MessageContext) -> bytes:
        """A whole request in, a whole reply out (the items beside it, if any, are left out)."""
        return self.dispatch(message, context)[0]

    def dispatch(self, message: bytes, context: MessageContext) -> tuple[bytes, ReplyItems]:
        """A whole request in, a whole reply and its CPF items out. Errors are replies, never
        exceptions. Each reply is counted by service and status and kept for `pop_handled`."""
        reply = self._dispatch(message, context)
        status = reply[0][2]
        if self.replay and status in _NOT_IMPLEMENTED:  # the model first, then the replay table
            request = decode_request(message) if len(message) >= 2 else None
            recorded = self.replay.get((request.service, request.path, request.data)) if request else None
            if recorded is not None:
                reply = recorded, ()
                status = recorded[2]
        service = message[0] if message else 0
        self.request_counts[service, status] += 1
        head = reply[0]
        extended = head[4] | head[5] << 8 if status and len(head) >= 6 and head[3] else None
        self.handled.append((service, message[2 : 2 + 2 * message[1]] if len(message) > 1 else b"", status,
                             extended, type(reply) is Reply))
        return reply

    def pop_handled(self) -> list[Handled]:
        """The requests answered since the last call, embedded ones too (see `Handled`)."""
        handled, self.handled = self.handled, []
        return handled

    def pop_effects(self) -> list[Effect]:
        """The effects the services returned since the last call, embedded requests' too, in order."""
        effects, self.effects = self.effects, []
        return effects

    def _dispatch(self, message: bytes, context: MessageContext) -> tuple[bytes, ReplyItems]:
        try:
            service, path_bytes, data = decode_request(message)
        except CipDecodeError as error:
            return encode_reply(message[0] if message else 0, error.status), ()
        path = self._paths.get(path_bytes)
        if path is None:
            try:
                path = decode_request_path(path_bytes)
            except PathError as error:
                path = int(error.status)
            if len(self._paths) < _PATH_CACHE_SIZE:
                self._paths[path_bytes] = path
        if type(path) is int:
            return encode_reply(service, path), ()
        if self.forced_status and service in self.forced_status:
            return encode_reply(service, self.forced_status[service]), ()
        if service & REPLY_BIT:
            return encode_reply(service, GeneralStatus.SERVICE_NOT_SUPPORTED), ()
        obj = self.objects.get(path.class_id)
        if obj is None:
            return encode_reply(service, GeneralStatus.PATH_DESTINATION_UNKNOWN), ()
        instance = obj.instance(path.instance_id)
        if instance is None:
            return encode_reply(service, GeneralStatus.PATH_DESTINATION_UNKNOWN), ()
        handler = obj.handlers.get(service)
        if handler is None:
            return encode_reply(service, GeneralStatus.SERVICE_NOT_SUPPORTED), ()
        try:
            result = handler(instance, path, data, context)
        except Exception:  # a defect in an object must not cost the client its connection
            log.exception("class 0x%02X service 0x%02X failed", path.class_id, service)
            return encode_reply(service, GeneralStatus.VENDOR_SPECIFIC), ()
        if type(result) is Reply:
            return result
        if result[4]:
            self.effects.extend(result[4])
        return encode_reply(service, result[0], result[1], result[2]), result[3]

    def multiple_service_packet(self, instance: CipInstance, path: RequestPath, data: bytes,
                                context: MessageContext) -> ServiceResult:
        if path.instance_id != 1:
            return ServiceResult(GeneralStatus.SERVICE_NOT_SUPPORTED)
        if context.depth >= MAX_NESTING:
            return ServiceResult(GeneralStatus.RESOURCE_UNAVAILABLE)
        try:
            requests = decode_multiple_service_request(data)
        except CipDecodeError as error:
            return ServiceResult(error.status)
        inner = context.nested()
        replies = [self.handle(request, inner) for request in requests]
        failed = any(reply[2] != GeneralStatus.SUCCESS for reply in replies)
        status = GeneralStatus.EMBEDDED_SERVICE_ERROR if failed else GeneralStatus.SUCCESS
        return ServiceResult(status, encode_multiple_service(replies))

