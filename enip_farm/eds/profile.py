"""The catalogue profile of a device read from an EDS (`eds_profile`): every class-1 connection
entry of [Connection Manager] (Vol. 1 7-3.6.11) with its own points, sizes, real-time formats, RPI
range and connection types (`connections:` of the model), every assembly instance the entries or
[Assembly] (7-3.6.8) name (`points:`), the configuration assembly's default data from its members'
[Params] defaults (7-3.6.7), the Parameter Object's instances, and a device without class-1
entries as an explicit-only device (identity and its assemblies).
"""

from __future__ import annotations

import re
from typing import Any

from enip_farm import words
from enip_farm.cip.data_types import ELEMENTARY
from enip_farm.device.catalogue import MAX_ASSEMBLY_SIZE, Catalogue, shipped_catalogue
from enip_farm.eds.entries import FORMATS, EdsConnection, EdsDevice, EdsError, EdsParam


def _describe(connection: EdsConnection) -> str:
    return f"{connection.keyword} {connection.name!r} ({connection.kind}, path {connection.path})"


def _served(connection: EdsConnection, notes: list[str], assembly_sizes: dict[int, int]) -> dict[str, Any] | None:
    """The profile's entry of a class-1 connection the farm serves, or None (with a note). A
    configuration size the entry leaves empty is its configuration point's [Assembly] size."""
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
        "configuration_size": (connection.configuration_size if connection.configuration_size is not None
                               else assembly_sizes.get(configuration, 0) if configuration is not None else 0),
    }
    if connection.rpi is not None:
        entry["rpi_us"] = list(connection.rpi)
    return entry


def _parameter(param: EdsParam, notes: list[str]) -> dict[str, Any] | None:
    """The profile's entry of a ParamN the Parameter Object serves, or None (a note says why)."""
    if not 1 <= param.size <= 8 or param.data_type not in ELEMENTARY:
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
    assembly_sizes = {a.instance: a.size for a in device.assemblies.values()
                      if a.instance is not None and a.size is not None and a.size <= MAX_ASSEMBLY_SIZE}
    served = [(c, e) for c in device.connections if (e := _served(c, notes, assembly_sizes)) is not None]
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
    model_name = name or words.model_name(device.product_name) or "eds"  # the whole name, not the 32 served
    while model_name in catalogue.models:
        model_name += "_eds"
    return model_name, {"models": {model_name: model}}, notes
