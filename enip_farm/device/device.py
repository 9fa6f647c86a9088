"""One virtual device: its CIP objects, its I/O image and its encapsulation-level identity.

The assembly bytearrays are the device's I/O image: explicit messaging, and later implicit I/O and
the control API, all read and write these same bytes.
"""

from __future__ import annotations

from enip_farm.cip.assembly import AssemblyInstance, AssemblyObject
from enip_farm.cip.connection_manager import ConnectionManager
from enip_farm.cip.ethernet_link import EthernetLinkObject
from enip_farm.cip.identity import STATUS_NO_IO_CONNECTIONS, IdentityObject
from enip_farm.cip.message_router import MessageRouter
from enip_farm.cip.tcpip_interface import TcpIpInterfaceObject
from enip_farm.device.profile import DeviceProfile
from enip_farm.protocol.commands import (
    CAPABILITY_TCP,
    PROTOCOL_VERSION,
    IdentityItem,
    ServiceItem,
    SocketAddress,
    encode_identity_item,
    encode_service_item,
)
from enip_farm.protocol.cpf import ItemType, encode_items

ENIP_PORT = 44818
#: ListIdentity state: 3 = "operational" (Vol. 2, table 2-4.4 refers to the Identity state attribute).
_STATE_OPERATIONAL = 3


class Device:
    """Implements the encapsulation `Target` protocol for one configured device."""

    def __init__(self, profile: DeviceProfile) -> None:
        self.profile = profile
        self.assemblies: dict[str, AssemblyInstance] = {
            spec.role: AssemblyInstance(spec.instance_id, spec.size, spec.settable) for spec in profile.assemblies
        }
        self.status = STATUS_NO_IO_CONNECTIONS
        self._next_session_handle = 1
        self.sessions: set[int] = set()
        self.router = MessageRouter()
        for obj in (
            IdentityObject(
                vendor_id=profile.vendor_id,
                device_type=profile.device_type,
                product_code=profile.product_code,
                revision=profile.revision,
                serial_number=profile.serial_number,
                product_name=profile.product_name,
                status=lambda: self.status,
            ),
            AssemblyObject(list(self.assemblies.values())),
            ConnectionManager(self.router),
            TcpIpInterfaceObject(address=profile.address, netmask=profile.netmask, gateway=profile.gateway,
                                 host_name=profile.host_name),
            EthernetLinkObject(mac=profile.mac),
        ):
            self.router.register(obj)
        self._list_services = encode_items(
            [(ItemType.LIST_SERVICES, encode_service_item(ServiceItem(PROTOCOL_VERSION, CAPABILITY_TCP,
                                                                      "Communications")))]
        )

    @property
    def name(self) -> str:
        return self.profile.name

    # -- the I/O image --------------------------------------------------------------------------

    @property
    def outputs(self) -> bytes:
        assembly = self.assemblies.get("output")
        return bytes(assembly.data) if assembly else b""

    @property
    def inputs(self) -> bytes:
        assembly = self.assemblies.get("input")
        return bytes(assembly.data) if assembly else b""

    def set_inputs(self, data: bytes) -> None:
        """Set the input image as a sensor would (not subject to `writable_inputs`)."""
        assembly = self.assemblies["input"]
        if len(data) != len(assembly.data):
            raise ValueError(f"{self.name}: input image is {len(assembly.data)} bytes, got {len(data)}")
        assembly.data[:] = data

    # -- encapsulation Target -------------------------------------------------------------------

    def identity_item(self) -> IdentityItem:
        p = self.profile
        return IdentityItem(PROTOCOL_VERSION, SocketAddress(p.address, ENIP_PORT), p.vendor_id, p.device_type,
                            p.product_code, p.revision[0], p.revision[1], self.status, p.serial_number,
                            p.product_name, _STATE_OPERATIONAL)

    def list_identity_data(self) -> bytes:
        return encode_items([(ItemType.LIST_IDENTITY, encode_identity_item(self.identity_item()))])

    def list_services_data(self) -> bytes:
        return self._list_services

    def list_interfaces_data(self) -> bytes:
        return encode_items([])

    def register_session(self) -> int:
        handle = self._next_session_handle
        self._next_session_handle = handle + 1 if handle < 0xFFFFFFFF else 1
        self.sessions.add(handle)
        return handle

    def unregister_session(self, session_handle: int) -> None:
        self.sessions.discard(session_handle)

    def handle_unconnected(self, message: bytes) -> bytes:
        return self.router.handle(message)
