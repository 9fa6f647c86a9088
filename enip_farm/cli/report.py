"""`enip-farm report`: the report on the controller under test from a running farm's HTTP API (GET
/report: every class-1 connection's originator as measured and judged, reconnections, reactions)
as a table, and with `--junit FILE` as JUnit XML for CI (junitparser writes it): one test suite
per device (and one for the reactions), one test case per verdict, a failure for a broken bound,
skipped for "too short to judge". Exit status 1 when a bound failed."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import click

from enip_farm.cli.options import api_option, table, token_option


def _ms(ns: int | None) -> str:
    return "-" if ns is None else f"{ns / 1e6:.2f}"


def _where(connection: dict[str, Any]) -> str:
    return f"O->T 0x{connection['o_t_id']:08X} from {connection['originator']}"


def report_table(report: dict[str, Any]) -> str:
    """One row per measured connection, then the reconnections, the reactions and the failures."""
    rows = []
    for device in report["devices"]:
        for c in device["connections"]:
            i, s = c["intervals"], c["sequence"]
            rows.append([device["device"], f"0x{c['o_t_id']:08X}", c["originator"], c["ended"] or "open",
                         _ms(i["api_ns"]), str(i["count"]),
                         f"{_ms(i['p50_ns'])} / {_ms(i['p99_ns'])} / {_ms(i['max_ns'])}", str(i["late"]),
                         _ms(i["longest_silence_ns"]), f"{s['lost']} / {s['repeats']} / {s['stale']}",
                         str(c["run_idle"]["transitions"]), c["verdict"]])
    lines = [f"verdict: {report['verdict']}"]
    if rows:
        lines.append(table(rows, ["device", "O->T id", "originator", "ended", "API ms", "intervals",
                                  "p50 / p99 / max ms", ">=2 API", "silence ms", "lost / rep / stale",
                                  "run/idle", "verdict"]))
    else:
        lines.append("no class-1 connection measured")
    for device in report["devices"]:
        for r in device["reconnections"]:
            lines.append(f"{device['device']}: reconnection of {r['originator']} after {r['after']}: Forward Open "
                         f"{_ms(r['forward_open_after_ns'])} ms, first O->T {_ms(r['first_o_t_after_ns'])} ms")
    for r in report["reactions"]:
        lines.append(f"reaction {r['name']} ({r['stimulus']} -> {r['expect']}): {r['count']} samples, p50 "
                     f"{_ms(r['p50_ns'])} / p99 {_ms(r['p99_ns'])} / max {_ms(r['max_ns'])} ms, "
                     f"{r['timeouts']} timed out: {r['verdict']}")
    lines += [f"FAIL {line}" for line in report["failures"]]
    return "\n".join(lines)


def junit(report: dict[str, Any]) -> Any:
    """The report as a junitparser JUnitXml: a suite per device and one for the reactions."""
    from junitparser import Failure, JUnitXml, Skipped, TestCase, TestSuite

    def case(classname: str, verdict: dict[str, Any]) -> TestCase:
        test = TestCase(verdict["figure"], classname)
        bound = f"{verdict['value']} {verdict['unit']} (bound {verdict['bound']}: {verdict['source']})"
        if verdict["verdict"] == "fail":
            test.result = [Failure(f"{verdict['figure']} {bound}", "bound broken")]
        elif verdict["verdict"] != "pass":
            test.result = [Skipped(f"{verdict['verdict']}: {verdict['have']} of {verdict['needs']} samples")]
        test.system_out = bound
        return test

    xml = JUnitXml("enip-farm report")
    for device in report["devices"]:
        suite = TestSuite(f"enip-farm report: {device['device']}")
        for verdict in device["verdicts"]:
            suite.add_testcase(case(f"{device['device']}.reconnection", verdict))
        for connection in device["connections"]:
            for verdict in connection["verdicts"]:
                suite.add_testcase(case(f"{device['device']}.{_where(connection)}", verdict))
        suite.update_statistics()
        xml.add_testsuite(suite)
    if report["reactions"]:
        suite = TestSuite("enip-farm report: reactions")
        for reaction in report["reactions"]:
            for verdict in reaction["verdicts"]:
                suite.add_testcase(case(f"reaction.{reaction['name']}", verdict))
        suite.update_statistics()
        xml.add_testsuite(suite)
    xml.update_statistics()
    return xml


@click.command()
@click.option("--device", "devices", multiple=True, metavar="NAME", help="only this device (repeatable)")
@click.option("--junit", "junit_path", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="also write the verdicts as JUnit XML to FILE (for CI)")
@click.option("--json", "as_json", is_flag=True, help="print the report's JSON instead of the table")
@api_option
@token_option
def report(devices: tuple[str, ...], junit_path: Path | None, as_json: bool, api: str, token: str | None) -> None:
    """The report on the controller under test, from a running farm: each class-1 connection's O->T
    packet intervals against its API, sequence gaps, repeats and stale packets, run/idle
    transitions, how it ended, reconnections and reactions, each judged against its bound. Exit
    status 1 when a bound failed."""
    import json

    from enip_farm.cli.api import call

    answer = call(api, token, "GET", "/report", params=[("device", name) for name in devices])
    click.echo(json.dumps(answer, indent=1) if as_json else report_table(answer))
    if junit_path is not None:
        junit(answer).write(str(junit_path), pretty=True)
    if answer["verdict"] == "fail":
        sys.exit(1)


COMMANDS = (report,)
