"""The dashboard's inspector in a real browser (Debian's chromium through chromedriver, as in
tests/test_dashboard_browser.py): a card's "timeline" button opens a device's inspector: its
signal timeline, which draws the test's stimuli and the controller's explicit writes as steps of
their signals, each marked by who made it, and each class-1 connection's measured O->T intervals
as a histogram (GET /report); and the SVG drawing modules on their own (timeline.js, histogram.js)."""

from __future__ import annotations

import socket
import time
from collections.abc import Iterator

import pytest
from pycomm3 import CIPDriver, Services

from enip_farm.protocol.connection import decode_forward_open_reply, encode_io_packet
from tests.browser import browser_for_tests, call, open_page, page_errors, until
from tests.helpers import RawClient, wait_for
from tests.test_implicit import forward_close, forward_open

pytestmark = pytest.mark.system

MARKS = """return [...document.querySelectorAll('#inspect .mark')].map(m => [m.dataset.by, m.dataset.signals])"""
STEPS = """return document.querySelector(`#inspect .trace[data-signal="${arguments[0]}"] .step`).getAttribute('d')"""


@pytest.fixture(scope="module")
def browser() -> Iterator:
    with browser_for_tests() as driver:
        yield driver


def test_the_timeline_button_shows_stimuli_and_writes_marked(enip_farm, browser) -> None:
    farm = enip_farm(name="io1", model="DSQC1030", http=True)
    io = farm["io1"]
    open_page(browser, f"http://127.0.0.1:{farm.http.port}/", "io1")
    browser.find_element("css selector", ".card[data-device='io1'] button.inspect").click()
    until(lambda: browser.execute_script("return document.querySelectorAll('#inspect .trace').length") == 32,
          "the timeline's 32 rows (16 DI, 16 DO)")
    assert browser.find_element("id", "inspect-name").text == "io1"
    assert browser.execute_script(MARKS) == []
    io.set(DI3=1)
    with CIPDriver(io.address) as plc:
        assert not plc.generic_message(service=Services.set_attribute_single, class_code=4, instance=100,
                                       attribute=3, request_data=b"\x10\x00", connected=False,
                                       route_path=False).error
    until(lambda: browser.execute_script(MARKS) == [["stimulus", "DI3"], ["explicit", "DO5"]],
          lambda: f"two marks, got {browser.execute_script(MARKS)}")
    # each changed signal steps once: a move, one horizontal, one vertical, the run to now
    for name in ("DI3", "DO5"):
        assert browser.execute_script(STEPS, name).count(" V") == 1, name
    assert browser.execute_script(STEPS, "DI1").count(" V") == 0
    browser.find_element("id", "inspect-close").click()
    until(lambda: not browser.execute_script("return document.getElementById('inspect').open"), "closed")
    assert page_errors(browser) == []


STEP_MARKS = """return [...document.querySelectorAll('#inspect .mark.by-scenario')].map(
  m => [m.dataset.step, m.querySelector('title').textContent])"""


def test_a_running_scenarios_steps_are_marks_on_the_timeline(enip_farm, browser, tmp_path) -> None:
    farm = enip_farm(name="io1", model="DSQC1030", http=True)
    open_page(browser, f"http://127.0.0.1:{farm.http.port}/", "io1")
    browser.find_element("css selector", ".card[data-device='io1'] button.inspect").click()
    until(lambda: browser.execute_script("return document.querySelectorAll('#inspect .trace').length") == 32,
          "the timeline's 32 rows (16 DI, 16 DO)")  # recording from now on
    path = tmp_path / "steps.yaml"
    path.write_text("steps:\n  - set: {io1.DI3: 1}\n  - at: 200 ms\n    id: second\n    set: {io1.DI4: 1}\n")
    assert farm.run_scenario(path).status == "passed"
    lines = [event.detail.line for event in farm["io1"].events("scenario step")]
    assert len(lines) == 2 and "set io1.DI3=1" in lines[0] and lines[1].startswith("step 2 (second): ")
    until(lambda: [step for step, _ in browser.execute_script(STEP_MARKS)] == lines,
          lambda: f"a mark per step, got {browser.execute_script(STEP_MARKS)}")
    assert all(title.endswith(f" s: {step}") for step, title in browser.execute_script(STEP_MARKS))
    assert page_errors(browser) == []


HISTOGRAM = """const block = document.querySelector('#inspect .measured');
return block && {head: block.querySelector('.measured-head').textContent,
  counts: [...block.querySelectorAll('.bar')].map(b => Number(b.dataset.count)),
  figures: block.querySelector('.figures').textContent}"""


def test_the_inspector_plots_each_connections_interval_histogram(enip_farm, browser) -> None:
    """A class-1 connection of 30 packets, then closed: its histogram holds the 29 intervals the
    report counted, bucket by bucket, with the figures under it."""
    farm = enip_farm(name="io1", model="DSQC1030", implicit={"first_watchdog_s": 0}, http=True)
    io = farm["io1"]
    with RawClient(io.address) as client:
        client.register()
        message, triad = forward_open(rpi=10_000, multiplier=7)
        opened = decode_forward_open_reply(client.request(message).data)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as udp:
            udp.bind(("127.0.0.1", 0))
            for sequence in range(1, 31):
                udp.sendto(encode_io_packet(opened.o_t_connection_id, sequence, sequence, bytes(6)),
                           (io.address, 2222))
                time.sleep(0.01)
            assert wait_for(lambda: farm.report().devices[0].connections[0].sequence.packets == 30)
        assert client.request(forward_close(triad)).general_status == 0
    intervals = farm.report().as_dict()["devices"][0]["connections"][0]["intervals"]
    open_page(browser, f"http://127.0.0.1:{farm.http.port}/", "io1")
    browser.find_element("css selector", ".card[data-device='io1'] button.inspect").click()
    until(lambda: browser.execute_script(HISTOGRAM), "the connection's histogram")
    shown = browser.execute_script(HISTOGRAM)
    assert shown["counts"] == intervals["histogram"]["counts"] and sum(shown["counts"]) == 29
    assert shown["head"].startswith(f"O->T 0x{opened.o_t_connection_id:08X} from 127.0.0.1 · ")
    assert shown["head"].endswith(" · ended: forward close")
    assert shown["figures"].startswith("API 10 ms · 29 intervals · ")
    assert page_errors(browser) == []


def test_the_drawing_modules(enip_farm, browser) -> None:
    farm = enip_farm(name="io1", model="DSQC1030", http=True)
    open_page(browser, f"http://127.0.0.1:{farm.http.port}/", "io1")
    answer = {"now": 10, "start": 0, "marks": [{"at": 5, "by": "o->t", "signals": ["DO1"]},
                                              {"at": 7, "by": "connection timed out", "signals": ["DO1"]}],
              "signals": [{"name": "DO1", "type": "DO", "role": "output", "values": [[0, 0], [5, 1], [7, 0]]},
                          {"name": "AO1", "type": "AO", "role": "output", "values": [[0, -100], [2, 100]]}]}
    drawn = call(browser, "timeline.js", """
        const svg = m.draw(args[0]);
        return {rows: [...svg.querySelectorAll('.trace')].map(r => r.dataset.signal),
                steps: [...svg.querySelectorAll('.step')].map(p => p.getAttribute('d')),
                marks: [...svg.querySelectorAll('.mark')].map(l => [l.getAttribute('class'), l.getAttribute('x1')]),
                height: svg.getAttribute('height'), width: m.WIDTH, label: m.LABEL};""", answer)
    assert drawn["rows"] == ["DO1", "AO1"]
    scale = (drawn["width"] - drawn["label"] - 4) / 10
    x = [round(drawn["label"] + t * scale, 3) for t in (0, 5, 7, 10)]
    # DO1: low (y 14) to high (y 0) at 5 s, low again at 7 s; AO1's range is its window's -100..100
    assert drawn["steps"][0] == f"M{x[0]:g} 14 H{x[1]:g} V0 H{x[2]:g} V14 H{x[3]:g}"
    assert drawn["steps"][1].endswith(" V17 H" + f"{x[3]:g}")  # 100 at the top of its 34 px row (17 + 0)
    assert drawn["marks"] == [["mark by-o-t", f"{x[1]:g}"], ["mark by-event", f"{x[2]:g}"]]
    assert drawn["height"] == str(14 + 3 + 34 + 3 + 18)
    answer["steps"] = [{"at": 2, "text": "step 1: set io1.DI3=1"}]
    stepped = call(browser, "timeline.js", """
        const svg = m.draw(args[0], new Set(['AO1']));
        return [...svg.querySelectorAll('.mark')].map(l => [l.getAttribute('class'), l.getAttribute('x1'),
          l.getAttribute('y2'), l.dataset.step, l.querySelector('title').textContent]);""", answer)
    x2 = round(drawn["label"] + 2 * scale, 3)  # across every row shown, whatever signals are kept
    assert stepped == [["mark by-scenario", f"{x2:g}", "37", "step 1: set io1.DI3=1",
                        "-8.000 s: step 1: set io1.DI3=1"]]
    intervals = {"api_ns": 10_000_000, "count": 6, "p50_ns": 10_000_000, "p99_ns": 30_000_000, "max_ns": 30_000_000,
                 "late": 1, "longest_silence_ns": 30_000_000,
                 "histogram": {"bounds_api": [0.5, 1, 2, 4], "counts": [0, 5, 0, 1, 0]}}
    bars = call(browser, "histogram.js", """
        const svg = m.draw(args[0]);
        return {bars: [...svg.querySelectorAll('.bar')].map(b => [b.dataset.count, b.getAttribute('class'),
                                                                   Number(b.getAttribute('height'))]),
                labels: [...svg.querySelectorAll('.bucket')].map(t => t.textContent), line: m.figures(args[0])};""",
                intervals)
    assert [(count, cls) for count, cls, _ in bars["bars"]] == [
        ("0", "bar"), ("5", "bar"), ("0", "bar"), ("1", "bar late"), ("0", "bar late")]
    heights = [h for _, _, h in bars["bars"]]
    assert heights[0] == heights[2] == heights[4] == 0 and heights[1] == 5 * heights[3] > 0
    assert bars["labels"] == ["\u22640.5", "\u22641", "\u22642", "\u22644", ">4"]
    assert bars["line"] == ("API 10 ms · 6 intervals · p50 10 ms · p99 30 ms · max 30 ms · \u22652 API: 1 · "
                            "longest silence 30 ms")
    assert page_errors(browser) == []
