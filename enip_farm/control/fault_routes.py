"""The HTTP API's fault requests, and its routes for the cell's groups (enip_farm/topology.py): GET
/groups (each group, its kind and its devices), POST /groups/{name}/faults (one fault on every member
at once: the kind and its parameters as POST /devices/{name}/faults takes them), DELETE
/groups/{name}/faults (one kind, or all, on every member)."""

from __future__ import annotations

import math
from typing import Any

from fastapi import APIRouter, HTTPException
from fastapi.exceptions import RequestValidationError
from pydantic import BaseModel, ConfigDict, Field

from enip_farm.control.handle import FarmControl
from enip_farm.device.faults import Fault, FaultError, FaultKind, FaultType


class FaultRequest(BaseModel):
    """A kind and its parameters, side by side, e.g. {"kind": "delay", "delay_ms": 800, "duration_s": 10}:
    GET /fault-kinds lists each kind's parameters (a JSON Schema); `Fault` checks them."""

    model_config = ConfigDict(extra="allow")

    kind: FaultKind
    duration_s: float | None = Field(None, description="end the fault by itself after this long (> 0)")


def requested_fault(body: FaultRequest) -> FaultType:
    """The fault a request asks for; a parameter out of range is a 422 naming it, as pydantic's are."""
    try:
        return Fault(**body.model_dump())
    except FaultError as error:
        value = error.value
        safe = repr(value) if isinstance(value, float) and not math.isfinite(value) else value
        raise RequestValidationError([{"type": "value_error", "loc": ("body", error.field), "msg": str(error),
                                       "input": safe}]) from None


def group_routes(farm: FarmControl) -> APIRouter:
    router = APIRouter()
    topology = farm.config.topology

    def known(name: str) -> str:
        if name not in topology.groups:
            raise HTTPException(404, f"no group named {name!r}; known: {', '.join(topology.groups) or 'none'}")
        return name

    @router.get("/groups")
    def groups() -> list[dict[str, Any]]:
        kinds = {group.name: group.kind for group in farm.config.groups}
        return [{"name": name, "kind": kinds[name], "members": list(members)}
                for name, members in topology.groups.items()]

    @router.post("/groups/{name}/faults", status_code=201)
    async def inject(name: str, body: FaultRequest) -> dict[str, list[dict]]:
        """One fault on every device of the group at once; each device's active faults."""
        members = topology.members(known(name))
        await farm.inject_fault(name, requested_fault(body))
        return {member: farm[member].faults for member in members}

    @router.delete("/groups/{name}/faults")
    async def clear(name: str, kind: FaultKind | None = None) -> dict[str, list[str]]:
        return {"cleared": await farm.clear_faults(known(name), kind)}

    return router
