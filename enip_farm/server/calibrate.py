"""The farm's cyclic I/O budget measured at start (config `cyclic_io.budget_datagrams_per_s: auto`):
the CPU time one consumed O->T and one produced T->O packet cost on this machine, through the same
code the I/O thread runs (a scratch device's `receive_io` and `service_io`, and a batch sent and
read over loopback through server/batch.py). CPU time of this thread, not wall time, and the best
of several rounds, so that a busy moment at start does not halve the budget. Loopback only."""

from __future__ import annotations

import socket
import time

from enip_farm.cip.budget import CyclicBudget
from enip_farm.device.device import Device
from enip_farm.device.profile import DeviceProfile
from enip_farm.protocol.cip import ClassCode, Service, decode_reply, encode_request
from enip_farm.protocol.connection import (
    IO_PORT,
    ConnectionTriad,
    ConnectionType,
    ForwardOpenRequest,
    NetworkParameters,
    decode_forward_open_reply,
    encode_forward_open,
    encode_io_packet,
)
from enip_farm.protocol.epath import LogicalType, encode_logical, encode_request_path
from enip_farm.protocol.session import MessageContext
from enip_farm.server.batch import Datagrams, sockaddr

#: The share of one core the budget is for: the rest is the I/O thread's own turns, the event
#: loop (explicit requests, the API) and headroom for bursts.
UTILISATION = 0.5
#: Used when no device of the farm can carry an exclusive-owner connection to measure with.
DEFAULT_DATAGRAMS_PER_S = 60_000
_ROUNDS, _PACKETS = 5, 200
_RPI_NS = 10_000_000


def _scratch_connection(profile: DeviceProfile) -> tuple[Device, int] | None:
    """A device of this profile (no sockets) with one exclusive-owner connection, opened by a
    Forward Open through the device's own explicit messaging: its O->T id."""
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
    message = encode_request(Service.FORWARD_OPEN, encode_request_path(ClassCode.CONNECTION_MANAGER, 1),
                             encode_forward_open(request))
    reply, _ = device.handle_unconnected(message, MessageContext("127.0.0.1", None, (), 0))
    answer = decode_reply(reply)
    if answer.general_status != 0:
        return None
    return device, decode_forward_open_reply(answer.data).o_t_connection_id


def _device_cost_ns(device: Device, connection_id: int, size: int) -> float:
    """One O->T taken and one T->O produced, through the device's `receive_io` and `service_io`
    (the sequence counts go on from round to round, so every packet is new data)."""
    source = ("127.0.0.1", IO_PORT)
    sent: list[bytes] = []

    def send(packet: bytes, _: tuple[str, int]) -> None:
        sent.append(packet)

    best = float("inf")
    now = 0
    for round_ in range(_ROUNDS):
        first = round_ * _PACKETS + 1
        packets = [encode_io_packet(connection_id, n, n, b"\x01\x00\x00\x00" + bytes(size))
                   for n in range(first, first + _PACKETS)]
        started = time.thread_time_ns()
        for packet in packets:
            now += _RPI_NS
            device.receive_io(packet, source, now, send)
            device.service_io(now, send)
        best = min(best, (time.thread_time_ns() - started) / _PACKETS)
        sent.clear()
    return best


def _loopback_cost_ns() -> float:
    """One datagram sent (in a batch) and one read, through server/batch.py, over loopback."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as a, socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as b:
        a.bind(("127.0.0.1", 0))
        b.bind(("127.0.0.1", 0))
        b.setblocking(False)
        datagrams = Datagrams()
        datagrams.add(a)
        destination, source = sockaddr(*b.getsockname()), socket.inet_aton("127.0.0.1")
        batch = [(bytes(24), destination, source)] * 16
        best = float("inf")
        for _ in range(_ROUNDS):
            started = time.thread_time_ns()
            for _ in range(_PACKETS // 16):
                datagrams.send(batch)
                for _ in range(16):
                    datagrams.receive([b.fileno()])
            best = min(best, (time.thread_time_ns() - started) / (_PACKETS // 16 * 16))
        return best


def measure_budget(profiles: list[DeviceProfile]) -> CyclicBudget:
    """The budget of one I/O thread on this machine: UTILISATION of a core over the cost of a
    consumed plus a produced packet (a pair), counted as two datagrams."""
    scratch = next((s for s in map(_scratch_connection, profiles) if s is not None), None)
    if scratch is None:
        return CyclicBudget(DEFAULT_DATAGRAMS_PER_S, "no device to measure with: the default")
    device, connection_id = scratch
    output = device.profile.assembly("output")
    pair_ns = _device_cost_ns(device, connection_id, output.size if output else 0) + 2 * _loopback_cost_ns()
    datagrams_per_s = UTILISATION * 2e9 / pair_ns
    return CyclicBudget(round(datagrams_per_s, -2), f"measured at start: {pair_ns / 1000:.1f} us of CPU per "
                        f"O->T/T->O pair, for {UTILISATION:.0%} of a core")
