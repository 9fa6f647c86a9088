"""One device's class-1 pair in-process: thread CPU per O->T taken (`receive_io`) and T->O made
(`service_io`), on a device of a Farm built as `enip-farm serve --quiet` builds it (its observers:
the farm's resets, the device handles, the console at WARNING), no sockets. The device transaction
(device/guard.py) is on this path twice per pair; this is its cost, apart from the sockets that
bench_cyclic.py adds.

    python bench/bench_device_pair.py                      # constant O->T data, as cyclic_originator.c sends
    python bench/bench_device_pair.py --changing           # outputs that change with every O->T
    PYTHONPATH=/other/tree python bench/bench_device_pair.py   # the same against another checkout
"""

from __future__ import annotations

import argparse
import logging
import statistics
import time

from enip_farm.farm.console import Console
from enip_farm.farm.farm import Farm
from enip_farm.protocol.cip import decode_reply, encode_request
from enip_farm.protocol.connection import (
    ConnectionTriad,
    ConnectionType,
    ForwardOpenRequest,
    NetworkParameters,
    decode_forward_open_reply,
    encode_forward_open,
    encode_io_packet,
)
from enip_farm.protocol.epath import encode_request_path
from enip_farm.protocol.session import MessageContext

RPI_NS = 10_000_000


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--pairs", type=int, default=2000, help="pairs per round (2000)")
    parser.add_argument("--rounds", type=int, default=15, help="rounds; the median is shown (15)")
    parser.add_argument("--changing", action="store_true", help="O->T data that changes the outputs every time")
    args = parser.parse_args()
    farm = Farm({"devices": [{"name": "io1", "address": "127.0.0.1", "model": "DSQC1030"}], "discovery": False})
    logger = logging.getLogger("bench.quiet")
    logger.setLevel(logging.WARNING)
    Console(farm.devices.values(), logger).attach()
    device = farm.devices["io1"]
    output, inputs = device.profile.assembly("output"), device.profile.assembly("input")
    path = bytes.fromhex("20 04 24 01 2C") + bytes([output.instance_id]) + b"\x2C" + bytes([inputs.instance_id])
    p2p = ConnectionType.POINT_TO_POINT
    request = ForwardOpenRequest(0x0A, 0x0E, 0, 1, ConnectionTriad(1, 1, 1), 7, RPI_NS // 1000,
                                 NetworkParameters(False, p2p, 2, False, 6 + output.size), RPI_NS // 1000,
                                 NetworkParameters(False, p2p, 2, False, 2 + inputs.size), 0x01, path)
    reply, _ = device.handle_unconnected(encode_request(0x54, encode_request_path(6, 1), encode_forward_open(request)),
                                         MessageContext("127.0.0.1", None, (), 0))
    connection_id = decode_forward_open_reply(decode_reply(reply).data).o_t_connection_id
    source, now, sequence, spent = ("127.0.0.1", 2222), 0, 0, []

    def send(packet: bytes, address: tuple[str, int]) -> None:
        pass

    for _ in range(args.rounds):
        packets = []
        for _ in range(args.pairs):
            sequence += 1
            data = bytes([sequence & 0xFF]) * output.size if args.changing else bytes(range(24, 24 + output.size))
            packets.append(encode_io_packet(connection_id, sequence, sequence & 0xFFFF, b"\x01\x00\x00\x00" + data))
        started = time.thread_time_ns()
        for packet in packets:
            now += RPI_NS
            device.receive_io(packet, source, now, send)
            device.service_io(now, send)
        spent.append((time.thread_time_ns() - started) / args.pairs)
    print(f"{'changing' if args.changing else 'constant'} O->T data: {statistics.median(spent) / 1000:.2f} us of CPU "
          f"per pair (median of {args.rounds} rounds of {args.pairs}; fastest {min(spent) / 1000:.2f})")


if __name__ == "__main__":
    main()
