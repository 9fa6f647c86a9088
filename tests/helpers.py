"""Test helpers: loopback address allocation, a raw client built on the project's own codec,
bounded reads of a subprocess's output (a test never blocks on a pipe without a deadline) and the
one bounded wait for a condition."""

from __future__ import annotations

import os
import selectors
import shutil
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO

import pytest
from prometheus_client.parser import text_string_to_metric_families

from enip_farm.protocol.cip import MessageRouterReply, decode_reply, encode_request
from enip_farm.protocol.commands import decode_send_data, encode_send_data
from enip_farm.protocol.connection import (
    ConnectionTriad,
    ConnectionType,
    ForwardOpenRequest,
    NetworkParameters,
    encode_forward_open,
)
from enip_farm.protocol.cpf import CpfItem, ItemType
from enip_farm.protocol.encapsulation import ENIP_PORT, Command, Frame, StreamFramer, encode_frame
from enip_farm.protocol.epath import encode_request_path

ROOT = Path(__file__).resolve().parent.parent
CLI = [sys.executable, "-m", "enip_farm"]  # the tree under test (conftest puts ROOT on PYTHONPATH)
STARTUP_S = 60.0  # a subprocess's bound to print its table, generous for a loaded machine


def wait_for(predicate: Callable[[], object], timeout: float = 10.0) -> bool:
    """Poll `predicate` until it holds (True at once) or `timeout` seconds pass (its last answer, so
    a condition that became true at the deadline still counts). Use as `assert wait_for(...), what`:
    the timeout only bounds a failing test, a passing one waits no longer than the condition takes."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.005)
    return bool(predicate())


def read_lines(stream: IO[str], count: int, timeout: float = STARTUP_S) -> list[str]:
    """Up to `count` lines from a subprocess pipe; fewer when it closes first (the process exited).
    Raises TimeoutError when the deadline passes first. Reads byte by byte from the descriptor, so
    nothing past the last line is consumed and `communicate()` still gets the rest."""
    deadline = time.monotonic() + timeout
    fd = stream.fileno()
    lines: list[str] = []
    line = bytearray()
    with selectors.DefaultSelector() as selector:
        selector.register(fd, selectors.EVENT_READ)
        while len(lines) < count:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise TimeoutError(f"{len(lines)} of {count} lines within {timeout} s: {lines} {bytes(line)!r}")
            if not selector.select(remaining):
                continue
            byte = os.read(fd, 1)
            if not byte:  # end of file
                if line:
                    lines.append(line.decode())
                break
            line += byte
            if byte == b"\n":
                lines.append(line.decode())
                line.clear()
    return lines


@contextmanager
def serving(args: list[str], table_rows: int, prefix: tuple[str, ...] = (), **popen: object) -> Iterator[
        tuple[subprocess.Popen, list[str]]]:
    """`enip-farm ARGS` (behind `prefix`, e.g. a network namespace) until it has printed its table
    (a header and `table_rows` rows, bounded by STARTUP_S); yields the process and the table. A
    process that exits first fails the test with its stderr. At exit it is killed if still running
    and reaped, within bounds."""
    popen.setdefault("stderr", subprocess.PIPE)  # or a file: a long run's log lines must not fill a pipe
    process = subprocess.Popen([*prefix, *CLI, *args], stdout=subprocess.PIPE, text=True, cwd=ROOT,
                               **popen)  # type: ignore[call-overload]
    try:
        table = read_lines(process.stdout, 1 + table_rows)
        if len(table) < 1 + table_rows:
            _, error = process.communicate(timeout=STARTUP_S)
            raise AssertionError(f"exited {process.returncode} before its table was out: {table} {error}")
        yield process, table
    finally:
        if process.poll() is None:
            process.send_signal(signal.SIGKILL)
        process.communicate(timeout=STARTUP_S)


class RawClient:
    """A blocking TCP client that speaks frames through the project's codec."""

    def __init__(self, host: str, timeout: float = 10.0, source: str | None = None) -> None:
        """`source`: the local address to connect from (an originator of its own, 127.x)."""
        self.sock = socket.create_connection((host, ENIP_PORT), timeout=timeout,
                                             source_address=(source, 0) if source else None)
        self.framer = StreamFramer(max_length=65535)
        self.pending: list[Frame] = []
        self.session_handle = 0

    def close(self) -> None:
        self.sock.close()

    def __enter__(self) -> RawClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def send(self, data: bytes) -> None:
        self.sock.sendall(data)

    def recv_frame(self) -> Frame:
        while not self.pending:
            data = self.sock.recv(65536)
            if not data:
                raise ConnectionError("connection closed by the device")
            self.pending.extend(self.framer.feed(data))  # type: ignore[arg-type]
        return self.pending.pop(0)

    def exchange(self, data: bytes) -> Frame:
        self.send(data)
        return self.recv_frame()

    def is_closed(self, timeout: float = 10.0) -> bool:
        """True when the device has closed the connection (EOF or reset) within the timeout."""
        self.sock.settimeout(timeout)
        try:
            return self.sock.recv(1) == b""
        except ConnectionResetError:
            return True
        except TimeoutError:
            return False

    def register(self) -> int:
        frame = self.exchange(encode_frame(Command.REGISTER_SESSION, b"\x01\x00\x00\x00"))
        assert frame.header.status == 0, frame
        self.session_handle = frame.header.session_handle
        return self.session_handle

    def request(self, message: bytes) -> MessageRouterReply:
        return self.request_items(message)[0]

    def request_items(self, message: bytes, extra_items: list[tuple[int, bytes]] = ()) -> tuple[
            MessageRouterReply, list[CpfItem]]:
        """A request with optional extra CPF items (e.g. 0x8001); the reply and its extra items."""
        items = [(ItemType.NULL_ADDRESS, b""), (ItemType.UNCONNECTED_DATA, message), *extra_items]
        frame = self.exchange(encode_frame(Command.SEND_RR_DATA, encode_send_data(items), self.session_handle))
        assert frame.header.status == 0, frame
        reply_items = decode_send_data(frame.data).items
        return decode_reply(reply_items[1].data), reply_items[2:]

    def get(self, class_id: int, instance_id: int, attribute_id: int | None = None, service: int = 0x0E,
            data: bytes = b"") -> MessageRouterReply:
        return self.request(encode_request(service, encode_request_path(class_id, instance_id, attribute_id), data))

    def set(self, class_id: int, instance_id: int, attribute_id: int, data: bytes) -> MessageRouterReply:
        return self.get(class_id, instance_id, attribute_id, service=0x10, data=data)


def forward_open_message(path: bytes, o_t_size: int, t_o_size: int, rpi: int, serial: int,
                         t_o_multicast: bool = False, transport: int = 0x01, o_t_id: int = 0,
                         t_o_id: int = 0x7E570001, variable: bool = False) -> bytes:
    """A Forward Open request (0x54) to the Connection Manager: O->T point to point, T->O point to
    point or multicast, fixed (or variable) sizes, originator vendor 0x1234 and serial 0xABCD."""
    t_o_type = ConnectionType.MULTICAST if t_o_multicast else ConnectionType.POINT_TO_POINT
    request = ForwardOpenRequest(
        0x0A, 0x0E, o_t_id, t_o_id, ConnectionTriad(serial, 0x1234, 0xABCD), 1, rpi,
        NetworkParameters(False, ConnectionType.POINT_TO_POINT, 2, variable, o_t_size), rpi,
        NetworkParameters(False, t_o_type, 2, False, t_o_size), transport, path)
    return encode_request(0x54, encode_request_path(6, 1), encode_forward_open(request))


def own_network_namespace() -> tuple[str, ...]:
    """A prefix that runs a command in a fresh network namespace with loopback up (root and
    unshare(1) needed), so the default cell's fixed addresses, the wildcard discovery port and port
    8044 never meet a farm already serving on this host; the test is skipped, saying why, where it
    cannot."""
    if not all(shutil.which(tool) for tool in ("unshare", "nsenter", "ip")):
        pytest.skip("unshare, nsenter (util-linux) and ip (iproute2) are needed to serve the default cell in a netns")
    tried = subprocess.run(["unshare", "-n", "ip", "link", "set", "lo", "up"], capture_output=True, text=True,
                           timeout=STARTUP_S)
    if tried.returncode != 0:
        pytest.skip(f"a network namespace is not permitted here (root needed; uid {os.geteuid()}): "
                    f"{tried.stderr.strip()}")
    return ("unshare", "-n", "sh", "-c", 'ip link set lo up && exec "$@"', "sh")


def metric_samples(text: str, name: str) -> dict[tuple[tuple[str, str], ...], float]:
    """The samples called `name` in Prometheus exposition text, parsed by prometheus_client:
    {((label, value), ...) sorted by label: sample value}; {} when there is none."""
    return {tuple(sorted(sample.labels.items())): sample.value
            for family in text_string_to_metric_families(text) for sample in family.samples if sample.name == name}
