"""`enip-farm eio import|export`: RobotWare's I/O configuration (EIO.cfg, enip_farm/eio/)."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from enip_farm.cli.options import config_option


@click.group()
def eio() -> None:
    """RobotWare's I/O configuration (EIO.cfg): import a controller's devices and signals, export the farm's."""


@eio.command("import")
@click.argument("cfg_path", metavar="EIO.cfg", type=click.Path(dir_okay=False, path_type=Path))
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="write the cell configuration here ('-' or none: standard output)")
@click.option("--base-address", default=None, metavar="IP",
              help="renumber the devices from this address, e.g. 127.0.20.1 for a desk run (default: the "
                   "controller's addresses)")
def eio_import(cfg_path: Path, output: Path | None, base_address: str | None) -> None:
    """Make a cell configuration of a controller's EIO.cfg: each EtherNet/IP device it scans, with the
    identity, assemblies and sizes it expects, and its named signals. Warnings (one line each) say
    what was not imported or is unknown; nothing unknown is fatal."""
    from ipaddress import AddressValueError, IPv4Address

    from enip_farm.device.catalogue import shipped_catalogue
    from enip_farm.eio.cfg import CfgError, parse_cfg
    from enip_farm.eio.importer import EioError, import_eio
    from enip_farm.words import plural

    try:
        base = IPv4Address(base_address) if base_address is not None else None
    except AddressValueError as error:
        raise click.BadParameter(str(error), param_hint="--base-address") from None
    try:
        text = cfg_path.read_text(encoding="utf-8", errors="replace")
    except OSError as error:
        click.echo(f"{cfg_path}: cannot read: {error.strerror}", err=True)
        sys.exit(2)
    try:
        result = import_eio(parse_cfg(text, str(cfg_path)), shipped_catalogue(), base)
    except (CfgError, EioError) as error:
        for warning in getattr(error, "warnings", ()):
            click.echo(warning, err=True)
        click.echo(str(error), err=True)
        sys.exit(2)
    for warning in result.warnings:
        click.echo(warning, err=True)
    if output is None or str(output) == "-":
        click.echo(result.yaml, nl=False)
        return
    output.write_text(result.yaml)
    click.echo(f"{output}: {plural(result.device_count, 'device')}, {plural(result.signal_count, 'named signal')}, "
               f"{plural(len(result.warnings), 'warning')}", err=True)


@eio.command("export")
@config_option
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="write EIO.cfg here ('-' or none: standard output)")
def eio_export(config_path: Path | None, output: Path | None) -> None:
    """Write the EIO.cfg entries a controller needs to scan the farm's devices (ETHERNETIP_DEVICE)
    and their named signals (EIO_SIGNAL)."""
    from enip_farm.cli.cell import load_cell
    from enip_farm.config import ConfigError
    from enip_farm.device.catalogue import shipped_catalogue
    from enip_farm.eio.exporter import ExportError, export_eio
    from enip_farm.words import plural

    config = load_cell(config_path, build=False)
    try:
        text = export_eio(config, shipped_catalogue())
    except (ConfigError, ExportError) as error:
        click.echo(str(error), err=True)
        sys.exit(2)
    if output is None or str(output) == "-":
        click.echo(text, nl=False)
        return
    output.write_text(text)
    click.echo(f"{output}: {plural(len(config.devices), 'device')}, "
               f"{plural(sum(len(d.signals) for d in config.devices), 'named signal')}", err=True)


COMMANDS = (eio,)
