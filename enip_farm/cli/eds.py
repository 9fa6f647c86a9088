"""`enip-farm eds export|import`: Electronic Data Sheets (enip_farm/eds/)."""

from __future__ import annotations

import sys
from pathlib import Path

import click


@click.group()
def eds() -> None:
    """Electronic Data Sheets: write one for a catalogue model, make a profile of a vendor's."""


@eds.command("export")
@click.argument("model")
@click.option("--addons", multiple=True, metavar="ADDON[,ADDON...]",
              help="add-on modules in slot order (repeat the option or separate with commas)")
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="the EDS file to write ('-': standard output)")
def eds_export(model: str, addons: tuple[str, ...], output: Path) -> None:
    """Write the EDS of a catalogue model (or a profile file) as the farm serves it; the catalogue's
    unverified placeholders are marked UNVERIFIED in it."""
    import datetime

    from enip_farm.config import ConfigError
    from enip_farm.device.catalogue import shipped_catalogue
    from enip_farm.eds.writer import model_profile, write_eds

    names = [name for item in addons for name in item.split(",") if name]
    try:
        profile = model_profile(model, names, shipped_catalogue(), Path.cwd())
    except ConfigError as error:
        click.echo(str(error), err=True)
        sys.exit(2)
    text = write_eds(profile, datetime.datetime.now())
    if str(output) == "-":
        click.echo(text, nl=False)
        return
    output.write_text(text)
    click.echo(f"{output}: EDS of {' + '.join((profile.model, *profile.addons))}; "
               f"UNVERIFIED: {', '.join(profile.unverified) or 'nothing'}", err=True)


@eds.command("import")
@click.argument("source", type=click.Path(path_type=Path))
@click.option("-o", "--output", type=click.Path(path_type=Path), required=True,
              help="the profile file to write (name it as a device's model: `model: PROFILE.yaml`); for a "
                   "folder of EDS files, the folder to write one profile per file into")
@click.option("--name", default=None,
              help="the model's name (default: the EDS's product name); never a model of the catalogue")
def eds_import(source: Path, output: Path, name: str | None) -> None:
    """Make a catalogue profile (identity, assemblies, every class-1 connection) from a vendor's EDS
    file, or from each EDS file of a folder."""
    if source.is_dir():
        sources = sorted(p for p in source.iterdir() if p.suffix.lower() == ".eds")
        output.mkdir(parents=True, exist_ok=True)
        failed = sum(not _import_one(path, output / f"{path.stem}.yaml", None) for path in sources)
        click.echo(f"{len(sources) - failed} of {len(sources)} EDS files imported into {output}")
        sys.exit(2 if failed else 0)
    if not _import_one(source, output, name):
        sys.exit(2)


def _import_one(source: Path, output: Path, name: str | None) -> bool:
    from enip_farm.device.profile_file import write_profile
    from enip_farm.eds.grammar import decode_eds_bytes
    from enip_farm.eds.reader import eds_profile, read_eds
    from enip_farm.words import plural

    try:
        device = read_eds(decode_eds_bytes(source.read_bytes()), str(source))
        model_name, document, notes = eds_profile(device, source.name, name)
    except OSError as error:
        click.echo(f"{source}: {error.strerror}", err=True)
        return False
    except ValueError as error:  # EdsError: one line per defect
        click.echo(str(error), err=True)
        return False
    write_profile(output, document, f"enip-farm profile made from {source.name} by `enip-farm eds import`.", notes)
    model = document["models"][model_name]
    served = f"{plural(len(model['connections']), 'class-1 connection')}" if model["connections"] else "explicit only"
    click.echo(f"{output}: model {model_name}, assemblies {model.get('assemblies', {})}, sizes "
               f"{model.get('sizes', {})}, {served}")
    for note in notes:
        click.echo(f"  {note}")
    return True


COMMANDS = (eds,)
