"""The farms' answers merged into one, as one farm would answer for the whole cell: GET /report of
a fleet (the reports on the controller under test, cip/report.py's JSON), GET /overview
(control/overview.py's) and GET /metrics (Prometheus text)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from prometheus_client import CollectorRegistry, generate_latest
from prometheus_client.metrics_core import Metric
from prometheus_client.parser import text_string_to_metric_families

from enip_farm.cip.report import NOT_JUDGED, DeviceReport, worst
from enip_farm.control.overview import STATES


def down_device(name: str, marks: Mapping[str, Any]) -> dict[str, Any]:
    """A device of a part that is down, in the report's shape (cip/report.py's): nothing measured, not judged."""
    return {**DeviceReport(name, ()).as_dict(), **marks}


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


def merge_overviews(answers: list[tuple[dict[str, Any], Mapping[str, Any]]], down: list[dict[str, Any]],
                    position: Mapping[str, int], events: int) -> dict[str, Any]:
    """`answers`: each farm's GET /overview with the marks of its part; `down`: the tiles of the
    devices of parts that did not answer. Every device in `position`'s order, the counts of them
    all, the last `events` of the farms' recent events (oldest first), `monotonic` the latest."""
    devices = [{**device, **marks} for answer, marks in answers for device in answer["devices"]] + list(down)
    devices.sort(key=lambda device: position.get(device["name"], len(position)))
    counts = dict.fromkeys(STATES, 0)
    for device in devices:
        counts[device["state"]] += 1
    recent = sorted((event for answer, _ in answers for event in answer["events"]), key=lambda e: e["monotonic"])
    return {"monotonic": max((answer["monotonic"] for answer, _ in answers), default=0.0), "counts": counts,
            "devices": devices, "events": recent[-events:] if events > 0 else []}


def merge_metrics(texts: list[str], labels: list[dict[str, str]] | None = None,
                  extra: list[Metric] | None = None) -> str:
    """Prometheus text of several farms as one exposition, parsed and written by prometheus_client:
    each family once (HELP and TYPE from the first that has it) with every farm's samples, each
    given `labels[i]` (e.g. its shard) if given, then the families in `extra`."""
    families: dict[str, Metric] = {}
    for index, text in enumerate(texts):
        for family in text_string_to_metric_families(text):
            merged = families.get(family.name)
            if merged is None:
                merged = families[family.name] = Metric(family.name, family.documentation, family.type, family.unit)
            added = labels[index] if labels else {}
            merged.samples.extend(sample._replace(labels={**sample.labels, **added}) for sample in family.samples)

    class Merged:
        def collect(self) -> list[Metric]:
            return [*families.values(), *(extra or [])]

    registry = CollectorRegistry(auto_describe=False)
    registry.register(Merged())
    return generate_latest(registry).decode()
