"""pcap and pcapng in and out (with dpkt): packets as (addresses, ports, TCP flags, payload),
Ethernet/IPv4/TCP/UDP frames built with correct checksums, and TCP streams reassembled per
direction. A file dpkt cannot read as a capture is one `CaptureError` with a one-line message; a
damaged frame inside a readable capture is skipped and counted (`Capture.damaged`)."""

from __future__ import annotations

import socket
import struct
from dataclasses import dataclass, field
from pathlib import Path

import dpkt

PCAPNG_MAGIC = b"\x0a\x0d\x0d\x0a"


@dataclass(frozen=True)
class Packet:
    time: float
    src: str
    sport: int
    dst: str
    dport: int
    proto: str  # "tcp" or "udp"
    flags: int  # TCP flags (0 for UDP)
    seq: int
    payload: bytes


@dataclass(frozen=True)
class Capture:
    packets: list[Packet]  # IPv4 TCP and UDP packets, in capture order
    damaged: int  # frames skipped because dpkt could not decode them (cut or malformed headers)


def _ip_of(link_type: int, buf: bytes) -> dpkt.ip.IP | None:
    """The IPv4 packet of a frame, None for other traffic; UnpackError/ValueError for a damaged one
    (dpkt leaves an IPv4 payload it cannot decode as bytes: that is damage too)."""
    if link_type in (dpkt.pcap.DLT_EN10MB, dpkt.pcap.DLT_LINUX_SLL):
        frame = dpkt.ethernet.Ethernet(buf) if link_type == dpkt.pcap.DLT_EN10MB else dpkt.sll.SLL(buf)
        if isinstance(frame.data, dpkt.ip.IP):
            return frame.data
        ethertype = frame.type if link_type == dpkt.pcap.DLT_EN10MB else frame.ethtype
        if ethertype == dpkt.ethernet.ETH_TYPE_IP:
            raise ValueError("an IPv4 header dpkt cannot decode")
        return None
    if link_type in (dpkt.pcap.DLT_RAW, 101, 228):  # raw IP, LINKTYPE_RAW, IPv4
        return dpkt.ip.IP(buf)
    if link_type in (dpkt.pcap.DLT_NULL, dpkt.pcap.DLT_LOOP):
        frame = dpkt.loopback.Loopback(buf)
        return frame.data if isinstance(frame.data, dpkt.ip.IP) else None
    return None


class CaptureError(ValueError):
    """A file that is not a readable pcap or pcapng capture; the message is one line for the user."""


def read_capture(path: str | Path) -> Capture:
    """IPv4 TCP and UDP packets of a pcap or pcapng file, in capture order, and the number of
    damaged frames skipped. Raises CaptureError for a file that cannot be opened, is not a
    capture, or is cut inside a packet record."""
    packets: list[Packet] = []
    damaged = 0
    records = -1  # until the file's header is read
    try:
        with open(path, "rb") as handle:
            magic = handle.read(4)
            handle.seek(0)
            reader = dpkt.pcapng.Reader(handle) if magic == PCAPNG_MAGIC else dpkt.pcap.Reader(handle)
            link_type = reader.datalink()
            records = 0
            for timestamp, buf in reader:
                records += 1
                try:
                    packet = _packet(link_type, timestamp, buf)
                except (dpkt.UnpackError, ValueError, struct.error):  # one damaged frame: skipped, counted
                    damaged += 1
                    continue
                if packet is not None:
                    packets.append(packet)
    except OSError as error:
        raise CaptureError(f"{path}: {error.strerror}") from None
    except (dpkt.UnpackError, ValueError, struct.error) as error:  # dpkt.NeedData is an UnpackError
        if records >= 0:
            raise CaptureError(f"{path}: capture cut short after {records} packets ({error})") from None
        reason = "an empty file" if Path(path).stat().st_size == 0 else error or type(error).__name__
        raise CaptureError(f"{path}: not a pcap or pcapng capture ({reason})") from None
    return Capture(packets, damaged)


def _packet(link_type: int, timestamp: float, buf: bytes) -> Packet | None:
    """The TCP or UDP packet of one record, or None (not IPv4 TCP/UDP). Raises dpkt.UnpackError
    or ValueError for a frame dpkt cannot decode."""
    ip = _ip_of(link_type, buf)
    if ip is None:
        return None
    src, dst = socket.inet_ntoa(ip.src), socket.inet_ntoa(ip.dst)
    if isinstance(ip.data, dpkt.tcp.TCP):
        tcp = ip.data
        return Packet(timestamp, src, tcp.sport, dst, tcp.dport, "tcp", tcp.flags, tcp.seq, bytes(tcp.data))
    if isinstance(ip.data, dpkt.udp.UDP):
        udp = ip.data
        return Packet(timestamp, src, udp.sport, dst, udp.dport, "udp", 0, 0, bytes(udp.data))
    if ip.p in (dpkt.ip.IP_PROTO_TCP, dpkt.ip.IP_PROTO_UDP) and not ip.mf and not ip.offset:  # not a fragment
        raise ValueError("a TCP or UDP header dpkt cannot decode")
    return None


def mac_of(address: str) -> bytes:
    """A locally administered MAC derived from an IPv4 address (02:00 + the four bytes)."""
    return b"\x02\x00" + socket.inet_aton(address)


def ethernet_frame(src: str, dst: str, transport: dpkt.Packet, proto: int, ip_id: int = 0, ttl: int = 64,
                   tos: int = 0, src_mac: bytes | None = None, dst_mac: bytes | None = None) -> bytes:
    ip = dpkt.ip.IP(src=socket.inet_aton(src), dst=socket.inet_aton(dst), p=proto, ttl=ttl, id=ip_id, tos=tos,
                    data=transport)
    ip.len = len(ip)  # dpkt fills the checksums when packing
    ethernet = dpkt.ethernet.Ethernet(src=src_mac or mac_of(src), dst=dst_mac or mac_of(dst),
                                      type=dpkt.ethernet.ETH_TYPE_IP, data=ip)
    return bytes(ethernet)


@dataclass(eq=False)
class TcpStream:
    """One TCP connection: the client's and the server's bytes, each reassembled in capture order
    (retransmitted segments dropped), and the addresses."""

    client: tuple[str, int]
    server: tuple[str, int]
    to_server: bytearray = field(default_factory=bytearray)
    to_client: bytearray = field(default_factory=bytearray)
    _seen: set = field(default_factory=set)

    def add(self, packet: Packet) -> None:
        if not packet.payload or packet.flags & dpkt.tcp.TH_SYN:  # bytes on a SYN are padding, not data
            return
        key = (packet.src, packet.sport, packet.seq, packet.payload)
        if key in self._seen:  # a retransmission
            return
        self._seen.add(key)
        if (packet.src, packet.sport) == self.client:
            self.to_server += packet.payload
        else:
            self.to_client += packet.payload


def tcp_streams(packets: list[Packet], port: int) -> list[TcpStream]:
    """TCP connections to `port`, in the order they started."""
    streams: dict[tuple, TcpStream] = {}
    order: list[TcpStream] = []
    for packet in packets:
        if packet.proto != "tcp" or port not in (packet.sport, packet.dport):
            continue
        if packet.dport == port:
            client, server = (packet.src, packet.sport), (packet.dst, packet.dport)
        else:
            client, server = (packet.dst, packet.dport), (packet.src, packet.sport)
        key = (client, server)
        stream = streams.get(key)
        new_connection = packet.flags & dpkt.tcp.TH_SYN and not packet.flags & dpkt.tcp.TH_ACK
        if stream is None or (new_connection and (stream.to_server or stream.to_client)):
            stream = streams[key] = TcpStream(client, server)  # a reused 4-tuple starts a new stream
            order.append(stream)
        stream.add(packet)
    return order
