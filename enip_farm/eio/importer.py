"""A cell configuration from a controller's EIO.cfg: every EtherNet/IP device the controller scans
(`ETHERNETIP_DEVICE`) becomes a farm device with the identity, assembly instances and sizes the
controller expects, so that its electronic key and connection sizes match what the device answers;
the file's `EIO_SIGNAL` entries become each device's named signals.

A device's model is the catalogue's base whose vendor id and product code match the entry (and
whose own channels fit the entry's sizes), else the generic adapter (`GenericAdapter`) with the
entry's identity and sizes. Most of the catalogue's product codes are placeholders (ABB does not
publish them): a match on one is reported as a warning. An entry value equal to the model's
placeholder (as `eio export` writes it) is not written as an override, so the device still lists
it as unverified. EIO.cfg does not name add-on modules: sizes beyond a base's own are
served as they are, and the YAML's comment names add-ons that would give them.

Nothing unknown is fatal: attributes the farm does not use go to the device's or signal's
`extra` (and `eio export` writes them back); entries the farm cannot serve (other kinds of
devices, their signals, cross connections, unknown sections) are kept as comments in the YAML;
every such decision is reported as a warning naming the file and line.
"""

from __future__ import annotations

import itertools
import re
from dataclasses import dataclass, field
from ipaddress import AddressValueError, IPv4Address
from types import MappingProxyType
from typing import Any

import yaml
from pydantic import ValidationError

from enip_farm.config import ConfigError, SignalConfig, parse_config
from enip_farm.device.build import build_profiles
from enip_farm.device.catalogue import MAX_ASSEMBLY_SIZE, Catalogue, IoCounts, Model
from enip_farm.device.named_signals import SignalError, named_signal
from enip_farm.device.profile import DeviceProfile
from enip_farm.device.signals import parse_signal
from enip_farm.eio.cfg import CfgFile, Entry, Value

#: The catalogue model that serves a device type the catalogue does not know.
GENERIC_MODEL = "GenericAdapter"
#: Sections of devices a controller scans over EtherNet/IP.
ETHERNETIP_SECTIONS = frozenset({"ETHERNETIP_DEVICE"})
#: Device sections of other networks (or of the controller itself): their devices are not served.
_OTHER_NETWORKS = re.compile(r"^(LOCAL|DEVICENET|PROFINET|PROFIBUS|CCLINK|ETHERCAT|\w+_INTERNAL)_DEVICE$|"
                             r"^(EIO_UNIT|EIO_BUS|INDUSTRIAL_NETWORK)$")
SIGNAL_SECTION = "EIO_SIGNAL"
#: Sections seen in public files that the farm does not import (kept as comments, reported without
#: calling them unknown).
KNOWN_SECTIONS = frozenset({"INDUSTRIAL_NETWORK", "EIO_CROSS", "EIO_ACCESS", "SYSSIG_IN"})

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

#: EIO_SIGNAL attributes -> SignalConfig fields (-Name, -SignalType, -Device, -DeviceMap, -Invert
#: are read apart).
ANALOG_FIELDS = MappingProxyType({"MaxLog": "max_log", "MaxPhys": "max_phys", "MaxPhysLimit": "max_phys_limit",
                                  "MaxBitVal": "max_bit_val", "MinLog": "min_log", "MinPhys": "min_phys",
                                  "MinPhysLimit": "min_phys_limit", "MinBitVal": "min_bit_val"})
#: Seen in public files, kept in `extra` without a warning (anything else is kept with one).
SIGNAL_KNOWN = frozenset({"Label", "Category", "Access", "Default", "SafeLevel", "FiltPas", "FiltAct"})
_DUMPER = getattr(yaml, "CSafeDumper", yaml.SafeDumper)  # libyaml's emitter when PyYAML has it: 10x faster
_SIGNAL_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]{0,63}$")
_DEVICE_NAME = re.compile(r"^[A-Za-z0-9_.-]{1,64}$")


class EioImportWarning(UserWarning):
    """A warning of `import_eio` (the file and line, and what the farm did about it), raised as a
    Python warning where the import is not a command's (the pytest fixture)."""


class EioError(ValueError):
    """Nothing the farm can serve in the file (or it is not an EIO file); the message is one line,
    `warnings` say what was found instead."""

    def __init__(self, message: str, warnings: list[str] | None = None) -> None:
        super().__init__(message)
        self.warnings = warnings or []


@dataclass
class _Device:
    entry: Entry
    config: dict[str, Any]
    controller_address: str | None
    notes: list[str] = field(default_factory=list)  # comment lines for the YAML
    profile: DeviceProfile | None = None


@dataclass
class ImportResult:
    document: dict[str, Any]  # the cell configuration, in the format of `enip_farm.config`
    warnings: list[str]
    yaml: str  # the document with comments: where each device came from, what was not imported

    @property
    def device_count(self) -> int:
        return len(self.document["devices"])

    @property
    def signal_count(self) -> int:
        return sum(len(device.get("signals", ())) for device in self.document["devices"])


def import_eio(cfg: CfgFile, catalogue: Catalogue, base_address: IPv4Address | None = None) -> ImportResult:
    """The cell of a parsed EIO.cfg. `base_address` renumbers the devices consecutively from it
    (skipping host numbers 0 and 255), in file order; by default they keep the controller's.
    Raises EioError if the file is not an EIO file or holds no EtherNet/IP device to serve."""
    if cfg.domain != "EIO":
        raise EioError(f"{cfg.where(1)}: a {cfg.domain} configuration file, not EIO (the I/O configuration)")
    importer = _Importer(cfg, catalogue, base_address)
    return importer.run()


class _Importer:
    def __init__(self, cfg: CfgFile, catalogue: Catalogue, base_address: IPv4Address | None) -> None:
        self.cfg = cfg
        self.catalogue = catalogue
        self.warnings: list[tuple[int, str]] = [(_line_of(w), w) for w in cfg.warnings]
        self.not_imported: list[Entry] = []
        self.devices: dict[str, _Device] = {}
        self.skipped_devices: set[str] = set()
        self.other_devices: dict[str, str] = {}  # device name -> its section
        self.next_address = int(base_address) if base_address is not None else None
        self.base_address = base_address

    def warn(self, entry: Entry, message: str) -> None:
        self.warnings.append((entry.line, f"{self.cfg.where(entry.line)}: {entry.describe()}: {message}"))

    def run(self) -> ImportResult:
        signals: list[Entry] = []
        others: dict[str, list[Entry]] = {}
        for entry in self.cfg.entries:
            if entry.section in ETHERNETIP_SECTIONS or self._reads_as_ethernetip(entry):
                self._device(entry)
            elif entry.section == SIGNAL_SECTION:
                signals.append(entry)
            else:
                if _is_device_section(entry.section) and isinstance(entry.get("Name"), str):
                    self.other_devices[str(entry.get("Name")).casefold()] = entry.section
                others.setdefault(entry.section, []).append(entry)
                self.not_imported.append(entry)
        for section, entries in others.items():
            line = self.cfg.sections.get(section, entries[0].line)
            count = f"{len(entries)} entr{'y' if len(entries) == 1 else 'ies'}"
            if _is_device_section(section):
                what = "devices that are not EtherNet/IP devices the controller scans"
            elif section in KNOWN_SECTIONS:
                what = "not used by the farm, which serves devices and their signals"
            else:
                what = "an unknown section"
            self.warnings.append((line, f"{self.cfg.where(line)}: {section} ({count}): {what}: not imported, "
                                        "kept as comments"))
        for entry in signals:
            self._signal(entry)
        warnings = [text for _, text in sorted(self.warnings, key=lambda warning: warning[0])]
        if not self.devices:
            raise EioError(f"{self.cfg.source}: no EtherNet/IP device (ETHERNETIP_DEVICE entry) the farm can "
                           "serve: nothing to import", warnings)
        document = {"devices": [device.config for device in self.devices.values()]}
        parse_config(document, self.cfg.source)  # the pieces were checked one by one; this cannot fail
        return ImportResult(document, warnings, self._yaml(document, warnings))

    # -- devices -----------------------------------------------------------------------------------

    def _reads_as_ethernetip(self, entry: Entry) -> bool:
        """A device entry of a section other than ETHERNETIP_DEVICE that has what a scanned
        EtherNet/IP device has (an IPv4 address and a vendor id) is read as one, with a warning."""
        if not _is_device_section(entry.section) or _OTHER_NETWORKS.match(entry.section):
            return False
        if _ipv4(entry.get("Address")) is None or not isinstance(entry.get("VendorId"), int):
            return False
        self.warn(entry, "read as an EtherNet/IP device (it has an IPv4 -Address and a -VendorId)")
        return True

    def _device(self, entry: Entry) -> None:
        name = entry.get("Name")
        if not isinstance(name, str) or not _DEVICE_NAME.match(name):
            self.warn(entry, "no -Name a farm device can take (letters, digits, _ . -): not imported, kept as "
                      "a comment")
            self.not_imported.append(entry)
            return
        if name.casefold() in self.devices or name.casefold() in self.skipped_devices:
            self.warn(entry, "a second device of this name: not imported, kept as a comment")
            self.not_imported.append(entry)
            return
        controller = _ipv4(entry.get("Address"))
        if self.next_address is None and controller is None:
            self.warn(entry, f"no IPv4 -Address ({entry.get('Address')!r}): not imported, kept as a comment "
                      "(--base-address gives every device a farm address)")
            self._skip(entry, name)
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
                checked = self._device_value(entry, attribute, value)
                if checked is not None:
                    (identity if part == "identity" else assemblies)[key] = checked
                continue
            if attribute == "ConnectionPriority" and value == DEFAULT_CONNECTION_PRIORITY:
                continue  # what eio export writes by default
            if attribute not in DEVICE_KNOWN:
                self.warn(entry, f"attribute -{attribute} is unknown to the farm: kept in extra "
                          "(eio export writes it back)")
            extra[attribute] = value
        model, notes = self._model(entry, identity, assemblies)
        config["model"] = model
        notes += _drop_placeholders(self.catalogue.models[model], identity, assemblies)
        if identity:
            config["identity"] = _ordered(identity, ("vendor_id", "device_type", "product_code", "product_name"))
        if assemblies:
            config["assemblies"] = _ordered(assemblies, ("output", "input", "configuration", "output_size",
                                                         "input_size"))
        if extra:
            config["extra"] = extra
        profile = self._resolve(entry, config, controller)
        if profile is None:
            self._skip(entry, name)
            return
        device = _Device(entry, config, str(controller) if controller else None, notes, profile)
        self.devices[name.casefold()] = device

    def _skip(self, entry: Entry, name: str) -> None:
        self.skipped_devices.add(name.casefold())
        self.not_imported.append(entry)

    def _device_value(self, entry: Entry, attribute: str, value: Value) -> Any:
        """An identity or assembly attribute's value if the farm can serve it, else None (warned)."""
        if attribute == "ProductName":
            text = str(value)
            if not text.strip():
                return None  # no name given: the model's
            if len(text) > 32:
                self.warn(entry, f"-ProductName {text!r} is longer than the 32 characters of the identity "
                          f"object: served as {text[:32]!r}")
            return text[:32]
        limits = MAX_ASSEMBLY_SIZE if attribute in ("OutputSize", "InputSize") else 0xFFFF
        low = 0 if attribute in ("VendorId", "ProductCode", "DeviceType", "OutputSize", "InputSize") else 1
        if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= limits:
            self.warn(entry, f"-{attribute} {value!r} is not a number in {low}..{limits}: not used (the "
                      "model's value is served)")
            return None
        return value

    def _model(self, entry: Entry, identity: dict[str, Any], assemblies: dict[str, Any]) -> tuple[str, list[str]]:
        """The catalogue model for an entry, and comment lines saying why."""
        vendor, code = identity.get("vendor_id"), identity.get("product_code")
        if vendor is None or code is None:
            self.warn(entry, f"no -VendorId or -ProductCode: served by {GENERIC_MODEL} with the entry's identity "
                      "and sizes")
            return GENERIC_MODEL, self._generic_notes(identity, assemblies)
        for name in self.catalogue.bases():
            model = self.catalogue.models[name]
            if model.identity is None or name == GENERIC_MODEL:
                continue
            if (model.identity.vendor_id, model.identity.product_code) != (vendor, code):
                continue
            own = _own_sizes(model.io, model.sizes)
            given = (assemblies.get("input_size"), assemblies.get("output_size"))
            if any(size is not None and size < minimum for size, minimum in zip(given, own, strict=True)):
                self.warn(entry, f"vendor {vendor} product code {code} is catalogue model {name}, but the sizes "
                          f"{given[0]}/{given[1]} bytes (in/out) are smaller than its own {own[0]}/{own[1]}: "
                          f"served by {GENERIC_MODEL} with the entry's identity and sizes")
                break
            notes = [f"catalogue model {name} (vendor {vendor}, product code {code})"]
            if "identity.product_code" in model.unverified:
                self.warn(entry, f"matched {name} on an unverified product code: {code} is the catalogue's "
                          f"placeholder for {name}, not a published value")
                notes = [f"catalogue model {name}: vendor {vendor} and product code {code}, the catalogue's "
                         "placeholder (unverified)"]
            notes += _addon_notes(self.catalogue, name, own, given)
            return name, notes
        else:
            self.warn(entry, f"vendor {vendor} product code {code} is not a model of the catalogue: served by "
                      f"{GENERIC_MODEL} with the entry's identity and sizes")
        return GENERIC_MODEL, self._generic_notes(identity, assemblies)

    @staticmethod
    def _generic_notes(identity: dict[str, Any], assemblies: dict[str, Any]) -> list[str]:
        missing = [f"-{a}" for a in ("VendorId", "ProductCode", "DeviceType", "OutputAssembly", "InputAssembly",
                                     "ConfigurationAssembly", "OutputSize", "InputSize")
                   if DEVICE_FIELDS[a][1] not in (identity if DEVICE_FIELDS[a][0] == "identity" else assemblies)]
        notes = [f"{GENERIC_MODEL}, served with the entry's identity and sizes"]
        if missing:
            notes.append(f"not in the entry, so placeholders (unverified): {' '.join(missing)}")
        return notes

    def _resolve(self, entry: Entry, config: dict[str, Any], controller: IPv4Address | None) -> DeviceProfile | None:
        """Give the device its address and build it alone; None (warned) if the farm cannot serve it."""
        if self.next_address is not None:
            address = _host_address(self.next_address)
            if address is None:
                self.warn(entry, "the addresses from --base-address run past 255.255.255.254: not imported")
                return None
        else:
            address = controller
            clash = next((d for d in self.devices.values() if d.config["address"] == str(address)), None)
            if clash is not None:
                self.warn(entry, f"the same -Address {address} as device {clash.config['name']!r}: not imported, "
                          "kept as a comment (--base-address gives every device its own)")
                return None
        config["address"] = str(address)
        try:
            [profile] = build_profiles(parse_config({"devices": [config]}, self.cfg.source), self.catalogue)
        except ConfigError as error:
            for line in str(error).splitlines():
                self.warn(entry, f"{line.split(': ', 1)[-1]}: not imported, kept as a comment")
            return None
        if self.next_address is not None:
            self.next_address = int(address) + 1  # type: ignore[arg-type]
        return profile

    # -- signals -----------------------------------------------------------------------------------

    def _signal(self, entry: Entry) -> None:
        device_name = entry.get("Device")
        key = str(device_name).casefold() if isinstance(device_name, str) else None
        device = self.devices.get(key) if key is not None else None
        if device is None:
            if device_name is None:
                reason = "no -Device (a virtual signal)"
            elif key in self.other_devices:
                reason = f"device {device_name!r} is a {self.other_devices[key]} entry, not an EtherNet/IP device"
            elif key in self.skipped_devices:
                reason = f"device {device_name!r} was not imported"
            else:
                reason = f"no device {device_name!r} in the file"
            self.warn(entry, f"{reason}: not imported, kept as a comment")
            self.not_imported.append(entry)
            return
        config = self._signal_config(entry)
        problem = config if isinstance(config, str) else self._signal_problem(device, config)
        if problem:
            self.warn(entry, f"{problem}: not imported, kept as a comment")
            self.not_imported.append(entry)
            return
        assert not isinstance(config, str)
        device.config.setdefault("signals", []).append(config)

    def _signal_config(self, entry: Entry) -> dict[str, Any] | str:
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
                    self.warn(entry, f"attribute -{attribute} is unknown to the farm: kept in extra "
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

    def _signal_problem(self, device: _Device, config: dict[str, Any]) -> str | None:
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

    # -- the YAML ----------------------------------------------------------------------------------

    def _yaml(self, document: dict[str, Any], warnings: list[str]) -> str:
        out = [f"# Imported by `enip-farm eio import` from {self.cfg.source} ({self.cfg.header}).",
               "# Each device is an EtherNet/IP device the controller scans, with the identity, assemblies and",
               "# sizes the controller expects; its signals are the file's EIO_SIGNAL entries for it."]
        if self.base_address is not None:
            out.append(f"# Addresses renumbered from {self.base_address} (--base-address); each device's comment "
                       "gives the controller's.")
        else:
            out.append("# Devices keep the controller's addresses (--base-address renumbers them for a desk run).")
        if warnings:
            out += ["#", "# Warnings:"] + [f"#   {warning}" for warning in warnings]
        if self.not_imported:
            out += ["#", "# Not imported (as the file had them):"]
            out += [f"#   {self.cfg.where(entry.line)} {entry.section}: {entry.text()}"
                    for entry in sorted(self.not_imported, key=lambda e: e.line)]
        out.append("devices:")
        for device, config in zip(self.devices.values(), document["devices"], strict=True):
            origin = f"{self.cfg.where(device.entry.line)} {device.entry.section} {config['name']!r}"
            if device.controller_address and device.controller_address != config["address"]:
                origin += f", controller address {device.controller_address}"
            out.append(f"  # {origin}")
            out += [f"  # {note}" for note in device.notes]
            dumped = yaml.dump([config], Dumper=_DUMPER, sort_keys=False, default_flow_style=None, width=110,
                               allow_unicode=True)
            out += ["  " + line for line in dumped.splitlines()]
        return "\n".join(out) + "\n"


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


def _line_of(warning: str) -> int:
    """The line a `file:line: ...` message names (0 if none)."""
    match = re.match(r"^.*?:(\d+): ", warning)
    return int(match[1]) if match else 0


def _ordered(values: dict[str, Any], order: tuple[str, ...]) -> dict[str, Any]:
    return {key: values[key] for key in order if key in values}


def _is_device_section(section: str) -> bool:
    return section.endswith("_DEVICE") or section in ("EIO_UNIT",)


def _ipv4(value: Value | None) -> IPv4Address | None:
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
