"""The TCP side of a farm's devices: each device's listener on TCP 44818 (CIP Networks Library
Vol. 2, 2-2: one per device address) and the encapsulation connections it accepted
(server/tcp.py); listening, stopping, closing a device's connections; and why a socket cannot be
bound, said in words that tell what to do."""

from __future__ import annotations

import asyncio
import errno
import resource
import socket

from enip_farm.device.device import Device
from enip_farm.device.fault_type import Disconnect
from enip_farm.protocol.encapsulation import ENIP_PORT
from enip_farm.server.limits import TcpLimits
from enip_farm.server.tcp import EncapsulationProtocol

#: Sockets per device at rest: a TCP listener, UDP 44818 and UDP 2222; each client connection adds one.
SOCKETS_PER_DEVICE = 3


class BindError(Exception):
    """A device's address or port cannot be bound; the message says which and what to do."""


def raise_open_file_limit() -> int:
    """Raise the soft RLIMIT_NOFILE to the hard limit; return the limit now in force."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft < hard:
        try:
            resource.setrlimit(resource.RLIMIT_NOFILE, (hard, hard))
            soft = hard
        except (ValueError, OSError):
            pass
    return soft


def is_host_address(address: str) -> bool:
    """Whether this host can bind `address` (one of its interfaces', or any 127.x.y.z on Linux):
    a UDP socket bound to its port 0 for a moment, which takes no port anyone uses."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        try:
            probe.bind((address, 0))
        except OSError as error:
            return error.errno != errno.EADDRNOTAVAIL
    return True


def bind_message(device: Device, transport: str, error: OSError, port: int = ENIP_PORT) -> str:
    """Why `device` cannot bind `transport` on `port`, and what to do about it."""
    where = f"device {device.name!r}: cannot bind {transport} {device.profile.address}:{port}"
    if error.errno == errno.EADDRNOTAVAIL:
        return (f"{where}: the address is not assigned to any interface of this host. Add it as an alias, "
                f"e.g. `sudo ip addr add {device.profile.address}/32 dev lo` (every 127.x.y.z address "
                "works on Linux without this).")
    if error.errno == errno.EADDRINUSE:
        return (f"{where}: the port is already in use there (another farm or EtherNet/IP stack?). Stop it "
                f"(`ss -ltunp 'sport = :{port}'` names the process), or give the device an address nothing "
                "serves (on Linux any 127.x.y.z is this host's).")
    if error.errno == errno.EMFILE:
        return (f"{where}: out of file descriptors (limit {resource.getrlimit(resource.RLIMIT_NOFILE)[0]}); "
                f"each device needs {SOCKETS_PER_DEVICE} plus one per client connection. Raise `ulimit -n`.")
    return f"{where}: {error.strerror}"


class Listeners:
    """The devices' TCP listeners by device name, and every connection they accepted."""

    def __init__(self) -> None:
        self.servers: dict[str, asyncio.AbstractServer] = {}
        self.connections: set[EncapsulationProtocol] = set()
        self.tcp_limits: TcpLimits | None = None  # set at start, once the open-file limit is raised

    async def listen(self, device: Device) -> None:
        """Listen on the device's address, TCP 44818; BindError if it cannot."""
        loop = asyncio.get_running_loop()
        try:
            self.servers[device.name] = await loop.create_server(
                lambda: EncapsulationProtocol(device, self.connections, self.tcp_limits), host=device.profile.address,
                port=ENIP_PORT, reuse_address=True, backlog=128,
            )
        except OSError as error:
            raise BindError(bind_message(device, "TCP", error)) from None

    def listening(self, name: str) -> bool:
        return name in self.servers

    def stop_listening(self, name: str) -> None:
        """Close the device's listener (its accepted connections stay)."""
        server = self.servers.pop(name, None)
        if server is not None:
            server.close()

    def close_connections(self, device: Device, kind: Disconnect = Disconnect.CLOSE) -> None:
        """End the device's TCP connections: a FIN (CLOSE) or an RST (RESET)."""
        for connection in [c for c in self.connections if c.device is device]:
            connection.kill(kind)

    async def close(self) -> None:
        """Stop every listener and end every connection."""
        for server in self.servers.values():
            server.close()
        for connection in list(self.connections):
            connection.kill(Disconnect.CLOSE)
        for server in self.servers.values():
            await server.wait_closed()
        self.servers.clear()
