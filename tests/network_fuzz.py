"""Fuzzing a running farm over the network (TCP and UDP 44818 and UDP 2222 on loopback) while
class-1 connections run on other devices of the same farm. Shared by tests/test_network_fuzz.py
(about 25 s in CI) and bench/network_fuzz.py (millions of frames).

- `TcpFuzzer`: one stream of structure-aware frames (tests/fuzzing.py's `FrameGenerator`: every
  encapsulation command, CPF items, CIP services and paths, Forward Open/Close with their RPI,
  multiplier, sizes, transport class and connection types mutated) sent to a device; every reply is
  held by an independent `SessionMirror` to the frame that asked for it, and an explicit prober's
  latency is measured on a clean connection beside it. A stream the mirror says ends must be closed
  by the farm; the fuzzer then opens another.
- `mutated_datagram`: class-1 packets (valid ones with a field changed, truncated or extended, or
  random bytes) for UDP 2222, and random datagrams for UDP 44818.
- `Class1Originator`: exclusive-owner connections on the other devices, O->T on absolute deadlines,
  T->O stamped by the kernel (SO_TIMESTAMPNS), so that its own scheduling does not count.

Everything is seeded: one `random.Random(seed)` per stream, so a failing seed replays its stream.
Traffic goes to 127.0.0.0/8 only; every loop is bounded in count and time.
"""

from __future__ import annotations

import copy
import random
import select
import socket
import statistics
import struct
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import httpx
import yaml

from enip_farm.protocol.cip import decode_reply, encode_request
from enip_farm.protocol.commands import SocketAddress, decode_send_data, encode_send_data, encode_sockaddr
from enip_farm.protocol.connection import (
    ConnectionTriad,
    ConnectionType,
    ForwardCloseRequest,
    ForwardOpenRequest,
    NetworkParameters,
    decode_forward_open_reply,
    encode_forward_close,
    encode_forward_open,
    encode_io_packet,
)
from enip_farm.protocol.cpf import ItemType
from enip_farm.protocol.epath import encode_request_path
from tests.fuzzing import HEADER, TRIADS, FrameGenerator, Malformed, SessionMirror
from tests.helpers import serving, wait_for

ENIP_PORT, IO_PORT = 44818, 2222
ASSEMBLY_PATH = bytes.fromhex("20 04 24 01 2C 64 2C 65")  # DSQC1030: config 1, O->T 100, T->O 101
REPLY_WAIT_S = 10.0  # a reply later than this is a failure (generous for a loaded machine)
DRAIN_WAIT_S = 10.0  # at most this long for the farm to read what was sent before it is counted
_SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)
_REGISTER = HEADER.pack(0x65, 4, 0, 0, b"prober\0\0", 0) + b"\x01\x00\x00\x00"


class FuzzFailure(AssertionError):
    """A reply the mirror refused, a reply missing, or a stream not closed: with the seed that replays it."""


# -- TCP: structure-aware frames, every reply checked --------------------------------------------------


class TcpFuzzer:
    """Frames from one seeded generator to one device, one at a time; every reply is checked."""

    def __init__(self, host: str, key: tuple[int, int, int, int, int], seed: int) -> None:
        self.host, self.key, self.seed = host, key, seed
        self.rng = random.Random(seed)
        self.frames = self.replies = self.streams = 0
        self._sock: socket.socket | None = None
        self._mirror = SessionMirror()
        self._generator = FrameGenerator(self.rng, key)
        self._buffer = b""

    def _connect(self) -> None:
        deadline = time.monotonic() + REPLY_WAIT_S
        while True:  # a device restarted by an Identity Reset does not listen during its reset window
            try:
                self._sock = socket.create_connection((self.host, ENIP_PORT), timeout=REPLY_WAIT_S)
                break
            except ConnectionRefusedError:
                if time.monotonic() > deadline:
                    raise self._fail("the device did not listen again after its reset window") from None
                time.sleep(0.01)
        self._mirror = SessionMirror()
        self._generator = FrameGenerator(self.rng, self.key)
        self._buffer = b""
        self.streams += 1

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def _fail(self, what: str) -> FuzzFailure:
        return FuzzFailure(f"seed {self.seed}, stream {self.streams}, frame {self.frames}: {what}")

    def step(self, batch: int = 1) -> None:
        """Send `batch` frames back to back (made from the mirror's state before them) and check
        what comes back for them."""
        if self._sock is None:
            self._connect()
        frames = b"".join(self._generator.frame(self._mirror, TRIADS) for _ in range(batch))
        self.frames += batch
        try:
            self._sock.sendall(frames)  # type: ignore[union-attr]
        except OSError as error:  # the farm may close the stream after a frame that ends it
            if not isinstance(error, (BrokenPipeError, ConnectionResetError)):
                raise self._fail(f"send refused: {error!r}") from None
        replies: list[bytes] = []
        deadline = time.monotonic() + REPLY_WAIT_S
        while True:
            trial = copy.deepcopy(self._mirror)
            try:
                trial.feed(frames, list(replies))
                break
            except Malformed as problem:
                if not str(problem).startswith("no reply") or time.monotonic() > deadline:
                    raise self._fail(f"{problem}; frames {frames.hex()}") from None
            reply = self._read_frame(deadline)
            if reply is None:
                raise self._fail(f"the farm closed the stream where a reply was due; frames {frames.hex()}")
            replies.append(reply)
            while (whole := self._buffered_frame()) is not None:  # the others already read: one trial for all
                replies.append(whole)
        self._mirror = trial
        self.replies += len(replies)
        if trial.closed:  # an UnregisterSession or an Identity Reset: the farm closes
            if self._read_frame(time.monotonic() + REPLY_WAIT_S) is not None:
                raise self._fail("a reply after the stream ended")
            self.close()

    def _buffered_frame(self) -> bytes | None:
        """A whole frame already read, taken from the buffer."""
        if len(self._buffer) >= 24:
            length = struct.unpack_from("<H", self._buffer, 2)[0]
            if len(self._buffer) >= 24 + length:
                frame, self._buffer = self._buffer[: 24 + length], self._buffer[24 + length :]
                return frame
        return None

    def _read_frame(self, deadline: float) -> bytes | None:
        """One whole encapsulation frame from the stream; None when the farm closed it."""
        sock = self._sock
        assert sock is not None
        while True:
            frame = self._buffered_frame()
            if frame is not None:
                return frame
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise self._fail("no reply within the wait")
            sock.settimeout(remaining)
            try:
                chunk = sock.recv(65536)
            except TimeoutError:
                continue
            except ConnectionResetError:
                return None
            if not chunk:
                return None
            self._buffer += chunk


class Prober:
    """An explicit client on a clean registered connection: Get_Attribute_Single of the Identity's
    product name, its latency and its bytes checked."""

    def __init__(self, host: str) -> None:
        self.sock = socket.create_connection((host, ENIP_PORT), timeout=REPLY_WAIT_S)
        self.sock.sendall(_REGISTER)
        self.handle = struct.unpack_from("<I", _recv_frame(self.sock), 4)[0]

    def probe(self) -> float:
        """Seconds from the request to its whole reply."""
        request = encode_request(0x0E, encode_request_path(1, 1, 7))
        body = encode_send_data([(ItemType.NULL_ADDRESS, b""), (ItemType.UNCONNECTED_DATA, request)])
        frame = HEADER.pack(0x6F, len(body), self.handle, 0, b"probe\0\0\0", 0) + body
        started = time.perf_counter()
        self.sock.sendall(frame)
        reply = _recv_frame(self.sock)
        elapsed = time.perf_counter() - started
        answer = decode_reply(decode_send_data(reply[24:]).items[1].data)
        if struct.unpack_from("<I", reply, 8)[0] != 0 or answer.general_status != 0 or answer.data != b"\x08DSQC1030":
            raise FuzzFailure(f"the prober's reply is wrong: {reply.hex()}")
        return elapsed

    def close(self) -> None:
        self.sock.close()


def _recv_frame(sock: socket.socket) -> bytes:
    data = b""
    while len(data) < 24 or len(data) < 24 + struct.unpack_from("<H", data, 2)[0]:
        chunk = sock.recv(65536)
        if not chunk:
            raise FuzzFailure("the prober's connection was closed")
        data += chunk
    return data


# -- UDP: class-1 datagrams and discovery ---------------------------------------------------------------


def mutated_datagram(rng: random.Random, connection_ids: list[int]) -> bytes:
    """A class-1 O->T packet with something wrong (or random bytes): never one a running connection
    would take from this sender (it comes from another host than any originator)."""
    roll = rng.random()
    if roll < 0.15:
        return rng.randbytes(rng.randint(0, 64))
    connection_id = rng.choice(connection_ids) if connection_ids and rng.random() < 0.6 else rng.getrandbits(32)
    sequence = rng.getrandbits(32)
    data = rng.choice((b"\x01\x00\x00\x00\x00\x00", b"", b"\x01\x00\x00\x00", rng.randbytes(rng.randint(0, 40))))
    packet = bytearray(encode_io_packet(connection_id, sequence, sequence & 0xFFFF, data))
    mutation = rng.random()
    if mutation < 0.2 and packet:  # a field of the header changed: count, item types, lengths
        at = rng.randrange(min(len(packet), 18))
        packet[at] = rng.getrandbits(8)
    elif mutation < 0.35:
        del packet[rng.randrange(len(packet)) :]  # truncated
    elif mutation < 0.45:
        packet += rng.randbytes(rng.randint(1, 16))  # extended
    return bytes(packet)


# -- the class-1 connections that must keep running -------------------------------------------------------


@dataclass
class Stream:
    """One exclusive-owner connection of the originator, and what it saw."""

    host: str
    triad: ConnectionTriad
    o_t_id: int
    t_o_id: int
    sequence: int = 0
    arrivals: list[int] = field(default_factory=list)  # kernel receive times of T->O, ns


class Class1Originator:
    """Exclusive-owner connections to DSQC1030s at one RPI: O->T on absolute deadlines from its own
    thread, T->O taken with the kernel's receive time."""

    def __init__(self, hosts: list[str], rpi_us: int, multiplier: int, source: str = "127.0.0.1") -> None:
        self.rpi_us, self.multiplier = rpi_us, multiplier
        self.udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.udp.bind((source, 0))
        self.udp.setsockopt(socket.SOL_SOCKET, _SO_TIMESTAMPNS, 1)
        self.udp.setblocking(False)
        self.streams = [self._open(host, serial) for serial, host in enumerate(hosts, start=0x4000)]
        self._by_t_o = {stream.t_o_id: stream for stream in self.streams}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="class-1 originator", daemon=True)
        self.started_ns = self.stopped_ns = 0
        self.late_sends = 0  # O->T sent more than one RPI after its deadline (the originator's own lateness)

    def _open(self, host: str, serial: int) -> Stream:
        triad = ConnectionTriad(serial, 0x1234, 0x0F0F0F0F)
        request = ForwardOpenRequest(0x0A, 0x0E, 0, serial, triad, self.multiplier, self.rpi_us,
                                     NetworkParameters(False, ConnectionType.POINT_TO_POINT, 2, False, 8), self.rpi_us,
                                     NetworkParameters(False, ConnectionType.POINT_TO_POINT, 2, False, 4), 0x01,
                                     ASSEMBLY_PATH)
        port = self.udp.getsockname()[1]
        reply = _explicit(host, encode_request(0x54, encode_request_path(6, 1), encode_forward_open(request)),
                          [(ItemType.SOCKADDR_T_O, encode_sockaddr(SocketAddress("0.0.0.0", port)))])
        if reply.general_status != 0:
            raise FuzzFailure(f"{host}: Forward Open refused: {reply}")
        opened = decode_forward_open_reply(reply.data)
        return Stream(host, triad, opened.o_t_connection_id, opened.t_o_connection_id)

    def start(self) -> None:
        self.started_ns = time.monotonic_ns()
        self._thread.start()

    def stop_sending(self) -> None:
        """Stop sending O->T (each stream's `sequence` is then the count it sent)."""
        self._stop.set()
        self._thread.join(10)
        self.stopped_ns = time.monotonic_ns()

    def close(self) -> list[int]:
        """Forward Close every connection: the general statuses (0x01 = the farm had timed it out, a
        spurious timeout). Call it once the farm has taken every O->T sent (`stop_sending`): a
        datagram it reads after the close is one for an unknown connection."""
        statuses = []
        for stream in self.streams:
            close = encode_forward_close(ForwardCloseRequest(0x0A, 0x0E, stream.triad, ASSEMBLY_PATH))
            statuses.append(_explicit(stream.host, encode_request(0x4E, encode_request_path(6, 1), close))
                            .general_status)
        self.udp.close()
        return statuses

    def _run(self) -> None:
        period = self.rpi_us * 1000
        due = time.monotonic_ns()
        poller = select.poll()
        poller.register(self.udp, select.POLLIN)
        while not self._stop.is_set():
            now = time.monotonic_ns()
            if now >= due:
                if now - due > period:
                    self.late_sends += 1
                for stream in self.streams:
                    stream.sequence += 1
                    packet = encode_io_packet(stream.o_t_id, stream.sequence, stream.sequence & 0xFFFF,
                                              b"\x01\x00\x00\x00" + struct.pack("<H", stream.sequence & 0xFFFF))
                    self.udp.sendto(packet, (stream.host, IO_PORT))
                due += period * max(1, (now - due) // period + 1)
            poller.poll(max(0.0, (due - time.monotonic_ns()) / 1e6))
            self._drain()

    def _drain(self) -> None:
        while True:
            try:
                data, ancillary, _, _ = self.udp.recvmsg(2048, 64)
            except (BlockingIOError, InterruptedError):
                return
            stamp = next((struct.unpack("qq", d[:16]) for level, kind, d in ancillary
                          if level == socket.SOL_SOCKET and kind == _SO_TIMESTAMPNS), None)
            if len(data) < 10:
                continue
            stream = self._by_t_o.get(struct.unpack_from("<I", data, 6)[0])
            if stream is not None and stamp is not None:
                stream.arrivals.append(stamp[0] * 1_000_000_000 + stamp[1])


def _explicit(host: str, request: bytes, extra_items: list | None = None):
    """One unconnected request on its own registered connection: the Message Router reply."""
    with socket.create_connection((host, ENIP_PORT), timeout=REPLY_WAIT_S) as sock:
        sock.sendall(_REGISTER)
        handle = struct.unpack_from("<I", _recv_frame(sock), 4)[0]
        body = encode_send_data([(ItemType.NULL_ADDRESS, b""), (ItemType.UNCONNECTED_DATA, request),
                                 *(extra_items or [])])
        sock.sendall(HEADER.pack(0x6F, len(body), handle, 0, bytes(8), 0) + body)
        reply = _recv_frame(sock)
    return decode_reply(decode_send_data(reply[24:]).items[1].data)


def period_errors_ms(stream: Stream, rpi_us: int, skip_ns: int = 0) -> list[float]:
    """|interval - RPI| of consecutive T->O arrivals, ms (arrivals before `skip_ns` left out)."""
    arrivals = [t for t in stream.arrivals if t >= skip_ns]
    return [abs((b - a) / 1e6 - rpi_us / 1000) for a, b in zip(arrivals, arrivals[1:], strict=False)]


def percentile(values: list[float], fraction: float) -> float:
    if not values:
        return float("nan")
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(fraction * len(ordered)))]


def summary(values: list[float]) -> str:
    return (f"p50 {statistics.median(values):.2f} ms, p99 {percentile(values, 0.99):.2f} ms, "
            f"max {max(values):.2f} ms" if values else "none")


# -- one run: a farm in a subprocess, the fuzzers, the class-1 originator, the prober -------------------

KEY = (75, 7, 1030, 1, 1)  # the DSQC1030's identity as the catalogue gives it (placeholders, unverified)


@dataclass
class Report:
    """What one run did and saw."""

    seed: int
    seconds: float = 0.0
    frames: int = 0
    streams: int = 0
    replies: int = 0
    datagrams: int = 0
    datagrams_to_cyclic: int = 0  # to UDP 2222 of the devices whose connections run
    latencies_ms: list[float] = field(default_factory=list)
    originator: Class1Originator | None = None
    close_statuses: list[int] = field(default_factory=list)
    health: dict = field(default_factory=dict)
    cyclic_counters: dict[str, dict[str, int]] = field(default_factory=dict)
    farm_alive: bool = False
    farm_log: str = ""

    def lines(self) -> list[str]:
        out = [f"seed {self.seed}: {self.frames} frames in {self.streams} TCP streams, {self.replies} replies "
               f"checked, {self.datagrams} datagrams, in {self.seconds:.1f} s ({self.frames / self.seconds:.0f} "
               f"frames/s)", f"explicit prober: {len(self.latencies_ms)} probes, {summary(self.latencies_ms)}"]
        originator = self.originator
        if originator is not None:
            expected = (originator.stopped_ns - originator.started_ns) / (originator.rpi_us * 1000)
            for stream in originator.streams:
                out.append(f"class-1 {stream.host}: {len(stream.arrivals)} T->O of {expected:.0f} expected, period "
                           f"error {summary(period_errors_ms(stream, originator.rpi_us))}")
        out.append(f"Forward Close statuses {self.close_statuses}; health {self.health}")
        return out


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _counters(api: str, name: str) -> dict[str, int]:
    return httpx.get(f"{api}/devices/{name}", timeout=10).json()["counters"]


def _dropped(api: str, names: dict[str, str]) -> int:
    """O->T datagrams not taken (every reason) by these devices."""
    return sum(v for name in names for k, v in _counters(api, name).items() if k.startswith("o_t_dropped_"))


def fuzz_farm(workdir: Path, addresses: list[str], seconds: float, seed: int, max_frames: int = 10_000_000,
              batches: tuple[int, ...] = (1, 1, 2, 8), rpi_us: int = 20_000, multiplier: int = 5) -> Report:
    """Serve five DSQC1030s (`addresses`: two fuzzed, three with class-1 connections) with
    `enip-farm serve`, fuzz them for `seconds` (or `max_frames`), and report."""
    rng = random.Random(seed)
    fuzzed = {f"f{i}": address for i, address in enumerate(addresses[:2], start=1)}
    cyclic = {f"c{i}": address for i, address in enumerate(addresses[2:5], start=1)}
    devices = [{"name": name, "model": "DSQC1030", "address": address, "reset_time_s": 0.05}
               for name, address in fuzzed.items()]
    devices += [{"name": name, "model": "DSQC1030", "address": address} for name, address in cyclic.items()]
    (workdir / "cell.yaml").write_text(yaml.safe_dump({"devices": devices, "discovery": False}))
    port = _free_port()
    log = workdir / "farm.log"
    report = Report(seed)
    with log.open("w") as stderr, serving(["serve", "--config", str(workdir / "cell.yaml"), "--http",
                                           f"127.0.0.1:{port}"], len(devices), stderr=stderr) as (farm, _):
        api = f"http://127.0.0.1:{port}"
        originator = report.originator = Class1Originator(list(cyclic.values()), rpi_us, multiplier)
        originator.start()
        fuzzers = [TcpFuzzer(address, KEY, rng.getrandbits(32)) for address in fuzzed.values()]
        noise = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        noise.bind(("127.0.0.2", 0))  # another host than the originator's: its datagrams are never taken
        prober = Prober(cyclic["c1"])
        connection_ids = [s.o_t_id for s in originator.streams]
        started = time.monotonic()
        deadline = started + seconds
        step = 0
        try:
            while time.monotonic() < deadline and report.frames < max_frames:
                fuzzer = fuzzers[step % len(fuzzers)]
                before = fuzzer.frames
                fuzzer.step(rng.choice(batches))
                report.frames += fuzzer.frames - before
                step += 1
                if step % 20 == 0:
                    for _ in range(5):
                        name, address = rng.choice([*fuzzed.items(), *cyclic.items()])
                        udp_port = rng.choice((IO_PORT, IO_PORT, ENIP_PORT))
                        datagram = (mutated_datagram(rng, connection_ids) if udp_port == IO_PORT
                                    else rng.randbytes(rng.randint(0, 40)))
                        noise.sendto(datagram, (address, udp_port))
                        report.datagrams += 1
                        report.datagrams_to_cyclic += name in cyclic and udp_port == IO_PORT
                if step % 25 == 0:
                    report.latencies_ms.append(prober.probe() * 1000)
        finally:
            report.seconds = time.monotonic() - started
            for fuzzer in fuzzers:
                fuzzer.close()
            noise.close()
            prober.close()
            originator.stop_sending()
            # the farm reads UDP on its cyclic I/O thread and Forward Close on its event loop: close
            # once every O->T sent is taken (its count), so that no late one meets a closed connection
            sent = {name: stream.sequence for name, stream in zip(cyclic, originator.streams, strict=True)}
            wait_for(lambda: all(_counters(api, name)["o_t_packets"] >= count for name, count in sent.items()),
                     timeout=DRAIN_WAIT_S)
            report.close_statuses = originator.close()
            report.streams = sum(f.streams for f in fuzzers)
            report.replies = sum(f.replies for f in fuzzers)
        report.health = httpx.get(api + "/health", timeout=10).json()
        # every datagram sent to UDP 2222 of those devices is read before they are counted
        wait_for(lambda: _dropped(api, cyclic) >= report.datagrams_to_cyclic, timeout=DRAIN_WAIT_S)
        for name in cyclic:
            report.cyclic_counters[name] = _counters(api, name)
        report.farm_alive = farm.poll() is None
    report.farm_log = log.read_text()
    return report
