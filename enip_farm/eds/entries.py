"""What an EDS's entries mean, as typed values (CIP Networks Library Vol. 1 chapter 7): a ParamN
of [Params] (7-3.6.7), an AssemN of [Assembly] (7-3.6.8), a ConnectionN of [Connection Manager]
(7-3.6.11, its trigger and transport and connection parameters words decoded), the device of
[Device] (7-3.6.2), and the numbers fields hold. EdsError is every reader's refusal.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from types import MappingProxyType

from enip_farm.cip.data_types import SIGNED
from enip_farm.eds.grammar import Value
from enip_farm.protocol.epath import ElectronicKey

#: Real-time transfer formats, connection parameters bits 8-10 (O->T) and 12-14 (T->O). Real files
#: give 3 for heartbeat connections (no data) and 4 for the 32-bit run/idle header.
FORMATS = MappingProxyType({0: "modeless", 1: "zero length", 2: "heartbeat", 3: "heartbeat", 4: "run/idle"})


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
        return int(value).to_bytes(self.size, "little", signed=self.data_type in SIGNED and int(value) < 0)


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


def parse_number(value: Value | str | None) -> int | float | None:
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


def parse_int(value: Value | str | None) -> int | None:
    found = parse_number(value)
    return found if isinstance(found, int) else None
