"""Identity object, class 0x01 (CIP Networks Library Vol. 1, 5-2): vendor, device type, product
code, revision, status, serial number, product name and state (attributes 1-8), and the Reset
service (0x05, 5-2.4.1).

Reset's request data is an optional USINT, the reset type: 0 (the default, no data) emulates a
power cycle; 1 returns to the out-of-box configuration, then emulates a power cycle; 2 returns to
the out-of-box configuration except the communication link parameters (TCP/IP Interface and
Ethernet Link settings), then emulates a power cycle. Other types get 0x20 (invalid parameter);
more than one byte gets 0x15. The object only takes the request: it answers success with the effect
`ResetRequested(type)` (cip/object.py `Effect`), which the device performs once the reply is built
(device/reset.py); the server sends that reply before it ends the device's sessions (farm/resets.py)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from enip_farm.cip.attribute import Access, Attribute, CipInstance
from enip_farm.cip.data_types import SHORT_STRING, UDINT, UINT, USINT, WORD, Packed
from enip_farm.cip.object import CipClass, Effect, ServiceResult
from enip_farm.protocol.cip import ClassCode, Service
from enip_farm.protocol.epath import RequestPath
from enip_farm.protocol.session import MessageContext
from enip_farm.protocol.status import GeneralStatus

#: Identity status bits 4-7 = 0b0011: "no I/O connections established" (Vol. 1, table 5-2.4).
#: Attribute 8, state (Vol. 1, 5-2.3): 1 device self testing, 3 operational.
STATE_SELF_TESTING = 1
STATE_OPERATIONAL = 3
#: Reset types (Vol. 1, 5-2.4.1): 0 power cycle, 1 out-of-box configuration and power cycle, 2 the
#: same except the communication link parameters.
RESET_POWER_CYCLE = 0
RESET_OUT_OF_BOX = 1
RESET_KEEP_COMMUNICATION = 2
RESET_TYPES = (RESET_POWER_CYCLE, RESET_OUT_OF_BOX, RESET_KEEP_COMMUNICATION)
#: Attribute 4: major and minor revision (Vol. 1, 5-2.2.1.4).
REVISION = Packed("STRUCT of USINT major, USINT minor", "<BB")


@dataclass(frozen=True, slots=True)
class ResetRequested(Effect):
    """The effect of an accepted Reset (5-2.4.1): restart as reset type `type` (0, 1 or 2) says."""

    type: int


class IdentityObject(CipClass):
    class_id = ClassCode.IDENTITY
    revision = 1
    optional_attributes = (8,)

    def __init__(self, *, vendor_id: int, device_type: int, product_code: Callable[[], int],
                 revision: tuple[int, int] | Callable[[], tuple[int, int]],
                 serial_number: int, product_name: str, status: Callable[[], int],
                 state: Callable[[], int] = lambda: STATE_OPERATIONAL) -> None:
        super().__init__()
        self.instances[1] = CipInstance((  # Get Attributes All: the required attributes 1-7, as OpENer
            Attribute(1, UINT, value=vendor_id),
            Attribute(2, UINT, value=device_type),
            Attribute(3, UINT, product_code),
            Attribute(4, REVISION, revision) if callable(revision) else Attribute(4, REVISION, value=revision),
            Attribute(5, WORD, status),
            Attribute(6, UDINT, value=serial_number),
            Attribute(7, SHORT_STRING, value=product_name),
            Attribute(8, USINT, state, access=Access.GET),
        ))
        self.handlers[Service.RESET] = self.reset

    def reset(self, instance: CipInstance, path: RequestPath, data: bytes,
              context: MessageContext) -> ServiceResult:
        if path.instance_id == 0:  # an instance service
            return ServiceResult(GeneralStatus.SERVICE_NOT_SUPPORTED)
        if len(data) > 1:
            return ServiceResult(GeneralStatus.TOO_MUCH_DATA)
        kind = data[0] if data else RESET_POWER_CYCLE
        if kind not in RESET_TYPES:
            return ServiceResult(GeneralStatus.INVALID_PARAMETER)
        return ServiceResult(GeneralStatus.SUCCESS, effects=(ResetRequested(kind),))
