"""Class-1 (and CIP Safety class-0) consumption and production of a connection table
(CIP Networks Library Vol. 2, 3-2 and 3-3; Vol. 5, 2-4.6 and 2-4.7), sans-IO: O->T datagrams in
(`receive_datagram`), T->O datagrams out on absolute deadlines, and the datagrams that answer at
once (CIP Safety time coordination), all through one outbound queue (`datagrams_to_send(now)`, or
`produce(now, horizon)`, the cyclic I/O thread's batched call).

`ClassOneIo` is a part of `ConnectionTable` (cip/connection_table.py), kept in its own module: it
holds no state of its own. Time is a parameter (integer nanoseconds), never read here.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping

from enip_farm.cip.assembly import AssemblyInstance
from enip_farm.cip.connection import Connection, ConnectionKind, Production
from enip_farm.cip.connection_events import (
    SAFETY_FAULTS,
    ConnectionClosed,
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
from enip_farm.protocol.safety.validator import SafetyConsumer

_HALF = 0x80000000
#: A datagram to send: its bytes and where to (host, port).
Datagram = tuple[bytes, tuple[str, int]]


class ClassOneIo:
    """The I/O data exchange of a connection table (mixed into `ConnectionTable`)."""

    # the table's state this part reads and writes (cip/connection_table.py sets it)
    assemblies: Mapping[str, AssemblyInstance]
    policy: ConnectionPolicy
    counters: Counter[str]
    connections: dict[int, Connection]
    productions: dict[tuple[int, tuple[str, int]], Production]
    _points: dict[int, AssemblyInstance]
    _events: list[ConnectionEvent]
    _outbox: list[Datagram]
    _short_data_reported: set[int]
    _safety_connections: int

    def close(self, connection: Connection, reason: str, now: int,
              ended: type[ConnectionEnded] = ConnectionClosed) -> None:
        raise NotImplementedError  # the table's: ConnectionTable.close

    def receive_datagram(self, data: bytes, host: str, now: int, port: int | None = None,
                         received_at: int | None = None) -> bool:
        """An O->T datagram on UDP 2222 (Vol. 2, 3-2) from `host`:`port`: True if it was a valid
        packet of one of the table's connections. O->T is taken only from the originator's address
        and, once a first valid packet came, only from that packet's port (a forger on another port
        of the same host cannot advance the sequence). Every other datagram is counted by why it
        was not taken. `received_at`: the kernel's receive time (default `now`), which the
        connection's measurement (cip/o_t_measure.py) takes: repeats and stale ones included."""
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
        measure = connection.measure
        if measure is not None:
            measure.o_t(now if received_at is None else received_at, sequence, sequence_count)
        last = connection.last_sequence
        if last is not None and not 0 < (sequence - last) & 0xFFFFFFFF < _HALF:
            return self._drop("stale")  # a duplicate or older than what was consumed (Vol. 2, 3-2.1)
        if connection.safety is not None:
            return self._receive_safety(connection, IoPacket(connection_id, sequence, sequence_count,
                                                             data[IO_HEADER_SIZE:]), now, port)
        payload = data[IO_HEADER_SIZE:]
        output = self._consumed(connection)
        if connection.o_t_run_idle_header:
            if len(payload) < RUN_IDLE_HEADER_SIZE:
                return self._drop("wrong_size")
            run = bool(payload[0] & 1)
            image = payload[RUN_IDLE_HEADER_SIZE:]
            if len(image) != len(output.data) and not (connection.o_t_variable and len(image) < len(output.data)):
                return self._drop("wrong_size")
        elif connection.o_t_modeless:  # data without a header; no data: idle (zero-length format)
            run, image = bool(payload), payload or None
            if payload and len(payload) != len(output.data) and not (
                    connection.o_t_variable and len(payload) < len(output.data)):
                return self._drop("wrong_size")
        elif payload and len(payload) != RUN_IDLE_HEADER_SIZE:  # a heartbeat: nothing, or a run/idle header
            return self._drop("wrong_size")
        else:
            run = not payload or bool(payload[0] & 1)
            image = None
        connection.last_sequence = sequence
        if connection.o_t_port is None:
            connection.o_t_port = port
        connection.last_received = now
        connection.received += 1
        if run is not connection.run and measure is not None:
            measure.run_idle(run, now if received_at is None else received_at)
        connection.run = run
        self.counters["o_t_packets"] += 1
        if image is None:
            if not run and connection.o_t_modeless and self.policy.outputs_off_on_idle:
                output.data[:] = bytes(len(output.data))
            return True
        if not run:
            if self.policy.outputs_off_on_idle:
                output.data[:] = bytes(len(output.data))
        elif len(image) == len(output.data):
            output.data[:] = image
        else:  # variable size, shorter than the assembly: the assembly takes whole images only
            self.counters["o_t_short_data"] += 1
            if connection.o_t_id not in self._short_data_reported:
                self._short_data_reported.add(connection.o_t_id)
                self._events.append(ConnectionShortData(
                    now, connection, f"{len(image)} of {len(output.data)} bytes: not applied to the outputs"))
        return True

    def _receive_safety(self, connection: Connection, packet: IoPacket, now: int, port: int | None) -> bool:
        """A class-0 CIP Safety packet: safe output data on a server connection, a time
        coordination message on a client connection (Vol. 5, 2-4.6 and 2-4.7). The sequence and
        the originator's port are taken from packets the Safety Validator accepted only: a forged
        datagram cannot pin another port or push the sequence past the real packets'."""
        safety = connection.safety
        result = safety.receive(class0_data(packet), now)  # type: ignore[union-attr]
        if result.fault is not None:
            self.counters[f"safety_{result.fault}_faults"] += 1
            self._events.append(SAFETY_FAULTS[result.fault](now, connection, result.detail))
            if result.faulted:
                self.counters["safety_faulted"] += 1
                self.close(connection, f"safety {result.fault} fault: {result.detail}", now, ConnectionFaulted)
            return False
        connection.last_sequence = packet.sequence
        if connection.o_t_port is None:
            connection.o_t_port = port
        connection.last_received = now
        connection.received += 1
        self.counters["safety_packets_consumed"] += 1
        if type(safety) is SafetyConsumer:
            connection.run = result.run
            output = self.assemblies["output"]
            if result.run:
                output.data[:] = result.data  # type: ignore[index]
            else:
                output.data[:] = bytes(len(output.data))  # idle: the safe state
            answer = safety.time_coordination(now)
            if answer is not None:
                connection.t_o_sequence += 1
                self._outbox.append((encode_class0_packet(connection.t_o_id, connection.t_o_sequence, answer),
                                     connection.t_o_address))  # type: ignore[arg-type]
                self.counters["safety_time_coordination_sent"] += 1
        else:
            connection.run = True
        return True

    def _consumed(self, connection: Connection) -> AssemblyInstance:
        """The assembly a connection's O->T data goes to: its consumed point's, else the output."""
        return self._points.get(connection.o_t_point, self.assemblies.get("output"))  # type: ignore[arg-type,return-value]

    def _produced(self, production: Production) -> bytes:
        """The T->O data of a stream of an EDS's connection: its run/idle header and point's bytes."""
        if production.heartbeat:
            return b""
        assembly = self._points.get(production.point)  # type: ignore[arg-type]
        return production.header + (bytes(assembly.data) if assembly is not None else b"")

    def _drop(self, reason: str) -> bool:
        self.counters[f"o_t_dropped_{reason}"] += 1
        return False

    @property
    def answers_queued(self) -> bool:
        """Datagrams wait to go at once (CIP Safety time coordination answering a ping): the
        caller of `receive_datagram` calls `datagrams_to_send(now)` when this is true."""
        return bool(self._outbox)

    def datagrams_to_send(self, now: int) -> list[Datagram]:
        """Everything to send by `now`, the one way out: the answers queued (CIP Safety time
        coordination) and the T->O packets due, one per stream; a stream that fell a whole period
        behind skips the missed periods rather than bursting."""
        return self.produce(now)[0]

    def produce(self, now: int, horizon: int | None = None) -> tuple[list[Datagram], int | None]:
        """`datagrams_to_send(now)` and then `get_timer()`, in one pass over the streams (the cyclic
        I/O thread's call, once per stream and period). With `horizon`, the packets due up to it are
        produced now (the thread serves what falls due within its next turn: a packet leaves at
        most `horizon - now` before its deadline; deadlines stay absolute, so no period drifts)."""
        out = self._outbox
        if out:  # the answers queued go first
            self._outbox = []
        else:
            out = []
        if self._safety_connections and self._safety_pending:
            out += self._pending_time_coordination(now)
        data = None
        earliest = None
        until = now if horizon is None or horizon < now else horizon
        for production in self.productions.values():
            due = production.start + production.count * production.period_ns
            if due <= until:
                if data is None:
                    data = bytes(self.assemblies["input"].data)
                production.sequence += 1
                if production.safety is None:
                    payload = data if production.point is None else self._produced(production)
                    out.append((encode_io_packet(production.connection_id, production.sequence, production.sequence,
                                                 payload), production.address))
                else:
                    message = production.safety.produce(data, now)
                    out.append((encode_class0_packet(production.connection_id, production.sequence, message),
                                production.address))
                    self.counters["safety_packets_produced"] += 1
                production.count += 1
                behind = now - due - production.period_ns
                if behind >= 0:  # the next one is already due: skip to the first deadline after now
                    skipped = behind // production.period_ns + 1
                    production.count += skipped
                    production.late += skipped
                due = production.start + production.count * production.period_ns
            if earliest is None or due < earliest:
                earliest = due
        if out:
            self.counters["t_o_packets"] += len(out)
        for connection in self.connections.values():
            deadline = connection.deadline
            if earliest is None or deadline < earliest:
                earliest = deadline
            safety = connection.safety
            if type(safety) is SafetyConsumer and safety.tcoo_due is not None and safety.tcoo_due < earliest:
                earliest = safety.tcoo_due
        return out, earliest

    @property
    def _safety_pending(self) -> bool:
        return any(type(c.safety) is SafetyConsumer and c.safety.tcoo_due is not None
                   for c in self.connections.values())

    def _pending_time_coordination(self, now: int) -> list[Datagram]:
        """Time coordination messages held back by the min multiplier and due by `now`."""
        out = []
        for connection in self.connections.values():
            safety = connection.safety
            if type(safety) is SafetyConsumer:
                answer = safety.time_coordination(now)
                if answer is not None:
                    connection.t_o_sequence += 1
                    out.append((encode_class0_packet(connection.t_o_id, connection.t_o_sequence, answer),
                                connection.t_o_address))  # type: ignore[arg-type]
        self.counters["safety_time_coordination_sent"] += len(out)
        return out

