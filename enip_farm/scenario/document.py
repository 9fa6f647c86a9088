"""A scenario file's shape, as pydantic validates it: the top-level keys (name, duration, steps,
expect), each step's keys, its one action (fault, clear, set, wait) and its durations (100 ms, 2 s,
1.5, 1 min). What the values mean in the cell (targets, signals, the steps named, a fault kind's
parameters) is scenario/parse.py's to check. `problems` says each of pydantic's errors in the
farm's words, with its place in the document (config_errors.line_of finds its line)."""

from __future__ import annotations

import re
from typing import Annotated, Any

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, ValidationError, field_validator, model_validator

from enip_farm.config_errors import Location

DEFAULT_WAIT_NS = 10_000_000_000
ACTIONS = ("fault", "clear", "set", "wait")
_DURATION = re.compile(r"^\s*(\d+(?:\.\d+)?)\s*(ms|s|min)?\s*$")
_UNITS = {"ms": 1_000_000, "s": 1_000_000_000, "min": 60_000_000_000, None: 1_000_000_000}
_WHAT = {"steps": "a list of at least one step is needed", "expect": "a list of expectations"}


def duration_ns(value: Any) -> int | None:
    """"100 ms", "3 s", "2 min", 1.5 (s) as ns; None if it is none of these."""
    if isinstance(value, bool):
        return None
    if isinstance(value, (int, float)):
        return round(value * 1e9) if value >= 0 else None
    match = _DURATION.match(str(value))
    return round(float(match[1]) * _UNITS[match[2]]) if match else None


def _duration(value: Any) -> int:
    checked = duration_ns(value)
    if checked is None:
        raise ValueError(f"{value!r} is not a duration (100 ms, 2 s, 1.5, 1 min)")
    return checked


def _text(value: Any) -> Any:
    return value if value is None else str(value)


Duration = Annotated[int, BeforeValidator(_duration)]
Text = Annotated[str | None, BeforeValidator(_text)]  # an id, a step, a target or a kind as written


class ScenarioDocument(BaseModel):
    """The top level: `steps` and `expect` are checked item by item (StepDocument, `expectations`)."""

    model_config = ConfigDict(extra="forbid")

    name: Any = None
    duration: Duration = 0
    steps: list[Any] = Field(min_length=1)
    expect: list[Any] = []


class StepDocument(BaseModel):
    """One step's keys: when (`at`, or `after` a step and a `delay`) and one action."""

    model_config = ConfigDict(extra="forbid")

    id: Text = None
    at: Duration | None = None
    after: Text = None
    delay: Duration = 0
    fault: Text = None
    target: Any = None
    duration: Duration | None = None
    params: dict[str, Any] = {}
    clear: Any = None
    kind: Text = None
    set: dict[str, Any] = {}
    wait: Any = None
    timeout: Duration = DEFAULT_WAIT_NS
    note: Any = None

    @field_validator("duration")
    @classmethod
    def _lasts(cls, value: int | None) -> int | None:
        if value == 0:
            raise ValueError("must be > 0 (leave it out: until cleared)")
        return value

    @field_validator("params", mode="before")
    @classmethod
    def _params(cls, value: Any) -> Any:
        if value is None:
            return {}
        if not isinstance(value, dict):
            raise ValueError("a mapping of the kind's parameters")
        return value

    @field_validator("set", mode="before")
    @classmethod
    def _values(cls, value: Any) -> Any:
        if not isinstance(value, dict) or not value:
            raise ValueError("a mapping of DEVICE.SIGNAL: value")
        return {str(name): v for name, v in value.items()}

    @model_validator(mode="after")
    def _one_action(self) -> StepDocument:
        given = self.model_fields_set
        actions = [key for key in ACTIONS if key in given]
        if len(actions) != 1:
            raise ValueError(f"one action of {', '.join(ACTIONS)}, got {', '.join(actions) or 'none'}")
        if {"at", "after"} <= given:
            raise ValueError("at and after both given: one or the other")
        if {"at", "delay"} <= given:
            raise ValueError("delay goes with after, not with at")
        return self

    @property
    def action(self) -> str:
        return next(key for key in ACTIONS if key in self.model_fields_set)


def problems(error: ValidationError, where: Location, label: str = "") -> list[tuple[Location, str]]:
    """Each error of `error` (a model validated at `where` in the document) as (its place, the
    farm's words), `label` first ("step 3: ")."""
    out = []
    for e in error.errors():
        loc, message = tuple(e["loc"]), e["msg"].removeprefix("Value error, ")
        field = str(loc[0]) if loc else ""
        if e["type"] == "extra_forbidden":
            message = "not a key of a step" if label else "not a key of a scenario (name, duration, steps, expect)"
        elif not label and field in _WHAT:
            message = _WHAT[field]
        out.append(((*where, *loc), label + (f"{field}: {message}" if field else message)))
    return out


def step_document(raw: Any, number: int) -> StepDocument | list[tuple[Location, str]]:
    """Step `number`'s keys checked, or the problems found (at their places in the document)."""
    where = ("steps", number - 1)
    if not isinstance(raw, dict):
        return [(where, f"step {number}: a mapping (at:/after:, and one of {', '.join(ACTIONS)})")]
    try:
        return StepDocument.model_validate(raw)
    except ValidationError as error:
        return problems(error, where, f"step {number}: ")
