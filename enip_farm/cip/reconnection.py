"""Reconnection, per device and originator: after the device came back (a fault cleared, a reset
done) or after an originator's connection timed out, the time until that originator's next
accepted Forward Open and its first O->T packet after it (CIP Networks Library Vol. 1, 3-4.4.9
and 3-5.4.1: what a scanner does when a connection is lost). Sans-IO, time passed in; bounded: the
last `KEPT` reconnections and at most `ORIGINATORS` originators remembered."""

from __future__ import annotations

from collections import OrderedDict, deque

from enip_farm.cip.o_t_measure import OriginatorMeasure
from enip_farm.cip.report import ReconnectAfter, Reconnection

KEPT = 16
ORIGINATORS = 64


class _Pending:
    __slots__ = ("after", "since", "forward_open", "measure")

    def __init__(self, after: ReconnectAfter, since: int) -> None:
        self.after = after
        self.since = since
        self.forward_open: int | None = None
        self.measure: OriginatorMeasure | None = None  # the new connection's: its first O->T


class Reconnections:
    """What the connection table tells (opened, timed out) and the device (back), turned into
    `Reconnection` figures."""

    def __init__(self) -> None:
        self._pending: dict[str, _Pending] = {}  # by originator: waiting for a Forward Open
        self._done: deque[tuple[str, _Pending]] = deque(maxlen=KEPT)
        self._seen: OrderedDict[str, None] = OrderedDict()  # originators that had a connection, not closed

    def opened(self, originator: str, now: int, measure: OriginatorMeasure | None) -> None:
        """An I/O connection of `originator` was admitted at `now`."""
        self._seen[originator] = None
        self._seen.move_to_end(originator)
        if len(self._seen) > ORIGINATORS:
            self._seen.popitem(last=False)
        pending = self._pending.pop(originator, None)
        if pending is not None:
            pending.forward_open = now
            pending.measure = measure
            self._done.append((originator, pending))

    def timed_out(self, originator: str, now: int) -> None:
        """A connection of `originator` timed out at `now` (unless it already waits to reconnect)."""
        if originator in self._pending or len(self._pending) < ORIGINATORS:
            self._pending.setdefault(originator, _Pending("timeout", now))

    def left(self, originator: str) -> None:
        """`originator` Forward Closed its last connection: it is not expected back."""
        self._seen.pop(originator, None)

    def device_back(self, after: ReconnectAfter, now: int, connected: set[str]) -> None:
        """The device answers again at `now`: every originator whose connections it lost (it had
        one and did not close it) and that has none open (`connected`) is expected back."""
        for originator in [o for o in self._seen if o not in connected]:
            self._pending[originator] = _Pending(after, now)

    def figures(self, device: str) -> list[Reconnection]:
        """The reconnections done (oldest first), then those still waiting."""
        out = [Reconnection(device, o, p.after, p.since, p.forward_open,
                            p.measure.first_at if p.measure is not None else None) for o, p in self._done]
        out += [Reconnection(device, o, p.after, p.since, None, None) for o, p in self._pending.items()]
        return out
