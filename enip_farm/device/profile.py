"""A device's resolved profile: its catalogue model and add-ons merged with its configuration.

This is where sizes are derived (base I/O first, then each add-on in slot order) and where the
placeholders that a configuration did not override are remembered as unverified.
"""

from __future__ import annotations

import ipaddress
import zlib
from dataclasses import dataclass

from enip_farm.config import DeviceConfig, ImplicitConfig, LimitsConfig
from enip_farm.device.catalogue import Catalogue, ConnectionEntry, IoCounts, ParameterEntry, Routing
from enip_farm.device.named_signals import NamedSignal, named_signal


@dataclass(frozen=True)
class AssemblySpec:
    role: str  # "output", "input" or "configuration"
    instance_id: int
    size: int
    settable: bool


@dataclass(frozen=True)
class ModuleSlot:
    """Where one module's channels sit in the assemblies (byte offsets)."""

    slot: int
    model: str
    io: IoCounts
    input_offset: int
    output_offset: int


@dataclass(frozen=True)
class SafetyProfile:
    """A CIP Safety target's identity: TUNID (safety network number + node address), SCID, and the
    null connection point of its SafetyOpens."""

    snn: bytes
    node_address: int
    scid: bytes
    null_point: int
    max_connections: int


@dataclass(frozen=True)
class DeviceProfile:
    name: str
    address: str
    model: str
    addons: tuple[str, ...]
    vendor_id: int
    device_type: int
    product_code: int
    revision: tuple[int, int]
    serial_number: int
    product_name: str
    assemblies: tuple[AssemblySpec, ...]
    modules: tuple[ModuleSlot, ...]
    mac: bytes
    netmask: str
    gateway: str
    host_name: str
    unverified: tuple[str, ...]
    implicit: ImplicitConfig
    limits: LimitsConfig
    encapsulation_inactivity_timeout_s: int
    input_only_point: int | None
    listen_only_point: int | None
    multicast_group: str
    replay: tuple = ()  # (service, path, data, reply) of a learned profile
    routing: Routing = Routing()  # Multiple Service Packet and Unconnected Send to itself, or 0x08
    reset_time_s: float = 1.0  # Identity Reset: how long the device does not answer
    select_acd: bool = False  # TCP/IP attribute 10 out of box: ACD on (unverified for ABB's modules)
    multicast_configured: bool = False  # the multicast group comes from the configuration
    signals: tuple[NamedSignal, ...] = ()  # named signals (EIO_SIGNAL), beside DI1.., DO1..
    safety: SafetyProfile | None = None  # a CIP Safety target: its assemblies are safety assemblies
    connections: tuple[ConnectionEntry, ...] = ()  # an EDS's class-1 connections: only these are admitted
    configuration_data: bytes = b""  # the configuration assembly's default bytes (an EDS's)
    parameters: tuple[ParameterEntry, ...] = ()  # an EDS's [Params]: the Parameter Object's instances
    model_file: str = ""  # the profile file (a learned profile, an EDS) the configuration names as the model

    def assembly(self, role: str) -> AssemblySpec | None:
        return next((a for a in self.assemblies if a.role == role), None)

    @property
    def input_size(self) -> int:
        spec = self.assembly("input")
        return spec.size if spec else 0

    @property
    def output_size(self) -> int:
        spec = self.assembly("output")
        return spec.size if spec else 0


def _address_bytes(address: str) -> bytes:
    return bytes(int(part) for part in address.split("."))


#: CIP multicast address allocation (Vol. 2, 3-5.3): base 239.192.1.0, 32 groups per device.
_MULTICAST_BASE = int(ipaddress.IPv4Address("239.192.1.0"))


def default_multicast_group(address: str, netmask: str) -> str:
    host_id = int(ipaddress.IPv4Address(address)) & ~int(ipaddress.IPv4Address(netmask)) & 0xFFFFFFFF
    return str(ipaddress.IPv4Address(_MULTICAST_BASE + ((host_id - 1) & 0x3FF) * 32))


def resolve(config: DeviceConfig, catalogue: Catalogue) -> DeviceProfile:
    """The profile of one device whose model and add-ons `catalogue` holds (see device/build.py,
    which checks that first and names profile files' models)."""
    model = catalogue.models[config.model]
    assert model.identity is not None, f"base model {config.model} has no identity in the catalogue"
    identity = config.identity
    overridden = {name for name, value in identity.model_dump().items() if value is not None}
    overridden |= {f"assemblies.{name}" for name, value in config.assemblies.model_dump().items()
                   if value is not None}
    overridden |= {f"safety.{name}" for name, value in config.safety.model_dump().items() if value is not None}
    overridden |= {"select_acd"} & config.model_fields_set  # the device's own out-of-box SelectAcd
    unverified = [f"{config.model}.{item}" for item in model.unverified
                  if item.removeprefix("identity.") not in overridden and item not in overridden]

    modules = []
    input_offset = output_offset = 0
    for slot, name in enumerate((config.model, *config.addons)):
        io = catalogue.models[name].io
        modules.append(ModuleSlot(slot, name, io, input_offset, output_offset))
        input_offset += io.input_size
        output_offset += io.output_size
        if slot:
            unverified += [f"{name}.{item}" for item in catalogue.models[name].unverified]

    assemblies: list[AssemblySpec] = []
    overrides = config.assemblies
    if model.assemblies is not None or overrides.input or overrides.output:
        ids = model.assemblies
        sizes = {"output": output_offset, "input": input_offset, "configuration": 0}
        if model.sizes is not None:
            sizes = model.sizes.model_dump()
        for role in ("output", "input", "configuration"):
            instance_id = getattr(overrides, role) or (getattr(ids, role) if ids else None)
            if instance_id is None:
                continue
            size = getattr(overrides, f"{role}_size")
            # a safety target's safe outputs are written by its safety connection only
            settable = (role != "input" or config.writable_inputs) and not (model.safety and role == "output")
            assemblies.append(AssemblySpec(role, instance_id, sizes[role] if size is None else size, settable))

    taken = {spec.instance_id for spec in assemblies}
    produced = {entry.t_o for entry in model.connections}
    for instance_id, size in model.points.items():  # every other assembly an EDS's connections name
        if instance_id not in taken:
            assemblies.append(AssemblySpec(f"point {instance_id}", instance_id, size,
                                           instance_id not in produced or config.writable_inputs))

    address = str(config.address)
    raw = _address_bytes(address)
    safety = None
    if model.safety is not None:
        own = config.safety
        safety = SafetyProfile(
            snn=bytes.fromhex(own.snn or model.safety.snn),
            node_address=own.node_address if own.node_address is not None else int(ipaddress.IPv4Address(address)),
            scid=bytes.fromhex(own.scid or model.safety.scid), null_point=model.safety.null_point,
            max_connections=model.safety.max_connections)
    mac = bytes.fromhex(config.mac.replace(":", "").replace("-", "")) if config.mac else b"\x02\x00" + raw
    return DeviceProfile(
        name=config.name,
        address=address,
        model=config.model,
        addons=tuple(config.addons),
        vendor_id=identity.vendor_id if identity.vendor_id is not None else model.identity.vendor_id,
        device_type=identity.device_type if identity.device_type is not None else model.identity.device_type,
        product_code=identity.product_code if identity.product_code is not None else model.identity.product_code,
        revision=identity.revision or model.identity.revision,
        serial_number=identity.serial_number if identity.serial_number is not None else (
            model.identity.serial_number if model.identity.serial_number is not None else zlib.crc32(raw)),
        product_name=identity.product_name or model.identity.product_name,
        assemblies=tuple(assemblies),
        modules=tuple(modules),
        mac=mac,
        netmask=str(config.netmask),
        gateway=str(config.gateway),
        host_name=config.host_name,
        unverified=tuple(unverified),
        implicit=config.implicit,
        limits=config.limits,
        encapsulation_inactivity_timeout_s=config.encapsulation_inactivity_timeout_s,
        input_only_point=overrides.input_only or (model.assemblies.input_only if model.assemblies else None),
        listen_only_point=overrides.listen_only or (model.assemblies.listen_only if model.assemblies else None),
        multicast_group=str(config.implicit.multicast_group or default_multicast_group(address, str(config.netmask))),
        replay=tuple((e.service, bytes.fromhex(e.path), bytes.fromhex(e.data), bytes.fromhex(e.reply))
                     for e in model.replay),
        signals=tuple(named_signal(signal) for signal in config.signals),
        routing=model.effective_routing,
        reset_time_s=config.reset_time_s,
        select_acd=config.select_acd,
        multicast_configured=config.implicit.multicast_group is not None,
        safety=safety,
        connections=model.connections,
        configuration_data=bytes.fromhex(model.configuration_data),
        parameters=model.parameters,
    )
