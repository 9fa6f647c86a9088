"""`enip-farm eds import FILE.eds -o PROFILE.yaml`: a catalogue profile from a vendor's EDS (CIP
Networks Library Vol. 1 chapter 7; Vol. 2 for EtherNet/IP's [Connection Manager] and [Port]).

The file's syntax is enip_farm/eds/grammar.py's (a lark grammar: vendor sections and keywords, brace
lists, comments anywhere, quoted and unquoted EPATHs, CRLF, Latin-1). This module reads what the
sections mean: the identity of [Device] (a non-numeric VendCode is an error), [Params] (data type,
limits, default, read-only), the [Assembly] entries (instance, size, members) and every ConnectionN
of [Connection Manager] (7-3.6.11): application type, transport class and trigger, connection
parameters (fixed/variable size, real-time formats, connection types), RPI and sizes as numbers or
a ParamN's default within its limits (an empty size: the size of the [Assembly] entry its format
names), configuration #1 (proxy) and #2 (target) size, and its path with `[ParamN]` references
resolved to their default. Real defects are refused all at once, one `file:line: reason` each;
what the farm does not use (vendor sections and keywords, objects) is kept in the parse and never
fatal; what it cannot serve as the EDS says is a note.

The profile (`eds_profile`) serves every class-1 connection entry with its own points, sizes,
real-time formats, RPI range and connection types (`connections:` of the model), every assembly
instance the entries or [Assembly] name (`points:`), the configuration assembly's default data
from its members' parameter defaults, and a device without class-1 entries as an explicit-only
device (identity and its assemblies). The `$ UNVERIFIED: MODEL.item` comments `enip-farm eds
export` writes carry over into the profile's unverified items.

eds-pie (`parse_eds`) stays the independent checker of the EDS files `eds export` writes.
"""

from __future__ import annotations

import logging
import re
import struct
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from enip_farm.device.catalogue import MAX_ASSEMBLY_SIZE, Catalogue, shipped_catalogue
from enip_farm.eds.grammar import EdsText, Entry, Value, decode_eds_bytes, parse_eds_text
from enip_farm.protocol.cip import ClassCode
from enip_farm.protocol.epath import (
    DataSegment,
    ElectronicKey,
    LogicalSegment,
    LogicalType,
    PathError,
    PortSegment,
    decode_epath,
)

#: Application types of a connection entry's trigger and transport word, bits 24-27 (7-3.6.11.1).
_KINDS = ((26, "exclusive owner"), (25, "input only"), (24, "listen only"), (27, "redundant owner"))
#: Real-time transfer formats, connection parameters bits 8-10 (O->T) and 12-14 (T->O). Real files
#: give 3 for heartbeat connections (no data) and 4 for the 32-bit run/idle header.
FORMATS = {0: "modeless", 1: "zero length", 2: "heartbeat", 3: "heartbeat", 4: "run/idle"}
#: Parameter data types (Vol. 1, C-6.1) and their sizes in bytes.
_TYPE_SIZES = {0xC1: 1, 0xC2: 1, 0xC3: 2, 0xC4: 4, 0xC5: 8, 0xC6: 1, 0xC7: 2, 0xC8: 4, 0xC9: 8, 0xCA: 4,
               0xCB: 8, 0xD1: 1, 0xD2: 2, 0xD3: 4, 0xD4: 8}
_SIGNED = {0xC2, 0xC3, 0xC4, 0xC5}
_REFERENCE = re.compile(r"^\[?((?:Proxy)?Param|Assem|ProxyAssem)(\d+)\]?$")
_UNVERIFIED = re.compile(r"^\s*\$\s*UNVERIFIED:\s*(\S.*?)\s*$", re.MULTILINE)
_DEVICE_NUMBERS = ("VendCode", "ProdType", "ProdCode", "MajRev", "MinRev")


class EdsError(ValueError):
    """An EDS the farm cannot make a profile of: one line per defect, `file:line: reason`."""


@dataclass(frozen=True)
class EdsParam:
    """A ParamN of [Params] (7-3.6.7): fields 3 descriptor, 4 data type, 5 size, 6 name, 9-11
    minimum, maximum, default; its link path (fields 1-2) names the attribute it stands for."""

    keyword: str
    line: int
    descriptor: int
    data_type: int
    size: int
    name: str
    minimum: int | float | None
    maximum: int | float | None
    default: int | float | None
    link_path: str = ""

    @property
    def read_only(self) -> bool:
        return bool(self.descriptor & 0x10)

    def encode(self, value: int | float | None = None) -> bytes:
        """`value` (else the default) as the parameter's data type, little-endian."""
        value = self.default if value is None else value
        if value is None:
            return bytes(self.size)
        if self.data_type == 0xCA:
            return struct.pack("<f", float(value))
        if self.data_type == 0xCB:
            return struct.pack("<d", float(value))
        return int(value).to_bytes(self.size, "little", signed=self.data_type in _SIGNED and int(value) < 0)


@dataclass(frozen=True)
class EdsAssembly:
    """An AssemN of [Assembly] (7-3.6.8): its instance (from its path), size and members."""

    keyword: str
    line: int
    name: str
    instance: int | None
    size: int | None
    members: tuple[tuple[int | None, str], ...]  # (size in bits, reference: ParamN, AssemN or "")


@dataclass(frozen=True)
class EdsConnection:
    keyword: str  # ConnectionN
    name: str
    kind: str  # exclusive owner, input only, listen only, redundant owner, or other
    transport_classes: int  # the trigger and transport word
    parameters: int  # the connection parameters word
    o_t_size: int | None
    t_o_size: int | None
    configuration_size: int | None  # configuration #2 (target)
    rpi: tuple[int, int] | None  # microseconds, from the O->T RPI field (a ParamN's limits)
    points: tuple[int | None, int, int] | None  # configuration, consumed (O->T), produced (T->O)
    path: str
    line: int = 0
    proxy_configuration_size: int | None = None  # configuration #1
    configuration_format: str = ""  # the [Assembly] entry of the target configuration
    path_bytes: bytes = b""
    key: ElectronicKey | None = None
    rpi_default: int | None = None

    @property
    def transport_class(self) -> int | None:
        classes = self.transport_classes & 0xFFFF
        return next((n for n in range(16) if classes >> n & 1), None)

    @property
    def triggers(self) -> tuple[str, ...]:
        return tuple(name for bit, name in ((16, "cyclic"), (17, "change of state"), (18, "application"))
                     if self.transport_classes >> bit & 1)

    @property
    def o_t_format(self) -> int:
        return self.parameters >> 8 & 7

    @property
    def t_o_format(self) -> int:
        return self.parameters >> 12 & 7

    @property
    def o_t_variable(self) -> bool:
        return bool(self.parameters & 2) and not self.parameters & 1

    @property
    def t_o_variable(self) -> bool:
        return bool(self.parameters & 8) and not self.parameters & 4

    @property
    def t_o_multicast(self) -> bool:
        return bool(self.parameters >> 21 & 1)

    @property
    def t_o_point_to_point(self) -> bool:
        return bool(self.parameters >> 22 & 1)


@dataclass(frozen=True)
class EdsDevice:
    vendor_id: int
    vendor_name: str
    device_type: int
    product_code: int
    revision: tuple[int, int]
    product_name: str
    catalog: str
    connections: tuple[EdsConnection, ...]
    notes: tuple[str, ...]  # what could not be used, never fatal
    unverified: tuple[str, ...] = ()  # the model's items the file's `$ UNVERIFIED:` comments name
    params: dict[str, EdsParam] = field(default_factory=dict)
    assemblies: dict[str, EdsAssembly] = field(default_factory=dict)


def _number(value: Value | str | None) -> int | float | None:
    """A bare number: decimal, 0x hex, 0b binary, a leading zero, a sign, or a decimal fraction."""
    text = value.text if isinstance(value, Value) else value
    if not text or (isinstance(value, Value) and value.kind != "bare"):
        return None
    try:
        return int(text, 0)
    except ValueError:
        pass
    try:
        return int(text, 10)
    except ValueError:
        pass
    try:
        return float(text)
    except ValueError:
        return None


def _int(value: Value | str | None) -> int | None:
    number = _number(value)
    return number if isinstance(number, int) else None


class _Reader:
    """One file's meaning; `errors` (line, reason) refuse it, `notes` do not."""

    def __init__(self, parsed: EdsText) -> None:
        self.parsed = parsed
        self.errors: list[tuple[int, str]] = list(parsed.errors)
        self.notes: list[str] = []
        self.params: dict[str, EdsParam] = {}
        self.assemblies: dict[str, EdsAssembly] = {}

    def error(self, line: int, reason: str) -> None:
        self.errors.append((line, reason))

    @staticmethod
    def field(entry: Entry, index: int) -> Value:
        return entry.values[index] if index < len(entry.values) else Value("empty", "", 0)

    @staticmethod
    def line(entry: Entry, index: int) -> int:
        value = entry.values[index] if index < len(entry.values) else None
        return value.line if value is not None and value.line else entry.line

    # -- [Params] and [Assembly] -------------------------------------------------------------------

    def read_params(self) -> None:
        for section_name in ("Params", "Param"):
            section = self.parsed.sections.get(section_name)
            for keyword, entry in (section.entries.items() if section else ()):
                if not re.fullmatch(r"(Proxy)?Param\d+", keyword):
                    continue
                if len(entry.values) < 12:
                    self.error(entry.line, f"[Params] {keyword}: {len(entry.values)} fields, at least 12 expected")
                    continue
                data_type = _int(self.field(entry, 4))
                size = _int(self.field(entry, 5))
                if data_type is None or size is None:
                    self.error(self.line(entry, 4), f"[Params] {keyword}: data type and size must be numbers")
                    continue
                limits = [_number(self.field(entry, i)) for i in (9, 10, 11)]
                for index, number in zip((9, 10, 11), limits, strict=True):
                    text = self.field(entry, index).text
                    if number is None and text and not _REFERENCE.match(text):
                        self.notes.append(f"[Params] {keyword}: {('minimum', 'maximum', 'default')[index - 9]} "
                                          f"{text!r} is not a number; not used")
                minimum, maximum, default = limits
                param = EdsParam(keyword, entry.line, _int(self.field(entry, 3)) or 0, data_type,
                                 size or _TYPE_SIZES.get(data_type, 0), self.field(entry, 6).text,
                                 minimum, maximum, default, self.field(entry, 2).text)
                if default is not None and ((minimum is not None and default < minimum)
                                            or (maximum is not None and default > maximum)):
                    self.error(self.line(entry, 11), f"[Params] {keyword}: default {default} is outside its "
                               f"limits {minimum}..{maximum}")
                self.params[keyword] = param

    def read_assemblies(self) -> None:
        section = self.parsed.sections.get("Assembly")
        for keyword, entry in (section.entries.items() if section else ()):
            if not re.fullmatch(r"(Proxy)?Assem\d+", keyword):
                continue
            path = self.field(entry, 1).text
            instance = None
            if path:
                resolved = self.resolve_path(path, entry.line, f"[Assembly] {keyword}")
                if resolved is not None:
                    try:
                        segments = decode_epath(resolved)
                    except PathError as error:  # the connections' paths decide what is served
                        self.notes.append(f"line {self.line(entry, 1)}: [Assembly] {keyword}: path {path!r}: "
                                          f"{error}; its instance is not served")
                        segments = []
                    instance = next((s.value for s in segments if isinstance(s, LogicalSegment)
                                     and s.type in (LogicalType.INSTANCE_ID, LogicalType.CONNECTION_POINT)), None)
            members = tuple((_int(entry.values[i]), entry.values[i + 1].text if i + 1 < len(entry.values) else "")
                            for i in range(6, len(entry.values), 2))
            self.assemblies[keyword] = EdsAssembly(keyword, entry.line, self.field(entry, 0).text, instance,
                                                   self.number(self.field(entry, 2), entry, 2, keyword), members)

    def assembly_size(self, keyword: str, seen: frozenset[str] = frozenset()) -> int | None:
        """An [Assembly] entry's size: its own, else the sum of its members (bits, or a member
        assembly's size)."""
        assembly = self.assemblies.get(keyword)
        if assembly is None or keyword in seen:
            return None
        if assembly.size is not None:
            return assembly.size
        bits = 0
        for size, reference in assembly.members:
            if size is None and reference in self.assemblies:
                nested = self.assembly_size(reference, seen | {keyword})
                if nested is None:
                    return None
                bits += nested * 8
            elif size is None:
                return None
            else:
                bits += size
        return bits // 8 if assembly.members and bits % 8 == 0 else None

    # -- references ----------------------------------------------------------------------------------

    def number(self, value: Value, entry: Entry, index: int, where: str) -> int | None:
        """A number given as itself or as a ParamN reference (its default, within its limits)."""
        if value.empty:
            return None
        match = _REFERENCE.match(value.text)
        if match and match.group(1).endswith("Param"):
            param = self.params.get(value.text.strip("[]"))
            if param is None:
                self.error(self.line(entry, index), f"{where}: {value.text} is not in [Params]")
                return None
            if not isinstance(param.default, int):
                self.error(self.line(entry, index), f"{where}: {value.text} has no numeric default")
                return None
            return param.default
        number = _int(value)
        if number is None:
            self.error(self.line(entry, index), f"{where}: {value.text!r} is not a number")
        return number

    def resolve_path(self, path: str, line: int, where: str) -> bytes | None:
        """An EPATH's bytes: hex bytes, `[ParamN]` or `ParamN` references replaced with their
        default in the parameter's size (7-3.6.11.9)."""
        out = bytearray()
        for token in path.replace(",", " ").split():
            match = _REFERENCE.match(token)
            if match and match.group(1).endswith("Param"):
                param = self.params.get(token.strip("[]"))
                if param is None:
                    self.error(line, f"{where}: path {path!r}: {token} is not in [Params]")
                    return None
                if not isinstance(param.default, int):
                    self.error(line, f"{where}: path {path!r}: {token} has no numeric default")
                    return None
                out += param.encode()
            elif re.fullmatch(r"[0-9A-Fa-f]{2}", token):
                out.append(int(token, 16))
            else:
                self.error(line, f"{where}: path {path!r}: {token!r} is neither a hex byte nor a [ParamN]")
                return None
        return bytes(out)

    # -- [Connection Manager] ------------------------------------------------------------------------

    def size(self, entry: Entry, index: int, where: str) -> int | None:
        value = self.field(entry, index)
        if not value.empty:
            return self.number(value, entry, index, where)
        reference = self.field(entry, index + 1).text
        if not reference:
            return None
        if reference not in self.assemblies:
            self.error(self.line(entry, index + 1), f"{where}: format {reference} is not in [Assembly]")
            return None
        return self.assembly_size(reference)

    def connection(self, entry: Entry) -> EdsConnection | None:
        where = f"[Connection Manager] {entry.keyword}"
        if len(entry.values) < 15:
            self.error(entry.line, f"{where}: {len(entry.values)} fields, 15 expected")
            return None
        trigger = _int(self.field(entry, 0))
        parameters = _int(self.field(entry, 1))
        if trigger is None or parameters is None:
            self.error(self.line(entry, 0), f"{where}: the trigger and transport and the connection parameters "
                       "must be numbers")
            return None
        kind = next((name for bit, name in _KINDS if trigger >> bit & 1), "other")
        rpi_value = self.field(entry, 2)
        rpi, rpi_default = None, None
        if _REFERENCE.match(rpi_value.text or "-"):
            param = self.params.get(rpi_value.text.strip("[]"))
            if param is None:
                self.error(self.line(entry, 2), f"{where}: RPI {rpi_value.text} is not in [Params]")
            elif isinstance(param.minimum, int) and isinstance(param.maximum, int):
                rpi = (param.minimum, param.maximum)
                rpi_default = param.default if isinstance(param.default, int) else None
        elif not rpi_value.empty:
            rpi_default = self.number(rpi_value, entry, 2, f"{where} RPI")
            rpi = (rpi_default, rpi_default) if rpi_default is not None else None
        t_o_rpi = self.field(entry, 5)
        if _REFERENCE.match(t_o_rpi.text or "-") and t_o_rpi.text.strip("[]") not in self.params:
            self.error(self.line(entry, 5), f"{where}: T->O RPI {t_o_rpi.text} is not in [Params]")
        path = self.field(entry, 14).text
        path_bytes = self.resolve_path(path, self.line(entry, 14), where) if path else b""
        points, key = None, None
        if path_bytes:
            points, key = self.points(path_bytes, self.line(entry, 14), where, path)
        return EdsConnection(
            entry.keyword, self.field(entry, 12).text, kind, trigger, parameters,
            self.size(entry, 3, f"{where} O->T size"), self.size(entry, 6, f"{where} T->O size"),
            self.size(entry, 10, f"{where} configuration #2 size"), rpi, points, path, entry.line,
            self.size(entry, 8, f"{where} configuration #1 size"), self.field(entry, 11).text,
            path_bytes or b"", key, rpi_default)

    def points(self, raw: bytes, line: int, where: str,
               path: str) -> tuple[tuple[int | None, int, int] | None, ElectronicKey | None]:
        try:
            segments = decode_epath(raw)
        except PathError as error:
            self.error(line, f"{where}: path {path!r}: {error}")
            return None, None
        key = next((s for s in segments if isinstance(s, ElectronicKey)), None)
        segments = [s for s in segments if not isinstance(s, (PortSegment, ElectronicKey, DataSegment))]
        if not segments or segments[0] != LogicalSegment(LogicalType.CLASS_ID, ClassCode.ASSEMBLY):
            self.notes.append(f"{where}: path {path!r} names no assembly (class 4); not served")
            return None, key
        values = [s.value for s in segments[1:] if isinstance(s, LogicalSegment)
                  and s.type in (LogicalType.INSTANCE_ID, LogicalType.CONNECTION_POINT)]
        if len(values) == 3:
            return (values[0], values[1], values[2]), key
        if len(values) == 2:
            return (None, values[0], values[1]), key
        self.notes.append(f"{where}: path {path!r}: {len(values)} assembly points, 2 or 3 expected; not served")
        return None, key


def _device_value(reader: _Reader, keyword: str) -> tuple[Value | None, int]:
    entry = reader.parsed.entry("Device", keyword)
    return (entry.values[0] if entry is not None and entry.values else None), (entry.line if entry else 0)


def read_eds(text: str, source: str) -> EdsDevice:
    """The device an EDS describes. Raises EdsError listing every defect, `source:line: reason`."""
    parsed = parse_eds_text(text)
    if "Device" not in parsed.sections:
        first = parsed.errors[0] if parsed.errors else (1, "no [Device] section")
        raise EdsError(f"{source}:{first[0]}: not an EDS file: {first[1]}")
    reader = _Reader(parsed)
    identity: dict[str, int] = {}
    device_line = parsed.sections["Device"].line
    for keyword in _DEVICE_NUMBERS:
        value, line = _device_value(reader, keyword)
        number = _int(value) if value is not None else None
        if value is None or value.empty:
            reader.error(device_line, f"[Device] has no {keyword}")
        elif number is None:
            reader.error(line, f"[Device] {keyword} = {value.text!r}: a number is required"
                         + (" (the vendor id ODVA assigned, not the vendor's name)" if keyword == "VendCode" else ""))
        elif not 0 <= number <= (0xFFFF if keyword in ("VendCode", "ProdType", "ProdCode") else 0xFF):
            reader.error(line, f"[Device] {keyword} = {number} is out of range")
        else:
            identity[keyword] = number
    names = {}
    for keyword in ("VendName", "ProdName", "Catalog"):
        value, _ = _device_value(reader, keyword)
        names[keyword] = value.text if value is not None else ""
    reader.read_params()
    reader.read_assemblies()
    section = parsed.sections.get("Connection Manager")
    connections = []
    for keyword, entry in (section.entries.items() if section else ()):
        if re.fullmatch(r"Connection\d+", keyword):
            connection = reader.connection(entry)
            if connection is not None:
                connections.append(connection)
    for duplicate in [e for s in parsed.sections.values() for e in s.duplicates]:
        reader.notes.append(f"line {duplicate.line}: {duplicate.keyword} given again; the first is used")
    for extra in parsed.duplicate_sections:
        reader.notes.append(f"line {extra.line}: section [{extra.name}] given again; the first is used")
    if reader.errors:
        lines = sorted(set(reader.errors))
        raise EdsError("\n".join(f"{source}:{line}: {reason}" for line, reason in lines))
    catalog = names["Catalog"]
    return EdsDevice(identity["VendCode"], names["VendName"], identity["ProdType"], identity["ProdCode"],
                     (identity["MajRev"], identity["MinRev"]), names["ProdName"], catalog, tuple(connections),
                     tuple(reader.notes), _unverified_items(text, catalog), reader.params, reader.assemblies)


def _unverified_items(text: str, catalog: str) -> tuple[str, ...]:
    """The placeholders an exported EDS lists (`$ UNVERIFIED: DSQC1030.identity.product_code`): the
    base model's (the first of `Catalog`) without its name, an add-on's with it."""
    base = catalog.split(" + ")[0].strip()
    items = [item.removeprefix(f"{base}.") if base else item for item in _UNVERIFIED.findall(text)]
    return tuple(dict.fromkeys(items))


# -- the profile ------------------------------------------------------------------------------------


def _describe(connection: EdsConnection) -> str:
    return f"{connection.keyword} {connection.name!r} ({connection.kind}, path {connection.path})"


def _served(connection: EdsConnection, notes: list[str]) -> dict[str, Any] | None:
    """The profile's entry of a class-1 connection the farm serves, or None (with a note)."""
    if connection.transport_class != 1:
        notes.append(f"{_describe(connection)}: transport class {connection.transport_class}; only class-1 "
                     "entries are served")
        return None
    if connection.kind == "other" or connection.points is None:
        if connection.points is not None:
            notes.append(f"{_describe(connection)}: no application type (exclusive owner, input only, listen only, "
                         "redundant owner); not served")
        return None
    o_t_format = FORMATS.get(connection.o_t_format)
    t_o_format = FORMATS.get(connection.t_o_format)
    if o_t_format is None or t_o_format is None:
        notes.append(f"{_describe(connection)}: real-time formats {connection.o_t_format}/{connection.t_o_format}; "
                     "not served")
        return None
    sizes = {"o_t_size": connection.o_t_size, "t_o_size": connection.t_o_size}
    for role, size in sizes.items():
        if size is None:
            if (o_t_format if role == "o_t_size" else t_o_format) == "heartbeat":
                sizes[role] = 0
                continue
            direction = "O->T" if role == "o_t_size" else "T->O"
            notes.append(f"{_describe(connection)}: no {direction} size (neither in the entry nor in its "
                         "[Assembly] format); not served")
            return None
        if size > MAX_ASSEMBLY_SIZE:
            notes.append(f"{_describe(connection)}: {role} {size} is beyond the farm's {MAX_ASSEMBLY_SIZE} bytes; "
                         "not served")
            return None
    configuration, consumed, produced = connection.points
    entry: dict[str, Any] = {
        "entry": connection.keyword, "name": connection.name, "kind": connection.kind,
        "configuration": configuration, "o_t": consumed, "t_o": produced, **sizes,
        "o_t_format": o_t_format, "t_o_format": t_o_format,
        "o_t_variable": connection.o_t_variable, "t_o_variable": connection.t_o_variable,
        "t_o_multicast": connection.t_o_multicast or not connection.t_o_point_to_point,
        "t_o_point_to_point": connection.t_o_point_to_point or not connection.t_o_multicast,
        "configuration_size": connection.configuration_size or 0,
    }
    if connection.rpi is not None:
        entry["rpi_us"] = list(connection.rpi)
    return entry


def _parameter(param: EdsParam, notes: list[str]) -> dict[str, Any] | None:
    """The profile's entry of a ParamN the Parameter Object serves, or None (a note says why)."""
    if not 1 <= param.size <= 8 or param.data_type not in _TYPE_SIZES:
        notes.append(f"[Params] {param.keyword}: data type 0x{param.data_type:02X} size {param.size}; not served "
                     "by the Parameter Object")
        return None
    link = param.link_path.replace(" ", "")
    entry: dict[str, Any] = {"instance": int(param.keyword[len("Param"):]), "name": param.name,
                             "descriptor": param.descriptor, "data_type": param.data_type, "size": param.size}
    entry.update({k: v for k, v in (("minimum", param.minimum), ("maximum", param.maximum),
                                    ("default", param.default)) if v is not None})
    if re.fullmatch(r"([0-9A-Fa-f]{2})*", link):
        entry["link_path"] = link.upper()
    return entry


def _configuration_data(device: EdsDevice, connection: EdsConnection, size: int) -> str:
    """The configuration assembly's default bytes: its [Assembly] members' parameter defaults."""
    assembly = device.assemblies.get(connection.configuration_format)
    data = bytearray()
    for bits, reference in assembly.members if assembly else ():
        param = device.params.get(reference)
        if bits is None or bits % 8:
            return ""
        data += param.encode()[:bits // 8].ljust(bits // 8, b"\0") if param else bytes(bits // 8)
    return bytes(data[:size]).ljust(size, b"\0").hex() if data else ""


def eds_profile(device: EdsDevice, source: str, name: str | None = None,
                catalogue: Catalogue | None = None) -> tuple[str, dict[str, Any], list[str]]:
    """(model name, profile document, notes) of a device read from an EDS. Raises EdsError when the
    model name would replace a catalogue model."""
    catalogue = shipped_catalogue() if catalogue is None else catalogue
    if name is not None and name in catalogue.models:
        raise EdsError(f"{name!r} is a model of the catalogue: a profile never replaces one, choose another name")
    notes = list(device.notes)
    served = [(c, e) for c in device.connections if (e := _served(c, notes)) is not None]
    owners = [(c, e) for c, e in served if c.kind == "exclusive owner"]
    # the main connection: the first exclusive owner with data both ways, else with any data, else any
    main = next((p for p in owners if p[1]["o_t_size"] and p[1]["t_o_size"]), None) \
        or next((p for p in owners if p[1]["o_t_size"] or p[1]["t_o_size"]), None) \
        or (owners[0] if owners else None) or (served[0] if served else None)
    points: dict[int, int] = {}

    def claim(instance: int | None, size: int) -> None:
        if instance is not None and size >= points.get(instance, -1):
            points[instance] = size

    for _, entry in served:
        claim(entry["o_t"], entry["o_t_size"])
        claim(entry["t_o"], entry["t_o_size"])
        if entry["configuration"] is not None:
            claim(entry["configuration"], entry["configuration_size"])
    for assembly in device.assemblies.values():
        if assembly.instance is not None and assembly.instance not in points:
            size = assembly.size if assembly.size is not None else None
            if size is None:
                continue
            if size <= MAX_ASSEMBLY_SIZE:
                points[assembly.instance] = size
    model: dict[str, Any] = {
        "kind": "base",
        "description": f"from {source}: {device.vendor_name} {device.product_name}".rstrip()
                       + (f", catalog {device.catalog}" if device.catalog else ""),
        "identity": {},
    }
    product_name = device.product_name
    if len(product_name) > 32:
        notes.append(f"product name {product_name!r} cut to 32 characters")
        product_name = product_name[:32]
    model["identity"] = {"vendor_id": device.vendor_id, "device_type": device.device_type,
                         "product_code": device.product_code, "revision": list(device.revision),
                         "product_name": product_name}
    if main is not None:
        connection, entry = main
        configuration = entry["configuration"]
        roles = {"output": entry["o_t"], "input": entry["t_o"],
                 "configuration": configuration if configuration is not None else 1}
        if configuration is None:
            notes.append(f"{_describe(connection)} names no configuration point: the profile takes instance 1")
        if roles["configuration"] in (roles["output"], roles["input"]) or roles["output"] == roles["input"]:
            taken = set(points) | {roles["output"], roles["input"]}
            if roles["output"] == roles["input"]:
                raise EdsError(f"{source}: {_describe(connection)}: O->T and T->O are the same assembly "
                               f"{roles['output']}; the farm serves them as two")
            roles["configuration"] = next(n for n in range(1, 0x10000) if n not in taken)
            notes.append(f"{_describe(connection)}: its configuration point is also an I/O point; the profile's "
                         f"configuration assembly is instance {roles['configuration']}")
        for role, kind in (("input_only", "input only"), ("listen_only", "listen only")):
            heartbeat = next((e for c, e in served if c.kind == kind and e["t_o"] == entry["t_o"]), None)
            if heartbeat is not None:
                roles[role] = heartbeat["o_t"]
        model["assemblies"] = roles
        model["sizes"] = {"output": entry["o_t_size"], "input": entry["t_o_size"],
                          "configuration": points.get(roles["configuration"], 0)}
        data = _configuration_data(device, connection, model["sizes"]["configuration"])
        if data:
            model["configuration_data"] = data
        rpis = [tuple(e["rpi_us"]) for _, e in served if "rpi_us" in e]
        if rpis:
            low, high = min(r[0] for r in rpis), max(r[1] for r in rpis)
            model["rpi_us"] = [low, high]
    else:
        notes.append("no class-1 connection entry the farm serves: an explicit-only device (identity and its "
                     "assemblies)")
    model["io"] = {}
    parameters = [_parameter(p, notes) for p in device.params.values() if p.keyword.startswith("Param")]
    if any(parameters):
        model["parameters"] = [p for p in parameters if p]
    model["connections"] = [e for _, e in served]
    model["points"] = dict(sorted(points.items()))
    model["unverified"] = list(dict.fromkeys(["io layout", *device.unverified]))
    model_name = name or product_name.replace(" ", "_") or "eds"
    while model_name in catalogue.models:
        model_name += "_eds"
    return model_name, {"models": {model_name: model}}, notes


def eds_document(path: Path) -> dict[str, Any]:
    """The profile document of an EDS file named as a device's model (`model: vendor.eds`): as
    `enip-farm eds import` makes it, its model named after the file. Raises EdsError (a ValueError)."""
    device = read_eds(decode_eds_bytes(path.read_bytes()), str(path))
    return eds_profile(device, path.name, path.name)[1]


def eds_catalogue(catalogue: Catalogue | None = None) -> Catalogue:
    """`catalogue` (default: the shipped one) reading EDS files named as a device's model."""
    return (shipped_catalogue() if catalogue is None else catalogue).with_readers({".eds": eds_document})


# -- eds-pie, the independent checker of exported files ---------------------------------------------

class _Collector(logging.Handler):
    """The messages one parse logs: records of the thread that parses (another thread's parse
    logs to the same logger meanwhile)."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.thread = threading.get_ident()
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        if record.thread == self.thread:
            self.messages.append(record.getMessage())


@contextmanager
def _eds_pie_messages() -> Iterator[_Collector]:
    """eds-pie's warnings and errors, collected rather than printed. Its modules call
    `logging.basicConfig(level=DEBUG)` when first imported; a handler on the root logger meanwhile
    makes that call do nothing, so the process's logging is left as it was."""
    root = logging.getLogger()
    guard = logging.NullHandler()
    root.addHandler(guard)
    try:
        import eds_pie.eds_pie  # noqa: F401 (imported for its side effect, once)
    finally:
        root.removeHandler(guard)
    logger = logging.getLogger("eds_pie")
    level = logger.level
    logger.setLevel(logging.INFO)  # not the lexer's line per token; put back afterwards
    collector = _Collector()
    logger.addHandler(collector)
    try:
        yield collector
    finally:
        logger.removeHandler(collector)
        logger.setLevel(level)


def parse_eds(text: str) -> tuple[Any, list[str]]:
    """eds-pie's parse of an EDS (its `EDS` object) and the warnings and errors its checker logged.
    Raises EdsError for text it cannot parse."""
    with _eds_pie_messages() as messages:
        from eds_pie.eds_pie import CIP_EDS

        try:
            eds = CIP_EDS(text)
        except Exception as error:  # eds-pie raises plain Exception for syntax errors
            raise EdsError(f"not an EDS file eds-pie can read ({error})") from None
    return eds, messages.messages
