"""CIP Safety faults of a safety target (the DSQC1042), each as a safety originator must detect it
(CIP Networks Library Vol. 5, 2-4.6 and 2-4.7): applied to the class-0 datagrams the target sends,
after its Safety Validators built them (so the validators' own books stay right).

- `crc`: every safe-input data message has its last CRC byte inverted: the originator's consumer
  finds the CRC wrong and drops it (no valid data: its network time expectation runs out).
- `stale`: every safe-input data message is the first one sent while the fault holds, again (valid
  CRCs, the same time stamp): the originator's consumer sees the time stamp stand still.
- `time-coordination`: the time coordination messages answering the originator's pings (for its
  safe-output connection) are not sent: its producer's ping times out (Timeout_Multiplier.PI + 2
  ping intervals)."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any

from enip_farm.protocol.safety.multicast import MulticastProducer
from enip_farm.protocol.safety.validator import SafetyConsumer, SafetyProducer

_HEADER = 18  # a class-0 packet: item count, sequenced address item (id, sequence), data item header
SAFETY_FAULT_MODES = ("crc", "stale", "time-coordination")


class SafetyTamper:
    """What a safety fault does to the target's class-0 datagrams; counts what it did."""

    def __init__(self, mode: str) -> None:
        if mode not in SAFETY_FAULT_MODES:
            raise ValueError(f"a safety fault is one of {', '.join(SAFETY_FAULT_MODES)}, not {mode!r}")
        self.mode = mode
        self.kept: dict[int, bytes] = {}  # stale: each connection's first data message while the fault holds
        self.tampered = 0

    @staticmethod
    def streams(connections: Iterable[Any]) -> tuple[frozenset[int], frozenset[int]]:
        """The T->O connection ids of the safe-input data and of the time coordination answers."""
        data, coordination = set(), set()
        for connection in connections:
            safety = getattr(connection, "safety", None)
            if isinstance(safety, (SafetyProducer, MulticastProducer)):
                data.add(connection.t_o_id)
            elif isinstance(safety, SafetyConsumer):
                coordination.add(connection.t_o_id)
        return frozenset(data), frozenset(coordination)

    def through(self, send: Callable[[bytes, Any], None], data: frozenset[int],
                coordination: frozenset[int]) -> Callable[[bytes, Any], None]:
        def tampered(packet: bytes, address: Any) -> None:
            if len(packet) > _HEADER:
                connection_id = int.from_bytes(packet[6:10], "little")
                if self.mode == "time-coordination" and connection_id in coordination:
                    self.tampered += 1
                    return
                if connection_id in data:
                    payload = packet[_HEADER:]
                    if self.mode == "crc":
                        payload = payload[:-1] + bytes([payload[-1] ^ 0xFF])
                    elif self.mode == "stale":
                        payload = self.kept.setdefault(connection_id, payload)
                        payload = payload if len(payload) == len(packet) - _HEADER else packet[_HEADER:]
                    if payload != packet[_HEADER:]:
                        self.tampered += 1
                    packet = packet[:_HEADER] + payload
            send(packet, address)
        return tampered
