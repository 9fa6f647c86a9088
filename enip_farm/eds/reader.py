"""`enip-farm eds import FILE.eds -o PROFILE.yaml`: a catalogue profile from a vendor's EDS (CIP
Networks Library Vol. 1 chapter 7), parsed with eds-pie (its lexer takes EDS comments, entries
continued over lines and strings split across lines; its checker's warnings are kept as notes).

Taken: the identity from [Device] (VendCode, ProdType, ProdCode, MajRev, MinRev, ProdName); the
assemblies from the first class-1 exclusive-owner entry of [Connection Manager] (its path's
configuration, O->T and T->O points; its O->T, T->O and target configuration sizes, or where a size
is empty the size of the [Assembly] entry its format names, or the sum of that entry's members);
input-only and listen-only heartbeat points from the first such entries. A size given as a ParamN
reference takes that parameter's default. What the farm cannot serve as the EDS says (another
connection's assemblies, a T->O run/idle header, a modeless O->T, an RPI range other than the
device's policy) is reported as a note, never fatal. The I/O layout is not in an EDS in a form the
farm reads: the profile has no numbered signals (`io layout` is unverified); name them with
`signals:`. The `$ UNVERIFIED: MODEL.item` comments `enip-farm eds export` writes carry over into the
profile's unverified items, so a placeholder does not turn into a fact by a round trip.
"""

from __future__ import annotations

import logging
import re
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

from enip_farm.device.catalogue import MAX_ASSEMBLY_SIZE, Catalogue, shipped_catalogue
from enip_farm.protocol.epath import (
    DataSegment,
    ElectronicKey,
    LogicalSegment,
    LogicalType,
    PathError,
    PortSegment,
    decode_epath,
)

_KINDS = ((26, "exclusive owner"), (25, "input only"), (24, "listen only"), (27, "redundant owner"))
_MODELESS, _RUN_IDLE = 0, 4
#: The header comment `enip-farm eds export` writes for each placeholder: `$ UNVERIFIED: MODEL.item`.
_UNVERIFIED = re.compile(r"^\s*\$\s*UNVERIFIED:\s*(\S.*?)\s*$", re.MULTILINE)


class EdsError(ValueError):
    """An EDS the farm cannot make a profile of; the message is one line."""


@dataclass(frozen=True)
class EdsConnection:
    keyword: str  # ConnectionN
    name: str
    kind: str  # exclusive owner, input only, listen only, redundant owner, or other
    transport_classes: int  # bit n: class n
    parameters: int  # the connection parameters word
    o_t_size: int | None
    t_o_size: int | None
    configuration_size: int | None
    rpi: tuple[int, int] | None  # microseconds, from the O->T RPI field
    points: tuple[int | None, int, int] | None  # configuration, consumed (O->T), produced (T->O)
    path: str

    @property
    def o_t_format(self) -> int:
        return self.parameters >> 8 & 7

    @property
    def t_o_format(self) -> int:
        return self.parameters >> 12 & 7


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
    notes: tuple[str, ...]  # the checker's warnings and what could not be read
    unverified: tuple[str, ...] = ()  # the model's items the file's `$ UNVERIFIED:` comments name


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


def _int(value: Any) -> int | None:
    """A number as eds-pie gives it: an int, or the text of one (fields typed by another field)."""
    if isinstance(value, int) and not isinstance(value, bool):
        return value
    try:
        return int(value, 0) if isinstance(value, str) else None
    except ValueError:
        return None


def _reference(value: Any) -> bool:
    return isinstance(value, str) and value.startswith(("Param", "ProxyParam"))


class _Reader:
    def __init__(self, eds: Any, notes: list[str]) -> None:
        self.eds = eds
        self.notes = notes

    def values(self, section: str, keyword: str) -> list[Any]:
        entry = self.eds.get_entry(section, keyword)
        return [field.value for field in entry.fields] if entry is not None else []

    def param(self, reference: Any, index: int) -> int | None:
        """Field `index` of a ParamN entry (9 minimum, 10 maximum, 11 default)."""
        values = self.values("Params", reference) if _reference(reference) else []
        return _int(values[index]) if len(values) > index else None

    def number(self, value: Any) -> int | None:
        """A number given as itself or as a ParamN reference (its default)."""
        return self.param(value, 11) if _reference(value) else _int(value)

    def assembly_size(self, reference: Any) -> int | None:
        values = self.values("Assembly", reference) if isinstance(reference, str) and reference else []
        if len(values) < 3:
            return None
        size = self.number(values[2])
        if size is None and len(values) > 6:
            bits = [self.number(v) for v in values[6::2]]
            size = sum(bits) // 8 if bits and None not in bits and sum(bits) % 8 == 0 else None  # type: ignore[arg-type]
        return size

    def size(self, value: Any, reference: Any) -> int | None:
        size = self.number(value)
        return size if size is not None else self.assembly_size(reference)

    def points(self, keyword: str, path: str) -> tuple[int | None, int, int] | None:
        try:
            raw = bytes.fromhex(self.eds.resolve_epath(path)) if path else b""
            segments = decode_epath(raw)
        except (ValueError, PathError, Exception) as error:  # eds-pie raises plain Exception for references
            self.notes.append(f"[Connection Manager] {keyword}: path {path!r} not read ({error})")
            return None
        segments = [s for s in segments if not isinstance(s, (PortSegment, ElectronicKey, DataSegment))]
        if not segments or segments[0] != LogicalSegment(LogicalType.CLASS_ID, 4):
            return None
        values = [s.value for s in segments[1:] if isinstance(s, LogicalSegment)
                  and s.type in (LogicalType.INSTANCE_ID, LogicalType.CONNECTION_POINT)]
        if len(values) == 3:
            return values[0], values[1], values[2]
        if len(values) == 2:
            return None, values[0], values[1]
        return None

    def connection(self, keyword: str) -> EdsConnection | None:
        values = self.values("Connection Manager", keyword)
        if len(values) < 15:
            self.notes.append(f"[Connection Manager] {keyword}: {len(values)} fields, 15 expected; not read")
            return None
        trigger, parameters = _int(values[0]) or 0, _int(values[1]) or 0
        kind = next((name for bit, name in _KINDS if trigger >> bit & 1), "other")
        rpi = None
        if _reference(values[2]):
            low, high = self.param(values[2], 9), self.param(values[2], 10)
            rpi = (low, high) if low is not None and high is not None else None
        elif _int(values[2]) is not None:
            rpi = (_int(values[2]), _int(values[2]))
        return EdsConnection(
            keyword, str(values[12]), kind, trigger & 0xFFFF, parameters, self.size(values[3], values[4]),
            self.size(values[6], values[7]), self.size(values[10], values[11]), rpi,
            self.points(keyword, str(values[14])), str(values[14]))


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


def read_eds(text: str, source: str) -> EdsDevice:
    """The device an EDS describes. Raises EdsError for text eds-pie cannot parse or an EDS
    without the [Device] identity."""
    try:
        eds, messages = parse_eds(text)
    except EdsError as error:
        raise EdsError(f"{source}: {error}") from None
    notes: list[str] = []
    reader = _Reader(eds, notes)
    device = {keyword: eds.get_value("Device", keyword) for keyword in (
        "VendCode", "VendName", "ProdType", "ProdCode", "MajRev", "MinRev", "ProdName", "Catalog")}
    missing = [k for k in ("VendCode", "ProdType", "ProdCode", "MajRev", "MinRev") if _int(device[k]) is None]
    if missing:
        raise EdsError(f"{source}: [Device] has no {', '.join(missing)}")
    section = eds.get_section("Connection Manager")
    keywords = [k for k in (section.entries if section is not None else ()) if k.startswith("Connection")
                and k[len("Connection"):].isdigit()]
    connections = tuple(c for c in (reader.connection(k) for k in keywords) if c is not None)
    # eds-pie 1.2 logs "Unknown Entry" unformatted; its "Unknown Field" messages name the entry
    notes = [f"eds-pie: {m}" for m in messages if "{entry.keyword}" not in m] + notes
    catalog = str(device["Catalog"] or "")
    return EdsDevice(_int(device["VendCode"]), str(device["VendName"] or ""), _int(device["ProdType"]),
                     _int(device["ProdCode"]), (_int(device["MajRev"]), _int(device["MinRev"])),
                     str(device["ProdName"] or ""), catalog, connections, tuple(notes),
                     _unverified_items(text, catalog))


def _unverified_items(text: str, catalog: str) -> tuple[str, ...]:
    """The placeholders an exported EDS lists (`$ UNVERIFIED: DSQC1030.identity.product_code`): the
    base model's (the first of `Catalog`) without its name, an add-on's with it."""
    base = catalog.split(" + ")[0].strip()
    items = [item.removeprefix(f"{base}.") if base else item for item in _UNVERIFIED.findall(text)]
    return tuple(dict.fromkeys(items))


def _describe(connection: EdsConnection) -> str:
    return f"{connection.keyword} {connection.name!r} ({connection.kind}, path {connection.path})"


def eds_profile(device: EdsDevice, source: str, name: str | None = None,
                catalogue: Catalogue | None = None) -> tuple[str, dict[str, Any], list[str]]:
    """(model name, profile document, notes) of a device read from an EDS. Raises EdsError when it
    has no class-1 exclusive-owner connection the farm can serve, or a size beyond an assembly's."""
    catalogue = shipped_catalogue() if catalogue is None else catalogue
    if name is not None and name in catalogue.models:
        raise EdsError(f"{name!r} is a model of the catalogue: a profile never replaces one, choose another name")
    notes = list(device.notes)
    class_1 = [c for c in device.connections if c.transport_classes & 0x02 and c.points is not None]
    owner = next((c for c in class_1 if c.kind == "exclusive owner"), None)
    if owner is None or owner.points is None:
        raise EdsError(f"{source}: no class-1 exclusive-owner connection in [Connection Manager] with an "
                       "assembly path (20 04 ... 2C <O->T> 2C <T->O>): the farm serves an output and an input assembly")
    configuration, output, inputs = owner.points
    sizes = {"output": owner.o_t_size, "input": owner.t_o_size, "configuration": owner.configuration_size or 0}
    for role, size in sizes.items():
        if size is None:
            raise EdsError(f"{source}: {_describe(owner)}: no {role} size (neither in the entry nor in its "
                           "[Assembly] format)")
        if size > MAX_ASSEMBLY_SIZE:
            raise EdsError(f"{source}: {_describe(owner)}: {role} size {size} is beyond the farm's "
                           f"{MAX_ASSEMBLY_SIZE} bytes")
    assemblies: dict[str, int] = {"output": output, "input": inputs, "configuration": configuration or 1}
    if configuration is None:
        notes.append(f"{_describe(owner)} names no configuration point: the profile takes instance 1")
    if owner.o_t_format != _RUN_IDLE:
        notes.append(f"{_describe(owner)}: O->T real-time format {owner.o_t_format}; the farm takes O->T "
                     "with the 32-bit run/idle header")
    if owner.t_o_format != _MODELESS:
        notes.append(f"{_describe(owner)}: T->O real-time format {owner.t_o_format}; the farm's T->O is modeless")
    served = [owner]
    for role, kind in (("input_only", "input only"), ("listen_only", "listen only")):
        heartbeat = next((c for c in class_1 if c.kind == kind and c.points and c.points[2] == inputs), None)
        if heartbeat is not None and heartbeat.points is not None:
            assemblies[role] = heartbeat.points[1]
            served.append(heartbeat)
    notes += [f"{_describe(c)} is not served: the farm serves the assemblies of {owner.keyword}"
              for c in device.connections if c not in served]
    rpi = owner.rpi
    if rpi is not None:
        notes.append(f"RPI {rpi[0]}..{rpi[1]} us in {owner.keyword}: set the device's implicit.rpi_min_us and "
                     "rpi_max_us to match (the farm's default is 2000..10000000)")
    product_name = device.product_name
    if len(product_name) > 32:
        notes.append(f"product name {product_name!r} cut to 32 characters")
        product_name = product_name[:32]
    model_name = name or product_name.replace(" ", "_") or "eds"
    while model_name in catalogue.models:
        model_name += "_eds"
    model = {
        "kind": "base",
        "description": f"from {source}: {device.vendor_name} {device.product_name}".rstrip()
                       + (f", catalog {device.catalog}" if device.catalog else ""),
        "identity": {"vendor_id": device.vendor_id, "device_type": device.device_type,
                     "product_code": device.product_code, "revision": list(device.revision),
                     "product_name": product_name},
        "assemblies": assemblies,
        "sizes": sizes,
        "io": {},
        "unverified": list(dict.fromkeys(["io layout", *device.unverified])),
    }
    return model_name, {"models": {model_name: model}}, notes
