"""Commands about a cell configuration: `validate`, `models`, `addresses`, `probe`, `compose`."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from enip_farm.cli.options import config_option, shard_option, table


@click.command()
@click.argument("config_path", type=click.Path(path_type=Path))
def validate(config_path: Path) -> None:
    """Check a cell configuration without binding anything; warn of addresses this host does not have."""
    from enip_farm.cli.cell import load_cell
    from enip_farm.config import device_location
    from enip_farm.farm.listeners import is_host_address
    from enip_farm.words import plural

    config = load_cell(config_path)
    elsewhere = [device for device in config.devices if not is_host_address(str(device.address))]
    for device in elsewhere[:5]:
        click.echo(f"{config_path}: warning: {device_location(device.entry, device.name)}: {device.address} is not an "
                   "address of this host, so serve cannot bind it here", err=True)
    if elsewhere:
        more = f" (and {len(elsewhere) - 5} more)" if len(elsewhere) > 5 else ""
        click.echo(f"{config_path}: warning: add each address to this host{more}, e.g. `sudo ip addr add "
                   f"{elsewhere[0].address}/32 dev lo`, or move the devices to 127.x addresses (every one is this "
                   "host's on Linux; `eio import --base-address 127.0.20.1` renumbers an import)", err=True)
    off = f"; {plural(len(elsewhere), 'address', 'addresses')} not on this host" if elsewhere else ""
    click.echo(f"{config_path}: {plural(len(config.devices), 'device')}, valid{off}")


@click.command()
def models() -> None:
    """List the catalogue's models; UNVERIFIED marks unpublished placeholder values."""
    from enip_farm.device.catalogue import shipped_catalogue

    rows = []
    for name, model in shipped_catalogue().models.items():
        channels = ", ".join(f"{count} {kind.upper()}" for kind, count in model.io.model_dump().items() if count)
        identity = ""
        if model.identity:
            i = model.identity
            identity = (f"vendor {i.vendor_id} type {i.device_type} code {i.product_code} "
                        f"rev {i.revision[0]}.{i.revision[1]}")
        rows.append([name, model.kind, channels or "-", identity or "-",
                     "UNVERIFIED: " + ", ".join(model.unverified) if model.unverified else ""])
    click.echo(table(rows, ["MODEL", "KIND", "I/O", "IDENTITY", "PLACEHOLDERS"]))
    click.echo("\nUNVERIFIED values are placeholders: ABB does not publish them. Override them per device "
               "(identity:, assemblies:) from your EDS file, EIO.cfg or a capture.")


@click.command()
@config_option
@shard_option
def addresses(config_path: Path | None, shard_spec: str | None) -> None:
    """Print the device addresses a farm would bind, one per line (the container entrypoint adds
    them as aliases)."""
    from enip_farm.cli.cell import load_cell, select

    for device in select(load_cell(config_path), shard_spec).devices:
        click.echo(str(device.address))


@click.command()
@config_option
@shard_option
@click.option("--timeout", type=float, default=2.0, show_default=True)
def probe(config_path: Path | None, shard_spec: str | None, timeout: float) -> None:
    """Send ListIdentity (UDP) to every device of a config; exit 0 only if all answer."""
    from enip_farm.cli.cell import load_cell, select
    from enip_farm.cli.prober import list_identity
    from enip_farm.words import plural

    wanted = [str(d.address) for d in select(load_cell(config_path), shard_spec).devices]
    answered = list_identity(wanted, timeout)
    click.echo(f"{len(answered)}/{plural(len(wanted), 'device')} answered ListIdentity")
    if len(answered) != len(wanted):
        missing = sorted(set(wanted) - answered)
        click.echo("silent: " + ", ".join(missing[:20]) + (" ..." if len(missing) > 20 else ""), err=True)
        sys.exit(1)


@click.command()
@click.option("--config", "config_path", type=click.Path(path_type=Path), required=True,
              help="the cell, as the containers will see it (mounted at /etc/enip-farm/cell.yaml)")
@click.option("--shards", type=click.IntRange(1, 64), default=1, show_default=True)
@click.option("--subnet", default="192.168.125.0/24", show_default=True)
@click.option("--container-range", default="192.168.125.240/28", show_default=True,
              help="where Docker may place containers (keep the devices' addresses outside it)")
@click.option("--api-port", type=click.IntRange(0, 65535), default=8044, show_default=True,
              help="farm i's HTTP API on the host's 127.0.0.1:PORT+i-1 (0: not published)")
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="write the compose file here (paths in it are relative to its directory); default: stdout")
def compose(config_path: Path, shards: int, subnet: str, container_range: str, api_port: int,
            output: Path | None) -> None:
    """Print a compose file: one farm container per shard and a tester that reads every device."""
    from enip_farm.cli.cell import load_cell
    from enip_farm.engines.compose import compose_file

    source = Path(__file__).resolve().parents[2]  # a source checkout builds the image; an install uses it
    compose_dir = output.resolve().parent if output else Path.cwd()
    try:
        text = compose_file(load_cell(config_path), config_path, compose_dir, shards, subnet, container_range,
                            api_port, source if (source / "docker" / "Dockerfile").is_file() else None)
    except ValueError as error:
        raise click.BadParameter(str(error), param_hint="--shards/--container-range") from None
    if output:
        output.write_text(text)
        click.echo(f"wrote {output}", err=True)
    else:
        click.echo(text, nl=False)


COMMANDS = (validate, models, addresses, probe, compose)
