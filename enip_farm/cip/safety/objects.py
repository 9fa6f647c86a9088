"""The Safety Validator object (class 0x3A) of a safety target (CIP Networks Library Vol. 5,
chapter 5; attribute numbers as Wireshark's CIP Safety dissector names them): each open safety
connection is one validator instance (its instance id is the target connection serial number of
the SafetyOpen reply). The Safety Supervisor (class 0x39) is in supervisor.py."""

from __future__ import annotations

from collections.abc import Callable, Iterable

from enip_farm.cip.attribute import Attribute, CipInstance
from enip_farm.cip.connection import Connection
from enip_farm.cip.data_types import UINT, USINT
from enip_farm.cip.object import CipClass
from enip_farm.protocol.cip import ClassCode
from enip_farm.protocol.safety.validator import SafetyConsumer

#: Safety Validator state (attribute 1): 0 unallocated, 1 initializing, 2 established, 3 failed.
_INITIALIZING, _ESTABLISHED = 1, 2
#: Safety Validator type (attribute 2): bit 7 consumer (1) / producer (0), bits 0-6 1 = single-cast,
#: 2 = multicast (all consumers of a multicast producer share its instance).
_CONSUMER, _SINGLE_CAST, _MULTICAST = 0x80, 0x01, 0x02


class SafetyValidatorObject(CipClass):
    class_id = ClassCode.SAFETY_VALIDATOR
    revision = 1

    def __init__(self, connections: Callable[[], Iterable[Connection]], fault_count: Callable[[], int]) -> None:
        super().__init__()
        self._connections = connections
        self.class_instance.declare(Attribute(8, UINT, lambda: fault_count() & 0xFFFF))  # safety connection faults

    def _validators(self) -> dict[int, Connection]:
        return {c.instance: c for c in self._connections() if c.safety is not None}

    def instance(self, instance_id: int) -> CipInstance | None:
        if instance_id == 0:
            self.instances = {i: CipInstance() for i in self._validators()}  # class attributes 2, 3
            return self.class_instance
        connection = self._validators().get(instance_id)
        if connection is None:
            return None
        safety = connection.safety
        consumer = type(safety) is SafetyConsumer
        state = _ESTABLISHED if (safety.init_complete if consumer else safety.consumer_active) else _INITIALIZING  # type: ignore[union-attr]
        attributes = [
            Attribute(1, USINT, value=state),
            Attribute(2, USINT, value=(_CONSUMER if consumer else 0)
                      | (_MULTICAST if connection.multicast else _SINGLE_CAST)),
        ]
        if consumer:
            attributes.append(Attribute(12, UINT, value=safety.max_data_age))  # type: ignore[union-attr]
        return CipInstance(attributes)
