"""`enip-farm eds export MODEL -o FILE.eds`: the EDS of a catalogue model as the farm serves it
(CIP Networks Library Vol. 1 chapter 7: [File], [Device], [Device Classification], [Params], [Assembly],
[Connection Manager], [Capacity]). A CIP Safety target (the DSQC1042) gets its safe assemblies and
its two safety connections (class 0, Vol. 5) instead of class-1 ones: `_safety_sections`.

Every value is the farm's: the identity, assembly instances and sizes of the resolved profile, the
channel layout of its modules (each module's digital bytes, then its analog INTs, in slot order),
the connection points it admits (exclusive owner; input only and listen only where the model has
heartbeat points) and the RPI range and connection limits of its implicit policy. A value the
catalogue lists as unverified is written as it is and marked UNVERIFIED in a comment beside it.

Connection entry fields ([Connection Manager]): trigger and transport (bit 1 class 1, bit 16
cyclic, bit 24 listen only, 25 input only, 26 exclusive owner), connection parameters (bits 0-3 fixed or
variable O->T and T->O sizes, 8-10 and 12-14 real-time formats: 0 modeless, 3 heartbeat, 4 32-bit
run/idle header; 16-18 and 20-22 O->T and T->O connection types null, multicast, point to point;
24-26 and 28-30 priorities), O->T RPI, size, format, T->O RPI, size, format, proxy and target
configuration sizes and formats, name, help, path. Sizes are application data, without sequence
count or header.
"""

from __future__ import annotations

import datetime
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType

from enip_farm.config import ConfigError, is_profile_path, parse_config
from enip_farm.device.build import build_profiles
from enip_farm.device.catalogue import Catalogue
from enip_farm.device.profile import AssemblySpec, DeviceProfile
from enip_farm.protocol.cip import ClassCode
from enip_farm.protocol.epath import LogicalType, encode_logical

#: Trigger and transport: class 1, cyclic, and the connection type bit.
EXCLUSIVE_OWNER, INPUT_ONLY, LISTEN_ONLY = 0x04010002, 0x02010002, 0x01010002
#: Connection parameters: every priority; T->O fixed, modeless, point to point or multicast (listen
#: only: multicast); O->T point to point, fixed or variable with the run/idle header (exclusive
#: owner) or a fixed heartbeat (input only, listen only). The farm's admission, cip/admission.py.
EXCLUSIVE_OWNER_PARAMETERS, INPUT_ONLY_PARAMETERS, LISTEN_ONLY_PARAMETERS = 0x77640407, 0x77640305, 0x77240305
VENDOR_NAMES = MappingProxyType({75: "ABB Robotics"})
DEVICE_TYPES = MappingProxyType({0x07: "General Purpose Discrete I/O", 0x0C: "Communications Adapter",
                                 0x2B: "Generic Device"})
_DATA_TYPES = MappingProxyType({8: (0xD1, "BYTE"), 16: (0xD2, "WORD"), 32: (0xD3, "DWORD")})
_INT, _UDINT = 0xC3, 0xC8
_INDENT, _FIELD = " " * 8, " " * 16
_ASSEMBLY_CLASS = (LogicalType.CLASS_ID, ClassCode.ASSEMBLY)
_ASSEMBLY_CODE = f"{_INDENT}Object_Class_Code = {ClassCode.ASSEMBLY:#04x};"
_CONNECTION_MANAGER_CODE = f"{_INDENT}Object_Class_Code = {ClassCode.CONNECTION_MANAGER:#04x};"


@dataclass(frozen=True)
class _Member:
    bits: int
    param: int


def _quote(text: str) -> str:
    return '"' + text.replace('"', "'") + '"'


def _path(*segments: tuple[LogicalType, int]) -> str:
    return " ".join(f"{byte:02X}" for segment in segments for byte in encode_logical(*segment))


def _entry(keyword: str, fields: list[tuple[str, str]]) -> str:
    """An entry written field per line, each with its comment, as EDS tools write them."""
    lines = [f"{_INDENT}{keyword} ="]
    for index, (value, comment) in enumerate(fields):
        text = f"{_FIELD}{value}{';' if index == len(fields) - 1 else ','}"
        lines.append(f"{text:<47} $ {comment}" if comment else text)
    return "\n".join(lines)


class _Params:
    def __init__(self) -> None:
        self.entries: list[str] = []

    def add(self, name: str, data_type: int, size: int, units: str, help_text: str,
            limits: tuple[str, str, str] = ("", "", "")) -> int:
        number = len(self.entries) + 1
        self.entries.append(_entry(f"Param{number}", [
            ("0", "reserved, shall be 0"), (",", "link path size, link path"), ("0x0000", "descriptor"),
            (f"0x{data_type:02X}", "data type"), (str(size), "data size in bytes"), (_quote(name), "name"),
            (_quote(units), "units"), (_quote(help_text), "help string"),
            (",".join(limits), "minimum, maximum, default"), (",,,", "scaling: multiplier, divisor, base, offset"),
            (",,,", "links: multiplier, divisor, base, offset"), ("", "decimal places")]))
        return number


def _members(profile: DeviceProfile, params: _Params, role: str) -> list[_Member]:
    """The image's channels, one member per module's digital bytes and one per analog INT."""
    members: list[_Member] = []
    digital, analog = ("di", "ai") if role == "input" else ("do", "ao")
    first = {"di": 1, "do": 1, "ai": 1, "ao": 1}
    for module in profile.modules:
        count = getattr(module.io, digital)
        if count:
            bits = 8 * ((count + 7) // 8)
            data_type, type_name = _DATA_TYPES.get(bits, (0xD1, "BYTE"))
            name = f"{digital.upper()}{first[digital]}-{first[digital] + count - 1}"
            size = bits // 8 if bits in _DATA_TYPES else 1
            number = params.add(f"{module.model} {name}", data_type, size, "",
                                f"{type_name}, bit 0 = {digital.upper()}{first[digital]}")
            members += [_Member(bits, number)] if bits in _DATA_TYPES else [_Member(8, number)] * (bits // 8)
            first[digital] += count
        for _ in range(getattr(module.io, analog)):
            name = f"{analog.upper()}{first[analog]}"
            members.append(_Member(16, params.add(f"{module.model} {name}", _INT, 2, "", "INT, raw value")))
            first[analog] += 1
    return members


def _assembly(instance: int, name: str, size: int, members: list[_Member]) -> str:
    fields = [(_quote(name), "name"), (_quote(_path(_ASSEMBLY_CLASS, (LogicalType.INSTANCE_ID, instance),
                                                   (LogicalType.ATTRIBUTE_ID, 3))), "path"),
              (str(size), "size in bytes"), ("0x0000", "descriptor"), (",", "reserved")]
    if sum(m.bits for m in members) != 8 * size:
        members = []  # sizes given in the configuration, not from the modules: no members to describe
    fields += [(f"{m.bits},Param{m.param}", "member size in bits, member") for m in members]
    if not members:
        fields[-1] = (",", "reserved (no members)")
    return _entry(f"Assem{instance}", fields)


def _connection(number: int, kind: int, parameters: int, o_t: tuple[int, str], t_o: tuple[int, str],
                configuration: tuple[int, str], name: str, path: str) -> str:
    return _entry(f"Connection{number}", [
        (f"0x{kind:08X}", "trigger and transport: class 1, cyclic, " + name.lower()),
        (f"0x{parameters:08X}", "connection parameters"),
        (f"Param1,{o_t[0]},{o_t[1]}", "O->T RPI, size, format"),
        (f"Param1,{t_o[0]},{t_o[1]}", "T->O RPI, size, format"),
        (",", "proxy configuration size, format"),
        (f"{configuration[0]},{configuration[1]}", "target configuration size, format"),
        (_quote(name), "connection name"), (_quote(""), "help string"), (_quote(path), "path")])


def _unverified(profile: DeviceProfile, item: str) -> str:
    return "  $ UNVERIFIED placeholder" if f"{profile.model}.{item}" in profile.unverified else ""


def write_eds(profile: DeviceProfile, created: datetime.datetime) -> str:
    """The EDS text of a device as the farm serves it; `created` dates the file."""
    modules = " + ".join((profile.model, *profile.addons))
    date, time = created.strftime("%m-%d-%Y"), created.strftime("%H:%M:%S")
    implicit = profile.implicit
    lines = [
        f"$ Electronic Data Sheet of the enip-farm emulation of {modules}, written by `enip-farm eds export`.",
        "$ The values are the farm's catalogue and policy, not a datasheet of the module: ABB does not publish",
        "$ the device type, product codes, revisions, product names, assembly layouts with add-ons or RPI",
        "$ limits of these modules. Values marked UNVERIFIED are placeholders; so are the channel layout",
        "$ (each module's digital bytes, then its analog INTs, in slot order) and the connection limits.",
    ]
    lines += [f"$ UNVERIFIED: {item}" for item in profile.unverified]
    vendor = VENDOR_NAMES.get(profile.vendor_id, f"Vendor {profile.vendor_id}")
    device_type = DEVICE_TYPES.get(profile.device_type, f"Device type {profile.device_type}")
    lines += [
        "",
        "[File]",
        f"{_INDENT}DescText = {_quote(f'enip-farm emulation of {modules} (values unverified)')};",
        f"{_INDENT}CreateDate = {date};",
        f"{_INDENT}CreateTime = {time};",
        f"{_INDENT}ModDate = {date};",
        f"{_INDENT}ModTime = {time};",
        f"{_INDENT}Revision = 1.0;",
        "",
        "[Device]",
        f"{_INDENT}VendCode = {profile.vendor_id};",
        f"{_INDENT}VendName = {_quote(vendor)};",
        f"{_INDENT}ProdType = {profile.device_type};{_unverified(profile, 'identity.device_type')}",
        f"{_INDENT}ProdTypeStr = {_quote(device_type)};",
        f"{_INDENT}ProdCode = {profile.product_code};{_unverified(profile, 'identity.product_code')}",
        f"{_INDENT}MajRev = {profile.revision[0]};{_unverified(profile, 'identity.revision')}",
        f"{_INDENT}MinRev = {profile.revision[1]};{_unverified(profile, 'identity.revision')}",
        f"{_INDENT}ProdName = {_quote(profile.product_name)};{_unverified(profile, 'identity.product_name')}",
        f"{_INDENT}Catalog = {_quote(modules)};",
        "",
        "[Device Classification]",
        f"{_INDENT}Class1 = EtherNetIP;",
    ]
    output, inputs, configuration = (profile.assembly(role) for role in ("output", "input", "configuration"))
    if output is None or inputs is None:
        lines += ["", "$ No assemblies: identity and explicit messaging only (no I/O connections)."]
        return "\n".join(lines) + "\n"
    if profile.safety is not None:
        return "\n".join(lines + _safety_sections(profile, output, inputs, configuration)) + "\n"

    if profile.connections:
        return "\n".join(lines + _declared_sections(profile)) + "\n"
    params = _Params()
    default_rpi = min(max(10_000, implicit.rpi_min_us), implicit.rpi_max_us)
    params.add("RPI", _UDINT, 4, "microsecond", "Requested packet interval (the farm's policy, unverified)",
               (str(implicit.rpi_min_us), str(implicit.rpi_max_us), str(default_rpi)))
    output_members = _members(profile, params, "output")
    input_members = _members(profile, params, "input")
    lines += ["", "[Params]", *params.entries]
    lines += ["", "[Assembly]", f"{_INDENT}Object_Name = {_quote('Assembly Object')};",
              _ASSEMBLY_CODE,
              _assembly(output.instance_id, "Output", output.size, output_members),
              _assembly(inputs.instance_id, "Input", inputs.size, input_members)]
    config_format = ""
    if configuration is not None and configuration.size:
        lines.append(_assembly(configuration.instance_id, "Configuration", configuration.size, []))
        config_format = f"Assem{configuration.instance_id}"
    config_point = [(LogicalType.INSTANCE_ID, configuration.instance_id)] if configuration is not None else []
    config_size = configuration.size if configuration is not None else 0

    def connection_path(consumed: int) -> str:
        return _path(_ASSEMBLY_CLASS, *config_point, (LogicalType.CONNECTION_POINT, consumed),
                     (LogicalType.CONNECTION_POINT, inputs.instance_id))

    t_o = (inputs.size, f"Assem{inputs.instance_id}")
    connections = [(EXCLUSIVE_OWNER, EXCLUSIVE_OWNER_PARAMETERS, (output.size, f"Assem{output.instance_id}"),
                    "Exclusive Owner", output.instance_id)]
    if profile.input_only_point is not None:
        connections.append((INPUT_ONLY, INPUT_ONLY_PARAMETERS, (0, ""), "Input Only", profile.input_only_point))
    if profile.listen_only_point is not None:
        connections.append((LISTEN_ONLY, LISTEN_ONLY_PARAMETERS, (0, ""), "Listen Only", profile.listen_only_point))
    lines += ["", "[Connection Manager]", f"{_INDENT}Object_Name = {_quote('Connection Manager Object')};",
              _CONNECTION_MANAGER_CODE]
    if profile.input_only_point is not None or profile.listen_only_point is not None:
        lines.append(f"{_INDENT}$ Input-only and listen-only heartbeat points are a common convention, "
                     "unverified for these modules.")
    lines += [_connection(number, kind, parameters, o_t, t_o, (config_size, config_format), name,
                          connection_path(point))
              for number, (kind, parameters, o_t, name, point) in enumerate(connections, 1)]
    lines += ["", "[Capacity]", f"{_INDENT}$ The farm's limits per device (its guards, not the module's).",
              f"{_INDENT}MaxIOConnections = {implicit.max_class1_connections};",
              f"{_INDENT}MaxMsgConnections = {implicit.max_class3_connections};"]
    return "\n".join(lines) + "\n"


#: CIP Safety connections (Vol. 5, 3-5.4 and the EDS keywords of chapter 7 of Vol. 1): transport
#: class 0, application-object trigger (bit 18); the safety output connection is a server (bit 31)
#: that owns the outputs (bit 26), the safety input connection a client (bit 31 clear) producing
#: the inputs (bit 25, input only). Parameters: fixed sizes both ways (bits 0, 2), modeless (the
#: safety message carries its own mode byte), point to point both ways (bits 18, 22), high or
#: scheduled priority (bits 25-26, 29-30), as cip/safety/admission.py admits them.
SAFETY_OUTPUT, SAFETY_INPUT, SAFETY_PARAMETERS = 0x84040001, 0x02040001, 0x66440005
_SAFETY_RPI_MIN_US, _SAFETY_RPI_MAX_US = 1_000, 100_000  # base format data RPI (the admission's limits)


def _safety_sections(profile: DeviceProfile, output: AssemblySpec, inputs: AssemblySpec,
                     configuration: AssemblySpec | None) -> list[str]:
    """The safety assemblies and the two safety connections
    of a CIP Safety target as the farm admits them (the SafetyOpen's path: configuration point,
    consumed point, produced point; the null point where a direction carries no safe data)."""
    assert profile.safety is not None
    null = profile.safety.null_point
    params = _Params()
    params.add("Safety RPI", _UDINT, 4, "microsecond", "Requested packet interval of safety data (base format; "
               "the farm's limits, unverified)", (str(_SAFETY_RPI_MIN_US), str(_SAFETY_RPI_MAX_US), "10000"))
    output_members, input_members = _members(profile, params, "output"), _members(profile, params, "input")
    config = configuration.instance_id if configuration is not None else null

    def connection(number: int, kind: int, o_t: tuple[int, str], t_o: tuple[int, str], name: str,
                   consumed: int, produced: int) -> str:
        path = _path(_ASSEMBLY_CLASS, (LogicalType.INSTANCE_ID, config),
                     (LogicalType.CONNECTION_POINT, consumed), (LogicalType.CONNECTION_POINT, produced))
        return _entry(f"Connection{number}", [
            (f"0x{kind:08X}", "trigger and transport: class 0, application object, "
             + ("server, exclusive owner" if kind == SAFETY_OUTPUT else "client, input only")),
            (f"0x{SAFETY_PARAMETERS:08X}", "connection parameters"),
            (f"Param1,{o_t[0]},{o_t[1]}", "O->T RPI, size, format"),
            (f"Param1,{t_o[0]},{t_o[1]}", "T->O RPI, size, format"),
            (",", "proxy configuration size, format"), ("0,", "target configuration size, format"),
            (_quote(name), "connection name"),
            (_quote("CIP Safety (Vol. 5); the other direction carries time coordination"), "help string"),
            (_quote(path), "path")])

    return [
        f"{_INDENT}$ No Class2 = Safety: eds-pie's checker takes no classification after a public one (Class1).",
        "", "$ A CIP Safety target: its safe I/O travels over CIP Safety connections only, no class-1 I/O.",
        "", "[Params]", *params.entries,
        "", "[Assembly]", f"{_INDENT}Object_Name = {_quote('Assembly Object')};", _ASSEMBLY_CODE,
        _assembly(output.instance_id, "Safe Outputs", output.size, output_members),
        _assembly(inputs.instance_id, "Safe Inputs", inputs.size, input_members),
        "", "[Connection Manager]", f"{_INDENT}Object_Name = {_quote('Connection Manager Object')};",
        _CONNECTION_MANAGER_CODE,
        connection(1, SAFETY_OUTPUT, (output.size, f"Assem{output.instance_id}"), (0, ""), "Safety Output",
                   output.instance_id, null),
        connection(2, SAFETY_INPUT, (0, ""), (inputs.size, f"Assem{inputs.instance_id}"), "Safety Input",
                   null, inputs.instance_id),
        "", "[Capacity]", f"{_INDENT}$ The farm's limit of safety connections per device (unverified).",
        f"{_INDENT}MaxIOConnections = {profile.safety.max_connections};",
    ]
#: Real-time formats as connection parameters give them (bits 8-10 O->T, 12-14 T->O).
_FORMAT_CODES = MappingProxyType({"modeless": 0, "zero length": 1, "heartbeat": 3, "run/idle": 4})
_KIND_BITS = MappingProxyType({"listen only": 24, "input only": 25, "exclusive owner": 26, "redundant owner": 27})


def _declared_sections(profile: DeviceProfile) -> list[str]:
    """[Params], [Assembly], [Connection Manager] and [Capacity] of a device that serves the class-1
    connections its EDS declared (an imported profile): every entry as the farm admits it."""
    implicit = profile.implicit
    params = _Params()
    rpi_params: dict[tuple[int, int], int] = {}
    for entry in profile.connections:
        if entry.rpi_us is None:
            continue  # the RPI field left empty: the device's policy applies
        low, high = entry.rpi_us
        if (low, high) not in rpi_params:
            rpi_params[(low, high)] = params.add("RPI", _UDINT, 4, "microsecond", "Requested packet interval",
                                                 (str(low), str(high), str(min(max(10_000, low), high))))
    lines = ["", "[Params]", *params.entries] if params.entries else []  # eds-pie refuses an empty section
    lines += ["", "[Assembly]", f"{_INDENT}Object_Name = {_quote('Assembly Object')};",
              _ASSEMBLY_CODE]
    named = {entry.configuration for entry in profile.connections}
    sizes = {spec.instance_id: spec.size for spec in profile.assemblies
             if spec.role != "configuration" or spec.instance_id in named}
    lines += [_assembly(instance, f"Assembly {instance}", size, []) for instance, size in sorted(sizes.items())]
    lines += ["", "[Connection Manager]", f"{_INDENT}Object_Name = {_quote('Connection Manager Object')};",
              _CONNECTION_MANAGER_CODE]
    for number, entry in enumerate(profile.connections, 1):
        trigger = 0x00010002 | 1 << _KIND_BITS[entry.kind]
        parameters = (0x77040000 | _FORMAT_CODES[entry.o_t_format] << 8 | _FORMAT_CODES[entry.t_o_format] << 12
                      | (2 if entry.o_t_variable else 1) | (8 if entry.t_o_variable else 4)
                      | entry.t_o_multicast << 21 | entry.t_o_point_to_point << 22)
        rpi = f"Param{rpi_params[entry.rpi_us]}" if entry.rpi_us is not None else ""
        config_point = [(LogicalType.INSTANCE_ID, entry.configuration)] if entry.configuration is not None else []
        path = _path(_ASSEMBLY_CLASS, *config_point, (LogicalType.CONNECTION_POINT, entry.o_t),
                     (LogicalType.CONNECTION_POINT, entry.t_o))
        lines.append(_entry(f"Connection{number}", [
            (f"0x{trigger:08X}", f"trigger and transport: class 1, cyclic, {entry.kind}"),
            (f"0x{parameters:08X}", f"connection parameters: O->T {entry.o_t_format}, T->O {entry.t_o_format}"),
            (f"{rpi},{entry.o_t_size},", "O->T RPI, size, format"),
            (f"{rpi},{entry.t_o_size},", "T->O RPI, size, format"),
            (",", "proxy configuration size, format"),
            (f"{entry.configuration_size},", "target configuration size, format"),
            (_quote(entry.name or entry.entry), "connection name"), (_quote(""), "help string"),
            (_quote(path), "path")]))
    return lines + ["", "[Capacity]", f"{_INDENT}MaxIOConnections = {implicit.max_class1_connections};",
                    f"{_INDENT}MaxMsgConnections = {implicit.max_class3_connections};"]


def model_profile(model: str, addons: Sequence[str], catalogue: Catalogue, base_dir: str | Path = ".") -> DeviceProfile:
    """The profile a device of `model` (a catalogue model or a profile file) with `addons` gets.
    Raises ConfigError (one line per problem) for an unknown model or add-on."""
    problems = [] if is_profile_path(model) or model in catalogue.bases() else [
        f"eds export: unknown model {model!r}; known: {', '.join(catalogue.bases())}, or a profile file "
        "(PROFILE.yaml, FILE.eds)"]
    problems += [f"eds export: unknown add-on {addon!r}; known: {', '.join(catalogue.addons())}"
                 for addon in addons if addon not in catalogue.addons()]
    if problems:
        raise ConfigError("\n".join(problems))
    device = {"name": "eds", "address": "127.0.0.1", "model": model, "addons": list(addons)}
    config = parse_config({"devices": [device]}, "eds export", base_dir)
    (profile,) = build_profiles(config, catalogue)
    return profile
