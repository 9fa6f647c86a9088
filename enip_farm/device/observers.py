"""A device's observers, each told only the event classes it asked for (device/events.py,
cip/connection_events.py): the matching on a class is done once, here, when an observer is added
or a class is first published, not per event in every observer. An image comparison or a request's
Event is made only while someone observes that class (device/guard.py asks `of_images`, `of_requests`).

Copy on write: publishing (any thread) never locks; adding and removing replace the lists.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator

from enip_farm.device.events import Event, ImageChanged, RequestHandled

#: An observer of a device: called with an Event whose `detail` is the typed event.
Observer = Callable[[Event], None]


class Observers:
    """Who is told what: (observer, the classes it observes; () for every event)."""

    def __init__(self) -> None:
        self._subscribed: list[tuple[Observer, tuple[type, ...]]] = []
        self._routes: dict[type, list[Observer]] = {}
        self.of_images: list[Observer] = []  # of ImageChanged: the hot paths ask before comparing
        self.of_requests: list[Observer] = []  # of RequestHandled: before making an Event per request
        #: Told after each change of who observes (server/native.py: image observers leave the native path).
        self.changed: Callable[[], None] | None = None

    def add(self, observer: Observer, classes: tuple[type, ...] = ()) -> Callable[[], None]:
        """Tell `observer` the events of `classes` (and their subclasses; none: every event). The remove."""
        entry = (observer, classes)
        self._set([*self._subscribed, entry])

        def remove() -> None:
            self._set([subscribed for subscribed in self._subscribed if subscribed is not entry])
        return remove

    def _set(self, subscribed: list[tuple[Observer, tuple[type, ...]]]) -> None:
        self._subscribed = subscribed  # before the routes: a route made from now on is made of these
        self._routes = {}
        self.of_images = self._match(ImageChanged)
        self.of_requests = self._match(RequestHandled)
        if self.changed is not None:
            self.changed()

    def _match(self, cls: type) -> list[Observer]:
        return [observer for observer, classes in self._subscribed if not classes or issubclass(cls, classes)]

    def of(self, cls: type) -> list[Observer]:
        """The observers of events of class `cls`."""
        routes = self._routes
        found = routes.get(cls)
        if found is None:
            found = routes[cls] = self._match(cls)
        return found

    def __iter__(self) -> Iterator[Observer]:
        return iter([observer for observer, _ in self._subscribed])

    def __bool__(self) -> bool:
        return bool(self._subscribed)
