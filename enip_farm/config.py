"""Cell configuration: YAML in, validated pydantic models out. Pure schema: field formats, `count`
expansion, unique names and addresses. Whether the models, add-ons and wiring exist is checked
when devices are built from it against a catalogue (`enip_farm.device.build`).

Errors are reported as `ConfigError` with one line per problem naming the file, the device and the
field, never as a traceback.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from ipaddress import IPv4Address, IPv4Network
from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    PrivateAttr,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)
from pydantic_core import InitErrorDetails, PydanticCustomError

from enip_farm.bounds import BoundsConfig
from enip_farm.config_errors import describe, did_you_mean, duplicates, line_map, line_of, not_a_cell, yaml_problem
from enip_farm.config_errors import device_location as device_location  # where it has always been imported from
from enip_farm.topology import GroupConfig, Topology, resolve, subnet_problem

_MAC = re.compile(r"^([0-9A-Fa-f]{2}[:-]){5}[0-9A-Fa-f]{2}$")

#: An attribute of a RobotWare EIO.cfg entry kept as it was: a string, a number, or true for a flag.
EioValue = str | int | float | bool


class ConfigError(Exception):
    """A configuration that cannot be served; the message is meant for the user as it is."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class IdentityConfig(_Strict):
    """Per-device overrides of the model's identity (from your EDS file, EIO.cfg or a capture)."""

    vendor_id: int | None = Field(None, ge=0, le=0xFFFF)
    device_type: int | None = Field(None, ge=0, le=0xFFFF)
    product_code: int | None = Field(None, ge=0, le=0xFFFF)
    revision: tuple[int, int] | None = None
    serial_number: int | None = Field(None, ge=0, le=0xFFFFFFFF)
    product_name: str | None = Field(None, max_length=32)

    @field_validator("revision")
    @classmethod
    def _revision_bytes(cls, value: tuple[int, int] | None) -> tuple[int, int] | None:
        if value is not None and not (1 <= value[0] <= 0x7F and 0 <= value[1] <= 0xFF):
            raise ValueError("revision is [major 1..127, minor 0..255]")
        return value


class AssemblyConfig(_Strict):
    """Per-device overrides of assembly instance ids and sizes in bytes."""

    output: int | None = Field(None, ge=1, le=0xFFFF)
    input: int | None = Field(None, ge=1, le=0xFFFF)
    configuration: int | None = Field(None, ge=1, le=0xFFFF)
    input_only: int | None = Field(None, ge=1, le=0xFFFF, description="heartbeat point of input-only connections")
    listen_only: int | None = Field(None, ge=1, le=0xFFFF, description="heartbeat point of listen-only connections")
    output_size: int | None = Field(None, ge=0, le=496)
    input_size: int | None = Field(None, ge=0, le=496)
    configuration_size: int | None = Field(None, ge=0, le=496)


class ImplicitConfig(_Strict):
    """Class-1 and class-3 connection policy of a device: the farm's defaults (unverified, unpublished)."""

    rpi_min_us: int = Field(2_000, ge=100, description="smallest accepted RPI, microseconds")
    rpi_max_us: int = Field(10_000_000, le=0xFFFFFFFF, description="largest accepted RPI, microseconds")
    max_class1_connections: int = Field(8, ge=0, le=256)
    max_class3_connections: int = Field(6, ge=0, le=256)
    class3_rpi_min_us: int = Field(1_000, ge=1, description="smallest accepted RPI of a class-3 (explicit) "
                                   "connection, microseconds; its timeout is RPI x 2^(2 + multiplier)")
    class3_rpi_max_us: int = Field(60_000_000, le=0xFFFFFFFF, description="largest accepted class-3 RPI, "
                                   "microseconds (pycomm3 asks for 2.1 s, cpppo for 2 s)")
    idle_state: Literal["off", "hold"] = Field("off", description="outputs on Idle and on Forward Close")
    fault_state: Literal["off", "hold"] = Field("off", description="outputs when a connection times out")
    explicit_output_writes_while_owned: bool = Field(
        False, description="let Set Attribute Single write an output assembly an exclusive owner holds")
    multicast_group: IPv4Address | None = Field(None, description="T->O multicast group; default per CIP "
                                                "allocation (239.192.1.0 + 32 x (host id - 1))")
    first_watchdog_s: float = Field(10.0, ge=0, description="the watchdog before the first O->T packet "
                                    "is at least this long (OpENer uses 10 s)")

    @model_validator(mode="after")
    def _range(self) -> ImplicitConfig:
        if self.rpi_min_us > self.rpi_max_us:
            raise ValueError("rpi_min_us is larger than rpi_max_us")
        if self.class3_rpi_min_us > self.class3_rpi_max_us:
            raise ValueError("class3_rpi_min_us is larger than class3_rpi_max_us")
        return self


class LimitsConfig(_Strict):
    """What one device accepts at once; the farm's own guards, not the module's (unpublished)."""

    max_tcp_connections: int = Field(8192, ge=1, le=65535, description="TCP connections at once; more are "
                                     "closed at once (one log line, rate-limited)")
    max_sessions: int = Field(8192, ge=1, le=65535, description="registered sessions at once; more get "
                              "encapsulation status 0x0002 (insufficient memory)")


class SafetyConfig(_Strict):
    """Per-device overrides of a safety model's CIP Safety identity (from the safety configuration
    of your controller): safety network number and configuration signature, hex as on the wire."""

    snn: str | None = Field(None, pattern=r"^[0-9A-Fa-f]{12}$", description="safety network number (6 bytes hex)")
    node_address: int | None = Field(None, ge=0, le=0xFFFFFFFF, description="TUNID node address; default: the "
                                     "device's IPv4 address as a UDINT")
    scid: str | None = Field(None, pattern=r"^[0-9A-Fa-f]{20}$", description="SCCRC + SCTS (10 bytes hex); "
                             "zeros: no signature held, only SafetyOpens with a zero SCID are taken")


class SignalConfig(_Strict):
    """A named signal, as RobotWare's EIO_SIGNAL entry gives it (`enip-farm eio import` writes these)."""

    name: str = Field(pattern=r"^[A-Za-z][A-Za-z0-9_]{0,63}$")
    type: Literal["DI", "DO", "GI", "GO", "AI", "AO"]
    device_map: str = Field(description='0-based bit positions in the input (DI/GI/AI) or output (DO/GO/AO) '
                            'image, least significant first: "3", "8-15", "0-7,16-23"')
    invert: bool = Field(False, description="DI/DO: the physical bit is the inverse of the value")
    enc_type: Literal["UNSIGNED", "TWO_COMP"] = Field("UNSIGNED", description="AI/AO encoding of the raw value")
    min_log: float | None = Field(None, allow_inf_nan=False)
    max_log: float | None = Field(None, allow_inf_nan=False)
    min_phys: float | None = Field(None, allow_inf_nan=False)
    max_phys: float | None = Field(None, allow_inf_nan=False)
    min_phys_limit: float | None = Field(None, allow_inf_nan=False)
    max_phys_limit: float | None = Field(None, allow_inf_nan=False)
    min_bit_val: float | None = Field(None, allow_inf_nan=False)
    max_bit_val: float | None = Field(None, allow_inf_nan=False)
    extra: dict[str, EioValue] = Field({}, description="other EIO_SIGNAL attributes (Label, Category, Access...), "
                                       "kept as they were for `enip-farm eio export`")


class DeviceConfig(_Strict):
    name: str = Field(pattern=r"^[A-Za-z0-9_.{}-]{1,64}$")
    address: IPv4Address
    count: int = Field(1, ge=1, le=65536, description="this many devices: {n} in the name is 1-based, "
                       "addresses increase from the first")
    model: str
    addons: list[str] = []
    identity: IdentityConfig = IdentityConfig()
    assemblies: AssemblyConfig = AssemblyConfig()
    writable_inputs: bool = Field(False, description="let clients write the input assembly (test rigs)")
    netmask: IPv4Address = IPv4Address("255.255.255.0")
    gateway: IPv4Address = IPv4Address("0.0.0.0")
    mac: str | None = Field(None, description="default: 02:00 followed by the address's four bytes")
    host_name: str = ""
    implicit: ImplicitConfig = ImplicitConfig()
    encapsulation_inactivity_timeout_s: int = Field(120, ge=0, le=3600, description=(
        "TCP/IP object attribute 13: a TCP connection with no whole request for this long is closed (0 = never)"))
    limits: LimitsConfig = LimitsConfig()
    reset_time_s: float = Field(
        1.0, ge=0, le=3600, allow_inf_nan=False, description="Identity Reset: how long the device does not "
        "answer (no TCP listener, UDP dropped) after it has replied, as a module restarts")
    duplicate_address: bool = Field(False, description="on an earlier device's address: ACD finds it taken")
    select_acd: bool = Field(False, description="TCP/IP attribute 10 out of box: ACD on (ABB's: UNVERIFIED)")
    signals: list[SignalConfig] = Field([], description="named signals (RobotWare EIO_SIGNAL) beside DI1.., DO1..")
    safety: SafetyConfig = SafetyConfig()
    bounds: BoundsConfig = Field(BoundsConfig(), description="the report's bounds for this device, over the cell's")
    extra: dict[str, EioValue] = Field({}, description="other attributes of the controller's ETHERNETIP_DEVICE "
                                       "entry (VendorName, Label...), kept as they were for `enip-farm eio export`")
    _entry: int = PrivateAttr(0)

    @field_validator("model")
    @classmethod
    def _profile_path(cls, value: str, info: ValidationInfo) -> str:
        """A profile file (e.g. from `enip-farm learn`) is named relative to the configuration's
        directory; it is read when devices are built. A catalogue model is checked here when the
        catalogue's names are given (`parse_config(known=...)`), else when devices are built."""
        if is_profile_path(value):
            return value if Path(value).is_absolute() else str(Path((info.context or {}).get("base_dir", ".")) / value)
        bases = ((info.context or {}).get("known") or ((), ()))[0]
        if bases and value not in bases:
            raise ValueError(f"unknown base model {value!r}{did_you_mean(value, bases)}; known: {', '.join(bases)}")
        return value

    @field_validator("addons")
    @classmethod
    def _known_addons(cls, value: list[str], info: ValidationInfo) -> list[str]:
        addons = ((info.context or {}).get("known") or ((), ()))[1]
        for addon in value if addons else ():
            if addon not in addons:
                raise ValueError(f"unknown add-on {addon!r}{did_you_mean(addon, addons)}; known: {', '.join(addons)}")
        return value

    @field_validator("mac")
    @classmethod
    def _mac_format(cls, value: str | None) -> str | None:
        if value is not None and not _MAC.match(value):
            raise ValueError("MAC address must look like 02:00:7f:00:0a:01")
        return value

    @field_validator("netmask")
    @classmethod
    def _netmask_format(cls, value: IPv4Address) -> IPv4Address:
        try:
            IPv4Network(f"0.0.0.0/{value}")
        except ValueError:
            raise ValueError(f"{value} is not a netmask (ones, then zeros: 255.255.255.0, 255.255.0.0, ...)") from None
        return value

    @model_validator(mode="after")
    def _template(self) -> DeviceConfig:
        if self.count > 1 and "{n}" not in self.name:
            raise ValueError(f"name {self.name!r} needs {{n}} to number {self.count} devices")
        if "{" in self.name.replace("{n}", "") or "}" in self.name.replace("{n}", ""):
            raise ValueError("the only placeholder in a name is {n}")
        if int(self.address) + self.count - 1 > 0xFFFFFFFF:
            raise ValueError("the addresses run past 255.255.255.255")
        problem = subnet_problem(self.address, self.count, self.netmask)
        if problem:
            raise ValueError(problem)
        seen: dict[str, str] = {}
        for signal in self.signals:
            if signal.name.casefold() in seen:
                raise ValueError(f"signals {seen[signal.name.casefold()]!r} and {signal.name!r} have the same name")
            seen[signal.name.casefold()] = signal.name
        return self

    def expand(self) -> list[DeviceConfig]:
        """The devices this entry stands for: {n} = 1..count, addresses from the first upward."""
        if self.count == 1 and "{n}" not in self.name:
            return [self]
        return [self.model_copy(update={"name": self.name.replace("{n}", str(n + 1)),
                                        "address": self.address + n, "count": 1}) for n in range(self.count)]

    @property
    def entry(self) -> int:
        """The index of the entry in the configuration's `devices` list this device came from."""
        return self._entry


class WireConfig(_Strict):
    """Outputs of one device wired to inputs of another, e.g. harness.DO1-16 -> robot1.DI1-16."""

    model_config = ConfigDict(extra="forbid", populate_by_name=True)
    source: str = Field(alias="from", description="DEVICE.DOn[-m] or DEVICE.AOn[-m]")
    target: str = Field(alias="to", description="DEVICE.DIn[-m] or DEVICE.AIn[-m]")


class RuleConfig(_Strict):
    """When a bit rises or falls, set another bit (optionally after a delay)."""

    when: str = Field(description="DEVICE.SIGNAL, one bit")
    edge: Literal["rises", "falls"] = "rises"
    set: str = Field(description="DEVICE.SIGNAL, one bit")
    value: Literal[0, 1] = 1
    delay_ms: float = Field(0.0, ge=0)


#: The share of a core a worker's cyclic I/O budget is for (cip/budget.py). Unverified: a choice.
BUDGET_UTILISATION = 0.5


class CyclicIoConfig(_Strict):
    """What the farm's cyclic I/O thread (one per worker) may carry."""

    budget_datagrams_per_s: int | Literal["auto"] = Field(
        "auto", description="class-1 datagrams/s (O->T plus T->O) one worker admits connections for, past it "
        f"0x01/0x0113; auto: measured at start for {BUDGET_UTILISATION:.0%} of a core, lowered to what it spends")
    measure: bool = Field(True, description="measure every O->T stream for the report (cip/o_t_measure.py)")
    native: Literal["auto", "off"] | bool = Field("auto", description="native class-1 path: auto (true), off (false)")
    realtime_priority: int = Field(0, ge=0, le=99, description="the cyclic I/O thread's SCHED_FIFO priority; 0: none")
    @field_validator("budget_datagrams_per_s")
    @classmethod
    def _positive(cls, value: int | str) -> int | str:
        if isinstance(value, int) and value <= 0:
            raise ValueError("must be positive, or auto")
        return value


class FarmConfig(_Strict):
    devices: list[DeviceConfig] = Field(min_length=1)
    groups: list[GroupConfig] = Field([], description="named groups of devices that fail together (topology.py)")
    cyclic_io: CyclicIoConfig = CyclicIoConfig()
    discovery: bool = Field(True, description="answer broadcast ListIdentity on 0.0.0.0:44818")
    max_tcp_connections: int = Field(60000, ge=1, description="TCP connections of all devices at once (also "
                                     "bounded by the open-file limit)")
    wires: list[WireConfig] = []
    rules: list[RuleConfig] = []
    bounds: BoundsConfig = Field(BoundsConfig(), description="the report's bounds (enip_farm/bounds.py)")
    _source: str = PrivateAttr("<config>")
    _topology: Topology = PrivateAttr(default_factory=Topology)

    @property
    def topology(self) -> Topology:
        """The groups resolved to their devices (`targets(name)`: a device's or a group's devices)."""
        return self._topology

    @property
    def source(self) -> str:
        """Where the configuration came from (a file name), for messages."""
        return self._source

    @model_validator(mode="after")
    def _expand(self) -> FarmConfig:
        """Expand `count` entries, then refuse duplicate names and addresses."""
        devices = []
        for index, entry in enumerate(self.devices):
            for device in entry.expand():
                if device is entry:  # an entry may be shared with another configuration
                    device = device.model_copy()
                device._entry = index
                devices.append(device)
        self.devices = devices
        errors: list[InitErrorDetails] = []  # every duplicate, one line each
        for field in ("name", "address"):
            seen: dict[Any, DeviceConfig] = {}
            for device in self.devices:
                value = getattr(device, field)
                first = seen.setdefault(value, device)
                if first is not device and not (field == "address" and device.duplicate_address):
                    message = f"{value} is taken by {device_location(first.entry, first.name)}" + (
                        f" (here by {device.name!r})" if field == "address" else "")
                    errors.append(InitErrorDetails(type=PydanticCustomError("duplicate", message),
                                                   loc=("devices", device.entry, field), input=str(value)))
        self._topology, problems = resolve(self.groups, ((d.name, d.address) for d in self.devices))
        errors += [InitErrorDetails(type=PydanticCustomError("group", message), loc=("groups", index, *where),
                                    input=value) for index, where, message, value in problems]
        if errors:
            raise ValidationError.from_exception_data(type(self).__name__, errors)
        return self


def as_config(source: FarmConfig | Mapping[str, Any] | str | Path) -> FarmConfig:
    """A configuration from a FarmConfig, a dict (as a YAML file holds it) or a file path."""
    if isinstance(source, FarmConfig):
        return source
    if isinstance(source, Mapping):
        return parse_config(dict(source))
    if isinstance(source, (str, Path)):
        return load_config(source)
    raise TypeError(f"a configuration is a FarmConfig, a dict or a file path, not {type(source).__name__}")


def is_profile_path(model: str) -> bool:
    """A device's model names a profile file (the catalogue's format, or a vendor's EDS file read
    as `enip-farm eds import` reads it) rather than a catalogue model."""
    return model.endswith((".yaml", ".yml", ".eds", ".EDS"))


def parse_config(data: Any, source: str = "<config>", base_dir: str | Path = ".", text: str | None = None,
                 known: tuple[list[str], list[str]] | None = None) -> FarmConfig:
    """`source` names the configuration in messages; `base_dir`: where profile files named by a
    device's model are looked up; `text`: the YAML it was read from, whose lines the messages
    give; `known`: the catalogue's base models and add-ons, checked with everything else. Every
    problem is one line of the ConfigError, in the file's order (config_errors.py)."""
    problem = not_a_cell(source, data)
    if problem:
        raise ConfigError(problem)
    context: dict[str, Any] = {"base_dir": str(base_dir), "known": known}
    try:
        config = FarmConfig.model_validate(data, context=context)
    except ValidationError as error:
        errors: list[dict[str, Any]] = list(error.errors())
        if not any(e["type"] == "duplicate" for e in errors):  # told once every device is valid: tell them now
            errors += [{"loc": loc, "msg": message, "type": "duplicate"} for loc, message in duplicates(data)]
        lines = line_map(text) if text is not None else {}
        told = [(line_of(lines, tuple(e["loc"])), describe(e, data, FarmConfig)) for e in errors]
        told.sort(key=lambda item: item[0] or 0)
        raise ConfigError("\n".join(f"{source}:{line}: {message}" if line else f"{source}: {message}"
                                    for line, message in dict.fromkeys(told))) from None
    config._source = source
    return config


def load_config(path: str | Path, known: tuple[list[str], list[str]] | None = None) -> FarmConfig:
    """A configuration file (see `parse_config`); a YAML error is one line at its line and column."""
    path = Path(path)
    try:
        text = path.read_text()
        data = yaml.safe_load(text)
    except OSError as error:
        raise ConfigError(f"{path}: cannot read: {error.strerror}") from None
    except yaml.YAMLError as error:
        raise ConfigError(yaml_problem(str(path), error)) from None
    return parse_config(data, str(path), path.parent, text, known)


def default_config_path() -> Path:
    """The default cell shipped in the package (also at configs/default-cell.yaml in the repo)."""
    from importlib import resources

    return Path(str(resources.files("enip_farm").joinpath("configs/default-cell.yaml")))
