"""The CIP object model of one device, built from its catalogue profile (CIP Networks Library Vol. 1,
chapter 5; Vol. 2, 5-3 and 5-4): the assembly instances of its I/O image, its connection table and
the admission policy the profile declares (Vol. 1, 3-5), and the objects its Message Router
dispatches to: Identity, Assembly, Parameter, Connection Manager, TCP/IP Interface, Ethernet Link,
and for a safety target the Safety Supervisor and Safety Validator (Vol. 5). Building only: what
the objects do is theirs (cip/), locking and publishing are device/guard.py's.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from types import MappingProxyType

from enip_farm.cip.assembly import AssemblyInstance, AssemblyObject
from enip_farm.cip.budget import CyclicBudget
from enip_farm.cip.connection import Connection, ConnectionKind
from enip_farm.cip.connection_manager import ConnectionManager
from enip_farm.cip.connection_path import KeyIdentity
from enip_farm.cip.connection_policy import ConnectionPolicy, DeclaredConnection
from enip_farm.cip.connection_table import ConnectionTable
from enip_farm.cip.ethernet_link import EthernetLinkObject
from enip_farm.cip.identity import IdentityObject
from enip_farm.cip.message_router import MessageRouter
from enip_farm.cip.parameter import ParameterObject, ParameterSpec
from enip_farm.cip.safety.admission import SafetyPolicy
from enip_farm.cip.safety.objects import SafetyValidatorObject
from enip_farm.cip.safety.supervisor import SafetySupervisor
from enip_farm.cip.tcpip_interface import TcpIpInterfaceObject
from enip_farm.device.catalogue import ConnectionEntry
from enip_farm.device.profile import DeviceProfile
from enip_farm.protocol.safety.segment import Unid


@dataclass(frozen=True, slots=True)
class ObjectModel:
    """What `build_objects` returns: the parts of a device its other jobs hold."""

    assemblies: dict[str, AssemblyInstance]  # by role: "input", "output", "configuration"
    table: ConnectionTable
    router: MessageRouter
    tcpip: TcpIpInterfaceObject
    link: EthernetLinkObject


def build_objects(profile: DeviceProfile, counters: Counter[str], budget: CyclicBudget | None, *,
                  product_code: Callable[[], int], identity_state: Callable[[], int],
                  revision: Callable[[], tuple[int, int]] | None = None,
                  resetting: Callable[[], bool], forced_status: dict[int, int],
                  assembly_size: Callable[[str, int], int] | None = None) -> ObjectModel:
    """The objects of the device `profile` describes. `counters`: the device's (the connection table
    counts into them); `budget`: the cyclic I/O budget its connections share (None: no limit);
    `product_code`, `identity_state`, `resetting`: what the Identity object and the Safety Supervisor
    read as they answer; `forced_status`: the router's injected statuses (a `status` fault);
    `assembly_size`: the assembly sizes Forward Opens are checked against (a `wrong-module` fault)."""
    writable = profile.implicit.explicit_output_writes_while_owned
    shown_revision = revision or (lambda: profile.revision)
    assemblies = {spec.role: AssemblyInstance(spec.instance_id, spec.size, spec.settable, writable)
                  for spec in profile.assemblies}
    configuration = assemblies.get("configuration")
    if configuration is not None and len(profile.configuration_data) == len(configuration.data):
        configuration.data[:] = profile.configuration_data

    def key_identity() -> KeyIdentity:
        return KeyIdentity(profile.vendor_id, profile.device_type, product_code(), shown_revision())

    table = ConnectionTable(assemblies, _policy(profile), key_identity, counters, budget=budget,
                            sizes=assembly_size)
    tcpip = TcpIpInterfaceObject(address=profile.address, netmask=profile.netmask, gateway=profile.gateway,
                                 host_name=profile.host_name, select_acd=profile.select_acd,
                                 inactivity_timeout_s=profile.encapsulation_inactivity_timeout_s,
                                 multicast_group=profile.multicast_group,
                                 multicast_configured=profile.multicast_configured,
                                 safety_network_number=profile.safety.snn if profile.safety else None)
    link = EthernetLinkObject(mac=profile.mac)
    implicit, safety_profile = profile.implicit, profile.safety
    router = MessageRouter(
        multiple_service_packet=profile.routing.multiple_service_packet,
        max_connections=implicit.max_class1_connections + implicit.max_class3_connections + (
            safety_profile.max_connections if safety_profile else 0),
        active_connections=lambda: len(table.connections))
    router.forced_status = forced_status
    router.replay = {(service, path, data): reply for service, path, data, reply in profile.replay}
    for obj in (
        IdentityObject(vendor_id=profile.vendor_id, device_type=profile.device_type, product_code=product_code,
                       revision=shown_revision, serial_number=profile.serial_number,
                       product_name=profile.product_name, status=lambda: table.status, state=identity_state),
        AssemblyObject(list(assemblies.values())),
        *([ParameterObject([ParameterSpec(p.instance, p.name, p.descriptor, p.data_type, p.size, p.minimum,
                                          p.maximum, p.default, bytes.fromhex(p.link_path))
                            for p in profile.parameters])] if profile.parameters else []),
        ConnectionManager(router, table, unconnected_send=profile.routing.unconnected_send),
        tcpip,
        link,
    ):
        router.register(obj)
    safety = table.policy.safety
    if safety is not None:
        def open_connections() -> list[Connection]:
            return list(table.connections.values())

        def close_safety_connections(reason: str, now: int) -> None:
            for connection in [c for c in table.connections.values() if c.safety is not None]:
                table.close(connection, reason, now)

        router.register(SafetySupervisor(safety, open_connections, close_safety_connections, resetting))
        state = safety.state
        tcpip.safety_network_number = lambda: state.tunid.snn  # follows Apply_TUNID
        router.register(SafetyValidatorObject(open_connections, lambda: counters["safety_faulted"]))
    return ObjectModel(assemblies, table, router, tcpip, link)


def _safety_policy(profile: DeviceProfile) -> SafetyPolicy | None:
    safety, output, inputs = profile.safety, profile.assembly("output"), profile.assembly("input")
    if safety is None or output is None or inputs is None:
        return None
    configuration = profile.assembly("configuration")
    return SafetyPolicy(
        vendor_id=profile.vendor_id, serial_number=profile.serial_number, tunid=Unid(safety.snn, safety.node_address),
        scid=safety.scid, output_point=output.instance_id, input_point=inputs.instance_id,
        configuration_point=configuration.instance_id if configuration else safety.null_point,
        null_point=safety.null_point, max_connections=safety.max_connections)


def _policy(profile: DeviceProfile) -> ConnectionPolicy:
    implicit = profile.implicit
    return ConnectionPolicy(
        rpi_min_us=implicit.rpi_min_us, rpi_max_us=implicit.rpi_max_us,
        max_class1_connections=implicit.max_class1_connections,
        max_class3_connections=implicit.max_class3_connections,
        outputs_off_on_idle=implicit.idle_state == "off", outputs_off_on_fault=implicit.fault_state == "off",
        first_watchdog_ns=round(implicit.first_watchdog_s * 1e9),
        input_only_point=profile.input_only_point, listen_only_point=profile.listen_only_point,
        multicast_group=profile.multicast_group, safety=_safety_policy(profile),
        class3_rpi_min_us=implicit.class3_rpi_min_us, class3_rpi_max_us=implicit.class3_rpi_max_us,
        declared=tuple(_declared(entry) for entry in profile.connections),
    )


_DECLARED_KINDS: Mapping[str, ConnectionKind] = MappingProxyType({
    "exclusive owner": ConnectionKind.EXCLUSIVE_OWNER, "redundant owner": ConnectionKind.EXCLUSIVE_OWNER,
    "input only": ConnectionKind.INPUT_ONLY, "listen only": ConnectionKind.LISTEN_ONLY})


def _declared(entry: ConnectionEntry) -> DeclaredConnection:
    """An EDS's connection entry as admission holds Forward Opens against it."""
    return DeclaredConnection(
        kind=_DECLARED_KINDS[entry.kind], configuration=entry.configuration, o_t=entry.o_t, t_o=entry.t_o,
        o_t_size=entry.o_t_size, t_o_size=entry.t_o_size, o_t_format=entry.o_t_format, t_o_format=entry.t_o_format,
        o_t_variable=entry.o_t_variable, t_o_variable=entry.t_o_variable, t_o_multicast=entry.t_o_multicast,
        t_o_point_to_point=entry.t_o_point_to_point, configuration_size=entry.configuration_size,
        rpi_us=entry.rpi_us, shared_owner=entry.kind == "redundant owner", name=entry.name)
