"""EIO_SIGNAL entries of an EIO.cfg (-Name, -SignalType, -Device, -DeviceMap, -Invert, -EncType and
the analog scaling attributes) made the named signals of the devices imported from the file's
ETHERNETIP_DEVICE entries; a signal the farm cannot serve is kept as a comment, with a warning."""

from __future__ import annotations

import re
from types import MappingProxyType
from typing import Any

from pydantic import ValidationError

from enip_farm.config import SignalConfig
from enip_farm.device.named_signals import SignalError, named_signal
from enip_farm.device.signals import parse_signal
from enip_farm.eio.cell import CellImport, ImportedDevice
from enip_farm.eio.cfg import Entry, Value

#: The section of signals (each names its device with -Device).
SIGNAL_SECTION = "EIO_SIGNAL"
#: EIO_SIGNAL attributes -> SignalConfig fields (-Name, -SignalType, -Device, -DeviceMap, -Invert
#: are read apart).
ANALOG_FIELDS = MappingProxyType({"MaxLog": "max_log", "MaxPhys": "max_phys", "MaxPhysLimit": "max_phys_limit",
                                  "MaxBitVal": "max_bit_val", "MinLog": "min_log", "MinPhys": "min_phys",
                                  "MinPhysLimit": "min_phys_limit", "MinBitVal": "min_bit_val"})
#: Seen in public files, kept in `extra` without a warning (anything else is kept with one).
SIGNAL_KNOWN = frozenset({"Label", "Category", "Access", "Default", "SafeLevel", "FiltPas", "FiltAct"})
_SIGNAL_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]{0,63}$")


def import_signal(cell: CellImport, entry: Entry) -> None:
    """The entry as a named signal of its imported device, else kept as a comment (warned)."""
    device_name = entry.get("Device")
    key = str(device_name).casefold() if isinstance(device_name, str) else None
    device = cell.devices.get(key) if key is not None else None
    if device is None:
        if device_name is None:
            reason = "no -Device (a virtual signal)"
        elif key in cell.other_devices:
            reason = f"device {device_name!r} is a {cell.other_devices[key]} entry, not an EtherNet/IP device"
        elif key in cell.skipped_devices:
            reason = f"device {device_name!r} was not imported"
        else:
            reason = f"no device {device_name!r} in the file"
        cell.warn(entry, f"{reason}: not imported, kept as a comment")
        cell.not_imported.append(entry)
        return
    config = _signal_config(cell, entry)
    problem = config if isinstance(config, str) else _signal_problem(device, config)
    if problem:
        cell.warn(entry, f"{problem}: not imported, kept as a comment")
        cell.not_imported.append(entry)
        return
    assert not isinstance(config, str)
    device.config.setdefault("signals", []).append(config)


def _signal_config(cell: CellImport, entry: Entry) -> dict[str, Any] | str:
    """The signal's configuration, or why it cannot be one."""
    config: dict[str, Any] = {"name": entry.get("Name"), "type": entry.get("SignalType"),
                              "device_map": entry.get("DeviceMap")}
    if isinstance(config["type"], str):
        config["type"] = config["type"].upper()
    if isinstance(config["device_map"], int) and not isinstance(config["device_map"], bool):
        config["device_map"] = str(config["device_map"])
    for attribute in ("Name", "SignalType", "DeviceMap"):
        if entry.get(attribute) is None:
            return f"no -{attribute}"
    extra: dict[str, Value] = {}
    for attribute, value in entry.attributes.items():
        if attribute in ("Name", "SignalType", "DeviceMap", "Device"):
            continue
        if attribute == "Invert":
            if value not in (True, 1, 0):
                return f"-Invert {value!r} is neither a flag nor 0/1"
            config["invert"] = bool(value)
        elif attribute == "EncType":
            config["enc_type"] = str(value).upper()
        elif attribute in ANALOG_FIELDS:
            if isinstance(value, bool) or not isinstance(value, int | float):
                return f"-{attribute} {value!r} is not a number"
            config[ANALOG_FIELDS[attribute]] = float(value)
        else:
            if attribute not in SIGNAL_KNOWN:
                cell.warn(entry, f"attribute -{attribute} is unknown to the farm: kept in extra "
                          "(eio export writes it back)")
            extra[attribute] = value
    if extra:
        config["extra"] = extra
    try:
        SignalConfig.model_validate(config)
    except ValidationError as error:
        first = error.errors()[0]
        where = ".".join(str(part) for part in first["loc"])
        return f"{where}: {first['msg']} ({first.get('input')!r})"
    return config


def _signal_problem(device: ImportedDevice, config: dict[str, Any]) -> str | None:
    """Why a valid signal configuration does not fit its device, or None."""
    assert device.profile is not None
    name = config["name"]
    if any(s["name"].casefold() == name.casefold() for s in device.config.get("signals", ())):
        return f"a second signal named {name!r} on device {device.config['name']!r}"
    if not _SIGNAL_NAME.match(name):
        return "the name is not a RAPID name"
    try:
        parse_signal(name)
    except SignalError:
        pass
    else:
        return f"the name reads as the farm's numbered signal {name.upper()}"
    try:
        signal = named_signal(SignalConfig.model_validate(config))
    except SignalError as error:
        return str(error)
    size = device.profile.input_size if signal.role == "input" else device.profile.output_size
    beyond = [bit for bit in signal.bits if bit >= 8 * size]
    if beyond:
        return (f"bit {beyond[0]} is beyond the device's {size}-byte {signal.role} image "
                f"(-{'Input' if signal.role == 'input' else 'Output'}Size)")
    return None
