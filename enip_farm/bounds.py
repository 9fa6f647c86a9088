"""The bounds the farm judges the controller under test against (its report, cip/report.py): pure
schema, set for the cell (`bounds:` at the top of the YAML), per device (`bounds:` in a device's
entry, over the cell's) and per test (`farm.report(bounds=...)`, the pytest marker, over both).

Every bound is an upper one: a figure at or below it passes. None: not judged. Where each default
comes from is in `SOURCES`; ODVA's and NIST's EtherNet/IP performance publications define the
figures (the measured packet interval against the API, action latency) but publish no pass bound
for an originator, so most defaults are this farm's choice and say so ("a choice, unverified").
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from pydantic import BaseModel, ConfigDict, Field

_CHOICE = "a choice, unverified (ODVA/NIST define the figure, not a bound)"
#: Where each default bound comes from.
SOURCES: Mapping[str, str] = {
    "interval_p99_api": f"{_CHOICE}: 1.5 API",
    "interval_max_api": "not judged unless set",
    "late_intervals": f"{_CHOICE}: no interval of 2 API or more",
    "silence_timeout": "CIP Vol. 1, 3-4.4.9: a silence of the connection timeout (RPI x 2^(2 + multiplier)) "
                       "times the connection out",
    "lost": f"{_CHOICE}: no sequence number skipped (on loopback nothing is lost)",
    "repeats": "CIP Vol. 2, 3-2.1: every new O->T packet takes a new 32-bit sequence number",
    "stale": "CIP Vol. 2, 3-2.1: the 32-bit sequence only advances",
    "rpi_deviation_us": "the device's expected RPI (EIO.cfg or EDS, or `expected_o_t_rpi_us`): asked exactly",
    "reconnect_forward_open_s": f"{_CHOICE}: 10 s from the device's return to the next accepted Forward Open",
    "reconnect_first_o_t_s": "not judged unless set",
    "reaction_p99_ms": "not judged unless set (the test knows its controller's cycle)",
    "reaction_max_ms": "not judged unless set",
    "reaction_timeouts": "no reaction missed its timeout",
}


class BoundsConfig(BaseModel):
    """Bounds of the report's verdicts; a field left out takes the level below's (cell, then default)."""

    model_config = ConfigDict(extra="forbid")

    interval_p99_api: float | None = Field(1.5, gt=0, description="p99 of the O->T packet interval, in APIs")
    interval_max_api: float | None = Field(None, gt=0, description="longest O->T packet interval, in APIs")
    late_intervals: int | None = Field(0, ge=0, description="O->T intervals of 2 API or more")
    silence_timeout: float | None = Field(1.0, gt=0, description="longest silence, in connection timeouts")
    lost: int | None = Field(0, ge=0, description="32-bit sequence numbers skipped")
    repeats: int | None = Field(0, ge=0, description="O->T packets repeating the last sequence number")
    stale: int | None = Field(0, ge=0, description="O->T packets older than the last sequence number")
    expected_o_t_rpi_us: int | None = Field(None, ge=1, description="the O->T RPI the device expects "
                                            "(default: its EDS connection's, if it has one)")
    expected_t_o_rpi_us: int | None = Field(None, ge=1, description="the T->O RPI the device expects")
    rpi_deviation_us: int | None = Field(0, ge=0, description="|RPI asked - RPI expected|, where one is expected")
    reconnect_forward_open_s: float | None = Field(10.0, gt=0, description="from the device's return (fault "
                                                   "cleared, reset done) or a timeout to the next Forward Open")
    reconnect_first_o_t_s: float | None = Field(None, gt=0, description="... to the first O->T after it")
    reaction_p99_ms: float | None = Field(None, gt=0, description="p99 of a reaction's action latency")
    reaction_max_ms: float | None = Field(None, gt=0, description="longest action latency of a reaction")
    reaction_timeouts: int | None = Field(0, ge=0, description="repetitions of a reaction that timed out")
    min_intervals: int = Field(10, ge=1, description="intervals a connection needs before its counts are judged "
                                                     "(a choice); a p99 needs 100 (1 in 100 is the p99)")


#: Samples a p99 needs: with fewer, the p99 is the maximum.
P99_NEEDS = 100


@dataclass(frozen=True)
class ResolvedBounds:
    """The bounds in force for one device (or a reaction): each value and where it came from."""

    values: Mapping[str, Any]
    sources: Mapping[str, str]

    def __getitem__(self, name: str) -> Any:
        return self.values[name]

    def source(self, name: str) -> str:
        return self.sources.get(name, SOURCES.get(name, ""))


def resolve(*levels: tuple[str, BoundsConfig | Mapping[str, Any] | None]) -> ResolvedBounds:
    """The defaults, then each (name, bounds) level over the ones before: only the fields a level
    sets count (a YAML entry's given keys, a test's dict). ValueError for an unknown or bad bound."""
    values: dict[str, Any] = BoundsConfig().model_dump()
    sources: dict[str, str] = {}
    for name, level in levels:
        if level is None:
            continue
        model = level if isinstance(level, BoundsConfig) else BoundsConfig.model_validate(dict(level))
        for key in model.model_fields_set:
            values[key] = getattr(model, key)
            sources[key] = name
    return ResolvedBounds(values, sources)
