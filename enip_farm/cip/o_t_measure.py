"""The originator's side of one class-1 connection, measured packet by packet (CIP Networks Library
Vol. 2, 3-2.1: the 32-bit sequence of the sequenced address item and the 16-bit sequence count;
Vol. 1, 3-6.5: the API; ODVA/NIST: the measured packet interval against the API is the jitter).

Sans-IO: every call takes the time (integer ns, the kernel's receive time of the datagram on the
farm's monotonic clock). Memory is fixed whatever the originator sends: a histogram with fixed
buckets (as Prometheus and HdrHistogram keep them), counters, and the last `RECENT_RUN_IDLE`
run/idle transitions. `figures()` freezes it into the report's values (cip/report.py).
"""

from __future__ import annotations

from bisect import bisect_left
from collections import deque

from enip_farm.cip.connection_path import data_segments, electronic_key
from enip_farm.cip.report import (
    CipSequenceFigures,
    ConnectionFigures,
    ElectronicKeyAsked,
    EndWord,
    ForwardOpenAsked,
    Histogram,
    IntervalFigures,
    RunIdle,
    SequenceFigures,
)
from enip_farm.protocol.connection import ConnectionType, ForwardOpenRequest

#: Upper bounds of the interval histogram's buckets, in thousandths of the API: fine around 1 API,
#: where a scanner's jitter lies, coarse further out. One more bucket counts what lies above them.
BUCKETS_PERMILLE = (100, 250, 500, 750, 800, 850, 900, 950, 970, 980, 990, 995, 1000, 1005, 1010, 1020,
                    1030, 1050, 1100, 1150, 1200, 1300, 1400, 1500, 1750, 1999, 2500, 3000, 4000, 6000,
                    8000, 16000, 32000, 64000)
BOUNDS_API = tuple(b / 1000 for b in BUCKETS_PERMILLE)
#: Run/idle transitions kept with their times (the count of all is kept too).
RECENT_RUN_IDLE = 16
_HALF = 0x80000000
_NO_MIN = 1 << 63  # no interval yet
_LATE_FROM = BUCKETS_PERMILLE.index(1999) + 1  # the first bucket of intervals of 2 API or more


class OriginatorMeasure:
    """The measurement of one connection's O->T stream. `o_t` is the per-packet hook."""

    __slots__ = ("api_ns", "opened_at", "asked", "counts", "total_ns", "_min_ns", "max_ns", "_bounds_ns", "last_at",
                 "first_at", "last_sequence", "last_count", "packets", "lost", "gaps", "repeats", "stale", "cip_same",
                 "cip_skipped", "run", "transitions", "recent", "ended_at", "ended", "end_reason")

    def __init__(self, api_ns: int, opened_at: int, asked: ForwardOpenAsked | None = None) -> None:
        self.api_ns = max(api_ns, 1)
        self.opened_at = opened_at
        self.asked = asked
        self.counts = [0] * (len(BUCKETS_PERMILLE) + 1)
        self.total_ns = 0
        self._min_ns = _NO_MIN
        self.max_ns = 0
        # each bucket's bound in ns: an interval is in bucket i when interval * 1000 // api <= its bound
        # in thousandths (so one of 2 API, 2000 thousandths, is past the 1999 bucket: the late ones)
        api = self.api_ns
        self._bounds_ns = tuple(-(-(b + 1) * api // 1000) - 1 for b in BUCKETS_PERMILLE)
        self.last_at = 0
        self.first_at: int | None = None
        self.last_sequence: int | None = None
        self.last_count = 0
        self.packets = 0
        self.lost = self.gaps = self.repeats = self.stale = 0
        self.cip_same = self.cip_skipped = 0
        self.run = False
        self.transitions = 0
        self.recent: deque[tuple[int, bool]] = deque(maxlen=RECENT_RUN_IDLE)
        self.ended_at: int | None = None
        self.ended: EndWord | None = None
        self.end_reason = ""

    def o_t(self, at: int, sequence: int, count: int) -> bool:
        """An O->T packet of this connection received at `at` with its 32-bit `sequence` and 16-bit
        sequence `count`: True if it advanced the sequence (a new packet), False for a repeat or a
        stale one (those are counted, not timed). The hot path: what is rare is counted, what is
        common derived (intervals = packets - 1, new counts = intervals - same - skipped)."""
        last = self.last_sequence
        if last is not None:
            delta = (sequence - last) & 0xFFFFFFFF
            if delta != 1:
                if delta == 0:
                    self.repeats += 1
                    return False
                if delta >= _HALF:
                    self.stale += 1
                    return False
                self.lost += delta - 1
                self.gaps += 1
            interval = at - self.last_at
            if interval < 0:
                interval = 0
            self.counts[bisect_left(self._bounds_ns, interval)] += 1
            self.total_ns += interval
            if interval > self.max_ns:
                self.max_ns = interval
            if interval < self._min_ns:
                self._min_ns = interval
            step = (count - self.last_count) & 0xFFFF
            if step != 1:
                if step == 0:
                    self.cip_same += 1
                else:
                    self.cip_skipped += 1
        else:
            self.first_at = at
        self.last_sequence = sequence
        self.last_count = count
        self.last_at = at
        self.packets += 1
        return True

    @property
    def late(self) -> int:
        """Intervals of 2 API or more: those past the 1999 thousandths bucket."""
        return sum(self.counts[_LATE_FROM:])

    @property
    def intervals(self) -> int:
        """Intervals measured: one per new packet after the first."""
        return self.packets - 1 if self.packets else 0

    @property
    def min_ns(self) -> int | None:
        return None if self._min_ns == _NO_MIN else self._min_ns

    @property
    def cip_new(self) -> int:
        return self.intervals - self.cip_same - self.cip_skipped

    def run_idle(self, run: bool, at: int) -> None:
        """The O->T data's mode changed (the run/idle header, or data/no data of a modeless format)."""
        if run != self.run:
            self.run = run
            self.transitions += 1
            self.recent.append((at, run))

    def end(self, at: int, ended: EndWord, reason: str) -> None:
        if self.ended is None:
            self.ended_at, self.ended, self.end_reason = at, ended, reason

    # -- the figures ---------------------------------------------------------------------------------

    def percentile_ns(self, fraction: float) -> int | None:
        """The upper bound of the bucket that holds the `fraction` quantile (nearest rank), clamped to
        the exact min and max; None without intervals."""
        n = self.intervals
        if not n:
            return None
        rank = max(1, -(-round(fraction * 1_000_000) * n // 1_000_000))
        seen = 0
        for index, count in enumerate(self.counts):
            seen += count
            if seen >= rank:
                bound = self.max_ns if index == len(BUCKETS_PERMILLE) else BUCKETS_PERMILLE[index] * self.api_ns // 1000
                return max(self.min_ns or 0, min(bound, self.max_ns))
        return self.max_ns

    def longest_silence_ns(self, now: int) -> int:
        """The longest time without a new packet: the longest interval, or the time from the last
        packet (the Forward Open before the first) to the end, or to `now` while it is open."""
        until = self.ended_at if self.ended_at is not None else now
        since = self.last_at if self.first_at is not None else self.opened_at
        return max(self.max_ns, until - since)

    def interval_figures(self, now: int) -> IntervalFigures:
        n = self.intervals
        return IntervalFigures(
            self.api_ns, n, self.min_ns, self.percentile_ns(0.5), self.percentile_ns(0.99),
            self.max_ns if n else None, self.total_ns // n if n else None, self.late, self.longest_silence_ns(now),
            Histogram(BOUNDS_API, tuple(self.counts)))

    def figures(self, now: int, device: str, originator: str, o_t_id: int, t_o_id: int,
                kind: str) -> ConnectionFigures:
        return ConnectionFigures(
            device, originator, o_t_id, t_o_id, kind, self.opened_at, self.ended_at, self.ended, self.end_reason,
            None if self.first_at is None else self.first_at - self.opened_at, self.asked,
            self.interval_figures(now),
            SequenceFigures(self.packets, self.lost, self.gaps, self.repeats, self.stale, self.last_sequence),
            CipSequenceFigures(self.cip_new, self.cip_same, self.cip_skipped),
            RunIdle(self.run, self.transitions, tuple(self.recent)))


_PRIORITIES = ("low", "high", "scheduled", "urgent")
_TRIGGERS = {0: "cyclic", 1: "change of state", 2: "application object"}


def _type_word(kind: ConnectionType | int) -> str:
    """"point-to-point", "multicast", "null" (the enum's names), "reserved" for 3."""
    return kind.name.lower().replace("_", "-") if isinstance(kind, ConnectionType) else "reserved"


def forward_open_asked(request: ForwardOpenRequest, timeout_ns: int, expected_o_t_rpi_us: int | None = None,
                       expected_t_o_rpi_us: int | None = None) -> ForwardOpenAsked:
    """The Forward Open as the originator asked it (Vol. 1, 3-5.4.1): RPIs, network connection
    parameters, the transport trigger, the electronic key's form and the configuration data (the
    connection path read by cip/connection_path.py)."""
    o_t, t_o = request.o_t_parameters, request.t_o_parameters
    key = None
    segment = electronic_key(request.connection_path)
    if segment is not None:
        wildcard = not (segment.vendor_id or segment.device_type or segment.product_code or segment.major_revision)
        form = "any" if wildcard else "compatible" if segment.compatibility else "exact"
        key = ElectronicKeyAsked(form, segment.vendor_id, segment.device_type, segment.product_code,
                                 segment.major_revision, segment.minor_revision)
    configuration = data_segments(request.connection_path)
    return ForwardOpenAsked(
        request.o_t_rpi, request.t_o_rpi, expected_o_t_rpi_us, expected_t_o_rpi_us, request.timeout_multiplier,
        timeout_ns, _type_word(o_t.connection_type), _type_word(t_o.connection_type),
        _PRIORITIES[o_t.priority & 3], _PRIORITIES[t_o.priority & 3], o_t.size, t_o.size, o_t.variable, t_o.variable,
        request.large, request.transport_class, _TRIGGERS.get(request.production_trigger, "reserved"), key,
        b"".join(configuration) if configuration else None)
