"""The baseline for bench_explicit.py: the least a responder can do on uvloop.

It frames the stream with struct, answers RegisterSession with handle 1 and every SendRRData with
a fixed Get or Set Attribute Single reply (chosen by the service byte), echoing the sender context.
No sessions, no paths, no objects: the cost of Python + uvloop + the socket, nothing more.
"""

from __future__ import annotations

import asyncio
import struct
import sys

import uvloop

HEADER = struct.Struct("<HHII8sI")
CPF = struct.pack("<IHHHHH", 0, 0, 2, 0, 0, 0xB2)


class Responder(asyncio.Protocol):
    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport
        self.buffer = b""

    def data_received(self, data: bytes) -> None:
        buffer = self.buffer + data
        out = []
        offset = 0
        while len(buffer) - offset >= 24:
            command, length, session, _status, context, _options = HEADER.unpack_from(buffer, offset)
            end = offset + 24 + length
            if end > len(buffer):
                break
            if command == 0x65:
                out.append(HEADER.pack(0x65, 4, 1, 0, context, 0) + b"\x01\x00\x00\x00")
            elif command == 0x6F:
                service = buffer[offset + 40]
                cip = b"\x8e\x00\x00\x00\x00\x00" if service == 0x0E else bytes((service | 0x80, 0, 0, 0))
                body = CPF + struct.pack("<H", len(cip)) + cip
                out.append(HEADER.pack(0x6F, len(body), session, 0, context, 0) + body)
            offset = end
        self.buffer = buffer[offset:]
        if out:
            self.transport.write(b"".join(out))


async def main(host: str, port: int) -> None:
    server = await asyncio.get_running_loop().create_server(Responder, host, port, reuse_address=True)
    print("listening", flush=True)
    await server.serve_forever()


if __name__ == "__main__":
    uvloop.run(main(sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 44818))
