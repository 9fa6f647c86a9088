"""Unit tests of the report's arithmetic with injected time (cip/o_t_measure.py, cip/reconnection.py,
cip/verdicts.py, enip_farm/bounds.py): histogram buckets, percentiles, the 32-bit sequence across
its wrap, the 16-bit count, run/idle, how a connection ended, reconnections, verdicts at both sides
of their bounds and "too short to judge". No sockets, no sleeps."""

from __future__ import annotations

import json

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from enip_farm.bounds import BoundsConfig, resolve
from enip_farm.cip.o_t_measure import BUCKETS_PERMILLE, RECENT_RUN_IDLE, OriginatorMeasure, forward_open_asked
from enip_farm.cip.reconnection import KEPT, Reconnections
from enip_farm.cip.report import FAIL, PASS, TOO_SHORT, FarmReport, ReactionFigures
from enip_farm.cip.verdicts import judge_connection, judge_reaction, judge_reconnection, verdict
from enip_farm.config import parse_config
from enip_farm.device import report as device_report_module
from enip_farm.device.report import CellBounds, device_bounds
from enip_farm.protocol.connection import ConnectionType
from enip_farm.protocol.epath import ElectronicKey, encode_electronic_key
from tests.test_connection_table import MS, ORIGINATOR, T0, make_table, o_t, open_owner, request

API = 10 * MS


def measure(api: int = API) -> OriginatorMeasure:
    return OriginatorMeasure(api, T0, forward_open_asked(request(rpi_us=api // 1000), api << 2))


def feed(m: OriginatorMeasure, intervals: list[int], first: int = 1, start: int = T0) -> int:
    """One packet at `start`, then one after each interval, sequence and count +1 each; the last time."""
    at, sequence = start, first
    m.o_t(at, sequence & 0xFFFFFFFF, sequence & 0xFFFF)
    for interval in intervals:
        at += interval
        sequence += 1
        m.o_t(at, sequence & 0xFFFFFFFF, sequence & 0xFFFF)
    return at


# -- the interval histogram ------------------------------------------------------------------------


def test_each_interval_lands_in_the_bucket_of_its_thousandths_of_the_api() -> None:
    m = measure()
    # 1.000 API is the 1000 bucket; 1.0001 API floors to 1000 too; 1.001 goes to 1005; 2 API is past 1999
    feed(m, [API, API + API // 10_000, API + API // 1000, 2 * API - 1, 2 * API, 70 * API])
    counts = dict(zip((*BUCKETS_PERMILLE, "over"), m.counts, strict=True))
    assert counts[1000] == 2 and counts[1005] == 1 and counts[1999] == 1 and counts[2500] == 1
    assert counts["over"] == 1 and sum(m.counts) == 6 == m.intervals
    assert m.late == 2  # 2 API and 70 API; 2 API - 1 ns is not late
    figures = m.interval_figures(T0 + 10**12)
    assert figures.min_ns == API and figures.max_ns == 70 * API
    assert figures.histogram.counts == tuple(m.counts) and len(figures.histogram.bounds_api) == len(BUCKETS_PERMILLE)


def test_percentiles_are_their_buckets_upper_bound_clamped_to_min_and_max() -> None:
    m = measure()
    assert m.percentile_ns(0.5) is None  # no interval yet
    feed(m, [API] * 98 + [API * 3 // 2, 5 * API])  # 100 intervals
    assert m.percentile_ns(0.5) == API  # the 1000 bucket's bound
    assert m.percentile_ns(0.98) == API  # rank 98
    assert m.percentile_ns(0.99) == API * 3 // 2  # rank 99: the 1500 bucket
    assert m.percentile_ns(1.0) == 5 * API  # the 6000 bucket's bound, clamped to the max
    one = measure()
    feed(one, [API * 1021 // 1000])
    assert one.percentile_ns(0.5) == one.percentile_ns(0.99) == API * 1021 // 1000  # clamped to min = max


def test_memory_stays_fixed_whatever_the_originator_sends() -> None:
    m = measure()
    for n in range(5 * RECENT_RUN_IDLE):
        m.run_idle(n % 2 == 0, T0 + n)
    feed(m, [1, 10**15, 0, API] * 500)
    assert len(m.counts) == len(BUCKETS_PERMILLE) + 1 and len(m.recent) == RECENT_RUN_IDLE
    assert m.transitions == 5 * RECENT_RUN_IDLE


def test_longest_silence_counts_the_time_since_the_last_packet() -> None:
    m = measure()
    assert m.longest_silence_ns(T0 + 7 * API) == 7 * API  # nothing since the Forward Open
    last = feed(m, [API, 3 * API])
    assert m.longest_silence_ns(last + API) == 3 * API
    assert m.longest_silence_ns(last + 5 * API) == 5 * API
    m.end(last + 4 * API, "forward close", "forward close")
    assert m.longest_silence_ns(last + 10**12) == 4 * API  # an ended connection's silence ends with it


# -- the sequences ---------------------------------------------------------------------------------


def test_gaps_repeats_and_stale_across_the_32_bit_wrap() -> None:
    m = measure()
    assert m.o_t(T0, 0xFFFFFFFE, 1)
    assert m.o_t(T0 + API, 0xFFFFFFFF, 2)
    assert m.o_t(T0 + 2 * API, 2, 3)  # wraps past 0 and 1: 2 lost in one gap
    assert not m.o_t(T0 + 3 * API, 2, 3)  # a repeat
    assert not m.o_t(T0 + 4 * API, 0xFFFFFFFF, 2)  # older, across the wrap: stale
    assert not m.o_t(T0 + 4 * API, 0x80000002, 9)  # half the space ahead counts as older: stale
    assert m.o_t(T0 + 5 * API, 3, 4)
    s = m.figures(T0, "io1", "127.0.0.9", 1, 2, "exclusive owner").sequence
    assert (s.packets, s.lost, s.gaps, s.repeats, s.stale, s.last) == (4, 2, 1, 1, 2, 3)
    assert m.intervals == 3 and m.max_ns == 3 * API  # repeats and stale ones are not timed


def test_the_16_bit_count_new_same_and_skipped_across_its_wrap() -> None:
    m = measure()
    for n, count in enumerate([0xFFFE, 0xFFFF, 0, 0, 5, 6]):
        m.o_t(T0 + n * API, n + 1, count)
    assert (m.cip_new, m.cip_same, m.cip_skipped) == (3, 1, 1)


def test_run_idle_transitions_with_their_times() -> None:
    table = make_table()
    connection = open_owner(table).connection
    oid = connection.o_t_id
    for n, run in enumerate([False, True, True, False, True]):
        assert table.receive_datagram(o_t(oid, n + 1, run=run), ORIGINATOR.host, T0 + n * MS,
                                      received_at=T0 + n * MS - 7)
    r = connection.measure.figures(T0, "io1", "h", 1, 2, "k").run_idle
    assert r.run and r.transitions == 3
    assert r.recent == ((T0 + MS - 7, True), (T0 + 3 * MS - 7, False), (T0 + 4 * MS - 7, True))


def test_the_table_measures_by_the_kernel_time_and_sees_what_it_drops() -> None:
    table = make_table()
    connection = open_owner(table, rpi_us=10_000).connection
    oid, host = connection.o_t_id, ORIGINATOR.host
    assert table.receive_datagram(o_t(oid, 1), host, T0 + 5 * MS, received_at=T0 + 2 * MS)
    assert table.receive_datagram(o_t(oid, 2), host, T0 + 15 * MS, received_at=T0 + 12 * MS)
    assert not table.receive_datagram(o_t(oid, 2), host, T0 + 16 * MS)  # a repeat: dropped as stale, counted
    assert not table.receive_datagram(o_t(oid, 9), "127.0.0.77", T0 + 17 * MS)  # not the originator: not its packet
    f = connection.measure.figures(T0 + 20 * MS, "io1", host, oid, 0, "exclusive owner")
    assert f.first_o_t_after_ns == 2 * MS and f.intervals.min_ns == f.intervals.max_ns == 10 * MS
    assert (f.sequence.packets, f.sequence.repeats, f.sequence.lost) == (2, 1, 0)
    table.forward_close(connection.triad, T0 + 30 * MS)
    (ended,) = table.ended
    assert ended is connection and connection.measure.ended == "forward close"
    assert connection.measure.ended_at == T0 + 30 * MS


@pytest.mark.parametrize(("how", "word"), [("close", "forward close"), ("timeout", "timeout"),
                                           ("session", "closed"), ("reset", "device reset"),
                                           ("reason text only", "closed")])
def test_how_a_connection_ended(how: str, word: str) -> None:
    """The word comes from the end's class or the typed `ends`, never from the reason's text."""
    table = make_table(first_watchdog_ms=0)
    connection = open_owner(table, rpi_us=10_000).connection
    if how == "close":
        table.forward_close(connection.triad, T0 + MS)
    elif how == "timeout":
        table.handle_timer(T0 + connection.timeout_ns)
    elif how == "session":
        table.close(connection, "its producing connection closed", T0 + MS)
    elif how == "reset":
        table.close(connection, "identity reset (type 0)", T0 + MS, ends="device reset")
    else:
        table.close(connection, "identity reset (type 0)", T0 + MS)
    assert connection.measure.ended == word


def test_measuring_off_keeps_nothing() -> None:
    table = make_table()
    table.measuring = False
    connection = open_owner(table).connection
    assert table.receive_datagram(o_t(connection.o_t_id, 1), ORIGINATOR.host, T0)
    table.forward_close(connection.triad, T0 + MS)
    assert connection.measure is None and not table.ended


# -- the Forward Open as asked ---------------------------------------------------------------------


@pytest.mark.parametrize("route", [b"", bytes.fromhex("01 00")])  # none, or backplane port 1 slot 0
@pytest.mark.parametrize(("key", "form"), [
    (ElectronicKey(75, 7, 1030, 1, 1, False), "exact"), (ElectronicKey(75, 7, 1030, 1, 0, True), "compatible"),
    (ElectronicKey(0, 0, 0, 0, 0, False), "any"), (None, None)])
def test_forward_open_asked_names_the_key_form_and_the_configuration(key, form, route) -> None:
    path = bytes.fromhex("20 04 24 01 2C 64 2C 65") + bytes.fromhex("80 02 AA BB CC DD")
    if key is not None:
        path = encode_electronic_key(key) + path
    asked = forward_open_asked(request(path=route + path, rpi_us=4_000, multiplier=3), 123)
    assert (asked.o_t_rpi_us, asked.timeout_multiplier, asked.timeout_ns, asked.o_t_type, asked.o_t_priority) == (
        4_000, 3, 123, "point-to-point", "scheduled")
    assert asked.configuration_data == bytes.fromhex("AA BB CC DD") and asked.trigger == "cyclic"
    assert (asked.key.form if asked.key else None) == form
    assert json.dumps(asked.as_dict())


@pytest.mark.parametrize(("kind", "word"), [(ConnectionType.POINT_TO_POINT, "point-to-point"),
                                            (ConnectionType.MULTICAST, "multicast"), (ConnectionType.NULL, "null"),
                                            (3, "reserved")])
def test_forward_open_asked_names_the_connection_type(kind, word) -> None:
    asked = forward_open_asked(request(t_o_type=kind), 1)
    assert (asked.o_t_type, asked.t_o_type) == ("point-to-point", word)


def test_forward_open_asked_of_a_path_that_cannot_be_read_has_no_key_and_no_data() -> None:
    asked = forward_open_asked(request(path=bytes.fromhex("34 04 00 00")), 1)  # a key segment cut short
    assert (asked.key, asked.configuration_data) == (None, None)


# -- reconnections ---------------------------------------------------------------------------------


def test_reconnection_after_the_device_came_back_and_after_a_timeout() -> None:
    r = Reconnections()
    r.opened("127.0.0.9", T0 - 1000 * MS, None)
    r.opened("127.0.0.7", T0 - 1000 * MS, None)
    r.left("127.0.0.7")  # it Forward Closed: not expected back
    r.device_back("reset done", T0, set())
    m = measure()
    r.opened("127.0.0.9", T0 + 300 * MS, m)
    m.o_t(T0 + 310 * MS, 1, 1)
    r.timed_out("127.0.0.9", T0 + 1000 * MS)
    r.timed_out("127.0.0.9", T0 + 1100 * MS)  # already waiting: the first timeout counts
    r.opened("127.0.0.8", T0 + 1200 * MS, None)  # another originator: not this one's reconnection
    r.device_back("fault cleared", T0 + 2000 * MS, {"127.0.0.8"})  # .8 still connected: only .9 is expected
    first, pending = r.figures("io1")
    assert (first.originator, first.after, first.forward_open_after_ns, first.first_o_t_after_ns) == (
        "127.0.0.9", "reset done", 300 * MS, 310 * MS)
    assert (pending.originator, pending.after, pending.since_ns, pending.forward_open_ns) == (
        "127.0.0.9", "fault cleared", T0 + 2000 * MS, None)
    r.opened("127.0.0.9", T0 + 2500 * MS, None)
    assert [x.forward_open_after_ns for x in r.figures("io1")] == [300 * MS, 500 * MS]
    for n in range(2 * KEPT):
        r.timed_out(f"127.0.1.{n}", T0)
        r.opened(f"127.0.1.{n}", T0 + n, None)
    assert len(r.figures("io1")) == KEPT
    nobody = Reconnections()
    nobody.device_back("fault cleared", T0, set())  # no originator lost a connection: nobody is expected
    assert nobody.figures("io1") == []


def test_a_table_timeout_waits_for_the_originators_next_forward_open() -> None:
    table = make_table(first_watchdog_ms=0)
    connection = open_owner(table, rpi_us=10_000).connection
    table.handle_timer(T0 + connection.timeout_ns)
    again = open_owner(table, now=T0 + connection.timeout_ns + 250 * MS).connection
    table.receive_datagram(o_t(again.o_t_id, 1), ORIGINATOR.host, T0, received_at=T0 + connection.timeout_ns + 260 * MS)
    (reconnection,) = table.reconnections.figures("io1")
    assert (reconnection.after, reconnection.forward_open_after_ns, reconnection.first_o_t_after_ns) == (
        "timeout", 250 * MS, 260 * MS)


# -- verdicts and bounds ---------------------------------------------------------------------------


def test_a_verdict_passes_at_its_bound_fails_above_and_is_too_short_below_its_needs() -> None:
    assert verdict("x", 1.5, 1.5, "API", 100, 100, "s").verdict == PASS
    assert verdict("x", 1.5001, 1.5, "API", 100, 100, "s").verdict == FAIL
    assert verdict("x", 9, 1.5, "API", 100, 99, "s").verdict == TOO_SHORT
    assert verdict("x", None, 1.5, "API", 0, 5, "s").verdict == TOO_SHORT


def _figures(intervals: list[int], lost: int = 0):
    m = measure()
    feed(m, intervals)
    if lost:
        m.o_t(T0 + 10**9, m.last_sequence + 1 + lost, 0)
    return m.figures(T0 + sum(intervals), "io1", "127.0.0.9", 1, 2, "exclusive owner")


def test_connection_verdicts_with_both_sides_of_each_bound() -> None:
    bounds = resolve()
    passing = judge_connection(_figures([API] * 99 + [API * 3 // 2]), bounds)
    assert {v.figure: v.verdict for v in passing.verdicts} == {
        "interval p99": PASS, "intervals of 2 API or more": PASS, "sequence numbers lost": PASS,
        "sequence numbers repeated": PASS, "stale sequence numbers": PASS, "longest silence": PASS}
    assert passing.verdict == PASS
    failing = judge_connection(_figures([API] * 98 + [API * 1501 // 1000, 2 * API], lost=1), bounds)
    by = {v.figure: v for v in failing.verdicts}
    assert (by["interval p99"].verdict, by["interval p99"].value, by["interval p99"].bound) == (FAIL, 1.75, 1.5)
    assert (by["intervals of 2 API or more"].verdict, by["intervals of 2 API or more"].value) == (FAIL, 1)
    assert (by["sequence numbers lost"].verdict, by["sequence numbers lost"].value) == (FAIL, 1)
    assert "a choice, unverified" in by["interval p99"].source
    short = judge_connection(_figures([API] * 99), bounds)
    assert {v.figure: v.verdict for v in short.verdicts}["interval p99"] == TOO_SHORT  # 99 < 100 intervals
    assert short.verdict == TOO_SHORT
    assert judge_connection(_figures([API] * 5), bounds).verdict == TOO_SHORT  # counts need 10


def test_silence_is_judged_against_the_connection_timeout() -> None:
    m = measure()  # timeout 4 API
    feed(m, [API] * 20)
    ok = judge_connection(m.figures(m.last_at + 4 * API, "io1", "h", 1, 2, "k"), resolve())
    silent = judge_connection(m.figures(m.last_at + 4 * API + 1, "io1", "h", 1, 2, "k"), resolve())
    assert [v.verdict for v in ok.verdicts if v.figure == "longest silence"] == [PASS]
    assert [v.verdict for v in silent.verdicts if v.figure == "longest silence"] == [FAIL]


def test_rpi_against_what_the_device_expects() -> None:
    bounds = resolve(("test", {"expected_o_t_rpi_us": 10_000, "expected_t_o_rpi_us": 20_000}))
    figures = _figures([API] * 20)
    import dataclasses
    figures = dataclasses.replace(figures, forward_open=dataclasses.replace(
        figures.forward_open, expected_o_t_rpi_us=10_000, expected_t_o_rpi_us=20_000))
    rpi = [v for v in judge_connection(figures, bounds).verdicts if "RPI" in v.figure]
    assert [(v.figure, v.verdict, v.value) for v in rpi] == [
        ("O->T RPI asked vs 10000 us expected", PASS, 0), ("T->O RPI asked vs 20000 us expected", FAIL, 10_000)]


def test_bounds_levels_defaults_cell_device_test_with_their_sources() -> None:
    config = parse_config({"bounds": {"interval_p99_api": 1.2, "lost": 3},
                           "devices": [{"name": "io1", "model": "DSQC1030", "address": "127.0.0.1",
                                        "bounds": {"lost": 5, "reaction_p99_ms": 50}},
                                       {"name": "io2", "model": "DSQC1030", "address": "127.0.0.2"}]})
    io1 = device_bounds(config, "io1", {"late_intervals": 2})
    assert (io1["interval_p99_api"], io1["lost"], io1["reaction_p99_ms"], io1["late_intervals"], io1["stale"]) == (
        1.2, 5, 50, 2, 0)
    assert io1.source("interval_p99_api") == "cell configuration"
    assert io1.source("lost") == "device configuration (io1)" and io1.source("late_intervals") == "test"
    assert io1.source("stale").startswith("CIP Vol. 2, 3-2.1")
    assert device_bounds(config, "io2")["lost"] == 3
    with pytest.raises(ValidationError, match="intervals_p99"):
        resolve(("test", {"intervals_p99": 1}))
    with pytest.raises(ValidationError):
        BoundsConfig(lost=-1)


def test_one_report_resolves_the_devices_without_bounds_of_their_own_once(monkeypatch) -> None:
    """device/report.py: a report's bounds cost one resolution for every device without its own
    (was one per device, each searching the configuration's devices: quadratic in devices)."""
    config = parse_config({"bounds": {"lost": 3}, "devices": [
        {"name": "io{n}", "count": 300, "model": "DSQC1030", "address": "127.0.1.1", "netmask": "255.0.0.0"},
        {"name": "own", "model": "DSQC1030", "address": "127.0.9.1", "bounds": {"lost": 5}}]})
    calls = []
    monkeypatch.setattr(device_report_module, "resolve", lambda *levels: calls.append(levels) or resolve(*levels))
    cell = CellBounds(config, {"late_intervals": 2})
    resolved = {device.name: cell.of(device.name) for device in config.devices}
    assert len(calls) == 2  # the devices' shared one, and "own"'s
    assert all(resolved[f"io{n}"] is resolved["io1"] for n in range(1, 301))
    assert [(resolved[name]["lost"], resolved[name]["late_intervals"]) for name in ("io300", "own")] == [(3, 2), (5, 2)]
    assert resolved["own"].source("lost") == "device configuration (own)"
    assert resolved["io7"].source("lost") == "cell configuration" and resolved["io7"].source("late_intervals") == "test"
    reaction = cell.of("io7", {"late_intervals": 7, "lost": 9})  # a reaction's own: over the device's, under the test's
    assert (reaction["lost"], reaction["late_intervals"], len(calls)) == (9, 2, 3)
    assert device_bounds(config, "own", {"lost": 1})["lost"] == 1


def test_reconnection_and_reaction_verdicts() -> None:
    r = Reconnections()
    r.opened("127.0.0.9", T0 - MS, None)
    r.device_back("fault cleared", T0, set())
    r.opened("127.0.0.9", T0 + 10 * 10**9, None)
    r.device_back("reset done", T0 + 20 * 10**9, set())
    done, waiting = r.figures("io1")
    bounds = resolve(("test", {"reconnect_first_o_t_s": 1}))
    now = T0 + 20 * 10**9
    assert [(v.verdict, v.value) for v in judge_reconnection(done, bounds, now)] == [(PASS, 10.0), (FAIL, 20.0)]
    assert [v.verdict for v in judge_reconnection(waiting, bounds, now + 10**9)] == [TOO_SHORT, TOO_SHORT]
    late = [(v.verdict, v.value) for v in judge_reconnection(waiting, bounds, now + 10**9 + 1)]
    assert late == [(TOO_SHORT, None), (FAIL, 1.000000001)]  # waited past the 1 s bound: fails, not yet come
    slow = Reconnections()
    slow.opened("127.0.0.9", T0 - MS, None)
    slow.device_back("fault cleared", T0, set())
    slow.opened("127.0.0.9", T0 + 10 * 10**9 + 1, None)
    assert judge_reconnection(slow.figures("io1")[0], resolve(), T0)[0].verdict == FAIL
    reaction = ReactionFigures("r", "io1.DI3=1", "io1.DO5=1", "o->t", tuple(n * MS for n in range(1, 101)), 0)
    judged = judge_reaction(reaction, resolve(("test", {"reaction_p99_ms": 99, "reaction_max_ms": 100})))
    assert [(v.figure, v.verdict, v.value) for v in judged.verdicts] == [
        ("reaction p99", PASS, 99.0), ("reaction max", PASS, 100.0), ("reactions timed out", PASS, 0)]
    judged = judge_reaction(reaction, resolve(("test", {"reaction_p99_ms": 98.999})))
    assert judged.verdicts[0].verdict == FAIL and judged.percentile(0.5) == 50 * MS
    report = FarmReport(T0, (), (judged,))
    assert report.verdict == FAIL and report.failures == [
        "reaction r: reaction p99 99 ms > bound 98.999 (test)"]
    assert json.loads(json.dumps(report.as_dict()))["reactions"][0]["p99_ns"] == 99 * MS


def test_a_reaction_probe_counts_from_the_stimulus_leaving_to_the_output_arriving() -> None:
    from enip_farm.device.catalogue import shipped_catalogue
    from enip_farm.device.profile import resolve as resolve_profile
    from enip_farm.device.reaction import ReactionProbe
    from enip_farm.device.signals import SignalMap

    config = parse_config({"devices": [{"name": "io1", "model": "DSQC1030", "address": "127.0.0.1"}]})
    signals = SignalMap(resolve_profile(config.devices[0], shipped_catalogue()))
    probe = ReactionProbe((signals, signals.lookup("DI3"), 1), (signals, signals.lookup("DO5"), 1))
    probe.consumed(b"\x10\x00", T0)  # the output before any stimulus left: not a reaction
    probe.produced(b"\x00\x00", T0 + MS)  # a T->O without the stimulus
    probe.flushed(T0 + MS + 10)
    assert probe.stimulus_at is None
    probe.produced(b"\x04\x00", T0 + 2 * MS)  # the first T->O carrying DI3 = 1, produced at the turn's time
    assert probe.stimulus_at == T0 + 2 * MS
    probe.flushed(T0 + 2 * MS + 40)  # ... handed to the kernel 40 ns later
    probe.flushed(T0 + 3 * MS)  # a later turn's flush changes nothing
    probe.produced(b"\x04\x00", T0 + 4 * MS)  # nor a later T->O carrying it
    assert probe.stimulus_at == T0 + 2 * MS + 40 and not probe.done.is_set()
    probe.consumed(b"\x00\x00", T0 + 5 * MS)  # outputs changed, not to the expected value
    probe.consumed(b"\x10\x00", T0 + 7 * MS)
    probe.consumed(b"\x10\x00", T0 + 9 * MS)
    assert probe.done.is_set() and probe.latency_ns == 5 * MS - 40 and probe.via == "o->t"


def test_an_originator_that_closed_is_not_expected_back_one_that_was_reset_is() -> None:
    table = make_table()
    closed = open_owner(table).connection
    table.forward_close(closed.triad, T0 + MS)
    table.device_back("fault cleared", T0 + 2 * MS)
    assert table.reconnections.figures("io1") == []
    reset = open_owner(table, now=T0 + 3 * MS).connection
    table.close(reset, "identity reset (type 0)", T0 + 4 * MS)
    table.device_back("reset done", T0 + 5 * MS)
    (pending,) = table.reconnections.figures("io1")
    assert (pending.originator, pending.after, pending.since_ns) == (ORIGINATOR.host, "reset done", T0 + 5 * MS)


@settings(max_examples=150, deadline=None)
@given(st.lists(st.tuples(st.integers(-10**12, 10**15), st.integers(0, 0xFFFFFFFF), st.integers(0, 0xFFFF)),
                max_size=60), st.integers(1, 10**10))
def test_whatever_an_originator_sends_is_measured_and_adds_up(packets, api) -> None:
    m = OriginatorMeasure(api, T0)
    for at, sequence, count in packets:
        m.o_t(at, sequence, count)
    assert m.packets + m.repeats + m.stale == len(packets)
    assert sum(m.counts) == m.intervals == max(m.packets - 1, 0) and len(m.counts) == len(BUCKETS_PERMILLE) + 1
    assert m.cip_new + m.cip_same + m.cip_skipped == m.intervals and min(m.lost, m.gaps, m.cip_new) >= 0
    figures = judge_connection(m.figures(T0 + 10**15, "io1", "h", 1, 2, "k"), resolve())
    i = figures.intervals
    if i.count:
        assert 0 <= i.min_ns <= i.p50_ns <= i.p99_ns <= i.max_ns <= i.longest_silence_ns
    assert json.dumps(figures.as_dict())


@settings(max_examples=300, deadline=None)
@given(st.integers(0, 10**14), st.integers(1, 10**10))
def test_a_bucket_in_ns_is_the_bucket_in_thousandths_of_the_api(interval, api) -> None:
    from bisect import bisect_left
    m = OriginatorMeasure(api, T0)
    m.o_t(T0, 1, 1)
    m.o_t(T0 + interval, 2, 2)
    assert m.counts.index(1) == bisect_left(BUCKETS_PERMILLE, interval * 1000 // api)
    assert m.late == (1 if interval >= 2 * api else 0)
