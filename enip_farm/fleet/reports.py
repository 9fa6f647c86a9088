"""GET /report of a fleet: the farms' reports on the controller under test (cip/report.py's JSON)
merged into one, as one farm would answer for the whole cell."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from enip_farm.cip.report import NOT_JUDGED, worst


def down_device(name: str, marks: Mapping[str, Any]) -> dict[str, Any]:
    """A device of a part that is down, in the report's shape: nothing measured, not judged."""
    return {"device": name, "verdict": NOT_JUDGED, "connections": [], "reconnections": [], "verdicts": [], **marks}


def merge_reports(answers: list[tuple[dict[str, Any], Mapping[str, Any]]], down: list[dict[str, Any]],
                  position: Mapping[str, int]) -> dict[str, Any]:
    """`answers`: each farm's report with the marks of its part (e.g. {"worker": 2, "worker_up": True});
    `down`: the devices of parts that did not answer. Devices in `position`'s order, reactions one
    after the other, the verdict the worst of the farms' (a part that is down is listed, not judged;
    with nothing else judged the verdict is "not judged"), `at_ns` the latest (one host, one
    monotonic clock; 0 when none answered)."""
    devices = [{**device, **marks} for answer, marks in answers for device in answer["devices"]] + list(down)
    devices.sort(key=lambda device: position.get(device["device"], len(position)))
    verdicts = [answer["verdict"] for answer, _ in answers] + [NOT_JUDGED for _ in down]
    return {"at_ns": max((answer["at_ns"] for answer, _ in answers), default=0), "verdict": worst(verdicts),
            "failures": [line for answer, _ in answers for line in answer["failures"]], "devices": devices,
            "reactions": [reaction for answer, _ in answers for reaction in answer["reactions"]]}
