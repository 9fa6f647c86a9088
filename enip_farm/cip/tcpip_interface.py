"""TCP/IP Interface object, class 0xF5 (CIP Networks Library Vol. 2, 5-4): the read-only
attributes a scanner or commissioning tool reads (1-6), from the device's own address, and
attribute 13, the encapsulation inactivity timeout (seconds, 0 = never; settable, 0-3600): a TCP
connection with no whole encapsulation request for that long is closed (server/tcp.py)."""

from __future__ import annotations

import socket

from enip_farm.cip.object import UDINT, UINT, Attribute, CipClass, CipInstance, cip_string, constant, udint
from enip_farm.protocol.status import GeneralStatus

#: Attribute 1: interface configuration status 1 = "valid configuration obtained".
_STATUS_VALID = 1
#: Attribute 2: configuration capability: bit 2 DHCP client, bit 4 configuration settable
#: is left clear because the farm's configuration is read-only.
_CAPABILITY = 0x04
#: Attribute 3: configuration control 0 = static configuration.
_CONTROL_STATIC = 0
#: Attribute 13: the largest encapsulation inactivity timeout, seconds.
MAX_INACTIVITY_TIMEOUT_S = 3600


def ip_udint(address: str) -> bytes:
    """An IPv4 address as the UDINT the TCP/IP object uses (host order, sent little-endian)."""
    return UDINT.pack(int.from_bytes(socket.inet_aton(address), "big"))


class TcpIpInterfaceObject(CipClass):
    class_id = 0xF5
    revision = 4

    def __init__(self, *, address: str, netmask: str, gateway: str, host_name: str,
                 inactivity_timeout_s: int = 120) -> None:
        super().__init__()
        self.inactivity_timeout_s = inactivity_timeout_s
        interface_configuration = (
            ip_udint(address) + ip_udint(netmask) + ip_udint(gateway)
            + ip_udint("0.0.0.0") + ip_udint("0.0.0.0") + cip_string("")
        )
        self.instances[1] = CipInstance(
            {
                1: udint(_STATUS_VALID),
                2: udint(_CAPABILITY),
                3: udint(_CONTROL_STATIC),
                # physical link object: path size 2 words, path 20 F6 24 01 (Ethernet Link 1)
                4: constant(b"\x02\x00\x20\xf6\x24\x01"),
                5: constant(interface_configuration),
                6: constant(cip_string(host_name)),
                13: Attribute(lambda: UINT.pack(self.inactivity_timeout_s), self._set_inactivity_timeout),
            },
            all_ids=(1, 2, 3, 4, 5, 6),
        )

    def _set_inactivity_timeout(self, data: bytes) -> int:
        if len(data) < UINT.size:
            return GeneralStatus.NOT_ENOUGH_DATA
        if len(data) > UINT.size:
            return GeneralStatus.TOO_MUCH_DATA
        (value,) = UINT.unpack(data)
        if value > MAX_INACTIVITY_TIMEOUT_S:
            return GeneralStatus.INVALID_ATTRIBUTE_VALUE
        self.inactivity_timeout_s = value
        return GeneralStatus.SUCCESS
