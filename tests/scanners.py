"""The `ethernetip` scanner (PyPI, the test extra) set up as every test and benchmark uses it: a
session registered, two assemblies registered (the DSQC1030's T->O 101 and O->T 100 of 2 bytes
unless told), its UDP I/O on a port of its own (the farm's device sockets hold 2222 on their
addresses). `scanner()` stops it however the test ends."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import ethernetip

INPUT, OUTPUT = ethernetip.EtherNetIP.ENIP_IO_TYPE_INPUT, ethernetip.EtherNetIP.ENIP_IO_TYPE_OUTPUT


@dataclass
class Scanner:
    enip: ethernetip.EtherNetIP
    conn: Any  # its explicit connection: produce(), stopProduce(), the raw requests
    inputs: Any  # the T->O assembly's bits as the scanner holds them
    outputs: Any  # the O->T assembly's bits it sends
    points: tuple[int, int, int]  # its Forward Open's T->O, O->T and configuration instances

    def forward_open(self, rpi_ms: int, multiplier: int) -> int:
        """Its Forward Open (the same RPI both ways, timeout x 4 << multiplier); the status, 0: opened."""
        return self.conn.sendFwdOpenReq(*self.points, torpi=rpi_ms, otrpi=rpi_ms, multiplier=multiplier,
                                        originator_udp_port=self.enip.originator_udp_port)

    def forward_close(self) -> int:
        return self.conn.sendFwdCloseReq(*self.points)

    def stop(self, forward_close: bool = False) -> None:
        """No more O->T (a Forward Close sent with `forward_close`), and its I/O thread stopped."""
        self.conn.stopProduce()
        if forward_close:
            self.forward_close()
        self.enip.stopIO()


def start_scanner(address: str, t_o: tuple[int, int] = (101, 2), o_t: tuple[int, int] = (100, 2),
                  configuration: int = 1) -> Scanner:
    """A started scanner of the device at `address`; `t_o`, `o_t`: (instance, bytes) of each assembly."""
    enip = ethernetip.EtherNetIP(address)
    conn = enip.explicit_conn(address)
    assert conn.registerSession() == 0
    inputs = enip.registerAssembly(INPUT, t_o[1], t_o[0], conn)
    outputs = enip.registerAssembly(OUTPUT, o_t[1], o_t[0], conn)
    enip.startIO(udp_port=0)
    return Scanner(enip, conn, inputs, outputs, (t_o[0], o_t[0], configuration))


@contextmanager
def scanner(address: str, forward_close: bool = False, **assemblies: Any) -> Iterator[Scanner]:
    """`start_scanner()`, stopped when the block ends (`Scanner.stop`)."""
    started = start_scanner(address, **assemblies)
    try:
        yield started
    finally:
        started.stop(forward_close)
