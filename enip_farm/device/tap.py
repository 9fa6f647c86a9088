"""Where a device's traffic is recorded (`serve --record`): the interface the servers write to."""

from __future__ import annotations

from typing import Protocol


class TrafficTap(Protocol):
    def tcp_opened(self, key: object, client: tuple[str, int], server: tuple[str, int]) -> None: ...

    def tcp_data(self, key: object, from_client: bool, data: bytes) -> None: ...

    def tcp_closed(self, key: object, by_client: bool) -> None: ...

    def udp(self, src: tuple[str, int], dst: tuple[str, int], data: bytes) -> None: ...
