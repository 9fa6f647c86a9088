"""A capture's EtherNet/IP exchanges: each TCP stream to port 44818 cut into encapsulation frames
(the project's framer) with requests paired to their replies, and UDP 44818 datagrams paired to
the answers they got."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from enip_farm.capture.packets import Packet, read_capture, tcp_streams
from enip_farm.protocol.encapsulation import ENIP_PORT, HEADER, Frame, StreamFramer, decode_frame


@dataclass
class Exchange:
    stream: int  # TCP streams from 1 in the order they started; 0 for UDP
    number: int  # within the stream, from 1
    transport: str  # "tcp" or "udp"
    device: str  # the captured device address
    request: Frame
    reply: Frame | None  # None: the capture holds no answer (NOP, a good UnRegisterSession, ...)

    @property
    def raw_request(self) -> bytes:
        return HEADER.pack(*self.request.header) + self.request.data


def _frames(data: bytes) -> list[Frame]:
    return [f for f in StreamFramer(max_length=65535).feed(bytes(data)) if type(f) is Frame]


def _pair(stream: int, transport: str, device: str, requests: list[Frame], replies: list[Frame]) -> list[Exchange]:
    """Replies come in request order; a request is answered when the next reply has its command
    and sender context."""
    exchanges, pending = [], list(replies)
    for number, request in enumerate(requests, 1):
        reply = None
        if pending and pending[0].header.command == request.header.command \
                and pending[0].header.sender_context == request.header.sender_context:
            reply = pending.pop(0)
        exchanges.append(Exchange(stream, number, transport, device, request, reply))
    return exchanges


def load_exchanges(path: str | Path) -> list[list[Exchange]]:
    """The exchanges of a capture, grouped: one list per TCP stream in order, then the UDP ones.
    Raises CaptureError (capture/packets.py) for a file that is not a readable capture."""
    return exchanges_of(read_capture(path).packets)


def exchanges_of(packets: list[Packet]) -> list[list[Exchange]]:
    """The exchanges of a capture's packets, grouped as `load_exchanges` groups them."""
    groups = []
    for index, stream in enumerate(tcp_streams(packets, ENIP_PORT), 1):
        groups.append(_pair(index, "tcp", stream.server[0], _frames(stream.to_server), _frames(stream.to_client)))
    udp_requests: dict[tuple[str, int, str], list[Frame]] = {}
    udp_replies: dict[tuple[str, int, str], list[Frame]] = {}
    for packet in packets:
        if packet.proto != "udp" or ENIP_PORT not in (packet.sport, packet.dport):
            continue
        try:
            frame = decode_frame(packet.payload)
        except ValueError:
            continue
        if packet.dport == ENIP_PORT:
            udp_requests.setdefault((packet.src, packet.sport, packet.dst), []).append(frame)
        else:
            udp_replies.setdefault((packet.dst, packet.dport, packet.src), []).append(frame)
    udp = []
    for key, requests in udp_requests.items():
        udp += _pair(0, "udp", key[2], requests, udp_replies.get(key, []))
    if udp:
        groups.append(udp)
    return groups
