"""The Safety Validator of a target, sans-IO (CIP Networks Library Vol. 5, 2-4.6 and 2-4.7, and
the example code of Vol. 5 as public stacks implement it): the server that consumes the safe
outputs a single-cast originator produces (O->T data, T->O time coordination), and the client that
produces the safe inputs (T->O data, O->T time coordination). Time is an integer of nanoseconds
passed in; the CIP Safety clocks are its 128 us ticks, 16 bits wide.
"""

from __future__ import annotations

from typing import NamedTuple

from enip_farm.protocol.safety.crc import Seeds
from enip_farm.protocol.safety.messages import (
    decode_data,
    decode_time_coordination,
    encode_data,
    encode_time_coordination,
    message_timestamp,
    mode_byte,
    wire_size,
)
from enip_farm.protocol.safety.segment import SafetySegment

TICK_NS = 128_000
#: Timeout_Multiplier.PI: ping intervals a producer waits for a time coordination message, plus 2
#: (Vol. 5, 2-4.7: the base format allows 1..4).
MAX_PI = 4


def ticks(now: int) -> int:
    """A CIP Safety clock reading: 128 us ticks, 16 bits."""
    return now // TICK_NS & 0xFFFF


class Consumed(NamedTuple):
    """What one O->T message did: `fault` names an integrity ("crc") or a time ("timing") fault;
    `faulted` says the connection is faulted (its outputs go to the safe state); `data` is the data
    to apply (None: nothing to apply); `run` the producer's run/idle."""

    fault: str | None = None
    detail: str = ""
    faulted: bool = False
    data: bytes | None = None
    run: bool = False


class SafetyConsumer:
    """Safety Validator server (Vol. 5, 2-4.6): checks each data message's integrity, sequence
    and age, answers ping count changes with time coordination messages, and supervises the data
    with the network time expectation: no valid data for that long faults the connection."""

    def __init__(self, segment: SafetySegment, length: int, pid: Seeds, cid: Seeds, now: int,
                 first_watchdog_ns: int, initial_rc_offset: int = 1) -> None:
        self.length = length
        self.extended = segment.extended
        self.pid, self.cid = pid, cid
        self.ntem = segment.network_time_expectation_multiplier
        self.nte_ns = segment.network_time_expectation_ns
        self.max_fault_number = segment.max_fault_number
        self.tcoo_min_ns = segment.time_coord_msg_min_multiplier * TICK_NS
        self.opened_at = now
        self.first_watchdog_ns = first_watchdog_ns
        clock = ticks(now)
        # cold start (Vol. 5 example code): the consumer picks the producer's initial timestamp
        # and rollover value and returns them in the SafetyOpen reply (extended format)
        self.initial_timestamp = clock
        self.initial_rollover = (clock + initial_rc_offset) & 0xFFFF
        self.rollover = self.initial_rollover
        self.last_timestamp_for_rollover = clock
        self.init_complete = False
        self.last_timestamp = 0
        self.last_ping = 3
        self.last_valid: int | None = None
        self.last_tcoo: int | None = None
        self.tcoo_due: int | None = None  # a time coordination message held back by the min multiplier
        self.fault_count = 0
        self.max_data_age = 0  # 128 us ticks
        self.consumed = 0
        self.crc_faults = 0
        self.timing_faults = 0
        self.faulted = False

    @property
    def expected_size(self) -> int:
        return wire_size(self.length)

    @property
    def deadline(self) -> int:
        """When the data gets too old: the last valid message + the network time expectation;
        before the first one, the first watchdog if that is longer."""
        if self.last_valid is None:
            return self.opened_at + max(self.nte_ns, self.first_watchdog_ns)
        return self.last_valid + self.nte_ns

    def receive(self, message: bytes, now: int) -> Consumed:
        length = self.length
        if len(message) != wire_size(length):
            return self._fault("crc", f"{len(message)} bytes, not {wire_size(length)}", now)
        timestamp = message_timestamp(message, length, self.extended)
        rollover = 0
        if self.extended and (self.init_complete or timestamp):
            rollover = (self.rollover + (timestamp < self.last_timestamp_for_rollover)) & 0xFFFF
        decoded = decode_data(message, length, self.pid, self.extended, rollover)
        if decoded is None:
            return self._fault("crc", "CRC or redundancy mismatch", now)
        if decoded.ping_count != self.last_ping:
            self.last_ping = decoded.ping_count
            self.tcoo_due = max(now, self.last_tcoo + self.tcoo_min_ns) if self.last_tcoo is not None else now
        was_complete = self.init_complete
        if not was_complete and (timestamp or decoded.run):
            self.init_complete = True
        clock = ticks(now)
        if was_complete:
            delta = (timestamp - self.last_timestamp) & 0xFFFF
            if delta == 0 or delta > self.ntem:
                return self._fault("timing", f"timestamp delta {delta} ticks (network time expectation "
                                   f"{self.ntem})", now)
        if self.init_complete:
            age = (clock - timestamp) & 0xFFFF
            if age > self.ntem:
                return self._fault("timing", f"data age {age} ticks > network time expectation {self.ntem}", now)
            self.max_data_age = max(self.max_data_age, age)
            if self.extended:
                self.rollover = rollover
                self.last_timestamp_for_rollover = timestamp
        self.last_timestamp = timestamp
        self.last_valid = now
        self.consumed += 1
        run = decoded.run and self.init_complete
        return Consumed(data=decoded.data, run=run)

    def _fault(self, kind: str, detail: str, now: int) -> Consumed:
        if kind == "crc":
            self.crc_faults += 1
        else:
            self.timing_faults += 1
        self.fault_count += 1
        age_ok = self.last_valid is not None and now - self.last_valid <= self.nte_ns
        if self.extended and self.fault_count < self.max_fault_number and age_ok:
            return Consumed(kind, detail + "; message discarded")  # Vol. 5: Max_Fault_Number
        self.faulted = True
        return Consumed(kind, detail, faulted=True)

    def time_coordination(self, now: int) -> bytes | None:
        """The time coordination message due by `now`, if any."""
        if self.tcoo_due is None or self.tcoo_due > now:
            return None
        self.tcoo_due = None
        self.last_tcoo = now
        return encode_time_coordination(self.last_ping, ticks(now), self.cid, self.extended)


class SafetyProducer:
    """Safety Validator client (Vol. 5, 2-4.7): produces data messages every EPI, changes the ping
    count every ping interval, and corrects its timestamps into the consumer's time base from the
    time coordination message that answers each ping (worst case: the consumer time value minus
    the producer clock when the answer arrives). No answer for Timeout_Multiplier.PI + 2 ping
    intervals faults the connection."""

    def __init__(self, segment: SafetySegment, length: int, pid: Seeds, cid: Seeds, epi_ns: int, now: int,
                 first_watchdog_ns: int) -> None:
        self.length = length
        self.extended = segment.extended
        self.pid, self.cid = pid, cid
        self.ping_interval_ns = max(1, segment.ping_interval_epi_multiplier) * epi_ns
        self.timeout_pi = min(max(segment.timeout_multiplier, 1), MAX_PI)
        self.opened_at = now
        self.first_watchdog_ns = first_watchdog_ns
        self.ping_count = 0
        self.ping_sent_at = now
        self.consumer_active = False
        self.correction = 0  # Consumer_Time_Correction_Value, ticks
        self.rollover = segment.initial_rollover_value
        self.last_timestamp_for_rollover = segment.initial_timestamp
        self.last_sent: int | None = None
        self.last_tcoo: int | None = None
        self.produced = 0
        self.crc_faults = 0

    @property
    def deadline(self) -> int:
        timeout = (self.timeout_pi + 2) * self.ping_interval_ns
        if self.last_tcoo is None:
            return self.opened_at + max(timeout, self.first_watchdog_ns)
        return self.last_tcoo + timeout

    def produce(self, data: bytes, now: int, run: bool = True) -> bytes:
        while now - self.ping_sent_at >= self.ping_interval_ns:
            self.ping_count = (self.ping_count + 1) & 3
            self.ping_sent_at += self.ping_interval_ns
        self.produced += 1
        if not self.consumer_active:  # idle, timestamp 0 and rollover 0 until the first answer
            return encode_data(data, mode_byte(False, self.ping_count), 0, self.pid, self.extended, 0)
        timestamp = (ticks(now) + self.correction) & 0xFFFF
        if self.last_sent is not None and not 0 < (timestamp - self.last_sent) & 0xFFFF < 0x8000:
            timestamp = (self.last_sent + 1) & 0xFFFF  # a smaller correction never makes time run back
        self.last_sent = timestamp
        if self.extended:
            if timestamp < self.last_timestamp_for_rollover:
                self.rollover = (self.rollover + 1) & 0xFFFF
            self.last_timestamp_for_rollover = timestamp
        mode = mode_byte(run, self.ping_count)
        return encode_data(data, mode, timestamp, self.pid, self.extended, self.rollover)

    def receive(self, message: bytes, now: int) -> Consumed:
        reply = decode_time_coordination(message, self.cid, self.extended)
        if reply is None:
            self.crc_faults += 1
            return Consumed("crc", "time coordination message: CRC or format mismatch")
        if reply.ping_count_reply == self.ping_count:
            self.correction = (reply.consumer_time - ticks(now)) & 0xFFFF
            self.consumer_active = True
            self.last_tcoo = now
        return Consumed()

