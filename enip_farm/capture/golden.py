"""Golden testing: replay the client side of a capture against farm devices over real TCP and UDP
connections, and compare every reply with the captured one field by field (capture/compare.py)."""

from __future__ import annotations

import socket
from collections.abc import Callable
from dataclasses import dataclass

from enip_farm.capture.compare import Difference, compare_replies
from enip_farm.capture.exchanges import Exchange
from enip_farm.protocol.encapsulation import HEADER, Command, Frame, StreamFramer, decode_frame, encode_frame

TIMEOUT = 5.0


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


def _with_session(frame: Frame, handle: int) -> bytes:
    h = frame.header
    return HEADER.pack(h.command, h.length, handle, h.status, h.sender_context, h.options) + frame.data


class _Connection:
    def __init__(self, host: str) -> None:
        self.sock = socket.create_connection((host, 44818), timeout=TIMEOUT)
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


def replay_stream(exchanges: list[Exchange], host: str) -> list[Result]:
    results: list[Result] = []
    connection = _Connection(host)
    session_map: dict[int, int] = {}
    try:
        for exchange in exchanges:
            request = exchange.request
            captured_handle = request.header.session_handle
            if captured_handle and captured_handle not in session_map \
                    and request.header.command != Command.REGISTER_SESSION:
                # the capture starts mid-session: open one for it (masked: the handles are mapped)
                connection.send(encode_frame(Command.REGISTER_SESSION, b"\x01\x00\x00\x00"))
                registered = connection.receive()
                if registered is not None:
                    session_map[captured_handle] = registered.header.session_handle
            connection.send(_with_session(request, session_map.get(captured_handle, captured_handle)))
            if exchange.reply is None:
                results.append(Result(exchange, []))
                continue
            live = connection.receive()
            if live is None:
                results.append(Result(exchange, [], "the farm sent no reply"))
                continue
            if request.header.command == Command.REGISTER_SESSION and exchange.reply.header.status == 0:
                session_map[exchange.reply.header.session_handle] = live.header.session_handle
            results.append(Result(exchange, compare_replies(exchange.reply, live, session_map,
                                                            _moved(exchange.device, host))))
    finally:
        connection.close()
    return results


def _moved(captured: str, host: str) -> tuple[str, str] | None:
    return (captured, host) if captured != host else None


def replay_datagram(exchange: Exchange, host: str) -> Result:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.settimeout(TIMEOUT if exchange.reply is not None else 0.2)
        sock.sendto(exchange.raw_request, (host, 44818))
        try:
            data = sock.recv(65536)
        except OSError:
            return Result(exchange, [], "the farm sent no reply" if exchange.reply is not None else "")
    if exchange.reply is None:
        return Result(exchange, [], "the farm answered where the capture has no answer")
    return Result(exchange, compare_replies(exchange.reply, decode_frame(data), {}, _moved(exchange.device, host)))


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
