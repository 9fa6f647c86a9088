"""`enip-farm probe`'s prober: ListIdentity (CIP Vol 2 §2-4.2) over UDP to many addresses, a few at
a time, collecting who answers within a deadline."""

from __future__ import annotations

import socket
import time
from collections.abc import Iterable

from enip_farm.protocol.encapsulation import ENIP_PORT, Command, decode_frame, encode_frame

BURST = 64  # addresses asked at once: a burst of replies would overflow one socket's receive buffer


def list_identity(addresses: Iterable[str], timeout: float) -> set[str]:
    """The addresses among `addresses` that answered ListIdentity within `timeout` seconds."""
    wanted = list(addresses)
    answered: set[str] = set()

    def collect(sock: socket.socket, until: float, expected: int) -> None:
        while len(answered) < expected and (remaining := until - time.monotonic()) > 0:
            sock.settimeout(remaining)
            try:
                data, (host, _) = sock.recvfrom(2048)
            except OSError:  # timeout
                return
            try:
                if decode_frame(data).header.command == Command.LIST_IDENTITY:
                    answered.add(host)
            except ValueError:
                continue

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        deadline = time.monotonic() + timeout
        for start in range(0, len(wanted), BURST):
            for address in wanted[start : start + BURST]:
                sock.sendto(encode_frame(Command.LIST_IDENTITY), (address, ENIP_PORT))
            collect(sock, min(deadline, time.monotonic() + 0.5), min(start + BURST, len(wanted)))
        collect(sock, deadline, len(wanted))
    return answered
