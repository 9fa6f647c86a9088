"""The shipped catalogue of device models (`catalogue.yaml`), validated with pydantic."""

from __future__ import annotations

from functools import lru_cache
from importlib import resources
from pathlib import Path
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
    serial_number: int | None = Field(None, ge=0, le=0xFFFFFFFF, description="learned profiles only")
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


class AssemblySizes(_Strict):
    output: int = Field(0, ge=0, le=496)
    input: int = Field(0, ge=0, le=496)
    configuration: int = Field(0, ge=0, le=496)


class ReplayEntry(_Strict):
    """A request the object model does not implement, and the reply a capture showed for it;
    matched on service, path and request data exactly (hex)."""

    service: int
    path: str
    data: str = ""
    reply: str


class Model(_Strict):
    kind: Literal["base", "addon"]
    description: str
    identity: IdentityDefaults | None = None
    assemblies: AssemblyIds | None = None
    sizes: AssemblySizes | None = Field(None, description="explicit sizes (learned profiles); else from io")
    io: IoCounts = IoCounts()
    unverified: list[str] = []
    replay: list[ReplayEntry] = []


class Catalogue(_Strict):
    models: dict[str, Model]

    def bases(self) -> list[str]:
        return [name for name, model in self.models.items() if model.kind == "base"]

    def addons(self) -> list[str]:
        return [name for name, model in self.models.items() if model.kind == "addon"]


@lru_cache(maxsize=1)
def _shipped() -> Catalogue:
    text = resources.files("enip_farm.device").joinpath("catalogue.yaml").read_text()
    return Catalogue.model_validate(yaml.safe_load(text))


_profiles: dict[str, Model] = {}  # models from profile files (enip-farm learn), by name


def load_catalogue() -> Catalogue:
    """The shipped catalogue plus every profile file a configuration has named."""
    if not _profiles:
        return _shipped()
    return Catalogue(models={**_shipped().models, **_profiles})


def load_profile(path: str | Path) -> str:
    """Add the models of a profile file (the catalogue's format) and return its base model's name."""
    catalogue = Catalogue.model_validate(yaml.safe_load(Path(path).read_text()))
    bases = [name for name, model in catalogue.models.items() if model.kind == "base"]
    if len(bases) != 1:
        raise ValueError(f"{path}: a profile file holds one base model, found {len(bases)}")
    _profiles.update(catalogue.models)
    return bases[0]
