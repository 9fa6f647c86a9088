"""Property-based fuzzing of the sans-IO layers, in-process (unit tests: no sockets, no processes).

- The encapsulation session (protocol/session.py) with a real DSQC1030 behind it, fed arbitrary
  bytes, valid headers with random fields, SendRRData with random CIP, and structure-aware streams
  (tests/fuzzing.py), all split at random points. Every reply is held by an independent model
  (`SessionMirror`, struct only) to the frame that asked for it; nothing escapes or is logged.
- The connection table (cip/connection_table.py): random Forward Opens, O->T datagrams, Forward
  Closes, session ends and timer turns with a monotonic injected clock, and its invariants.
- `decode_io_packet` (protocol/connection.py) against an independent decoder, and its round trip.

The budget is fixed and reproducible: `derandomize=True`, no example database (nothing is written
to the tree): about 14 500 examples, about 130 000 frames, table operations and packets, about
30 s on 2 cores. ENIP_FARM_FUZZ_SCALE=10 multiplies every budget for a longer local run; bench/fuzz.py is
the tool for millions of inputs.
"""

from __future__ import annotations

import os
import random
import struct

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from enip_farm.device.device import Device
from enip_farm.device.profile import DeviceProfile
from enip_farm.protocol.connection import IoPacket, decode_io_packet, encode_io_packet
from enip_farm.protocol.session import EncapsulationSession
from tests.fuzzing import (
    COMMANDS,
    HEADER,
    MS,
    REGISTER,
    SEND_RR_DATA,
    SERVICES,
    Malformed,
    SessionMirror,
    SessionRun,
    TableFuzzer,
    check_service_io,
    dsqc1030_profile,
    logged_errors,
    logical,
    reference_decode_io_packet,
)

SCALE = float(os.environ.get("ENIP_FARM_FUZZ_SCALE", "1"))
T0 = 1_000_000 * MS
REGISTER_FRAME = HEADER.pack(REGISTER, 4, 0, 0, b"register", 0) + b"\x01\x00\x00\x00"
FIRST_HANDLE = 1  # a new device's first session handle


def budget(examples: int) -> settings:
    return settings(max_examples=max(1, round(examples * SCALE)), deadline=None, derandomize=True, database=None,
                    print_blob=False, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                                            HealthCheck.function_scoped_fixture,
                                                            HealthCheck.large_base_example])


@pytest.fixture(scope="module")
def profile() -> DeviceProfile:
    return dsqc1030_profile()


def feed_session(profile: DeviceProfile, chunks: list[bytes], now: int = T0) -> SessionMirror:
    """Feed the chunks to a new session of a new device, each reply checked; no error logged."""
    device = Device(profile)
    session = EncapsulationSession(device, "127.0.0.9")
    mirror = SessionMirror()
    with logged_errors() as errors:
        for chunk in chunks:
            mirror.feed(chunk, session.receive(chunk, now))
            assert session.closing == mirror.closed
            if mirror.closed:
                break
            now += MS
        check_service_io(device, now)
        session.connection_lost(now)
    assert not errors, [record.getMessage() for record in errors]
    return mirror


def split(data: bytes, cuts: list[int]) -> list[bytes]:
    points = sorted({cut % (len(data) + 1) for cut in cuts} | {0, len(data)})
    return [data[a:b] for a, b in zip(points, points[1:], strict=False)] or [b""]


# -- the session ----------------------------------------------------------------------------------------


@budget(2_000)
@given(st.booleans(), st.lists(st.binary(max_size=80), max_size=8))
def test_session_any_bytes(profile: DeviceProfile, register: bool, chunks: list[bytes]) -> None:
    feed_session(profile, ([REGISTER_FRAME] if register else []) + chunks)


header_fields = st.tuples(
    st.sampled_from(COMMANDS) | st.integers(0, 0xFFFF),  # command
    st.sampled_from([FIRST_HANDLE, FIRST_HANDLE, 0, 2]) | st.integers(0, 0xFFFFFFFF),  # session handle
    st.sampled_from([0, 0, 0, 1]) | st.integers(0, 0xFFFFFFFF),  # status
    st.binary(min_size=8, max_size=8),  # sender context
    st.sampled_from([0, 0, 0, 1]) | st.integers(0, 0xFFFFFFFF),  # options
    st.binary(max_size=48),  # command data
    st.sampled_from([None, None, None, 0, 4097]) | st.integers(0, 0xFFFF),  # a length field that lies
)


@budget(1_000)
@given(st.lists(header_fields, max_size=8), st.lists(st.integers(0, 2_000), max_size=6))
def test_session_valid_headers(profile: DeviceProfile, frames: list[tuple], cuts: list[int]) -> None:
    stream = REGISTER_FRAME + b"".join(
        HEADER.pack(command, len(data) if length is None else length, handle, status, context, options) + data
        for command, handle, status, context, options, data, length in frames)
    feed_session(profile, split(stream, cuts))


PATHS = [logical(0, c) + logical(1, i) + (logical(4, a) if a is not None else b"") for c, i, a in (
    (0x01, 1, None), (0x01, 1, 7), (0x02, 1, None), (0x04, 100, 3), (0x04, 101, 3), (0x04, 1, 3), (0x06, 1, None),
    (0xF5, 1, 5), (0xF6, 1, 1), (0x04, 198, 3), (0x01, 0, 1))]
cip_requests = st.tuples(
    st.sampled_from(SERVICES) | st.integers(0, 0xFF),
    st.sampled_from(PATHS) | st.binary(max_size=12),
    st.none() | st.integers(0, 0xFF),  # a path size that lies
    st.binary(max_size=48),
).map(lambda r: bytes((r[0], len(r[1]) // 2 if r[2] is None else r[2])) + r[1] + r[3])


@budget(1_000)
@given(st.lists(st.tuples(cip_requests, st.binary(min_size=8, max_size=8)), min_size=1, max_size=6),
       st.lists(st.integers(0, 2_000), max_size=4))
def test_session_send_rr_data_any_cip(profile: DeviceProfile, requests: list[tuple[bytes, bytes]],
                                      cuts: list[int]) -> None:
    stream = REGISTER_FRAME
    for message, context in requests:
        body = struct.pack("<IHHHHHH", 0, 0, 2, 0, 0, 0xB2, len(message)) + message
        stream += HEADER.pack(SEND_RR_DATA, len(body), FIRST_HANDLE, 0, context, 0) + body
    mirror = feed_session(profile, split(stream, cuts))
    if mirror.reset_frame is None:  # every frame answered: RegisterSession and each request
        assert mirror.replies == 1 + len(requests)
    else:  # an Identity Reset among the requests: answered up to it, nothing after (the mirror checks)
        reset_index = mirror.reset_frame - 1  # frame 0 is the RegisterSession
        assert 0 <= reset_index < len(requests)
        assert mirror.replies == reset_index + 2


@budget(300)
@given(st.lists(st.booleans(), max_size=300), cip_requests, st.lists(st.integers(0, 4_000), max_size=3))
def test_session_nesting_any_depth(profile: DeviceProfile, wrappers: list[bool], message: bytes,
                                   cuts: list[int]) -> None:
    """A request in Multiple Service Packets (True) and Unconnected Sends (False), any depth: a
    well-formed reply, nothing logged."""
    for msp in wrappers:
        if msp:
            message = b"\x0A\x02" + logical(0, 2) + logical(1, 1) + struct.pack("<HH", 1, 4) + message
        else:
            message = (b"\x52\x02" + logical(0, 6) + logical(1, 1) + struct.pack("<BBH", 0x0A, 0x0E, len(message))
                       + message + b"\x00" * (len(message) & 1) + b"\x01\x00\x01\x00")
    body = struct.pack("<IHHHHHH", 0, 0, 2, 0, 0, 0xB2, len(message)) + message
    stream = REGISTER_FRAME + HEADER.pack(SEND_RR_DATA, len(body), FIRST_HANDLE, 0, b"nesting!", 0) + body
    assert feed_session(profile, split(stream, cuts)).replies == 2


def structure_aware_session(profile: DeviceProfile, rng: random.Random, frames: int) -> SessionRun:
    run = SessionRun(rng, Device(profile), T0)
    with logged_errors() as errors:
        run.run(frames)
    assert not errors, [record.getMessage() for record in errors]
    return run


@budget(2_000)
@given(st.integers(0, 2**64 - 1))
def test_session_structure_aware(profile: DeviceProfile, seed: int) -> None:
    """Streams as a client, a buggy client and a fuzzer send them (tests/fuzzing.py), 30 frames each."""
    structure_aware_session(profile, random.Random(seed), 30)


@budget(150)
@given(st.randoms(use_true_random=False))
def test_session_structure_aware_shrinkable(profile: DeviceProfile, rng: random.Random) -> None:
    """The same, each choice drawn by hypothesis, so that a failure shrinks to a short stream."""
    structure_aware_session(profile, rng, 8)


def test_structure_aware_streams_reach_deep(profile: DeviceProfile) -> None:
    """The generator keeps reaching the interesting states (a guard against a harness that only
    ever hears 'invalid session handle'): successful CIP replies, opened connections, class-3 replies."""
    statuses: dict[int, int] = {}
    encapsulation: dict[tuple[int, int], int] = {}
    connections = 0
    for seed in range(100):
        mirror = structure_aware_session(profile, random.Random(seed), 30).mirror
        connections += len(mirror.connections)
        for status, count in mirror.cip_statuses.items():
            statuses[status] = statuses.get(status, 0) + count
        for key, count in mirror.statuses.items():
            encapsulation[key] = encapsulation.get(key, 0) + count
    assert statuses.get(0, 0) >= 50 and len(statuses) >= 8, statuses
    assert connections >= 10 and encapsulation.get((0x70, 0), 0) >= 10, (connections, encapsulation)


def test_the_mirror_catches_a_bad_reply() -> None:
    """The checker is not vacuous: a reply with another sender context, or none at all, fails it."""
    good = HEADER.pack(REGISTER, 4, 7, 0, b"register", 0) + b"\x01\x00\x00\x00"
    SessionMirror().feed(REGISTER_FRAME, [good])
    for replies, message in (([good.replace(b"register", b"REGISTER")], "sender context not echoed"),
                             ([], "no reply to command 0x0065"),
                             ([good, good], "more replies than frames that call for one"),
                             ([good[:-1]], "length field 4, 3 bytes follow")):
        with pytest.raises(Malformed, match=f"^{message}$"):
            SessionMirror().feed(REGISTER_FRAME, replies)


# -- the connection table --------------------------------------------------------------------------------


@budget(1_000)
@given(st.integers(0, 2**64 - 1))
def test_connection_table(seed: int) -> None:
    fuzzer = TableFuzzer(random.Random(seed))
    for _ in range(60):
        fuzzer.step()


@budget(100)
@given(st.randoms(use_true_random=False))
def test_connection_table_shrinkable(rng: random.Random) -> None:
    fuzzer = TableFuzzer(rng)
    for _ in range(25):
        fuzzer.step()


def test_table_fuzzer_reaches_deep() -> None:
    operations: dict[str, int] = {}
    for seed in range(50):
        fuzzer = TableFuzzer(random.Random(seed))
        for _ in range(60):
            fuzzer.step()
        for name, count in fuzzer.operations.items():
            operations[name] = operations.get(name, 0) + count
    assert operations.get("forward open opened", 0) >= 100 and operations.get("datagram taken", 0) >= 50, operations


# -- class-1 packets ----------------------------------------------------------------------------------------


def as_tuple(packet: IoPacket | None) -> tuple | None:
    return None if packet is None else tuple(packet)


@budget(3_000)
@given(st.binary(max_size=64))
def test_decode_io_packet_any_bytes(data: bytes) -> None:
    assert as_tuple(decode_io_packet(data)) == reference_decode_io_packet(data)


io_fields = st.tuples(
    st.sampled_from([2, 2, 1, 3]) | st.integers(0, 0xFFFF),  # item count
    st.sampled_from([0x8002, 0x8002, 0x00A1]) | st.integers(0, 0xFFFF),  # address item type
    st.sampled_from([8, 8, 4]) | st.integers(0, 0xFFFF),  # address item length
    st.integers(0, 0xFFFFFFFF), st.integers(0, 0xFFFFFFFF),  # connection id, sequence
    st.sampled_from([0x00B1, 0x00B1, 0x00B2]) | st.integers(0, 0xFFFF),  # data item type
    st.none() | st.integers(0, 0xFFFF),  # a data length that lies
    st.integers(0, 0xFFFF), st.binary(max_size=40), st.binary(max_size=3),  # sequence count, data, trailer
)


@budget(2_000)
@given(io_fields, st.none() | st.integers(0, 80))
def test_decode_io_packet_structured(fields: tuple, cut: int | None) -> None:
    *head, data_type, length, sequence_count, data, extra = fields
    packet = struct.pack("<HHHIIHHH", *head, data_type, 2 + len(data) if length is None else length,
                         sequence_count) + data + extra
    if cut is not None:
        packet = packet[:cut]
    assert as_tuple(decode_io_packet(packet)) == reference_decode_io_packet(packet)


@budget(2_000)
@given(st.integers(0, 0xFFFFFFFF), st.integers(-(2**40), 2**40), st.integers(-(2**20), 2**20),
       st.binary(max_size=512))
def test_io_packet_round_trip(connection_id: int, sequence: int, sequence_count: int, data: bytes) -> None:
    packet = encode_io_packet(connection_id, sequence, sequence_count, data)
    expected = (connection_id, sequence & 0xFFFFFFFF, sequence_count & 0xFFFF, data)
    assert as_tuple(decode_io_packet(packet)) == expected == reference_decode_io_packet(packet)
