"""Assembly object, class 0x04 (CIP Networks Library Vol. 1, 5-5): attribute 3 is the instance's
data (the device's I/O image, shared with every other view of it), attribute 4 its size in bytes.
The device holds its lock around every read and write of the bytes (device/guard.py)."""

from __future__ import annotations

from enip_farm.cip.object import UINT, Attribute, CipClass, CipInstance
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

    def set(self, value: bytes) -> int:
        """Set Attribute Single on attribute 3. While an exclusive owner holds the assembly, explicit
        writes get 0x10 (device state conflict) unless the device's config allows them."""
        if self.owned and not self.writable_while_owned:
            return GeneralStatus.DEVICE_STATE_CONFLICT
        size = len(self.data)
        if len(value) < size:
            return GeneralStatus.NOT_ENOUGH_DATA
        if len(value) > size:
            return GeneralStatus.TOO_MUCH_DATA
        self.data[:] = value
        return GeneralStatus.SUCCESS


class AssemblyObject(CipClass):
    class_id = ClassCode.ASSEMBLY
    revision = 2

    def __init__(self, assemblies: list[AssemblyInstance]) -> None:
        super().__init__()
        for assembly in assemblies:
            self.instances[assembly.instance_id] = CipInstance(
                {
                    3: Attribute(assembly.get, assembly.set if assembly.settable else None),
                    4: Attribute(lambda a=assembly: UINT.pack(len(a.data))),
                },
                all_ids=(3,),
            )
