"""The multicast Safety Validator client of a target, sans-IO (CIP Networks Library Vol. 5, 2-4.7
and 3-5.4, and the example code of Vol. 5 as the HMS CIP Safety target stack implements it): one
producer of the safe inputs, up to Max_Consumer_Number (1..15) consumers, each opened by its own
SafetyOpen and numbered 1..max by the target (the consumer number of its application reply).

- Data messages carry the producer's own clock as timestamp (no consumer's correction); each one
  has a time correction section appended (EtherNet/IP: no separate time correction connection).
- The ping count changes every Ping_Interval_EPI_Multiplier productions. From the 8th production
  of a ping interval, the sections go round the consumer numbers once: an active consumer's
  section carries its number, the active bit and its Time_Correction_Value (its time value minus
  the producer's clock when its time coordination message answered the current ping); a free or
  idle number, and every production after the round, gets a null section (number 0, idle, 0).
- Each consumer is supervised on its own: no answer for Timeout_Multiplier.PI + 2 ping intervals
  ends that consumer only; the production ends with the last one.
"""

from __future__ import annotations

from dataclasses import dataclass

from enip_farm.protocol.safety.crc import Seeds
from enip_farm.protocol.safety.messages import (
    TimeCorrection,
    decode_time_coordination,
    encode_data,
    encode_time_correction,
    mode_byte,
)
from enip_farm.protocol.safety.segment import SafetySegment
from enip_farm.protocol.safety.validator import MAX_PI, Consumed, ticks

MAX_CONSUMERS = 15  # Max_Consumer_Number of a multicast connection (Vol. 5, 3-5.3)
_FIRST_SECTION_EPI = 8  # time correction sections start at the 8th production of a ping interval
_NULL = TimeCorrection(0, False, 0)


@dataclass
class _Consumer:
    cid: Seeds
    timeout_pi: int  # Timeout_Multiplier.PI: 1..4
    opened_at: int
    active: bool = False
    correction: int = 0  # Consumer_Time_Correction_Value, ticks
    last_tcoo: int | None = None


class MulticastProducer:
    """The producer all consumers of one safe input point share (one Safety Validator instance)."""

    def __init__(self, segment: SafetySegment, length: int, pid: Seeds, epi_ns: int, now: int,
                 first_watchdog_ns: int) -> None:
        self.length = length
        self.extended = segment.extended
        self.pid = pid
        self.max_consumers = segment.max_consumer_number
        self.ping_interval_epi_multiplier = max(1, segment.ping_interval_epi_multiplier)
        self.ping_interval_ns = self.ping_interval_epi_multiplier * epi_ns
        self.first_watchdog_ns = first_watchdog_ns
        self.consumers: dict[int, _Consumer] = {}  # by consumer number
        self.ping_count = 0
        self.epi_count = 0  # productions since the ping count changed
        self.round_robin = self.max_consumers  # index of the next section's consumer; max: round done
        # extended format: the producer picks the initial timestamp and rollover value (its clock, 0)
        self.last_timestamp_for_rollover = ticks(now)
        self.rollover = 0
        self.produced = 0
        self.crc_faults = 0

    @property
    def initial_values(self) -> tuple[int, int]:
        """Initial timestamp and rollover value for a SafetyOpen reply (extended format): where the
        producer's timestamps and rollover count stand now."""
        return self.last_timestamp_for_rollover, self.rollover

    def join(self, segment: SafetySegment, cid: Seeds, now: int) -> MulticastConsumer | None:
        """A new consumer with the lowest free number; None when all numbers are taken."""
        number = next((n for n in range(1, self.max_consumers + 1) if n not in self.consumers), None)
        if number is None:
            return None
        self.consumers[number] = _Consumer(cid, min(max(segment.timeout_multiplier, 1), MAX_PI), now)
        return MulticastConsumer(self, number)

    def leave(self, number: int) -> None:
        self.consumers.pop(number, None)

    def deadline(self, number: int) -> int:
        consumer = self.consumers[number]
        timeout = (consumer.timeout_pi + 2) * self.ping_interval_ns
        if consumer.last_tcoo is None:
            return consumer.opened_at + max(timeout, self.first_watchdog_ns)
        return consumer.last_tcoo + timeout

    def produce(self, data: bytes, now: int, run: bool = True) -> bytes:
        """The next data message with its time correction section."""
        self.epi_count += 1
        if self.epi_count >= self.ping_interval_epi_multiplier:
            self.ping_count = (self.ping_count + 1) & 3
            self.epi_count = 0
        if self.epi_count == _FIRST_SECTION_EPI:
            self.round_robin = 0
        correction = _NULL
        if self.round_robin < self.max_consumers:
            consumer = self.consumers.get(self.round_robin + 1)
            if consumer is not None and consumer.active:
                correction = TimeCorrection(self.round_robin + 1, True, consumer.correction)
            self.round_robin += 1
        timestamp = ticks(now)
        if self.extended and timestamp < self.last_timestamp_for_rollover:
            self.rollover = (self.rollover + 1) & 0xFFFF
        self.last_timestamp_for_rollover = timestamp
        self.produced += 1
        message = encode_data(data, mode_byte(run, self.ping_count), timestamp, self.pid, self.extended,
                              self.rollover)
        return message + encode_time_correction(correction, self.pid, self.extended)

    def receive(self, number: int, message: bytes, now: int) -> Consumed:
        """A time coordination message of consumer `number`: an answer to the current ping sets its
        correction (its time value minus the producer's clock now) and makes it active."""
        consumer = self.consumers[number]
        reply = decode_time_coordination(message, consumer.cid, self.extended)
        if reply is None:
            self.crc_faults += 1
            return Consumed("crc", f"time coordination message of consumer {number}: CRC or format mismatch")
        if reply.ping_count_reply == self.ping_count:
            consumer.correction = (reply.consumer_time - ticks(now)) & 0xFFFF
            consumer.active = True
            consumer.last_tcoo = now
        return Consumed()


class MulticastConsumer:
    """One consumer of a multicast producer: the Safety Validator of one consumer's connection."""

    def __init__(self, producer: MulticastProducer, number: int) -> None:
        self.producer = producer
        self.number = number

    @property
    def deadline(self) -> int:
        return self.producer.deadline(self.number)

    @property
    def timeout_pi(self) -> int:
        return self.producer.consumers[self.number].timeout_pi

    @property
    def consumer_active(self) -> bool:
        return self.producer.consumers[self.number].active

    def receive(self, message: bytes, now: int) -> Consumed:
        return self.producer.receive(self.number, message, now)

    def leave(self) -> None:
        self.producer.leave(self.number)
