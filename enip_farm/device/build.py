"""Building devices from a configuration: the step between the pure schema (`config.py`) and
running devices. It reads the profile files that devices name into a copy of the catalogue it is
given, checks every model and add-on, resolves each device's profile (`device/profile.py`) and
checks wires and rules against the devices' signals, refusing cycles.

Problems are raised as one `ConfigError`, one line per problem naming the file, the device and the
field, like the schema's own errors.
"""

from __future__ import annotations

from collections.abc import Mapping

import yaml
from pydantic import ValidationError

from enip_farm.config import ConfigError, DeviceConfig, FarmConfig, device_location, is_profile_path
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
    for device in config.devices:
        for field, message in _device_problems(device, models.get(device.model, device.model), catalogue):
            if (device.entry, field, message) not in seen:  # a `count` entry's devices share their problems
                seen.add((device.entry, field, message))
                where = device_location(device.entry, device.name)
                problems.append(f"{config.source}: {where}" + (f", {field}: " if field else ": ") + message)
    if problems:
        raise ConfigError("\n".join(problems))
    profiles = [resolve(device.model_copy(update={"model": models[device.model]}) if device.model in models
                        else device, catalogue) for device in config.devices]
    problems = list(dict.fromkeys(  # a `count` entry's devices share their problems
        f"{config.source}: {device_location(device.entry)}, {field}: {message}"
        for device, profile in zip(config.devices, profiles, strict=True)
        for field, messages in (("assemblies", assembly_problems(profile)), ("signals", signal_problems(profile)))
        for message in messages))
    problems += [f"{config.source}: {message}" for message in check_wiring(config, profiles)]
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
        problems.append(("model", f"unknown base model {model_name!r}; known: {', '.join(catalogue.bases())}"))
    elif model.identity is None:
        problems.append(("model", f"base model {model_name!r} has no identity"))
    for addon in device.addons:
        if addon not in catalogue.addons():
            problems.append(("addons", f"unknown add-on {addon!r}; known: {', '.join(catalogue.addons())}"))
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


def check_wiring(config: FarmConfig, profiles: list[DeviceProfile]) -> list[str]:
    """One message per wire or rule that does not fit the devices' signals; if all fit, a message
    for a cycle (a change that would feed back into itself), if any."""
    if not config.wires and not config.rules:
        return []
    maps: Mapping[str, SignalMap] = {profile.name: SignalMap(profile) for profile in profiles}
    problems: list[str] = []
    edges: dict[tuple[str, str], set[tuple[str, str]]] = {}
    for wire in config.wires:
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
        try:
            when, target = parse_endpoint(rule.when, maps), parse_endpoint(rule.set, maps)
        except SignalError as error:
            problems.append(f"rule {rule.when} -> {rule.set}: {error}")
            continue
        if when.signal.count != 1 or target.signal.count != 1 or not (when.signal.digital and target.signal.digital):
            problems.append(f"rule {when} -> {target}: a rule watches one bit and sets one bit")
        else:
            edges.setdefault((when.device, when.signal.role), set()).add((target.device, target.signal.role))
    if not problems:
        cycle = _cycle(edges)
        if cycle:
            problems.append("wiring cycle: " + " -> ".join(f"{d}.{r}s" for d, r in cycle))
    return problems


def _named_kind(signal: object) -> str | None:
    """G (group), A (analog) or D for a named signal whose value is not a numbered range's, else None."""
    if isinstance(signal, NamedSignal) and not signal.digital:
        return signal.type[0] + ("s" if signal.signed else "") + ("x" if signal.scale else "")
    return None


def _cycle(edges: dict[tuple[str, str], set[tuple[str, str]]]) -> list[tuple[str, str]] | None:
    """The nodes of one cycle of the graph (first node repeated at the end), or None."""
    state: dict[tuple[str, str], int] = {}  # 1 visiting, 2 done

    def visit(node: tuple[str, str], path: list[tuple[str, str]]) -> list[tuple[str, str]] | None:
        state[node] = 1
        for following in edges.get(node, ()):
            if state.get(following) == 1:
                return path[path.index(following):] + [following] if following in path else [node, following]
            if following not in state:
                found = visit(following, path + [following])
                if found:
                    return found
        state[node] = 2
        return None

    for node in list(edges):
        if node not in state:
            found = visit(node, [node])
            if found:
                return found
    return None
