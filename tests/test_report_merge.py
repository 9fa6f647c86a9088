"""The report's surfaces as pure functions (unit): a fleet's merge of its farms' reports
(fleet/reports.py) and `enip-farm report`'s JUnit mapping and table (cli/report.py), on reports
made by hand in the JSON shape of cip/report.py."""

from __future__ import annotations

from junitparser import Failure, Skipped

from enip_farm.cli.report import junit, report_table
from enip_farm.fleet.reports import down_device, merge_reports


def verdict(figure: str, word: str, value: float | None = 1, bound: float = 0) -> dict:
    return {"figure": figure, "verdict": word, "value": value, "bound": bound, "unit": "packets", "needs": 10,
            "have": 3 if word == "too short to judge" else 100, "source": "test"}


def device(name: str, word: str, *verdicts: dict) -> dict:
    connection = {"o_t_id": 0x10, "originator": "127.0.0.1", "ended": None, "verdict": word,
                  "verdicts": list(verdicts), "run_idle": {"transitions": 1},
                  "intervals": {"api_ns": 10_000_000, "count": 100, "p50_ns": 10_000_000, "p99_ns": 12_000_000,
                                "max_ns": 13_000_000, "late": 0, "longest_silence_ns": 13_000_000},
                  "sequence": {"lost": 0, "repeats": 2, "stale": 0}}
    return {"device": name, "verdict": word, "connections": [connection], "reconnections": [], "verdicts": []}


def report(at: int, verdict_word: str, *devices: dict, failures: tuple[str, ...] = (), reactions: tuple = ()) -> dict:
    return {"at_ns": at, "verdict": verdict_word, "failures": list(failures), "devices": list(devices),
            "reactions": list(reactions)}


def test_a_fleet_merges_its_farms_reports_worst_verdict_first() -> None:
    one = report(5, "pass", device("io2", "pass", verdict("lost", "pass")))
    two = report(9, "fail", device("io1", "fail", verdict("repeats", "fail")), failures=("io1 O->T: repeats",),
                 reactions=({"name": "r"},))
    merged = merge_reports([(one, {"worker": 1, "worker_up": True}), (two, {"worker": 2, "worker_up": True})],
                           [down_device("io3", {"worker": 3, "worker_up": False})], {"io1": 0, "io2": 1, "io3": 2})
    assert [(d["device"], d["worker"], d["worker_up"], d["verdict"]) for d in merged["devices"]] == [
        ("io1", 2, True, "fail"), ("io2", 1, True, "pass"), ("io3", 3, False, "not judged")]
    assert (merged["at_ns"], merged["verdict"], merged["failures"]) == (9, "fail", ["io1 O->T: repeats"])
    assert merged["reactions"] == [{"name": "r"}]
    # a part that is down: its devices listed, not judged; the verdict is the others'
    passing = merge_reports([(one, {})], [down_device("io3", {})], {"io2": 0, "io3": 1})
    assert passing["verdict"] == "pass" and passing["devices"][1]["connections"] == []
    assert merge_reports([], [down_device("io3", {})], {})["verdict"] == "not judged"
    assert merge_reports([], [], {})["at_ns"] == 0


def test_junit_has_a_case_per_verdict_a_failure_per_broken_bound_and_skips_what_is_too_short() -> None:
    answer = report(1, "fail", device("io1", "fail", verdict("repeats", "fail", 2), verdict("lost", "pass", 0),
                                      verdict("interval p99", "too short to judge", None, 1.5)),
                    device("io2", "not judged"),
                    reactions=({"name": "DI3 to DO5", "verdicts": [verdict("reaction p99", "pass", 3, 10)]},))
    answer["devices"][1]["connections"] = []
    xml = junit(answer)
    suites = list(xml)
    assert [s.name for s in suites] == ["enip-farm report: io1", "enip-farm report: io2", "enip-farm report: reactions"]
    cases = {case.name: case for case in suites[0]}
    assert [type(r) for r in cases["repeats"].result] == [Failure]
    assert cases["repeats"].result[0].message == "repeats 2 packets (bound 0: test)"
    assert cases["lost"].result == []
    assert [type(r) for r in cases["interval p99"].result] == [Skipped]
    assert cases["interval p99"].result[0].message == "too short to judge: 3 of 10 samples"
    assert {case.classname for case in suites[0]} == {"io1.O->T 0x00000010 from 127.0.0.1"}
    assert (suites[0].tests, suites[0].failures, suites[0].skipped, suites[1].tests) == (3, 1, 1, 0)
    assert [case.classname for case in suites[2]] == ["reaction.DI3 to DO5"]
    assert (xml.tests, xml.failures) == (4, 1)


def test_the_table_has_a_row_per_connection_and_a_line_per_failure() -> None:
    answer = report(1, "fail", device("io1", "fail", verdict("repeats", "fail", 2)), failures=("io1: repeats",))
    lines = report_table(answer).splitlines()
    assert lines[0] == "verdict: fail"
    assert lines[2].split() == ["io1", "0x00000010", "127.0.0.1", "open", "10.00", "100", "10.00", "/", "12.00",
                                "/", "13.00", "0", "13.00", "0", "/", "2", "/", "0", "1", "fail"]
    assert lines[-1] == "FAIL io1: repeats"
    assert report_table(report(1, "not judged")).splitlines() == ["verdict: not judged",
                                                                  "no class-1 connection measured"]
