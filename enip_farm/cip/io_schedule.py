"""What is due next in a connection table, sans-IO: the T->O production streams on absolute
deadlines (CIP Networks Library Vol. 2, 3-3: a packet every RPI), the supervision deadlines of the
connections (Vol. 1, 3-4.4.9) and the CIP Safety time coordination answers held back by the
minimum multiplier (Vol. 5, 2-4.6). One structure holds them (the streams, the supervised
connections, the safety consumers) and one scan reads it (`produce`): what falls due by a time,
handed to the per-packet bookkeeping (cip/io_packets.py) to make its datagrams, and the earliest
time anything is due after it; `get_timer` is that scan with nothing due.

Time is a parameter (integer nanoseconds of a monotonic clock), never read here.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from enip_farm.cip.connection import Connection, Production
from enip_farm.cip.io_packets import Datagram
from enip_farm.protocol.safety.multicast import MulticastConsumer
from enip_farm.protocol.safety.validator import SafetyConsumer

#: A T->O stream's key: (T->O connection id, destination). Multicast connections to one group share a
#: stream; point-to-point ones never do, even when two originators chose the same T->O id.
StreamKey = tuple[int, tuple[str, int]]
#: Makes the datagrams of what is due: the streams, the time coordination answers, now.
Make = Callable[[list[Production], Sequence[Connection], int], list[Datagram]]
_NEVER = -(1 << 63)  # before any time: nothing is due by it


class IoSchedule:
    """The production schedule and the supervision deadlines of one connection table."""

    def __init__(self, connections: dict[int, Connection], make: Make) -> None:
        self.connections = connections  # the table's, by O->T connection id: each one's deadline
        self.make = make  # the datagrams of what is due (cip/io_packets.py)
        self.productions: dict[StreamKey, Production] = {}
        self.safety_consumers: list[Connection] = []  # CIP Safety servers: their time coordination answers

    # -- what is scheduled ----------------------------------------------------------------------

    def add(self, connection: Connection, now: int, point: int | None = None, header: bytes = b"",
            heartbeat: bool = False) -> None:
        """Schedule an I/O connection: its T->O stream from `now` on (or one more user of the
        stream it shares; a CIP Safety client's is made by its validator, a multicast one's by the
        producer its consumers share) or, a CIP Safety server, its time coordination answers."""
        safety = connection.safety
        if type(safety) is SafetyConsumer:
            self.safety_consumers.append(connection)
            return
        key = (connection.t_o_id, connection.t_o_address)
        production = self.productions.get(key)  # type: ignore[arg-type]
        if production is not None:
            production.users += 1
        else:
            self.productions[key] = Production(  # type: ignore[index]
                connection.t_o_id, connection.t_o_address, connection.t_o_rpi * 1000, now,  # type: ignore[arg-type]
                point=point, header=header, heartbeat=heartbeat,
                safety=safety.producer if type(safety) is MulticastConsumer else safety)

    def remove(self, connection: Connection) -> None:
        """A connection closed: its stream ends with its last user."""
        if type(connection.safety) is SafetyConsumer:
            self.safety_consumers.remove(connection)
            return
        key = (connection.t_o_id, connection.t_o_address)
        production = self.productions.get(key)  # type: ignore[arg-type]
        if production is not None:
            production.users -= 1
            if production.users <= 0:
                del self.productions[key]  # type: ignore[arg-type]

    def shares(self, connection: Connection) -> bool:
        """Whether the connection would join a stream that is already produced."""
        return (connection.t_o_id, connection.t_o_address) in self.productions

    def stream_id_taken(self, connection_id: int) -> bool:
        return any(key[0] == connection_id for key in self.productions)

    # -- what is due ----------------------------------------------------------------------------

    def produce(self, now: int, horizon: int | None = None,
                dry: bool = False) -> tuple[list[Datagram], int | None]:
        """The datagrams to send by `now` (made by `make`) and then the earliest time anything is due
        (a T->O packet, a supervision deadline, a time coordination answer held back), in one scan:
        the streams due, each moved on to its next deadline (one that fell a whole period behind
        skips the missed periods rather than bursting; deadlines stay absolute, so no period
        drifts), and the safety consumers whose answer is due. With `horizon`, the packets due up to
        it are produced now (the cyclic I/O thread serves what falls due within its next turn: a
        packet leaves at most `horizon - now` before its deadline). `dry`: nothing is made."""
        until = now if horizon is None or horizon < now else horizon
        streams = []
        earliest = None
        for production in self.productions.values():
            due = production.due
            if due <= until:
                streams.append(production)
                period = production.period_ns
                production.count += 1
                behind = now - due - period
                if behind >= 0:  # the next one is already due: skip to the first deadline after now
                    skipped = behind // period + 1
                    production.count += skipped
                    production.late += skipped
                production.due = due = production.start + production.count * period
            if earliest is None or due < earliest:
                earliest = due
        for connection in self.connections.values():
            deadline = connection.deadline
            if earliest is None or deadline < earliest:
                earliest = deadline
        answers: Sequence[Connection] = ()
        if self.safety_consumers:
            answers = []
            for connection in self.safety_consumers:
                due = connection.safety.tcoo_due  # type: ignore[union-attr]
                if due is not None:
                    if due <= now:
                        answers.append(connection)
                    elif due < earliest:  # type: ignore[operator]
                        earliest = due
        return [] if dry else self.make(streams, answers, now), earliest

    def get_timer(self) -> int | None:
        """The earliest time something is due: `produce`'s at a time before anything, making nothing."""
        return self.produce(_NEVER, dry=True)[1]

    def supervision_due(self, now: int) -> bool:
        """Whether a connection's supervision deadline has come by `now`."""
        for connection in self.connections.values():
            if connection.deadline <= now:
                return True
        return False

    def expired(self, now: int) -> list[Connection]:
        """The connections whose supervision deadline has come (at the deadline, not a tick before)."""
        return [c for c in self.connections.values() if c.deadline <= now]
