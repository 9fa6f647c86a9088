"""The few client-side pieces the benchmarks share: a registered TCP connection to a device and
reading an exact number of bytes. Loopback only, bounded by socket timeouts."""

from __future__ import annotations

import socket

from enip_farm.protocol.encapsulation import Command, encode_frame

PORT = 44818
REGISTER = encode_frame(Command.REGISTER_SESSION, b"\x01\x00\x00\x00")


def recv_exact(sock: socket.socket, size: int) -> bytes:
    data = b""
    while len(data) < size:
        chunk = sock.recv(size - len(data))
        if not chunk:
            raise ConnectionError("closed")
        data += chunk
    return data


def register(host: str, timeout: float = 5.0) -> tuple[socket.socket, int]:
    """A TCP connection to `host`:44818 (no Nagle delay) with a registered session, and its handle."""
    sock = socket.create_connection((host, PORT), timeout=timeout)
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    sock.sendall(REGISTER)
    return sock, int.from_bytes(recv_exact(sock, 28)[4:8], "little")
