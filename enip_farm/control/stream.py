"""The HTTP API's event stream (server-sent events): one hub fans the devices' events out to at
most `max_subscribers` streams, each with its own bounded queue.

Producers are whatever thread changes a device: the farm's loop (requests, faults), the cyclic
I/O thread (image changes), callers of the Python API. `Device.observe` calls `EventHub.deliver`
in that thread; it appends the event to one bounded deque and asks the loop, at most once per
turn, to hand the batch out. It never blocks, never formats and never touches a subscriber.

On the loop each subscriber takes what its filter selects into its own queue of `queue_size`
events; a full queue counts the rest in `lost`, and the stream says `event: lost` with the count
where they would have been. A client that does not read leaves its stream waiting in `send`;
nothing else waits for it, and it costs the farm a filter test and a counter per event. A stream
whose client has taken nothing for `stall_s` seconds is closed, so that clients that never read
cannot hold the subscriber slots for ever. An idle stream carries a comment every `keepalive_s`
seconds, so that a vanished client is noticed.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
from collections import deque
from collections.abc import Iterable

from starlette.responses import JSONResponse, Response
from starlette.types import Receive, Scope, Send

from enip_farm.device.device import Device
from enip_farm.device.events import Event

log = logging.getLogger(__name__)

MAX_SUBSCRIBERS = 32
QUEUE_SIZE = 4096  # events per subscriber, about 1 MB of text
PENDING_SIZE = 16384  # events between two turns of the loop, across all devices
KEEPALIVE_S = 15.0
STALL_S = 60.0
BATCH = 256  # events per write


class TooManySubscribers(Exception):
    pass


class _Item:
    """An event, formatted once for every stream that sends it, and only if one does."""

    __slots__ = ("event", "_text")

    def __init__(self, event: Event) -> None:
        self.event = event
        self._text: str | None = None

    def text(self) -> str:
        if self._text is None:
            self._text = f"data: {json.dumps(self.event.as_dict())}\n\n"
        return self._text


def _lost(count: int) -> str:
    return f"event: lost\ndata: {json.dumps({'lost': count})}\n\n"


class Subscriber:
    """One stream's filter, queue and lost count; used on the loop only."""

    def __init__(self, devices: frozenset[str] | None, kinds: frozenset[str] | None, size: int) -> None:
        self.devices = devices
        self.kinds = kinds
        self.size = size
        self.queue: deque[_Item] = deque()
        self.lost = 0  # not yet told
        self.lost_total = 0
        self._lost_after = 0  # queued events that precede the lost ones
        self.ready = asyncio.Event()
        self.closed: str | None = None  # why the stream ends: "disconnected", "stopped"

    def offer(self, batch: list[_Item], overflow: int) -> None:
        devices, kinds, queue = self.devices, self.kinds, self.queue
        room = self.size - len(queue)
        for item in batch:
            event = item.event
            if (devices is None or event.device in devices) and (kinds is None or event.kind in kinds):
                if room > 0:
                    queue.append(item)
                    room -= 1
                else:
                    self._lose(1)
        if overflow:
            self._lose(overflow)
        if queue or self.lost:
            self.ready.set()

    def _lose(self, count: int) -> None:
        if not self.lost:
            self._lost_after = len(self.queue)
        self.lost += count
        self.lost_total += count

    def take(self) -> str:
        """Up to BATCH queued events as one piece of the stream, with the lost count in its place."""
        parts = []
        for _ in range(min(BATCH, len(self.queue))):
            if self.lost and self._lost_after <= 0:
                parts.append(_lost(self.lost))
                self.lost = 0
            parts.append(self.queue.popleft().text())
            self._lost_after -= 1
        if self.lost and self._lost_after <= 0:
            parts.append(_lost(self.lost))
            self.lost = 0
        return "".join(parts)

    def close(self, why: str) -> None:
        self.closed = self.closed or why
        self.ready.set()


class EventHub:
    def __init__(self, devices: Iterable[Device], max_subscribers: int = MAX_SUBSCRIBERS,
                 queue_size: int = QUEUE_SIZE, keepalive_s: float = KEEPALIVE_S, stall_s: float = STALL_S) -> None:
        self.devices = list(devices)
        self.max_subscribers = max_subscribers
        self.queue_size = queue_size
        self.keepalive_s = keepalive_s
        self.stall_s = stall_s
        self.subscribers: set[Subscriber] = set()
        self._pending: deque[Event] = deque()
        self._overflow = 0  # events the pending deque had no room for (counted approximately across threads)
        self._scheduled = False
        self._loop: asyncio.AbstractEventLoop | None = None
        self._unobserve: list = []

    # -- any thread --------------------------------------------------------------------------------

    def deliver(self, event: Event) -> None:
        """The devices' observer: cheap, never blocks (it runs in the thread that made the change)."""
        pending = self._pending
        if len(pending) >= PENDING_SIZE:
            self._overflow += 1
            return
        pending.append(event)
        if not self._scheduled:  # reset by _distribute before it takes the batch: nothing is left behind
            self._scheduled = True
            try:
                self._loop.call_soon_threadsafe(self._distribute)  # type: ignore[union-attr]
            except RuntimeError:  # the loop has closed: the farm has stopped
                pass

    # -- on the loop -------------------------------------------------------------------------------

    def subscribe(self, devices: Iterable[str] = (), kinds: Iterable[str] = ()) -> Subscriber:
        if len(self.subscribers) >= self.max_subscribers:
            raise TooManySubscribers(f"{len(self.subscribers)} event streams are open, the most this farm serves "
                                     f"({self.max_subscribers}); close one and try again")
        self._loop = asyncio.get_running_loop()
        subscriber = Subscriber(frozenset(devices) or None, frozenset(kinds) or None, self.queue_size)
        if not self.subscribers:  # no observers while nobody listens: the hot paths pay nothing
            self._unobserve = [device.observe(self.deliver) for device in self.devices]
        self.subscribers.add(subscriber)
        return subscriber

    def unsubscribe(self, subscriber: Subscriber) -> None:
        self.subscribers.discard(subscriber)
        if not self.subscribers:
            for unobserve in self._unobserve:
                unobserve()
            self._unobserve = []
            self._pending.clear()

    def close(self) -> None:
        """End every stream (the API is stopping)."""
        for subscriber in list(self.subscribers):
            subscriber.close("stopped")

    def _distribute(self) -> None:
        self._scheduled = False
        pending = self._pending
        batch = [_Item(pending.popleft()) for _ in range(len(pending))]
        overflow, self._overflow = self._overflow, 0
        for subscriber in self.subscribers:
            subscriber.offer(batch, overflow)


class EventStream(Response):
    """The response of GET /events: subscribes when it starts, unsubscribes when it ends."""

    media_type = "text/event-stream"

    def __init__(self, hub: EventHub, devices: Iterable[str] = (), kinds: Iterable[str] = ()) -> None:
        super().__init__()
        self.hub = hub
        self.devices = list(devices)
        self.kinds = list(kinds)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        hub = self.hub
        try:
            subscriber = hub.subscribe(self.devices, self.kinds)
        except TooManySubscribers as error:
            await JSONResponse({"detail": str(error)}, status_code=503, headers={"Retry-After": "5"})(
                scope, receive, send)
            return
        loop = asyncio.get_running_loop()
        watcher = loop.create_task(_watch(receive, subscriber))
        try:
            await send({"type": "http.response.start", "status": 200, "headers": [
                (b"content-type", b"text/event-stream; charset=utf-8"), (b"cache-control", b"no-cache")]})
            text = ": enip-farm event stream\n\n"
            while subscriber.closed is None:
                try:
                    await asyncio.wait_for(send({"type": "http.response.body", "body": text.encode(),
                                                 "more_body": True}), hub.stall_s)
                except asyncio.TimeoutError:
                    client = scope.get("client") or ("?", 0)
                    log.warning("event stream to %s:%s closed: its client took nothing for %g s",
                                client[0], client[1], hub.stall_s)
                    return
                text = await _next(subscriber, loop, hub.keepalive_s)
            if subscriber.closed == "stopped":
                with contextlib.suppress(asyncio.TimeoutError):
                    await asyncio.wait_for(send({"type": "http.response.body", "body": b"", "more_body": False}), 1)
        finally:
            watcher.cancel()
            hub.unsubscribe(subscriber)


async def _next(subscriber: Subscriber, loop: asyncio.AbstractEventLoop, keepalive_s: float) -> str:
    if not subscriber.ready.is_set():
        timer = loop.call_later(keepalive_s, subscriber.ready.set)
        try:
            await subscriber.ready.wait()
        finally:
            timer.cancel()
    subscriber.ready.clear()
    text = subscriber.take()
    if subscriber.queue or subscriber.lost:
        subscriber.ready.set()  # more than one batch was waiting
    return text or ": keep-alive\n\n"


async def _watch(receive: Receive, subscriber: Subscriber) -> None:
    while (await receive())["type"] != "http.disconnect":
        pass
    subscriber.close("disconnected")
