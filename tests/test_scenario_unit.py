"""Issue 28, item 3: a scenario parsed and checked before anything runs (every defect one line,
`file:line: reason`), and its scheduler held to the tick with the time given."""

from __future__ import annotations

import textwrap

import pytest

from enip_farm.cip.report import Reconnection
from enip_farm.config import parse_config
from enip_farm.device.build import build_profiles
from enip_farm.device.catalogue import shipped_catalogue
from enip_farm.device.signals import SignalMap
from enip_farm.scenario.model import (
    ClearAction,
    Expectation,
    FaultAction,
    NoTimeouts,
    Reconnected,
    Scenario,
    SetAction,
    WaitAction,
)
from enip_farm.scenario.parse import ScenarioError, duration_ns, parse_scenario, signal_check
from enip_farm.scenario.schedule import Schedule, StepState
from enip_farm.scenario.verdict import Recording, judge

CONFIG = parse_config({"devices": [{"name": "io1", "address": "127.0.50.1", "model": "DSQC1030"},
                                   {"name": "r2-io{n}", "count": 2, "address": "127.0.50.11", "model": "DSQC1030"}],
                       "groups": [{"name": "rack2", "members": ["r2-*"]}]})
CHECK = signal_check({p.name: SignalMap(p) for p in build_profiles(CONFIG, shipped_catalogue())})
MS = 1_000_000


def parse(text: str):
    return parse_scenario(textwrap.dedent(text), "s.yaml", CONFIG, CHECK)


GOOD = """\
    name: switch of rack 2
    duration: 5 s
    steps:
      - at: 2 s
        id: loss
        fault: link-down
        target: rack2
        duration: 4 s
      - after: loss
        delay: 100 ms
        set: {io1.DI3: 1}
      - wait: io1.DO5 == 0
        timeout: 1.5
      - clear: rack2
        kind: link-down
    expect:
      - io1.DO5 == 0 within 100 ms of step 1
      - rack2 reconnected within 3 s of end of step loss
      - no connection timed out outside rack2
      - count(connection timed out, rack2) == 2
"""


def test_a_scenario_is_parsed_into_steps_and_expectations() -> None:
    scenario = parse(GOOD)
    assert scenario.name == "switch of rack 2" and scenario.duration_ns == 5_000 * MS
    one, two, three, four = scenario.steps
    assert (one.at_ns, one.after, one.name, one.line) == (2_000 * MS, None, "loss", 4)
    assert one.action == FaultAction("rack2", "link-down", 4_000 * MS, {})
    assert (two.after, two.delay_ns, two.action) == (1, 100 * MS, SetAction((("io1", "DI3", 1),)))
    assert (three.after, three.action.timeout_ns) == (2, 1_500 * MS) and isinstance(three.action, WaitAction)
    assert four.action == ClearAction("rack2", "link-down")
    within, reconnected, quiet, count = (e.check for e in scenario.expectations)
    assert (within.step, within.bound_ns, within.end, str(within.condition)) == (1, 100 * MS, False, "io1.DO5 == 0")
    assert (reconnected.devices, reconnected.step, reconnected.end) == (("r2-io1", "r2-io2"), 1, True)
    assert quiet == NoTimeouts(("io1",))
    assert (count.kind, count.devices, count.op, count.count) == ("connection timed out", ("r2-io1", "r2-io2"),
                                                                  "==", 2)
    assert [e.line for e in scenario.expectations] == [17, 18, 19, 20]


def test_every_defect_is_one_line_naming_the_file_and_line() -> None:
    with pytest.raises(ScenarioError) as caught:
        parse("""\
            steps:
              - at: 1 s
                fault: power-cut
                target: rack2
              - fault: link-down
                target: rack9
              - after: 9
                set: {io1.DI99: 1, io9.DI1: 1}
              - wait: io1.DO5 = 0
              - at: soon
                clear: io1
              - after: 6
                fault: power-loss
                target: io1
                params: {boot_time_s: -1}
              - after: 6
                id: 6
                wait: io1.DO5 == 1
              - fault: stop-io
                target: io1
                at: 1 s
                after: 1
            expect:
              - io1.DO5 == 0 within 100 ms of step 12
              - rack3 reconnected within 3 s of step 1
              - io1.DO5 is low
              - count(connection timed out, rack7) == 2
            """)
    assert caught.value.problems == [
        "s.yaml:2: step 1: fault power-cut: kind: 'power-cut' is not one of delay, drop, close, reset, offline, "
        "status, stop-io, identity, power-loss, link-down, flapping-link, degraded-link, address-conflict, "
        "wrong-module, safety-crc, safety-stale, safety-time-coordination",
        "s.yaml:5: step 2: target: 'rack9' is neither a device nor a group of the cell (groups: rack2)",
        "s.yaml:7: step 3: after: no step '9' (steps 1..8, or 6)",
        "s.yaml:7: step 3: set io1.DI99: device 'io1': DI99: this device has 16 DI signals",
        "s.yaml:7: step 3: set io9.DI1: no device 'io9' in the cell",
        "s.yaml:9: step 4: wait: 'io1.DO5 = 0' is not a condition (DEVICE.SIGNAL OP NUMBER, OP one of == != <= >= "
        "< >)",
        "s.yaml:10: step 5: at: 'soon' is not a duration (100 ms, 2 s, 1.5, 1 min)",
        "s.yaml:12: step 6: waits for itself (after: 6)",  # a number is a step's number before an id
        "s.yaml:12: step 6: fault power-loss: boot_time_s: must be 0..3600 s, got -1",
        "s.yaml:16: id '6': a number names a step already",
        "s.yaml:19: step 8: at and after both given: one or the other",
        "s.yaml:24: of step: no step '12' (steps 1..8, or 6)",
        "s.yaml:25: reconnected: 'rack3' is neither a device nor a group of the cell (groups: rack2)",
        "s.yaml:26: 'io1.DO5 is low' is not an expectation (CONDITION within T of step S; TARGET reconnected "
        "within T of step S; no connection timed out [in|outside TARGET]; count(KIND[, TARGET]) OP N)",
        "s.yaml:27: count: 'rack7' is neither a device nor a group of the cell (groups: rack2)",
    ]
    assert str(caught.value).splitlines() == caught.value.problems


def test_steps_that_can_never_happen_are_refused() -> None:
    with pytest.raises(ScenarioError) as caught:
        parse("""\
            steps:
              - after: 2
                fault: link-down
                target: io1
              - after: 1
                clear: io1
                kind: power-loss
              - {}
            """)
    assert caught.value.problems == [
        "s.yaml:2: step 1 can never happen: steps 1, 2 wait for each other",
        "s.yaml:5: step 2 can never happen: steps 2, 1 wait for each other",
        "s.yaml:5: step 2: clears power-loss on io1, which no step sets",
        "s.yaml:8: step 3: one action of fault, clear, set, wait, got none",
    ]
    with pytest.raises(ScenarioError, match=r"^s.yaml:3: step 2: clears power-loss on io1, which no step sets$"):
        parse("""\
            steps:
              - {fault: link-down, target: io1}
              - {clear: io1, kind: power-loss}
            """)
    with pytest.raises(ScenarioError, match=r"^s.yaml:2:1: not valid YAML: while parsing a flow node: expected the "
                                            r"node content, but found '<stream end>'$"):  # its line and column
        parse("steps: [\n")
    with pytest.raises(ScenarioError, match=r"^s.yaml:1: steps: a list of at least one step is needed$"):
        parse("name: x\n")


def test_the_files_shape_is_told_at_the_line_of_each_key() -> None:
    """The keys, the one action, the durations and the mappings (pydantic: scenario/document.py),
    each problem at the line of the key that has it (config_errors.line_map, as a configuration's)."""
    with pytest.raises(ScenarioError) as caught:
        parse("""\
            name: x
            repeat: 3
            steps:
              - at: 1 s
                delay: 2 s
                fault: link-down
                target: io1
              - fault: link-down
                target: io1
                duration: 0
                params: [1]
                colour: red
              - set: {}
              - 7
            expect:
              - 12
            """)
    assert caught.value.problems == [
        "s.yaml:2: repeat: not a key of a scenario (name, duration, steps, expect)",
        "s.yaml:4: step 1: delay goes with after, not with at",
        "s.yaml:10: step 2: duration: must be > 0 (leave it out: until cleared)",
        "s.yaml:11: step 2: params: a mapping of the kind's parameters",
        "s.yaml:12: step 2: colour: not a key of a step",
        "s.yaml:13: step 3: set: a mapping of DEVICE.SIGNAL: value",
        "s.yaml:14: step 4: a mapping (at:/after:, and one of fault, clear, set, wait)",
        "s.yaml:16: an expectation is a line of text, got 12",
    ]
    with pytest.raises(ScenarioError, match=r"^s.yaml:2: steps: a list of at least one step is needed$"):
        parse("name: x\nsteps: []\n")  # the line of the key


@pytest.mark.parametrize(("text", "ns"), [("100 ms", 100 * MS), ("2 s", 2_000 * MS), ("1.5", 1_500 * MS),
                                          (3, 3_000 * MS), ("1 min", 60_000 * MS), ("0", 0), ("-1 s", None),
                                          (-1, None), (True, None), ("2 h", None)])
def test_durations(text, ns) -> None:
    assert duration_ns(text) == ns


def test_the_scheduler_runs_each_step_at_its_tick_and_not_one_before() -> None:
    scenario = parse(GOOD)
    schedule = Schedule(scenario.steps)
    t0 = 1_000_000_000_000
    schedule.start(t0)
    assert schedule.due(t0 + 2_000 * MS - 1) == [] and schedule.next_due() == t0 + 2_000 * MS
    assert [s.number for s in schedule.due(t0 + 2_000 * MS)] == [1]
    assert schedule.started[1] == t0 + 2_000 * MS
    assert schedule.due(t0 + 5_000 * MS) == [] and schedule.next_due() is None  # step 2 waits for step 1's end
    schedule.end(1, t0 + 2_000 * MS + 7)
    assert schedule.next_due() == t0 + 2_100 * MS + 7
    assert schedule.due(t0 + 2_100 * MS + 6) == []
    # looked at late: the step keeps its own due time
    assert [s.number for s in schedule.due(t0 + 9_000 * MS)] == [2] and schedule.started[2] == t0 + 2_100 * MS + 7
    schedule.end(2, t0 + 9_000 * MS)
    assert [s.number for s in schedule.due(t0 + 9_000 * MS)] == [3]
    schedule.fail(3, t0 + 10_500 * MS)  # the wait timed out: the clear after it never runs
    assert schedule.state == {1: StepState.DONE, 2: StepState.DONE, 3: StepState.FAILED, 4: StepState.SKIPPED}
    assert schedule.done and schedule.due(t0 + 99_000 * MS) == []


def test_steps_at_times_from_the_start_come_in_time_order_whatever_the_file_order() -> None:
    scenario = parse("""\
        steps:
          - {at: 3 s, fault: link-down, target: io1}
          - {at: 1 s, fault: stop-io, target: r2-io1}
          - {at: 1 s, fault: delay, target: r2-io2, params: {delay_ms: 5}}
        """)
    schedule = Schedule(scenario.steps)
    schedule.start(0)
    assert [s.number for s in schedule.due(3_000 * MS)] == [2, 3, 1]
    schedule.cancel()
    assert schedule.done


def test_a_run_lasts_until_its_faults_and_its_expectations_have_had_their_time() -> None:
    from enip_farm.scenario.run import horizon

    scenario = parse(GOOD.replace("    duration: 5 s\n", ""))
    schedule = Schedule(scenario.steps)
    schedule.start(0)
    assert horizon(scenario, schedule) == 0
    schedule.due(2_000 * MS)
    schedule.end(1, 2_000 * MS)
    # the fault's 4 s, then 3 s for rack2 to reconnect after its end (the 100 ms of step 1 is shorter)
    assert horizon(scenario, schedule) == 2_000 * MS + 4_000 * MS + 3_000 * MS


def test_reconnected_is_judged_from_the_reports_reconnections_first_o_t() -> None:
    check = Reconnected("io1", ("io1",), 100_000_000, 1, end=True)
    scenario = Scenario("s", "s.yaml", (), (Expectation("io1 reconnected within 100 ms of end of step 1", 7, check),))
    ms = 1_000_000

    def judged(*figures: Reconnection) -> tuple[bool, str]:
        recording = Recording(0, {}, ended={1: 500 * ms}, reconnections={"io1": list(figures)})
        verdict = judge(scenario, recording, {})[0]
        return verdict.passed, verdict.figure

    before = Reconnection("io1", "10.0.0.9", "timeout", -50 * ms, -40 * ms, -39 * ms)  # before the run: not this one
    done = Reconnection("io1", "127.0.0.1", "fault cleared", 501 * ms, 560 * ms, 600 * ms)
    assert judged(before, done) == (True, "last io1 after 100.0 ms (127.0.0.1: first O->T 99.0 ms, Forward "
                                          "Open 59.0 ms after it came back) (bound 100.0 ms)")
    late = Reconnection("io1", "127.0.0.1", "fault cleared", 501 * ms, 560 * ms, 600 * ms + 1)
    assert judged(late)[0] is False  # the first O->T one ns past the bound, though the Forward Open was in time
    no_o_t = Reconnection("io1", "127.0.0.1", "fault cleared", 501 * ms, 560 * ms, None)
    waiting = Reconnection("io1", "127.0.0.2", "fault cleared", 501 * ms, None, None)
    assert judged(no_o_t, waiting) == (False, "not reconnected: io1 (127.0.0.1, 127.0.0.2: no first O->T after "
                                              "a Forward Open) (bound 100.0 ms)")
