"""TCP/IP Interface object, class 0xF5 (CIP Networks Library Vol. 2, 5-4), revision 4, instance 1:
attributes 1-13 from the device's own address and configuration.

| # | attribute | here |
|---|---|---|
| 1-2 | status, capability | valid configuration; 0: no BOOTP, DNS or DHCP client, configuration not settable |
| 3 | configuration control (DWORD) | settable to what attribute 2 offers: static (0) here; else 0x09 |
| 4 | physical link object | path to Ethernet Link instance 1 |
| 5 | interface configuration | address, mask, gateway of the device; no name servers or domain; read-only |
| 6 | host name (STRING) | settable: up to 64 letters, digits and inner hyphens (RFC 1123 label) |
| 7 | safety network number | a CIP Safety target's SNN, read-only; else 0x14 (six zero bytes in Get Attributes All) |
| 8 | TTL value (USINT) | settable 1-255, default 1 |
| 9 | multicast configuration | the device's T->O group: allocation 0 (CIP algorithm) or 1 (configured); read-only |
| 10 | SelectAcd (BOOL) | settable 0/1, out of box `select_acd` (default 0, unverified): ACD on |
| 11 | last conflict detected | ACD activity, remote MAC, ARP PDU (35 bytes): zeros until a conflict detected |
| 12 | EtherNet/IP Quick Connect (BOOL) | settable 0/1, default 0 (stored) |
| 13 | encapsulation inactivity timeout (UINT, s) | settable 0-3600, default 120 (server/tcp.py applies it) |

Attribute 1's bits 6 (AcdStatus: a conflict detected) and 7 (AcdFault: the address given up) follow
an `address-conflict` fault (device/hardware.py) while SelectAcd is 1; attribute 11 keeps the last one.
Set values live until the device is reset to its out-of-box configuration (Identity Reset type 1,
`restore_defaults`): like the module's non-volatile settings they survive a type-0 reset.
Get Attributes All returns 1-13 in order, 7 as six zero bytes: 96 bytes plus the padded domain
and host names (as OpENer's GetAttributeAll of class 0xF5 lays them out)."""

from __future__ import annotations

import re
import socket
from collections.abc import Callable

from enip_farm.cip.attribute import GET_ALL, Access, Attribute, CipInstance
from enip_farm.cip.data_types import BOOL, DWORD, PADDED_STRING, UDINT, UINT, USINT, Encoded, Octets, Packed
from enip_farm.cip.object import CipClass
from enip_farm.protocol.cip import ClassCode
from enip_farm.protocol.epath import encode_request_path
from enip_farm.protocol.status import GeneralStatus

#: Attribute 1: interface configuration status 1 = "valid configuration obtained".
_STATUS_VALID = 1
#: Attribute 2: configuration capability (Vol. 2, 5-4): no bit set. Bits 0 BOOTP client, 1 DNS
#: client and 2 DHCP client stay clear because none runs, bit 4 configuration settable because the
#: address (attribute 5) is the device's configured one.
_CAPABILITY = 0x00
CAPABILITY_BOOTP, CAPABILITY_DNS, CAPABILITY_DHCP = 0x01, 0x02, 0x04
#: Attribute 3: configuration control, bits 0-3 the method (0 static, 1 BOOTP, 2 DHCP, 3-15
#: reserved), bit 4 DNS enable, bits 5-31 reserved. Out of the box: static.
CONTROL_STATIC, CONTROL_BOOTP, CONTROL_DHCP, CONTROL_METHOD_MASK, CONTROL_DNS_ENABLE = 0, 1, 2, 0x0F, 0x10
#: Attribute 13: the largest encapsulation inactivity timeout, seconds.
MAX_INACTIVITY_TIMEOUT_S = 3600
#: Attribute 6: the longest host name (RFC 1123), and what a name may be made of.
MAX_HOST_NAME = 64
_HOST_NAME = re.compile(r"^[A-Za-z0-9](?:[A-Za-z0-9-]*[A-Za-z0-9])?$")
#: Attribute 7 in Get Attributes All: a device that is not a safety device has no safety network number.
_NO_SAFETY_NETWORK_NUMBER = bytes(6)
#: Attribute 11: ACD activity 0 (no conflict), remote MAC and ARP PDU all zero.
_NO_CONFLICT = bytes(1 + 6 + 28)
#: Attribute 1: AcdStatus (a conflict detected) and AcdFault (the address given up), Vol. 2, 5-4.3.2.1.
ACD_STATUS, ACD_FAULT = 0x40, 0x80
#: Attribute 11's ACD activity: no conflict, probing the address, ongoing detection (Vol. 2, 5-4.3.2.11).
ACD_NONE, ACD_PROBE, ACD_ONGOING = 0, 1, 2
#: Attribute 9's allocation control: 0 the CIP algorithm (Vol. 2, 3-5.3), 1 a configured group.
ALLOC_ALGORITHM, ALLOC_CONFIGURED = 0, 1
#: Attribute 9: allocation control, reserved, number of groups, the first group's address.
_MCAST_CONFIG = Packed("STRUCT of USINT, USINT, UINT, UDINT", "<BBHI")


def ip_udint(address: str) -> bytes:
    """An IPv4 address as the UDINT the TCP/IP object uses (host order, sent little-endian)."""
    return UDINT.encode(_ip(address))


def _ip(address: str) -> int:
    return int.from_bytes(socket.inet_aton(address), "big")


def _epath_size(data: bytes) -> int | None:
    """Attribute 4: a UINT path size in words and the path."""
    return 2 + 2 * UINT.decode(data[:2]) if len(data) >= 2 else None


def _configuration_size(data: bytes) -> int | None:
    """Attribute 5: five UDINTs and a STRING."""
    name = PADDED_STRING.size_in(data[20:])
    return None if name is None else 20 + name


#: Attribute 4: a UINT path size in words and a padded EPATH.
PHYSICAL_LINK = Encoded("STRUCT of UINT path size, padded EPATH", _epath_size)
#: Attribute 5: IP address, network mask, gateway, name servers 1 and 2 (UDINTs), domain name (STRING).
INTERFACE_CONFIGURATION = Encoded("STRUCT of UDINT[5], STRING", _configuration_size)


class TcpIpSettings:
    """The settable attributes, as configured (out of box) or as clients set them."""

    __slots__ = ("configuration_control", "host_name", "ttl", "select_acd", "quick_connect", "inactivity_timeout_s")

    def __init__(self, host_name: str, inactivity_timeout_s: int, select_acd: int = 0) -> None:
        self.configuration_control = CONTROL_STATIC
        self.host_name = host_name
        self.ttl = 1
        self.select_acd = select_acd
        self.quick_connect = 0
        self.inactivity_timeout_s = inactivity_timeout_s

    def copy(self) -> TcpIpSettings:
        settings = TcpIpSettings(self.host_name, self.inactivity_timeout_s, self.select_acd)
        settings.ttl, settings.quick_connect = self.ttl, self.quick_connect
        settings.configuration_control = self.configuration_control
        return settings


class TcpIpInterfaceObject(CipClass):
    class_id = ClassCode.TCP_IP_INTERFACE
    revision = 4
    #: Get Attributes All of the class: 1-7 (Vol. 2's layout, which Wireshark's ENIP dissector decodes)
    class_get_all = (1, 2, 3, 4, 5, 6, 7)

    def __init__(self, *, address: str, netmask: str, gateway: str, host_name: str,
                 inactivity_timeout_s: int = 120, select_acd: bool = False, multicast_group: str = "0.0.0.0",
                 multicast_configured: bool = False, safety_network_number: bytes | None = None) -> None:
        super().__init__()
        self.capability = _CAPABILITY
        self._out_of_box = TcpIpSettings(host_name, inactivity_timeout_s, int(select_acd))
        self.settings = self._out_of_box.copy()
        interface_configuration = (
            ip_udint(address) + ip_udint(netmask) + ip_udint(gateway)
            + ip_udint("0.0.0.0") + ip_udint("0.0.0.0") + PADDED_STRING.encode("")
        )
        multicast = (ALLOC_CONFIGURED if multicast_configured else ALLOC_ALGORITHM, 0, 1, _ip(multicast_group))
        if safety_network_number is not None and len(safety_network_number) != len(_NO_SAFETY_NETWORK_NUMBER):
            raise ValueError("a safety network number has 6 bytes")
        #: Attribute 7: the safety network number, as the device's CIP Safety state has it (a safety
        #: device replaces this getter with one that follows Apply_TUNID).
        self.safety_network_number: Callable[[], bytes] = lambda: safety_network_number or _NO_SAFETY_NETWORK_NUMBER
        self.instances[1] = CipInstance((
            Attribute(1, DWORD, lambda: _STATUS_VALID | self.acd_bits),
            Attribute(2, DWORD, lambda: self.capability),
            Attribute(3, DWORD, lambda: self.settings.configuration_control, self._set_configuration_control),
            # physical link object: path size 2 words, path 20 F6 24 01 (Ethernet Link 1)
            Attribute(4, PHYSICAL_LINK, value=UINT.encode(2) + encode_request_path(ClassCode.ETHERNET_LINK, 1)),
            Attribute(5, INTERFACE_CONFIGURATION, value=interface_configuration),
            Attribute(6, PADDED_STRING, lambda: self.settings.host_name, self._set_host_name),
            # not a safety device: no attribute 7, six zero bytes in its place in Get Attributes All
            Attribute(7, Octets(6, "USINT[6]"), lambda: self.safety_network_number(),
                      access=GET_ALL if safety_network_number is not None else Access.ALL),
            Attribute(8, USINT, lambda: self.settings.ttl, self._set_ttl),
            Attribute(9, _MCAST_CONFIG, value=multicast),
            Attribute(10, BOOL, lambda: self.settings.select_acd, self._setter_bool("select_acd")),
            Attribute(11, Octets(len(_NO_CONFLICT)), lambda: self.last_conflict),
            Attribute(12, BOOL, lambda: self.settings.quick_connect, self._setter_bool("quick_connect")),
            Attribute(13, UINT, lambda: self.settings.inactivity_timeout_s, self._set_inactivity_timeout),
        ))
        self.optional_attributes = tuple(i for i in self.instances[1].served_ids() if i > 5)
        self.acd_bits = 0  # attribute 1's bits 6 and 7
        self.last_conflict = _NO_CONFLICT

    def conflict_detected(self, activity: int, remote_mac: bytes, arp_pdu: bytes, address_given_up: bool) -> bool:
        """An address conflict (Vol. 2, 5-4.3.2.11): attribute 11 records it and attribute 1 says so, if
        the module detects conflicts (SelectAcd, attribute 10, is 1). False: it detected nothing."""
        if not self.settings.select_acd:
            return False
        self.last_conflict = bytes([activity]) + remote_mac + arp_pdu
        self.acd_bits = ACD_STATUS | (ACD_FAULT if address_given_up else 0)
        return True

    def conflict_over(self) -> None:
        """The other host left: the module holds its address again; attribute 11 keeps the record."""
        self.acd_bits = 0

    @property
    def inactivity_timeout_s(self) -> int:
        return self.settings.inactivity_timeout_s

    def restore_defaults(self) -> None:
        """Back to the out-of-box configuration (Identity Reset type 1)."""
        self.settings = self._out_of_box.copy()

    # -- setters: encoded data in, a general status out ------------------------------------------

    def _set_configuration_control(self, value: int) -> int:
        """Attribute 3: a method, and DNS enable, that attribute 2 offers (static always is); a
        reserved method or bit, or one the capabilities do not offer, is 0x09."""
        offered = {CONTROL_STATIC}
        if self.capability & CAPABILITY_BOOTP:
            offered.add(CONTROL_BOOTP)
        if self.capability & CAPABILITY_DHCP:
            offered.add(CONTROL_DHCP)
        if (value & ~(CONTROL_METHOD_MASK | CONTROL_DNS_ENABLE) or value & CONTROL_METHOD_MASK not in offered
                or value & CONTROL_DNS_ENABLE and not self.capability & CAPABILITY_DNS):
            return GeneralStatus.INVALID_ATTRIBUTE_VALUE
        self.settings.configuration_control = value
        return GeneralStatus.SUCCESS

    def _set_inactivity_timeout(self, value: int) -> int:
        if value > MAX_INACTIVITY_TIMEOUT_S:
            return GeneralStatus.INVALID_ATTRIBUTE_VALUE
        self.settings.inactivity_timeout_s = value
        return GeneralStatus.SUCCESS

    def _set_ttl(self, value: int) -> int:
        if value == 0:
            return GeneralStatus.INVALID_ATTRIBUTE_VALUE
        self.settings.ttl = value
        return GeneralStatus.SUCCESS

    def _setter_bool(self, name: str) -> Callable[[int], int]:
        def set_bool(value: int) -> int:
            if value > 1:
                return GeneralStatus.INVALID_ATTRIBUTE_VALUE
            setattr(self.settings, name, value)
            return GeneralStatus.SUCCESS
        return set_bool

    def _set_host_name(self, name: str) -> int:
        if len(name) > MAX_HOST_NAME:
            return GeneralStatus.TOO_MUCH_DATA  # as OpENer
        if name and not _HOST_NAME.match(name):
            return GeneralStatus.INVALID_ATTRIBUTE_VALUE
        self.settings.host_name = name
        return GeneralStatus.SUCCESS
