"""Connections as the Connection Manager opens them (CIP Networks Library Vol. 1, 3-4 and 3-5):
class-1 I/O connections (exclusive owner, input only, listen only) and class-3 explicit
connections. State only; the server produces and consumes their packets."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from enum import Enum

from enip_farm.protocol.connection import ConnectionTriad


class ConnectionKind(str, Enum):
    EXCLUSIVE_OWNER = "exclusive owner"
    INPUT_ONLY = "input only"
    LISTEN_ONLY = "listen only"
    EXPLICIT = "explicit (class 3)"


@dataclass(eq=False)
class Connection:
    kind: ConnectionKind
    triad: ConnectionTriad
    o_t_id: int
    t_o_id: int
    o_t_rpi: int  # microseconds
    t_o_rpi: int
    timeout_multiplier: int
    originator_host: str
    t_o_address: tuple[str, int] | None = None  # where T->O packets go (class 1)
    multicast: bool = False
    o_t_point: int | None = None
    t_o_point: int | None = None
    o_t_run_idle_header: bool = True
    owner: object | None = None  # the encapsulation session of a class-3 connection
    opened_at: float = field(default_factory=time.monotonic)
    last_received: float = field(default_factory=time.monotonic)
    received: int = 0  # valid packets consumed
    produced: int = 0
    last_sequence: int | None = None  # 32-bit sequence of the last O->T packet consumed
    run: bool = False
    closed: bool = False
    last_reply: tuple[int, bytes] | None = None  # class 3: (sequence count, reply) for duplicates

    @property
    def timeout(self) -> float:
        """Connection timeout in seconds: O->T RPI x 2^(2 + multiplier) (Vol. 1, 3-4.4.9)."""
        return self.o_t_rpi * (1 << (2 + min(self.timeout_multiplier, 7))) / 1e6

    @property
    def is_io(self) -> bool:
        return self.kind is not ConnectionKind.EXPLICIT
