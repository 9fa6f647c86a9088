"""What a fault does to the module itself, beyond what its network paths see (device/fault_type.py's
`FaultedDevice`): its power and its IP address.

- Power lost: the module's volatile state is gone at once, as a power cycle loses it (device/reset.py's
  type-0 reset, CIP Networks Library Vol. 1, 5-2.4.1): every connection ends without a word (the
  originators' watchdogs time them out), the output and configuration images go to their power-up
  state (zero), the interface counters (Ethernet Link attribute 4) and session handles start again;
  non-volatile settings (the TCP/IP and Ethernet Link settings, a safety target's TUNID and
  configuration) are kept. The fault's hooks keep it silent while the power is off.
- Power back: the module boots, its reset window (no listener, UDP and class-1 dropped, Identity
  attribute 8 self testing) for the boot time, then it is operational (device/reset.py's `end`).
- An address conflict: the TCP/IP object's attributes 1 and 11 (cip/tcpip_interface.py).
Time is passed in (int ns of the monotonic clock)."""

from __future__ import annotations

import socket
import struct

from enip_farm.device.events import AddressConflict, PowerLost, PowerReturned, SelfTestDone
from enip_farm.device.guard import DeviceGuard
from enip_farm.device.objects import ObjectModel
from enip_farm.device.reset import ResetWindow
from enip_farm.device.sessions import SessionHandles


class ModuleHardware:
    """One device's power and address, as faults change them."""

    def __init__(self, objects: ObjectModel, guard: DeviceGuard, sessions: SessionHandles,
                 window: ResetWindow, address: str, mac: bytes) -> None:
        self.address = address
        self.mac = mac
        self.objects = objects
        self.guard = guard
        self.sessions = sessions
        self.window = window
        self.powered = True
        self.self_test_ns = 0  # after the boot now under way: how long the self test lasts
        self.self_testing = False  # answering, but Identity attribute 8 says self testing

    def lose_power(self, now: int) -> None:
        """The supply is gone at `now`: the module's volatile state with it."""
        objects, guard = self.objects, self.guard
        table = objects.table
        with guard.transaction(now) as transaction:
            for connection in list(table.connections.values()):
                table.close(connection, "power lost", now)
            for role in ("output", "configuration"):
                assembly = objects.assemblies.get(role)
                if assembly is not None:
                    assembly.data[:] = bytes(len(assembly.data))
            objects.link.clear_counters()
            self.sessions.restart()
            self.powered = False
            transaction.emit(PowerLost())

    def restore_power(self, boot_ns: int, now: int, self_test_ns: int = 0) -> None:
        """The supply is back at `now`: the module boots for `boot_ns` (its reset window), then answers,
        self testing (Identity attribute 8 = 1) for `self_test_ns` before it is operational (the farm
        times the phases: farm/resets.py)."""
        with self.guard.transaction(now) as transaction:
            self.window.resets += 1
            self.window.deadline = now + boot_ns
            self.powered = True
            self.self_test_ns = self_test_ns
            transaction.emit(PowerReturned(boot_ns / 1e9))

    def begin_self_test(self) -> int:
        """The boot's silence is over: the self test (its length in ns; 0: none, operational at once)."""
        length, self.self_test_ns = self.self_test_ns, 0
        self.self_testing = length > 0
        return length

    def end_self_test(self, now: int | None = None) -> None:
        """The self test is over at `now` (None: the device's clock): operational."""
        if self.self_testing:
            self.self_testing = False
            self.guard.record(SelfTestDone(), now)

    def address_conflict(self, activity: int, remote_mac: bytes, probing: bool) -> bool:
        """Another host claims the module's address (its ARP reply, RFC 826, is the ARP PDU attribute 11
        keeps); `probing`: found as the module came up. True: the module gives the address up (it
        detected the conflict, SelectAcd 1, while probing); with SelectAcd 0 it detects nothing and keeps it."""
        ip = socket.inet_aton(self.address)
        arp_pdu = struct.pack("!HHBBH6s4s6s4s", 1, 0x0800, 6, 4, 2, remote_mac, ip, self.mac, ip)
        with self.guard.transaction() as transaction:
            detected = self.objects.tcpip.conflict_detected(activity, remote_mac, arp_pdu, probing)
            transaction.emit(AddressConflict(remote_mac, detected, detected and probing))
        return detected and probing

    def conflict_resolved(self) -> None:
        with self.guard.transaction():
            self.objects.tcpip.conflict_over()
