"""Ethernet Link object, class 0xF6 (CIP Networks Library Vol. 2, 5-5): interface speed, flags and
physical (MAC) address, read-only."""

from __future__ import annotations

from enip_farm.cip.object import CipClass, CipInstance, constant, udint

#: Interface flags: link active (bit 0), full duplex (bit 1), negotiation status 3 = speed and
#: duplex successfully negotiated (bits 2-4).
_FLAGS = 0x01 | 0x02 | (3 << 2)


class EthernetLinkObject(CipClass):
    class_id = 0xF6
    revision = 4

    def __init__(self, *, mac: bytes, speed_mbps: int = 100) -> None:
        super().__init__()
        if len(mac) != 6:
            raise ValueError("a MAC address has 6 bytes")
        self.instances[1] = CipInstance({1: udint(speed_mbps), 2: udint(_FLAGS), 3: constant(mac)})
