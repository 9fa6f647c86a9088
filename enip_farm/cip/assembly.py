"""Assembly object, class 0x04 (CIP Networks Library Vol. 1, 5-5): attribute 3 is the instance's
data (the device's I/O image, shared with every other view of it), attribute 4 its size in bytes.
The device holds its lock around every read and write of the bytes (device/guard.py)."""

from __future__ import annotations

from enip_farm.cip.attribute import Access, Attribute, CipInstance
from enip_farm.cip.data_types import UINT, Octets
from enip_farm.cip.object import CipClass
from enip_farm.protocol.cip import ClassCode
from enip_farm.protocol.status import GeneralStatus


class AssemblyInstance:
    """One assembly's bytes. `settable` says whether clients may write attribute 3."""

    __slots__ = ("instance_id", "data", "settable", "owned", "writable_while_owned")

    def __init__(self, instance_id: int, size: int, settable: bool, writable_while_owned: bool = False) -> None:
        self.instance_id = instance_id
        self.data = bytearray(size)
        self.settable = settable
        self.owned = False  # an exclusive-owner connection consumes into it
        self.writable_while_owned = writable_while_owned

    def get(self) -> bytes:
        return bytes(self.data)

    def guard(self) -> int:
        """While an exclusive owner holds the assembly, explicit writes of attribute 3 get 0x10
        (device state conflict) unless the device's config allows them."""
        if self.owned and not self.writable_while_owned:
            return GeneralStatus.DEVICE_STATE_CONFLICT
        return GeneralStatus.SUCCESS

    def set(self, value: bytes) -> int:
        """Set Attribute Single on attribute 3, once the guard and the size let it through."""
        self.data[:] = value
        return GeneralStatus.SUCCESS


class AssemblyObject(CipClass):
    class_id = ClassCode.ASSEMBLY
    revision = 2

    def __init__(self, assemblies: list[AssemblyInstance]) -> None:
        super().__init__()
        for assembly in assemblies:
            data = Octets(len(assembly.data), "USINT[]")
            self.instances[assembly.instance_id] = CipInstance((
                Attribute(3, data, assembly.get, assembly.set, guard=assembly.guard) if assembly.settable
                else Attribute(3, data, assembly.get),
                Attribute(4, UINT, value=len(assembly.data), access=Access.GET),
            ))
