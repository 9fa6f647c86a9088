"""Ethernet Link object, class 0xF6 (CIP Networks Library Vol. 2, 5-5), revision 4, instance 1.

| # | attribute | here |
|---|---|---|
| 1 | interface speed (UDINT, Mbit/s) | 100 |
| 2 | interface flags | link up, full duplex, negotiation 3 (auto-negotiated) or 4 (forced) |
| 3 | physical address | the device's MAC |
| 4 | interface counters (11 UDINTs) | the device's own traffic, below |
| 5 | media counters (12 UDINTs) | all 0: there is no medium |
| 6 | interface control (WORD, UINT) | settable: auto-negotiate (1, 0) or forced 100 Mbit/s full duplex (2, 100) |
| 7 | interface type | 2, twisted pair |
| 8 | interface state | 1, enabled |
| 9 | admin state | 1, enabled (read-only: disabling the port would cut the device off for good) |
| 10 | interface label (SHORT_STRING) | "port 1" |
| 11 | interface capability | auto-negotiate and manual speed/duplex; one mode, 100 Mbit/s full duplex |

Get_and_Clear (0x4C) on attributes 4 and 5 answers as Get Attribute Single, then zeroes the
counters; on another attribute 0x2E (not supported for that path), on an unknown one 0x14.

The interface counters count what the device's sockets move (TCP 44818, UDP 44818 and UDP 2222),
fed by the server through the device: octets of payload (no IP, TCP or UDP headers) and "packets"
as the sockets see them (a datagram; for TCP a read or a write, not the segments the kernel cuts).
Unicast and non-unicast (a broadcast ListIdentity in, a multicast T->O packet out) are told
apart; In Discards counts datagrams the device did not take, Out Errors sends that failed. Each
thread that moves traffic writes its own `InterfaceCounters` (no lock on the hot path); the object
sums them, and clearing moves a baseline. UDINTs wrap at 2^32."""

from __future__ import annotations

import struct

from enip_farm.cip.attribute import Attribute, CipInstance
from enip_farm.cip.data_types import DWORD, SHORT_STRING, UDINT, USINT, Encoded, Octets, Packed
from enip_farm.cip.object import CipClass, ServiceResult
from enip_farm.protocol.cip import ClassCode, Service
from enip_farm.protocol.epath import RequestPath
from enip_farm.protocol.session import MessageContext
from enip_farm.protocol.status import GeneralStatus

#: Interface flags: link active (bit 0), full duplex (bit 1), negotiation status (bits 2-4):
#: 3 = speed and duplex successfully negotiated, 4 = not attempted, speed and duplex forced.
_LINK_FULL_DUPLEX = 0x01 | 0x02
_NEGOTIATED, _FORCED = 3 << 2, 4 << 2
#: Interface control bits: 0 auto-negotiate, 1 forced duplex mode (1 = full).
AUTO_NEGOTIATE, FORCED_FULL_DUPLEX = 0x01, 0x02
#: Attribute 6: control bits (WORD) and forced interface speed (UINT).
_CONTROL = Packed("STRUCT of WORD, UINT", "<HH")
#: Interface capability: bit 1 auto-negotiate, bit 3 manual speed/duplex; one speed/duplex mode.
_CAPABILITY = DWORD.encode(0x02 | 0x08) + bytes((1,)) + struct.pack("<HB", 100, 1)
_INTERFACE_TYPE_TWISTED_PAIR = 2
_ENABLED = 1
LABEL = "port 1"
MEDIA_COUNTERS = 12
_UDINT_MASK = 0xFFFFFFFF
#: Attribute 4: In Octets, In Ucast Packets, ... Out Errors (eleven UDINTs).
_INTERFACE_COUNTERS = Packed("STRUCT of UDINT[11]", "<11I")


def _capability_size(data: bytes) -> int | None:
    """Attribute 11: capability bits DWORD, a USINT count and that many (UINT speed, USINT duplex)."""
    return 5 + 3 * data[4] if len(data) >= 5 else None


_INTERFACE_CAPABILITY = Encoded("STRUCT of DWORD, USINT count, STRUCT of UINT, USINT[count]", _capability_size)


class InterfaceCounters:
    """Attribute 4's counters as one thread counts them (one writer per instance)."""

    __slots__ = ("in_octets", "in_ucast", "in_nucast", "in_discards", "in_errors", "in_unknown_protos",
                 "out_octets", "out_ucast", "out_nucast", "out_discards", "out_errors")

    def __init__(self) -> None:
        for name in self.__slots__:
            setattr(self, name, 0)

    def received(self, octets: int, unicast: bool = True) -> None:
        self.in_octets += octets
        if unicast:
            self.in_ucast += 1
        else:
            self.in_nucast += 1

    def sent(self, octets: int, unicast: bool = True) -> None:
        self.out_octets += octets
        if unicast:
            self.out_ucast += 1
        else:
            self.out_nucast += 1

    def discarded(self) -> None:
        """An inbound datagram the device did not take."""
        self.in_discards += 1

    def send_failed(self) -> None:
        self.out_errors += 1

    def values(self) -> tuple[int, ...]:
        return tuple(getattr(self, name) for name in self.__slots__)


class EthernetLinkObject(CipClass):
    class_id = ClassCode.ETHERNET_LINK
    revision = 4
    #: Get Attributes All of the class: 1-7 (Vol. 2's layout, which Wireshark's ENIP dissector decodes)
    class_get_all = (1, 2, 3, 4, 5, 6, 7)
    optional_attributes = tuple(range(4, 12))
    optional_services = (Service.GET_AND_CLEAR,)

    def __init__(self, *, mac: bytes, speed_mbps: int = 100) -> None:
        super().__init__()
        if len(mac) != 6:
            raise ValueError("a MAC address has 6 bytes")
        self._sources: list[InterfaceCounters] = []
        self._baseline = (0,) * len(InterfaceCounters.__slots__)
        self.control = (AUTO_NEGOTIATE, 0)
        self.instances[1] = CipInstance((
            Attribute(1, UDINT, value=speed_mbps),
            Attribute(2, DWORD, lambda: _LINK_FULL_DUPLEX | (
                _NEGOTIATED if self.control[0] & AUTO_NEGOTIATE else _FORCED)),
            Attribute(3, Octets(6, "USINT[6]"), value=mac),
            Attribute(4, _INTERFACE_COUNTERS, self.counters),
            Attribute(5, Octets(4 * MEDIA_COUNTERS, "STRUCT of UDINT[12]"), value=bytes(4 * MEDIA_COUNTERS)),
            Attribute(6, _CONTROL, lambda: self.control, self._set_control),
            Attribute(7, USINT, value=_INTERFACE_TYPE_TWISTED_PAIR),
            Attribute(8, USINT, value=_ENABLED),
            Attribute(9, USINT, value=_ENABLED),
            Attribute(10, SHORT_STRING, value=LABEL),
            Attribute(11, _INTERFACE_CAPABILITY, value=_CAPABILITY),
        ))
        self.handlers[Service.GET_AND_CLEAR] = self.get_and_clear

    # -- interface counters ---------------------------------------------------------------------

    def new_counters(self) -> InterfaceCounters:
        """Counters for one thread that moves the device's traffic, summed into attribute 4."""
        counters = InterfaceCounters()
        self._sources = [*self._sources, counters]
        return counters

    def _totals(self) -> tuple[int, ...]:
        return tuple(map(sum, zip(*(source.values() for source in self._sources), strict=True))) \
            if self._sources else self._baseline

    def counters(self) -> tuple[int, ...]:
        """Attribute 4's eleven UDINTs since the last clear."""
        return tuple((total - base) & _UDINT_MASK for total, base in zip(self._totals(), self._baseline, strict=True))

    def clear_counters(self) -> None:
        self._baseline = self._totals()

    # -- settings ---------------------------------------------------------------------------------

    def restore_defaults(self) -> None:
        """Back to the out-of-box configuration (Identity Reset type 1)."""
        self.control = (AUTO_NEGOTIATE, 0)

    def _set_control(self, value: tuple[int, int]) -> int:
        bits, speed = value
        if bits > AUTO_NEGOTIATE | FORCED_FULL_DUPLEX:
            return GeneralStatus.INVALID_ATTRIBUTE_VALUE
        if bits & AUTO_NEGOTIATE:
            if bits & FORCED_FULL_DUPLEX or speed:  # nothing to force while negotiating (as OpENer)
                return GeneralStatus.OBJECT_STATE_CONFLICT
        elif not (bits & FORCED_FULL_DUPLEX and speed == 100):  # the one mode attribute 11 offers
            return GeneralStatus.INVALID_ATTRIBUTE_VALUE
        self.control = (bits, speed)
        return GeneralStatus.SUCCESS

    # -- Get_and_Clear ----------------------------------------------------------------------------

    def get_and_clear(self, instance: CipInstance, path: RequestPath, data: bytes,
                      context: MessageContext) -> ServiceResult:
        attribute = instance.attributes.get(path.attribute_id)  # type: ignore[arg-type]
        if attribute is None:
            return ServiceResult(GeneralStatus.ATTRIBUTE_NOT_SUPPORTED)
        if instance is self.class_instance or path.attribute_id not in (4, 5):
            return ServiceResult(GeneralStatus.SERVICE_NOT_SUPPORTED_FOR_PATH)
        value = attribute.read()
        if path.attribute_id == 4:
            self.clear_counters()
        return ServiceResult(GeneralStatus.SUCCESS, value)

