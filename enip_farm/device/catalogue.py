"""Catalogues of device models: the shipped one (`catalogue.yaml`) and profile files in the same
format (`enip-farm learn`), validated with pydantic.

A `Catalogue` is an immutable value: adding a profile file returns a new catalogue, and a profile
never redefines a model the catalogue already holds (a learned DSQC1030 cannot replace the built-in
one). Who needs models is handed a catalogue; there is no process-wide registry."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from functools import lru_cache
from importlib import resources
from pathlib import Path
from types import MappingProxyType
from typing import Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, model_validator


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


#: The largest assembly a device serves, in bytes (a Forward Open's 9-bit size less the headers).
MAX_ASSEMBLY_SIZE = 496


class AssemblySizes(_Strict):
    output: int = Field(0, ge=0, le=MAX_ASSEMBLY_SIZE)
    input: int = Field(0, ge=0, le=MAX_ASSEMBLY_SIZE)
    configuration: int = Field(0, ge=0, le=MAX_ASSEMBLY_SIZE)


RealTimeFormat = Literal["modeless", "zero length", "heartbeat", "run/idle"]


class ParameterEntry(_Strict):
    """A parameter of an EDS's [Params] (ParamN: instance N of the Parameter Object, class 0x0F)."""

    instance: int = Field(ge=1, le=0xFFFF)
    name: str = ""
    descriptor: int = Field(0, ge=0, le=0xFFFF, description="bit 4: read only")
    data_type: int = Field(ge=0, le=0xFF)
    size: int = Field(ge=1, le=8)
    minimum: float | None = None
    maximum: float | None = None
    default: float | None = None
    link_path: str = Field("", pattern=r"^([0-9A-Fa-f]{2})*$", description="hex")


class ConnectionEntry(_Strict):
    """A class-1 connection a device serves as its EDS declares it (a ConnectionN of [Connection
    Manager], Vol. 1 7-3.6.11): its points, its application data sizes (without the sequence count
    and a run/idle header), real-time formats, connection types and RPI range."""

    entry: str = Field("", description="the EDS keyword, ConnectionN")
    name: str = ""
    kind: Literal["exclusive owner", "input only", "listen only", "redundant owner"]
    configuration: int | None = Field(None, ge=1, description="configuration point; none: the path may omit it")
    o_t: int = Field(ge=1, description="consumed connection point (O->T)")
    t_o: int = Field(ge=1, description="produced connection point (T->O)")
    o_t_size: int = Field(0, ge=0, le=MAX_ASSEMBLY_SIZE)
    t_o_size: int = Field(0, ge=0, le=MAX_ASSEMBLY_SIZE)
    o_t_format: RealTimeFormat = "run/idle"
    t_o_format: RealTimeFormat = "modeless"
    o_t_variable: bool = False
    t_o_variable: bool = False
    t_o_multicast: bool = True
    t_o_point_to_point: bool = True
    configuration_size: int = Field(0, ge=0, le=MAX_ASSEMBLY_SIZE)
    rpi_us: tuple[int, int] | None = Field(None, description="the RPI range the entry allows; none: the device's")


class SafetyDefaults(_Strict):
    """A CIP Safety target (Vol. 5): its safety network number and configuration signature, and
    the null connection point of its SafetyOpens. The model's `assemblies` are its safety
    assemblies: output = the safe outputs a server connection consumes, input = the safe inputs a
    client connection produces."""

    snn: str = Field(pattern=r"^[0-9A-Fa-f]{12}$", description="safety network number, 6 bytes hex as on the wire")
    scid: str = Field("0" * 20, pattern=r"^[0-9A-Fa-f]{20}$",
                      description="SCCRC + SCTS, 10 bytes hex as on the wire; zeros: none held")
    null_point: int = Field(0, ge=0, le=0xFFFF, description="the connection point a server does not produce "
                            "and a client does not consume")
    max_connections: int = Field(8, ge=1, le=64)


class ReplayEntry(_Strict):
    """A request the object model does not implement, and the reply a capture showed for it;
    matched on service, path and request data exactly (hex)."""

    service: int
    path: str
    data: str = ""
    reply: str


class Routing(_Strict):
    """Whether a base answers Multiple Service Packet (0x0A) and Unconnected Send (0x52) addressed
    to itself, or 0x08 (service not supported) as a non-routing adapter such as OpENer does."""

    multiple_service_packet: bool = True
    unconnected_send: bool = True


class Model(_Strict):
    kind: Literal["base", "addon"]
    description: str
    identity: IdentityDefaults | None = None
    assemblies: AssemblyIds | None = None
    sizes: AssemblySizes | None = Field(None, description="explicit sizes (learned profiles); else from io")
    io: IoCounts = IoCounts()
    routing: Routing | None = Field(None, description="a base that does not say gets Routing()'s defaults, "
                                    "listed as unverified")
    unverified: tuple[str, ...] = ()
    replay: tuple[ReplayEntry, ...] = ()
    safety: SafetyDefaults | None = Field(None, description="a CIP Safety target (safety I/O over CIP Safety only)")
    connections: tuple[ConnectionEntry, ...] = Field((), description="every class-1 connection the device serves "
                                                     "(from its EDS); none: the assemblies' roles decide")
    points: dict[int, int] = Field({}, description="every assembly instance the device serves, with its size (EDS)")
    configuration_data: str = Field("", pattern=r"^([0-9A-Fa-f]{2})*$",
                                    description="the configuration assembly's default bytes, hex")
    rpi_us: tuple[int, int] | None = Field(None, description="the RPI range of the device's connection entries")
    parameters: tuple[ParameterEntry, ...] = Field((), description="the EDS's [Params], served by the Parameter "
                                                   "Object (class 0x0F)")

    @model_validator(mode="before")
    @classmethod
    def _default_routing_is_unverified(cls, data: Any) -> Any:
        """A base model that does not say how it routes answers as the farm does by default, which
        nobody has checked against it: `routing` joins its unverified placeholders."""
        if isinstance(data, dict) and data.get("kind") == "base" and data.get("routing") is None:
            unverified = tuple(data.get("unverified") or ())
            if "routing" not in unverified:
                data = {**data, "unverified": (*unverified, "routing")}
        return data

    @property
    def effective_routing(self) -> Routing:
        return self.routing or Routing()


class CatalogueFile(_Strict):
    """The format of `catalogue.yaml` and of a profile file."""

    models: dict[str, Model]


#: The origin of the shipped catalogue's models.
BUILT_IN = "built in"


@dataclass(frozen=True)
class Catalogue:
    """Models by name, each with its origin (`BUILT_IN` or the profile file it came from)."""

    models: Mapping[str, Model]
    origins: Mapping[str, str] = field(default_factory=dict)
    #: Profile files of another format than YAML, by suffix (".eds"): a function that makes the
    #: catalogue document of one (the layer that reads the format hands it in).
    readers: Mapping[str, Callable[[Path], Any]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        origins = {name: self.origins.get(name, BUILT_IN) for name in self.models}
        object.__setattr__(self, "models", MappingProxyType(dict(self.models)))
        object.__setattr__(self, "origins", MappingProxyType(origins))

    @classmethod
    def from_document(cls, data: Any, origin: str = BUILT_IN) -> Catalogue:
        """Raises pydantic.ValidationError if `data` is not in the catalogue's format."""
        models = CatalogueFile.model_validate(data).models
        return cls(models, {name: origin for name in models})

    def bases(self) -> list[str]:
        return [name for name, model in self.models.items() if model.kind == "base"]

    def addons(self) -> list[str]:
        return [name for name, model in self.models.items() if model.kind == "addon"]

    def with_models(self, models: Mapping[str, Model], origin: str) -> Catalogue:
        """A new catalogue with `models` added. Raises ValueError if one of them would redefine a
        model of this catalogue (one from the same origin may be added again unchanged)."""
        for name, model in models.items():
            if name in self.models and (self.origins[name] != origin or self.models[name] != model):
                where = "the built-in model" if self.origins[name] == BUILT_IN else f"the model of {self.origins[name]}"
                raise ValueError(f"profile {origin} defines model {name!r}, which would replace {where}: "
                                 "give the profile's model another name (enip-farm learn --name)")
        return Catalogue({**self.models, **models}, {**self.origins, **{name: origin for name in models}},
                         self.readers)

    def with_readers(self, readers: Mapping[str, Callable[[Path], Any]]) -> Catalogue:
        """A new catalogue that also reads profile files of these suffixes (".eds") with these functions."""
        return Catalogue(self.models, self.origins, {**self.readers, **readers})

    def with_profile(self, path: str | Path) -> tuple[Catalogue, str]:
        """A new catalogue with the models of a profile file, and the name of its base model.
        Raises OSError, yaml.YAMLError, pydantic.ValidationError or ValueError."""
        reader = self.readers.get(Path(path).suffix.lower())
        document = reader(Path(path)) if reader is not None else yaml.safe_load(Path(path).read_text())
        profile = Catalogue.from_document(document, str(path))
        bases = profile.bases()
        if len(bases) != 1:
            raise ValueError(f"profile {path} holds one base model, found {len(bases)}")
        return self.with_models(profile.models, str(path)), bases[0]


@lru_cache(maxsize=1)
def shipped_catalogue() -> Catalogue:
    """The models shipped with the package (immutable, so one copy serves every caller)."""
    text = resources.files("enip_farm.device").joinpath("catalogue.yaml").read_text()
    return Catalogue.from_document(yaml.safe_load(text))
