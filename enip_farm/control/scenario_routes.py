"""The HTTP API's scenarios (enip_farm/scenario/), so that test agents in any language can drive one:
POST /scenarios (the scenario's YAML as `text`: checked first, 422 listing every defect
`file:line: reason`; then started on the farm's loop, 201 with its id), GET /scenarios (each run and
its status), GET /scenarios/{id} (its status, progress lines and, once it ended, its result), GET
/scenarios/{id}/result (409 while it runs), DELETE /scenarios/{id} (cancel it: every fault it set
cleared, every signal put back; its result). The last `KEPT` runs are kept."""

from __future__ import annotations

import asyncio
import itertools
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Any

from fastapi import APIRouter, HTTPException
from pydantic import BaseModel, Field

from enip_farm.control.handle import FarmControl
from enip_farm.scenario.parse import ScenarioError, parse_scenario, signal_check
from enip_farm.scenario.run import run_scenario
from enip_farm.scenario.verdict import ScenarioResult

KEPT = 16
MAX_PROGRESS = 1000


class ScenarioRequest(BaseModel):
    text: str = Field(description="the scenario file's YAML", max_length=1_000_000)
    source: str = Field("scenario.yaml", description="its name, for the defects' file:line")


@dataclass
class _Run:
    id: int
    name: str
    task: asyncio.Task
    progress: list[str] = field(default_factory=list)

    def status(self) -> str:
        if not self.task.done():
            return "running"
        if self.task.cancelled() or self.task.exception() is not None:
            return "error"
        result: ScenarioResult = self.task.result()
        return result.status

    def describe(self, detail: bool = False) -> dict[str, Any]:
        out: dict[str, Any] = {"id": self.id, "name": self.name, "status": self.status()}
        if detail:
            out["progress"] = list(self.progress)
            if self.task.done() and not self.task.cancelled() and self.task.exception() is None:
                out["result"] = self.task.result().as_dict()
        return out


def scenario_routes(farm: FarmControl) -> APIRouter:
    router = APIRouter()
    runs: OrderedDict[int, _Run] = OrderedDict()
    numbers = itertools.count(1)

    def known(run_id: int) -> _Run:
        if run_id not in runs:
            raise HTTPException(404, f"no scenario run {run_id}; known: {', '.join(map(str, runs)) or 'none'}")
        return runs[run_id]

    @router.post("/scenarios", status_code=201)
    async def start(body: ScenarioRequest) -> dict[str, Any]:
        """Check the scenario against the farm's cell, then run it; its id to follow it by."""
        check = signal_check({name: farm[name].signals for name in farm.devices})
        try:
            scenario = parse_scenario(body.text, body.source, farm.config, check)
        except ScenarioError as error:
            raise HTTPException(422, {"problems": error.problems}) from None
        number = next(numbers)
        progress: list[str] = []

        def say(line: str) -> None:
            if len(progress) < MAX_PROGRESS:
                progress.append(line)

        task = asyncio.get_running_loop().create_task(run_scenario(farm, scenario, say))  # type: ignore[arg-type]
        runs[number] = _Run(number, scenario.name, task, progress)
        while len(runs) > KEPT:
            oldest = next(iter(runs))
            if not runs[oldest].task.done():
                break
            del runs[oldest]
        return runs[number].describe()

    @router.get("/scenarios")
    def listing() -> list[dict[str, Any]]:
        return [run.describe() for run in runs.values()]

    @router.get("/scenarios/{run_id}")
    def status(run_id: int) -> dict[str, Any]:
        return known(run_id).describe(detail=True)

    @router.get("/scenarios/{run_id}/result")
    def result(run_id: int) -> dict[str, Any]:
        run = known(run_id)
        if not run.task.done():
            raise HTTPException(409, f"scenario run {run_id} is still running")
        return run.describe(detail=True)["result"]

    @router.delete("/scenarios/{run_id}")
    async def cancel(run_id: int) -> dict[str, Any]:
        """Cancel a run (nothing it set outlives it) and answer its result once it has ended."""
        run = known(run_id)
        run.task.cancel()
        await asyncio.wait({run.task})
        return run.describe(detail=True)

    return router
