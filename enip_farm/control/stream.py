"""The HTTP API's event stream (server-sent events): one hub fans the devices' events out to at
most `max_subscribers` streams, each with its own bounded queue.

Producers are whatever thread changes a device: the farm's loop (requests, faults), the cyclic
I/O thread (image changes), callers of the Python API. `Device.observe` calls `EventHub.deliver`
in that thread, which appends the event to one bounded deque and returns: it never blocks, never
formats, never wakes the loop and never touches a subscriber. The hub has observers on the
devices only while someone subscribes.

While streams are open, the hub ticks on the loop every `tick_s` (20 ms) and hands the batch out,
with each device's image changes merged into one "io" event per image and tick (the signals that
changed, by name, old and new: control/io_changes.py), so that a device changing its I/O at 1 kHz
adds at most 50 events a second per image to the stream:
each subscriber takes what its filter selects into its own queue of `queue_size` events; a full
queue counts the rest in `lost`, and the stream says `event: lost` with the count where they would
have been. A stream therefore wakes and writes at most once a tick, whatever the event rate.
A client that does not read leaves its stream waiting in `send`; nothing else waits for it, and
it costs the farm a filter and a counter per tick. A stream whose `send` has waited `stall_s`
(60 s) is closed, so that clients that never read cannot hold the subscriber slots for ever; an
idle stream carries a comment every `keepalive_s` (15 s), so that a vanished client is noticed.
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

from enip_farm.control.client import KEEPALIVE_S
from enip_farm.control.io_changes import IO_KIND, IoChange, SignalDiff, coalesce
from enip_farm.device.device import Device
from enip_farm.device.events import Event, ImageChanged
from enip_farm.device.signals import SignalMap

log = logging.getLogger(__name__)

MAX_SUBSCRIBERS = 32
QUEUE_SIZE = 4096  # events per subscriber, about 1 MB of text
PENDING_SIZE = 65536  # events between two ticks, across all devices
TICK_S = 0.02
STALL_S = 60.0
BATCH = 1024  # events per write


class TooManySubscribers(Exception):
    pass


class _Item:
    """An event, formatted once for every stream that sends it, and only if one does."""

    __slots__ = ("event", "_text")

    def __init__(self, event: Event) -> None:
        self.event = event
        self._text: bytes | None = None

    def text(self) -> bytes:
        if self._text is None:
            event = self.event
            fields = event.detail.as_dict(event) if isinstance(event.detail, IoChange) else event.as_dict()
            self._text = f"data: {json.dumps(fields)}\n\n".encode()
        return self._text


def _lost(count: int) -> bytes:
    return f"event: lost\ndata: {json.dumps({'lost': count})}\n\n".encode()


class Subscriber:
    """One stream's filter, queue and lost count; used on the loop only."""

    def __init__(self, devices: frozenset[str] | None, kinds: frozenset[str] | None, size: int, now: float,
                 excluded: frozenset[str] = frozenset()) -> None:
        self.devices = devices
        self.kinds = kinds
        self.excluded = excluded
        self.size = size
        self.queue: deque[_Item] = deque()
        self.lost = 0  # not yet told
        self.lost_total = 0
        self._lost_after = 0  # queued events that precede the lost ones
        self.ready = asyncio.Event()
        self.closed: str | None = None  # why the stream ends: "disconnected", "stopped", "stalled"
        self.task: asyncio.Task | None = None
        self.sending_since: float | None = None
        self.written_at = now

    def offer(self, batch: list[_Item], overflow: int) -> None:
        devices, kinds, excluded = self.devices, self.kinds, self.excluded
        if devices is None and kinds is None and not excluded:
            chosen = batch
        else:
            chosen = [item for item in batch if (devices is None or item.event.device in devices)
                      and (kinds is None or item.event.kind in kinds) and item.event.kind not in excluded]
        room = self.size - len(self.queue)
        if len(chosen) <= room:
            self.queue.extend(chosen)
        else:
            self.queue.extend(chosen[:room])
            self._lose(len(chosen) - room)
        if overflow:
            self._lose(overflow)
        if self.queue or self.lost:
            self.ready.set()

    def _lose(self, count: int) -> None:
        if not self.lost:
            self._lost_after = len(self.queue)
        self.lost += count
        self.lost_total += count

    def wants(self, kind: str) -> bool:
        return (self.kinds is None or kind in self.kinds) and kind not in self.excluded

    def take(self) -> bytes:
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
        return b"".join(parts)

    def close(self, why: str) -> None:
        self.closed = self.closed or why
        self.ready.set()


class EventHub:
    def __init__(self, devices: Iterable[Device], max_subscribers: int = MAX_SUBSCRIBERS,
                 queue_size: int = QUEUE_SIZE, keepalive_s: float = KEEPALIVE_S, stall_s: float = STALL_S,
                 tick_s: float = TICK_S) -> None:
        self.devices = list(devices)
        self._by_name = {device.name: device for device in self.devices}
        self._diffs: dict[str, SignalDiff] = {}  # made when a device's I/O first changes under a stream
        self.max_subscribers = max_subscribers
        self.queue_size = queue_size
        self.keepalive_s = keepalive_s
        self.stall_s = stall_s
        self.tick_s = tick_s
        self.subscribers: set[Subscriber] = set()
        self._pending: deque[Event] = deque()
        self._overflow = 0  # events the pending deque had no room for (counted approximately across threads)
        self._unobserve: list = []
        self._timer: asyncio.TimerHandle | None = None

    # -- any thread --------------------------------------------------------------------------------

    def deliver(self, event: Event) -> None:
        """The devices' observer: a length test and an append (it runs in the thread that made the change)."""
        if len(self._pending) < PENDING_SIZE:
            self._pending.append(event)
        else:
            self._overflow += 1

    # -- on the loop -------------------------------------------------------------------------------

    def subscribe(self, devices: Iterable[str] = (), kinds: Iterable[str] = (),
                  excluded: Iterable[str] = ()) -> Subscriber:
        if len(self.subscribers) >= self.max_subscribers:
            raise TooManySubscribers(f"{len(self.subscribers)} event streams are open, the most this farm serves "
                                     f"({self.max_subscribers}); close one and try again")
        loop = asyncio.get_running_loop()
        subscriber = Subscriber(frozenset(devices) or None, frozenset(kinds) or None, self.queue_size, loop.time(),
                                frozenset(excluded))
        subscriber.task = asyncio.current_task()
        if not self.subscribers:  # no observers while nobody listens: the hot paths pay nothing
            self._unobserve = [device.observe(self.deliver) for device in self.devices]
            self._timer = loop.call_later(self.tick_s, self._tick, loop)
        self.subscribers.add(subscriber)
        return subscriber

    def unsubscribe(self, subscriber: Subscriber) -> None:
        self.subscribers.discard(subscriber)
        if not self.subscribers:
            for unobserve in self._unobserve:
                unobserve()
            self._unobserve = []
            self._pending.clear()
            if self._timer is not None:
                self._timer.cancel()
                self._timer = None

    def close(self) -> None:
        """End every stream (the API is stopping)."""
        for subscriber in list(self.subscribers):
            subscriber.close("stopped")

    def _diff(self, name: str) -> SignalDiff:
        diff = self._diffs.get(name)
        if diff is None:
            diff = self._diffs[name] = SignalDiff(SignalMap(self._by_name[name].profile))
        return diff

    def _tick(self, loop: asyncio.AbstractEventLoop) -> None:
        pending = self._pending
        if pending or self._overflow:
            events = [pending.popleft() for _ in range(len(pending))]  # producers only append
            watching = [subscriber.devices for subscriber in self.subscribers if subscriber.wants(IO_KIND)]
            if watching and None not in watching:  # only these devices' I/O is named (e.g. `io watch io1`)
                wanted = frozenset().union(*watching)
                events = [event for event in events
                          if not isinstance(event.detail, ImageChanged) or event.device in wanted]
            if watching:
                events = coalesce(events, self._diff)
            else:
                events = [event for event in events if not isinstance(event.detail, ImageChanged)]
            batch = [_Item(event) for event in events]
            overflow, self._overflow = self._overflow, 0
            for subscriber in self.subscribers:
                subscriber.offer(batch, overflow)
        now = loop.time()
        for subscriber in list(self.subscribers):
            if subscriber.sending_since is not None:
                if now - subscriber.sending_since > self.stall_s and subscriber.closed is None:
                    subscriber.closed = "stalled"
                    if subscriber.task is not None:
                        subscriber.task.cancel()
            elif now - subscriber.written_at > self.keepalive_s:
                subscriber.ready.set()
        self._timer = loop.call_later(self.tick_s, self._tick, loop) if self.subscribers else None


class EventStream(Response):
    """The response of GET /events: subscribes when it starts, unsubscribes when it ends."""

    media_type = "text/event-stream"

    def __init__(self, hub: EventHub, devices: Iterable[str] = (), kinds: Iterable[str] = (),
                 excluded: Iterable[str] = ()) -> None:
        super().__init__()
        self.hub = hub
        self.devices = list(devices)
        self.kinds = list(kinds)
        self.excluded = list(excluded)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        hub = self.hub
        try:
            subscriber = hub.subscribe(self.devices, self.kinds, self.excluded)
        except TooManySubscribers as error:
            await JSONResponse({"detail": str(error)}, status_code=503, headers={"Retry-After": "5"})(
                scope, receive, send)
            return
        loop = asyncio.get_running_loop()
        watcher = loop.create_task(_watch(receive, subscriber))
        try:
            await send({"type": "http.response.start", "status": 200, "headers": [
                (b"content-type", b"text/event-stream; charset=utf-8"), (b"cache-control", b"no-cache")]})
            text = b": enip-farm event stream\n\n"
            while subscriber.closed is None:
                subscriber.sending_since = loop.time()
                try:
                    await send({"type": "http.response.body", "body": text, "more_body": True})
                except asyncio.CancelledError:
                    if subscriber.closed != "stalled":
                        raise
                    asyncio.current_task().uncancel()  # type: ignore[union-attr]  # our own cancel: handled
                    client = scope.get("client") or ("?", 0)
                    log.warning("event stream to %s:%s closed: its client took nothing for %g s",
                                client[0], client[1], hub.stall_s)
                    return
                subscriber.sending_since = None
                subscriber.written_at = loop.time()
                await subscriber.ready.wait()
                subscriber.ready.clear()
                text = subscriber.take() or b": keep-alive\n\n"
                if subscriber.queue or subscriber.lost:
                    subscriber.ready.set()  # more than one write's worth was waiting
            if subscriber.closed == "stopped":
                with contextlib.suppress(asyncio.TimeoutError):
                    await asyncio.wait_for(send({"type": "http.response.body", "body": b"", "more_body": False}), 1)
        finally:
            watcher.cancel()
            hub.unsubscribe(subscriber)


async def _watch(receive: Receive, subscriber: Subscriber) -> None:
    while (await receive())["type"] != "http.disconnect":
        pass
    subscriber.close("disconnected")
