"""Identity object, class 0x01 (CIP Networks Library Vol. 1, 5-2): vendor, device type, product
code, revision, status, serial number and product name."""

from __future__ import annotations

import struct
from collections.abc import Callable

from enip_farm.cip.object import UDINT, UINT, Attribute, CipClass, CipInstance, constant, short_string

#: Identity status bits 4-7 = 0b0011: "no I/O connections established" (Vol. 1, table 5-2.4).
STATUS_NO_IO_CONNECTIONS = 0x0030


class IdentityObject(CipClass):
    class_id = 0x01
    revision = 1

    def __init__(self, *, vendor_id: int, device_type: int, product_code: Callable[[], int], revision: tuple[int, int],
                 serial_number: int, product_name: str, status: Callable[[], int]) -> None:
        super().__init__()
        self.instances[1] = CipInstance(
            {
                1: constant(UINT.pack(vendor_id)),
                2: constant(UINT.pack(device_type)),
                3: Attribute(lambda: UINT.pack(product_code())),
                4: constant(struct.pack("<BB", *revision)),
                5: Attribute(lambda: UINT.pack(status())),
                6: constant(UDINT.pack(serial_number)),
                7: constant(short_string(product_name)),
            }
        )
