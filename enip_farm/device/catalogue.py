"""The shipped catalogue of device models (`catalogue.yaml`), validated with pydantic."""

from __future__ import annotations

from functools import lru_cache
from importlib import resources
from typing import Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class IoCounts(_Strict):
    di: int = Field(0, ge=0)
    do: int = Field(0, ge=0)
    ai: int = Field(0, ge=0)
    ao: int = Field(0, ge=0)

    @property
    def input_size(self) -> int:
        return (self.di + 7) // 8 + 2 * self.ai

    @property
    def output_size(self) -> int:
        return (self.do + 7) // 8 + 2 * self.ao


class IdentityDefaults(_Strict):
    vendor_id: int = Field(ge=0, le=0xFFFF)
    device_type: int = Field(ge=0, le=0xFFFF)
    product_code: int = Field(ge=0, le=0xFFFF)
    revision: tuple[int, int]
    product_name: str = Field(max_length=32)


class AssemblyIds(_Strict):
    output: int = Field(ge=1)
    input: int = Field(ge=1)
    configuration: int = Field(ge=1)
    input_only: int | None = Field(None, ge=1, description="heartbeat connection point, input-only connections")
    listen_only: int | None = Field(None, ge=1, description="heartbeat connection point, listen-only connections")


class Model(_Strict):
    kind: Literal["base", "addon"]
    description: str
    identity: IdentityDefaults | None = None
    assemblies: AssemblyIds | None = None
    io: IoCounts = IoCounts()
    unverified: list[str] = []


class Catalogue(_Strict):
    models: dict[str, Model]

    def bases(self) -> list[str]:
        return [name for name, model in self.models.items() if model.kind == "base"]

    def addons(self) -> list[str]:
        return [name for name, model in self.models.items() if model.kind == "addon"]


@lru_cache(maxsize=1)
def load_catalogue() -> Catalogue:
    text = resources.files("enip_farm.device").joinpath("catalogue.yaml").read_text()
    return Catalogue.model_validate(yaml.safe_load(text))
