"""`enip-farm io get|set|watch`: a running farm's I/O through its HTTP API (cli/api.py)."""

from __future__ import annotations

from urllib.parse import quote

import click

from enip_farm.cli.options import api_option, token_option

#: What `io set` takes after SIGNAL=, said when it is given something else.
VALUES = ("a number: 0 or 1 for a digital signal (DI3=1), an integer for a group or analog one (goProgramNo=5, "
          "AI1=0x4B0), a decimal for a scaled one (AI1=2.5), or integers separated by commas for a range "
          "(DI1-4=1,0,1,1)")


def _print_io(io: dict) -> None:
    click.echo(f"inputs  {io['inputs']}\noutputs {io['outputs']}")
    for kind, values in io["signals"].items():
        click.echo(f"{kind:7} " + " ".join(f"{kind}{i}={v}" for i, v in enumerate(values, 1)))
    for name, value in io.get("named", {}).items():
        click.echo(f"{name} = {value}")


def parse_value(assignment: str) -> tuple[str, int | float | list[int]]:
    """`SIGNAL=VALUE` as the API takes it; anything else is refused, saying what is accepted."""
    name, equals, value = assignment.partition("=")
    try:
        if not name or not equals:
            raise ValueError(assignment)
        if "," in value:
            return name, [int(item, 0) for item in value.split(",")]
        return name, int(value, 0) if "." not in value else float(value)
    except ValueError:
        raise click.BadParameter(f"{assignment!r}: expected SIGNAL=VALUE, VALUE being {VALUES}",
                                 param_hint="SIGNAL=VALUE") from None


@click.group()
def io() -> None:
    """Read and write a running farm's I/O."""


@io.command("get")
@click.argument("device")
@click.argument("names", nargs=-1, metavar="[SIGNAL...]")
@api_option
@token_option
def io_get(device: str, names: tuple[str, ...], api: str, token: str | None) -> None:
    """Show a device's images and signals, or only the signals named, one `NAME = VALUE` line each:
    `enip-farm io get io1 goProgramNo DI1-4`."""
    from enip_farm.cli.api import call

    if not names:
        _print_io(call(api, token, "GET", f"/devices/{quote(device, safe='')}/io"))
        return
    for name in names:
        row = call(api, token, "GET", f"/devices/{quote(device, safe='')}/io/{quote(name, safe='')}")
        click.echo(f"{row['name']} = {row['value']}")


@io.command("set")
@click.argument("device")
@click.argument("assignments", nargs=-1, required=True, metavar="SIGNAL=VALUE...")
@api_option
@token_option
def io_set(device: str, assignments: tuple[str, ...], api: str, token: str | None) -> None:
    """Set signals of a device, SIGNAL=VALUE each.

    For example `enip-farm io set io1 DI3=1 AI1=1200` or `enip-farm io set cell1 diGripperClosed=1`."""
    signals = dict(parse_value(assignment) for assignment in assignments)
    from enip_farm.cli.api import call

    _print_io(call(api, token, "PUT", f"/devices/{quote(device, safe='')}/io", json={"signals": signals}))


@io.command("watch")
@click.argument("device")
@click.option("--json", "as_json", is_flag=True, help="print each event's JSON as the API sends it")
@api_option
@token_option
def io_watch(device: str, as_json: bool, api: str, token: str | None) -> None:
    """Print a device's I/O changes as they happen, one line each, until Ctrl-C.

    Each line is one "io" event of the API's event stream: the signals of one image that changed
    within 20 ms, with their old and new values (changes that undo themselves within it do not show)."""
    import os
    import signal
    import sys
    from datetime import datetime

    from enip_farm.cli.api import events

    def interrupted(*_: object) -> None:
        """Ctrl-C ends the watch at once, exit 0: what was printed is flushed, and nothing of the
        stream's teardown (which a busy farm can hold up) stands in the way."""
        sys.stdout.flush()
        os._exit(0)

    previous = signal.signal(signal.SIGINT, interrupted)
    try:
        with events(api, token, {"device": device, "kind": "io"}) as stream:
            for event in stream:
                if event.event == "lost":
                    click.echo(f"{event.json()['lost']} events lost: this reader fell behind", err=True)
                elif as_json:
                    click.echo(event.data)
                else:
                    fields = event.json()
                    clock = datetime.fromtimestamp(fields["time"]).strftime("%H:%M:%S.%f")[:-3]
                    click.echo(f"{clock} {fields['device']} {fields['detail']}")
    except KeyboardInterrupt:
        return
    finally:
        signal.signal(signal.SIGINT, previous)
    click.echo("the farm ended the event stream", err=True)
    sys.exit(1)


COMMANDS = (io,)
