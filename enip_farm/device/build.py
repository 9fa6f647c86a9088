"""Building devices from a configuration: the step between the pure schema (`config.py`) and
running devices. It reads the profile files that devices name into a copy of the catalogue it is
given, checks every model and add-on, resolves each device's profile (`device/profile.py`) and
checks wires and rules against the devices' signals, refusing cycles.

Problems are raised as one `ConfigError`, one line per problem naming the file, the device and the
field, like the schema's own errors.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping
from dataclasses import replace
from pathlib import Path

import yaml
from pydantic import ValidationError

from enip_farm.config import ConfigError, DeviceConfig, FarmConfig, device_location, is_profile_path
from enip_farm.config_errors import did_you_mean
from enip_farm.device.catalogue import Catalogue
from enip_farm.device.named_signals import NamedSignal, named_signal
from enip_farm.device.profile import DeviceProfile, resolve
from enip_farm.device.signals import SignalError, SignalMap, parse_endpoint, parse_signal, width


def build_profiles(config: FarmConfig, catalogue: Catalogue) -> list[DeviceProfile]:
    """The resolved profile of every device of `config`, in order. `catalogue` holds the models
    devices name directly; profile files named as a model are added to a copy of it, and may not
    redefine one of its models."""
    catalogue, models, problems = _with_profiles(config, catalogue)
    seen: set[tuple[int, str, str]] = set()
    failed: set[str] = set()  # devices that cannot be built: wires to them are not checked further
    for device in config.devices:
        model = models.get(device.model, device.model)
        device_problems = _device_problems(device, model, catalogue)
        if device_problems or (is_profile_path(model) and device.model not in models):
            failed.add(device.name)
        for field, message in device_problems:
            if (device.entry, field, message) not in seen:  # a `count` entry's devices share their problems
                seen.add((device.entry, field, message))
                where = device_location(device.entry, device.name)
                problems.append(f"{config.source}: {where}" + (f", {field}: " if field else ": ") + message)
    profiles = [replace(resolve(device.model_copy(update={"model": models[device.model]}), catalogue),
                        model_file=Path(device.model).name) if device.model in models
                else resolve(device, catalogue) for device in config.devices if device.name not in failed]
    problems += list(dict.fromkeys(  # a `count` entry's devices share their problems
        f"{config.source}: {device_location(device.entry)}, {field}: {message}"
        for device, profile in zip([d for d in config.devices if d.name not in failed], profiles, strict=True)
        for field, messages in (("assemblies", assembly_problems(profile)), ("signals", signal_problems(profile)))
        for message in messages))
    problems += [f"{config.source}: {message}" for message in check_wiring(config, profiles, failed)]
    if problems:
        raise ConfigError("\n".join(problems))
    return profiles


def _with_profiles(config: FarmConfig, catalogue: Catalogue) -> tuple[Catalogue, dict[str, str], list[str]]:
    """The catalogue with every profile file the devices name, each file's base model by path, and
    the problems of files that cannot be added."""
    models: dict[str, str] = {}
    problems: list[str] = []
    failed: set[str] = set()
    for device in config.devices:
        path = device.model
        if not is_profile_path(path) or path in models or path in failed:
            continue
        try:
            catalogue, models[path] = catalogue.with_profile(path)
            continue
        except OSError as error:
            message = f"profile {path}: {error.strerror}"
        except (yaml.YAMLError, ValidationError) as error:
            message = f"profile {path} is not a valid profile: {error}"
        except ValueError as error:
            message = str(error)
        failed.add(path)
        problems.append(f"{config.source}: {device_location(device.entry, device.name)}, model: {message}")
    return catalogue, models, problems


def _device_problems(device: DeviceConfig, model_name: str, catalogue: Catalogue) -> list[tuple[str, str]]:
    """(field, message) for each problem of one device's model and add-ons."""
    if is_profile_path(model_name):
        return []  # the profile file itself failed, and is reported once
    problems = []
    model = catalogue.models.get(model_name)
    if model is None or model.kind != "base":
        problems.append(("model", f"unknown base model {model_name!r}{did_you_mean(model_name, catalogue.bases())}; "
                                  f"known: {', '.join(catalogue.bases())}"))
    elif model.identity is None:
        problems.append(("model", f"base model {model_name!r} has no identity"))
    for addon in device.addons:
        if addon not in catalogue.addons():
            problems.append(("addons", f"unknown add-on {addon!r}{did_you_mean(addon, catalogue.addons())}; "
                                       f"known: {', '.join(catalogue.addons())}"))
    for signal in device.signals:
        try:
            named_signal(signal)
        except SignalError as error:
            problems.append(("signals", str(error)))
    if not problems and device.addons and model is not None and model.assemblies is None:
        problems.append(("", f"model {model_name} takes no add-ons"))
    return problems


def assembly_problems(profile: DeviceProfile) -> list[str]:
    """One message per assembly instance id that two roles share (e.g. an input override of 100
    on a model whose output is 100): one of them would hide the other."""
    roles: dict[int, str] = {}
    problems = []
    for spec in profile.assemblies:
        if spec.instance_id in roles:
            problems.append(f"{roles[spec.instance_id]} and {spec.role} are both instance {spec.instance_id}")
        roles.setdefault(spec.instance_id, spec.role)
    return problems


def signal_problems(profile: DeviceProfile) -> list[str]:
    """One message per named signal that does not fit the device: a name that reads as a built-in
    signal (DI3, AO1-2), or a bit beyond its image."""
    problems = []
    for signal in profile.signals:
        try:
            parse_signal(signal.name)
        except SignalError:
            pass
        else:
            problems.append(f"{signal.name}: the name reads as a built-in signal; choose another")
            continue
        size = profile.input_size if signal.role == "input" else profile.output_size
        beyond = [bit for bit in signal.bits if bit >= 8 * size]
        if beyond:
            problems.append(f"{signal.name}: bit {beyond[0]} is beyond the {size}-byte {signal.role} image "
                            f"(bits 0..{8 * size - 1})")
    return problems


def check_wiring(config: FarmConfig, profiles: list[DeviceProfile], failed: Collection[str] = ()) -> list[str]:
    """One message per wire or rule that does not fit the devices' signals, and one per cycle (a
    change that would feed back into itself) among those that fit. Wires and rules that touch a
    device in `failed` (one that could not be built, reported already) are left out."""
    if not config.wires and not config.rules:
        return []
    maps: Mapping[str, SignalMap] = {profile.name: SignalMap(profile) for profile in profiles}
    problems: list[str] = []
    edges: dict[tuple[str, str], set[tuple[str, str]]] = {}

    def touches_failed(*endpoints: str) -> bool:
        return any(endpoint.rpartition(".")[0] in failed for endpoint in endpoints)

    for wire in config.wires:
        if touches_failed(wire.source, wire.target):
            continue
        try:
            source, target = parse_endpoint(wire.source, maps), parse_endpoint(wire.target, maps)
        except SignalError as error:
            problems.append(f"wire {wire.source} -> {wire.target}: {error}")
            continue
        if source.signal.role != "output" or target.signal.role != "input":
            problems.append(f"wire {source} -> {target}: wires go from outputs (DO, AO) to inputs (DI, AI)")
        elif (source.signal.digital != target.signal.digital or source.signal.count != target.signal.count
              or width(source.signal) != width(target.signal)
              or _named_kind(source.signal) != _named_kind(target.signal)):
            problems.append(f"wire {source} -> {target}: both ends need the same kind and number of signals")
        else:
            edges.setdefault((source.device, "output"), set()).add((target.device, "input"))
    for rule in config.rules:
        if touches_failed(rule.when, rule.set):
            continue
        try:
            when, target = parse_endpoint(rule.when, maps), parse_endpoint(rule.set, maps)
        except SignalError as error:
            problems.append(f"rule {rule.when} -> {rule.set}: {error}")
            continue
        if when.signal.count != 1 or target.signal.count != 1 or not (when.signal.digital and target.signal.digital):
            problems.append(f"rule {when} -> {target}: a rule watches one bit and sets one bit")
        else:
            edges.setdefault((when.device, when.signal.role), set()).add((target.device, target.signal.role))
    for cycle in _cycles(edges):
        problems.append("wiring cycle: " + " -> ".join(f"{d}.{r}s" for d, r in cycle))
    return problems


def _named_kind(signal: object) -> str | None:
    """G (group), A (analog) or D for a named signal whose value is not a numbered range's, else None."""
    if isinstance(signal, NamedSignal) and not signal.digital:
        return signal.type[0] + ("s" if signal.signed else "") + ("x" if signal.scale else "")
    return None


def _cycles(edges: dict[tuple[str, str], set[tuple[str, str]]]) -> list[list[tuple[str, str]]]:
    """One cycle (first node repeated at the end) per strongly connected part of the graph that
    holds one, in a stable order: every separate feedback loop is reported once."""
    order = sorted({node for node in edges} | {node for targets in edges.values() for node in targets})
    index: dict[tuple[str, str], int] = {}
    low: dict[tuple[str, str], int] = {}
    stack: list[tuple[str, str]] = []
    on_stack: set[tuple[str, str]] = set()
    components: list[list[tuple[str, str]]] = []

    for root in order:  # Tarjan's algorithm with an explicit stack: a chain of thousands of devices is fine
        if root in index:
            continue
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        work = [(root, iter(sorted(edges.get(root, ()))))]
        while work:
            node, followers = work[-1]
            following = next(followers, None)
            if following is not None:
                if following not in index:
                    index[following] = low[following] = len(index)
                    stack.append(following)
                    on_stack.add(following)
                    work.append((following, iter(sorted(edges.get(following, ())))))
                elif following in on_stack:
                    low[node] = min(low[node], index[following])
                continue
            work.pop()
            if work:
                parent = work[-1][0]
                low[parent] = min(low[parent], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                components.append(component)
    cycles = []
    for component in components:
        members = set(component)
        start = min(component)
        if len(component) == 1 and start not in edges.get(start, ()):
            continue
        path, node = [start], start  # walk inside the component back to the start (it is strongly connected)
        while True:
            following = _next_towards(node, start, edges, members)
            path.append(following)
            if following == start:
                break
            node = following
        cycles.append(path)
    return sorted(cycles)


def _next_towards(node: tuple[str, str], goal: tuple[str, str], edges: dict[tuple[str, str], set[tuple[str, str]]],
                  members: set[tuple[str, str]]) -> tuple[str, str]:
    """The first step of a shortest path from `node` to `goal` inside `members` (breadth first)."""
    if goal in edges.get(node, ()):
        return goal
    first_step: dict[tuple[str, str], tuple[str, str]] = {}
    queue = []
    for following in sorted(edges.get(node, ()) & members):
        first_step.setdefault(following, following)
        queue.append(following)
    for current in queue:
        if current == goal:
            return first_step[current]
        for following in sorted(edges.get(current, ()) & members):
            if following not in first_step:
                first_step[following] = first_step[current]
                queue.append(following)
    raise AssertionError("a strongly connected component reaches every member")
