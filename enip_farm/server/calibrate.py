"""The farm's cyclic I/O budget measured at start (config `cyclic_io.budget_datagrams_per_s: auto`):
the CPU time one consumed O->T and one produced T->O packet cost on this machine, through the same
code and the same system calls the I/O thread runs, over as many scratch devices as the worker has (up to
SCRATCH_DEVICES): each one's UDP socket on loopback with its O->T datagram waiting, read as the
thread reads them in a turn (epoll, then recvmmsg through server/batch.py), taken and serviced
through their DeviceIo (server/implicit.py), their T->O sent in one batch (sendmmsg) to a socket
of this module. CPU time of this thread, not wall time,
and the best of several rounds, so that a busy moment at start does not halve the budget; the
running check (cip/budget.py) lowers it to what the thread really spends. Loopback only: the
scratch device's originator and T->O destination are this module's own sockets on 127.0.0.1."""

from __future__ import annotations

import socket
import time

from enip_farm.cip.budget import CyclicBudget
from enip_farm.config import BUDGET_UTILISATION
from enip_farm.device.device import Device
from enip_farm.device.profile import DeviceProfile
from enip_farm.protocol.cip import ClassCode, Service, decode_reply, encode_request
from enip_farm.protocol.commands import SocketAddress, encode_sockaddr
from enip_farm.protocol.connection import (
    ConnectionTriad,
    ConnectionType,
    ForwardOpenRequest,
    NetworkParameters,
    decode_forward_open_reply,
    encode_forward_open,
    encode_io_packet,
)
from enip_farm.protocol.cpf import CpfItem, ItemType
from enip_farm.protocol.epath import LogicalType, encode_logical, encode_request_path
from enip_farm.protocol.session import MessageContext
from enip_farm.server.batch import NATIVE_RECEIVE_LIMIT, Datagrams
from enip_farm.server.implicit import CyclicIoThread, DeviceIo

#: Used when no device of the farm can carry an exclusive-owner connection to measure with.
DEFAULT_DATAGRAMS_PER_S = 60_000
#: Scratch devices at most: a worker's working set up to this many devices (each costs what a device
#: of the farm costs to build, a few ms).
SCRATCH_DEVICES = 128
_ROUNDS, _PAIRS = 5, 96  # rounds, and pairs at least in each
_RPI_NS = 10_000_000
_HOST = "127.0.0.1"


def _scratch_connection(profile: DeviceProfile, port: int) -> tuple[Device, int] | None:
    """A device of this profile (no sockets of its own) with one exclusive-owner connection whose
    originator is 127.0.0.1 and whose T->O goes to 127.0.0.1:`port`, opened by a Forward Open
    through the device's own explicit messaging: its O->T id."""
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
    t_o = CpfItem(ItemType.SOCKADDR_T_O, encode_sockaddr(SocketAddress("0.0.0.0", port)))
    reply, _ = device.handle_unconnected(message, MessageContext(_HOST, None, (t_o,), 0))
    answer = decode_reply(reply)
    if answer.general_status != 0:
        return None
    return device, decode_forward_open_reply(answer.data).o_t_connection_id


def _pair_cost_ns(profiles: list[DeviceProfile], native: bool = False) -> tuple[float, float] | None:
    """CPU ns of one O->T taken and one T->O made and sent, as the I/O thread does them, over as many
    scratch devices as the worker has (at most SCRATCH_DEVICES; profiles in turn): each turn reads
    one O->T on every device's socket and sends their T->O in one batch, so the working set and the
    turn are the worker's, not one device's kept warm. With it, the share of a core this thread got
    meanwhile (its CPU over the wall time: all of it is CPU-bound work). None: no profile carries an
    exclusive owner. `native`: the devices run by the native engine (server/native.py), as the thread runs them."""
    usable = [p for p in profiles if p.assembly("output") is not None and p.assembly("input") is not None
              and p.safety is None]
    if not usable:
        return None
    count = min(len(profiles), SCRATCH_DEVICES)
    wall_at, cpu_at = time.monotonic_ns(), time.thread_time_ns()
    thread = CyclicIoThread(Datagrams(), native=native)  # not started: its epoll, outbox, batched send, engine
    sockets: list[socket.socket] = []
    endpoints: list[tuple[DeviceIo, int, tuple[str, int], bytes]] = []
    try:
        originator, sink = _socket(sockets), _socket(sockets)
        for index in range(count):
            profile = usable[index % len(usable)]
            scratch = _scratch_connection(profile, sink.getsockname()[1])
            if scratch is None:
                continue
            device, connection_id = scratch
            sock = _socket(sockets)
            endpoint = DeviceIo(device, sock, thread)
            endpoint.source = socket.inet_aton(_HOST)  # T->O leave from the scratch socket's own address
            thread.register(endpoint)
            with device.guard.transaction(0):  # to the native engine, where there is one
                pass
            output = profile.assembly("output")
            endpoints.append((endpoint, connection_id, sock.getsockname(),
                              b"\x01\x00\x00\x00" + bytes(output.size if output is not None else 0)))
        if not endpoints:
            return None
        readers = {endpoint.sock.fileno(): endpoint for endpoint, _, _, _ in endpoints}
        poll, receive, engine = thread._epoll.poll, thread.datagrams.receive, thread.native
        turns = max(1, -(-_PAIRS // len(endpoints)))
        best, sequence, now = float("inf"), 0, 0
        for _ in range(_ROUNDS):
            spent = 0
            for _ in range(turns):
                sequence += 1
                for _, connection_id, target, image in endpoints:  # the originator's datagrams, not timed
                    originator.sendto(encode_io_packet(connection_id, sequence, sequence, image), target)
                started = time.thread_time_ns()
                now += _RPI_NS
                fds = [fd for fd, _ in poll(0)]
                for fd, data, host, port, received_at in (engine.receive(fds, NATIVE_RECEIVE_LIMIT, now)[0] if engine
                                                          else receive(fds)):
                    readers[fd].take(data, host, port, now, received_at or now)
                if engine is not None:
                    engine.produce(now, now)
                for endpoint, _, _, _ in endpoints:
                    endpoint.service(now, now)
                thread._flush()
                spent += time.thread_time_ns() - started
                while True:  # the T->O, read back untimed
                    try:
                        sink.recv(2048)
                    except BlockingIOError:
                        break
            best = min(best, spent / (turns * len(endpoints)))
        return best, (time.thread_time_ns() - cpu_at) / max(1, time.monotonic_ns() - wall_at)
    finally:
        for endpoint, _, _, _ in endpoints:
            endpoint.close()
        thread.stop()  # never started: its epoll and wake-up pipe closed
        for sock in sockets:
            sock.close()


def _socket(opened: list[socket.socket]) -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    opened.append(sock)
    sock.bind((_HOST, 0))
    sock.setblocking(False)
    return sock


def measure_budget(profiles: list[DeviceProfile], native: bool = False) -> CyclicBudget:
    """The budget of one I/O thread on this machine: BUDGET_UTILISATION of a core over the cost of
    a consumed plus a produced packet (a pair), counted as two datagrams; where the machine gave the
    measuring thread less of a core than that (other programs keep it busy), that share instead,
    the CPU figure staying the ceiling the running check may rise to (cip/budget.py)."""
    measured = _pair_cost_ns(profiles, native)
    if measured is None:
        return CyclicBudget(DEFAULT_DATAGRAMS_PER_S, "no device to measure with: the default")
    pair_ns, share = measured
    ceiling = round(BUDGET_UTILISATION * 2e9 / pair_ns, -2)
    cost = f"measured at start: {pair_ns / 1000:.1f} us of CPU per O->T/T->O pair"
    if share >= BUDGET_UTILISATION:
        return CyclicBudget(ceiling, f"{cost}, for {BUDGET_UTILISATION:.0%} of a core")
    return CyclicBudget(round(share * 2e9 / pair_ns, -2), f"{cost}, for the {share:.0%} of a core the machine gave "
                        f"while measuring ({BUDGET_UTILISATION:.0%} once the I/O thread keeps time)", ceiling)
