"""The connection table of one device, sans-IO (CIP Networks Library Vol. 1, 3-4 and 3-5.5;
Vol. 2, 3-2 and 3-3), in the style of aioquic's `QuicConnection`:

- Forward Open (admitted or refused by cip/admission.py, then within the I/O thread's budget,
  cip/budget.py: past it 0x01/0x0113), Forward Close, and the close cascade of listen-only
  connections;
- consumption of O->T packets (`receive_datagram`) and production of T->O packets on absolute
  deadlines (`datagrams_to_send`, `produce`): what is due when is the table's `IoSchedule`
  (cip/io_schedule.py), the bookkeeping of each packet its `IoPackets` (cip/io_packets.py);
- supervision (`get_timer`, `handle_timer`): the first watchdog, then exactly the last valid
  packet + RPI x 2^(2 + multiplier);
- CIP Safety connections (Vol. 5): a server consumes the safe outputs through its Safety Validator
  (integrity, sequence and age checks; its time coordination answers go out with the T->O
  packets: one outbound queue, `datagrams_to_send(now)`), a client produces the safe inputs on
  the T->O schedule; their supervision is the validator's (network time expectation; time
  coordination), and the end of a server connection, whatever ends it, puts the safe outputs in
  the safe state (all off).

Time is always a parameter (integer nanoseconds of a monotonic clock), never read here. The
caller holds the device lock around every call: the table reads and writes the assemblies' bytes.
What happened is returned (`pop_events`: one typed event per kind, cip/connection_events.py), never
called back.
"""

from __future__ import annotations

import random
from collections import Counter, deque
from collections.abc import Callable, Mapping
from typing import NamedTuple

from enip_farm.cip.admission import Admission, Originator
from enip_farm.cip.assembly import AssemblyInstance
from enip_farm.cip.budget import CyclicBudget
from enip_farm.cip.connection import Connection, ConnectionKind
from enip_farm.cip.connection_events import (
    ConnectionClosed,
    ConnectionEnded,
    ConnectionEvent,
    ConnectionOpened,
    ConnectionRefused,
    ConnectionTimedOut,
    SafeState,
    refused_open,
)
from enip_farm.cip.connection_path import KeyIdentity
from enip_farm.cip.connection_policy import ConnectionPolicy, Refusal, SafetyOpen
from enip_farm.cip.io_packets import DROP_REASONS, Datagram, IoPackets
from enip_farm.cip.io_schedule import IoSchedule
from enip_farm.cip.o_t_measure import OriginatorMeasure, forward_open_asked
from enip_farm.cip.reconnection import Reconnections
from enip_farm.cip.report import EndWord, ReconnectAfter
from enip_farm.protocol.commands import SocketAddress, encode_sockaddr
from enip_farm.protocol.connection import ConnectionTriad, ForwardOpenRequest
from enip_farm.protocol.cpf import ItemType
from enip_farm.protocol.safety.multicast import MulticastConsumer
from enip_farm.protocol.safety.validator import SafetyConsumer
from enip_farm.protocol.session import ReplyItems
from enip_farm.protocol.status import ExtendedStatus as X
from enip_farm.protocol.status import GeneralStatus, describe_status

#: Identity status (Vol. 1, table 5-2.4): bit 0 owned; bits 4-7 extended device status.
_OWNED = 0x0001
_NO_IO = 0x0030  # no I/O connection established
_IO_RUN = 0x0060  # at least one I/O connection in run mode
_IO_IDLE = 0x0070  # I/O connections established, all idle

#: The counters the table keeps (in the device's Counter).
TABLE_COUNTERS = ("connection_timeouts", "o_t_packets", "t_o_packets", "o_t_short_data",
                  *(f"o_t_dropped_{reason}" for reason in DROP_REASONS),
                  # CIP Safety: connections opened, messages taken and produced, time coordination
                  # answers, faults by kind (`safety_<crc|timing>_faults`), faulted connections, timeouts
                  "safety_connections", "safety_packets_consumed", "safety_packets_produced",
                  "safety_time_coordination_sent", "safety_crc_faults", "safety_timing_faults", "safety_faulted",
                  "safety_timeouts")


class Opened(NamedTuple):
    connection: Connection
    reply_items: ReplyItems  # e.g. the multicast group (0x8001) of Vol. 2, 3-3.9.4
    application_reply: bytes = b""  # a SafetyOpen's (Vol. 5, 3-5.4.2)


_RUN_HEADER = b"\x01\x00\x00\x00"  # a T->O 32-bit run/idle header: run
#: Ended connections whose measurement the table keeps (the report shows them after the open ones).
ENDED_KEPT = 16


class ConnectionTable:
    """The CIP connections of one device. Every method takes the time, none reads a clock.

    Composed of two parts, each with one job: `schedule` (cip/io_schedule.py) says what is due next
    and `packets` (cip/io_packets.py) keeps the books of each class-1 packet. Their hot calls are
    the table's own: `receive_datagram(data, host, now, port)` (an O->T datagram: True if a
    connection took it), `produce(now, horizon)` (the datagrams due, then the next time),
    `get_timer()` and `supervision_due(now)`."""

    def __init__(self, assemblies: Mapping[str, AssemblyInstance], policy: ConnectionPolicy,
                 identity: Callable[[], KeyIdentity], counters: Counter[str] | None = None,
                 rng: random.Random | None = None, budget: CyclicBudget | None = None,
                 sizes: Callable[[str, int], int] | None = None) -> None:
        self.assemblies = assemblies
        self.budget = budget
        self.policy = policy
        self.admission = Admission(assemblies, policy, identity, rng, sizes)
        self.counters: Counter[str] = counters if counters is not None else Counter()
        self.connections: dict[int, Connection] = {}  # by O->T connection id
        self._by_triad: dict[ConnectionTriad, Connection] = {}
        self._events: list[ConnectionEvent] = []
        #: The events not yet popped, read only (the device transaction asks whether there are any
        #: without a call: the same list, never replaced).
        self.pending_events: list[ConnectionEvent] = self._events
        self._outbox: list[Datagram] = []  # to send at once (CIP Safety time coordination): datagrams_to_send
        self.packets = IoPackets(assemblies, policy, self.counters, self.connections, self._events, self._outbox,
                                 self.close)  # the bookkeeping of each class-1 packet
        self.schedule = IoSchedule(self.connections, self.packets.produce)  # what is due next
        self.productions = self.schedule.productions  # the T->O streams, by (T->O connection id, destination)
        # the hot calls go straight to the part that answers them
        self.receive_datagram = self.packets.receive  # an O->T datagram: True if a connection took it
        # (datagrams to send by `now`, by `horizon` if given; then `get_timer()`): the cyclic I/O thread's call
        self.produce = self.schedule.produce
        self.get_timer = self.schedule.get_timer  # the earliest time something is due
        self.supervision_due = self.schedule.supervision_due  # whether `handle_timer(now)` would close one
        #: Measure every I/O connection's O->T stream (cip/o_t_measure.py); the last ENDED_KEPT ended ones stay.
        self.measuring = True
        self.ended: deque[Connection] = deque(maxlen=ENDED_KEPT)
        self.reconnections = Reconnections()

    # -- what the table says -------------------------------------------------------------------

    @property
    def has_events(self) -> bool:
        return bool(self._events)

    def pop_events(self) -> list[ConnectionEvent]:
        events = self._events[:]  # the list itself is shared with the table's parts
        self._events.clear()
        return events

    def _id_taken(self, connection_id: int) -> bool:
        return connection_id in self.connections or self.schedule.stream_id_taken(connection_id)

    def find(self, triad: ConnectionTriad) -> Connection | None:
        return self._by_triad.get(triad)

    @property
    def status(self) -> int:
        """Identity attribute 5 as the I/O connections make it."""
        io = [c for c in self.connections.values() if c.is_io]
        if not io:
            return _NO_IO
        owned = _OWNED if any(c.kind is ConnectionKind.EXCLUSIVE_OWNER for c in io) else 0
        return owned | (_IO_RUN if any(c.run for c in io) else _IO_IDLE)

    # -- class-1 I/O: the one way in, the one way out ----------------------------------------------

    @property
    def answers_queued(self) -> bool:
        """Datagrams wait to go at once (CIP Safety time coordination answering a ping): the
        caller of `receive_datagram` (`IoPackets.receive`) calls `datagrams_to_send(now)` when this is true."""
        return bool(self._outbox)

    def datagrams_to_send(self, now: int) -> list[Datagram]:
        """Everything to send by `now`, the one way out: the answers queued (CIP Safety time
        coordination) and the T->O packets due, one per stream; a stream that fell a whole period
        behind skips the missed periods rather than bursting."""
        return self.produce(now)[0]


    # -- Forward Open, Forward Close -------------------------------------------------------------

    def forward_open(self, request: ForwardOpenRequest, originator: Originator, now: int) -> Opened | Refusal:
        connection = self.admission.admit(request, originator, now, self.connections.values(), self._id_taken)
        if type(connection) is Refusal:
            self._events.append(ConnectionRefused(now, refused_open(request, originator, connection)))
            return connection
        if type(connection) is SafetyOpen:
            refusal = self._reserve(connection.connection, request, originator, now)
            if refusal is None and self.measuring:
                connection.connection.measure = OriginatorMeasure(
                    connection.connection.o_t_rpi * 1000, now,
                    forward_open_asked(request, connection.connection.timeout_ns))
            return refusal if refusal is not None else self._safety_opened(connection, now)
        if connection.is_io:
            refusal = self._reserve(connection, request, originator, now)
            if refusal is not None:
                return refusal
            if self.measuring:
                connection.measure = OriginatorMeasure(connection.o_t_rpi * 1000, now,
                                                       forward_open_asked(request, connection.timeout_ns))
        self._opened(connection, now)
        if not connection.is_io:
            return Opened(connection, ())
        if connection.kind is ConnectionKind.EXCLUSIVE_OWNER:
            self.packets.consumed_assembly(connection).owned = True
        if connection.configuration_data:  # the Forward Open's configuration data (an EDS's connections)
            configuration = self.assemblies.get("configuration")
            if configuration is not None and len(configuration.data) == len(connection.configuration_data):
                configuration.data[:] = connection.configuration_data
        self.schedule.add(connection, now, point=connection.t_o_point if self.policy.declared else None,
                          header=_RUN_HEADER if connection.t_o_run_idle_header else b"",
                          heartbeat=connection.t_o_heartbeat)
        self.reconnections.opened(originator.host, now, connection.measure)
        return Opened(connection, _multicast_items(connection))

    def _opened(self, connection: Connection, now: int) -> None:
        self.connections[connection.o_t_id] = connection
        self._by_triad[connection.triad] = connection
        self._events.append(ConnectionOpened(now, connection))

    def _reserve(self, connection: Connection, request: ForwardOpenRequest, originator: Originator,
                 now: int) -> Refusal | None:
        """Take the connection's datagrams per second from the I/O thread's budget, or refuse it
        (0x01/0x0113, Vol. 1 table 3-5.33) with the figures."""
        budget = self.budget
        if budget is None:
            return None
        shares = self.schedule.shares(connection)
        rate = budget.rate(connection.o_t_rpi, None if shares else connection.t_o_rpi)
        connection.reservation = budget.reserve(rate)
        if connection.reservation is not None:
            return None
        refusal = Refusal(X.OUT_OF_CONNECTIONS)
        self._events.append(ConnectionRefused(now, refused_open(request, originator, refusal) + (
            f": the farm's cyclic I/O budget is {budget.datagrams_per_s:.0f} datagrams/s per worker, "
            f"{budget.reserved:.0f} taken, this connection needs {rate:.0f}")))
        return refusal

    def _safety_opened(self, opened: SafetyOpen, now: int) -> Opened:
        connection = opened.connection
        self.counters["safety_connections"] += 1
        self._opened(connection, now)
        if connection.kind is ConnectionKind.SAFETY_OUTPUT:
            self.assemblies["output"].owned = True
        self.schedule.add(connection, now)
        return Opened(connection, _multicast_items(connection), opened.application_reply)

    def forward_close(self, triad: ConnectionTriad, now: int, host: str = "") -> Connection | None:
        """Close the connection of this triad; None if there is none (0x0107). `host`: who asked."""
        connection = self._by_triad.get(triad)
        if connection is not None:
            self.close(connection, "forward close", now, ends="forward close")
        else:
            self._events.append(ConnectionRefused(now, (
                f"Forward Close from {host or '?'}: "
                f"{describe_status(GeneralStatus.CONNECTION_FAILURE, X.CONNECTION_NOT_FOUND)} "
                f"(connection serial 0x{triad.connection_serial:04X}, vendor {triad.originator_vendor_id}, "
                f"originator serial 0x{triad.originator_serial:08X})")))
        return connection

    def device_back(self, after: ReconnectAfter, now: int) -> None:
        """The device answers again (a fault cleared, a reset done): its originators are expected back."""
        self.reconnections.device_back(after, now, {c.originator_host for c in self.connections.values() if c.is_io})

    def session_closed(self, session: object, now: int) -> None:
        """The TCP connection of a session ended: its class-3 connections end with it."""
        for connection in [c for c in self.connections.values() if c.owner is session]:
            self.close(connection, "TCP connection closed", now, ends="tcp gone")

    def close(self, connection: Connection, reason: str, now: int,
              ended: type[ConnectionEnded] = ConnectionClosed, ends: EndWord = "closed") -> None:
        """Close a connection; `ended` says how (a timeout or a fault applies the fault state), and
        the report's word for it: the class's (`ConnectionEnded.ends`), else `ends`. `reason`: text only."""
        word = ended.ends or ends
        if connection.closed:
            return
        connection.closed = True
        if connection.reservation is not None and self.budget is not None:
            self.budget.release(connection.reservation)
            connection.reservation = None
        if type(connection.safety) is MulticastConsumer:  # only this consumer leaves the producer
            connection.safety.leave()
        self.connections.pop(connection.o_t_id, None)
        self._by_triad.pop(connection.triad, None)
        if connection.is_io:
            self.schedule.remove(connection)
        if connection.kind is ConnectionKind.EXCLUSIVE_OWNER:
            output = self.packets.consumed_assembly(connection)
            output.owned = False
            if self.policy.outputs_off_on_idle if ended is ConnectionClosed else self.policy.outputs_off_on_fault:
                output.data[:] = bytes(len(output.data))
        self._events.append(ended(now, connection, reason))
        if connection.measure is not None:
            connection.measure.end(now, word, reason)
            self.ended.append(connection)
            host = connection.originator_host
            if word == "forward close" and not any(c.originator_host == host for c in self.connections.values()):
                self.reconnections.left(host)
        if connection.kind is ConnectionKind.SAFETY_OUTPUT:  # whatever ends it: the safe state
            output = self.assemblies["output"]
            output.owned = False
            output.data[:] = bytes(len(output.data))
            self._events.append(SafeState(now, connection, f"safe outputs off: {reason}"))
        if connection.multicast and connection.kind is not ConnectionKind.LISTEN_ONLY and not any(
                c.multicast and c.t_o_point == connection.t_o_point and c.kind is not ConnectionKind.LISTEN_ONLY
                for c in self.connections.values()):
            for listener in [c for c in self.connections.values()
                             if c.kind is ConnectionKind.LISTEN_ONLY and c.t_o_point == connection.t_o_point]:
                self.close(listener, "its producing connection closed", now)

    # -- supervision -----------------------------------------------------------------------------

    def handle_timer(self, now: int) -> None:
        """Close every connection whose deadline has come (at the deadline, not a tick before)."""
        for connection in self.schedule.expired(now):
            self.counters["connection_timeouts"] += 1
            safety = connection.safety
            if type(safety) is SafetyConsumer:
                self.counters["safety_timeouts"] += 1
                reason = (f"safety timeout: no valid data for the network time expectation, "
                          f"{safety.nte_ns / 1e6:g} ms" if safety.last_valid is not None else
                          f"safety timeout: no valid data within {(safety.deadline - safety.opened_at) / 1e6:g} ms")
            elif safety is not None:  # a producer, single-cast or one multicast consumer
                self.counters["safety_timeouts"] += 1
                reason = f"safety timeout: no time coordination for {(safety.timeout_pi + 2)} ping intervals"
            else:
                reason = f"no packet for {connection.timeout_ns / 1e6:g} ms"
            self.reconnections.timed_out(connection.originator_host, now)
            self.close(connection, reason, now, ConnectionTimedOut)

    # -- class-3 consumption -----------------------------------------------------------------------

    def receive_connected(self, connection_id: int, session: object, now: int) -> Connection | None:
        """A class-3 request on a connection of this session (Vol. 2, 2-6.2): the connection, its
        watchdog fed; None when the connection is not this session's."""
        connection = self.connections.get(connection_id)
        if connection is None or connection.is_io or connection.owner is not session:
            return None
        connection.last_received = now
        connection.deadline = now + connection.timeout_ns
        connection.received += 1
        return connection


def _multicast_items(connection: Connection) -> ReplyItems:
    """The T->O socket address item of a multicast connection's reply: its group (Vol. 2, 3-3.9.4)."""
    if not connection.multicast:
        return ()
    return ((ItemType.SOCKADDR_T_O, encode_sockaddr(SocketAddress(*connection.t_o_address))),)  # type: ignore[misc]
