"""The sections of an EDS that describe its data and connections (CIP Networks Library Vol. 1
chapter 7): [Params] (7-3.6.7: data type, limits, default, read-only), [Assembly] (7-3.6.8:
instance from its path, size, members) and every ConnectionN of [Connection Manager] (7-3.6.11:
application type, transport class and trigger, connection parameters, RPI and sizes as numbers or
a ParamN's default within its limits, an empty size being its [Assembly] format's size,
configuration #1 and #2 sizes, its path with `[ParamN]` references resolved, 7-3.6.11.9). Real
defects are collected as (line, reason) errors, what the farm cannot serve as notes: e.g. a path
`SYMBOL_ANSI` (a produced or consumed tag whose name the user chooses, not an assembly).
"""

from __future__ import annotations

import re

from enip_farm.cip.data_types import ELEMENTARY
from enip_farm.eds.entries import (
    EdsAssembly,
    EdsConnection,
    EdsParam,
    parse_int,
    parse_number,
)
from enip_farm.eds.grammar import EdsText, Entry, Value
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
_REFERENCE = re.compile(r"^\[?((?:Proxy)?Param|Assem|ProxyAssem)(\d+)\]?$")
#: The EDS path keyword of a symbolic (ANSI extended symbol) segment the user fills in.
SYMBOL_ANSI = "SYMBOL_ANSI"


def _symbolic(path: str) -> bool:
    return SYMBOL_ANSI in path.replace(",", " ").split()


class SectionReader:
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
                data_type = parse_int(self.field(entry, 4))
                size = parse_int(self.field(entry, 5))
                if data_type is None or size is None:
                    self.error(self.line(entry, 4), f"[Params] {keyword}: data type and size must be numbers")
                    continue
                limits = [parse_number(self.field(entry, i)) for i in (9, 10, 11)]
                for index, number in zip((9, 10, 11), limits, strict=True):
                    text = self.field(entry, index).text
                    if number is None and text and not _REFERENCE.match(text):
                        self.notes.append(f"[Params] {keyword}: {('minimum', 'maximum', 'default')[index - 9]} "
                                          f"{text!r} is not a number; not used")
                minimum, maximum, default = limits
                elementary = ELEMENTARY.get(data_type)
                param = EdsParam(keyword, entry.line, parse_int(self.field(entry, 3)) or 0, data_type,
                                 size or (elementary.size if elementary is not None else 0), self.field(entry, 6).text,
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
            if path and _symbolic(path):
                self.notes.append(f"line {self.line(entry, 1)}: [Assembly] {keyword}: path {path!r}: a tag the user "
                                  "names, not an assembly instance; not served")
            elif path:
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
            members = tuple((parse_int(entry.values[i]), entry.values[i + 1].text if i + 1 < len(entry.values) else "")
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
        number = parse_int(value)
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
        trigger = parse_int(self.field(entry, 0))
        parameters = parse_int(self.field(entry, 1))
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
        symbolic = _symbolic(path)
        if symbolic:
            self.notes.append(f"line {self.line(entry, 14)}: {where} {self.field(entry, 12).text!r}: path {path!r}: "
                              "a tag the user names (ANSI extended symbol segment), not assembly points; not served")
        path_bytes = self.resolve_path(path, self.line(entry, 14), where) if path and not symbolic else b""
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
