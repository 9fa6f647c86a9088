"""Test helpers: loopback address allocation and a raw client built on the project's own codec."""

from __future__ import annotations

import socket

from enip_farm.protocol.cip import MessageRouterReply, decode_reply, encode_request
from enip_farm.protocol.commands import decode_send_data, encode_send_data
from enip_farm.protocol.cpf import CpfItem, ItemType
from enip_farm.protocol.encapsulation import Command, Frame, StreamFramer, encode_frame
from enip_farm.protocol.epath import encode_request_path
from enip_farm.pytest_plugin import free_address

ENIP_PORT = 44818
next_address = free_address  # one allocator for the plugin and the tests


class RawClient:
    """A blocking TCP client that speaks frames through the project's codec."""

    def __init__(self, host: str, timeout: float = 5.0) -> None:
        self.sock = socket.create_connection((host, ENIP_PORT), timeout=timeout)
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

    def is_closed(self, timeout: float = 2.0) -> bool:
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
