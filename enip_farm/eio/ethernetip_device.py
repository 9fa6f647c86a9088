"""ETHERNETIP_DEVICE entries of an EIO.cfg (a device the controller scans over EtherNet/IP: -Name,
-Address, -VendorId, -ProductCode, -DeviceType, -ProductName, -OutputAssembly, -InputAssembly,
-ConfigurationAssembly, -OutputSize, -InputSize) made farm devices, with the identity, assembly
instances and sizes the controller expects, so that its electronic key and connection sizes match
what the device answers.

A device's model is the catalogue's base whose vendor id and product code match the entry (and
whose own channels fit the entry's sizes), else the generic adapter (`GenericAdapter`) with the
entry's identity and sizes. Most of the catalogue's product codes are placeholders (ABB does not
publish them): a match on one is reported as a warning. An entry value equal to the model's
placeholder (as `eio export` writes it) is not written as an override, so the device still lists
it as unverified. EIO.cfg does not name add-on modules: sizes beyond a base's own are served as
they are, and the YAML's comment names add-ons that would give them.
"""

from __future__ import annotations

import itertools
import re
from ipaddress import AddressValueError, IPv4Address
from types import MappingProxyType
from typing import Any

from enip_farm.config import ConfigError, parse_config
from enip_farm.device.build import build_profiles
from enip_farm.device.catalogue import MAX_ASSEMBLY_SIZE, Catalogue, IoCounts, Model
from enip_farm.device.profile import DeviceProfile
from enip_farm.eio.cell import CellImport, ImportedDevice
from enip_farm.eio.cfg import Entry, Value

#: The catalogue model that serves a device type the catalogue does not know.
GENERIC_MODEL = "GenericAdapter"
#: Sections of devices a controller scans over EtherNet/IP.
ETHERNETIP_SECTIONS = frozenset({"ETHERNETIP_DEVICE"})
#: Device sections of other networks (or of the controller itself): their devices are not served.
_OTHER_NETWORKS = re.compile(r"^(LOCAL|DEVICENET|PROFINET|PROFIBUS|CCLINK|ETHERCAT|\w+_INTERNAL)_DEVICE$|"
                             r"^(EIO_UNIT|EIO_BUS|INDUSTRIAL_NETWORK)$")

#: ETHERNETIP_DEVICE attributes the device is made of: attribute -> (section of the config, field).
DEVICE_FIELDS = MappingProxyType({
    "VendorId": ("identity", "vendor_id"), "ProductCode": ("identity", "product_code"),
    "DeviceType": ("identity", "device_type"), "ProductName": ("identity", "product_name"),
    "OutputAssembly": ("assemblies", "output"), "InputAssembly": ("assemblies", "input"),
    "ConfigurationAssembly": ("assemblies", "configuration"),
    "OutputSize": ("assemblies", "output_size"), "InputSize": ("assemblies", "input_size")})
#: Seen in public files, kept in `extra` without a warning (anything else is kept with one).
DEVICE_KNOWN = frozenset({"VendorName", "Label", "ConnectionPriority", "TrustLevel", "Simulated", "Network"})
#: What `eio export` writes when a device's extra does not say (so import leaves it out of extra).
DEFAULT_CONNECTION_PRIORITY = "SCHEDULE"
_DEVICE_NAME = re.compile(r"^[A-Za-z0-9_.-]{1,64}$")


def reads_as_ethernetip(cell: CellImport, entry: Entry) -> bool:
    """A device entry of a section other than ETHERNETIP_DEVICE that has what a scanned
    EtherNet/IP device has (an IPv4 address and a vendor id) is read as one, with a warning."""
    if not is_device_section(entry.section) or _OTHER_NETWORKS.match(entry.section):
        return False
    if ipv4(entry.get("Address")) is None or not isinstance(entry.get("VendorId"), int):
        return False
    cell.warn(entry, "read as an EtherNet/IP device (it has an IPv4 -Address and a -VendorId)")
    return True


def import_device(cell: CellImport, entry: Entry) -> None:
    """The entry as a farm device of `cell`, else kept as a comment (warned)."""
    name = entry.get("Name")
    if not isinstance(name, str) or not _DEVICE_NAME.match(name):
        cell.warn(entry, "no -Name a farm device can take (letters, digits, _ . -): not imported, kept as "
                  "a comment")
        cell.not_imported.append(entry)
        return
    if name.casefold() in cell.devices or name.casefold() in cell.skipped_devices:
        cell.warn(entry, "a second device of this name: not imported, kept as a comment")
        cell.not_imported.append(entry)
        return
    controller = ipv4(entry.get("Address"))
    if cell.next_address is None and controller is None:
        cell.warn(entry, f"no IPv4 -Address ({entry.get('Address')!r}): not imported, kept as a comment "
                  "(--base-address gives every device a farm address)")
        cell.skip(entry, name)
        return
    config: dict[str, Any] = {"name": name, "address": None, "model": GENERIC_MODEL}
    identity: dict[str, Any] = {}
    assemblies: dict[str, Any] = {}
    extra: dict[str, Value] = {}
    for attribute, value in entry.attributes.items():
        if attribute in ("Name", "Address"):
            continue
        if attribute in DEVICE_FIELDS:
            part, key = DEVICE_FIELDS[attribute]
            checked = _device_value(cell, entry, attribute, value)
            if checked is not None:
                (identity if part == "identity" else assemblies)[key] = checked
            continue
        if attribute == "ConnectionPriority" and value == DEFAULT_CONNECTION_PRIORITY:
            continue  # what eio export writes by default
        if attribute not in DEVICE_KNOWN:
            cell.warn(entry, f"attribute -{attribute} is unknown to the farm: kept in extra "
                      "(eio export writes it back)")
        extra[attribute] = value
    model, notes = _model(cell, entry, identity, assemblies)
    config["model"] = model
    notes += _drop_placeholders(cell.catalogue.models[model], identity, assemblies)
    if identity:
        config["identity"] = _ordered(identity, ("vendor_id", "device_type", "product_code", "product_name"))
    if assemblies:
        config["assemblies"] = _ordered(assemblies, ("output", "input", "configuration", "output_size",
                                                     "input_size"))
    if extra:
        config["extra"] = extra
    profile = _resolve(cell, entry, config, controller)
    if profile is None:
        cell.skip(entry, name)
        return
    device = ImportedDevice(entry, config, str(controller) if controller else None, notes, profile)
    cell.devices[name.casefold()] = device


def _device_value(cell: CellImport, entry: Entry, attribute: str, value: Value) -> Any:
    """An identity or assembly attribute's value if the farm can serve it, else None (warned)."""
    if attribute == "ProductName":
        text = str(value)
        if not text.strip():
            return None  # no name given: the model's
        if len(text) > 32:
            cell.warn(entry, f"-ProductName {text!r} is longer than the 32 characters of the identity "
                      f"object: served as {text[:32]!r}")
        return text[:32]
    limits = MAX_ASSEMBLY_SIZE if attribute in ("OutputSize", "InputSize") else 0xFFFF
    low = 0 if attribute in ("VendorId", "ProductCode", "DeviceType", "OutputSize", "InputSize") else 1
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= limits:
        cell.warn(entry, f"-{attribute} {value!r} is not a number in {low}..{limits}: not used (the "
                  "model's value is served)")
        return None
    return value


def _model(cell: CellImport, entry: Entry, identity: dict[str, Any],
           assemblies: dict[str, Any]) -> tuple[str, list[str]]:
    """The catalogue model for an entry, and comment lines saying why."""
    vendor, code = identity.get("vendor_id"), identity.get("product_code")
    if vendor is None or code is None:
        cell.warn(entry, f"no -VendorId or -ProductCode: served by {GENERIC_MODEL} with the entry's identity "
                  "and sizes")
        return GENERIC_MODEL, _generic_notes(identity, assemblies)
    for name in cell.catalogue.bases():
        model = cell.catalogue.models[name]
        if model.identity is None or name == GENERIC_MODEL:
            continue
        if (model.identity.vendor_id, model.identity.product_code) != (vendor, code):
            continue
        own = _own_sizes(model.io, model.sizes)
        given = (assemblies.get("input_size"), assemblies.get("output_size"))
        if any(size is not None and size < minimum for size, minimum in zip(given, own, strict=True)):
            cell.warn(entry, f"vendor {vendor} product code {code} is catalogue model {name}, but the sizes "
                      f"{given[0]}/{given[1]} bytes (in/out) are smaller than its own {own[0]}/{own[1]}: "
                      f"served by {GENERIC_MODEL} with the entry's identity and sizes")
            break
        notes = [f"catalogue model {name} (vendor {vendor}, product code {code})"]
        if "identity.product_code" in model.unverified:
            cell.warn(entry, f"matched {name} on an unverified product code: {code} is the catalogue's "
                      f"placeholder for {name}, not a published value")
            notes = [f"catalogue model {name}: vendor {vendor} and product code {code}, the catalogue's "
                     "placeholder (unverified)"]
        notes += _addon_notes(cell.catalogue, name, own, given)
        return name, notes
    else:
        cell.warn(entry, f"vendor {vendor} product code {code} is not a model of the catalogue: served by "
                  f"{GENERIC_MODEL} with the entry's identity and sizes")
    return GENERIC_MODEL, _generic_notes(identity, assemblies)


def _generic_notes(identity: dict[str, Any], assemblies: dict[str, Any]) -> list[str]:
    missing = [f"-{a}" for a in ("VendorId", "ProductCode", "DeviceType", "OutputAssembly", "InputAssembly",
                                 "ConfigurationAssembly", "OutputSize", "InputSize")
               if DEVICE_FIELDS[a][1] not in (identity if DEVICE_FIELDS[a][0] == "identity" else assemblies)]
    notes = [f"{GENERIC_MODEL}, served with the entry's identity and sizes"]
    if missing:
        notes.append(f"not in the entry, so placeholders (unverified): {' '.join(missing)}")
    return notes


def _resolve(cell: CellImport, entry: Entry, config: dict[str, Any],
             controller: IPv4Address | None) -> DeviceProfile | None:
    """Give the device its address and build it alone; None (warned) if the farm cannot serve it."""
    if cell.next_address is not None:
        address = _host_address(cell.next_address)
        if address is None:
            cell.warn(entry, "the addresses from --base-address run past 255.255.255.254: not imported")
            return None
    else:
        address = controller
        clash = next((d for d in cell.devices.values() if d.config["address"] == str(address)), None)
        if clash is not None:
            cell.warn(entry, f"the same -Address {address} as device {clash.config['name']!r}: not imported, "
                      "kept as a comment (--base-address gives every device its own)")
            return None
    config["address"] = str(address)
    try:
        [profile] = build_profiles(parse_config({"devices": [config]}, cell.cfg.source), cell.catalogue)
    except ConfigError as error:
        for line in str(error).splitlines():
            cell.warn(entry, f"{line.split(': ', 1)[-1]}: not imported, kept as a comment")
        return None
    if cell.next_address is not None:
        cell.next_address = int(address) + 1  # type: ignore[arg-type]
    return profile


#: An entry's attribute -> the catalogue model's value it is compared with (placeholders).
_PLACEHOLDERS = MappingProxyType({
    "identity": ("vendor_id", "device_type", "product_code", "product_name"),
    "assemblies": ("output", "input", "configuration", "output_size", "input_size")})


def _drop_placeholders(model: Model, identity: dict[str, Any], assemblies: dict[str, Any]) -> list[str]:
    """Remove the values equal to a placeholder of `model` (as `eio export` writes them) from the
    overrides, so the device keeps them among its unverified values; a comment line naming them."""
    dropped = []
    for part, values in (("identity", identity), ("assemblies", assemblies)):
        for key in _PLACEHOLDERS[part]:
            if f"{part}.{key}" not in model.unverified or key not in values:
                continue
            own = getattr(model.identity, key) if part == "identity" else _model_assembly(model, key)
            if own is not None and values[key] == own:
                del values[key]
                dropped.append(next(a for a, field in DEVICE_FIELDS.items() if field == (part, key)))
    if not dropped:
        return []
    return [f"-{' -'.join(dropped)} as the catalogue's placeholders for this model: not overrides, still unverified"]


def _model_assembly(model: Model, key: str) -> int | None:
    if key.endswith("_size"):
        return getattr(model.sizes, key.removesuffix("_size")) if model.sizes is not None else None
    return getattr(model.assemblies, key) if model.assemblies is not None else None


def _ordered(values: dict[str, Any], order: tuple[str, ...]) -> dict[str, Any]:
    return {key: values[key] for key in order if key in values}


def is_device_section(section: str) -> bool:
    """A section of devices (of any network, or of the controller itself)."""
    return section.endswith("_DEVICE") or section in ("EIO_UNIT",)


def ipv4(value: Value | None) -> IPv4Address | None:
    """An attribute's IPv4 address, or None."""
    if not isinstance(value, str):
        return None
    try:
        return IPv4Address(value.strip())
    except AddressValueError:
        return None


def _host_address(number: int) -> IPv4Address | None:
    """The first address from `number` on whose last byte is neither 0 nor 255 (a /24's network
    and broadcast addresses); None past 255.255.255.254."""
    while number < 0xFFFFFFFF and number & 0xFF in (0, 255):
        number += 1
    return IPv4Address(number) if number < 0xFFFFFFFF else None


def _own_sizes(io: IoCounts, sizes: Any) -> tuple[int, int]:
    """(input, output) bytes of a base model alone."""
    if sizes is not None:
        return sizes.input, sizes.output
    return io.input_size, io.output_size


def _addon_notes(catalogue: Catalogue, model: str, own: tuple[int, int], given: tuple[int | None, int | None]
                 ) -> list[str]:
    """Comment lines for an entry whose sizes exceed its base model's own: the catalogue's add-on
    combinations (up to four modules) that would give them. EIO.cfg does not name add-ons."""
    if not catalogue.models[model].assemblies or given == (None, None):
        return []
    extra_in = (given[0] if given[0] is not None else own[0]) - own[0]
    extra_out = (given[1] if given[1] is not None else own[1]) - own[1]
    if extra_in == extra_out == 0:
        return []
    sizes = {name: (catalogue.models[name].io.input_size, catalogue.models[name].io.output_size)
             for name in catalogue.addons()}
    found = []
    for count in range(1, 5):  # the fewest modules that give the sizes
        found = [list(combination) for combination in itertools.combinations_with_replacement(sorted(sizes), count)
                 if (sum(sizes[n][0] for n in combination), sum(sizes[n][1] for n in combination))
                 == (extra_in, extra_out)]
        if found:
            break
    line = (f"sizes {given[0]}/{given[1]} bytes (in/out), {model} alone has {own[0]}/{own[1]}: served as the entry "
            "says (EIO.cfg does not name add-on modules)")
    if not found:
        return [line]
    options = " or ".join(f"addons: [{', '.join(c)}]" for c in found[:3])
    return [line, f"for numbered channels of add-ons (AI1..), add: {options}"]
