"""The farm's cyclic I/O budget measured at start (config `cyclic_io.budget_datagrams_per_s: auto`):
the CPU time one consumed O->T and one produced T->O packet cost on this machine, through the same
code and the same system calls the I/O thread runs: a scratch device's UDP socket on loopback with
its O->T datagram waiting, read as the thread reads it (epoll, then recvmmsg through
server/batch.py), taken and serviced through its DeviceIo (server/implicit.py), its T->O sent in
the thread's batches (sendmmsg) to a socket of this module. CPU time of this thread, not wall time,
and the best of several rounds, so that a busy moment at start does not halve the budget; the
running check (cip/budget.py) lowers it to what the thread really spends. Loopback only: the
scratch device's originator and T->O destination are this module's own sockets on 127.0.0.1."""

from __future__ import annotations

import socket
import time

from enip_farm.cip.admission import Originator
from enip_farm.cip.budget import CyclicBudget
from enip_farm.config import BUDGET_UTILISATION
from enip_farm.device.device import Device
from enip_farm.device.profile import DeviceProfile
from enip_farm.protocol.cip import ClassCode
from enip_farm.protocol.commands import SocketAddress
from enip_farm.protocol.connection import (
    ConnectionTriad,
    ConnectionType,
    ForwardOpenRequest,
    NetworkParameters,
    encode_io_packet,
)
from enip_farm.protocol.epath import LogicalType, encode_logical
from enip_farm.server.batch import Datagrams
from enip_farm.server.implicit import CyclicIoThread, DeviceIo

#: Used when no device of the farm can carry an exclusive-owner connection to measure with.
DEFAULT_DATAGRAMS_PER_S = 60_000
_ROUNDS, _PACKETS, _TURN = 5, 192, 16  # a turn: this many pairs, their T->O in one sendmmsg
_RPI_NS = 10_000_000
_HOST = "127.0.0.1"


def _scratch_connection(profile: DeviceProfile, port: int) -> tuple[Device, int] | None:
    """A device of this profile (no sockets of its own) with one exclusive-owner connection whose
    originator is 127.0.0.1 and whose T->O goes to 127.0.0.1:`port`: its O->T id."""
    output, inputs = profile.assembly("output"), profile.assembly("input")
    if output is None or inputs is None or profile.safety is not None:
        return None
    device = Device(profile)
    config = profile.assembly("configuration")
    path = (encode_logical(LogicalType.CLASS_ID, ClassCode.ASSEMBLY)
            + (encode_logical(LogicalType.INSTANCE_ID, config.instance_id) if config is not None else b"")
            + encode_logical(LogicalType.CONNECTION_POINT, output.instance_id)
            + encode_logical(LogicalType.CONNECTION_POINT, inputs.instance_id))
    request = ForwardOpenRequest(0x0A, 0x0E, 0, 1, ConnectionTriad(1, 1, 1), 7, _RPI_NS // 1000,
                                 NetworkParameters(False, ConnectionType.POINT_TO_POINT, 2, False, 6 + output.size),
                                 _RPI_NS // 1000,
                                 NetworkParameters(False, ConnectionType.POINT_TO_POINT, 2, False, 2 + inputs.size),
                                 0x01, path)
    with device.lock:
        opened = device.table.forward_open(request, Originator(_HOST, SocketAddress("0.0.0.0", port)), 0)
    connection = getattr(opened, "connection", None)
    return (device, connection.o_t_id) if connection is not None else None


def _pair_cost_ns(profile: DeviceProfile) -> float | None:
    """CPU ns of one O->T taken and one T->O made and sent, as the I/O thread does them (None: no
    device of this profile carries an exclusive-owner connection)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as originator, \
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as device_socket, \
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sink:
        for sock in (originator, device_socket, sink):
            sock.bind((_HOST, 0))
            sock.setblocking(False)
        scratch = _scratch_connection(profile, sink.getsockname()[1])
        if scratch is None:
            return None
        device, connection_id = scratch
        output = profile.assembly("output")
        image = b"\x01\x00\x00\x00" + bytes(output.size if output is not None else 0)
        thread = CyclicIoThread(Datagrams())  # not started: its outbox and its batched send
        endpoint = DeviceIo(device, device_socket, thread)
        endpoint.source = socket.inet_aton(_HOST)  # T->O leave from the scratch socket's own address
        thread.register(endpoint)
        poll, receive, fd = thread._epoll.poll, thread.datagrams.receive, device_socket.fileno()
        target = device_socket.getsockname()
        best, sequence, now = float("inf"), 0, 0
        try:
            for _ in range(_ROUNDS):
                spent = 0
                for _ in range(_PACKETS // _TURN):
                    for _ in range(_TURN):  # the originator's datagrams, not timed
                        sequence += 1
                        originator.sendto(encode_io_packet(connection_id, sequence, sequence, image), target)
                    started = time.thread_time_ns()
                    for _ in range(_TURN):
                        now += _RPI_NS
                        poll(0)
                        for _, data, host, port, received_at in receive([fd]):
                            endpoint.take(data, host, port, now, received_at or now)
                        endpoint.service(now, now)
                    thread._flush()
                    spent += time.thread_time_ns() - started
                    while True:  # the T->O, read back untimed
                        try:
                            sink.recv(2048)
                        except BlockingIOError:
                            break
                best = min(best, spent / (_PACKETS // _TURN * _TURN))
        finally:
            endpoint.close()
            thread.stop()  # never started: its epoll and wake-up pipe closed
        return best


def measure_budget(profiles: list[DeviceProfile]) -> CyclicBudget:
    """The budget of one I/O thread on this machine: BUDGET_UTILISATION of a core over the cost of
    a consumed plus a produced packet (a pair), counted as two datagrams."""
    pair_ns = next((cost for cost in map(_pair_cost_ns, profiles) if cost is not None), None)
    if pair_ns is None:
        return CyclicBudget(DEFAULT_DATAGRAMS_PER_S, "no device to measure with: the default")
    datagrams_per_s = BUDGET_UTILISATION * 2e9 / pair_ns
    return CyclicBudget(round(datagrams_per_s, -2), f"measured at start: {pair_ns / 1000:.1f} us of CPU per "
                        f"O->T/T->O pair, for {BUDGET_UTILISATION:.0%} of a core")
