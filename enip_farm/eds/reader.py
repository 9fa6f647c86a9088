"""`enip-farm eds import FILE.eds -o PROFILE.yaml`: a catalogue profile from a vendor's EDS (CIP
Networks Library Vol. 1 chapter 7; Vol. 2 for EtherNet/IP's [Connection Manager] and [Port]).

This module reads [Device] (7-3.6.2: the identity; a non-numeric VendCode is an error), has the
other sections read, and refuses the file's real defects all at once, one `file:line: reason`
each; what the farm does not use (vendor sections and keywords, objects) is kept in the parse and
never fatal; what it cannot serve as the EDS says is a note. The `$ UNVERIFIED: MODEL.item`
comments `enip-farm eds export` writes carry over into the profile's unverified items.

The parts: the syntax is grammar.py's (a lark grammar); the typed entries entries.py's; [Params],
[Assembly] and [Connection Manager] sections.py's; the profile profile.py's; eds-pie, the
independent checker of the files `eds export` writes, checker.py's. Their public names are
importable from here too.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from enip_farm.device.catalogue import Catalogue, shipped_catalogue
from enip_farm.eds.checker import _eds_pie_messages, parse_eds
from enip_farm.eds.entries import EdsAssembly, EdsConnection, EdsDevice, EdsError, EdsParam, parse_int
from enip_farm.eds.grammar import Value, decode_eds_bytes, parse_eds_text
from enip_farm.eds.profile import eds_profile
from enip_farm.eds.sections import SectionReader

__all__ = ["EdsAssembly", "EdsConnection", "EdsDevice", "EdsError", "EdsParam", "_eds_pie_messages", "eds_catalogue",
           "eds_document", "eds_profile", "parse_eds", "read_eds"]

_UNVERIFIED = re.compile(r"^\s*\$\s*UNVERIFIED:\s*(\S.*?)\s*$", re.MULTILINE)
_DEVICE_NUMBERS = ("VendCode", "ProdType", "ProdCode", "MajRev", "MinRev")


def _device_value(reader: SectionReader, keyword: str) -> tuple[Value | None, int]:
    entry = reader.parsed.entry("Device", keyword)
    return (entry.values[0] if entry is not None and entry.values else None), (entry.line if entry else 0)


def read_eds(text: str, source: str) -> EdsDevice:
    """The device an EDS describes. Raises EdsError listing every defect, `source:line: reason`."""
    parsed = parse_eds_text(text)
    if "Device" not in parsed.sections:
        first = parsed.errors[0] if parsed.errors else (1, "no [Device] section")
        raise EdsError(f"{source}:{first[0]}: not an EDS file: {first[1]}")
    reader = SectionReader(parsed)
    identity: dict[str, int] = {}
    device_line = parsed.sections["Device"].line
    for keyword in _DEVICE_NUMBERS:
        value, line = _device_value(reader, keyword)
        number = parse_int(value) if value is not None else None
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
    for line, reason in parsed.warnings:
        reader.notes.append(f"line {line}: {reason}")
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


def eds_document(path: Path) -> dict[str, Any]:
    """The profile document of an EDS file named as a device's model (`model: vendor.eds`): as
    `enip-farm eds import` makes it, its model named after the file. Raises EdsError (a ValueError)."""
    device = read_eds(decode_eds_bytes(path.read_bytes()), str(path))
    return eds_profile(device, path.name, path.name)[1]


def eds_catalogue(catalogue: Catalogue | None = None) -> Catalogue:
    """`catalogue` (default: the shipped one) reading EDS files named as a device's model."""
    return (shipped_catalogue() if catalogue is None else catalogue).with_readers({".eds": eds_document})
