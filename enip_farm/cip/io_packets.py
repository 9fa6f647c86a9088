"""The per-packet bookkeeping of a connection table's I/O connections (CIP Networks Library Vol. 2,
3-2 and 3-3; Vol. 5, 2-4.6 and 2-4.7), sans-IO: an O->T datagram consumed (its headers, the 32-bit
sequence against stale and duplicate packets, the run/idle header, the image into its assembly,
the counters) and the T->O datagrams made (each stream's sequence and headers; CIP Safety data and
time coordination messages as class 0), all through one outbound queue.

Every valid O->T packet passes through `_accepted`, every T->O datagram through `_produced`: the
one place each for what is learnt from a packet. What is due when is cip/io_schedule.py's; which
connections exist is the table's (cip/connection_table.py). Time is a parameter (integer
nanoseconds), never read here.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Mapping, Sequence

from enip_farm.cip.assembly import AssemblyInstance
from enip_farm.cip.connection import Connection, ConnectionKind, Production
from enip_farm.cip.connection_events import (
    SAFETY_FAULTS,
    ConnectionEnded,
    ConnectionEvent,
    ConnectionFaulted,
    ConnectionShortData,
)
from enip_farm.cip.connection_policy import RUN_IDLE_HEADER_SIZE, ConnectionPolicy
from enip_farm.protocol.connection import (
    IO_HEADER_SIZE,
    IoPacket,
    class0_data,
    encode_class0_packet,
    encode_io_packet,
    unpack_io_header,
)
from enip_farm.protocol.safety.validator import Consumed, SafetyConsumer

_HALF = 0x80000000
_IMAGE = IO_HEADER_SIZE + RUN_IDLE_HEADER_SIZE  # where the image of a packet with a run/idle header begins
#: A datagram to send: its bytes and where to (host, port).
Datagram = tuple[bytes, tuple[str, int]]
#: Why an O->T datagram was not taken; each reason is counted as `o_t_dropped_<reason>`.
DROP_REASONS = ("malformed", "unknown_connection", "wrong_originator", "wrong_port", "stale", "wrong_size",
                "io_stopped")
#: Ends a connection (the table's `close`): connection, reason, now, how it ended.
Close = Callable[[Connection, str, int, type[ConnectionEnded]], None]


class IoPackets:
    """Consumes the O->T datagrams and makes the T->O datagrams of one connection table."""

    def __init__(self, assemblies: Mapping[str, AssemblyInstance], policy: ConnectionPolicy, counters: Counter[str],
                 connections: Mapping[int, Connection], events: list[ConnectionEvent], outbox: list[Datagram],
                 close: Close) -> None:
        self.assemblies = assemblies
        self.policy = policy
        self.counters = counters
        self.connections = connections  # the table's, by O->T connection id
        self.events = events  # the table's: what happened, in order
        self.outbox = outbox  # the table's: datagrams to send at once (CIP Safety time coordination answers)
        self.close = close
        # every assembly by instance: an EDS's connections consume and produce their own points
        self._points = {a.instance_id: a for a in assemblies.values()}

    def consumed_assembly(self, connection: Connection) -> AssemblyInstance:
        """The assembly a connection's O->T data goes to: its consumed point's, else the output."""
        return self._points.get(connection.o_t_point, self.assemblies.get("output"))  # type: ignore[arg-type,return-value]

    # -- O->T ----------------------------------------------------------------------------------

    def receive(self, data: bytes, host: str, now: int, port: int | None = None,
                received_at: int | None = None) -> bool:
        """An O->T datagram on UDP 2222 (Vol. 2, 3-2) from `host`:`port`: True if it was a valid
        packet of one of the table's connections. O->T is taken only from the originator's address
        and, once a first valid packet came, only from that packet's port (a forger on another port
        of the same host cannot advance the sequence). Every other datagram is counted by why it
        was not taken. A CIP Safety packet is valid when its Safety Validator accepts it: a forged
        one cannot pin another port or push the sequence past the real packets'. `received_at`:
        the kernel's receive time (default `now`), which the connection's measurement
        (cip/o_t_measure.py) takes: repeats and stale ones included."""
        fields = unpack_io_header(data)
        if fields is None:
            return self._drop("malformed")
        connection_id, sequence, sequence_count = fields
        connection = self.connections.get(connection_id)
        if connection is None or connection.kind is ConnectionKind.EXPLICIT:
            return self._drop("unknown_connection")
        if host != connection.originator_host:
            return self._drop("wrong_originator")
        if port is not None and connection.o_t_port is not None and port != connection.o_t_port:
            return self._drop("wrong_port")
        measure = connection.measure  # every datagram of the originator's stream, stale ones too
        if measure is not None:
            measure.o_t(now if received_at is None else received_at, sequence, sequence_count)
        last = connection.last_sequence
        if last is not None and not 0 < (sequence - last) & 0xFFFFFFFF < _HALF:
            return self._drop("stale")  # a duplicate or older than what was consumed (Vol. 2, 3-2.1)
        safety = connection.safety
        if safety is not None:
            result = safety.receive(class0_data(IoPacket(connection_id, sequence, sequence_count,
                                                         data[IO_HEADER_SIZE:])), now)
            if result.fault is not None:
                return self._safety_fault(connection, result, now)
        else:
            output = self.consumed_assembly(connection)
            if connection.o_t_run_idle_header:
                if len(data) < _IMAGE:
                    return self._drop("wrong_size")
                run = bool(data[IO_HEADER_SIZE] & 1)
                image = data[_IMAGE:]
                if len(image) != len(output.data) and not (connection.o_t_variable and len(image) < len(output.data)):
                    return self._drop("wrong_size")
            elif connection.o_t_modeless:  # data without a header; no data: idle (zero-length format)
                image = data[IO_HEADER_SIZE:] or None
                run = image is not None
                if image and len(image) != len(output.data) and not (
                        connection.o_t_variable and len(image) < len(output.data)):
                    return self._drop("wrong_size")
            elif len(data) != IO_HEADER_SIZE and len(data) != _IMAGE:  # a heartbeat: nothing, or a run/idle header
                return self._drop("wrong_size")
            else:
                run = len(data) == IO_HEADER_SIZE or bool(data[IO_HEADER_SIZE] & 1)
                image = None
        # a valid packet, class 1 or CIP Safety: the one place for what it tells of its connection
        connection.last_sequence = sequence
        if connection.o_t_port is None:
            connection.o_t_port = port  # the first valid packet's, then only it
        connection.last_received = now  # the watchdog fed
        connection.deadline = now + connection.timeout_ns if safety is None else safety.deadline
        connection.received += 1
        if safety is not None:
            self._consume_safety(connection, result, now)
            return True
        if run is not connection.run and measure is not None:
            measure.run_idle(run, now if received_at is None else received_at)
        connection.run = run
        self.counters["o_t_packets"] += 1
        if image is None:
            if not run and connection.o_t_modeless and self.policy.outputs_off_on_idle:
                output.data[:] = bytes(len(output.data))
            return True
        size = len(output.data)
        if not run:
            if self.policy.outputs_off_on_idle:
                output.data[:] = bytes(size)
        elif len(image) == size:
            output.data[:] = image
        else:  # variable size, shorter than the assembly: the assembly takes whole images only
            self.counters["o_t_short_data"] += 1
            if not connection.short_data_reported:
                connection.short_data_reported = True
                self.events.append(ConnectionShortData(
                    now, connection, f"{len(image)} of {size} bytes: not applied to the outputs"))
        return True

    def _safety_fault(self, connection: Connection, result: Consumed, now: int) -> bool:
        """A CIP Safety packet its Safety Validator refused (Vol. 5, 2-4.6): counted, reported and,
        past the validator's limit, the connection faulted."""
        self.counters[f"safety_{result.fault}_faults"] += 1
        self.events.append(SAFETY_FAULTS[result.fault](now, connection, result.detail))  # type: ignore[index]
        if result.faulted:
            self.counters["safety_faulted"] += 1
            self.close(connection, f"safety {result.fault} fault: {result.detail}", now, ConnectionFaulted)
        return False

    def _consume_safety(self, connection: Connection, result: Consumed, now: int) -> None:
        """A CIP Safety packet its Safety Validator took: safe output data on a server connection
        (its time coordination answer goes at once unless the min multiplier holds it back), a time
        coordination message on a client connection (Vol. 5, 2-4.6 and 2-4.7)."""
        self.counters["safety_packets_consumed"] += 1
        safety = connection.safety
        if type(safety) is SafetyConsumer:
            connection.run = result.run
            output = self.assemblies["output"]
            if result.run:
                output.data[:] = result.data  # type: ignore[index]
            else:
                output.data[:] = bytes(len(output.data))  # idle: the safe state
            if safety.tcoo_due is not None and safety.tcoo_due <= now:
                self.outbox += self.time_coordination([connection], now)
        else:
            connection.run = True

    def _drop(self, reason: str) -> bool:
        self.counters[f"o_t_dropped_{reason}"] += 1
        return False

    # -- T->O ----------------------------------------------------------------------------------

    def produce(self, streams: list[Production], answers: Sequence[Connection], now: int) -> list[Datagram]:
        """The datagrams to send now: the answers queued, the time coordination `answers` held back
        and now due, then one T->O packet for each of `streams` (cip/io_schedule.py says which)."""
        outbox = self.outbox
        if outbox:  # the answers queued go first
            out = outbox[:]
            outbox.clear()
        else:
            out = []
        if answers:
            out += self.time_coordination(answers, now)
        if streams:
            data = bytes(self.assemblies["input"].data)
            for production in streams:  # the one place for a T->O packet: its sequence, headers and data
                production.sequence += 1
                safety = production.safety
                if safety is not None:  # a CIP Safety client: its Safety Validator's message, class 0
                    out.append((encode_class0_packet(production.connection_id, production.sequence,
                                                     safety.produce(data, now)), production.address))
                    self.counters["safety_packets_produced"] += 1
                    continue
                if production.point is None:  # the input assembly
                    payload = data
                elif production.heartbeat:  # an EDS's connection: no data, or its header and point's bytes
                    payload = b""
                else:
                    assembly = self._points.get(production.point)
                    payload = production.header + (bytes(assembly.data) if assembly is not None else b"")
                out.append((encode_io_packet(production.connection_id, production.sequence, production.sequence,
                                             payload), production.address))
        if out:
            self.counters["t_o_packets"] += len(out)
        return out

    def time_coordination(self, consumers: Sequence[Connection], now: int) -> list[Datagram]:
        """The time coordination messages (class 0) of these CIP Safety servers that are due by `now`."""
        out = []
        for connection in consumers:
            answer = connection.safety.time_coordination(now)  # type: ignore[union-attr]
            if answer is not None:
                connection.t_o_sequence += 1
                out.append((encode_class0_packet(connection.t_o_id, connection.t_o_sequence, answer),
                            connection.t_o_address))  # type: ignore[arg-type]
        self.counters["safety_time_coordination_sent"] += len(out)
        return out
