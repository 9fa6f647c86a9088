"""`enip-farm serve --record FILE.pcap`: the farm's traffic as a pcap that Wireshark opens.

Each TCP connection is written as a stream of its own: a three-way handshake when it opens, every
received and sent byte as segments (at most 1460 bytes) whose sequence and acknowledgement numbers
follow the bytes, and a FIN exchange when it closes, with the real client and device addresses
and ports. UDP datagrams (44818 and 2222) are written as themselves. Frames are Ethernet/IPv4 with
MACs derived from the addresses and correct checksums. Each packet is flushed as it is written,
so a farm that is killed leaves a readable file. Thread-safe (the cyclic I/O thread records too).

A scenario's steps go to a side file, FILE.steps (a line of wall-clock time and text per step, to
find it among the packets' time stamps), written in the order marked by a thread of the recorder's
own: the event loop that marks a step never waits on the disk. `close()` writes what is left.
"""

from __future__ import annotations

import random
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import dpkt

from enip_farm.capture.packets import ethernet_frame

MSS = 1460
_ACK, _PSH, _SYN, _FIN = dpkt.tcp.TH_ACK, dpkt.tcp.TH_PUSH, dpkt.tcp.TH_SYN, dpkt.tcp.TH_FIN


class _TcpState:
    __slots__ = ("client", "server", "client_seq", "server_seq")

    def __init__(self, client: tuple[str, int], server: tuple[str, int]) -> None:
        self.client, self.server = client, server
        self.client_seq = random.getrandbits(32)
        self.server_seq = random.getrandbits(32)


def append_line(path: Path, line: str) -> None:
    with open(path, "a", encoding="utf-8") as side:
        side.write(line)


class Recorder:
    def __init__(self, path: str | Path, wall: Callable[[], float] = time.time,
                 append: Callable[[Path, str], None] = append_line) -> None:
        """`wall`: the wall clock of the time stamps; `append`: how a line joins the steps file."""
        self.path = Path(path)
        self.wall = wall
        self._append = append
        self._steps = ThreadPoolExecutor(max_workers=1, thread_name_prefix="enip-farm-steps")  # one: in order
        self._file = open(self.path, "wb")  # noqa: SIM115 (closed in close())
        self._writer = dpkt.pcap.Writer(self._file, linktype=dpkt.pcap.DLT_EN10MB)
        self._file.flush()
        self._lock = threading.Lock()
        self._tcp: dict[object, _TcpState] = {}
        self._ip_id = 0

    def _write(self, src: str, dst: str, transport: dpkt.Packet, proto: int) -> None:
        self._ip_id = (self._ip_id + 1) & 0xFFFF
        self._writer.writepkt(ethernet_frame(src, dst, transport, proto, self._ip_id), ts=self.wall())
        self._file.flush()

    def _segment(self, state: _TcpState, from_client: bool, flags: int, payload: bytes = b"") -> None:
        src, dst = (state.client, state.server) if from_client else (state.server, state.client)
        seq, ack = (state.client_seq, state.server_seq) if from_client else (state.server_seq, state.client_seq)
        tcp = dpkt.tcp.TCP(sport=src[1], dport=dst[1], seq=seq, ack=ack if flags & _ACK else 0, flags=flags,
                           win=65535, data=payload)
        self._write(src[0], dst[0], tcp, dpkt.ip.IP_PROTO_TCP)
        advance = len(payload) + (1 if flags & (_SYN | _FIN) else 0)
        if from_client:
            state.client_seq = (state.client_seq + advance) & 0xFFFFFFFF
        else:
            state.server_seq = (state.server_seq + advance) & 0xFFFFFFFF

    def tcp_opened(self, key: object, client: tuple[str, int], server: tuple[str, int]) -> None:
        with self._lock:
            state = self._tcp[key] = _TcpState(client, server)
            self._segment(state, True, _SYN)
            self._segment(state, False, _SYN | _ACK)
            self._segment(state, True, _ACK)

    def tcp_data(self, key: object, from_client: bool, data: bytes) -> None:
        with self._lock:
            state = self._tcp.get(key)
            if state is None:
                return
            for start in range(0, len(data), MSS):
                self._segment(state, from_client, _PSH | _ACK, data[start : start + MSS])

    def tcp_closed(self, key: object, by_client: bool) -> None:
        with self._lock:
            state = self._tcp.pop(key, None)
            if state is None:
                return
            self._segment(state, by_client, _FIN | _ACK)
            self._segment(state, not by_client, _FIN | _ACK)
            self._segment(state, by_client, _ACK)

    def udp(self, src: tuple[str, int], dst: tuple[str, int], data: bytes) -> None:
        datagram = dpkt.udp.UDP(sport=src[1], dport=dst[1], data=data)
        datagram.ulen = len(datagram)  # dpkt leaves the length field at 8 otherwise
        with self._lock:
            self._write(src[0], dst[0], datagram, dpkt.ip.IP_PROTO_UDP)

    def mark(self, text: str) -> None:
        """A scenario's step, stamped now, appended to FILE.steps by the recorder's thread (once the
        recorder is closed, a step that comes late is appended at once)."""
        steps, line = Path(f"{self.path}.steps"), f"{self.wall():.6f} {text}\n"
        try:
            self._steps.submit(self._append, steps, line)
        except RuntimeError:  # closed: no thread to write it
            self._append(steps, line)

    def close(self) -> None:
        self._steps.shutdown(wait=True)
        with self._lock:
            for key in list(self._tcp):
                state = self._tcp.pop(key)
                self._segment(state, False, _FIN | _ACK)
                self._segment(state, True, _FIN | _ACK)
                self._segment(state, False, _ACK)
            self._file.close()
