"""Reaction time (action latency) of the controller under test, measured `repeat` times: the test sets
a stimulus (an input of one device), the controller answers with an output (of the same or another
device). Each repetition first puts the stimulus back (`reset`) and waits until the expected output
is gone, then arms a probe (device/reaction.py) and sets the stimulus: the sample runs from the T->O
packet that first carried it (when the I/O thread handed it to the kernel) to the O->T packet
(kernel receive time) or explicit write that first carried the expected output. A repetition whose
output does not come (or does not go away before it) within `timeout` counts as a timeout. The
stimulus stays set at the end, as the test set it."""

from __future__ import annotations

from collections.abc import Callable, Mapping

from enip_farm.cip.report import ReactionFigures
from enip_farm.control.handle import DeviceHandle
from enip_farm.device.events import Event, ImageChanged
from enip_farm.device.reaction import ReactionProbe

#: (device, signal, value), as farm["io1"].set(DI3=1) writes it: ("io1", "DI3", 1).
SignalValue = tuple[str, str, int | float]
#: Subscribes a callback to the time each I/O turn's T->O go to the kernel; returns the unsubscribe.
WatchFlush = Callable[[Callable[[int], None]], Callable[[], None]]
#: The most repetitions one reaction measures (its samples are all kept).
MAX_REPEAT = 10_000


def measure_reaction(handles: Mapping[str, DeviceHandle], stimulus: SignalValue, expect: SignalValue,
                     timeout: float = 1.0, repeat: int = 1, reset: int | float | None = None,
                     name: str | None = None, watch_flush: WatchFlush | None = None) -> ReactionFigures:
    """Measure the reaction `repeat` times; KeyError for an unknown device, SignalError for a bad signal.
    `reset`: the stimulus's value between repetitions (default: 0, or 1 where the stimulus is 0);
    `watch_flush`: the cyclic I/O thread's (when each turn's T->O go to the kernel)."""
    if not 1 <= repeat <= MAX_REPEAT:
        raise ValueError(f"repeat is 1 to {MAX_REPEAT}, got {repeat}")
    if not 0 < timeout <= 3600:
        raise ValueError(f"timeout is more than 0 and at most 3600 s, got {timeout}")
    (s_device, s_name, s_value), (e_device, e_name, e_value) = stimulus, expect
    source, target = handles[s_device], handles[e_device]
    s_signal, e_signal = source.signals.lookup(s_name), target.signals.lookup(e_name)
    if s_signal.role != "input":
        raise ValueError(f"{s_device}.{s_name}: a stimulus is an input the test sets")
    if e_signal.role != "output":
        raise ValueError(f"{e_device}.{e_name}: the expected reaction is an output the controller writes")
    back = reset if reset is not None else (0 if s_value else 1)
    samples: list[int] = []
    vias: set[str] = set()
    timeouts = 0
    for _ in range(repeat):
        source.set({s_name: back})
        try:
            target.wait_for(lambda h: h.get(e_name) != e_value, timeout)
        except TimeoutError:
            timeouts += 1
            continue
        probe = ReactionProbe((source.signals, s_signal, s_value), (target.signals, e_signal, e_value))
        latency = _once(source, target, probe, s_name, s_value, timeout, watch_flush)
        if latency is None:
            timeouts += 1
        else:
            samples.append(latency)
            vias.add(probe.via or "")
    via = vias.pop() if len(vias) == 1 else "any"
    return ReactionFigures(name or f"{s_device}.{s_name}={s_value} -> {e_device}.{e_name}={e_value}",
                           f"{s_device}.{s_name}={s_value}", f"{e_device}.{e_name}={e_value}", via,  # type: ignore[arg-type]
                           tuple(samples), timeouts)


def _once(source: DeviceHandle, target: DeviceHandle, probe: ReactionProbe, name: str, value: int | float,
          timeout: float, watch_flush: WatchFlush | None) -> int | None:
    """One repetition with the probe armed: its latency, or None if the output did not come in time."""
    def explicit(event: Event) -> None:
        change: ImageChanged = event.detail
        if change.role == "output":
            probe.consumed(change.new, event.monotonic_ns, "explicit")

    s_cyclic, t_cyclic = source.device.cyclic, target.device.cyclic
    s_cyclic.stimuli = (*s_cyclic.stimuli, probe)
    t_cyclic.expectations = (*t_cyclic.expectations, probe)
    unsubscribe = target.device.observe(explicit, ImageChanged)
    unwatch = watch_flush(probe.flushed) if watch_flush is not None else None
    try:
        written_at = source.device.clock()
        source.set({name: value})
        produced = source.device.guard.read(lambda: bool(source.device.table.productions))
        if not produced:  # no T->O carries the inputs: an explicit reader could see it from now
            probe.set_at(written_at)
        probe.done.wait(timeout)
        return probe.latency_ns
    finally:
        unsubscribe()
        if unwatch is not None:
            unwatch()
        s_cyclic.stimuli = tuple(p for p in s_cyclic.stimuli if p is not probe)
        t_cyclic.expectations = tuple(p for p in t_cyclic.expectations if p is not probe)
