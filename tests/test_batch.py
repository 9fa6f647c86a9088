"""Batched UDP of the cyclic I/O thread (server/batch.py): the native extension (sendmmsg with each
device's source address, recvmmsg) and its pure-Python fallback move the same datagrams, from the
same source address and port, over loopback. CI builds the extension and sets
ENIP_FARM_REQUIRE_NATIVE=1, so a build that silently fell back fails here."""

from __future__ import annotations

import os
import socket
import time

import pytest

from enip_farm.server import batch
from enip_farm.server.batch import Datagrams, sockaddr

pytestmark = pytest.mark.integration


def test_the_native_extension_is_built_where_ci_requires_it() -> None:
    if os.environ.get("ENIP_FARM_REQUIRE_NATIVE") == "1":
        assert batch.NATIVE, "enip_farm/server/_mmsg.c was not built (a compiler and Python headers are needed)"
    elif not batch.NATIVE:
        pytest.skip("the native extension is not built here; the fallback is tested below")


@pytest.mark.parametrize("native", [True, False], ids=["sendmmsg", "sendto"])
def test_each_packet_leaves_from_its_device_address_and_port(free_address, native: bool) -> None:
    if native and not batch.NATIVE:
        pytest.skip("the native extension is not built here")
    devices = [free_address() for _ in range(3)]
    sockets = []
    try:
        for address in devices:
            sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            sock.bind((address, 0))
            sock.setblocking(False)
            sockets.append(sock)
        receiver = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        receiver.bind(("127.0.0.1", 0))
        receiver.settimeout(5)
        sockets.append(receiver)
        datagrams = Datagrams(native=native)
        for sock in sockets[:3]:
            datagrams.add(sock)
        to = sockaddr(*receiver.getsockname())
        messages = [(f"packet {i}".encode(), to, socket.inet_aton(devices[i % 3])) for i in range(9)]
        messages.append((b"nowhere", to, socket.inet_aton("127.0.0.3")))  # no device socket of that address
        failures = datagrams.send(messages)
        got = sorted(receiver.recvfrom(64) for _ in range(9 if not native else 10))
        ports = {sock.getsockname()[1] for sock in sockets[:3]}
        if native:  # one socket sends all: each packet's source address is its device's, its port the sender's
            assert failures == []
            expected = sorted([(f"packet {i}".encode(), (devices[i % 3], sockets[0].getsockname()[1]))
                               for i in range(9)] + [(b"nowhere", ("127.0.0.3", sockets[0].getsockname()[1]))])
            assert got == expected
        else:  # each device's own socket sends its packets; an address with no socket is a failure
            assert failures == [(9, 99)]  # EADDRNOTAVAIL
            assert got == sorted((f"packet {i}".encode(), sockets[i % 3].getsockname()) for i in range(9))
            assert {port for _, (_, port) in got} == ports
        # and back: what waits on several sockets is read in one call, with its source and the
        # kernel's receive time (SO_TIMESTAMPNS, as server/implicit.py sets it) in monotonic ns
        for sock in sockets[:3]:
            sock.setsockopt(socket.SOL_SOCKET, batch.SO_TIMESTAMPNS, 1)
        sent_from = time.monotonic_ns()
        for i, sock in enumerate(sockets[:3]):
            receiver.sendto(f"o->t {i}".encode(), sock.getsockname())
            receiver.sendto(f"o->t {i}b".encode(), sock.getsockname())
        fds = [sock.fileno() for sock in sockets[:3]]
        received: list = []
        for _ in range(200):  # each datagram is in its socket's queue when sendto returns (loopback)
            received += datagrams.receive(fds)
            if len(received) == 6:
                break
        read_by = time.monotonic_ns()
        assert all(sent_from <= at <= read_by for *_, at in received), (sent_from, received, read_by)
        assert sorted((fd, data, host, port) for fd, data, host, port, _ in received) == sorted(
            (sockets[i].fileno(), f"o->t {i}{suffix}".encode(), "127.0.0.1", receiver.getsockname()[1])
            for i in range(3) for suffix in ("", "b"))
    finally:
        for sock in sockets:
            sock.close()
