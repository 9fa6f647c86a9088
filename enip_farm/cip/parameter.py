"""The Parameter Object, class 0x0F (CIP Networks Library Vol. 1, 5-14): one instance per
parameter an EDS's [Params] declares (ParamN is instance N). Instance attributes: 1 parameter value
(its data type, settable unless the descriptor says read only: 0x0E; outside the EDS's minimum and
maximum: 0x09), 2 link path size, 3 link path, 4 descriptor, 5 data type, 6 data size.
"""

from __future__ import annotations

from dataclasses import dataclass

from enip_farm.cip.attribute import Attribute, CipInstance
from enip_farm.cip.data_types import ELEMENTARY, SIGNED, USINT, WORD, CipType, Integer, Octets
from enip_farm.cip.object import CipClass
from enip_farm.protocol.cip import ClassCode
from enip_farm.protocol.status import GeneralStatus

_READ_ONLY = 0x0010  # descriptor bit 4
_FLOATS = (0xCA, 0xCB)  # REAL, LREAL


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
    """One parameter: its data type (attribute 5's, as its EDS gives the size) and current value."""

    __slots__ = ("spec", "type", "value")

    def __init__(self, spec: ParameterSpec) -> None:
        self.spec = spec
        elementary = ELEMENTARY.get(spec.data_type)
        self.type: CipType = elementary if elementary is not None and elementary.size == spec.size else \
            Integer(f"0x{spec.data_type:02X}[{spec.size}]", spec.size, spec.data_type in SIGNED)
        default = spec.default if spec.default is not None else 0
        self.value = float(default) if spec.data_type in _FLOATS else int(default)

    @property
    def data(self) -> bytes:
        return self.type.encode(self.value)

    def set(self, value: float) -> int:
        spec = self.spec
        if (spec.minimum is not None and value < spec.minimum) or (spec.maximum is not None and value > spec.maximum):
            return GeneralStatus.INVALID_ATTRIBUTE_VALUE
        self.value = value
        return GeneralStatus.SUCCESS


class ParameterObject(CipClass):
    class_id = ClassCode.PARAMETER
    revision = 1

    def __init__(self, parameters: list[ParameterSpec]) -> None:
        super().__init__()
        self.parameters: dict[int, ParameterInstance] = {}
        for spec in parameters:
            parameter = self.parameters[spec.instance] = ParameterInstance(spec)
            value = parameter.type
            self.instances[spec.instance] = CipInstance((
                Attribute(1, value, lambda p=parameter: p.value) if spec.descriptor & _READ_ONLY
                else Attribute(1, value, lambda p=parameter: p.value, parameter.set),
                Attribute(2, USINT, value=len(spec.link_path)),
                Attribute(3, Octets(len(spec.link_path), "EPATH"), value=spec.link_path),
                Attribute(4, WORD, value=spec.descriptor),
                Attribute(5, USINT, value=spec.data_type),
                Attribute(6, USINT, value=spec.size),
            ))
