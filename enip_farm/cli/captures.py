"""`enip-farm golden` and `enip-farm learn`: captures of real devices replayed against the farm and
made into profiles (enip_farm/capture/)."""

from __future__ import annotations

import re
import sys
from contextlib import ExitStack
from pathlib import Path

import click


@click.command()
@click.argument("capture", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--config", "config_path", type=click.Path(path_type=Path), default=None,
              help="start this cell in-process and replay against it (default: the default cell)")
@click.option("--device", default=None, help="the farm device that answers for the captured device")
@click.option("--address", default=None, help="replay against a farm already running at this address")
@click.option("--map", "mapping", multiple=True, metavar="CAPTURED_IP=DEVICE",
              help="for a capture of several devices: which farm device answers for which address")
def golden(capture: Path, config_path: Path | None, device: str | None, address: str | None,
           mapping: tuple[str, ...]) -> None:
    """Replay a capture's requests against the farm and compare every reply field by field.
    One line per exchange, a summary, exit status 0 only when all pass (1 when one fails or nothing
    answers at --address, 2 for a file that is not a capture or holds no EtherNet/IP exchange).
    Without --address, golden serves the cell itself on loopback addresses of its own, so it runs
    beside `enip-farm serve`."""
    from enip_farm.capture.exchanges import exchanges_of
    from enip_farm.capture.golden import replay
    from enip_farm.capture.packets import read_capture
    from enip_farm.cli.cell import load_cell
    from enip_farm.cli.golden_farm import own_farm
    from enip_farm.farm.farm import BindError
    from enip_farm.protocol.encapsulation import ENIP_PORT
    from enip_farm.words import plural

    try:
        read = read_capture(capture)
    except ValueError as error:  # CaptureError: not a capture, or cut short
        click.echo(str(error), err=True)
        sys.exit(2)
    groups = exchanges_of(read.packets)
    captured = sorted({e.device for group in groups for e in group})
    if not captured:
        damaged = f" ({plural(read.damaged, 'damaged frame')} skipped)" if read.damaged else ""
        click.echo(f"{capture}: no EtherNet/IP exchanges on port {ENIP_PORT}{damaged}", err=True)
        sys.exit(2)
    if address and (device or mapping or config_path):
        given = ", ".join(o for o, v in (("--device", device), ("--map", mapping), ("--config", config_path)) if v)
        raise click.UsageError(f"{given}: only for the farm golden starts itself; with --address, what answers at "
                               f"{address} is compared: leave out {given} or --address")
    config = None if address else load_cell(config_path, build=False)
    names = dict(item.partition("=")[::2] for item in mapping)
    if config is not None:
        known = [d.name for d in config.devices]
        unknown = sorted({name for name in [device, *names.values()] if name and name not in known})
        if unknown:
            raise click.UsageError(f"no device {', '.join(map(repr, unknown))} in {config.source}; known: "
                                   f"{', '.join(known)}")
        if not names:
            if device is None and len(captured) > 1:
                raise click.UsageError(f"the capture holds {len(captured)} devices ({', '.join(captured)}): use --map")
            names = {ip: device or known[0] for ip in captured}
    try:
        with ExitStack() as stack:
            farm = own_farm(stack, config) if config is not None else None

            def target(ip: str) -> str:
                if farm is None:
                    return address  # type: ignore[return-value]
                if ip not in names:
                    raise click.UsageError(f"no farm device for captured address {ip}: use --map {ip}=NAME")
                return farm.devices[names[ip]].profile.address

            results = replay(groups, target)
    except BindError as error:
        click.echo(str(error), err=True)
        sys.exit(1)
    except OSError as error:
        if address is None:
            raise
        reason = error.strerror or str(error) or type(error).__name__  # refused, unreachable, timed out
        click.echo(f"cannot replay against {address}:{ENIP_PORT}: {reason}; is a farm serving there? Start one "
                   "(enip-farm serve), or leave out --address to let golden start its own", err=True)
        sys.exit(1)
    for result in results:
        click.echo(result.line())
    failed = sum(not r.passed for r in results)
    skipped = f", {plural(read.damaged, 'damaged frame')} skipped" if read.damaged else ""
    click.echo(f"{plural(len(results), 'exchange')}: {len(results) - failed} passed, {failed} failed{skipped}")
    sys.exit(1 if failed else 0)


@click.command()
@click.argument("capture", type=click.Path(dir_okay=False, path_type=Path))
@click.option("-o", "--output", type=click.Path(path_type=Path), required=True,
              help="the profile file; a directory (one profile per device) for a capture of several devices")
@click.option("--device", default=None, metavar="IP", help="learn only this captured device")
@click.option("--name", default=None,
              help="the model's name (default: the learned product name); never a model of the catalogue")
def learn(capture: Path, output: Path, device: str | None, name: str | None) -> None:
    """Write device profiles learned from a capture of real devices, one per device. Name one as a
    device's model in a cell config (`model: PROFILE.yaml`); values the capture does not
    determine are listed under `unverified`."""
    from enip_farm.capture.learn import learn as learn_profiles
    from enip_farm.device.profile_file import write_profile
    from enip_farm.words import plural

    try:
        profiles = learn_profiles(capture, name, device=device)
    except ValueError as error:  # CaptureError, LearnError
        click.echo(str(error), err=True)
        sys.exit(2)
    several = len(profiles) > 1
    if several and output.suffix in (".yaml", ".yml"):
        click.echo(f"{capture} holds {len(profiles)} devices ({', '.join(p.device for p in profiles)}): "
                   "give -o a directory for one profile each, or --device IP", err=True)
        sys.exit(2)
    if several:
        output.mkdir(parents=True, exist_ok=True)
    for profile in profiles:
        path = output / (re.sub(r"[^\w.-]", "_", profile.name) + ".yaml") if output.is_dir() else output
        write_profile(path, profile.document, f"enip-farm profile learned from {capture.name} (device "
                      f"{profile.device}); values listed under unverified are placeholders or guesses.", profile.notes)
        model = profile.model
        click.echo(f"{path}: device {profile.device}, model {profile.name}, "
                   f"{plural(len(model['replay']), 'replay entry', 'replay entries')}, "
                   f"unverified: {', '.join(model['unverified']) or 'nothing'}")
        for note in profile.notes:
            click.echo(f"  {note}")


COMMANDS = (golden, learn)
