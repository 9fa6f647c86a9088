"""The Parameter Object, class 0x0F (CIP Networks Library Vol. 1, 5-14): one instance per
parameter an EDS's [Params] declares (ParamN is instance N). Instance attributes: 1 parameter value
(its data type, settable unless the descriptor says read only: 0x0E; outside the EDS's minimum and
maximum: 0x09), 2 link path size, 3 link path, 4 descriptor, 5 data type, 6 data size.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from enip_farm.cip.object import Attribute, CipClass, CipInstance
from enip_farm.protocol.cip import ClassCode
from enip_farm.protocol.status import GeneralStatus

_READ_ONLY = 0x0010  # descriptor bit 4
_FLOATS = {0xCA: "<f", 0xCB: "<d"}
_SIGNED = {0xC2, 0xC3, 0xC4, 0xC5}


@dataclass(frozen=True)
class ParameterSpec:
    """A parameter as an EDS declares it: instance number, data type and size, limits, default."""

    instance: int
    name: str
    descriptor: int
    data_type: int
    size: int
    minimum: float | None = None
    maximum: float | None = None
    default: float | None = None
    link_path: bytes = b""


class ParameterInstance:
    """One parameter's current value, as its data type encodes it."""

    __slots__ = ("spec", "data")

    def __init__(self, spec: ParameterSpec) -> None:
        self.spec = spec
        self.data = self.encode(spec.default if spec.default is not None else 0)

    def encode(self, value: float) -> bytes:
        form = _FLOATS.get(self.spec.data_type)
        if form is not None:
            return struct.pack(form, float(value))
        return int(value).to_bytes(self.spec.size, "little", signed=self.spec.data_type in _SIGNED)

    def decode(self, data: bytes) -> float:
        form = _FLOATS.get(self.spec.data_type)
        if form is not None:
            return struct.unpack(form, data)[0]
        return int.from_bytes(data, "little", signed=self.spec.data_type in _SIGNED)

    def set(self, data: bytes) -> int:
        if len(data) < len(self.data):
            return GeneralStatus.NOT_ENOUGH_DATA
        if len(data) > len(self.data):
            return GeneralStatus.TOO_MUCH_DATA
        value, spec = self.decode(data), self.spec
        if (spec.minimum is not None and value < spec.minimum) or (spec.maximum is not None and value > spec.maximum):
            return GeneralStatus.INVALID_ATTRIBUTE_VALUE
        self.data = bytes(data)
        return GeneralStatus.SUCCESS


class ParameterObject(CipClass):
    class_id = ClassCode.PARAMETER
    revision = 1

    def __init__(self, parameters: list[ParameterSpec]) -> None:
        super().__init__()
        self.parameters: dict[int, ParameterInstance] = {}
        for spec in parameters:
            parameter = self.parameters[spec.instance] = ParameterInstance(spec)
            self.instances[spec.instance] = CipInstance({
                1: Attribute(lambda p=parameter: p.data, None if spec.descriptor & _READ_ONLY else parameter.set),
                2: Attribute(lambda s=spec: bytes((len(s.link_path),))),
                3: Attribute(lambda s=spec: s.link_path),
                4: Attribute(lambda s=spec: struct.pack("<H", s.descriptor)),
                5: Attribute(lambda s=spec: bytes((s.data_type,))),
                6: Attribute(lambda s=spec: bytes((s.size,))),
            })
