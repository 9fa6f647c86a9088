"""The EIO.cfg entries a controller needs to scan the farm's devices: one `ETHERNETIP_DEVICE` per
device (address, identity as the device answers it, assembly instances and sizes, connection
priority, and the attributes the device's `extra` kept) and one `EIO_SIGNAL` per named signal,
in RobotWare's format (`eio/cfg.py`); a group of kind network is an `INDUSTRIAL_NETWORK` entry.
`eio import` of the output gives back the same devices and
signals (add-on modules aside: EIO.cfg has no place for them, only for the sizes they make)."""

from __future__ import annotations

from enip_farm.config import DeviceConfig, FarmConfig, SignalConfig
from enip_farm.device.build import build_profiles
from enip_farm.device.catalogue import Catalogue
from enip_farm.device.profile import DeviceProfile
from enip_farm.eio.cfg import Value, write_cfg
from enip_farm.eio.eio_signal import ANALOG_FIELDS
from enip_farm.eio.ethernetip_device import DEFAULT_CONNECTION_PRIORITY, DEVICE_FIELDS

#: The header of an exported file: the EIO domain and format version, no RobotWare version.
HEADER = "EIO:CFG_1.0::"
#: Attributes of a device entry written first, from `extra`, in the order RobotWare's files have them.
_DEVICE_LEADING = ("VendorName",)
_DEVICE_OWN = frozenset({"Name", "Address", "ConnectionPriority", *DEVICE_FIELDS})
_SIGNAL_OWN = frozenset({"Name", "SignalType", "Device", "DeviceMap", "Invert", "EncType", *ANALOG_FIELDS})


class ExportError(ValueError):
    """A configuration whose entries EIO.cfg cannot hold; the message names the device and field."""


def export_eio(config: FarmConfig, catalogue: Catalogue) -> str:
    """The EIO.cfg text for every device of `config`. Raises ConfigError for a configuration
    that does not build, ExportError for a value the format cannot hold."""
    profiles = build_profiles(config, catalogue)
    devices: list[list[tuple[str, Value]]] = []
    signals: list[list[tuple[str, Value]]] = []
    for device, profile in zip(config.devices, profiles, strict=True):
        devices.append(device_entry(device, profile))
        signals += [signal_entry(device.name, signal) for signal in device.signals]
    networks = [[("Name", group.name)] for group in config.groups if group.kind == "network"]
    sections = ([("INDUSTRIAL_NETWORK", networks)] if networks else []) + [("ETHERNETIP_DEVICE", devices)] + (
        [("EIO_SIGNAL", signals)] if signals else [])
    try:
        return write_cfg(HEADER, sections)
    except ValueError as error:
        raise ExportError(str(error)) from None


def device_entry(device: DeviceConfig, profile: DeviceProfile) -> list[tuple[str, Value]]:
    """The ETHERNETIP_DEVICE attributes of one device, as it answers over CIP."""
    extra = dict(device.extra)
    own = sorted(_DEVICE_OWN.intersection(extra) - {"ConnectionPriority"})
    if own:
        raise ExportError(f"device {device.name!r}: extra holds {', '.join(own)}, which the export writes from "
                          "the device itself (identity:, assemblies:, address)")
    attributes: list[tuple[str, Value]] = [("Name", device.name)]
    attributes += [(name, extra.pop(name)) for name in _DEVICE_LEADING if name in extra]
    if f"{profile.model}.identity.product_name" not in profile.unverified:  # a placeholder is no name to give
        attributes.append(("ProductName", profile.product_name))
    if "Label" in extra:
        attributes.append(("Label", extra.pop("Label")))
    attributes += [("Address", profile.address), ("VendorId", profile.vendor_id),
                   ("ProductCode", profile.product_code), ("DeviceType", profile.device_type)]
    # a CIP Safety target's assemblies are for safety connections, not for a class-1 scanner
    roles = {spec.role: spec for spec in profile.assemblies} if profile.safety is None else {}
    for role, attribute in (("output", "OutputAssembly"), ("input", "InputAssembly"),
                            ("configuration", "ConfigurationAssembly")):
        if role in roles:
            attributes.append((attribute, roles[role].instance_id))
    if roles:
        attributes.append(("ConnectionPriority", extra.pop("ConnectionPriority", DEFAULT_CONNECTION_PRIORITY)))
    for role, attribute in (("output", "OutputSize"), ("input", "InputSize")):
        if role in roles:
            attributes.append((attribute, roles[role].size))
    return attributes + list(extra.items())


def signal_entry(device: str, signal: SignalConfig) -> list[tuple[str, Value]]:
    """The EIO_SIGNAL attributes of one named signal."""
    extra = dict(signal.extra)
    own = sorted(_SIGNAL_OWN.intersection(extra))
    if own:
        raise ExportError(f"device {device!r}, signal {signal.name!r}: extra holds {', '.join(own)}, which the "
                          "export writes from the signal's own fields")
    attributes: list[tuple[str, Value]] = [("Name", signal.name), ("SignalType", signal.type), ("Device", device)]
    if "Label" in extra:
        attributes.append(("Label", extra.pop("Label")))
    attributes.append(("DeviceMap", signal.device_map))
    if signal.invert:
        attributes.append(("Invert", True))
    if signal.enc_type != "UNSIGNED":
        attributes.append(("EncType", signal.enc_type))
    for attribute, field in ANALOG_FIELDS.items():
        value = getattr(signal, field)
        if value is not None:
            attributes.append((attribute, value))
    return attributes + list(extra.items())
