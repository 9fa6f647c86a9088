"""Golden testing: replay the client side of a capture against farm devices over real TCP and UDP
connections, and compare every reply with the captured one field by field (capture/compare.py).

What the farm numbers itself is mapped, as session handles are (`ReplayMap`): each Forward Open
(Vol. 1 3-5.5.2) is sent with a fresh connection serial, so a replay never collides with a
connection still open on the farm (a second replay, or the recorded client's own), and its Forward
Close with the same; each SendUnitData (Vol. 2, 2-4) goes to the O->T connection id the farm gave
that Forward Open. A capture that starts mid-session gets a session registered by golden, and one
that starts mid-connection a class-3 connection opened by golden, both mapped in their place.
"""

from __future__ import annotations

import random
import socket
import struct
from collections.abc import Callable
from dataclasses import dataclass

from enip_farm.capture.compare import Difference, ReplayMap, compare_replies
from enip_farm.capture.exchanges import Exchange
from enip_farm.protocol.cip import (
    CipDecodeError,
    ClassCode,
    Service,
    decode_reply,
    decode_request,
    decode_unconnected_send,
    encode_request,
    encode_unconnected_send,
)
from enip_farm.protocol.commands import decode_send_data, encode_send_data, encode_unconnected_payload
from enip_farm.protocol.connection import (
    ConnectionTriad,
    ConnectionType,
    DecodeError,
    ForwardOpenRequest,
    NetworkParameters,
    decode_forward_close,
    decode_forward_open,
    decode_forward_open_reply,
    encode_forward_close,
    encode_forward_open,
)
from enip_farm.protocol.cpf import ItemType
from enip_farm.protocol.encapsulation import ENIP_PORT, HEADER, Command, Frame, StreamFramer, decode_frame, encode_frame
from enip_farm.protocol.epath import PathError, decode_request_path, encode_request_path

TIMEOUT = 5.0
_CONNECTION_MANAGER = (ClassCode.CONNECTION_MANAGER, 1)
_MESSAGE_ROUTER_PATH = encode_request_path(ClassCode.MESSAGE_ROUTER, 1)


@dataclass
class Result:
    exchange: Exchange
    differences: list[Difference]
    note: str = ""

    @property
    def passed(self) -> bool:
        return not self.differences and not self.note

    def line(self) -> str:
        e = self.exchange
        where = f"{e.transport} stream {e.stream} #{e.number}" if e.transport == "tcp" else f"udp #{e.number}"
        what = Command(e.request.header.command).name if e.request.header.command in Command._value2member_map_ \
            else f"command 0x{e.request.header.command:04X}"
        if self.passed:
            return f"PASS  {where} {what}"
        detail = self.note or "; ".join(f"{name}: captured {a} != farm {b}" for name, a, b in self.differences)
        return f"FAIL  {where} {what}  {detail}"


def _with_session(frame: Frame, handle: int, data: bytes | None = None) -> bytes:
    h = frame.header
    return HEADER.pack(h.command, h.length, handle, h.status, h.sender_context, h.options) + (
        frame.data if data is None else data)


class _Rewriter:
    """Rewrites a captured request's connection serials and connection ids to the replay's. Only
    requests the project's codec reproduces byte for byte are touched, so a malformed captured
    request is replayed exactly as it was."""

    def __init__(self, mapping: ReplayMap, rng: random.Random) -> None:
        self.mapping = mapping
        self.rng = rng

    def fresh_serial(self) -> int:
        used = {triad.connection_serial for triad in (*self.mapping.triads.values(), *self.mapping.adopted)}
        while (serial := self.rng.getrandbits(16)) in used:
            pass
        return serial

    def send_data(self, data: bytes) -> bytes:
        try:
            send = decode_send_data(data)
        except ValueError:
            return data
        items = [(item.type_id, item.data) for item in send.items]
        if encode_send_data(items, send.timeout, send.interface_handle) != data:
            return data
        for index, (type_id, body) in enumerate(items):
            if type_id == ItemType.CONNECTED_ADDRESS and len(body) == 4:
                captured = int.from_bytes(body, "little")
                items[index] = (type_id, self.mapping.o_t_ids.get(captured, captured).to_bytes(4, "little"))
            elif type_id == ItemType.CONNECTED_DATA and len(body) > 2:
                items[index] = (type_id, body[:2] + self.message(body[2:]))  # the sequence count as captured
            elif type_id == ItemType.UNCONNECTED_DATA:
                items[index] = (type_id, self.message(body))
        return encode_send_data(items, send.timeout, send.interface_handle)

    def message(self, message: bytes) -> bytes:
        """A CIP request with its Forward Open or Forward Close serial (also inside Unconnected Send)
        mapped."""
        try:
            request = decode_request(message)
            path = decode_request_path(request.path)
        except (CipDecodeError, PathError):
            return message
        if (path.class_id, path.instance_id) != _CONNECTION_MANAGER or \
                encode_request(request.service, request.path, request.data) != message:
            return message
        try:
            data = self._connection_manager(request.service, request.data)
        except (CipDecodeError, DecodeError):
            return message
        return encode_request(request.service, request.path, data)

    def _connection_manager(self, service: int, data: bytes) -> bytes:
        if service == Service.UNCONNECTED_SEND:
            send = decode_unconnected_send(data)
            if encode_unconnected_send(send.message, send.route_path, send.priority_time_tick,
                                       send.timeout_ticks) != data:
                return data
            return encode_unconnected_send(self.message(send.message), send.route_path, send.priority_time_tick,
                                           send.timeout_ticks)
        if service in (Service.FORWARD_OPEN, Service.LARGE_FORWARD_OPEN):
            request = decode_forward_open(data, service == Service.LARGE_FORWARD_OPEN)
            if encode_forward_open(request) != data:
                return data
            if request.triad not in self.mapping.triads:
                self.mapping.triads[request.triad] = request.triad._replace(connection_serial=self.fresh_serial())
            self.mapping.sent_t_o_ids.add(request.t_o_connection_id)
            return encode_forward_open(request._replace(triad=self.mapping.triads[request.triad]))
        if service == Service.FORWARD_CLOSE:
            close = decode_forward_close(data)
            if encode_forward_close(close) != data:
                return data
            if close.triad not in self.mapping.triads and self.mapping.adopted:
                # the capture closes a connection it opened before it started: golden's stands in for it
                self.mapping.triads[close.triad] = self.mapping.adopted.pop(0)
            return encode_forward_close(close._replace(triad=self.mapping.triad(close.triad)))
        return data


class _Connection:
    def __init__(self, host: str) -> None:
        self.sock = socket.create_connection((host, ENIP_PORT), timeout=TIMEOUT)
        self.framer = StreamFramer(max_length=65535)
        self.pending: list[Frame] = []

    def send(self, data: bytes) -> None:
        self.sock.sendall(data)

    def receive(self) -> Frame | None:
        while not self.pending:
            try:
                data = self.sock.recv(65536)
            except OSError:
                return None
            if not data:
                return None
            self.pending += [f for f in self.framer.feed(data) if type(f) is Frame]
        return self.pending.pop(0)

    def close(self) -> None:
        self.sock.close()


def _captured_connection_ids(exchanges: list[Exchange]) -> set[int]:
    """The O->T connection ids the captured Forward Open replies of a stream gave."""
    ids = set()
    for exchange in exchanges:
        if exchange.reply is None or exchange.request.header.command not in (Command.SEND_RR_DATA,
                                                                              Command.SEND_UNIT_DATA):
            continue
        try:
            items = decode_send_data(exchange.reply.data).items
            data = next(i.data for i in items if i.type_id in (ItemType.UNCONNECTED_DATA, ItemType.CONNECTED_DATA))
            reply = decode_reply(data[2:] if exchange.request.header.command == Command.SEND_UNIT_DATA else data)
            if reply.service in (0xD4, 0xDB) and reply.general_status == 0:
                ids.add(decode_forward_open_reply(reply.data).o_t_connection_id)
        except (ValueError, StopIteration, IndexError, struct.error):
            continue
    return ids


def _connection_id(frame: Frame | None) -> int | None:
    """The connection id of a SendUnitData frame's connected address item."""
    try:
        item = decode_send_data(frame.data).items[0]  # type: ignore[union-attr]
    except (AttributeError, ValueError, IndexError):
        return None
    return int.from_bytes(item.data, "little") if item.type_id == ItemType.CONNECTED_ADDRESS \
        and len(item.data) == 4 else None


def _open_class3(connection: _Connection, session: int, t_o_id: int, rewriter: _Rewriter) -> int | None:
    """Open a class-3 connection for a capture that starts inside one; the farm's O->T id."""
    triad = ConnectionTriad(rewriter.fresh_serial(), 0, rewriter.rng.getrandbits(32))
    request = ForwardOpenRequest(
        0x0A, 0x0E, 0, t_o_id, triad, 7,
        2_000_000, NetworkParameters(False, ConnectionType.POINT_TO_POINT, 0, True, 504), 2_000_000,
        NetworkParameters(False, ConnectionType.POINT_TO_POINT, 0, True, 504), 0xA3, _MESSAGE_ROUTER_PATH)
    message = encode_request(Service.FORWARD_OPEN, encode_request_path(*_CONNECTION_MANAGER),
                             encode_forward_open(request))
    connection.send(encode_frame(Command.SEND_RR_DATA, encode_unconnected_payload(message), session))
    reply = connection.receive()
    try:
        cip = decode_reply(decode_send_data(reply.data).items[1].data)  # type: ignore[union-attr]
        opened = decode_forward_open_reply(cip.data).o_t_connection_id if cip.general_status == 0 else None
    except (AttributeError, ValueError, IndexError, struct.error):
        return None
    if opened is not None:
        rewriter.mapping.adopted.append(triad)
    return opened


def replay_stream(exchanges: list[Exchange], host: str, rng: random.Random | None = None) -> list[Result]:
    results: list[Result] = []
    connection = _Connection(host)
    mapping = ReplayMap()
    rewriter = _Rewriter(mapping, rng or random.SystemRandom())
    opened_in_capture = _captured_connection_ids(exchanges)
    try:
        for exchange in exchanges:
            request = exchange.request
            command = request.header.command
            captured_handle = request.header.session_handle
            if captured_handle and captured_handle not in mapping.sessions and command != Command.REGISTER_SESSION:
                # the capture starts mid-session: open one for it (masked: the handles are mapped)
                connection.send(encode_frame(Command.REGISTER_SESSION, b"\x01\x00\x00\x00"))
                registered = connection.receive()
                if registered is not None:
                    mapping.sessions[captured_handle] = registered.header.session_handle
            session = mapping.sessions.get(captured_handle, captured_handle)
            captured_id = _connection_id(request) if command == Command.SEND_UNIT_DATA else None
            if captured_id is not None and captured_id not in opened_in_capture | mapping.o_t_ids.keys() \
                    and exchange.reply is not None and exchange.reply.header.status == 0:
                # the capture starts mid-connection: open one for it (masked: the ids are mapped)
                t_o_id = _connection_id(exchange.reply) or rewriter.rng.getrandbits(32)
                live_id = _open_class3(connection, session, t_o_id, rewriter)
                if live_id is not None:
                    mapping.o_t_ids[captured_id] = live_id
            data = rewriter.send_data(request.data) if command in (Command.SEND_RR_DATA,
                                                                   Command.SEND_UNIT_DATA) else None
            connection.send(_with_session(request, session, data))
            if exchange.reply is None:
                results.append(Result(exchange, []))
                continue
            live = connection.receive()
            if live is None:
                results.append(Result(exchange, [], "the farm sent no reply"))
                continue
            if command == Command.REGISTER_SESSION and exchange.reply.header.status == 0:
                mapping.sessions[exchange.reply.header.session_handle] = live.header.session_handle
            results.append(Result(exchange, compare_replies(exchange.reply, live, mapping,
                                                            _moved(exchange.device, host))))
    finally:
        connection.close()
    return results


def _moved(captured: str, host: str) -> tuple[str, str] | None:
    return (captured, host) if captured != host else None


def replay_datagram(exchange: Exchange, host: str) -> Result:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.settimeout(TIMEOUT if exchange.reply is not None else 0.2)
        sock.sendto(exchange.raw_request, (host, ENIP_PORT))
        try:
            data = sock.recv(65536)
        except OSError:
            return Result(exchange, [], "the farm sent no reply" if exchange.reply is not None else "")
    if exchange.reply is None:
        return Result(exchange, [], "the farm answered where the capture has no answer")
    live = decode_frame(data)
    return Result(exchange, compare_replies(exchange.reply, live, ReplayMap(), _moved(exchange.device, host)))


def replay(groups: list[list[Exchange]], target: Callable[[str], str]) -> list[Result]:
    """Replay every group in capture order; `target` maps a captured device address to a farm host."""
    results: list[Result] = []
    for group in groups:
        if not group:
            continue
        if group[0].transport == "tcp":
            results += replay_stream(group, target(group[0].device))
        else:
            for exchange in group:
                results.append(replay_datagram(exchange, target(exchange.device)))
    return results
