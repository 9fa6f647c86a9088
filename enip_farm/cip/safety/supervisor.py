"""The Safety Supervisor object, class 0x39, instance 1, of a safety target (CIP Networks Library
Vol. 5, chapter 5; attribute numbers, service codes and request layouts as Wireshark's CIP Safety
dissector, packet-cipsafety.c, decodes them).

| # | attribute | here |
|---|---|---|
| 11 | device status (USINT) | 1 self-testing (Identity Reset window), 8 waiting for TUNID, |
|    |                       | 4 executing (a safety connection open), else 2 idle |
| 12 | exception status (BYTE) | 0: the farm models no device exception |
| 24 | configuration lock (BOOL) | 0: the farm offers no Configuration_Lock service |
| 25 | CFUNID | the configuration owner's UNID (ten zero bytes: none) |
| 26 | SCID | SCCRC (UDINT) + SCTS (6 bytes); zeros: no configuration signature |
| 27 | TUNID | safety network number (6) + node address (UDINT, the IPv4 address); all 0xFF: not set |
| 28 | output connection point owners | UINT count; per owner: OCPUNID (10), USINT path size (bytes), path |
| 29 | proposed TUNID | the TUNID Propose_TUNID stored; all 0xFF: none |

Services (request data as Wireshark lays it out; every malformed request changes nothing):
- Propose_TUNID (0x56): a TUNID (10 bytes). All 0xFF cancels a pending proposal. A node address
  other than the device's own: 0x20; while a safety connection is open: 0x10 (device state conflict).
- Apply_TUNID (0x57): a TUNID (10 bytes) that must equal the pending proposal, else 0x0C (object
  state conflict, as cm-ethernetip's target answers when no proposal is pending). Sets the TUNID
  (and TCP/IP attribute 7, the safety network number); the device leaves "waiting for TUNID".
- Safety_Reset (0x54): reset type (USINT 0, 1 or 2; else 0x20), password (16 bytes), TUNID (10
  bytes), and for type 2 only the attribute bit map (1 byte: preserve 0x01 MAC id, 0x02 baud rate,
  0x04 TUNID, 0x08 password, 0x10 CFUNID, 0x20 OCPUNIDs; 0x40 and 0x80 reserved/extended map: 0x20).
  A wrong password: 0x0F (privilege violation); a TUNID other than the device's: 0x20; nothing
  changes then. Accepted: every safety connection closes (the safe outputs go to their safe state),
  then the state is reset as cip/safety/state.py says.
Short request data: 0x13; longer: 0x15.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Iterable

from enip_farm.cip.attribute import Attribute, CipInstance
from enip_farm.cip.connection import Connection, ConnectionKind
from enip_farm.cip.data_types import BOOL, BYTE, USINT, Encoded, Octets
from enip_farm.cip.object import CipClass, ServiceResult
from enip_farm.cip.safety.admission import SafetyPolicy
from enip_farm.cip.safety.state import (
    EXTENDED_MAP,
    NO_UNID,
    PASSWORD_SIZE,
    RESERVED_BIT,
    SCID_SIZE,
    UNID_SIZE,
    UNSET_UNID,
)
from enip_farm.protocol.cip import ClassCode
from enip_farm.protocol.epath import RequestPath, encode_request_path
from enip_farm.protocol.safety.segment import Unid
from enip_farm.protocol.session import MessageContext
from enip_farm.protocol.status import GeneralStatus

SAFETY_RESET, PROPOSE_TUNID, APPLY_TUNID = 0x54, 0x56, 0x57
#: Device status (attribute 11), Vol. 5 as Wireshark names the values.
SELF_TESTING, IDLE, EXECUTING, ABORT, CRITICAL_FAULT, CONFIGURING, WAITING_FOR_TUNID = 1, 2, 4, 5, 6, 7, 8
_RESET_FIXED = 1 + PASSWORD_SIZE + UNID_SIZE  # type, password, TUNID
UNID = Octets(UNID_SIZE, "UNID: SNN (6 bytes), node address (UDINT)")
SCID = Octets(SCID_SIZE, "SCID: SCCRC (UDINT), SCTS (6 bytes)")


def _exact(data: bytes, size: int) -> int:
    if len(data) < size:
        return GeneralStatus.NOT_ENOUGH_DATA
    if len(data) > size:
        return GeneralStatus.TOO_MUCH_DATA
    return GeneralStatus.SUCCESS


class SafetySupervisor(CipClass):
    class_id = ClassCode.SAFETY_SUPERVISOR
    revision = 1
    optional_services = (SAFETY_RESET, PROPOSE_TUNID, APPLY_TUNID)

    def __init__(self, policy: SafetyPolicy, connections: Callable[[], Iterable[Connection]],
                 close_safety_connections: Callable[[str, int], None] = lambda reason, now: None,
                 self_testing: Callable[[], bool] = lambda: False) -> None:
        super().__init__()
        self.policy = policy
        self.state = policy.state
        self._connections = connections
        self._close = close_safety_connections
        self._self_testing = self_testing
        state = self.state
        self.instances[1] = CipInstance((
            Attribute(11, USINT, lambda: self.device_status),
            Attribute(12, BYTE, value=0),  # exception status
            Attribute(24, BOOL, lambda: int(state.locked)),
            Attribute(25, UNID, lambda: (state.cfunid or NO_UNID).encode()),  # Configuration UNID (CFUNID)
            Attribute(26, SCID, lambda: state.scid),  # Safety Configuration Identifier: SCCRC + SCTS
            Attribute(27, UNID, lambda: state.tunid.encode()),  # Target UNID: SNN + node address
            Attribute(28, OUTPUT_CONNECTION_POINT_OWNERS, self._output_owners),
            Attribute(29, UNID, lambda: (state.proposed_tunid or UNSET_UNID).encode()),
        ))
        self.handlers[PROPOSE_TUNID] = self.propose_tunid
        self.handlers[APPLY_TUNID] = self.apply_tunid
        self.handlers[SAFETY_RESET] = self.safety_reset

    # -- attributes -------------------------------------------------------------------------------

    def _safety_connections(self) -> list[Connection]:
        return [c for c in self._connections() if c.safety is not None and not c.closed]

    @property
    def device_status(self) -> int:
        if self._self_testing():
            return SELF_TESTING
        if not self.state.tunid_set:
            return WAITING_FOR_TUNID
        return EXECUTING if self._safety_connections() else IDLE

    def _output_owners(self) -> bytes:
        owners = [c for c in self._safety_connections() if c.kind is ConnectionKind.SAFETY_OUTPUT]
        data = struct.pack("<H", len(owners))
        for connection in owners:
            path = encode_request_path(ClassCode.ASSEMBLY, connection.o_t_point & 0xFF)
            data += (connection.ounid or NO_UNID).encode() + bytes((len(path),)) + path
        return data

    # -- services ---------------------------------------------------------------------------------

    def _instance_only(self, path: RequestPath) -> ServiceResult | None:
        return ServiceResult(GeneralStatus.SERVICE_NOT_SUPPORTED) if path.instance_id != 1 else None

    def propose_tunid(self, instance: CipInstance, path: RequestPath, data: bytes,
                      context: MessageContext) -> ServiceResult:
        refused = self._instance_only(path)
        if refused:
            return refused
        status = _exact(data, UNID_SIZE)
        if status:
            return ServiceResult(status)
        proposed = Unid.decode(data)
        if proposed == UNSET_UNID:  # cancel
            self.state.proposed_tunid = None
            return ServiceResult(GeneralStatus.SUCCESS)
        if proposed.node_address != self.policy.tunid.node_address:
            return ServiceResult(GeneralStatus.INVALID_PARAMETER)  # another device's node address
        if self._safety_connections():
            return ServiceResult(GeneralStatus.DEVICE_STATE_CONFLICT)
        self.state.proposed_tunid = proposed
        return ServiceResult(GeneralStatus.SUCCESS)

    def apply_tunid(self, instance: CipInstance, path: RequestPath, data: bytes,
                    context: MessageContext) -> ServiceResult:
        refused = self._instance_only(path)
        if refused:
            return refused
        status = _exact(data, UNID_SIZE)
        if status:
            return ServiceResult(status)
        applied = Unid.decode(data)
        if self.state.proposed_tunid is None or applied != self.state.proposed_tunid:
            return ServiceResult(GeneralStatus.OBJECT_STATE_CONFLICT)
        if self._safety_connections():
            return ServiceResult(GeneralStatus.DEVICE_STATE_CONFLICT)
        self.state.tunid, self.state.proposed_tunid = applied, None
        return ServiceResult(GeneralStatus.SUCCESS)

    def safety_reset(self, instance: CipInstance, path: RequestPath, data: bytes,
                     context: MessageContext) -> ServiceResult:
        refused = self._instance_only(path)
        if refused:
            return refused
        if not data:
            return ServiceResult(GeneralStatus.NOT_ENOUGH_DATA)
        kind = data[0]
        if kind > 2:
            return ServiceResult(GeneralStatus.INVALID_PARAMETER)
        status = _exact(data, _RESET_FIXED + (1 if kind == 2 else 0))
        if status:
            return ServiceResult(status)
        password, tunid = data[1:1 + PASSWORD_SIZE], Unid.decode(data[1 + PASSWORD_SIZE:_RESET_FIXED])
        preserve = data[_RESET_FIXED] if kind == 2 else 0
        if preserve & (RESERVED_BIT | EXTENDED_MAP):
            return ServiceResult(GeneralStatus.INVALID_PARAMETER)
        if password != self.state.password:
            return ServiceResult(GeneralStatus.PRIVILEGE_VIOLATION)
        if tunid != self.state.tunid:
            return ServiceResult(GeneralStatus.INVALID_PARAMETER)
        self._close(f"safety reset (type {kind})", context.now)
        self.state.reset(kind, preserve)
        return ServiceResult(GeneralStatus.SUCCESS)


def _owners_size(data: bytes) -> int | None:
    """Attribute 28 in request data: a UINT count, then per entry 10 bytes, a USINT size, the path."""
    if len(data) < 2:
        return None
    (count,) = struct.unpack_from("<H", data)
    offset = 2
    for _ in range(count):
        if len(data) < offset + UNID_SIZE + 1:
            return None
        offset += UNID_SIZE + 1 + data[offset + UNID_SIZE]
    return offset


OUTPUT_CONNECTION_POINT_OWNERS = Encoded("STRUCT of UINT count, STRUCT of UNID, USINT size, EPATH[count]", _owners_size)
