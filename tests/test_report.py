"""The report on the controller under test (`Farm.report()`, `Farm.reaction()`) against real
originators on loopback: the `ethernetip` scanner from PyPI, a raw UDP originator whose send times
bound the kernel's receive times, pycomm3 as a test agent writing outputs explicitly."""

from __future__ import annotations

import json
import socket
import threading
import time

import pytest
from pycomm3 import CIPDriver, Services

from enip_farm.protocol.connection import decode_forward_open_reply, encode_io_packet
from tests.helpers import RawClient, wait_for
from tests.scanners import scanner, start_scanner
from tests.test_implicit import forward_close, forward_open

pytestmark = [pytest.mark.integration, pytest.mark.class1_paths]  # both class-1 paths
MS = 1_000_000


@pytest.fixture
def farm(make_farm):
    return make_farm({"name": "io1", "model": "DSQC1030", "implicit": {"first_watchdog_s": 0}})


def _connection(farm, index: int = 0) -> dict:
    return farm.report().as_dict()["devices"][0]["connections"][index]


def test_the_ethernetip_scanner_measured_packet_by_packet(farm) -> None:
    device = farm.device("io1")
    with scanner(device.profile.address) as scan:
        assert scan.forward_open(10, 2) == 0
        scan.outputs[4] = True
        scan.conn.produce()
        assert wait_for(lambda: device.counters["o_t_packets"] >= 60)
        scan.conn.stopProduce()
        packets = device.counters["o_t_packets"]
        assert wait_for(lambda: _connection(farm)["sequence"]["packets"] == device.counters["o_t_packets"], 2)
        assert scan.forward_close() == 0
    report = farm.report()
    c = json.loads(json.dumps(report.as_dict()))["devices"][0]["connections"][0]
    packets = device.counters["o_t_packets"]
    assert c["ended"] == "forward close" and c["originator"] == "127.0.0.1" and c["kind"] == "exclusive owner"
    assert c["sequence"] == {"packets": packets, "lost": 0, "gaps": 0, "repeats": 0, "stale": 0,
                             "last": c["sequence"]["last"]}
    intervals = c["intervals"]
    assert intervals["count"] == packets - 1 == sum(intervals["histogram"]["counts"])
    assert intervals["api_ns"] == 10 * MS
    assert 0 <= intervals["min_ns"] <= intervals["p50_ns"] <= intervals["p99_ns"] <= intervals["max_ns"]
    assert c["cip_sequence"]["new"] + c["cip_sequence"]["same"] + c["cip_sequence"]["skipped"] == packets - 1
    assert c["run_idle"]["run"] is True and c["run_idle"]["transitions"] == 1  # idle at the open, run from the first
    fo = c["forward_open"]
    assert (fo["o_t_rpi_us"], fo["t_o_rpi_us"], fo["timeout_multiplier"], fo["timeout_ns"]) == (
        10_000, 10_000, 2, 160 * MS)
    assert (fo["o_t_type"], fo["t_o_type"], fo["transport_class"], fo["trigger"]) == (
        "point-to-point", "point-to-point", 1, "cyclic")
    assert 0 <= c["first_o_t_after_ns"] < c["ended_at_ns"] - c["opened_at_ns"]
    assert {v["figure"] for v in c["verdicts"]} >= {"interval p99", "sequence numbers lost", "longest silence"}
    assert {v["figure"]: v["verdict"] for v in c["verdicts"]}["sequence numbers lost"] == "pass"


def test_intervals_are_the_kernels_receive_times_not_the_farms(farm) -> None:
    """The I/O thread is held up (the device lock taken) while the second packet waits in its socket:
    the measured interval is still the one between the two sends, bounded by their send calls."""
    device = farm.device("io1")
    with RawClient(device.profile.address) as client:
        client.register()
        message, triad = forward_open(rpi=20_000)
        opened = decode_forward_open_reply(client.request(message).data)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as udp:
            udp.bind(("127.0.0.1", 0))
            target = (device.profile.address, 2222)
            oid = opened.o_t_connection_id
            payload = b"\x01\x00\x00\x00\x00\x00"
            udp.sendto(encode_io_packet(oid, 1, 1, payload), target)
            assert wait_for(lambda: device.counters["o_t_packets"] == 1)
            with device.guard.lock:  # the I/O thread takes packet 2 only once this is released
                before2 = time.monotonic_ns()
                udp.sendto(encode_io_packet(oid, 2, 2, payload), target)
                after2 = time.monotonic_ns()
                time.sleep(0.03)
                before3 = time.monotonic_ns()
                udp.sendto(encode_io_packet(oid, 3, 3, payload), target)
                after3 = time.monotonic_ns()
                time.sleep(0.05)
            assert wait_for(lambda: device.counters["o_t_packets"] == 3)
        assert client.request(forward_close(triad)).general_status == 0
    intervals = _connection(farm)["intervals"]
    assert intervals["count"] == 2
    # the time between the two sends, not between the thread's takes (packet 3 is taken after the
    # lock is released, 50 ms after its send: later than after3 - before2 allows)
    assert before3 - after2 <= intervals["max_ns"] <= after3 - before2


def test_sequence_figures_from_a_raw_originator_with_exact_counts(farm) -> None:
    device = farm.device("io1")
    with RawClient(device.profile.address) as client:
        client.register()
        message, triad = forward_open(rpi=20_000)
        opened = decode_forward_open_reply(client.request(message).data)
        oid = opened.o_t_connection_id
        run, idle = b"\x01\x00\x00\x00\x00\x00", b"\x00\x00\x00\x00\x00\x00"
        # sequence, 16-bit count, run: across the wrap 3 lost (0, 1, 2), then 2 (5, 6), a repeat of 7, a
        # stale 4, an idle and back to run
        sent = [(0xFFFFFFFE, 0xFFFF, run), (0xFFFFFFFF, 0, run), (3, 1, run), (4, 1, idle), (7, 3, run),
                (7, 3, run), (4, 1, run), (8, 4, run)]
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as udp:
            udp.bind(("127.0.0.1", 0))
            for n, (sequence, count, data) in enumerate(sent, 1):
                udp.sendto(encode_io_packet(oid, sequence, count, data), (device.profile.address, 2222))
                assert wait_for(lambda n=n: device.counters["o_t_packets"] + device.counters["o_t_dropped_stale"] == n)
        assert client.request(forward_close(triad)).general_status == 0
    c = _connection(farm)
    assert c["sequence"] == {"packets": 6, "lost": 5, "gaps": 2, "repeats": 1, "stale": 1, "last": 8}
    assert c["cip_sequence"] == {"new": 3, "same": 1, "skipped": 1}
    assert [r["run"] for r in c["run_idle"]["recent"]] == [True, False, True] and c["run_idle"]["transitions"] == 3
    verdicts = {v["figure"]: v for v in c["verdicts"]}
    assert verdicts["sequence numbers lost"]["verdict"] == "too short to judge"  # 5 intervals < 10


def _controller(scanner_inputs, scanner_outputs, conn, stop: threading.Event) -> None:
    """A controller's program: DO5 follows DI3, looked at every millisecond."""
    while not stop.is_set():
        value = bool(scanner_inputs[2])
        if scanner_outputs[4] != value:
            scanner_outputs[4] = value
        time.sleep(0.001)


def test_reaction_time_of_a_scanner_program_and_the_report_judges_it(farm) -> None:
    device = farm.device("io1")
    scan = start_scanner(device.profile.address)
    stop = threading.Event()
    program = threading.Thread(target=_controller, args=(scan.inputs, scan.outputs, scan.conn, stop), daemon=True)
    try:
        assert scan.forward_open(10, 4) == 0
        scan.conn.produce()
        program.start()
        started = time.monotonic_ns()
        reaction = farm.reaction(set=("io1", "DI3", 1), expect=("io1", "DO5", 1), timeout=2, repeat=5,
                                 bounds={"reaction_max_ms": 2000})
        elapsed = time.monotonic_ns() - started
    finally:
        stop.set()
        program.join(5)
        scan.stop()
    assert reaction.count == 5 and reaction.timeouts == 0 and reaction.via == "o->t"
    assert all(0 < sample <= elapsed for sample in reaction.samples_ns)
    assert [v.verdict for v in reaction.verdicts] == ["pass", "pass"]  # max 2000 ms, no timeout
    assert reaction.stimulus == "io1.DI3=1" and reaction.expect == "io1.DO5=1"
    (reported,) = farm.report(bounds={"reaction_max_ms": 0.001}).as_dict()["reactions"]
    assert reported["count"] == 5 and reported["verdict"] == "fail"  # the report's bound over the reaction's


def test_reaction_time_of_a_test_agents_explicit_writes(farm) -> None:
    device = farm.device("io1")
    stop = threading.Event()

    def agent() -> None:  # reads the inputs (assembly 101) and writes the outputs (assembly 100) explicitly
        with CIPDriver(device.profile.address) as driver:
            while not stop.is_set():
                inputs = driver.generic_message(service=Services.get_attribute_single, class_code=4, instance=101,
                                                attribute=3).value
                wanted = b"\x10\x00" if inputs and inputs[0] & 0x04 else b"\x00\x00"
                if device.outputs != wanted:
                    driver.generic_message(service=Services.set_attribute_single, class_code=4, instance=100,
                                           attribute=3, request_data=wanted)
                time.sleep(0.002)

    thread = threading.Thread(target=agent, daemon=True)
    thread.start()
    try:
        reaction = farm.reaction(set=("io1", "DI3", 1), expect=("io1", "DO5", 1), timeout=3, repeat=3)
    finally:
        stop.set()
        thread.join(10)
    assert reaction.count == 3 and reaction.timeouts == 0 and reaction.via == "explicit"
    assert all(0 < sample < 3_000 * MS for sample in reaction.samples_ns)


def test_a_reaction_that_never_comes_times_out(farm) -> None:
    started = time.monotonic()
    reaction = farm.reaction(set=("io1", "DI3", 1), expect=("io1", "DO5", 1), timeout=0.2, repeat=2)
    assert 0.4 <= time.monotonic() - started < 5
    assert reaction.count == 0 and reaction.timeouts == 2
    assert [(v.figure, v.verdict, v.value) for v in reaction.verdicts] == [("reactions timed out", "fail", 2)]
    with pytest.raises(ValueError, match="an input the test sets"):
        farm.reaction(set=("io1", "DO5", 1), expect=("io1", "DO5", 1))


def test_reconnection_after_a_fault_cleared_and_the_end_it_had(farm) -> None:
    device = farm.device("io1")
    with scanner(device.profile.address) as scan:
        assert scan.forward_open(10, 0) == 0
        scan.conn.produce()
        assert wait_for(lambda: device.counters["o_t_packets"] >= 5)
        farm["io1"].inject("stop-io")
        assert wait_for(lambda: not device.connections)  # timed out while the device stopped its I/O
        before_clear = time.monotonic_ns()
        farm["io1"].clear_faults()
        after_clear = time.monotonic_ns()
        time.sleep(0.05)
        before_open = time.monotonic_ns()
        assert scan.forward_open(10, 0) == 0
        after_open = time.monotonic_ns()
        assert wait_for(lambda: farm.report().devices[0].reconnections[0].first_o_t_ns is not None)
        scan.forward_close()
    device_report = farm.report().devices[0]
    (reconnection,) = device_report.reconnections
    assert (reconnection.after, reconnection.originator) == ("fault cleared", "127.0.0.1")
    assert before_open - after_clear <= reconnection.forward_open_after_ns <= after_open - before_clear
    assert reconnection.first_o_t_after_ns >= reconnection.forward_open_after_ns
    assert device_report.connections[0].ended == "device fault"
    assert device_report.connections[0].end_reason.startswith("no packet for")
    assert [v.verdict for v in device_report.verdicts] == ["pass"]  # within 10 s
