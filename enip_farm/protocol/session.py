"""Encapsulation session state machine for one TCP connection, and the UDP command handler
(CIP Networks Library Vol. 2, 2-4 and 2-5). Sans-IO: bytes in, whole reply frames out.

The device behind the connection is reached through the `Target` protocol; this module knows
sessions, commands and their status codes, and nothing of CIP objects. A target that restarts
(Identity Reset) ends its sessions: the request that restarted it is answered, then the session
closes, and a session of the target's earlier life answers nothing more (`Target.restarts`).

Requests that get no reply (and change nothing): a NOP (2-4.1, whatever its length); a frame whose
options (2-3.7) or status (2-3.5) is not zero. A message longer than the farm takes is read whole
and discarded, then answered 0x0065 (2-3.3); the connection stays usable.
"""

from __future__ import annotations

import functools
import struct
from typing import NamedTuple, Protocol

from enip_farm.protocol.commands import (
    PROTOCOL_VERSION,
    REGISTER_SESSION,
    decode_connected_message,
    decode_unconnected_message,
    encode_connected_payload,
)
from enip_farm.protocol.cpf import CpfItem, ItemType, encode_items
from enip_farm.protocol.encapsulation import (
    HEADER,
    MAX_DATA_LENGTH,
    Command,
    EncapsulationHeader,
    EncapsulationStatus,
    Frame,
    StreamFramer,
    decode_frame,
)

_SUPPORTED_REGISTER = REGISTER_SESSION.pack(PROTOCOL_VERSION, 0)
# interface handle 0, timeout 0, 2 items: null address, unconnected data (length follows)
_RR_PREFIX = struct.pack("<IHHHHH", 0, 0, 2, ItemType.NULL_ADDRESS, 0, ItemType.UNCONNECTED_DATA)
_UINT = struct.Struct("<H")
_SEND_DATA_HEAD = struct.pack("<IH", 0, 0)  # interface handle, timeout
_SEND_RR_DATA = int(Command.SEND_RR_DATA)
#: Refusals kept until the caller empties `refusals` (the server does after every `receive`, which
#: handles a bounded batch of frames); a caller that never looks costs no more than this.
_MAX_REFUSALS = 256


class MessageContext(NamedTuple):
    """One explicit request's circumstances, immutable: where it came from, the session it came
    on (class-3 connections belong to it), the socket-address items that travelled beside it (a
    Forward Open's T->O address) and the time it arrived (ns, monotonic). The items a reply must
    carry are returned with the reply, never stored here."""

    peer_host: str
    session: object | None
    items: tuple[CpfItem, ...]
    now: int  # ns, monotonic: required, the caller's clock
    depth: int = 0  # how deep in Multiple Service Packets / Unconnected Sends this request is

    def nested(self) -> MessageContext:
        """The context of a request embedded in this one."""
        return self._replace(depth=self.depth + 1)


_new_context = functools.partial(tuple.__new__, MessageContext)  # MessageContext(...) without its Python __new__

#: CPF items (type id, data) that go beside a reply, e.g. a Forward Open's T->O socket address.
ReplyItems = tuple[tuple[int, bytes], ...]
#: A reply message and the items that go beside it.
ReplyWithItems = tuple[bytes, ReplyItems]


class Target(Protocol):
    """What the encapsulation layer needs from a device."""

    @property
    def restarts(self) -> int:
        """How many times the target has restarted: the sessions of an earlier count have ended."""
        ...

    def list_identity_data(self) -> bytes: ...

    def list_services_data(self) -> bytes: ...

    def list_interfaces_data(self) -> bytes: ...

    def register_session(self, peer_host: str = "") -> int | None:
        """A new session handle for a client at `peer_host`, or None when the target takes no more."""
        ...

    def unregister_session(self, session_handle: int) -> None: ...

    def handle_unconnected(self, message: bytes, context: MessageContext) -> ReplyWithItems:
        """An unconnected CIP request in, its whole reply and the items beside it out."""
        ...

    def handle_connected(self, connection_id: int, sequence_count: int, message: bytes,
                         context: MessageContext) -> tuple[int, bytes, ReplyItems] | None:
        """A class-3 request on one of this session's connections: (T->O connection id, reply,
        items), or None when the connection is not this session's."""
        ...

    def session_closed(self, session: object, now: int) -> None:
        """The TCP connection ended: its class-3 connections end with it."""
        ...


def _reply(header: EncapsulationHeader, data: bytes = b"", session_handle: int | None = None,
           status: int = EncapsulationStatus.SUCCESS) -> bytes:
    handle = header.session_handle if session_handle is None else session_handle
    return HEADER.pack(header.command, len(data), handle, status, header.sender_context, 0) + data


class EncapsulationSession:
    """One TCP connection: frames in, replies out; `closing` says the connection must end."""

    __slots__ = ("target", "framer", "session_handle", "closing", "discarded", "peer_host", "last_frame_at", "_now",
                 "refusals", "ignored", "_life")

    def __init__(self, target: Target, peer_host: str = "0.0.0.0", max_length: int = MAX_DATA_LENGTH) -> None:
        self.target = target
        self.framer = StreamFramer(max_length)
        self.session_handle = 0  # 0: no session registered on this connection
        self.closing = False
        self.discarded = 0  # frames with non-zero options or status, discarded as the spec requires
        self.peer_host = peer_host
        self.last_frame_at = 0  # ns: when the last whole frame arrived (encapsulation inactivity)
        self._now = 0
        #: (command, encapsulation status) of every request answered with an error status since the
        #: caller last emptied it (the server reports them as events)
        self.refusals: list[tuple[int, int]] = []
        #: (command, status field) of every request ignored for its non-zero status (Vol. 2, 2-3.5)
        #: since the caller last emptied it, bounded like `refusals`
        self.ignored: list[tuple[int, int]] = []
        self._life = target.restarts  # the target's restart count when this connection began

    def receive(self, data: bytes, now: int, limit: int | None = None) -> list[bytes]:
        """Bytes from the stream, received at `now` (ns, monotonic): the whole replies to send.
        At most `limit` frames are handled; the rest wait for `receive(b"", now, limit)` (see
        `backlog`), so that one busy connection takes its turn like the others."""
        self._now = now
        replies: list[bytes] = []
        frames = self.framer.feed(data, limit)
        if frames:
            self.last_frame_at = now
        for frame in frames:
            reply = self.handle_frame(frame) if type(frame) is Frame else self._oversize(frame.header)
            if reply is not None:
                replies.append(reply)
                if (reply[8] or reply[9]) and len(self.refusals) < _MAX_REFUSALS:  # a non-zero status
                    self.refusals.append((frame.header.command, reply[8] | reply[9] << 8))
            if self.closing:
                break
        return replies

    @property
    def backlog(self) -> bool:
        """Whole frames received and not handled yet (receive was given a limit)."""
        return not self.closing and self.framer.has_frame

    def connection_lost(self, now: int) -> None:
        """The TCP connection ended at `now` (ns): the session ends, its class-3 connections with it."""
        if self.session_handle:
            self.target.unregister_session(self.session_handle)
            self.session_handle = 0
            self.target.session_closed(self, now)

    def _ignores(self, header: EncapsulationHeader) -> bool:
        """Whether a request gets no reply and does nothing: the target restarted since the
        connection began (which ends it), or the options (2-3.7) or the status (2-3.5) is not zero."""
        if self.target.restarts != self._life:  # a connection of the target's earlier life
            self.closing = True
            return True
        if header.options or header.status:
            self.discarded += 1
            if header.status and len(self.ignored) < _MAX_REFUSALS:
                self.ignored.append((header.command, header.status))
            return True
        return False

    def _oversize(self, header: EncapsulationHeader) -> bytes | None:
        """A message longer than the farm takes, read whole and discarded (2-3.3): 0x0065, but a NOP
        (which may carry 0-65511 bytes) gets nothing."""
        if self._ignores(header) or header.command == Command.NOP:
            return None
        return _reply(header, status=EncapsulationStatus.INVALID_LENGTH)

    def handle_frame(self, frame: Frame) -> bytes | None:
        header, data = frame
        if (header.options or header.status or self.target.restarts != self._life) and self._ignores(header):
            return None
        command = header.command
        if command == _SEND_RR_DATA:  # the hot path first
            return self._send_rr_data(header, data)
        if command == Command.NOP:
            return None
        if command == Command.REGISTER_SESSION:
            return self._register_session(header, data)
        if command == Command.UNREGISTER_SESSION:
            if header.session_handle and header.session_handle == self.session_handle:
                self.connection_lost(self._now)
                self.closing = True
                return None
            return _reply(header, status=EncapsulationStatus.INVALID_SESSION_HANDLE)
        if command == Command.LIST_IDENTITY:
            return _reply(header, self.target.list_identity_data(), 0)
        if command == Command.LIST_SERVICES:
            return _reply(header, self.target.list_services_data(), 0)
        if command == Command.LIST_INTERFACES:
            return _reply(header, self.target.list_interfaces_data(), 0)
        if command == Command.SEND_UNIT_DATA:
            return self._send_unit_data(header, data)
        return _reply(header, status=EncapsulationStatus.INVALID_COMMAND)

    def _register_session(self, header: EncapsulationHeader, data: bytes) -> bytes:
        if len(data) != REGISTER_SESSION.size:
            return _reply(header, _SUPPORTED_REGISTER, 0, EncapsulationStatus.INVALID_LENGTH)
        version, options = REGISTER_SESSION.unpack(data)
        if version != PROTOCOL_VERSION or options != 0:
            return _reply(header, _SUPPORTED_REGISTER, 0, EncapsulationStatus.UNSUPPORTED_PROTOCOL)
        if self.session_handle:  # one session per TCP connection
            return _reply(header, _SUPPORTED_REGISTER, self.session_handle, EncapsulationStatus.INVALID_COMMAND)
        handle = self.target.register_session(self.peer_host)
        if handle is None:  # the device holds all the sessions it takes; this connection stays usable
            return _reply(header, _SUPPORTED_REGISTER, 0, EncapsulationStatus.INSUFFICIENT_MEMORY)
        self.session_handle = handle
        return _reply(header, _SUPPORTED_REGISTER, handle)

    def _restarted(self) -> None:
        """After a request: if it restarted the target, its reply is this connection's last."""
        if self.target.restarts != self._life:
            self.closing = True

    def _send_rr_data(self, header: EncapsulationHeader, data: bytes) -> bytes:
        if not header.session_handle or header.session_handle != self.session_handle:
            return _reply(header, status=EncapsulationStatus.INVALID_SESSION_HANDLE)
        decoded = decode_unconnected_message(data)
        if decoded is None:
            return _reply(header, status=EncapsulationStatus.INCORRECT_DATA)
        request, items = decoded
        message, reply_items = self.target.handle_unconnected(
            request, _new_context((self.peer_host, self, items, self._now, 0)))
        self._restarted()
        if reply_items:  # e.g. the T->O socket address of a multicast Forward Open
            body = _SEND_DATA_HEAD + encode_items([(ItemType.NULL_ADDRESS, b""), (ItemType.UNCONNECTED_DATA, message),
                                                   *reply_items])
        else:
            body = _RR_PREFIX + _UINT.pack(len(message)) + message
        return HEADER.pack(_SEND_RR_DATA, len(body), header.session_handle, 0, header.sender_context, 0) + body

    def _send_unit_data(self, header: EncapsulationHeader, data: bytes) -> bytes | None:
        if not header.session_handle or header.session_handle != self.session_handle:
            return _reply(header, status=EncapsulationStatus.INVALID_SESSION_HANDLE)
        decoded = decode_connected_message(data)
        if decoded is None:
            return _reply(header, status=EncapsulationStatus.INCORRECT_DATA)
        connection_id, sequence_count, message, items = decoded
        answer = self.target.handle_connected(connection_id, sequence_count, message,
                                              MessageContext(self.peer_host, self, tuple(items), self._now))
        self._restarted()
        if answer is None:  # not a connection of this session: say so rather than stay silent
            return _reply(header, status=EncapsulationStatus.INCORRECT_DATA)
        t_o_id, reply, reply_items = answer
        return _reply(header, encode_connected_payload(t_o_id, sequence_count, reply, reply_items))


def handle_datagram(target: Target, datagram: bytes) -> bytes | None:
    """UDP 44818: ListIdentity, ListServices and ListInterfaces are answered (Table 2-3.2 allows
    each over UDP); anything else gets no reply, and so does a request whose options (2-3.7) or
    status (2-3.5) is not zero."""
    try:
        header, _ = decode_frame(datagram)
    except ValueError:
        return None
    if header.options or header.status:
        return None
    if header.command == Command.LIST_IDENTITY:
        return _reply(header, target.list_identity_data(), 0)
    if header.command == Command.LIST_SERVICES:
        return _reply(header, target.list_services_data(), 0)
    if header.command == Command.LIST_INTERFACES:
        return _reply(header, target.list_interfaces_data(), 0)
    return None
