"""Each ES module of the dashboard (enip_farm/control/web/*.js) in a real browser, against a real
farm: Debian's chromium driven by Selenium through Debian's chromedriver, as in
tests/test_dashboard_browser.py (which drives the page as a whole). A test imports the module the
page loaded (the same instance: one URL, one module) with a dynamic import, calls what it exports
and looks at the page and the farm.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from typing import Any

import httpx
import pytest

from enip_farm.control.dashboard import WEB
from tests.browser import browser_for_tests, call, open_page, page_errors, until

pytestmark = pytest.mark.system

DEADLINE_S = 30.0  # generous: conditions end the waits as soon as they hold
THREE = {"devices": [{"name": "io1", "model": "DSQC1030"}, {"name": "io2", "model": "DSQC1030"},
                     {"name": "weld1", "model": "DSQC1030", "addons": ["DSQC1032"]}]}

@pytest.fixture(scope="module")
def browser() -> Iterator:
    with browser_for_tests() as driver:
        yield driver


def page(driver: Any, farm: Any, device: str = "io1", suffix: str = "") -> str:
    base = f"http://127.0.0.1:{farm.http.port}/"
    open_page(driver, base + suffix, device)
    return base


def shown_cards(driver: Any) -> list[str]:
    return driver.execute_script("return [...document.querySelectorAll('.card')].map(c => c.dataset.device).sort()")


def test_dom_makes_elements_and_says_on_the_message_line(enip_farm, browser) -> None:
    page(browser, enip_farm(name="io1", model="DSQC1030", http=True))
    assert call(browser, "dom.js", "return m.el('span', 'chip k', 'drop').outerHTML") == \
        '<span class="chip k">drop</span>'
    assert call(browser, "dom.js", "return m.el('li').outerHTML") == "<li></li>"
    assert call(browser, "dom.js", "m.say('io1: drop active', true); const l = m.$('#message');"
                " return [l.textContent, l.className]") == ["io1: drop active", "ok"]
    assert call(browser, "dom.js", "m.say('io1: 404'); return m.$('#message').className") == ""
    slept = call(browser, "dom.js", "const t = performance.now(); await m.sleep(50); return performance.now() - t")
    assert 50 <= slept < 5000  # not before; the upper bound only catches a sleep that never ends
    assert call(browser, "dom.js", "return [0, 1, 2].map(n => m.plural(n, 'device'))") == \
        ["0 devices", "1 device", "2 devices"]
    assert page_errors(browser) == []


def test_frame_runs_each_task_once_a_frame_however_often_asked(enip_farm, browser) -> None:
    page(browser, enip_farm(name="io1", model="DSQC1030", http=True))
    runs = call(browser, "frame.js", """
        const runs = [];
        m.onFrame(() => runs.push('a'));
        m.onFrame(() => runs.push('b'));
        for (let i = 0; i < 5; i++) m.schedule();
        await new Promise(resolve => requestAnimationFrame(() => requestAnimationFrame(resolve)));
        const first = runs.slice();
        await new Promise(resolve => requestAnimationFrame(() => requestAnimationFrame(resolve)));
        return [first, runs.length - first.length];""")
    assert runs == [["a", "b"], 0]  # one frame for five requests, in registration order; none unasked


def test_api_carries_the_token_and_words_the_apis_errors(free_address, browser) -> None:
    from enip_farm.config import parse_config
    from enip_farm.farm.farm import Farm

    config = parse_config({"devices": [{"name": "io1", "address": free_address(), "model": "DSQC1030"}],
                           "discovery": False})
    farm = Farm(config, http=("127.0.0.1", 0), token="s3cret")
    with farm.running_in_thread():
        base = page(browser, farm, "io1", "#token=s3cret")
        assert browser.current_url == base  # the token left the address bar for sessionStorage
        assert browser.execute_script("return sessionStorage.getItem('enip-farm-token')") == "s3cret"
        devices = call(browser, "api.js", "return (await m.api('devices')).map(d => [d.name, d.address])")
        assert devices == [["io1", farm["io1"].address]]
        assert call(browser, "api.js", "return m.devicePath('io 1/x')") == "devices/io%201%2Fx"
        refused = call(browser, "api.js", """
            try { await m.api(m.devicePath('nope')); return 'answered'; }
            catch (e) { return [e instanceof m.ApiError, e.status, e.message]; }""")
        assert refused[:2] == [True, 404] and re.match(r"404 [^;]*'nope'", refused[2]), refused
        bad = call(browser, "api.js", """
            try { await m.api('devices/io1/faults', {method: 'POST', json: {kind: 'delay', delay_ms: -1}}); }
            catch (e) { return [e.status, e.message]; }""")
        assert bad == [422, "422 delay_ms: delay_ms: must be 0..60000 ms, got -1"]
        assert farm["io1"].faults == []
        assert call(browser, "api.js", "return typeof (await m.api('health', {answers: [503]}))") == "object"
    assert [error.rsplit(" ", 3)[-3:] for error in page_errors(browser)] == [  # the browser's own lines
        ["404", "(Not", "Found)"], ["422", "(Unprocessable", "Entity)"]]


def test_events_parses_the_stream_and_follows_it(enip_farm, browser) -> None:
    farm = enip_farm(name="io1", model="DSQC1030", http=True)
    page(browser, farm)
    text = 'event: lost\ndata: {"lost": 3}\n\n: keep-alive\n\ndata: {"kind": "io",\ndata:  "device": "io1"}\n\nevent: x'
    assert call(browser, "events.js", "return m.parseEvents(args[0])", text) == [
        [{"kind": "lost", "data": {"lost": 3}}, {"kind": "message", "data": {"kind": "io", "device": "io1"}}],
        "event: x"]
    assert call(browser, "events.js", "return m.parseEvents('')") == [[], ""]
    call(browser, "events.js", """
        window.followed = {live: 0, events: []};
        m.follow('events?exclude_kind=request&exclude_kind=io', {onLive: () => window.followed.live++,
                 onEvent: (kind, e) => window.followed.events.push([kind, e])});""")
    until(lambda: browser.execute_script("return window.followed.live") == 1, "the second stream live")
    farm["io1"].inject("drop")
    kind, event = until(lambda: next((item for item in browser.execute_script("return window.followed.events")
                                      if item[1]["kind"] == "fault injected"), None), "the fault's event")
    assert kind == "message" and (event["device"], event["detail"]) == ("io1", {"kind": "drop"})
    assert browser.find_element("id", "stream").text == "live"
    assert page_errors(browser) == []


def test_devices_apply_snapshots_and_io_events(enip_farm, browser) -> None:
    farm = enip_farm(THREE, http=True)
    page(browser, farm)
    assert call(browser, "devices.js", "return m.devices.map(d => d.name)") == ["io1", "io2", "weld1"]
    assert call(browser, "devices.js", "return m.byName.get('weld1').signals.map(s => s.type).join()") == \
        ",".join(["DI"] * 16 + ["DO"] * 16 + ["AI"] * 4 + ["AO"] * 4)  # DSQC1030 and its DSQC1032 add-on
    farm["weld1"].set(DI3=1, AI2=-1200)
    until(lambda: call(browser, "devices.js", "const d = m.byName.get('weld1');"
                       " return [d.index.get('DI3').value, d.index.get('AI2').value]") == [1, -1200],
          "the io event applied")
    assert call(browser, "devices.js", "return m.byName.get('io2').faulted") is False
    farm["io2"].inject("stop-io")
    until(lambda: call(browser, "devices.js", "return m.byName.get('io2').faulted"), "faulted by the event")
    until(lambda: call(browser, "devices.js", "const s = m.byName.get('io2').state;"
                       " return s && s.faults.map(f => f.kind).join()") == "stop-io", "the snapshot re-read")
    assert page_errors(browser) == []


def test_table_shows_the_filtered_devices_cards(enip_farm, browser) -> None:
    farm = enip_farm(THREE, http=True)
    page(browser, farm)
    assert shown_cards(browser) == ["io1", "io2", "weld1"]
    assert call(browser, "table.js", "const d = {name: 'weld1', search: 'weld1 dsqc1030 dsqc1032'};"
                " return [m.matches(d, ['weld', '1032']), m.matches(d, ['=weld']), m.matches(d, ['=weld1'])]") == \
        [True, False, True]
    call(browser, "table.js", "m.showDevice('io2')")
    until(lambda: shown_cards(browser) == ["io2"], "io2's card alone")
    assert browser.find_element("id", "filter").get_attribute("value") == "=io2"
    assert browser.find_element("id", "count").text == "1 of 3 devices"
    call(browser, "table.js", "m.showDevice('io', false)")
    until(lambda: shown_cards(browser) == ["io1", "io2"], "the io devices")
    assert call(browser, "table.js", "return m.filterWords()") == ["io"]
    farm["weld1"].inject("drop")
    call(browser, "table.js", "document.getElementById('filter').value = '';"
         " document.getElementById('show').value = 'faulted'; m.refilter()")
    until(lambda: shown_cards(browser) == ["weld1"], "only the faulted device")
    assert "faulted" in browser.find_element("css selector", ".card[data-device='weld1']").get_attribute("class")
    assert page_errors(browser) == []


def test_io_panel_draws_the_signals_and_writes_inputs(enip_farm, browser) -> None:
    farm = enip_farm(name="io1", model="DSQC1030", http=True)
    io1 = farm["io1"]
    page(browser, farm)
    groups = browser.execute_script(
        "return [...document.querySelectorAll(\".card[data-device='io1'] .io .group\")]"
        ".map(g => [g.querySelector('.label').textContent, g.querySelectorAll('[data-signal]').length])")
    assert groups == [["DI", 16], ["DO", 16]]
    assert call(browser, "io-panel.js", "return [m.format(1.23456), m.format(2), m.format(-1200), m.format(0.5)]") == \
        ["1.235", "2", "-1200", "0.5"]
    call(browser, "io-panel.js", "await m.write({name: 'io1'}, {DI2: 1, DI16: 1})")
    assert io1.get("DI1-16") == [0, 1] + [0] * 13 + [1]
    until(lambda: "on" in browser.find_element("css selector", ".card[data-device='io1'] [data-signal='DI16']")
          .get_attribute("class").split(), "the DI16 LED on")
    browser.find_element("css selector", ".card[data-device='io1'] [data-signal='DI16']").click()
    io1.wait_for(lambda d: d.get("DI16") == 0, timeout=DEADLINE_S)
    browser.find_element("css selector", ".card[data-device='io1'] [data-signal='DO1']").click()  # the controller's
    call(browser, "io-panel.js", "await m.write({name: 'io1'}, {DI3: 2})")
    assert browser.find_element("id", "message").text == "io1: 422 DI3: a digital signal is 0 or 1, got 2"
    assert io1.inputs == b"\x02\x00" and io1.outputs == b"\x00\x00"
    assert [error.split(" - ")[0].rsplit("/", 3)[-3:] for error in page_errors(browser)] == [["devices", "io1", "io"]]


def test_faults_panel_offers_the_farms_kinds_and_injects_and_clears(enip_farm, browser) -> None:
    farm = enip_farm(name="io1", model="DSQC1030", http=True, reset_time_s=0.5)
    io1 = farm["io1"]
    base = page(browser, farm)
    kinds = httpx.get(base + "fault-kinds", timeout=DEADLINE_S).json()
    card = ".card[data-device='io1']"
    options = browser.execute_script(f"return [...document.querySelectorAll(\"{card} .fault-kind option\")]"
                                     ".map(o => [o.textContent, o.title])")
    assert options == [[kind["kind"], kind["summary"]] for kind in kinds]
    hints = call(browser, "faults-panel.js", "return ['delay', 'status', 'drop', 'sideways'].map(m.parameterNames)")
    assert hints == [["delay_ms", "max_delay_ms"], ["service", "status"], [], []]
    requests = call(browser, "faults-panel.js", "return [m.faultRequest('status', ' 0x0E, 0x08 ', '5'),"
                    " m.faultRequest('delay', '200 900', ''), m.faultRequest('drop', '1 2', ''),"
                    " m.faultRequest('delay', '', '')]")
    assert requests == [{"kind": "status", "service": 14, "status": 8, "duration_s": 5},
                        {"kind": "delay", "delay_ms": 200, "max_delay_ms": 900}, {"kind": "drop"}, {"kind": "delay"}]
    from selenium.webdriver.support.ui import Select

    Select(browser.find_element("css selector", f"{card} .fault-kind")).select_by_visible_text("delay")
    param = browser.find_element("css selector", f"{card} .fault-param")
    assert param.get_attribute("placeholder") == "delay_ms max_delay_ms"
    param.send_keys("800")
    browser.find_element("css selector", f"{card} .fault-duration").send_keys("30")
    browser.find_element("css selector", f"{card} button.inject").click()
    until(lambda: io1.faults, "the fault injected")
    assert [{k: v for k, v in fault.items() if k != "age_s"} for fault in io1.faults] == [
        {"kind": "delay", "delay_ms": 800.0, "duration_s": 30.0}]
    chip = until(lambda: browser.find_elements("css selector", f"{card} .chip"), "the fault's chip")[0]
    assert chip.text == "delay (delay_ms 800, duration_s 30)×"
    assert browser.find_element("id", "message").text == "io1: delay active"
    chip.find_element("css selector", "button.clear").click()
    until(lambda: not io1.faults, "the fault cleared")
    until(lambda: not browser.find_elements("css selector", f"{card} .chip"), "the chip gone")
    browser.find_element("css selector", f"{card} button.power-cycle").click()
    until(lambda: browser.find_element("id", "message").text == "io1: power cycled, answering again in 0.5 s",
          "the power cycle said")
    assert page_errors(browser) == []


# Each control of each shown card: [device, its class, inside its card (the card clips: overflow
# hidden), the topmost element at its centre is the control itself].
CONTROLS_REACHABLE = """
return [...document.querySelectorAll('.card')].flatMap(card => {
  const box = card.getBoundingClientRect();
  return [...card.querySelectorAll('button, input, select')].map(control => {
    const r = control.getBoundingClientRect();
    const inside = r.width > 0 && r.height > 0 && r.left >= box.left && r.right <= box.right
      && r.top >= box.top && r.bottom <= box.bottom;
    const top = document.elementFromPoint(r.left + r.width / 2, r.top + r.height / 2);
    return [card.dataset.device, control.className, inside, !!top && control.contains(top)];
  });
});
"""


def test_every_cards_controls_lie_inside_the_card(enip_farm, browser) -> None:
    """The fault form wraps rather than pushing inject and power cycle out of the card, whatever the
    longest fault kind's name (the select is as wide as it), on each model's card."""
    farm = enip_farm({"devices": [{"name": "weld1", "model": "DSQC1030", "addons": ["DSQC1031", "DSQC1032"]},
                                  {"name": "safety1", "model": "DSQC1042"}]}, http=True)  # one row, in view
    base = page(browser, farm, "weld1")
    until(lambda: shown_cards(browser) == ["safety1", "weld1"], "the two cards")
    until(lambda: browser.execute_script("return document.querySelectorAll('.card .fault-kind option').length")
          == 2 * len(httpx.get(base + "fault-kinds", timeout=DEADLINE_S).json()), "the kinds offered")
    controls = browser.execute_script(CONTROLS_REACHABLE)
    assert sorted({kind for _, kind, _, _ in controls}) == [
        "fault-duration", "fault-kind", "fault-param", "inject", "inspect", "power-cycle"]
    assert [control for control in controls if not (control[2] and control[3])] == []


def test_event_log_shows_the_events_and_filters_by_a_click(enip_farm, browser) -> None:
    farm = enip_farm(THREE, http=True)
    page(browser, farm)
    assert call(browser, "event-log.js", "return [m.detailText({kind: 'delay', delay_ms: 250}), m.detailText(null),"
                " m.detailText('input DI2 0 -> 1')]") == ["kind=delay delay_ms=250", "", "input DI2 0 -> 1"]
    assert call(browser, "event-log.js", "return m.clock(0.25).endsWith('.250')") is True

    def logged() -> list[str]:
        return browser.execute_script("return [...document.querySelectorAll('#log li')].map(li => li.textContent)")

    farm["io2"].inject("drop")
    line = until(lambda: next((text for text in logged() if "fault injected" in text), None), "the fault's line")
    assert line.endswith(" io2 fault injected kind=drop"), line
    browser.find_element("id", "log-pause").click()
    before = len(logged())
    farm["io2"].clear_faults()
    until(lambda: call(browser, "devices.js", "return m.byName.get('io2').faulted") is False, "the clear seen")
    assert len(logged()) == before  # paused: nothing drawn
    browser.find_element("id", "log-pause").click()
    browser.find_element("css selector", "#log li span.d[data-device='io2']").click()
    until(lambda: shown_cards(browser) == ["io2"], "the cards filtered to io2")
    assert browser.find_element("id", "filter").get_attribute("value") == "io2"
    assert page_errors(browser) == []


def test_overview_colours_the_tiles_and_opens_a_card(enip_farm, browser) -> None:
    farm = enip_farm(THREE, http=True)
    page(browser, farm)
    until(lambda: browser.execute_script("return document.body.dataset.overview") == "complete", "the overview")

    def tiles() -> dict[str, str]:
        return dict(browser.execute_script(
            "return [...document.querySelectorAll('#tiles [data-device]')].map(t => [t.dataset.device,"
            " t.className.split(' ').find(c => c.startsWith('s-'))])"))

    assert tiles() == {"io1": "s-idle", "io2": "s-idle", "weld1": "s-idle"}
    call(browser, "overview.js", "m.onEvent({kind: 'fault injected', device: 'io1', detail: {kind: 'drop'}})")
    until(lambda: tiles()["io1"] == "s-faulted", "the event's guess")
    until(lambda: tiles()["io1"] == "s-idle", "the read after it: no fault on the farm")
    farm["weld1"].inject("offline")
    until(lambda: tiles()["weld1"] == "s-faulted", "weld1 faulted")
    counts = browser.execute_script("return [...document.querySelectorAll('#counts [data-state]')]"
                                    ".map(b => [b.dataset.state, b.querySelector('b').textContent])")
    assert counts == [["idle", "2"], ["running", "0"], ["timed_out", "0"], ["faulted", "1"]]
    browser.find_element("css selector", "#tiles [data-device='io2']").click()
    until(lambda: shown_cards(browser) == ["io2"], "io2's card")
    assert page_errors(browser) == []


def test_the_entry_module_loads_every_module_and_starts_the_page(enip_farm, browser) -> None:
    page(browser, enip_farm(name="io1", model="DSQC1030", http=True))
    assert browser.execute_script("return document.body.dataset.ready") == "true"
    loaded = browser.execute_script("return performance.getEntriesByType('resource')"
                                    ".map(e => new URL(e.name).pathname).filter(p => p.endsWith('.js')).sort()")
    assert loaded == sorted(f"/dashboard/{path.name}" for path in WEB.glob("*.js"))
    assert browser.execute_script("return typeof window.enipFarm") == "undefined"  # no globals between scripts
    assert page_errors(browser) == []
