"""Details no test pinned until mutation testing (bench/mutation.py, issue 32) changed them and every
test still passed: codes checked against a real peer's (pycomm3) rather than against themselves,
fields at offsets other than 0, bytes the spec fixes (an interface handle of 0). Each test says
which mutant it kills; bench/mutation-equivalents.md lists those no test can tell apart."""

from __future__ import annotations

import math
import socket
import struct
import time

import pytest
from pycomm3 import ClassCode as PeerClassCode
from pycomm3 import Services as PeerServices
from pycomm3.cip import ConnectionManagerServices, EncapsulationCommands
from pycomm3.cip.data_types import DataTypes

from enip_farm.cip.connection_path import KeyIdentity, key_mismatch
from enip_farm.cip.connection_policy import Refusal
from enip_farm.cip.connection_table import Opened
from enip_farm.cip.data_types import ELEMENTARY
from enip_farm.cip.parameter import ParameterInstance, ParameterSpec
from enip_farm.cip.reconnection import ORIGINATORS, Reconnections
from enip_farm.config import parse_config
from enip_farm.device.build import build_profiles
from enip_farm.device.catalogue import shipped_catalogue
from enip_farm.device.device import Device
from enip_farm.device.faults import DeviceFaults, Disconnect, Fault, FaultError
from enip_farm.protocol.cip import ClassCode, MessageRouterReply, Service, decode_reply, encode_request
from enip_farm.protocol.commands import (
    ServiceItem,
    decode_service_item,
    encode_service_item,
    encode_unconnected_payload,
)
from enip_farm.protocol.connection import (
    ConnectionTriad,
    ConnectionType,
    ForwardOpenRequest,
    NetworkParameters,
    encode_forward_open,
    encode_io_packet,
)
from enip_farm.protocol.encapsulation import Command
from enip_farm.protocol.epath import ElectronicKey, LogicalSegment, LogicalType, decode_epath, encode_request_path
from enip_farm.protocol.session import MessageContext
from enip_farm.protocol.status import ExtendedStatus as X
from enip_farm.server.batch import SO_TIMESTAMPNS, Datagrams, wall_stamp
from enip_farm.server.implicit import CyclicIoThread, DeviceIo, Lag
from enip_farm.server.waits import os_wait_s
from tests.helpers import wait_for
from tests.test_safety import ORIGINATOR as SAFETY_ORIGINATOR
from tests.test_safety import make_table as safety_make_table
from tests.test_safety import safety_open

T0 = 5_000_000_000  # ns: the faults never read a clock

# -- protocol/: codes as a peer has them --------------------------------------------------------------


def _code(peer: bytes) -> int:
    return int.from_bytes(peer, "little")


def test_service_codes_are_pycomm3s() -> None:
    """Vol. 1, appendix A and 3-5.5: e.g. Unconnected Send 0x52 (a mutant made it 0x53)."""
    peer = {**{k: v for k, v in vars(PeerServices).items() if isinstance(v, bytes)},
            **{k: v for k, v in vars(ConnectionManagerServices).items() if isinstance(v, bytes)}}
    names = {Service.GET_ATTRIBUTES_ALL: "get_attributes_all", Service.SET_ATTRIBUTES_ALL: "set_attributes_all",
             Service.GET_ATTRIBUTE_LIST: "get_attribute_list", Service.SET_ATTRIBUTE_LIST: "set_attribute_list",
             Service.RESET: "reset", Service.MULTIPLE_SERVICE_PACKET: "multiple_service_request",
             Service.GET_ATTRIBUTE_SINGLE: "get_attribute_single", Service.SET_ATTRIBUTE_SINGLE: "set_attribute_single",
             Service.FORWARD_CLOSE: "forward_close", Service.UNCONNECTED_SEND: "unconnected_send",
             Service.FORWARD_OPEN: "forward_open", Service.LARGE_FORWARD_OPEN: "large_forward_open"}
    assert set(names) == set(Service) - {Service.GET_AND_CLEAR}  # Get_and_Clear (0x4C, Ethernet Link): not in pycomm3
    assert {service.name: int(service) for service in names} == {s.name: _code(peer[n]) for s, n in names.items()}
    assert Service.GET_AND_CLEAR == 0x4C


def test_class_codes_are_pycomm3s() -> None:
    """Vol. 1, table 5-1.1: e.g. Parameter 0x0F (a mutant made it 0x10)."""
    names = {ClassCode.IDENTITY: "identity_object", ClassCode.MESSAGE_ROUTER: "message_router",
             ClassCode.ASSEMBLY: "assembly", ClassCode.CONNECTION_MANAGER: "connection_manager",
             ClassCode.PARAMETER: "parameter", ClassCode.SAFETY_SUPERVISOR: "safety_supervisor",
             ClassCode.SAFETY_VALIDATOR: "safety_validator", ClassCode.TCP_IP_INTERFACE: "tcp_ip_interface",
             ClassCode.ETHERNET_LINK: "ethernet_link"}
    assert set(names) == set(ClassCode)
    assert {c.name: int(c) for c in names} == {c.name: _code(getattr(PeerClassCode, n)) for c, n in names.items()}


def test_encapsulation_commands_are_pycomm3s() -> None:
    """Vol. 2, table 2-3.2: e.g. ListServices 0x0004."""
    assert {c.name: int(c) for c in Command} == {
        c.name: _code(getattr(EncapsulationCommands, c.name.lower())) for c in Command}


# -- protocol/: fields at their offsets -----------------------------------------------------------------


def test_a_32_bit_logical_segment_after_an_8_bit_one() -> None:
    """Vol. 1, C-1.4.2: the 32-bit format has a pad byte, its value at offset + 2 of the segment
    (a mutant read `offset | 2`, the same at offset 0 and 4, not at 2)."""
    assert decode_epath(bytes.fromhex("20 04 26 00 78 56 34 12 30 03")) == [
        LogicalSegment(LogicalType.CLASS_ID, 4), LogicalSegment(LogicalType.INSTANCE_ID, 0x12345678),
        LogicalSegment(LogicalType.ATTRIBUTE_ID, 3)]
    assert decode_epath(bytes.fromhex("21 00 F5 00 26 00 01 00 00 80")) == [
        LogicalSegment(LogicalType.CLASS_ID, 0xF5), LogicalSegment(LogicalType.INSTANCE_ID, 0x80000001)]


def test_the_list_services_item() -> None:
    """Vol. 2, 2-4.6.3: version 1, flags (bit 5: CIP over TCP, bit 8: class 0/1 over UDP), a
    16-byte name; decoded from its first byte (a mutant read from the second)."""
    item = bytes.fromhex("0100 2001") + b"Communications\x00\x00"
    assert encode_service_item(ServiceItem(1, 0x0120, "Communications")) == item
    assert decode_service_item(item) == ServiceItem(1, 0x0120, "Communications")


def test_an_unconnected_payload_has_interface_handle_0() -> None:
    """Vol. 2, 2-4.7: interface handle 0 (CIP), then the timeout, the null address item and the
    unconnected data item (a mutant wrote handle 1)."""
    assert encode_unconnected_payload(b"\x0e\x02\x20\x01\x24\x01", timeout=5) == bytes.fromhex(
        "00000000 0500 0200 0000 0000 b200 0600 0e0220012401")


# -- device/: fault parameters to their bounds, and what several faults make together ---------------------


@pytest.mark.parametrize(("kind", "params", "message"), [
    ("status", {"service": 256, "status": 8}, "service: must be a CIP service code 0..255 (0x00..0xFF), got 256"),
    ("status", {"service": -1, "status": 8}, "service: must be a CIP service code 0..255 (0x00..0xFF), got -1"),
    ("status", {"service": 14, "status": 256}, "status: must be a CIP general status 0..255 (0x00..0xFF), got 256"),
    ("status", {"service": 14}, "status: a status fault needs a service and a status"),
    ("status", {"status": 8}, "service: a status fault needs a service and a status"),
    ("delay", {"delay_ms": 60_000.5}, "delay_ms: must be 0..60000 ms, got 60000.5"),
    ("delay", {"delay_ms": -0.5}, "delay_ms: must be 0..60000 ms, got -0.5"),
    ("delay", {"delay_ms": 50, "max_delay_ms": 40}, "max_delay_ms: must not be below delay_ms (50), got 40"),
    ("delay", {"delay_ms": 0}, "delay_ms: a delay fault needs delay_ms > 0 (and optionally max_delay_ms)"),
    ("delay", {"delay_ms": True}, "delay_ms: must be a number, got True"),
    ("drop", {"duration_s": 0}, "duration_s: must be > 0, got 0"),
    ("drop", {"duration_s": -1}, "duration_s: must be > 0, got -1"),
])
def test_fault_parameters_refused_at_their_bounds_with_the_field_named(kind: str, params: dict, message: str) -> None:
    """Each a FaultError naming its field (not pydantic's ValidationError, also a ValueError)."""
    with pytest.raises(FaultError) as refused:
        Fault(kind, **params)
    assert (type(refused.value), str(refused.value), refused.value.field) == (FaultError, message,
                                                                              message.split(":")[0])


@pytest.mark.parametrize(("kind", "params"), [
    ("status", {"service": 0, "status": 0}), ("status", {"service": 255, "status": 255}),
    ("delay", {"delay_ms": 0, "max_delay_ms": 0.001}), ("delay", {"delay_ms": 60_000}),
    ("delay", {"delay_ms": 0.001}), ("drop", {"duration_s": 0.001}), ("drop", {"duration_s": 0.5}),
])
def test_fault_parameters_taken_at_their_bounds(kind: str, params: dict) -> None:
    assert Fault(kind, **params).parameters() == {"kind": kind, **{k: float(v) if kind == "delay" else v
                                                                    for k, v in params.items()}}


def test_the_identity_fault_adds_1_to_the_product_code_modulo_2_16() -> None:
    faults = DeviceFaults()
    assert faults.product_code(1030) == 1030
    faults.set(Fault("identity"), T0)
    assert [faults.product_code(code) for code in (0, 1030, 0x7FFF, 0xFFFE, 0xFFFF)] == [1, 1031, 0x8000, 0xFFFF, 0]


@pytest.mark.parametrize(("kinds", "ends"), [((), None), (("delay",), None), (("close",), Disconnect.CLOSE),
                                             (("reset",), Disconnect.RESET), (("close", "reset"), Disconnect.RESET),
                                             (("reset", "close", "drop"), Disconnect.RESET)])
def test_how_new_tcp_connections_end_reset_wins_over_close(kinds: tuple[str, ...], ends: Disconnect | None) -> None:
    faults = DeviceFaults()
    for kind in kinds:
        faults.set(Fault(kind, **({"delay_ms": 5} if kind == "delay" else {})), T0)
    assert faults.on_tcp_connection() is ends
    assert faults.clear() == list(kinds) and faults.on_tcp_connection() is None


def test_clearing_one_kind_leaves_the_others() -> None:
    faults = DeviceFaults()
    faults.set(Fault("status", service=14, status=8), T0)
    faults.set(Fault("offline"), T0)
    assert (faults.forced_status, faults.listens, faults.listens_without("offline"), faults.listens_without(None)) == (
        {14: 8}, False, True, True)
    assert faults.listens_without("status") is False
    assert faults.clear("offline") == ["offline"] and faults.listens and list(faults.active) == ["status"]
    assert faults.clear("offline") == [] and faults.forced_status == {14: 8}


# -- cip/: the elementary types, the Message Router's class attributes, electronic keys --------------------


def test_elementary_type_codes_are_pycomm3s() -> None:
    """Vol. 1, C-6.1: e.g. LREAL 0xCB (a mutant made it 0xCC)."""
    assert {code: kind.name for code, kind in ELEMENTARY.items()} == {
        getattr(DataTypes, kind.name.lower()).code: kind.name for kind in ELEMENTARY.values()}


def test_the_message_router_class_get_attributes_all_is_1_4_5_6_7() -> None:
    """Vol. 1, 5-5.3 and 4-4.1: revision, optional attributes and services, highest class and
    instance attribute ids, in that order, each as Get Attribute Single answers it (a mutant
    answered 1, 4, 5, 7; another 2, 4, 5, 6, 7: max instance is 1 as the revision is, so the test
    sets a revision other than 1)."""
    config = parse_config({"devices": [{"name": "d", "address": "127.0.0.1", "model": "DSQC1030"}]})
    (profile,) = build_profiles(config, shipped_catalogue())
    router = Device(profile).router
    router.revision = 3  # not 1, which max instance (attribute 2) also is

    def ask(service: int, attribute: int | None = None) -> MessageRouterReply:
        request = encode_request(service, encode_request_path(ClassCode.MESSAGE_ROUTER, 0, attribute))
        return decode_reply(router.handle(request, MessageContext("127.0.0.9", None, (), T0)))

    every = ask(Service.GET_ATTRIBUTES_ALL)
    assert every.general_status == 0
    assert every.data == b"".join(ask(Service.GET_ATTRIBUTE_SINGLE, a).data for a in (1, 4, 5, 6, 7))
    assert every.data[:2] == b"\x03\x00"


IDENTITY = KeyIdentity(75, 7, 1030, (2, 5))


@pytest.mark.parametrize(("major", "minor", "compatible", "mismatch"), [
    (2, 5, False, None), (2, 5, True, None), (2, 0, False, None), (2, 0, True, None),
    (2, 4, True, None), (2, 1, True, None),  # an older minor revision: emulated when the key allows it
    (2, 4, False, X.REVISION_MISMATCH), (2, 6, True, X.REVISION_MISMATCH), (2, 6, False, X.REVISION_MISMATCH),
    (1, 5, True, X.REVISION_MISMATCH), (3, 5, False, X.REVISION_MISMATCH), (0, 9, False, None),
])
def test_an_electronic_keys_revision_and_its_compatibility_bit(major: int, minor: int, compatible: bool,
                                                               mismatch: int | None) -> None:
    """Vol. 1, C-1.4.2: without the compatibility bit the revision must be the device's exactly;
    with it, the major must be and the minor at most the device's (a mutant swapped the two)."""
    assert key_mismatch(ElectronicKey(75, 7, 1030, major, minor, compatible), IDENTITY) == mismatch


@pytest.mark.parametrize(("nte", "taken"), [(0, False), (1, True), (2, True), (45_313, True), (45_314, False)])
def test_a_safety_opens_network_time_expectation_multiplier_at_both_bounds(nte: int, taken: bool) -> None:
    """Vol. 5, 3-5.4: 1..45313 (x 128 us, up to 5.8 s); a mutant refused 1."""
    result = safety_make_table().forward_open(safety_open(nte=nte), SAFETY_ORIGINATOR, T0)
    assert (type(result) is Opened) if taken else result == Refusal(X.INVALID_NETWORK_TIME_EXPECTATION_MULTIPLIER)


def test_the_reconnections_remember_the_64_latest_originators() -> None:
    """The oldest is forgotten when a 65th opens (a mutant forgot the newest)."""
    reconnections = Reconnections()
    originators = [f"127.0.1.{n}" for n in range(ORIGINATORS + 1)]
    for n, originator in enumerate(originators):
        reconnections.opened(originator, T0 + n, None)
    reconnections.opened(originators[1], T0 + 100, None)  # seen again: now the latest
    reconnections.opened("127.0.2.1", T0 + 101, None)  # the 66th: originators[2] goes, not [1]
    reconnections.device_back("reset", T0 + 200, connected=set())
    waiting = [r.originator for r in reconnections.figures("d")]
    assert waiting == [*originators[3:], originators[1], "127.0.2.1"]


@pytest.mark.parametrize(("kind", "params", "field"), [
    ("flapping-link", {"count": 0}, "count"), ("address-conflict", {"phase": "later"}, "phase")])
def test_a_parameter_pydantic_refuses_is_a_fault_error_naming_its_field(kind: str, params: dict, field: str) -> None:
    """Fields without a `before` validator of their own: pydantic's error, its field taken from
    its location (a mutant read the location's second part)."""
    with pytest.raises(FaultError) as refused:
        Fault(kind, **params)
    assert (type(refused.value), refused.value.field) == (FaultError, field)
    assert str(refused.value).startswith(f"{field}: ")


def test_a_kind_named_by_an_equal_string_not_the_same_object() -> None:
    """Kinds from JSON are new strings, equal to the class's name but not the same object (a mutant
    compared with `is not`)."""
    faults = DeviceFaults()
    faults.set(Fault("offline"), T0)
    offline = "".join(["off", "line"])
    assert offline == "offline" and offline is not Fault("offline").name
    assert faults.listens_without(offline) is True
    assert faults.clear(offline) == ["offline"] and faults.listens


def test_a_suspended_fault_is_kept_without_its_effects_and_only_an_active_one_is_suspended() -> None:
    faults = DeviceFaults()
    faults.suspend("offline", True)  # not active: nothing to suspend
    faults.set(Fault("offline"), T0)
    assert (faults.listens, faults.suspended) == (False, set())
    faults.suspend("offline", True)
    assert (faults.listens, list(faults.active)) == (True, ["offline"])
    faults.suspend("offline", False)
    assert faults.listens is False


# -- device/: what the cyclic path and the explicit path publish, and what a stop-io fault withholds -------

PEER = "127.0.0.9"


def _dsqc1030() -> Device:
    config = parse_config({"devices": [{"name": "d", "address": "127.0.0.1", "model": "DSQC1030"}]})
    (profile,) = build_profiles(config, shipped_catalogue())
    return Device(profile)


def _explicit(device: Device, service: int, class_id: int, instance: int, attribute: int | None = None,
              data: bytes = b"") -> MessageRouterReply:
    message = encode_request(service, encode_request_path(class_id, instance, attribute), data)
    reply = device.handle_unconnected(message, MessageContext(PEER, None, (), T0))
    return decode_reply(reply[0] if isinstance(reply, tuple) else reply)


def _forward_open(device: Device) -> ForwardOpenRequest:
    p2p = ConnectionType.POINT_TO_POINT
    sizes = len(device.outputs) + 6, len(device.inputs) + 2
    return ForwardOpenRequest(
        0x0A, 0x0E, 0, 0x7E570001, ConnectionTriad(77, 0x1234, 0xABCD), 0, 10_000,
        NetworkParameters(False, p2p, 2, False, sizes[0]), 10_000, NetworkParameters(False, p2p, 2, False, sizes[1]),
        0x01, bytes.fromhex("20 04 24 01 2C 64 2C 65"))


def test_an_observer_is_told_of_a_request_that_changed_nothing() -> None:
    """A mutant told observers only when something changed (or when none listened)."""
    device, seen = _dsqc1030(), []
    device.observe(seen.append)
    assert _explicit(device, Service.GET_ATTRIBUTE_SINGLE, ClassCode.IDENTITY, 1, 1).general_status == 0
    assert [e.kind for e in seen] == ["request"] and seen[0].text.startswith("service 0x0E path 20 01 24 01 30 01")


def test_with_nobody_listening_a_reset_and_a_connection_opened_are_still_done_and_logged() -> None:
    """The hot path (nothing changed, nobody listening) must not swallow a reset or an opened
    connection (a mutant did, each)."""
    device, moved = _dsqc1030(), []
    device.timer_moved = lambda: moved.append(True)
    opened = _explicit(device, Service.FORWARD_OPEN, ClassCode.CONNECTION_MANAGER, 1,
                       data=encode_forward_open(_forward_open(device)))
    assert opened.general_status == 0 and len(device.connections) == 1
    assert [e.kind for e in device.events if e.kind != "request"] == ["connection opened"] and moved == [True]
    quiet = _dsqc1030()  # nothing to close, outputs already off: the reset changes no image
    assert _explicit(quiet, Service.RESET, ClassCode.IDENTITY, 1).general_status == 0
    assert [e.kind for e in quiet.events if e.kind != "request"] == ["reset"] and quiet.resetting


def test_an_input_change_is_published_as_an_image_change() -> None:
    device, seen = _dsqc1030(), []
    device.observe(seen.append)
    old = device.inputs
    new = bytes([old[0] ^ 0x01]) + old[1:]
    device.set_inputs(new, T0)
    assert [(e.kind, e.detail.role, e.detail.old, e.detail.new) for e in seen] == [
        ("image changed", "input", old, new)]


def test_stop_io_withholds_the_t_o_due_and_drops_o_t() -> None:
    """A mutant sent the T->O due while the fault stopped the I/O."""
    device, sent = _dsqc1030(), []
    _explicit(device, Service.FORWARD_OPEN, ClassCode.CONNECTION_MANAGER, 1,
              data=encode_forward_open(_forward_open(device)))
    device.service_io(T0, lambda data, address: sent.append(address))
    assert sent == [(PEER, 2222)]
    device.faults.set(Fault("stop-io"), T0)
    device.service_io(T0 + 10 * 1_000_000, lambda data, address: sent.append(address))
    assert sent == [(PEER, 2222)]
    (connection,) = device.connections.values()
    datagram = encode_io_packet(connection.o_t_id, 1, 1, bytes(4 + len(device.outputs)))
    assert device.receive_io(datagram, (PEER, 2222), T0, lambda *a: None) is False
    assert device.counters["o_t_dropped_io_stopped"] == 1
    device.faults.clear()
    device.service_io(T0 + 20 * 1_000_000, lambda data, address: sent.append(address))
    assert sent == [(PEER, 2222)] * 2


def test_a_connection_past_its_deadline_times_out_at_the_next_turn_however_late() -> None:
    """The I/O thread may come late: a deadline passed (not only one reached to the nanosecond)
    is supervision due (a mutant took only `deadline == now`)."""
    device = _dsqc1030()
    _explicit(device, Service.FORWARD_OPEN, ClassCode.CONNECTION_MANAGER, 1,
              data=encode_forward_open(_forward_open(device)))
    (connection,) = device.connections.values()
    device.service_io(connection.deadline - 1, lambda *a: None)
    assert len(device.connections) == 1
    device.service_io(connection.deadline + 7_000_000, lambda *a: None)  # 7 ms late
    assert device.connections == {} and [e.kind for e in device.events if e.kind.startswith("connection t")] == [
        "connection timed out"]


@pytest.mark.parametrize(("value", "status"), [(9, 0x09), (10, 0), (11, 0), (1000, 0), (1001, 0x09)])
def test_a_parameter_is_set_within_its_minimum_and_maximum_both_included(value: int, status: int) -> None:
    """Vol. 1, 7-3.6.8 (an EDS's min and max): a mutant refused the minimum and took less."""
    parameter = ParameterInstance(ParameterSpec(1, "p", 0, 0xC7, 2, minimum=10, maximum=1000, default=500))
    assert parameter.set(value) == status
    assert parameter.value == (value if status == 0 else 500)


# -- server/: the I/O thread's lag, the kernel's receive time, the bounded waits ----------------------------

S = 1_000_000_000  # ns


def test_the_lag_is_the_worst_of_the_last_whole_second_and_overloads_are_beyond_5_ms() -> None:
    lag = Lag()
    assert [lag.observe(ns, 7 * S + n) for n, ns in enumerate((2_000_000, 9_000_000, 5_000_000, 5_000_001))] == [
        False, True, False, True]
    assert (lag.worst_ns, lag.overloads) == (0, 2)  # the second is not over
    assert lag.observe(1_000, 8 * S) is False
    assert (lag.worst_ns, lag.overloads) == (9_000_000, 2)  # second 7's worst
    assert lag.observe(3_000, 8 * S + 5) is False and lag.observe(0, 10 * S) is False
    assert lag.worst_ns == 3_000  # second 8's (second 9 had no wake-up)


def test_the_kernels_receive_time_or_0() -> None:
    stamp = struct.pack("@qq", 1_700_000_000, 123_456_789)  # struct timespec
    assert wall_stamp([(socket.SOL_SOCKET, SO_TIMESTAMPNS, stamp)]) == 1_700_000_000_123_456_789
    assert wall_stamp([(socket.SOL_SOCKET, SO_TIMESTAMPNS + 1, stamp)]) == 0
    assert wall_stamp([(socket.SOL_SOCKET, SO_TIMESTAMPNS, stamp[:8])]) == 0
    assert wall_stamp([]) == 0


@pytest.mark.parametrize(("seconds", "wait"), [(1.5, 1.5), (1e-9, 1e-9), (0, 0.0), (-1, 0.0), (math.nan, 0.0),
                                               (3600, 3600), (3600.5, 3600), (math.inf, 3600)])
def test_a_wait_handed_to_the_os_is_bounded(seconds: float, wait: float) -> None:
    assert os_wait_s(seconds) == wait


@pytest.mark.integration
def test_the_fallback_receive_reads_what_waits_and_passes_over_empty_unknown_and_failed_sockets(free_address) -> None:
    """Without the native extension: a socket with nothing to read, an fd it does not know and a
    socket with an ICMP error pending (port unreachable) give nothing and end nothing; a datagram
    without a kernel timestamp has receive time 0 (mutants let the errors out, or made it 1)."""
    host = free_address()
    sockets = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(3)]
    try:
        for sock in sockets:
            sock.bind((host, 0))
            sock.setblocking(False)
        waiting, empty, refused = sockets
        closed = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        closed.bind((host, 0))
        port = closed.getsockname()[1]
        closed.close()
        refused.connect((host, port))
        refused.send(b"to nobody")  # the ICMP port unreachable comes back as an error on the socket
        datagrams = Datagrams(native=False)
        for sock in sockets:
            datagrams.add(sock)
        empty.sendto(b"o->t", waiting.getsockname())
        got: list = []
        for _ in range(200):  # loopback: there as soon as sendto returns; bounded all the same
            got += datagrams.receive([empty.fileno(), 9999, refused.fileno(), waiting.fileno()])
            if got:
                break
        assert got == [(waiting.fileno(), b"o->t", host, empty.getsockname()[1], 0)]
        assert datagrams.receive([empty.fileno(), refused.fileno(), waiting.fileno()]) == []
    finally:
        for sock in sockets:
            sock.close()


def test_the_io_thread_runs_only_while_alive_not_stopping_and_turning() -> None:
    """`running` (the supervision's question): each of the three must hold (mutants let a stalled
    or an unstarted thread count as running)."""
    thread = CyclicIoThread()
    assert thread.running(thread.turned_at) is False  # not started, though it "turned" just now
    thread.start()
    try:
        assert wait_for(lambda: thread.running(time.monotonic_ns()))
        turned = thread.turned_at
        assert thread.running(turned + 5 * S - 1) and not thread.running(turned + 5 * S + 1_000_000_000)
    finally:
        thread.stop()
    assert thread.running(thread.turned_at) is False


def test_a_devices_io_endpoint_counts_unicast_multicast_and_failures_and_unhooks_only_itself() -> None:
    """T->O to a multicast group counts as non-unicast (a mutant read the port as the address),
    a failed send once (a mutant twice); closing unhooks the device's timer only if it is its own."""
    device, thread = _dsqc1030(), CyclicIoThread()
    try:
        endpoint = DeviceIo(device, None, thread)  # type: ignore[arg-type]  # its socket is the thread's business
        assert device.timer_moved == endpoint._timer_moved
        endpoint.send(b"\x00" * 20, (PEER, 2222))
        endpoint.send(b"\x00" * 20, ("239.192.1.0", 2222))
        endpoint.send(b"\x00" * 20, ("239.192.1.0", 2222))
        endpoint.send_failed()
        counters = device.io_traffic
        assert (counters.out_ucast, counters.out_nucast, counters.out_octets, counters.out_errors) == (1, 2, 60, 1)
        assert device.counters["t_o_send_errors"] == 1
        newer = DeviceIo(device, None, thread)  # type: ignore[arg-type]
        endpoint.close()
        assert device.timer_moved == newer._timer_moved
        newer.close()
        assert device.timer_moved is None
    finally:
        thread.stop()
