"""The fuzz harness's shared parts: structure-aware generators driven by a `random.Random`, and
independent checkers written with `struct` alone (none of enip_farm's codec is used to judge a
reply). tests/test_fuzz.py drives them through hypothesis (its `st.randoms()` make every choice
shrinkable); bench/fuzz.py drives them with a seeded `random.Random` for long runs.

- `SessionMirror`: an independent model of one encapsulation connection (CIP Networks Library
  Vol. 2, 2-3 to 2-6). It frames the bytes fed to a session itself, predicts which frames get a
  reply and holds every reply to the header, the status and the command data that frame demands.
- `FrameGenerator`: frames as a client, a buggy client or a fuzzer would send them: valid headers
  with random commands, lengths, handles and options; SendRRData/SendUnitData carrying random and
  structure-aware CIP (Get/Set, Multiple Service Packet, Unconnected Send, (Large) Forward Open,
  Forward Close, random EPATHs), and now and then a flipped byte.
- `TableFuzzer`: random Forward Opens, O->T datagrams, Forward Closes, session ends and timer
  turns on a `ConnectionTable` with a monotonic injected clock, with `check_table`'s invariants.
- `reference_decode_io_packet`: the class-1 packet layout of Vol. 2, 3-2, decoded independently.
"""

from __future__ import annotations

import logging
import random
import struct
from collections.abc import Iterator
from contextlib import contextmanager

from enip_farm.cip.admission import Originator
from enip_farm.cip.assembly import AssemblyInstance
from enip_farm.cip.connection import ConnectionKind
from enip_farm.cip.connection_events import ConnectionEnded
from enip_farm.cip.connection_path import KeyIdentity
from enip_farm.cip.connection_policy import ConnectionPolicy
from enip_farm.cip.connection_table import ConnectionTable
from enip_farm.config import parse_config
from enip_farm.device.build import build_profiles
from enip_farm.device.catalogue import shipped_catalogue
from enip_farm.device.device import Device
from enip_farm.device.profile import DeviceProfile
from enip_farm.protocol.commands import SocketAddress
from enip_farm.protocol.connection import (
    ConnectionTriad,
    ConnectionType,
    ForwardOpenRequest,
    NetworkParameters,
)
from enip_farm.protocol.session import EncapsulationSession

MS = 1_000_000  # ns
HEADER = struct.Struct("<HHII8sI")  # command, length, session handle, status, sender context, options
U16, U32 = struct.Struct("<H"), struct.Struct("<I")
MAX_LENGTH = 4096  # the farm's documented limit on command data (README, "What a device answers")

NOP, LIST_SERVICES, LIST_IDENTITY, LIST_INTERFACES = 0x0000, 0x0004, 0x0063, 0x0064
REGISTER, UNREGISTER, SEND_RR_DATA, SEND_UNIT_DATA = 0x0065, 0x0066, 0x006F, 0x0070
COMMANDS = (NOP, LIST_SERVICES, LIST_IDENTITY, LIST_INTERFACES, REGISTER, UNREGISTER, SEND_RR_DATA, SEND_UNIT_DATA)
NULL_ADDRESS, CONNECTED_ADDRESS, CONNECTED_DATA, UNCONNECTED_DATA = 0x0000, 0x00A1, 0x00B1, 0x00B2
SOCKADDR_ITEMS = (0x8000, 0x8001)


class Malformed(AssertionError):
    """A reply (or a T->O packet, or the table's state) that breaks the rules the checker holds it to."""


def expect(condition: bool, what: str) -> None:
    if not condition:
        raise Malformed(what)


# -- an independent reading of the wire formats ------------------------------------------------------


def parse_items(data: bytes, offset: int = 0) -> list[tuple[int, bytes]] | None:
    """A CPF item list (Vol. 2, 2-6): count, then (type, length, data); None if it does not add up
    exactly to the end of `data`."""
    if len(data) - offset < 2:
        return None
    (count,) = U16.unpack_from(data, offset)
    offset += 2
    items = []
    for _ in range(count):
        if len(data) - offset < 4:
            return None
        type_id, length = struct.unpack_from("<HH", data, offset)
        offset += 4
        if len(data) - offset < length:
            return None
        items.append((type_id, data[offset : offset + length]))
        offset += length
    return items if offset == len(data) else None


def parse_send_data(body: bytes) -> list[tuple[int, bytes]] | None:
    """SendRRData/SendUnitData: interface handle (UDINT), timeout (UINT), CPF items."""
    return parse_items(body, 6) if len(body) >= 6 else None


def unconnected_request(body: bytes) -> bytes | None:
    """The CIP request of a SendRRData body the farm must take: a null address item, a non-empty
    unconnected data item, then only socket-address items of 16 bytes."""
    items = parse_send_data(body)
    if (items is None or len(items) < 2 or items[0] != (NULL_ADDRESS, b"") or items[1][0] != UNCONNECTED_DATA
            or not items[1][1] or any(t not in SOCKADDR_ITEMS or len(d) != 16 for t, d in items[2:])):
        return None
    return items[1][1]


def connected_request(body: bytes) -> tuple[int, int, bytes] | None:
    """(connection id, sequence count, CIP request) of a well-formed SendUnitData body."""
    items = parse_send_data(body)
    if (items is None or len(items) < 2 or items[0][0] != CONNECTED_ADDRESS or len(items[0][1]) != 4
            or items[1][0] != CONNECTED_DATA or len(items[1][1]) < 3
            or any(t not in SOCKADDR_ITEMS or len(d) != 16 for t, d in items[2:])):
        return None
    return U32.unpack(items[0][1])[0], U16.unpack_from(items[1][1])[0], items[1][1][2:]


def reply_services(request: bytes) -> set[int]:
    """The reply services a request may get: its own with the reply bit, or for an Unconnected
    Send (Vol. 1, 3-5.5.2: the embedded request's reply comes back as it is) the embedded one's."""
    services = {request[0] | 0x80}
    path_end = 2 + 2 * request[1] if len(request) >= 2 else 0
    data = request[path_end:]
    if request[0] == 0x52 and len(data) >= 5:
        size = U16.unpack_from(data, 2)[0]
        if size:
            services |= reply_services(data[4 : 4 + size])
    return services


def embedded_requests(request: bytes) -> list[bytes] | None:
    """The requests of a Multiple Service Packet (Vol. 1, 4-A.5), cut by their offsets; None if the
    offsets are not in order within the data."""
    if len(request) < 2 or request[0] != 0x0A:
        return None
    data = request[2 + 2 * request[1] :]
    if len(data) < 2:
        return None
    count = U16.unpack_from(data)[0]
    if not count or 2 + 2 * count > len(data):
        return None
    offsets = [*struct.unpack_from(f"<{count}H", data, 2), len(data)]
    if any(not 2 + 2 * count <= a < b for a, b in zip(offsets, offsets[1:], strict=False)) or offsets[-2] > len(data):
        return None
    return [data[a:b] for a, b in zip(offsets, offsets[1:], strict=False)]


def check_cip_reply(reply: bytes, request: bytes) -> int:
    """A message-router reply (Vol. 1, 2-4.2) to `request`: the service with the reply bit, reserved
    0, general status, additional status words that fit; a Multiple Service Packet's replies one by
    one. Its general status."""
    expect(len(reply) >= 4, f"CIP reply of {len(reply)} bytes")
    expect(reply[0] in reply_services(request), f"reply service 0x{reply[0]:02X} to 0x{request[0]:02X}")
    expect(reply[1] == 0, "reserved byte of the reply is not 0")
    data_start = 4 + 2 * reply[3]
    expect(data_start <= len(reply), "additional status longer than the reply")
    requests = embedded_requests(request) if reply[0] == 0x8A and reply[2] in (0x00, 0x1E) else None
    if requests is not None:
        replies = embedded_requests(b"\x0A\x00" + reply[data_start:])
        expect(replies is not None and len(replies) == len(requests), "Multiple Service Packet reply layout")
        assert replies is not None
        statuses = [check_cip_reply(r, q) for r, q in zip(replies, requests, strict=True)]
        expect((reply[2] == 0) == (not any(statuses)), "Multiple Service Packet status and its replies' statuses")
    return reply[2]


def restarts_device(reply: bytes) -> bool:
    """The reply is, or a Multiple Service Packet reply holds, a successful Identity Reset (0x85,
    status 0; Vol. 1, 5-2.4.1): the device restarts, and the connection ends after this reply."""
    if len(reply) < 4:
        return False
    if reply[0] == 0x85:
        return reply[2] == 0
    if reply[0] == 0x8A:
        replies = embedded_requests(b"\x0A\x00" + reply[4 + 2 * reply[3] :])
        return any(restarts_device(r) for r in replies or ())
    return False


def check_io_packet(packet: bytes) -> tuple[int, int, int, bytes]:
    decoded = reference_decode_io_packet(packet)
    expect(decoded is not None, f"malformed class-1 packet {packet.hex()}")
    return decoded  # type: ignore[return-value]


def reference_decode_io_packet(datagram: bytes) -> tuple[int, int, int, bytes] | None:
    """Vol. 2, 3-2: item count 2, sequenced address item (0x8002, 8 bytes: connection id, sequence
    number), connected data item (0x00B1) holding the 16-bit sequence count and the data, nothing
    after it. (connection id, sequence, sequence count, data) or None."""
    if len(datagram) < 20:
        return None
    count, address_type, address_length = struct.unpack_from("<HHH", datagram, 0)
    connection_id, sequence = struct.unpack_from("<II", datagram, 6)
    data_type, data_length, sequence_count = struct.unpack_from("<HHH", datagram, 14)
    if count != 2 or address_type != 0x8002 or address_length != 8 or data_type != 0x00B1:
        return None
    if data_length < 2 or 18 + data_length != len(datagram):
        return None
    return connection_id, sequence, sequence_count, datagram[20:]


# -- the device under test -----------------------------------------------------------------------------


def dsqc1030_profile() -> DeviceProfile:
    config = parse_config({"devices": [{"name": "fuzz", "address": "127.0.0.1", "model": "DSQC1030"}]})
    (profile,) = build_profiles(config, shipped_catalogue())
    return profile


@contextmanager
def logged_errors() -> Iterator[list[logging.LogRecord]]:
    """Records of ERROR and above logged by enip_farm meanwhile: an exception the farm caught and
    logged (the message router's last resort) is a defect the fuzzer reports like an escaped one."""
    records: list[logging.LogRecord] = []

    class Keep(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            records.append(record)

    handler = Keep(logging.ERROR)
    logger = logging.getLogger("enip_farm")
    logger.addHandler(handler)
    try:
        yield records
    finally:
        logger.removeHandler(handler)


# -- the session mirror ----------------------------------------------------------------------------------


class SessionMirror:
    """An independent model of one encapsulation connection. `feed(chunk, replies)` frames the
    chunk after what was fed before, predicts the frames that get a reply and checks each reply,
    in order, against its request; it raises Malformed on the first difference."""

    def __init__(self) -> None:
        self.buffer = b""
        self.handle = 0  # the session handle registered on this connection
        self.closed = False  # an UnregisterSession or an Identity Reset ended it
        self.skip = 0  # bytes of an oversize message still to come, dropped as they arrive
        self.skip_header = b""  # that message's header
        self.reset_frame: int | None = None  # index (from 0, among frames taken) of the frame whose
        # successful Identity Reset restarted the device: its reply was the connection's last
        self.frames = 0  # whole messages taken (an oversize one's data dropped)
        self.replies = 0
        self.connections: dict[int, None] = {}  # O->T ids handed out in Forward Open replies, in order
        self.last_connected: dict[int, tuple[int, bytes]] = {}  # id -> (sequence count, its reply)
        self.cip_statuses: dict[int, int] = {}  # general status -> replies (for the report)
        self.statuses: dict[tuple[int, int], int] = {}  # (command, encapsulation status) -> replies

    def feed(self, chunk: bytes, replies: list[bytes], limit: int | None = None) -> int:
        """The chunk and the replies that `receive(chunk, now, limit)` gave for it (at most `limit`
        frames taken, the rest left for later calls); the number of frames taken."""
        expect(not self.closed or not replies, "a reply after the connection ended")
        if self.closed:
            return 0
        pending = iter(replies)
        taken = 0
        if self.skip:  # the rest of an oversize message: read and dropped (Vol. 2, 2-3.3)
            dropped = min(self.skip, len(chunk))
            self.skip -= dropped
            chunk = chunk[dropped:]
            if not self.skip:
                taken = 1
                self._take(self.skip_header, b"", pending, oversize=True)
        buffer = self.buffer + chunk
        while len(buffer) >= 24 and not self.closed and (limit is None or taken < limit):
            length = U16.unpack_from(buffer, 2)[0]
            if length > MAX_LENGTH and len(buffer) < 24 + length:
                self.skip_header, self.skip = buffer[:24], 24 + length - len(buffer)
                buffer = b""
                break
            if len(buffer) < 24 + length:
                break
            header, body, buffer = buffer[:24], buffer[24 : 24 + length], buffer[24 + length :]
            taken += 1
            self._take(header, body, pending, oversize=length > MAX_LENGTH)
        self.buffer = b"" if self.closed else buffer
        expect(next(pending, None) is None, "more replies than frames that call for one")
        return taken

    def _take(self, header: bytes, body: bytes, pending: Iterator[bytes], oversize: bool) -> None:
        """One whole message (an oversize one's body dropped): its reply, if it calls for one."""
        command, _, handle, status, _, options = HEADER.unpack(header)
        self.frames += 1
        if options or status or command == NOP:
            return  # no reply: non-zero options (Vol. 2, 2-3.7) or status (2-3.5), a NOP (2-4.1)
        if command == UNREGISTER and handle and handle == self.handle and not oversize:
            self.closed = True
            self.handle = 0
            return
        self._check(next(pending, None), header, body, oversize)

    @property
    def backlog(self) -> bool:
        """A whole frame (or an oversize header, which can be taken) buffered and not taken yet."""
        if self.closed or self.skip or len(self.buffer) < 24:
            return False
        length = U16.unpack_from(self.buffer, 2)[0]
        return length > MAX_LENGTH or len(self.buffer) >= 24 + length

    def _check(self, reply: bytes | None, header: bytes, body: bytes, oversize: bool = False) -> None:
        command, _, handle, _, context, _ = HEADER.unpack(header)
        expect(reply is not None, f"no reply to command 0x{command:04X}")
        assert reply is not None
        self.replies += 1
        expect(len(reply) >= 24, f"reply of {len(reply)} bytes")
        r_command, r_length, r_handle, status, r_context, r_options = HEADER.unpack_from(reply)
        expect(r_length == len(reply) - 24, f"length field {r_length}, {len(reply) - 24} bytes follow")
        expect(r_options == 0, "options in a reply")
        expect(r_command == command, f"reply command 0x{r_command:04X} to 0x{command:04X}")
        self.statuses[command, status] = self.statuses.get((command, status), 0) + 1
        expect(r_context == context, "sender context not echoed")
        data = reply[24:]

        def error(expected_status: int, expected_handle: int = handle) -> None:
            expect(status == expected_status, f"status 0x{status:X}, expected 0x{expected_status:X}")
            expect(data == b"", "data in an error reply")
            expect(r_handle == expected_handle, "session handle of an error reply")

        if oversize:
            return error(0x65)
        if command == REGISTER:
            expect(data == b"\x01\x00\x00\x00", "RegisterSession reply data")
            if len(body) != 4:
                expect(status == 0x65 and r_handle == 0, "RegisterSession with a bad length")
            elif body != b"\x01\x00\x00\x00":
                expect(status == 0x69 and r_handle == 0, "RegisterSession of another version or options")
            elif self.handle:
                expect(status == 0x01 and r_handle == self.handle, "a second RegisterSession")
            else:
                expect(status == 0 and r_handle != 0, "RegisterSession refused")
                self.handle = r_handle
            return None
        if command == UNREGISTER:
            return error(0x64)
        if command in (LIST_IDENTITY, LIST_SERVICES, LIST_INTERFACES):
            expect(status == 0 and r_handle == 0, "a List reply's status or handle")
            items = parse_items(data)
            expect(items is not None, "List reply items")
            assert items is not None
            if command == LIST_INTERFACES:
                expect(items == [], "ListInterfaces items")
            elif command == LIST_SERVICES:
                expect(len(items) == 1 and items[0][0] == 0x0100 and len(items[0][1]) == 20, "ListServices item")
            else:
                expect(len(items) == 1 and items[0][0] == 0x000C, "ListIdentity item")
                identity = items[0][1]
                # version, socket address (16), vendor .. serial (14), product name (SHORT_STRING), state
                expect(len(identity) >= 34 and U16.unpack_from(identity)[0] == 1, "identity item head")
                expect(len(identity) == 33 + identity[32] + 1, "identity item: product name and state")
            return None
        if command not in (SEND_RR_DATA, SEND_UNIT_DATA):
            return error(0x01)
        if not handle or handle != self.handle:
            return error(0x64)
        if command == SEND_RR_DATA:
            request = unconnected_request(body)
            if request is None:
                return error(0x03)
            expect(status == 0 and r_handle == handle, f"SendRRData status 0x{status:X}")
            items = parse_send_data(data)
            expect(items is not None and len(items) >= 2 and items[0] == (NULL_ADDRESS, b"")
                   and items[1][0] == UNCONNECTED_DATA, "SendRRData reply items")
            assert items is not None
            expect(all(t in SOCKADDR_ITEMS and len(d) == 16 for t, d in items[2:]), "items beside the reply")
            general = check_cip_reply(items[1][1], request)
            self.cip_statuses[general] = self.cip_statuses.get(general, 0) + 1
            self._restarts(items[1][1])
            if request[0] in (0x54, 0x5B) and general == 0:
                cip = items[1][1]
                reply_data = cip[4 + 2 * cip[3] :]
                expect(len(reply_data) >= 26, "Forward Open reply data")
                self.connections[U32.unpack_from(reply_data)[0]] = None
            return None
        connected = connected_request(body)
        if connected is None:
            return error(0x03)
        connection_id, sequence_count, request = connected
        if connection_id not in self.connections:
            return error(0x03)
        if status:  # the connection may have closed since (Forward Close, timeout, another session's)
            return error(0x03)
        expect(r_handle == handle, "SendUnitData reply handle")
        items = parse_send_data(data)
        expect(items is not None and len(items) >= 2 and items[0][0] == CONNECTED_ADDRESS and len(items[0][1]) == 4
               and items[1][0] == CONNECTED_DATA and len(items[1][1]) >= 6, "SendUnitData reply items")
        assert items is not None
        expect(all(t in SOCKADDR_ITEMS and len(d) == 16 for t, d in items[2:]), "items beside the connected reply")
        expect(U16.unpack_from(items[1][1])[0] == sequence_count, "sequence count not echoed")
        cip = items[1][1][2:]
        previous = self.last_connected.get(connection_id)
        if previous is not None and previous[0] == sequence_count:  # a retransmission: the same reply again
            expect(cip == previous[1], "a duplicate's reply differs from the first")
        else:
            check_cip_reply(cip, request)
        self.last_connected[connection_id] = (sequence_count, cip)
        self._restarts(cip)
        return None

    def _restarts(self, cip_reply: bytes) -> None:
        """A successful Identity Reset (alone or in a Multiple Service Packet) ends the connection."""
        if restarts_device(cip_reply):
            self.closed = True
            self.reset_frame = self.frames - 1


# -- structure-aware generators --------------------------------------------------------------------------


def logical(segment_type: int, value: int, fmt: int | None = None) -> bytes:
    """A logical segment (Vol. 1, C-1.4.2) in the 8-, 16- or 32-bit format."""
    kind = 0x20 | segment_type << 2
    if fmt is None:
        fmt = 0 if value <= 0xFF else 1 if value <= 0xFFFF else 2
    if fmt == 0:
        return bytes((kind, value & 0xFF))
    if fmt == 1:
        return bytes((kind | 1, 0)) + U16.pack(value & 0xFFFF)
    return bytes((kind | 2, 0)) + U32.pack(value & 0xFFFFFFFF)


CLASS, INSTANCE, MEMBER, POINT, ATTRIBUTE = 0, 1, 2, 3, 4
CLASSES = (0x01, 0x02, 0x04, 0x06, 0xF5, 0xF6)
SERVICES = (0x01, 0x02, 0x05, 0x0A, 0x0E, 0x10, 0x4E, 0x52, 0x54, 0x5B)
INSTANCES = (0, 1, 2, 100, 101, 198, 199)
#: (class, instance, highest attribute) of the objects a DSQC1030 has.
TARGETS = ((0x01, 1, 7), (0x02, 1, 2), (0x04, 100, 4), (0x04, 101, 4), (0x06, 1, 1), (0xF5, 1, 13), (0xF6, 1, 10))


class FrameGenerator:
    """Frames and CIP requests from `rng`. `key`: the device's (vendor, device type, product code,
    major, minor), so that some electronic keys match."""

    def __init__(self, rng: random.Random, key: tuple[int, int, int, int, int] = (0, 0, 0, 0, 0),
                 max_depth: int = 3) -> None:
        self.rng = rng
        self.key = key
        self.max_depth = max_depth
        self.sequence: dict[int, int] = {}

    def pick(self, *options):  # noqa: ANN001, ANN202
        return options[self.rng.randrange(len(options))]

    def raw(self, low: int = 0, high: int = 16) -> bytes:
        return self.rng.randbytes(self.rng.randint(low, high))

    # EPATHs
    def request_path(self) -> bytes:
        rng = self.rng
        roll = rng.random()
        if roll < 0.05:
            return self.raw(0, 12)
        fmt = None if roll < 0.85 else rng.randrange(3)
        path = logical(CLASS, self.pick(*CLASSES) if rng.random() < 0.9 else rng.getrandbits(16), fmt)
        if rng.random() < 0.9:
            path += logical(self.pick(INSTANCE, POINT), self.pick(*INSTANCES) if rng.random() < 0.8
                            else rng.getrandbits(32), fmt)
            if rng.random() < 0.6:
                path += logical(ATTRIBUTE, rng.randint(0, 20) if rng.random() < 0.9 else rng.getrandbits(16), fmt)
                if rng.random() < 0.05:
                    path += logical(MEMBER, rng.getrandbits(8))
        if rng.random() < 0.05:
            path += self.pick(b"\x01\x00", b"\x80\x01\xAA\xBB", b"\x34\x04" + bytes(8), b"\x40\x01", b"\xFF\x00")
        if len(path) % 2:
            path += b"\x00"
        return path

    def key_segment(self) -> bytes:
        """An electronic key (Vol. 1, C-1.4.2, format 4): the device's, wildcards, or anything."""
        rng = self.rng
        vendor, device_type, product, major, minor = (
            self.key if rng.random() < 0.7 else (rng.getrandbits(16), rng.getrandbits(16), rng.getrandbits(16),
                                                 rng.getrandbits(8), rng.getrandbits(8)))
        fields = [vendor, device_type, product, major | (0x80 if rng.random() < 0.3 else 0), minor]
        for i in range(5):
            if rng.random() < 0.2:
                fields[i] = 0
        return b"\x34\x04" + struct.pack("<HHHBB", *fields)

    def connection_path(self, kind: str) -> bytes:
        """The connection path of a Forward Open of `kind` (owner, input only, listen only, class 3),
        maybe routed to the device itself or keyed; now and then any request path."""
        rng = self.rng
        path = b"\x01\x00" if rng.random() < 0.1 else b""
        if rng.random() < 0.3:
            path += self.key_segment()
        if kind == "class 3":
            return path + logical(CLASS, 2) + logical(INSTANCE, 1)
        if rng.random() < 0.05:
            return path + self.request_path()
        consuming = {"owner": 100, "input only": 198, "listen only": 199}[kind]
        path += logical(CLASS, 4) + (logical(INSTANCE, 1) if rng.random() < 0.5 else b"")
        return path + logical(POINT, consuming) + logical(POINT, 101)

    def forward_open_fields(self, triads: list[tuple[int, int, int]], output_size: int = 2,
                            input_size: int = 2) -> dict:
        """The fields of a Forward Open that a device of these image sizes admits, then now and then
        one or more of them changed to something else (which the device may refuse)."""
        rng, pick = self.rng, self.pick
        kind = pick("owner", "owner", "owner", "input only", "listen only", "class 3", "class 3")
        p2p, multicast = 2, 1
        rpi = pick(2_000, 10_000, 100_000)
        fields = {
            "large": rng.random() < 0.2, "kind": kind, "path": self.connection_path(kind),
            "o_t_id": rng.getrandbits(32), "t_o_id": rng.getrandbits(32), "triad": pick(*triads),
            "multiplier": pick(0, 1, 3, 7), "o_t_rpi": rpi, "t_o_rpi": rpi, "transport": 0x01,
            "o_t_type": p2p, "t_o_type": pick(p2p, multicast), "o_t_variable": False, "t_o_variable": False,
            "o_t_size": 6 + output_size, "t_o_size": 2 + input_size,
            "o_t_priority": rng.getrandbits(2), "t_o_priority": rng.getrandbits(2),
        }
        if kind == "input only":
            fields["o_t_size"] = pick(2, 6)
        elif kind == "listen only":
            fields["o_t_size"], fields["t_o_type"] = 2, multicast
        elif kind == "class 3":
            fields.update(transport=pick(0xA3, 0x83), t_o_type=p2p, o_t_size=500, t_o_size=500, o_t_variable=True,
                          t_o_variable=True, o_t_rpi=pick(100_000, 2_000_000), t_o_rpi=2_000_000)
        if rng.random() < 0.5:
            fields["o_t_variable"] = fields["t_o_variable"] = rng.random() < 0.5
        mutations = {
            "triad": lambda: (rng.getrandbits(16), rng.getrandbits(16), rng.getrandbits(32)),
            "multiplier": lambda: rng.getrandbits(8),
            "o_t_rpi": lambda: pick(0, 1_000, 1_999, 10_000_001, rng.getrandbits(32)),
            "t_o_rpi": lambda: pick(0, 1_000, 20_000, rng.getrandbits(32)),
            "transport": lambda: pick(0x81, 0x03, 0x11, 0x00, rng.getrandbits(8)),
            "o_t_type": lambda: rng.getrandbits(2), "t_o_type": lambda: rng.getrandbits(2),
            "o_t_size": lambda: pick(0, 1, 2, 5, 6, 7, 9, 500, rng.getrandbits(9)),
            "t_o_size": lambda: pick(0, 1, 2, 3, 5, 500, rng.getrandbits(9)),
            "path": lambda: self.connection_path(pick("owner", "input only", "listen only", "class 3")),
            "kind": lambda: None,
        }
        if rng.random() < 0.4:
            for name in rng.sample(sorted(mutations), rng.randint(1, 3)):
                value = mutations[name]()
                if value is not None:
                    fields[name] = value
        return fields

    def forward_open(self, triads: list[tuple[int, int, int]]) -> bytes:
        """A (Large) Forward Open request to the Connection Manager (Vol. 1, 3-5.5.2), encoded here."""
        rng = self.rng
        f = self.forward_open_fields(triads)
        large = f["large"]

        def parameters(direction: str) -> int:
            connection_type, size = f[f"{direction}_type"], f[f"{direction}_size"]
            priority, variable = f[f"{direction}_priority"], f[f"{direction}_variable"]
            if large:
                return connection_type << 29 | priority << 26 | variable << 25 | size & 0xFFFF
            return connection_type << 13 | priority << 10 | variable << 9 | size & 0x1FF

        rpi_format = "<II" if large else "<IH"
        path = f["path"]
        words = len(path) // 2 if rng.random() < 0.97 else rng.getrandbits(8)
        body = (struct.pack("<BBIIHHIB3x", 0x0A, 0x0E, f["o_t_id"], f["t_o_id"], *f["triad"], f["multiplier"])
                + struct.pack(rpi_format, f["o_t_rpi"], parameters("o_t"))
                + struct.pack(rpi_format, f["t_o_rpi"], parameters("t_o"))
                + bytes((f["transport"], words & 0xFF)) + path)
        if rng.random() < 0.03:
            body = body[: rng.randrange(len(body) + 1)]
        return bytes((0x5B if large else 0x54, 2)) + logical(CLASS, 6) + logical(INSTANCE, 1) + body

    def forward_close(self, triads: list[tuple[int, int, int]]) -> bytes:
        rng = self.rng
        triad = self.pick(*triads) if rng.random() < 0.9 else (rng.getrandbits(16), rng.getrandbits(16),
                                                                 rng.getrandbits(32))
        path = self.connection_path(self.pick("owner", "class 3")) if rng.random() < 0.7 else b""
        body = (struct.pack("<BBHHI", 0x0A, 0x0E, *triad) + bytes(((len(path) // 2) & 0xFF, 0)) + path)
        if rng.random() < 0.05:
            body = body[: rng.randrange(len(body) + 1)]
        return b"\x4E\x02" + logical(CLASS, 6) + logical(INSTANCE, 1) + body

    def cip_request(self, triads: list[tuple[int, int, int]], depth: int = 0) -> bytes:
        """One message-router request: mostly well-formed, often addressed to something that exists."""
        rng = self.rng
        roll = rng.random()
        if depth == 0 and roll < 0.005:
            return self.nested_chain(triads)
        if roll < 0.05:
            return self.raw(1, 24)
        if roll < 0.15:
            return self.forward_open(triads)
        if roll < 0.2:
            return self.forward_close(triads)
        if roll < 0.3 and depth < self.max_depth:  # Multiple Service Packet
            requests = [self.cip_request(triads, depth + 1) for _ in range(rng.randint(0, 4))]
            offsets, position = [], 2 + 2 * len(requests)
            for request in requests:
                offsets.append(position if rng.random() < 0.95 else rng.getrandbits(16))
                position += len(request)
            data = struct.pack(f"<H{len(requests)}H", len(requests), *offsets) + b"".join(requests)
            return b"\x0A\x02" + logical(CLASS, 2) + logical(INSTANCE, self.pick(1, 1, 1, 0, 2)) + data
        if roll < 0.38 and depth < self.max_depth:  # Unconnected Send
            embedded = self.cip_request(triads, depth + 1)
            size = len(embedded) if rng.random() < 0.95 else rng.getrandbits(16)
            route = self.pick(b"\x01\x00", b"\x01\x00", b"", b"\x01\x01", b"\x12\x02\x31\x30", self.raw(0, 6))
            route_words = len(route) // 2 if rng.random() < 0.95 else rng.getrandbits(8)
            data = (struct.pack("<BBH", 0x0A, 0x0E, size) + embedded + b"\x00" * (len(embedded) & 1)
                    + bytes((route_words, 0)) + route)
            return b"\x52\x02" + logical(CLASS, 6) + logical(INSTANCE, 1) + data
        if roll < 0.45:  # the assemblies' data, as a scanner reads and writes it
            instance = self.pick(100, 101, 1, 198, 199)
            service = self.pick(0x0E, 0x10, 0x01, 0x02)
            path = logical(CLASS, 4) + logical(INSTANCE, instance) + (logical(ATTRIBUTE, 3) if service in (
                0x0E, 0x10) else b"")
            return bytes((service, len(path) // 2)) + path + (self.raw(0, 4) if service in (0x10, 0x02) else b"")
        if roll < 0.75:  # an attribute of an object the device has, as a configuration tool asks
            class_id, instance, attributes = self.pick(*TARGETS)
            service = self.pick(0x0E, 0x0E, 0x0E, 0x01, 0x10, 0x02, 0x05, 0x4B)
            path = logical(CLASS, class_id) + logical(INSTANCE, self.pick(instance, instance, instance, 0))
            if service in (0x0E, 0x10):
                path += logical(ATTRIBUTE, rng.randint(1, attributes + 1))
            data = self.raw(0, 8) if service in (0x10, 0x02, 0x05) or rng.random() < 0.05 else b""
            return bytes((service, len(path) // 2)) + path + data
        service = self.pick(*SERVICES) if rng.random() < 0.8 else rng.getrandbits(8)
        path = self.request_path()
        words = len(path) // 2 if rng.random() < 0.95 else rng.getrandbits(8)
        return bytes((service, words & 0xFF)) + path + (self.raw(0, 8) if rng.random() < 0.6 else b"")

    def nested_chain(self, triads: list[tuple[int, int, int]]) -> bytes:
        """A request wrapped in Multiple Service Packets and Unconnected Sends up to 300 deep (the
        abuse of issue 10: each level must cost little and end in a reply, not a traceback)."""
        rng = self.rng
        message = self.cip_request(triads, self.max_depth)
        for _ in range(rng.randint(5, 300)):
            if rng.random() < 0.5:
                message = b"\x0A\x02" + logical(CLASS, 2) + logical(INSTANCE, 1) + struct.pack("<HH", 1, 4) + message
            else:
                message = (b"\x52\x02" + logical(CLASS, 6) + logical(INSTANCE, 1)
                           + struct.pack("<BBH", 0x0A, 0x0E, len(message)) + message + b"\x00" * (len(message) & 1)
                           + b"\x01\x00\x01\x00")
        return message

    def sockaddr_item(self) -> bytes:
        rng = self.rng
        kind = self.pick(*SOCKADDR_ITEMS)
        if rng.random() < 0.9:
            host = self.pick(b"\x00\x00\x00\x00", b"\x7F\x00\x00\x09", b"\xEF\xC0\x01\x00", rng.randbytes(4))
            data = struct.pack(">HH4s8x", self.pick(2, 2, 0, 23), self.pick(2222, 0, 44818), host)
        else:
            data = self.raw(0, 20)
        return struct.pack("<HH", kind, len(data)) + data

    def items(self, first: tuple[int, bytes], second: tuple[int, bytes]) -> bytes:
        """A CPF list of two items and maybe socket-address items, now and then malformed."""
        rng = self.rng
        extra = [self.sockaddr_item() for _ in range(self.pick(0, 0, 0, 0, 1, 2))]
        parts = [struct.pack("<HH", *(first[0], len(first[1]))) + first[1],
                 struct.pack("<HH", *(second[0], len(second[1]))) + second[1], *extra]
        count = len(parts)
        roll = rng.random()
        if roll < 0.03:
            count = rng.getrandbits(16)
        elif roll < 0.06:
            parts.reverse()
        elif roll < 0.08:
            parts.append(self.raw(1, 4))
        return U16.pack(count) + b"".join(parts)

    def body(self, command: int, mirror: SessionMirror, triads: list[tuple[int, int, int]]) -> bytes:
        rng = self.rng
        if command == REGISTER:
            return b"\x01\x00\x00\x00" if rng.random() < 0.9 else self.raw(0, 6)
        if command == SEND_RR_DATA:
            head = struct.pack("<IH", 0 if rng.random() < 0.9 else rng.getrandbits(32), rng.getrandbits(16))
            address = NULL_ADDRESS if rng.random() < 0.97 else self.pick(CONNECTED_ADDRESS, rng.getrandbits(16))
            kind = UNCONNECTED_DATA if rng.random() < 0.97 else self.pick(CONNECTED_DATA, rng.getrandbits(16))
            return head + self.items((address, b""), (kind, self.cip_request(triads)))
        if command == SEND_UNIT_DATA:
            known = list(mirror.connections)  # in the order opened: choices do not depend on the ids drawn
            connection_id = self.pick(*known) if known and rng.random() < 0.9 else rng.getrandbits(32)
            count = self.sequence.get(connection_id, 0)
            count = (count + self.pick(1, 1, 1, 0, 2)) & 0xFFFF  # 0: a retransmission
            self.sequence[connection_id] = count
            return b"\x00\x00\x00\x00\x00\x00" + self.items(
                (CONNECTED_ADDRESS, U32.pack(connection_id)), (CONNECTED_DATA, U16.pack(count)
                                                               + self.cip_request(triads)))
        return b"" if rng.random() < 0.8 else self.raw(1, 8)

    def frame(self, mirror: SessionMirror, triads: list[tuple[int, int, int]]) -> bytes:
        """One frame; the command, handle, length and options mostly right, each sometimes not."""
        rng = self.rng
        roll = rng.random()
        if not mirror.handle and roll < 0.5:
            command = REGISTER  # a client registers first
        elif roll < 0.55:
            command = SEND_RR_DATA
        elif roll < 0.75:
            command = SEND_UNIT_DATA if mirror.connections or rng.random() < 0.2 else SEND_RR_DATA
        elif roll < 0.95:
            command = self.pick(*COMMANDS)
            if command == UNREGISTER and rng.random() < 0.8:
                command = SEND_RR_DATA  # an UnregisterSession ends the stream: keep most streams going
        else:
            command = rng.getrandbits(16)
        body = self.body(command, mirror, triads)
        handle = mirror.handle if rng.random() < 0.9 else self.pick(0, 1, mirror.handle + 1, rng.getrandbits(32))
        options = 0 if rng.random() < 0.97 else rng.getrandbits(32)
        length = len(body)
        roll = rng.random()
        if roll < 0.003:
            length = rng.randint(MAX_LENGTH + 1, 0xFFFF)  # oversize: read whole and refused, the stream goes on
            body += bytes(length - len(body))
        elif roll < 0.02:
            length = rng.randint(0, len(body) + 8)  # the framing slips
        frame = HEADER.pack(command & 0xFFFF, length, handle, 0 if rng.random() < 0.95 else rng.getrandbits(32),
                            rng.randbytes(8), options) + body
        if rng.random() < 0.01:  # a flipped byte
            at = rng.randrange(len(frame))
            frame = frame[:at] + bytes((frame[at] ^ (1 << rng.randrange(8)),)) + frame[at + 1 :]
        return frame


TRIADS = [(serial, 0x1234, 0xABCD) for serial in range(1, 5)]


class SessionRun:
    """One TCP connection's worth of fuzzing: generated frames fed to a session in random cuts,
    every reply checked by a `SessionMirror`; now and then the device's timer turned and its T->O
    packets checked. `inputs` counts the frames fed."""

    def __init__(self, rng: random.Random, device: Device, now: int, max_depth: int = 3,
                 peer_host: str = "127.0.0.9") -> None:
        self.rng = rng
        self.device = device
        self.session = EncapsulationSession(device, peer_host)
        self.mirror = SessionMirror()
        profile = device.profile
        self.generator = FrameGenerator(rng, (profile.vendor_id, profile.device_type, profile.product_code,
                                              *profile.revision), max_depth)
        self.now = now
        self.inputs = 0

    def feed(self, data: bytes) -> None:
        """`receive` the data, with a limit on the frames handled per call now and then (as the
        server takes turns between connections), then the backlog until none is left."""
        limit = None if self.rng.random() < 0.6 else self.rng.randint(1, 3)
        while True:
            replies = self.session.receive(data, self.now, limit)
            taken = self.mirror.feed(data, replies, limit)
            expect(self.session.closing == self.mirror.closed, "the session and the mirror disagree on closing")
            expect(self.session.backlog == self.mirror.backlog, "the session and the mirror disagree on the backlog")
            expect(not taken or self.session.last_frame_at == self.now, "last_frame_at not the time of the frame")
            if not self.session.backlog:
                return
            data = b""

    def run(self, frames: int) -> None:
        rng = self.rng
        pending = b""
        for _ in range(frames):
            if self.mirror.closed:
                break
            pending += self.generator.frame(self.mirror, TRIADS)
            self.inputs += 1
            while pending and rng.random() < 0.7:  # a cut anywhere, or all of it
                cut = len(pending) if rng.random() < 0.6 else rng.randint(1, len(pending))
                self.feed(pending[:cut])
                pending = pending[cut:]
                if self.mirror.closed:
                    break
            self.tick()
        if pending and not self.mirror.closed:
            self.feed(pending)
        self.close()

    def tick(self) -> None:
        rng = self.rng
        self.now += self.generator.pick(0, 1_000, MS, 10 * MS, 100 * MS, 2_000 * MS)
        if rng.random() < 0.2:
            check_service_io(self.device, self.now)

    def close(self) -> None:
        self.session.connection_lost(self.now)
        session = self.session
        expect(all(c.owner is not session for c in self.device.connections.values()),
               "a class-3 connection outlived its TCP connection")


def check_service_io(device: Device, now: int) -> None:
    """Turn the device's timer: no connection is past its deadline afterwards, and every T->O packet
    is well-formed and belongs to an open connection's stream."""
    sent: list[tuple[bytes, tuple[str, int]]] = []
    device.service_io(now, lambda data, address: sent.append((data, address)))
    connections = device.connections.values()
    streams = {(c.t_o_id, c.t_o_address) for c in connections if c.is_io}
    for packet, address in sent:
        connection_id = check_io_packet(packet)[0]
        expect((connection_id, address) in streams, "a T->O packet for a connection that is not open")
    expect(all(c.deadline > now for c in connections), "a connection past its deadline after the timer")


# -- the connection table ----------------------------------------------------------------------------


HOSTS = ("127.0.0.9", "127.0.0.10", "10.0.0.1")  # source addresses handed to the table in-process, never sent to
OWNER, INPUT_ONLY, LISTEN_ONLY = ConnectionKind.EXCLUSIVE_OWNER, ConnectionKind.INPUT_ONLY, ConnectionKind.LISTEN_ONLY


def expected_status(table: ConnectionTable) -> int:
    """Identity status (Vol. 1, 5-2.4): bit 0 owned; extended status 3 (no I/O), 6 (run), 7 (idle)."""
    io = [c for c in table.connections.values() if c.kind is not ConnectionKind.EXPLICIT]
    if not io:
        return 0x0030
    owned = any(c.kind is OWNER for c in io)
    return int(owned) | (0x0060 if any(c.run for c in io) else 0x0070)


class TableFuzzer:
    """Random operations on one connection table with a monotonic injected clock; `step()` does one
    and checks the invariants after it. `inputs` counts the operations."""

    def __init__(self, rng: random.Random) -> None:
        self.rng = rng
        self.output_size = rng.choice((0, 1, 2, 8, 32))
        self.input_size = rng.choice((0, 1, 2, 8, 32))
        assemblies = {"output": AssemblyInstance(100, self.output_size, True),
                      "input": AssemblyInstance(101, self.input_size, False),
                      "configuration": AssemblyInstance(1, 0, True)}
        policy = ConnectionPolicy(
            rpi_min_us=2_000, rpi_max_us=10_000_000, max_class1_connections=rng.randint(1, 6),
            max_class3_connections=rng.randint(0, 3), outputs_off_on_idle=rng.random() < 0.5,
            outputs_off_on_fault=rng.random() < 0.5, first_watchdog_ns=rng.choice((0, 50 * MS, 10_000 * MS)),
            input_only_point=198, listen_only_point=199, multicast_group="239.192.1.0")
        self.table = ConnectionTable(assemblies, policy, lambda: KeyIdentity(75, 7, 1030, (1, 1)),
                                     rng=random.Random(rng.getrandbits(32)))
        self.generator = FrameGenerator(rng, (75, 7, 1030, 1, 1))
        self.sessions = [object(), object()]
        self.now = rng.getrandbits(40)
        self.inputs = 0
        self.closed: set[int] = set()  # O->T ids of connections that closed (ids are never reused)
        self.sequences: dict[tuple[int, tuple[str, int]], tuple[object, int]] = {}  # stream -> last sequence
        self.operations: dict[str, int] = {}
        self.ports = rng.random() < 0.9  # the device always says the source port; a unit test may not

    def step(self) -> None:
        rng = self.rng
        roll = rng.random()
        self.inputs += 1
        if roll < 0.2:
            self.forward_open()
        elif roll < 0.55:
            self.datagram()
        elif roll < 0.62:
            self.count("forward close")
            self.table.forward_close(ConnectionTriad(*self.generator.pick(*TRIADS)), self.now)
        elif roll < 0.65:
            self.count("session closed")
            self.table.session_closed(self.generator.pick(*self.sessions), self.now)
        elif roll < 0.7:
            self.count("connected")
            self.connected()
        else:
            self.timer()
        self.check()

    def count(self, operation: str) -> None:
        self.operations[operation] = self.operations.get(operation, 0) + 1

    def forward_open(self) -> None:
        rng, pick = self.rng, self.generator.pick
        f = self.generator.forward_open_fields(TRIADS, self.output_size, self.input_size)

        def parameters(direction: str) -> NetworkParameters:
            connection_type = f[f"{direction}_type"]
            return NetworkParameters(rng.random() < 0.02, ConnectionType(connection_type) if connection_type < 3 else 3,
                                     f[f"{direction}_priority"], f[f"{direction}_variable"],
                                     f[f"{direction}_size"] & (0xFFFF if f["large"] else 0x1FF))

        request = ForwardOpenRequest(
            0x0A, 0x0E, f["o_t_id"], f["t_o_id"], ConnectionTriad(*f["triad"]), f["multiplier"], f["o_t_rpi"],
            parameters("o_t"), f["t_o_rpi"], parameters("t_o"), f["transport"], f["path"], f["large"])
        sockaddr = None
        if rng.random() < 0.3:
            sockaddr = SocketAddress(pick("0.0.0.0", "127.0.0.9", "127.0.0.10"), pick(0, 2222, 2223), pick(2, 2, 23))
        originator = Originator(pick(*HOSTS), sockaddr, pick(*self.sessions))
        result = self.table.forward_open(request, originator, self.now)  # type: ignore[arg-type]
        self.count(f"forward open {'opened' if hasattr(result, 'connection') else 'refused'}")
        if hasattr(result, "connection"):
            connection = result.connection
            expect(connection.o_t_id not in self.closed, "a connection id used again")
            expect(self.table.connections.get(connection.o_t_id) is connection, "an opened connection not in the table")

    def datagram(self) -> None:
        rng, pick = self.rng, self.generator.pick
        io = [c for c in self.table.connections.values() if c.is_io]
        if rng.random() < 0.1:
            data, host = self.generator.raw(0, 40), pick(*HOSTS)
            connection = None
        else:
            connection = pick(*io) if io and rng.random() < 0.9 else None
            connection_id = connection.o_t_id if connection else pick(rng.getrandbits(32), *self.closed or {0})
            last = connection.last_sequence if connection and connection.last_sequence is not None else 0
            sequence = (last + pick(1, 1, 1, 2, 0, -1, 0x7FFFFFFF, 0x80000000)) & 0xFFFFFFFF
            run_idle = U32.pack(pick(1, 1, 0, 3))
            image = rng.randbytes(pick(self.output_size, self.output_size, 0, self.output_size + 1, 1))
            payload = pick(run_idle + image, run_idle + image, b"", run_idle, image)
            data = struct.pack("<HHHIIHHH", 2, 0x8002, 8, connection_id, sequence, 0x00B1, 2 + len(payload),
                               sequence & 0xFFFF) + payload
            host = connection.originator_host if connection and rng.random() < 0.9 else pick(*HOSTS)
        port = pick(2222, 2222, 2222, 50000, 50001) if self.ports else None
        before = bytes(self.table.assemblies["output"].data)
        first_port = connection.o_t_port if connection else None
        taken = self.table.receive_datagram(data, host, self.now, port)
        self.count(f"datagram {'taken' if taken else 'dropped'}")
        if taken:
            decoded = reference_decode_io_packet(data)
            expect(decoded is not None, "a malformed datagram taken")
            assert decoded is not None
            owner = self.table.connections.get(decoded[0])
            expect(owner is not None and owner.originator_host == host and owner.last_received == self.now,
                   "a datagram taken for no open connection of that originator")
            expect(first_port is None or port is None or port == first_port, "O->T taken from another port")
            expect(owner is None or port is None or owner.o_t_port == port, "O->T port not kept")
        else:
            expect(bytes(self.table.assemblies["output"].data) == before, "a dropped datagram changed the outputs")

    def connected(self) -> None:
        rng = self.rng
        explicit = [c for c in self.table.connections.values() if not c.is_io]
        connection_id = (self.generator.pick(*explicit).o_t_id if explicit and rng.random() < 0.8
                         else rng.getrandbits(32))
        session = self.generator.pick(*self.sessions)
        found = self.table.receive_connected(connection_id, session, self.now)
        if found is not None:
            expect(not found.is_io and found.owner is session and found.last_received == self.now,
                   "a class-3 request taken for a connection that is not the session's")

    def timer(self) -> None:
        rng, table = self.rng, self.table
        self.now += self.generator.pick(0, 1, 1_000, MS, 2 * MS, 10 * MS, 100 * MS, 1_000 * MS, 20_000 * MS)
        if rng.random() < 0.3:
            return
        turn = rng.random()
        if turn < 0.8:
            self.count("handle_timer")
            table.handle_timer(self.now)
            expect(all(c.deadline > self.now for c in table.connections.values()),
                   "a connection past its deadline after handle_timer")
        if turn > 0.2:
            self.count("datagrams_to_send")
            streams = {(c.t_o_id, c.t_o_address) for c in table.connections.values() if c.is_io}
            image = bytes(table.assemblies["input"].data)
            for packet, address in table.datagrams_to_send(self.now):
                connection_id, sequence, sequence_count, data = check_io_packet(packet)
                key = (connection_id, address)
                expect(key in streams, "a T->O packet for a closed connection")
                expect(sequence_count == sequence & 0xFFFF and data == image, "T->O packet contents")
                production = table.productions[key]
                previous = self.sequences.get(key)
                expect(previous is None or previous[0] is not production or sequence > previous[1],
                       "T->O sequence went back")
                self.sequences[key] = (production, sequence)
        if 0.2 < turn < 0.8:  # both turned: nothing is due any more
            timer = table.get_timer()
            expect(timer is None or timer > self.now, "get_timer() not after now with everything handled")

    def check(self) -> None:
        table = self.table
        for event in table.pop_events():
            if isinstance(event, ConnectionEnded):
                self.closed.add(event.connection.o_t_id)
        connections = table.connections
        expect(all(key == c.o_t_id and not c.closed and key not in self.closed for key, c in connections.items()),
               "a closed or misfiled connection in the table")
        expect(all(table.find(c.triad) is c for c in connections.values()), "triad index out of step")
        expect(len({c.triad for c in connections.values()}) == len(connections), "two connections share a triad")
        expect(table.status == expected_status(table), f"Identity status 0x{table.status:04X} "
               f"with {sorted(c.kind.value for c in connections.values())}")
        expect(table.assemblies["output"].owned == any(c.kind is OWNER for c in connections.values()),
               "output ownership out of step with the connections")
        expect(len(table.assemblies["output"].data) == self.output_size, "the output image changed size")
        expect(len(table.assemblies["input"].data) == self.input_size, "the input image changed size")
        users: dict[tuple[int, tuple[str, int]], int] = {}
        for c in connections.values():
            if c.is_io:
                expect(c.t_o_address == ("239.192.1.0", 2222) if c.multicast else c.t_o_address[0] == c.originator_host,
                       f"T->O to {c.t_o_address} for an originator at {c.originator_host}")
                key = (c.t_o_id, c.t_o_address)
                users[key] = users.get(key, 0) + 1
        expect({key: p.users for key, p in table.productions.items()} == users,
               "T->O streams out of step with the connections")


def run_table(rng: random.Random, steps: int) -> TableFuzzer:
    fuzzer = TableFuzzer(rng)
    for _ in range(steps):
        fuzzer.step()
    return fuzzer

