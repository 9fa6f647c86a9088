"""Unit tests of the CIP Safety target (enip_farm/cip/safety/): CRCs against check values and a
bitwise reference, messages and a SafetyOpen against bytes cm-ethernetip's originator produced,
the safety network segment and CPCRC, every SafetyOpen refusal with its extended status, and the
Safety Validators in the connection table with an injected clock: timeouts to the tick."""

from __future__ import annotations

import random
import struct

import pytest

from enip_farm.cip.admission import Originator
from enip_farm.cip.assembly import AssemblyInstance
from enip_farm.cip.connection import ConnectionKind
from enip_farm.cip.connection_events import (
    ConnectionClosed,
    ConnectionFaulted,
    ConnectionOpened,
    ConnectionTimedOut,
    SafeState,
    SafetyCrcFault,
    SafetyTimingFault,
)
from enip_farm.cip.connection_path import KeyIdentity
from enip_farm.cip.connection_policy import ConnectionPolicy, Refusal
from enip_farm.cip.connection_table import ConnectionTable, Opened
from enip_farm.cip.safety.admission import SafetyPolicy
from enip_farm.protocol.connection import (
    ConnectionTriad,
    ConnectionType,
    ForwardOpenRequest,
    NetworkParameters,
    class0_data,
    decode_forward_open,
    decode_io_packet,
    encode_class0_packet,
    encode_forward_open,
)
from enip_farm.protocol.safety.crc import Seeds, crc_s1, crc_s2, crc_s3, crc_s4, crc_s5
from enip_farm.protocol.safety.messages import (
    decode_data,
    decode_time_coordination,
    encode_data,
    encode_time_coordination,
    mode_byte,
    wire_size,
)
from enip_farm.protocol.safety.segment import (
    FORMAT_BASE,
    FORMAT_EXTENDED,
    SafetySegment,
    Unid,
    compute_cpcrc,
    decode_segment,
    encode_segment,
)
from enip_farm.protocol.safety.validator import TICK_NS, ticks
from enip_farm.protocol.status import ExtendedStatus as X

MS = 1_000_000
T0 = 7_000 * MS
SNN = bytes.fromhex("000000000001")
NODE = 0x7F004D01  # 127.0.77.1
TUNID = Unid(SNN, NODE)
OUNID = Unid(bytes.fromhex("0000000000aa"), 1)
VENDOR, SERIAL = 75, 0x11223344  # the target
ORIGINATOR = Originator("127.0.0.9")

# -- CRCs ---------------------------------------------------------------------------------------------


def _bitwise(data: bytes, width: int, polynomial: int, seed: int = 0) -> int:
    """A reference CRC, most significant bit first, one bit at a time (no table)."""
    crc, top, mask = seed, 1 << (width - 1), (1 << width) - 1
    for byte in data:
        crc ^= byte << (width - 8)
        for _ in range(8):
            crc = ((crc << 1) ^ polynomial) & mask if crc & top else (crc << 1) & mask
    return crc


def test_crc_check_values() -> None:
    check = b"123456789"
    assert crc_s4(check) == 0x340BC6D9 == 0xCBF43926 ^ 0xFFFFFFFF  # CRC-32's check value, not inverted
    # the same values cm-ethernetip's CRC routines give
    assert (crc_s1(check), crc_s2(check), crc_s3(check), crc_s5(check)) == (0x2F, 0xFD, 0xC952, 0xB0C390)
    for crc, width, polynomial in ((crc_s1, 8, 0x37), (crc_s2, 8, 0x3B), (crc_s3, 16, 0x080F), (crc_s5, 24, 0x5D6DCB)):
        for seed in (0, 0x5A, 0xA5A5 & ((1 << width) - 1)):
            assert crc(check, seed) == _bitwise(check, width, polynomial, seed)
    assert crc_s4(b"6789", crc_s4(b"12345")) == crc_s4(check)  # S4 continues from a previous value


def test_pid_seeds() -> None:
    assert Seeds.of(0x0001, 0x00C0FFEE, 0x1234) == Seeds(0x7E, 0xAFE1, 0x4C0B39)


# -- messages: bytes cm-ethernetip 0.1.0 encoded ---------------------------------------------------------

SEEDS = Seeds.of(0x0001, 0x00C0FFEE, 0x1234)
RUN_PING_1 = 0x85


@pytest.mark.parametrize(("extended", "data", "rollover", "wire"), [
    (False, "05", 0, "0585d9fc341264"),
    (False, "010203", 0, "010203850520fefdfcea25341264"),
    (True, "050a", 7, "050a85f06f3412a4"),
    (True, "010203", 0xFFFF, "0102038545eefefdfcfb6934128e"),
])
def test_data_messages_match_cm_ethernetip(extended: bool, data: str, rollover: int, wire: str) -> None:
    message = bytes.fromhex(wire)
    assert mode_byte(True, 1) == RUN_PING_1
    assert encode_data(bytes.fromhex(data), RUN_PING_1, 0x1234, SEEDS, extended, rollover) == message
    decoded = decode_data(message, len(data) // 2, SEEDS, extended, rollover)
    assert decoded is not None and decoded.data.hex() == data and decoded.timestamp == 0x1234 and decoded.run
    assert len(message) == wire_size(len(data) // 2)
    for i in range(len(message)):  # any bit flipped anywhere: an integrity fault
        flipped = bytearray(message)
        flipped[i] ^= 0x10
        assert decode_data(bytes(flipped), len(data) // 2, SEEDS, extended, rollover) is None
    if extended:  # the rollover count is in the CRC, not on the wire
        assert decode_data(message, len(data) // 2, SEEDS, extended, rollover + 1) is None


@pytest.mark.parametrize(("extended", "wire"), [(False, "0aefbe5f16af"), (True, "0aefbe55754e")])
def test_time_coordination_matches_cm_ethernetip(extended: bool, wire: str) -> None:
    assert encode_time_coordination(2, 0xBEEF, SEEDS, extended) == bytes.fromhex(wire)
    assert decode_time_coordination(bytes.fromhex(wire), SEEDS, extended) == (2, 0xBEEF)
    assert decode_time_coordination(bytes.fromhex(wire)[:5] + b"\x00", SEEDS, extended) is None
    # cm-ethernetip 0.1.0 puts a consumer time below 256 into its CRC-S3 as one byte: refused
    assert decode_time_coordination(bytes.fromhex("09ab005c7c36"), SEEDS, False) == (1, 0x00AB)
    assert decode_time_coordination(bytes.fromhex("09ab005c12c2"), SEEDS, False) is None
    # ack byte: ping count reply, ping response bit 3, even parity in bit 7
    assert [encode_time_coordination(ping, 0, SEEDS, False)[0] for ping in range(4)] == [0x88, 0x09, 0x0A, 0x8B]


# -- the safety network segment and CPCRC: a SafetyOpen cm-ethernetip built ----------------------------

CM_SAFETY_OPEN = {  # server (0xA0) to O->T 100, config 1, TUNID 000000000001/127.0.77.1, NTE 781, RPI 10 ms
    FORMAT_BASE: "059c000000003412001034120100eeffc00002000000102700000744102700000644a020200424012c642c00501b0000"
                 "00000000000000000000000000000000000000000001014d007f0000000000aa01000000640000000d030201f4ed21e5"
                 "ffffffff",
    FORMAT_EXTENDED: "059c000000003412001034120100eeffc00002000000102700000744102700000644a023200424012c642c00501e02"
                     "0000000000000000000000000000000000000000000001014d007f0000000000aa01000000640000000d0302010200"
                     "e8734183ffffffffffffffff",
}


@pytest.mark.parametrize("fmt", [FORMAT_BASE, FORMAT_EXTENDED])
def test_segment_and_cpcrc_of_cm_ethernetip_safety_open(fmt: int) -> None:
    request = decode_forward_open(bytes.fromhex(CM_SAFETY_OPEN[fmt]))
    application, raw = request.connection_path[:8], request.connection_path[8:]
    segment = decode_segment(raw)
    assert segment.format == fmt and segment.tunid == TUNID and segment.ounid == OUNID
    assert (segment.ping_interval_epi_multiplier, segment.time_coord_msg_min_multiplier,
            segment.network_time_expectation_multiplier, segment.timeout_multiplier,
            segment.max_consumer_number) == (100, 0, 781, 2, 1)
    assert segment.time_correction_connection_id == 0xFFFFFFFF
    if fmt == FORMAT_EXTENDED:
        assert (segment.max_fault_number, segment.initial_timestamp, segment.initial_rollover_value) == (
            2, 0xFFFF, 0xFFFF)
    assert encode_segment(segment) == raw
    path_words = bytes((len(request.connection_path) // 2,))
    fixed = encode_forward_open(request._replace(connection_path=b""))[:-1] + path_words
    assert compute_cpcrc(fixed, application, raw) == segment.cpcrc == {FORMAT_BASE: 0xE521EDF4,
                                                                       FORMAT_EXTENDED: 0x834173E8}[fmt]


def test_router_format_and_wrong_sizes_are_format_errors() -> None:
    segment = decode_segment(bytes.fromhex(CM_SAFETY_OPEN[FORMAT_BASE])[44:])
    router = bytearray(encode_segment(segment))
    router[2] = 1
    with pytest.raises(ValueError, match="^safety segment format 1 is not a target format$") as error:
        decode_segment(bytes(router))
    assert error.value.format_error  # type: ignore[attr-defined]


# -- SafetyOpen admission through the connection table ---------------------------------------------------


def make_table(scid: bytes = bytes(10), snn: bytes = SNN, output_size: int = 1, input_size: int = 2,
               first_watchdog_ms: int = 10_000) -> ConnectionTable:
    assemblies = {"output": AssemblyInstance(100, output_size, False),
                  "input": AssemblyInstance(101, input_size, False), "configuration": AssemblyInstance(1, 0, True)}
    safety = SafetyPolicy(vendor_id=VENDOR, serial_number=SERIAL, tunid=Unid(snn, NODE), scid=scid, output_point=100,
                          input_point=101, configuration_point=1, null_point=0)
    policy = ConnectionPolicy(
        rpi_min_us=2_000, rpi_max_us=10_000_000, max_class1_connections=8, max_class3_connections=6,
        outputs_off_on_idle=True, outputs_off_on_fault=True, first_watchdog_ns=first_watchdog_ms * MS,
        input_only_point=None, listen_only_point=None, multicast_group="239.192.1.0", safety=safety)
    return ConnectionTable(assemblies, policy, lambda: KeyIdentity(VENDOR, 7, 1042, (1, 1)), rng=random.Random(3))


_serials = iter(range(0x100, 0x10000))


def safety_open(server: bool = True, extended: bool = False, rpi_us: int = 10_000, nte: int = 781, ping: int = 100,
                timeout_multiplier: int = 2, max_faults: int = 2, scid: bytes = bytes(10), tunid: Unid = TUNID,
                points: tuple[int, int, int] | None = None, data_size: int | None = None, tcoo_size: int = 6,
                key: bytes = b"", transport: int | None = None, cpcrc_delta: int = 0, configuration_data: bytes = b"",
                ounid: Unid = OUNID, multicast: bool = False, **changes: object) -> ForwardOpenRequest:
    """A SafetyOpen as an originator builds it (CPCRC over the fields, as cm-ethernetip computes it);
    with `configuration_data`, a Type 1 SafetyOpen (the data in a simple data segment, 0x80); with
    `multicast`, a client's T->O multicast (the data message and its 6-byte time correction)."""
    configuration, consuming, producing = points or ((1, 100, 0) if server else (1, 0, 101))
    application = key + bytes((0x20, 0x04, 0x24, configuration, 0x2C, consuming, 0x2C, producing))
    if configuration_data:
        application += bytes((0x80, len(configuration_data) // 2)) + configuration_data
    segment = SafetySegment(
        FORMAT_EXTENDED if extended else FORMAT_BASE, struct.unpack_from("<I", scid)[0], scid[4:], 0, 0, tunid, ounid,
        ping, 0, nte, timeout_multiplier, 1, 0, 0xFFFFFFFF, max_faults if extended else 0)
    segment = segment._replace(**changes)  # type: ignore[arg-type]
    size = data_size if data_size is not None else wire_size(1 if server else 2) + (6 if multicast else 0)
    data = NetworkParameters(False, ConnectionType.MULTICAST if multicast else ConnectionType.POINT_TO_POINT, 1,
                             False, size)
    tcoo = NetworkParameters(False, ConnectionType.POINT_TO_POINT, 1, False, tcoo_size)
    raw = encode_segment(segment)
    request = ForwardOpenRequest(0x05, 0x9C, 0, 0x10000000 | next(_serials), ConnectionTriad(next(_serials), 0x0001,
                                 0x00C0FFEE), 2, rpi_us, data if server else tcoo, rpi_us, tcoo if server else data,
                                 transport if transport is not None else (0xA0 if server else 0x20),
                                 application + raw)
    fixed = encode_forward_open(request._replace(connection_path=b""))[:-1] + bytes((len(application + raw) // 2,))
    cpcrc = (compute_cpcrc(fixed, application, raw) + cpcrc_delta) & 0xFFFFFFFF
    return request._replace(connection_path=application + encode_segment(segment._replace(cpcrc=cpcrc)))


def admit(table: ConnectionTable, request: ForwardOpenRequest, now: int = T0) -> Opened:
    result = table.forward_open(request, ORIGINATOR, now)
    assert type(result) is Opened, result
    return result


def test_cm_ethernetip_safety_open_is_admitted_with_its_application_reply() -> None:
    for fmt, expected_words in ((FORMAT_BASE, 5), (FORMAT_EXTENDED, 7)):
        table = make_table()
        request = decode_forward_open(bytes.fromhex(CM_SAFETY_OPEN[fmt]))
        opened = admit(table, request)
        assert opened.connection.kind is ConnectionKind.SAFETY_OUTPUT
        reply = opened.application_reply
        assert len(reply) == 2 * expected_words
        assert struct.unpack_from("<HHIH", reply) == (0xFFFF, VENDOR, SERIAL, opened.connection.instance)
        if fmt == FORMAT_EXTENDED:  # the consumer picks the producer's initial timestamp and rollover value
            assert struct.unpack_from("<HH", reply, 10) == (ticks(T0), (ticks(T0) + 1) & 0xFFFF)


@pytest.mark.parametrize(("request_kwargs", "table_kwargs", "extended_status"), [
    ({"cpcrc_delta": 1}, {}, X.INVALID_CPCRC),
    ({}, {"snn": b"\xff" * 6}, X.TUNID_NOT_SET),
    ({"tunid": Unid(SNN, NODE + 1)}, {}, X.TUNID_MISMATCH),
    ({"key": bytes.fromhex("3404 4b00 0700 0104 0101")}, {}, X.VENDOR_OR_PRODUCT_MISMATCH),  # product 1025
    ({"key": bytes.fromhex("3404 4b00 0800 1204 0101")}, {}, X.DEVICE_TYPE_MISMATCH),
    ({"key": bytes.fromhex("3404 4b00 0700 1204 0201")}, {}, X.REVISION_MISMATCH),
    ({"transport": 0x01}, {}, X.TRANSPORT_TRIGGER_NOT_SUPPORTED),
    ({"tcoo_size": 8}, {}, X.INVALID_CONNECTION_TYPE),
    ({"time_correction_parameters": 0x4406}, {}, X.INVALID_TIME_CORRECTION_PARAMETERS),
    ({"data_size": 9}, {}, X.INVALID_SAFETY_CONNECTION_SIZE),
    ({"rpi_us": 200_000}, {}, X.RPI_NOT_SUPPORTED),  # base format: data RPI up to 100 ms
    ({"time_correction_epi": 5}, {}, X.MISCELLANEOUS),
    ({"ping": 16}, {}, X.INVALID_PING_INTERVAL_EPI_MULTIPLIER),  # at least 2 x 1 + 15
    ({"time_coord_msg_min_multiplier": 7814}, {}, X.INVALID_TIME_COORD_MSG_MIN_MULTIPLIER),
    ({"nte": 45314}, {}, X.INVALID_NETWORK_TIME_EXPECTATION_MULTIPLIER),
    ({"timeout_multiplier": 5, "ping": 100}, {}, X.INVALID_SAFETY_TIMEOUT_MULTIPLIER),  # base: 1..4
    ({"max_consumer_number": 2}, {}, X.INVALID_MAX_CONSUMER_NUMBER),
    ({"time_correction_connection_id": 7}, {}, X.INVALID_TIME_CORRECTION_CONNECTION_ID),
    ({"extended": True, "initial_timestamp": 0}, {}, X.PARAMETER_ERROR),  # a consumer's are "not used"
    ({"points": (2, 100, 0)}, {}, X.INVALID_CONFIGURATION_PATH),
    ({"points": (1, 101, 0)}, {}, X.INVALID_CONSUMING_PATH),
    ({"points": (1, 100, 101)}, {}, X.INVALID_PRODUCING_PATH),
    ({"server": False, "points": (1, 100, 101)}, {}, X.INVALID_CONSUMING_PATH),
    ({"scid": bytes.fromhex("0102030405060708090a")}, {}, X.SCID_MISMATCH),
])
def test_safety_open_refusals(request_kwargs: dict, table_kwargs: dict, extended_status: int) -> None:
    result = make_table(**table_kwargs).forward_open(safety_open(**request_kwargs), ORIGINATOR, T0)
    assert result == Refusal(extended_status)


def test_size_refusal_names_the_expected_size_and_scid_match_is_taken() -> None:
    result = make_table().forward_open(safety_open(data_size=wire_size(2)), ORIGINATOR, T0)
    assert result == Refusal(X.INVALID_O_T_SIZE, wire_size(1))
    result = make_table().forward_open(safety_open(server=False, data_size=wire_size(1)), ORIGINATOR, T0)
    assert result == Refusal(X.INVALID_T_O_SIZE, wire_size(2))
    scid = bytes.fromhex("0102030405060708090a")
    admit(make_table(scid=scid), safety_open(scid=scid))
    admit(make_table(scid=scid), safety_open())  # a zero SCID asks for no configuration check


def test_duplicate_second_owner_and_class_1_are_refused() -> None:
    table = make_table()
    request = safety_open()
    admit(table, request)
    assert table.forward_open(request, ORIGINATOR, T0) == Refusal(X.CONNECTION_IN_USE)
    assert table.forward_open(safety_open(), ORIGINATOR, T0) == Refusal(X.OWNERSHIP_CONFLICT)
    class_1 = request._replace(transport_type_trigger=0x01, connection_path=bytes.fromhex("20042401 2c642c65"),
                               triad=request.triad._replace(connection_serial=1))
    assert table.forward_open(class_1, ORIGINATOR, T0) == Refusal(X.TRANSPORT_TRIGGER_NOT_SUPPORTED)


def test_a_device_that_is_no_safety_target_refuses_a_safety_open() -> None:
    table = make_table()
    table.admission.policy = table.policy = table.policy.__class__(**{**table.policy.__dict__, "safety": None})
    assert table.forward_open(safety_open(), ORIGINATOR, T0) == Refusal(X.INVALID_SEGMENT)


# -- the server (safe outputs): consumption, time coordination, faults, the safety timeout, to the tick ----

def _pid(request: ForwardOpenRequest) -> Seeds:
    triad = request.triad
    return Seeds.of(triad.originator_vendor_id, triad.originator_serial, triad.connection_serial)


def _send(table: ConnectionTable, opened: Opened, message: bytes, sequence: int, now: int) -> bool:
    return table.receive_datagram(encode_class0_packet(opened.connection.o_t_id, sequence, message),
                                  ORIGINATOR.host, now, 2222)


def _open_server(extended: bool = False, **kwargs: object) -> tuple[ConnectionTable, Opened, Seeds, ForwardOpenRequest]:
    table = make_table()
    request = safety_open(extended=extended, **kwargs)
    opened = admit(table, request)
    return table, opened, _pid(request), request


def test_server_applies_run_data_answers_pings_and_times_out_at_the_network_time_expectation() -> None:
    table, opened, pid, request = _open_server()
    output = table.assemblies["output"]
    # idle, timestamp 0: the producer waits for time coordination; the ping count (0) differs from
    # the consumer's initial 3, so a time coordination message answers at once
    now = T0 + 5 * MS
    assert _send(table, opened, encode_data(b"\x0f", mode_byte(False, 0), 0, pid, False), 1, now)
    assert table.answers_queued
    (packet, address), = table.datagrams_to_send(now)  # the one outbound queue
    io = decode_io_packet(packet)
    assert io is not None and io.connection_id == request.t_o_connection_id and address == ("127.0.0.9", 2222)
    cid = Seeds.of(VENDOR, SERIAL, opened.connection.instance)
    assert decode_time_coordination(class0_data(io), cid, False) == (0, ticks(now))
    assert output.data == b"\x00"  # idle: the safe state
    # run data, timestamped in the consumer's time base
    now += 10 * MS
    assert _send(table, opened, encode_data(b"\x05", mode_byte(True, 0), ticks(now) - 3, pid, False), 2, now)
    assert output.data == b"\x05" and output.owned and not table.answers_queued and table.datagrams_to_send(now) == []
    last = now
    deadline = last + 781 * TICK_NS
    assert table.get_timer() == deadline
    table.handle_timer(deadline - 1)
    assert output.data == b"\x05"  # not a tick early
    table.handle_timer(deadline)
    assert output.data == b"\x00" and not output.owned and not table.connections
    events = table.pop_events()
    assert [type(e) for e in events] == [ConnectionOpened, ConnectionTimedOut, SafeState]
    assert events[1].reason == "safety timeout: no valid data for the network time expectation, 99.968 ms"
    assert table.counters["safety_timeouts"] == 1


def test_base_format_crc_fault_is_counted_not_applied_and_faults_the_connection() -> None:
    table, opened, pid, _ = _open_server()
    now = T0 + 10 * MS
    assert _send(table, opened, encode_data(b"\x05", mode_byte(True, 0), ticks(now), pid, False), 1, now)
    bad = bytearray(encode_data(b"\x0f", mode_byte(True, 0), ticks(now + 10 * MS), pid, False))
    bad[2] ^= 0x01  # the actual-data CRC
    assert not _send(table, opened, bytes(bad), 2, now + 10 * MS)
    assert table.assemblies["output"].data == b"\x00"  # not applied; the connection faulted: safe state
    assert table.counters["safety_crc_faults"] == 1 and not table.connections
    kinds = [type(e) for e in table.pop_events()]
    assert kinds == [ConnectionOpened, SafetyCrcFault, ConnectionFaulted, SafeState]


def test_extended_format_discards_up_to_max_fault_number_then_faults() -> None:
    table, opened, pid, _ = _open_server(extended=True, max_faults=2)
    reply = struct.unpack_from("<HH", opened.application_reply, 10)
    assert reply == (ticks(T0), (ticks(T0) + 1) & 0xFFFF)
    rollover = reply[1]
    now = T0 + 10 * MS
    assert _send(table, opened, encode_data(b"\x05", mode_byte(True, 0), ticks(now), pid, True, rollover), 1, now)
    bad = encode_data(b"\x0f", mode_byte(True, 0), ticks(now + 10 * MS), pid, True, rollover + 1)  # wrong rollover
    assert not _send(table, opened, bad, 2, now + 10 * MS)
    assert table.connections and table.assemblies["output"].data == b"\x05"  # discarded, kept the last good
    assert not _send(table, opened, bad, 3, now + 20 * MS)
    assert not table.connections and table.assemblies["output"].data == b"\x00"
    assert table.counters["safety_crc_faults"] == 2


@pytest.mark.parametrize(("delta_ticks", "age_ticks", "detail"), [
    (0, 0, "timestamp delta 0 ticks"),  # a repeated timestamp
    (782, 0, "timestamp delta 782 ticks"),  # out of sequence
    (78, 782, "data age 782 ticks > network time expectation 781"),
])
def test_timing_faults(delta_ticks: int, age_ticks: int, detail: str) -> None:
    table, opened, pid, _ = _open_server()
    now = T0 + 10 * MS
    first = ticks(now) - 800
    assert _send(table, opened, encode_data(b"\x05", mode_byte(True, 0), first, pid, False), 1, now - 800 * TICK_NS)
    stamp = (first + delta_ticks) & 0xFFFF
    arrival = (now - 800 * TICK_NS) + (delta_ticks + age_ticks) * TICK_NS
    assert not _send(table, opened, encode_data(b"\x0a", mode_byte(True, 0), stamp, pid, False), 2, arrival)
    faults = [e for e in table.pop_events() if type(e) is SafetyTimingFault]
    assert len(faults) == 1 and faults[0].reason.startswith(detail)
    assert table.assemblies["output"].data == b"\x00" and table.counters["safety_timing_faults"] == 1


def test_data_age_at_the_limit_is_taken() -> None:
    table, opened, pid, _ = _open_server()
    now = T0 + 10 * MS
    assert _send(table, opened, encode_data(b"\x05", mode_byte(True, 0), ticks(now) - 781, pid, False), 1, now)
    assert table.assemblies["output"].data == b"\x05"


def test_forward_close_puts_the_safe_outputs_in_the_safe_state() -> None:
    table, opened, pid, request = _open_server()
    now = T0 + 10 * MS
    assert _send(table, opened, encode_data(b"\x0f", mode_byte(True, 0), ticks(now), pid, False), 1, now)
    table.forward_close(request.triad, now)
    assert table.assemblies["output"].data == b"\x00"
    assert [type(e) for e in table.pop_events()][-2:] == [ConnectionClosed, SafeState]


# -- the client (safe inputs): production, pings, time correction, rollover, its timeout ---------------


@pytest.mark.parametrize("extended", [False, True])
def test_client_produces_time_corrected_safe_inputs(extended: bool) -> None:
    table = make_table()
    table.assemblies["input"].data[:] = b"\x04\x08"
    request = safety_open(server=False, extended=extended, initial_timestamp=0xFFFF, initial_rollover_value=0xFFFF)
    opened = admit(table, request)
    pid = Seeds.of(VENDOR, SERIAL, opened.connection.instance)
    cid = _pid(request)
    (packet, address), = table.datagrams_to_send(T0)
    io = decode_io_packet(packet)
    assert io is not None and io.connection_id == request.t_o_connection_id and address == ("127.0.0.9", 2222)
    message = class0_data(io)
    # idle, timestamp 0, rollover 0 until the first time coordination message
    decoded = decode_data(message, 2, pid, extended, 0)
    assert decoded is not None and decoded.data == b"\x04\x08" and not decoded.run and decoded.timestamp == 0
    # the consumer answers ping 0 with its time: the producer's clock + 1000 ticks
    answer_at = T0 + 3 * MS
    consumer_time = (ticks(answer_at) + 1000) & 0xFFFF
    assert table.receive_datagram(encode_class0_packet(opened.connection.o_t_id, 1, encode_time_coordination(
        0, consumer_time, cid, extended)), ORIGINATOR.host, answer_at, 2222)
    at = T0 + 10 * MS
    (packet, _), = table.datagrams_to_send(at)
    message = class0_data(decode_io_packet(packet))  # type: ignore[arg-type]
    decoded = decode_data(message, 2, pid, extended, 0)  # 0xFFFF + 1: the first timestamp below the initial one
    assert decoded is not None and decoded.run and decoded.timestamp == (ticks(at) + 1000) & 0xFFFF
    # a bad time coordination message is counted as a CRC fault, the connection stays
    assert not table.receive_datagram(encode_class0_packet(opened.connection.o_t_id, 2, b"\x08\x00\x00\xf7\x00\x00"),
                                      ORIGINATOR.host, at, 2222)
    assert table.counters["safety_crc_faults"] == 1 and table.connections


def test_client_pings_and_times_out_after_timeout_multiplier_plus_2_ping_intervals() -> None:
    table = make_table(first_watchdog_ms=0)
    request = safety_open(server=False, ping=100, timeout_multiplier=2)  # ping interval 100 x 10 ms = 1 s
    opened = admit(table, request)
    pid, cid = Seeds.of(VENDOR, SERIAL, opened.connection.instance), _pid(request)
    table.datagrams_to_send(T0)
    assert table.receive_datagram(encode_class0_packet(opened.connection.o_t_id, 1, encode_time_coordination(
        0, 0, cid, False)), ORIGINATOR.host, T0 + MS, 2222)
    (packet, _), = table.datagrams_to_send(T0 + 1000 * MS)  # one ping interval later: ping count 1
    decoded = decode_data(class0_data(decode_io_packet(packet)), 2, pid, False)  # type: ignore[arg-type]
    assert decoded is not None and decoded.ping_count == 1
    deadline = T0 + MS + 4 * 1000 * MS  # (2 + 2) ping intervals after the last answer
    assert opened.connection.deadline == deadline
    table.handle_timer(deadline - 1)
    assert table.connections
    table.handle_timer(deadline)
    assert not table.connections and not table.productions
    assert [e.reason for e in table.pop_events() if type(e) is ConnectionTimedOut] == [
        "safety timeout: no time coordination for 4 ping intervals"]


# -- what a forged datagram cannot do; time coordination counted on every path -------------------------


def test_a_bad_crc_time_coordination_from_another_port_pins_no_port() -> None:
    table = make_table()
    request = safety_open(server=False)
    opened = admit(table, request)
    o_t_id, cid = opened.connection.o_t_id, _pid(request)
    table.datagrams_to_send(T0)
    forged = encode_class0_packet(o_t_id, 50, b"\x08\x00\x00\xf7\x00\x00")  # bad CRC, sequence ahead, port 3333
    assert not table.receive_datagram(forged, ORIGINATOR.host, T0 + MS, 3333)
    assert table.counters["safety_crc_faults"] == 1 and opened.connection.o_t_port is None
    assert opened.connection.last_sequence is None
    good = encode_class0_packet(o_t_id, 1, encode_time_coordination(0, 0, cid, False))
    assert table.receive_datagram(good, ORIGINATOR.host, T0 + 2 * MS, 2222)  # sequence 1 < 50: not stale
    assert opened.connection.o_t_port == 2222 and opened.connection.last_sequence == 1
    assert opened.connection.safety.consumer_active  # type: ignore[union-attr]
    assert table.counters["o_t_dropped_wrong_port"] == 0 and table.counters["o_t_dropped_stale"] == 0
    # once a valid packet came, its port is the only one taken
    again = encode_class0_packet(o_t_id, 2, encode_time_coordination(0, 0, cid, False))
    assert not table.receive_datagram(again, ORIGINATOR.host, T0 + 3 * MS, 3333)
    assert table.counters["o_t_dropped_wrong_port"] == 1


def test_a_discarded_bad_crc_message_does_not_push_the_sequence_ahead() -> None:
    table, opened, pid, _ = _open_server(extended=True, max_faults=2)
    rollover = struct.unpack_from("<H", opened.application_reply, 12)[0]
    output = table.assemblies["output"]
    now = T0 + 10 * MS
    assert _send(table, opened, encode_data(b"\x05", mode_byte(True, 0), ticks(now), pid, True, rollover), 1, now)
    bad = bytearray(encode_data(b"\x0f", mode_byte(True, 0), ticks(now + MS), pid, True, rollover))
    bad[2] ^= 0x01
    assert not _send(table, opened, bytes(bad), 1_000, now + MS)  # discarded (extended: under Max_Fault_Number)
    assert table.connections and opened.connection.last_sequence == 1 and output.data == b"\x05"
    now += 10 * MS
    assert _send(table, opened, encode_data(b"\x0a", mode_byte(True, 0), ticks(now), pid, True, rollover), 2, now)
    assert output.data == b"\x0a" and opened.connection.last_sequence == 2
    assert table.counters["o_t_dropped_stale"] == 0 and table.counters["safety_crc_faults"] == 1


def test_time_coordination_held_back_by_the_min_multiplier_is_counted_when_sent() -> None:
    table, opened, pid, request = _open_server(time_coord_msg_min_multiplier=100)  # 100 x 128 us = 12.8 ms
    first = T0 + 5 * MS
    assert _send(table, opened, encode_data(b"\x00", mode_byte(False, 0), 0, pid, False), 1, first)
    assert table.answers_queued and len(table.datagrams_to_send(first)) == 1  # the first answers at once
    assert table.counters["safety_time_coordination_sent"] == 1 and table.counters["t_o_packets"] == 1
    assert _send(table, opened, encode_data(b"\x00", mode_byte(False, 1), 0, pid, False), 2, first + MS)
    # the next ping count change: held back until 12.8 ms after the first
    assert not table.answers_queued and table.datagrams_to_send(first + MS) == []
    due = first + 100 * TICK_NS
    assert table.datagrams_to_send(due - 1) == []
    (packet, address), = table.datagrams_to_send(due)
    io = decode_io_packet(packet)
    assert io is not None and io.connection_id == request.t_o_connection_id and address == ("127.0.0.9", 2222)
    cid = Seeds.of(VENDOR, SERIAL, opened.connection.instance)
    assert decode_time_coordination(class0_data(io), cid, False) == (1, ticks(due))
    assert table.counters["safety_time_coordination_sent"] == 2 and table.counters["t_o_packets"] == 2
