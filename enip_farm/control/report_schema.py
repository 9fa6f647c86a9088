"""GET /report's answer as OpenAPI shows it: the report on the controller under test
(cip/report.py, `FarmReport.as_dict()`), in pydantic models for the schema. Fields the report adds
later pass through (extra allowed), so the schema describes and never truncates."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

VerdictWord = Literal["pass", "fail", "too short to judge", "not judged"]


class _Open(BaseModel):
    model_config = ConfigDict(extra="allow")


class VerdictModel(_Open):
    figure: str = Field(description="what was measured, e.g. `interval p99`")
    verdict: VerdictWord
    value: float | int | None = Field(description="the figure (None: not measured yet)")
    bound: float | int = Field(description="its upper bound: a value at or below it passes")
    unit: str
    needs: int = Field(description="samples the bound needs before it judges")
    have: int = Field(description="samples measured")
    source: str = Field(description="where the bound comes from: a spec section, a publication, the "
                        "configuration, the test, or 'a choice, unverified'")


class HistogramModel(_Open):
    bounds_api: list[float] = Field(description="upper bound of each bucket, in multiples of the O->T API")
    counts: list[int] = Field(description="intervals per bucket; one more than bounds: those above every bound")


class IntervalsModel(_Open):
    """The measured O->T packet interval against the API (ODVA/NIST: jitter), in ns."""

    api_ns: int
    count: int
    min_ns: int | None
    p50_ns: int | None
    p99_ns: int | None
    max_ns: int | None
    mean_ns: int | None
    late: int = Field(description="intervals of 2 API or more")
    longest_silence_ns: int
    histogram: HistogramModel


class SequenceModel(_Open):
    packets: int
    lost: int
    gaps: int
    repeats: int
    stale: int
    last: int | None


class ConnectionModel(_Open):
    device: str
    originator: str
    o_t_id: int
    t_o_id: int
    kind: str
    opened_at_ns: int
    ended_at_ns: int | None
    ended: str | None = Field(description="forward close, timeout, tcp gone, device fault, device reset, closed")
    forward_open: dict | None = Field(description="the Forward Open as the originator asked it")
    intervals: IntervalsModel
    sequence: SequenceModel
    cip_sequence: dict
    run_idle: dict
    verdict: VerdictWord
    verdicts: list[VerdictModel]


class DeviceReportModel(_Open):
    device: str
    verdict: VerdictWord
    connections: list[ConnectionModel]
    reconnections: list[dict]
    verdicts: list[VerdictModel]


class FarmReportModel(_Open):
    """The whole cell (or the devices asked for): every class-1 connection's originator as
    measured and judged, reconnections, reactions."""

    at_ns: int = Field(description="when the report was made, ns of the farm's monotonic clock")
    verdict: VerdictWord = Field(description="fail if any bound failed, else too short if any was, else pass")
    failures: list[str] = Field(description="one line per broken bound")
    devices: list[DeviceReportModel]
    reactions: list[dict]
