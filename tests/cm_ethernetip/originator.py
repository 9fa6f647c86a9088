"""Drives cm-ethernetip's scanners (PyPI `cm-ethernetip`, Apache-2.0) against a farm device. Run
by the python of a venv that has cm-ethernetip installed (its top-level package `ethernetip`
clashes with the `ethernetip` scanner of the test dependencies), never imported by the tests.

    python originator.py '{"mode": "safety", "host": "127.0.20.1", "local": "127.0.21.1", ...}'

Writes one JSON object per line on stdout ({"event": "open", ...}, {"event": "rx", "data": hex},
{"event": "stats", ...}, {"event": "error", ...}) and reads commands from stdin, one JSON object
per line: {"cmd": "out", "data": hex}, {"cmd": "stats"}, {"cmd": "silent"} (stop sending, close
nothing), {"cmd": "close"} (Forward Close, then exit).

Workarounds for cm-ethernetip 0.1.0, in this script only (the farm is not bent to them):
- T->O destination: its scanners bind UDP to an ephemeral port and send no T->O socket address
  item, so a target sends T->O to port 2222 of the originator's address (Vol. 2, 3-3.9.4) where
  nobody listens. Here the scanner's TCP connection comes from `local` and its UDP socket listens
  on `local`:2222 (SO_REUSEADDR).
- The safety producer (`fix_producer`, default on): SafetyScannerConnection ignores the consumer
  time value of the target's time coordination message, advances its timestamp by a fixed 390
  ticks (49.92 ms) per message whatever the RPI, and in extended format ignores the initial
  timestamp and rollover value of the SafetyOpen reply and seeds idle messages with its own
  rollover value. A target that checks timestamps (sequence and data age, Vol. 5, 2-4.6) faults
  such a connection. With the fix the producer does what Vol. 5 asks: idle with timestamp 0 and
  rollover 0 until the first time coordination message, then its clock (128 us ticks) plus the
  correction from that message, rollover counted from the reply's initial values.
- Its base-format time coordination message (`encode_tcoo`) computes CRC-S3 over the consumer
  time value as one byte instead of two whenever the value is below 256 (its CRC routine takes an
  int below 256 for a single byte): 1 message in 256 fails a target's CRC check. The fix encodes
  the value as two bytes.
"""

from __future__ import annotations

import asyncio
import json
import socket
import struct
import sys
import time

from ethernetip.protocol.eip_scanner import EipScanner
from ethernetip.protocol.eip_udp_transport import EipUdpTransport, _UdpProtocol
from ethernetip.protocol.forward_open_config import ForwardOpenConfig
from ethernetip.safety import (
    ModeByte,
    SafetyConfigurationId,
    SafetyCrc,
    SafetyFormat,
    SafetyForwardOpenConfig,
    SafetyNetworkNumber,
    SafetyScannerConnection,
    UniqueNetworkId,
    encode_safety_frame,
)

TICK_NS = 128_000


def emit(**event: object) -> None:
    sys.stdout.write(json.dumps(event) + "\n")
    sys.stdout.flush()


class BoundUdp(EipUdpTransport):
    """cm-ethernetip's UDP transport listening on `address`:2222 with SO_REUSEADDR."""

    async def start(self, loop: asyncio.AbstractEventLoop | None = None) -> None:
        loop = loop or asyncio.get_running_loop()
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind((self._bind_address, self._bind_port))
        self._protocol = _UdpProtocol(self)
        self._transport, _ = await loop.create_datagram_endpoint(lambda: self._protocol, sock=sock)
        self.actual_port = self._bind_port


class BoundScanner(EipScanner):
    """EipScanner whose TCP connection comes from `local` and whose UDP listens on `local`:2222."""

    def __init__(self, local: str) -> None:
        super().__init__()
        self._local = local

    async def connect(self, host: str, port: int = 44818) -> None:
        self._reader, self._writer = await asyncio.open_connection(host, port, local_addr=(self._local, 0))
        sock = self._writer.get_extra_info("socket")
        self.local_endpoint = sock.getsockname()[:2]
        self.remote_endpoint = sock.getpeername()[:2]
        self._udp = BoundUdp(bind_address=self._local, bind_port=2222)
        await self._udp.start()
        self.session_handle = await self._register_session()


class FixedProducer(SafetyScannerConnection):
    """SafetyScannerConnection whose producer follows Vol. 5 (see the module docstring)."""

    def start_fix(self) -> None:
        reply = self._server_app_reply
        self._fix_active = False
        self._fix_correction = 0
        self._fix_rollover = reply.initial_rollover_value
        self._fix_last_ts = reply.initial_timestamp
        self._fix_sent = None
        self.last_sent_ns = None
        self.send_periods_us: list[int] = []

    def _send_client_tcoo(self, ping_count_reply: int) -> None:
        if self._format == SafetyFormat.EXTENDED:
            super()._send_client_tcoo(ping_count_reply)
            return
        consumer_time = (time.perf_counter_ns() // TICK_NS) & 0xFFFF
        ack = (ping_count_reply & 3) | 0x08
        ack |= 0x80 if bin(ack).count("1") % 2 else 0
        crc = SafetyCrc.compute_s3(struct.pack("<BH", ack, consumer_time), self._cid_seed_s3)
        message = struct.pack("<BHBH", ack, consumer_time, ((ack ^ 0xFF) & 0x55) | (ack & 0xAA), crc)
        self._udp.send_io_data(self._target_endpoint, self._client_ot_id, self._client_encap_seq, message)
        self._client_encap_seq += 1

    def _on_server_tcoo(self, data: bytes) -> None:
        if len(data) != 6 or (data[0] & 3) != self._ping_count:
            return
        consumer_time = struct.unpack_from("<H", data, 1)[0]
        self._fix_correction = (consumer_time - time.monotonic_ns() // TICK_NS) & 0xFFFF
        self._fix_active = self._consumer_active = self._run_idle = True

    def _produce_server_frame(self) -> None:
        if not self.is_open or self._target_endpoint is None:
            return
        if self._fix_active:
            timestamp = (time.monotonic_ns() // TICK_NS + self._fix_correction) & 0xFFFF
            if self._fix_sent is not None and not 0 < (timestamp - self._fix_sent) & 0xFFFF < 0x8000:
                timestamp = (self._fix_sent + 1) & 0xFFFF
            self._fix_sent = timestamp
            if timestamp < self._fix_last_ts:
                self._fix_rollover = (self._fix_rollover + 1) & 0xFFFF
            self._fix_last_ts = timestamp
            rollover = self._fix_rollover
        else:
            timestamp = rollover = 0
        mode = ModeByte.create(run_idle=self._fix_active, ping_count=self._ping_count)
        buf = bytearray(len(self._output_data) * 2 + 16)
        n = encode_safety_frame(buf, bytes(self._output_data), self._format, mode, timestamp,
                                self._pid_seed_s1, self._pid_seed_s3, self._pid_seed_s5, rollover)
        now = time.monotonic_ns()  # before the send: the target cannot receive it earlier
        if getattr(self, "last_sent_ns", None) is not None:
            self.send_periods_us.append((now - self.last_sent_ns) // 1000)
        self.last_sent_ns = now
        self._udp.send_io_data(self._target_endpoint, self._server_ot_id, self._server_encap_seq, bytes(buf[:n]))
        self._server_encap_seq += 1


def percentiles(values_us: list[int]) -> dict[str, float | None]:
    """p50, p99 and max of intervals in microseconds, as milliseconds."""
    ordered = sorted(values_us)
    if not ordered:
        return {"p50_ms": None, "p99_ms": None, "max_ms": None}
    return {"p50_ms": ordered[len(ordered) // 2] / 1000, "p99_ms": ordered[min(len(ordered) - 1,
            len(ordered) * 99 // 100)] / 1000, "max_ms": ordered[-1] / 1000}


def unid(snn_hex: str, node: int) -> UniqueNetworkId:
    return UniqueNetworkId(snn=SafetyNetworkNumber(bytes.fromhex(snn_hex)), node_address=node)


async def open_safety(scanner: EipScanner, args: dict) -> SafetyScannerConnection:
    fmt = SafetyFormat.EXTENDED if args.get("format") == "extended" else SafetyFormat.BASE
    scid = SafetyConfigurationId(sccrc=args.get("sccrc", 0),
                                 scts=SafetyNetworkNumber(bytes.fromhex(args.get("scts", "00" * 6))))
    common = dict(
        format=fmt, tunid=unid(args["snn"], args["node"]), ounid=unid(args.get("originator_snn", "0000000000aa"), 1),
        scid=scid, ping_interval_multiplier=args.get("ping", 100), time_coord_msg_min_multiplier=0,
        network_time_expectation_multiplier=args.get("nte", 781), timeout_multiplier=args.get("timeout", 2),
        connection_timeout_multiplier=2, initial_timestamp=0xFFFF, initial_rollover_value=0xFFFF,
        config_assembly=args.get("config_assembly", 1))
    rpi = args.get("rpi_us", 10_000)
    server = SafetyForwardOpenConfig(consumed_assembly=args.get("output_assembly", 100), produced_assembly=0,
                                     consumed_data_size=args.get("output_size", 1), produced_data_size=0,
                                     ot_rpi=rpi, to_rpi=rpi, **common)
    client = SafetyForwardOpenConfig(consumed_assembly=0, produced_assembly=args.get("input_assembly", 101),
                                     consumed_data_size=0, produced_data_size=args.get("input_size", 2),
                                     ot_rpi=rpi, to_rpi=rpi, **common)
    connection = await SafetyScannerConnection.open(scanner, scanner.udp, server, client,
                                                    orig_vendor=args.get("vendor", 0x0001),
                                                    orig_serial=args.get("serial", 0x00C0FFEE))
    if args.get("fix_producer", True):  # open() builds a SafetyScannerConnection whatever the class
        connection.__class__ = FixedProducer  # before its first message: no await since open() returned
        connection.start_fix()
    return connection


async def main(args: dict) -> None:
    scanner = BoundScanner(args["local"])
    await scanner.connect(args["host"])
    stats = {"rx": 0, "crc_faults": 0, "periods_us": []}
    last_rx = [None, None]

    def received(data: bytes) -> None:
        now = time.monotonic_ns()
        if last_rx[0] is not None:
            stats["periods_us"].append((now - last_rx[0]) // 1000)
        last_rx[0] = now
        stats["rx"] += 1
        if data != last_rx[1]:
            last_rx[1] = data
            emit(event="rx", data=data.hex())

    try:
        if args["mode"] == "safety":
            connection = await open_safety(scanner, args)
            connection.on_data_received.append(received)
            connection.log.append(lambda m: m.startswith("RX CRC FAIL") and stats.__setitem__(
                "crc_faults", stats["crc_faults"] + 1))
            emit(event="open", server_ot=connection._server_ot_id, client_to=connection._client_to_id)
        else:
            config = ForwardOpenConfig(consumed_assembly=args.get("output_assembly", 100),
                                       produced_assembly=args.get("input_assembly", 101),
                                       config_assembly=args.get("config_assembly", 1),
                                       consumed_size=args["output_size"], produced_size=args["input_size"],
                                       rpi=args.get("rpi_us", 10_000), transport_class=1, timeout_multiplier=2)
            connection = await scanner.forward_open(config)
            connection.on_data_received.append(received)
            emit(event="open", ot=connection.ot_connection_id, to=connection.to_connection_id)
    except RuntimeError as error:
        emit(event="error", error=str(error))
        await scanner.close()
        return

    loop = asyncio.get_running_loop()
    reader = asyncio.StreamReader()
    await loop.connect_read_pipe(lambda: asyncio.StreamReaderProtocol(reader), sys.stdin)
    while True:
        line = await reader.readline()
        if not line:
            break
        command = json.loads(line)
        cmd = command["cmd"]
        if cmd == "out":
            data = bytes.fromhex(command["data"])
            if args["mode"] == "safety":
                connection.set_output_data(data)
            else:
                connection.set_consumed_data(data)
        elif cmd == "stats":
            emit(event="stats", rx=stats["rx"], crc_faults=stats["crc_faults"],
                 rx_period=percentiles(stats["periods_us"]),
                 tx_period=percentiles(getattr(connection, "send_periods_us", [])),
                 sent=getattr(connection, "_server_encap_seq", getattr(connection, "send_count", 0)))
        elif cmd == "silent":
            connection.is_open = False  # production and time coordination stop; no Forward Close
            task = getattr(connection, "_production_task", None)
            if task is not None:
                task.cancel()
            emit(event="silent", at_ns=time.monotonic_ns(), last_sent_ns=getattr(connection, "last_sent_ns", None))
        elif cmd == "close":
            if connection.is_open:
                await connection.close()
            emit(event="closed")
            break
    await scanner.close()


if __name__ == "__main__":
    asyncio.run(main(json.loads(sys.argv[1])))
