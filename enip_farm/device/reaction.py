"""Action latency, one repetition (ODVA/NIST's EtherNet/IP performance definitions): from the T->O
packet that first carries a stimulus (an input the test set) leaving the farm to the O->T packet
that first carries the expected output (the kernel's receive time of that datagram), or to the
explicit write that first carries it (the time the farm took the request).

The probe is told by the devices' cyclic I/O (device/cyclic.py, in the I/O thread, under each
device's lock): `produced` with the input image each T->O of the stimulus device carried (then
`flushed` with the time the I/O thread hands that turn's T->O to the kernel, where the farm tells
it: server/implicit.py's `watch_flush`; else the turn's time stands), and
`consumed` with the output image after an O->T changed it; explicit writes reach it as "image
changed" events (`changed`). Where the stimulus device produces no T->O (an explicit reader), the
stimulus counts from when the input was set (`set_at`), the earliest any reader could see it.
"""

from __future__ import annotations

import threading

from enip_farm.device.signals import Signal, SignalMap


class ReactionProbe:
    """One repetition: armed before the stimulus is written, done once the expected output came."""

    def __init__(self, stimulus: tuple[SignalMap, Signal, object], expect: tuple[SignalMap, Signal, object]) -> None:
        self._stimulus = stimulus
        self._expect = expect
        self.stimulus_at: int | None = None  # the T->O that first carried it, or when it was set
        self.reacted_at: int | None = None
        self.via: str | None = None  # "o->t" or "explicit"
        self.done = threading.Event()
        self._unsent = False  # the stimulus's T->O is produced, not yet handed to the kernel

    def _is(self, side: tuple[SignalMap, Signal, object], image: bytes | bytearray) -> bool:
        signals, signal, value = side
        return signals.value(signal, image) == value

    def set_at(self, now: int) -> None:
        """The stimulus was written at `now` and no T->O carries the device's inputs."""
        if self.stimulus_at is None:
            self.stimulus_at = now

    def produced(self, inputs: bytes | bytearray, now: int) -> None:
        """The stimulus device's T->O packets of this turn (`now`) carry `inputs`."""
        if self.stimulus_at is None and self._is(self._stimulus, inputs):
            self.stimulus_at = now
            self._unsent = True

    def flushed(self, at: int) -> None:
        """The I/O thread hands this turn's T->O to the kernel at `at`: the stimulus's leaves now."""
        if self._unsent:
            self._unsent = False
            if self.reacted_at is None and at > self.stimulus_at:  # type: ignore[operator]
                self.stimulus_at = at

    def consumed(self, outputs: bytes | bytearray, at: int, via: str = "o->t") -> None:
        """The expect device's outputs became `outputs` at `at` (an O->T's kernel receive time)."""
        if self.stimulus_at is not None and self.reacted_at is None and self._is(self._expect, outputs):
            self.reacted_at = at if at >= self.stimulus_at else self.stimulus_at
            self.via = via
            self.done.set()

    @property
    def latency_ns(self) -> int | None:
        if self.reacted_at is None or self.stimulus_at is None:
            return None
        return self.reacted_at - self.stimulus_at
