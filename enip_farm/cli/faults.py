"""`enip-farm fault` and `enip-farm reset`: faults and resets of a running farm's devices through
its HTTP API. The fault kinds and their parameters are the farm's (GET /fault-kinds), not the CLI's."""

from __future__ import annotations

import re
import sys
from types import MappingProxyType
from typing import Any

import click

from enip_farm.cli.options import api_option, token_option

#: The `fault` command's flags for the parameters of the kinds the farm has had from the start; any
#: parameter of any kind is also taken as NAME=VALUE (`enip-farm fault --list` names them).
FLAGS = MappingProxyType({"max_delay_ms": "--max-delay-ms", "delay_ms": "--delay-ms", "duration_s": "--duration",
                          "service": "--service", "status": "--status"})
EXAMPLES = MappingProxyType({"--delay-ms": " (e.g. --delay-ms 800)",
                             "--service": " (e.g. --service 0x0E --status 0x08)",
                             "--status": " (e.g. --service 0x0E --status 0x08)"})


def _number(text: str) -> int | float | str:
    for parse in (lambda t: int(t, 0), float):
        try:
            return parse(text)
        except ValueError:
            continue
    return text


def _flag_number(text: str) -> int | float:
    """A flag's number as written: 800 an integer (the farm's messages say 800, not 800.0), 2.5 a decimal."""
    value = _number(text)
    if isinstance(value, str):
        raise ValueError(f"{text!r} is not a number")
    return value


def in_flags(detail: str) -> str:
    """A parameter problem (`field: message`, the farm's words) in the CLI's: flags, not field names."""
    field, _, message = detail.partition(": ")
    message = message.removeprefix(f"{field}: ")  # the API's error names the field twice: where, and in its text
    for name in sorted((n for n in FLAGS if "_" in n), key=len, reverse=True):  # no word of prose; max_ first
        message = re.sub(rf"(?<![\w-]){name}\b", FLAGS[name], message)
    flag = FLAGS.get(field, field)
    return f"{flag}: {message}{EXAMPLES.get(flag, '')}"


def _listing(kinds: list[dict[str, Any]], parameters: bool = True) -> str:
    """One line per kind (its summary), and one per parameter under it unless `parameters` is False."""
    width = max(len(kind["kind"]) for kind in kinds)
    lines = []
    for kind in kinds:
        lines.append(f"{'  ' if not parameters else ''}{kind['kind']:{width}}  {kind['summary']}")
        for name in kind["parameters"].get("properties", {}) if parameters else ():
            schema = kind["parameters"]["properties"][name]
            flag = f" ({FLAGS[name]})" if name in FLAGS else ""
            lines.append(f"{'':{width}}    {name}=VALUE{flag}: {schema.get('description', schema.get('type', ''))}")
    return "\n".join(lines)


@click.command()
@click.argument("first", required=False, metavar="DEVICE|clear")
@click.argument("rest", nargs=-1, metavar="KIND [NAME=VALUE...] | DEVICE [KIND]")
@click.option("--list", "list_kinds", is_flag=True, help="list the farm's fault kinds and their parameters")
@click.option("--delay-ms", type=_flag_number, default=None, help="delay: how long to hold each reply")
@click.option("--max-delay-ms", type=_flag_number, default=None, help="delay: random up to this")
@click.option("--service", type=lambda v: int(v, 0), default=None, help="status: the CIP service, e.g. 0x0E")
@click.option("--status", type=lambda v: int(v, 0), default=None, help="status: the general status, e.g. 0x08")
@click.option("--duration", "duration_s", type=_flag_number, default=None,
              help="seconds until the fault ends by itself")
@api_option
@token_option
def fault(first: str | None, rest: tuple[str, ...], list_kinds: bool, api: str, token: str | None,
          **flags: Any) -> None:
    """Inject a fault: `fault DEVICE|GROUP KIND [NAME=VALUE...] [options]` (a group: every member at
    once), or end them: `fault clear DEVICE|GROUP [KIND]`. `fault --list` lists the kinds the farm has
    and their parameters."""
    from urllib.parse import quote

    from enip_farm.cli.api import call

    if list_kinds:
        click.echo(_listing(call(api, token, "GET", "/fault-kinds")))
        return
    if first == "clear":
        if len(rest) not in (1, 2):
            raise click.UsageError("fault clear DEVICE|GROUP [KIND]")
        params = {"kind": rest[1]} if len(rest) == 2 else None
        cleared = call(api, token, "DELETE", f"{_where(api, token, rest[0])}/{quote(rest[0], safe='')}/faults",
                       params=params)
        click.echo(f"{rest[0]}: cleared {', '.join(cleared['cleared']) or 'nothing'}")
        return
    if first is None or not rest:
        raise click.UsageError("fault DEVICE KIND [NAME=VALUE...] [options] (fault --list: the kinds)")
    kind, assignments = rest[0], rest[1:]
    body: dict[str, Any] = {name: value for name, value in flags.items() if value is not None}
    said = {name: FLAGS[name] for name in body}  # each parameter as the command line gave it
    for assignment in assignments:
        name, equals, value = assignment.partition("=")
        if not equals or not name:
            raise click.UsageError(f"{assignment!r}: expected NAME=VALUE (fault --list: each kind's parameters)")
        body[name], said[name] = _number(value), name
    kinds = {item["kind"]: item for item in call(api, token, "GET", "/fault-kinds")}
    if kind not in kinds:
        import difflib

        close = difflib.get_close_matches(kind, kinds, n=1)
        hint = f" (did you mean {close[0]}?)" if close else ""
        click.echo(f"fault {first} {kind}: unknown kind {kind!r}{hint}; the farm's kinds (fault --list: their "
                   f"parameters):\n" + _listing(list(kinds.values()), parameters=False), err=True)
        sys.exit(2)
    known = set(kinds[kind]["parameters"].get("properties", {})) | {"duration_s"}
    for name in body:
        if name not in known:
            takes = ", ".join(sorted(known - {"duration_s"})) or "no parameter"
            click.echo(f"fault {first} {kind}: {said[name]}: not a parameter of {kind} "
                       f"(it takes {takes}, and --duration)", err=True)
            sys.exit(2)
    active = _inject(api, token, first, kind, body)
    click.echo(f"{first}: active faults: " + ", ".join(f["kind"] for f in active))


def _where(api: str, token: str | None, name: str) -> str:
    """/groups for a group of the farm's topology, /devices otherwise."""
    from enip_farm.cli.api import call

    return "/groups" if any(group["name"] == name for group in call(api, token, "GET", "/groups")) else "/devices"


def _inject(api: str, token: str | None, device: str, kind: str, body: dict[str, Any]) -> list[dict[str, Any]]:
    """A fault on a device (its active faults) or on every device of a group (the first member's)."""
    from urllib.parse import quote

    from enip_farm.cli.api import ApiError, call

    def refused(error: ApiError) -> None:
        if error.status == 422:  # a parameter the kind refuses: in the CLI's words, a usage error
            click.echo(f"fault {device} {kind}: {in_flags(error.detail)}", err=True)
            sys.exit(2)

    where = _where(api, token, device)
    answer = call(api, token, "POST", f"{where}/{quote(device, safe='')}/faults", refused, json={"kind": kind, **body})
    if where == "/groups":
        click.echo(f"{device}: {kind} on {', '.join(answer)}")
        return next(iter(answer.values()), [])
    return answer


@click.command()
@click.argument("device")
@click.option("--type", "kind", type=click.IntRange(0, 2), default=0, show_default=True,
              help="0 power cycle, 1 out-of-box configuration, 2 out-of-box but the communication parameters")
@api_option
@token_option
def reset(device: str, kind: int, api: str, token: str | None) -> None:
    """Power-cycle or reset a device of a running farm, as its Identity Reset does: its TCP
    connections drop, its connections close, it answers nothing for its reset time."""
    from urllib.parse import quote

    from enip_farm.cli.api import call

    done = call(api, token, "POST", f"/devices/{quote(device, safe='')}/reset", json={"type": kind})
    click.echo(f"{device}: reset type {kind}, answering again in {done['reset_time_s']:g} s")


COMMANDS = (fault, reset)
