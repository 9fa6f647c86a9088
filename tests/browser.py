"""The dashboard in headless Chromium, shared by tests/test_dashboard_browser.py,
bench/bench_dashboard.py and docs/dashboard_screenshot.py: Debian's chromium driven by Selenium
through Debian's chromedriver (`.ci/run` installs both), the scripts the page runs to time itself,
and a bounded poll of the page.

Timing is taken inside the page (a MutationObserver stamps each LED's class change with
`performance.timeOrigin + performance.now()`, the same wall clock as Python's `time.time()`), so
polling the page does not add to what is measured.
"""

from __future__ import annotations

import shutil
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

CHROMIUM = "/usr/bin/chromium"
CHROMEDRIVER = "/usr/bin/chromedriver"
# Without the background-networking flags a closed network makes Chromium slow (it waits for hosts
# it cannot reach); a fresh profile per session keeps runs apart.
CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync"]
WINDOW = (1400, 1000)
WAIT_S = 30.0  # generous: conditions end the waits as soon as they hold

# Installs the page's own clock on every LED change of the page: `window.seen` holds
# [device, signal, on (1/0), wall-clock ms] per change.
RECORD_CHANGES = """
window.seen = [];
new MutationObserver(records => {
  const now = performance.timeOrigin + performance.now();
  for (const record of records) {
    const element = record.target;
    if (!element.dataset || !element.dataset.signal) continue;
    const card = element.closest('.card');
    window.seen.push([card && card.dataset.device, element.dataset.signal,
                      element.classList.contains('on') ? 1 : 0, now]);
  }
}).observe(document.getElementById('sizer'), {subtree: true, attributes: true, attributeFilter: ['class']});
"""

# The longest gap between animation frames since the page loaded (or `window.frameGaps.max = 0`).
MEASURE_FRAMES = """
window.frameGaps = {max: 0, last: performance.now()};
(function tick(now) {
  window.frameGaps.max = Math.max(window.frameGaps.max, now - window.frameGaps.last);
  window.frameGaps.last = now;
  requestAnimationFrame(tick);
})(performance.now());
"""

# execute_async_script(FILTER_ROUND_TRIP, text): sets the filter, answers two animation frames later
# with the milliseconds taken, the cards in the DOM and the page's device count.
FILTER_ROUND_TRIP = """
const [text, done] = [arguments[0], arguments[arguments.length - 1]];
const started = performance.now();
const input = document.getElementById('filter');
input.value = text;
input.dispatchEvent(new Event('input'));
requestAnimationFrame(() => requestAnimationFrame(() => done({
  ms: performance.now() - started, cards: document.querySelectorAll('.card').length,
  count: document.getElementById('count').textContent})));
"""

# Page.addScriptToEvaluateOnNewDocument(OVERVIEW_COMPLETE % count): `window.overviewComplete` becomes
# the page's time (ms since navigation began) at which the overview first shows `count` tiles, each
# coloured by a state, and counts on top that add up to `count`.
OVERVIEW_COMPLETE = """
window.overviewComplete = null;
new MutationObserver((records, observer) => {
  const tiles = document.getElementById('tiles'), counts = document.querySelectorAll('#counts b');
  if (!tiles || tiles.childElementCount !== %d) return;
  if ([...tiles.children].some(tile => !/\\bs-/.test(tile.className))) return;
  if ([...counts].reduce((sum, b) => sum + (Number(b.textContent) || 0), 0) !== tiles.childElementCount) return;
  window.overviewComplete = performance.now();
  observer.disconnect();
}).observe(document, {subtree: true, childList: true, characterData: true, attributes: true});
"""

# Installs the page's own clock on every change of a tile's class: `window.tileChanges` holds
# [device, class, wall-clock ms] per change.
RECORD_TILES = """
window.tileChanges = [];
new MutationObserver(records => {
  const now = performance.timeOrigin + performance.now();
  for (const record of records) {
    window.tileChanges.push([record.target.dataset.device, record.target.className, now]);
  }
}).observe(document.getElementById('tiles'), {subtree: true, attributes: true, attributeFilter: ['class']});
"""


# execute_async_script(MODULE_CALL, module, body, *args): imports dashboard/<module> and answers what
# `body` (an async function's body over `m`, the module, and `args`) returns, or {error: text}.
MODULE_CALL = """
const [module, body, ...rest] = arguments;
const done = rest.pop();
const run = new Function('m', 'args', `return (async () => { ${body} })();`);
import(new URL('dashboard/' + module, document.baseURI).href)
  .then(m => run(m, rest))
  .then(value => done(value === undefined ? null : value), error => done({error: String(error)}));
"""


def call(driver: Any, module: str, body: str, *args: Any) -> Any:
    """What `body` answers over the dashboard's ES module `module` (MODULE_CALL); an error fails the test."""
    value = driver.execute_async_script(MODULE_CALL, module, body, *args)
    assert not (isinstance(value, dict) and set(value) == {"error"}), value
    return value


def installed() -> bool:
    return Path(CHROMIUM).exists() and Path(CHROMEDRIVER).exists()


@contextmanager
def browser_for_tests() -> Iterator[Any]:
    """`chromium()` for a test: skipped where Debian's chromium is not installed (a failure on CI)."""
    import pytest

    if not installed():
        pytest.skip("needs Debian's chromium and chromium-driver (apt-get install chromium chromium-driver; "
                    ".ci/run installs them)")  # fails on CI (tests/conftest.py)
    with chromium() as driver:
        yield driver


@contextmanager
def chromium(*flags: str, window: tuple[int, int] = WINDOW) -> Iterator[Any]:
    """A headless Chromium session (a Selenium driver) on a fresh profile, its browser log kept;
    quit and its profile removed at exit."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for flag in [*CHROMIUM_FLAGS, f"--window-size={window[0]},{window[1]}", *flags]:
        options.add_argument(flag)
    profile = tempfile.mkdtemp(prefix="enip-farm-chromium-")
    options.add_argument(f"--user-data-dir={profile}")
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    try:
        driver = webdriver.Chrome(options=options, service=Service(CHROMEDRIVER))
        try:
            driver.set_script_timeout(WAIT_S)
            yield driver
        finally:
            driver.quit()
    finally:
        shutil.rmtree(profile, ignore_errors=True)


def until(condition: Callable[[], object], what: str | Callable[[], str], timeout: float = WAIT_S,
          step: float = 0.01) -> Any:
    """Poll `condition` every `step` seconds until it is truthy: its value. AssertionError naming
    `what` once `timeout` seconds have passed."""
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"not within {timeout} s: {what() if callable(what) else what}")
        time.sleep(step)


def open_page(driver: Any, url: str, device: str = "io1") -> float:
    """Load the dashboard until `device`'s card shows its signals and the event stream is live; the
    seconds that took. The last page's browser messages are drained first: they are not this page's."""
    driver.get("about:blank")
    driver.get_log("browser")
    started = time.monotonic()
    driver.get(url)
    until(lambda: driver.execute_script(
        "return document.querySelector(`.card[data-device='${arguments[0]}'] [data-signal]`) !== null"
        " && document.getElementById('stream').textContent === 'live'", device), f"{device}'s card with signals")
    return time.monotonic() - started


def page_errors(driver: Any) -> list[str]:
    """The page's SEVERE console messages since the last call."""
    return [entry["message"] for entry in driver.get_log("browser") if entry["level"] == "SEVERE"]
