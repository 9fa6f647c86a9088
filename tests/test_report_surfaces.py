"""The report on the controller under test through the farm's surfaces (issue 27): GET /report (in
the OpenAPI schema, the same figures as Farm.report()), `enip-farm report` against the running farm
(a table, exit 1 when a bound failed) and `--junit FILE` (JUnit XML, read back with junitparser and
ElementTree), and the Prometheus histogram of each connection's O->T intervals. The originator is
this test, on raw UDP: 20 O->T packets and one repeat, to a device whose configuration expects an
RPI of 20 ms where the test asks 10 ms, so exactly two bounds fail (a repeated sequence number, the
RPI asked), whatever the machine's load (the interval bounds are switched off in the cell)."""

from __future__ import annotations

import socket
import subprocess
import xml.etree.ElementTree as ElementTree
from pathlib import Path

import httpx
import jsonschema
import pytest
from junitparser import Failure, JUnitXml

from enip_farm.protocol.connection import decode_forward_open_reply, encode_io_packet
from enip_farm.protocol.epath import ElectronicKey
from tests.helpers import CLI, RawClient, metric_samples, wait_for
from tests.test_implicit import forward_close, forward_open

pytestmark = pytest.mark.integration

PACKETS, REPEATED = 20, 10
CELL = {"bounds": {"interval_p99_api": None, "late_intervals": None, "silence_timeout": None},
        "devices": [{"name": "io1", "model": "DSQC1030", "implicit": {"first_watchdog_s": 0},
                     "bounds": {"expected_o_t_rpi_us": 20_000}},
                    {"name": "io2", "model": "DSQC1030"}]}
FAILED = ["sequence numbers repeated", "O->T RPI asked vs 20000 us expected"]


@pytest.fixture
def measured(enip_farm):
    """A farm whose io1 has one connection measured and closed: 20 packets, one repeated."""
    farm = enip_farm(CELL, http=True)
    io = farm["io1"]
    with RawClient(io.address) as client:
        client.register()
        # timeout 5.12 s: a busy machine times nothing out; a key of zeros: one of every form's fields
        message, triad = forward_open(rpi=10_000, multiplier=7, key=ElectronicKey(0, 0, 0, 0, 0, False))
        opened = decode_forward_open_reply(client.request(message).data)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as udp:
            udp.bind(("127.0.0.1", 0))
            for sequence in range(1, PACKETS + 1):
                for _ in range(2 if sequence == REPEATED else 1):
                    udp.sendto(encode_io_packet(opened.o_t_connection_id, sequence, sequence,
                                                b"\x01\x00\x00\x00\x00\x00"), (io.address, 2222))
            assert wait_for(lambda: farm.report().devices[0].connections[0].sequence.packets == PACKETS)
        assert client.request(forward_close(triad)).general_status == 0
    return farm, opened.o_t_connection_id, triad


def test_get_report_is_the_farms_report_in_the_schema(measured) -> None:
    farm, o_t_id, _ = measured
    base = f"http://127.0.0.1:{farm.http.port}"
    answer = httpx.get(f"{base}/report").json()
    expected = farm.report().as_dict()
    assert {**answer, "at_ns": 0} == {**expected, "at_ns": 0}
    assert answer["verdict"] == "fail"
    (connection,) = answer["devices"][0]["connections"]
    assert (connection["o_t_id"], connection["ended"]) == (o_t_id, "forward close")
    assert (connection["sequence"]["packets"], connection["sequence"]["repeats"]) == (PACKETS, 1)
    assert sorted(v["figure"] for v in connection["verdicts"] if v["verdict"] == "fail") == sorted(FAILED)
    assert [d["device"] for d in answer["devices"]] == ["io1", "io2"]
    only = httpx.get(f"{base}/report", params={"device": "io2"}).json()
    assert [d["device"] for d in only["devices"]] == ["io2"] and only["verdict"] == "not judged"
    assert only["failures"] == []
    assert httpx.get(f"{base}/report", params={"device": "nope"}).status_code == 404


def _objects(schema: dict, schemas: dict, seen: set[str]) -> list[dict]:
    """Every object schema reachable from `schema` through the components' $refs."""
    if "$ref" in schema:
        name = schema["$ref"].rsplit("/", 1)[1]
        if name in seen:
            return []
        seen.add(name)
        schema = schemas[name]
    out = [schema] if schema.get("type") == "object" else []
    for value in schema.values():
        for part in (value if isinstance(value, list) else [value]):
            if isinstance(part, dict):
                out += [s for inner in [part, *part.values()] if isinstance(inner, dict)
                        for s in _objects(inner, schemas, seen)]
    return out


def test_get_report_is_exactly_its_openapi_schema(measured) -> None:
    """The JSON GET /report serves validates against the schema /openapi.json publishes for it,
    one derived from cip/report.py's dataclasses with every object closed and every field
    required: a field added to the JSON and not to the dataclasses, or one missing, fails."""
    farm, _, _ = measured
    base = f"http://127.0.0.1:{farm.http.port}"
    openapi = httpx.get(f"{base}/openapi.json").json()
    ok = openapi["paths"]["/report"]["get"]["responses"]["200"]["content"]["application/json"]["schema"]
    assert ok == {"$ref": "#/components/schemas/FarmReport"}
    objects = _objects(ok, openapi["components"]["schemas"], set())
    assert len(objects) >= 12 and all(o["additionalProperties"] is False for o in objects)
    assert all(set(o["required"]) == set(o["properties"]) for o in objects)
    validator = jsonschema.Draft202012Validator({**ok, "components": openapi["components"]})
    answer = httpx.get(f"{base}/report").json()
    connection = answer["devices"][0]["connections"][0]
    assert connection["forward_open"]["key"] == {"form": "any", "vendor_id": 0, "device_type": 0, "product_code": 0,
                                                 "major_revision": 0, "minor_revision": 0}
    assert list(validator.iter_errors(answer)) == []
    drifted = {**answer, "devices": [{**answer["devices"][0], "connections": [{**connection, "new": 1}]}]}
    assert [e.message for e in validator.iter_errors(drifted)] == [
        "Additional properties are not allowed ('new' was unexpected)"]
    del connection["run_idle"]
    assert [e.message for e in validator.iter_errors(answer)] == ["'run_idle' is a required property"]


@pytest.mark.system
def test_cli_report_prints_a_table_and_writes_junit(measured, tmp_path: Path) -> None:
    farm, o_t_id, _ = measured
    out = tmp_path / "report.xml"
    run = subprocess.run([*CLI, "report", "--api", f"http://127.0.0.1:{farm.http.port}", "--junit", str(out)],
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 1, run.stderr  # a bound failed
    lines = run.stdout.splitlines()
    assert lines[0] == "verdict: fail"
    assert lines[1].split()[:4] == ["device", "O->T", "id", "originator"]
    row = lines[2].split()
    assert row[:4] == ["io1", f"0x{o_t_id:08X}", "127.0.0.1", "forward"] and row[-1] == "fail"
    assert sum(line.startswith("FAIL io1 O->T") for line in lines) == 2
    xml = JUnitXml.fromfile(str(out))
    suites = {suite.name: suite for suite in xml}
    assert list(suites) == ["enip-farm report: io1", "enip-farm report: io2"]
    io1 = suites["enip-farm report: io1"]
    cases = {case.name: case for case in io1}
    judged = {v["figure"] for v in farm.report().as_dict()["devices"][0]["connections"][0]["verdicts"]}
    assert set(cases) == judged and (io1.tests, io1.failures, io1.errors) == (len(judged), 2, 0)
    assert sorted(name for name, case in cases.items() if any(isinstance(r, Failure) for r in case.result)) == \
        sorted(FAILED)
    assert all(case.classname == f"io1.O->T 0x{o_t_id:08X} from 127.0.0.1" for case in io1)
    assert suites["enip-farm report: io2"].tests == 0
    root = ElementTree.parse(out).getroot()  # plain XML as any CI reads it
    assert root.tag == "testsuites" and root.get("tests") == str(len(judged)) and root.get("failures") == "2"
    assert [s.get("name") for s in root.iter("testsuite")] == list(suites)


def test_metrics_show_each_connections_interval_histogram(measured) -> None:
    farm, o_t_id, _ = measured
    text = httpx.get(f"http://127.0.0.1:{farm.http.port}/metrics").text
    labels = (("connection", f"0x{o_t_id:08X}"), ("device", "io1"), ("originator", "127.0.0.1"))
    counts = metric_samples(text, "enip_farm_o_t_interval_apis_count")
    assert counts == {labels: PACKETS - 1}  # 20 packets that advanced the sequence: 19 intervals
    buckets = metric_samples(text, "enip_farm_o_t_interval_apis_bucket")
    assert buckets[(*labels[:2], ("le", "+Inf"), labels[2])] == PACKETS - 1
    cumulative = [value for key, value in buckets.items()]
    assert cumulative == sorted(cumulative)  # cumulative buckets, as Prometheus histograms are
