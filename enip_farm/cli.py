"""The `enip-farm` command: serve, validate, models."""

from __future__ import annotations

import asyncio
import re
import signal
import sys
from pathlib import Path
from types import MappingProxyType
from typing import Any
from urllib.parse import urlsplit

import click

from enip_farm.cli_engines import COMMANDS as engine_commands
from enip_farm.config import ConfigError, FarmConfig, default_config_path, load_config
from enip_farm.console import Console, configure_logging
from enip_farm.device.build import build_profiles
from enip_farm.device.catalogue import shipped_catalogue
from enip_farm.device.faults import Fault, FaultError, FaultKind
from enip_farm.eds.reader import eds_catalogue
from enip_farm.farm import BindError, Farm, freeze_heap, new_event_loop, until_stopped_or_failed
from enip_farm.fleet import shard
from enip_farm.table import device_table

#: Where the CLI's client commands look for the farm's HTTP API (serve --http 8044).
DEFAULT_API = "http://127.0.0.1:8044"


def _load(path: Path | None, build: bool = True) -> FarmConfig:
    """The configuration, checked by building its devices (models, add-ons, profile files, wiring)
    unless the caller builds a Farm of it at once (`build=False`, then see `_farm`)."""
    try:
        config = load_config(path or default_config_path())
        if build:
            build_profiles(config, eds_catalogue())
    except ConfigError as error:
        click.echo(str(error), err=True)
        sys.exit(2)
    return config


def _farm(config: FarmConfig, **options: Any) -> Farm:
    try:
        return Farm(config, **options)
    except ConfigError as error:
        click.echo(str(error), err=True)
        sys.exit(2)


def _table(rows: list[list[str]], headers: list[str]) -> str:
    widths = [max(len(str(row[i])) for row in [headers, *rows]) for i in range(len(headers))]
    lines = ["  ".join(str(cell).ljust(width) for cell, width in zip(row, widths, strict=True)).rstrip()
             for row in [headers, *rows]]
    return "\n".join(lines)


def _select(config: FarmConfig, shard_spec: str | None) -> FarmConfig:
    if not shard_spec:
        return config
    try:
        return shard(config, shard_spec)
    except ValueError as error:
        raise click.BadParameter(str(error), param_hint="--shard") from None


@click.group()
@click.version_option(package_name="enip-farm")
def main() -> None:
    """Virtual EtherNet/IP I/O devices (ABB scalable I/O) for testing robot controller software."""


def _http_address(text: str | None) -> tuple[str, int] | None:
    """--http [HOST:]PORT: (host, port), localhost when no host is given; a port out of 0..65535 or
    text that is no port is refused (click's usage error, exit 2)."""
    if not text:
        return None
    host, _, port = text.rpartition(":")
    host = host.removeprefix("[").removesuffix("]")
    if not port.isdigit():
        raise click.BadParameter(f"{text!r}: expected [HOST:]PORT, e.g. 8044 or 127.0.0.1:8044", param_hint="--http")
    if not 0 <= int(port) <= 65535:
        raise click.BadParameter(f"{text!r}: the port {int(port)} is out of range (0..65535; 0 picks a free one)",
                                 param_hint="--http")
    return host or "127.0.0.1", int(port)


def _banner(devices: int, config: FarmConfig, config_path: Path | None, http_url: str | None) -> list[str]:
    """What `serve` says once every device listens: the configuration it loaded, where the HTTP API
    and the dashboard are (or how to get them)."""
    source = f"{config.source} (the default cell)" if config_path is None else config.source
    lines = [f"{devices} devices listening on TCP and UDP 44818, from {source}. Ctrl-C to stop."]
    if http_url:
        lines += [f"HTTP API on {http_url}",
                  f"dashboard on {http_url}/ and API docs on {http_url}/docs; `enip-farm io` and `enip-farm fault` "
                  "use this API" + ("" if http_url == DEFAULT_API else f" with --api {http_url}")]
    else:
        lines.append("no HTTP API: `enip-farm io`, `enip-farm fault` and the dashboard need one (serve --http 8044)")
    return lines


@main.command()
@click.option("--config", "config_path", type=click.Path(path_type=Path), default=None,
              help="cell configuration (YAML); default: the shipped default cell")
@click.option("--log-level", default="info", show_default=True,
              type=click.Choice(["debug", "info", "warning", "error"]),
              help="info: one line per connection, session, Forward Open/Close, timeout, fault and refusal; "
                   "debug: also every request and I/O change")
@click.option("-q", "--quiet", is_flag=True, help="only warnings and errors (timeouts, refusals, faults)")
@click.option("--http", "http", default=None, metavar="[HOST:]PORT",
              help="serve the HTTP API and dashboard (localhost unless a host is given; an address that is not "
                   "loopback needs --token)")
@click.option("--token", envvar="ENIP_FARM_TOKEN", default=None, help="bearer token for the HTTP API")
@click.option("--workers", type=click.IntRange(1, 256), default=1, show_default=True,
              help="processes, each serving a slice of the devices (worker i's HTTP API on PORT + i)")
@click.option("--shard", "shard_spec", envvar="ENIP_FARM_SHARD", default=None, metavar="I/N",
              help="serve only slice I of N (N farms started from one config, e.g. one per host; "
                   "or ENIP_FARM_SHARD)")
@click.option("--record", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="write every TCP and UDP exchange to this pcap file")
@click.option("--heartbeat", envvar="ENIP_FARM_HEARTBEAT", type=click.Path(dir_okay=False, path_type=Path),
              default=None, help="set this file's time every second while cyclic I/O runs (worker i: FILE.i); "
                                 "docker/healthcheck.sh reads it (or ENIP_FARM_HEARTBEAT)")
@click.option("--state", "state", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="keep the devices' non-volatile state (a safety target's TUNID, configuration, owner) in this "
                   "JSON file across restarts: read at start, written at stop")
def serve(config_path: Path | None, log_level: str, quiet: bool, http: str | None, token: str | None, workers: int,
          shard_spec: str | None, record: Path | None, heartbeat: Path | None, state: Path | None) -> None:
    """Serve every device of a cell until Ctrl-C or SIGTERM, logging what happens to them."""
    address = _http_address(http)
    configure_logging(log_level, quiet)
    config = _select(_load(config_path, build=bool(shard_spec) or workers > 1), shard_spec)
    if workers > 1:
        if record or state:
            raise click.UsageError("--record and --state write one file: use them with --workers 1")
        from enip_farm.workers import serve_workers

        sys.exit(serve_workers(config, workers, address, token, log_level, quiet, heartbeat))
    farm = _farm(config, http=address, token=token, record=record, heartbeat=heartbeat, state=state)
    loop = new_event_loop()
    asyncio.set_event_loop(loop)
    try:
        loop.run_until_complete(_serve(farm, config_path))
    except BindError as error:
        click.echo(str(error), err=True)
        sys.exit(1)
    finally:
        loop.close()
    if farm.failure is not None:
        sys.exit(1)


async def _serve(farm: Farm, config_path: Path | None) -> None:
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    await farm.start()
    console = Console(farm.devices.values(), also_flush=[farm.tcp_limits.log] if farm.tcp_limits else [])
    console.start(loop)
    freeze_heap()
    try:
        click.echo(device_table(farm.devices.values()))
        for line in _banner(len(farm.devices), farm.config, config_path,
                            farm.http.url if farm.http is not None else None):
            click.echo(line, err=True)
        click.echo(f"cyclic I/O budget: {farm.budget.describe()}", err=True)
        await until_stopped_or_failed(stop, farm)
    finally:
        console.close()
        await farm.stop()


@main.command()
@click.argument("config_path", type=click.Path(path_type=Path))
def validate(config_path: Path) -> None:
    """Check a cell configuration without binding anything."""
    config = _load(config_path)
    click.echo(f"{config_path}: {len(config.devices)} devices, valid")


@main.command()
def models() -> None:
    """List the catalogue's models; UNVERIFIED marks unpublished placeholder values."""
    catalogue = shipped_catalogue()
    rows = []
    for name, model in catalogue.models.items():
        io = model.io
        channels = ", ".join(f"{count} {kind.upper()}" for kind, count in io.model_dump().items() if count)
        identity = ""
        if model.identity:
            i = model.identity
            identity = (f"vendor {i.vendor_id} type {i.device_type} code {i.product_code} "
                        f"rev {i.revision[0]}.{i.revision[1]}")
        rows.append([name, model.kind, channels or "-", identity or "-",
                     "UNVERIFIED: " + ", ".join(model.unverified) if model.unverified else ""])
    click.echo(_table(rows, ["MODEL", "KIND", "I/O", "IDENTITY", "PLACEHOLDERS"]))
    click.echo("\nUNVERIFIED values are placeholders: ABB does not publish them. Override them per device "
               "(identity:, assemblies:) from your EDS file, EIO.cfg or a capture.")


# -- the HTTP API's client -----------------------------------------------------------------------

_api_option = click.option("--api", envvar="ENIP_FARM_API", default=DEFAULT_API, show_default=True,
                           help="the farm's HTTP API (or ENIP_FARM_API)")
_token_option = click.option("--token", envvar="ENIP_FARM_TOKEN", default=None,
                             help="bearer token (or ENIP_FARM_TOKEN)")


def _request(method: str, api: str, path: str, token: str | None, **kwargs: object) -> object:
    import httpx

    headers = {"Authorization": f"Bearer {token}"} if token else {}
    try:
        response = httpx.request(method, api.rstrip("/") + path, headers=headers, timeout=10, **kwargs)
    except httpx.ConnectError as error:
        port = urlsplit(api).port or 8044
        click.echo(f"cannot reach the farm's HTTP API at {api} ({_reason(error)}): is the farm running with its "
                   f"HTTP API? Start it with `enip-farm serve --http {port}`, or give the API's address with --api "
                   "(or ENIP_FARM_API).", err=True)
        sys.exit(1)
    except httpx.HTTPError as error:
        click.echo(f"the farm's HTTP API at {api} did not answer: {_reason(error)}", err=True)
        sys.exit(1)
    if response.status_code >= 400:
        click.echo(f"{method} {path}: {response.status_code} {_detail(response)}", err=True)
        sys.exit(1)
    return response.json()


def _reason(error: Exception) -> str:
    """The innermost reason of a connection error, e.g. `[Errno 111] Connection refused`."""
    text = str(error)
    return text.rsplit("] ", 1)[-1].strip() if text.startswith("[") and "] " in text else text or type(error).__name__


def _detail(response: object) -> str:
    """An error reply's detail in one line: FastAPI's list of validation errors as `field: message`."""
    try:
        detail = response.json().get("detail")  # type: ignore[attr-defined]
    except ValueError:
        return response.text  # type: ignore[attr-defined, no-any-return]
    if isinstance(detail, list):
        return "; ".join(f"{'.'.join(str(p) for p in item.get('loc', ())[1:]) or 'request'}: {item.get('msg', item)}"
                         if isinstance(item, dict) else str(item) for item in detail)
    return str(detail)


def _print_io(io: dict) -> None:
    click.echo(f"inputs  {io['inputs']}\noutputs {io['outputs']}")
    for kind, values in io["signals"].items():
        click.echo(f"{kind:7} " + " ".join(f"{kind}{i}={v}" for i, v in enumerate(values, 1)))
    for name, value in io.get("named", {}).items():
        click.echo(f"{name} = {value}")


@main.group()
def io() -> None:
    """Read and write a running farm's I/O."""


@io.command("get")
@click.argument("device")
@click.argument("names", nargs=-1, metavar="[SIGNAL...]")
@_api_option
@_token_option
def io_get(device: str, names: tuple[str, ...], api: str, token: str | None) -> None:
    """Show a device's images and signals, or only the signals named, one `NAME = VALUE` line each:
    `enip-farm io get io1 goProgramNo DI1-4`."""
    if not names:
        _print_io(_request("GET", api, f"/devices/{device}/io", token))  # type: ignore[arg-type]
        return
    from urllib.parse import quote

    for name in names:
        row = _request("GET", api, f"/devices/{quote(device)}/io/{quote(name)}", token)
        click.echo(f"{row['name']} = {row['value']}")  # type: ignore[index]


@io.command("set")
@click.argument("device")
@click.argument("assignments", nargs=-1, required=True, metavar="SIGNAL=VALUE...")
@_api_option
@_token_option
def io_set(device: str, assignments: tuple[str, ...], api: str, token: str | None) -> None:
    """Set signals, e.g. `enip-farm io set io1 DI3=1 AI1=1200` or `io set cell1 diGripperClosed=1`."""
    signals: dict[str, int | float] = {}
    for assignment in assignments:
        name, _, value = assignment.partition("=")
        try:
            signals[name] = int(value, 0) if "." not in value else float(value)
        except ValueError:
            raise click.BadParameter(f"{assignment!r}: expected SIGNAL=VALUE") from None
    _print_io(_request("PUT", api, f"/devices/{device}/io", token, json={"signals": signals}))  # type: ignore[arg-type]


@io.command("watch")
@click.argument("device")
@click.option("--json", "as_json", is_flag=True, help="print each event's JSON as the API sends it")
@_api_option
@_token_option
def io_watch(device: str, as_json: bool, api: str, token: str | None) -> None:
    """Print a device's I/O changes as they happen, one line each, until Ctrl-C.

    Each line is one "io" event of the API's event stream: the signals of one image that changed
    within 20 ms, with their old and new values (changes that undo themselves within it do not show)."""
    try:
        _watch(api, {"device": device, "kind": "io"}, token, as_json)
    except KeyboardInterrupt:
        return


def _watch(api: str, params: dict[str, str], token: str | None, as_json: bool) -> None:
    import json
    from datetime import datetime

    import httpx

    headers = {"Authorization": f"Bearer {token}"} if token else {}
    try:
        with httpx.stream("GET", api.rstrip("/") + "/events", params=params, headers=headers,
                          timeout=httpx.Timeout(10, read=None)) as response:
            if response.status_code >= 400:
                response.read()
                detail = (response.json().get("detail") if "json" in response.headers.get("content-type", "")
                          else response.text)
                click.echo(f"GET /events: {response.status_code} {detail}", err=True)
                sys.exit(1)
            kind = "message"
            for line in response.iter_lines():
                if line.startswith("event: "):
                    kind = line[7:]
                elif line.startswith("data: ") and kind == "lost":
                    click.echo(f"{json.loads(line[6:])['lost']} events lost: this reader fell behind", err=True)
                elif line.startswith("data: ") and as_json:
                    click.echo(line[6:])
                elif line.startswith("data: "):
                    event = json.loads(line[6:])
                    clock = datetime.fromtimestamp(event["time"]).strftime("%H:%M:%S.%f")[:-3]
                    click.echo(f"{clock} {event['device']} {event['detail']}")
                elif not line:
                    kind = "message"
    except httpx.HTTPError as error:
        click.echo(f"cannot reach the farm at {api}: {error}", err=True)
        sys.exit(1)
    click.echo("the farm ended the event stream", err=True)
    sys.exit(1)


@main.command()
@click.argument("first")
@click.argument("second", required=False)
@click.argument("third", required=False)
@click.option("--delay-ms", type=float, default=0.0, help="delay: how long to hold each reply")
@click.option("--max-delay-ms", type=float, default=None, help="delay: random up to this")
@click.option("--service", type=lambda v: int(v, 0), default=None, help="status: the CIP service, e.g. 0x0E")
@click.option("--status", type=lambda v: int(v, 0), default=None, help="status: the general status, e.g. 0x08")
@click.option("--duration", "duration_s", type=float, default=None, help="seconds until the fault ends by itself")
@_api_option
@_token_option
def fault(first: str, second: str | None, third: str | None, delay_ms: float, max_delay_ms: float | None,
          service: int | None, status: int | None, duration_s: float | None, api: str, token: str | None) -> None:
    """Inject a fault: `fault DEVICE KIND [options]`, or end them: `fault clear DEVICE [KIND]`.

    KIND: delay, drop, close, reset, offline, status, stop-io, identity."""
    if first == "clear":
        if second is None:
            raise click.UsageError("fault clear DEVICE [KIND]")
        query = f"?kind={third}" if third else ""
        cleared = _request("DELETE", api, f"/devices/{second}/faults{query}", token)
        click.echo(f"{second}: cleared {', '.join(cleared['cleared']) or 'nothing'}")  # type: ignore[index]
        return
    if second is None:
        raise click.UsageError("fault DEVICE KIND [options]")
    body = {"kind": second, "delay_ms": delay_ms, "max_delay_ms": max_delay_ms, "service": service,
            "status": status, "duration_s": duration_s}
    try:
        Fault(**body)  # type: ignore[arg-type]  # the farm checks the same; here the message names the flags
    except FaultError as error:
        click.echo(f"fault {first} {second}: {_fault_problem(error)}", err=True)
        sys.exit(2)
    active = _request("POST", api, f"/devices/{first}/faults", token, json=body)
    click.echo(f"{first}: active faults: " + ", ".join(f["kind"] for f in active))  # type: ignore[union-attr]


@main.command()
@click.argument("device")
@click.option("--type", "kind", type=click.IntRange(0, 2), default=0, show_default=True,
              help="0 power cycle, 1 out-of-box configuration, 2 out-of-box but the communication parameters")
@_api_option
@_token_option
def reset(device: str, kind: int, api: str, token: str | None) -> None:
    """Power-cycle or reset a device of a running farm, as its Identity Reset does: its TCP
    connections drop, its connections close, it answers nothing for its reset time."""
    done = _request("POST", api, f"/devices/{device}/reset", token, json={"type": kind})
    click.echo(f"{device}: reset type {kind}, answering again in {done['reset_time_s']:g} s")  # type: ignore[index]


#: The `fault` command's flag for each parameter of a Fault.
_FAULT_FLAGS = MappingProxyType({"max_delay_ms": "--max-delay-ms", "delay_ms": "--delay-ms",
                                 "duration_s": "--duration", "service": "--service", "status": "--status"})


def _fault_problem(error: FaultError) -> str:
    """A fault's parameter problem in the CLI's words: flags, not field names."""
    message = str(error).removeprefix(f"{error.field}: ")
    if error.field == "kind":
        return f"unknown kind {error.value!r}; one of {', '.join(kind.value for kind in FaultKind)}"
    for field in ("max_delay_ms", "delay_ms", "duration_s"):  # names no word of prose; max_ first
        message = re.sub(rf"(?<![\w-]){field}\b", _FAULT_FLAGS[field], message)
    flag = _FAULT_FLAGS.get(error.field, error.field)
    example = {"--delay-ms": " (e.g. --delay-ms 800)", "--service": " (e.g. --service 0x0E --status 0x08)",
               "--status": " (e.g. --service 0x0E --status 0x08)"}.get(flag, "")
    return f"{flag}: {message}{example}"


# -- fleet helpers: container entrypoint, healthcheck, compose generator ---------------------------


@main.command()
@click.option("--config", "config_path", type=click.Path(path_type=Path), default=None)
@click.option("--shard", "shard_spec", envvar="ENIP_FARM_SHARD", default=None, metavar="I/N")
def addresses(config_path: Path | None, shard_spec: str | None) -> None:
    """Print the device addresses a farm would bind, one per line (the container entrypoint adds
    them as aliases)."""
    for device in _select(_load(config_path), shard_spec).devices:
        click.echo(str(device.address))


@main.command()
@click.option("--config", "config_path", type=click.Path(path_type=Path), default=None)
@click.option("--shard", "shard_spec", envvar="ENIP_FARM_SHARD", default=None, metavar="I/N")
@click.option("--timeout", type=float, default=2.0, show_default=True)
def probe(config_path: Path | None, shard_spec: str | None, timeout: float) -> None:
    """Send ListIdentity (UDP) to every device of a config; exit 0 only if all answer."""
    import socket
    import time

    from enip_farm.protocol.encapsulation import ENIP_PORT, Command, decode_frame, encode_frame

    wanted = [str(d.address) for d in _select(_load(config_path), shard_spec).devices]
    answered: set[str] = set()

    def collect(sock: socket.socket, until: float, expected: int) -> None:
        while len(answered) < expected and (remaining := until - time.monotonic()) > 0:
            sock.settimeout(remaining)
            try:
                data, (host, _) = sock.recvfrom(2048)
            except OSError:  # timeout
                return
            try:
                if decode_frame(data).header.command == Command.LIST_IDENTITY:
                    answered.add(host)
            except ValueError:
                continue

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        deadline = time.monotonic() + timeout
        # a few at a time: a burst of replies would overflow one socket's receive buffer
        for start in range(0, len(wanted), 64):
            for address in wanted[start : start + 64]:
                sock.sendto(encode_frame(Command.LIST_IDENTITY), (address, ENIP_PORT))
            collect(sock, min(deadline, time.monotonic() + 0.5), min(start + 64, len(wanted)))
        collect(sock, deadline, len(wanted))
    click.echo(f"{len(answered)}/{len(wanted)} devices answered ListIdentity")
    if len(answered) != len(wanted):
        missing = sorted(set(wanted) - answered)
        click.echo("silent: " + ", ".join(missing[:20]) + (" ..." if len(missing) > 20 else ""), err=True)
        sys.exit(1)


@main.command()
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
    from enip_farm.compose import compose_file

    source = Path(__file__).resolve().parents[1]  # a source checkout builds the image; an install uses it
    compose_dir = output.resolve().parent if output else Path.cwd()
    try:
        text = compose_file(_load(config_path), config_path, compose_dir, shards, subnet, container_range, api_port,
                            source if (source / "docker" / "Dockerfile").is_file() else None)
    except ValueError as error:
        raise click.BadParameter(str(error), param_hint="--shards/--container-range") from None
    if output:
        output.write_text(text)
        click.echo(f"wrote {output}", err=True)
    else:
        click.echo(text, nl=False)


# -- Electronic Data Sheets ---------------------------------------------------------------------


@main.group()
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
    import yaml

    from enip_farm.eds.grammar import decode_eds_bytes
    from enip_farm.eds.reader import eds_profile, read_eds

    try:
        device = read_eds(decode_eds_bytes(source.read_bytes()), str(source))
        model_name, document, notes = eds_profile(device, source.name, name)
    except OSError as error:
        click.echo(f"{source}: {error.strerror}", err=True)
        return False
    except ValueError as error:  # EdsError: one line per defect
        click.echo(str(error), err=True)
        return False
    comments = "".join(f"# {note}\n" for note in notes)
    output.write_text(f"# enip-farm profile made from {source.name} by `enip-farm eds import`.\n{comments}"
                      + yaml.safe_dump(document, sort_keys=False))
    model = document["models"][model_name]
    served = f"{len(model['connections'])} class-1 connections" if model["connections"] else "explicit only"
    click.echo(f"{output}: model {model_name}, assemblies {model.get('assemblies', {})}, sizes "
               f"{model.get('sizes', {})}, {served}")
    for note in notes:
        click.echo(f"  {note}")
    return True


# -- captures ------------------------------------------------------------------------------------


@main.command()
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
    One line per exchange, a summary, exit status 0 only when all pass (1 when one fails, 2 for a
    file that is not a capture or holds no EtherNet/IP exchange)."""
    from contextlib import nullcontext

    from enip_farm.capture.exchanges import exchanges_of
    from enip_farm.capture.golden import replay
    from enip_farm.capture.packets import read_capture

    try:
        read = read_capture(capture)
    except ValueError as error:  # CaptureError: not a capture, or cut short
        click.echo(str(error), err=True)
        sys.exit(2)
    groups = exchanges_of(read.packets)
    captured = sorted({e.device for group in groups for e in group})
    if not captured:
        damaged = f" ({read.damaged} damaged frames skipped)" if read.damaged else ""
        click.echo(f"{capture}: no EtherNet/IP exchanges on port 44818{damaged}", err=True)
        sys.exit(2)
    farm = None if address else _farm(_load(config_path, build=False))
    names: dict[str, str] = {}
    for item in mapping:
        ip, _, name = item.partition("=")
        names[ip] = name
    if not address and not names:
        if device is None and len(captured) > 1:
            raise click.UsageError(f"the capture holds {len(captured)} devices ({', '.join(captured)}): use --map")
        for ip in captured:
            names[ip] = device or next(iter(farm.devices))  # type: ignore[union-attr]

    def target(ip: str) -> str:
        if address:
            return address
        if ip not in names or names[ip] not in farm.devices:  # type: ignore[union-attr]
            raise click.UsageError(f"no farm device for captured address {ip}: use --map {ip}=NAME")
        return farm.devices[names[ip]].profile.address  # type: ignore[union-attr]

    try:
        with farm.running_in_thread() if farm else nullcontext():
            results = replay(groups, target)
    except BindError as error:
        click.echo(str(error), err=True)
        sys.exit(1)
    for result in results:
        click.echo(result.line())
    failed = sum(not r.passed for r in results)
    skipped = f", {read.damaged} damaged frame{'s' if read.damaged > 1 else ''} skipped" if read.damaged else ""
    click.echo(f"{len(results)} exchanges: {len(results) - failed} passed, {failed} failed{skipped}")
    sys.exit(1 if failed else 0)


@main.command()
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
    import yaml

    from enip_farm.capture.learn import learn as learn_profiles

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
        notes = "".join(f"# {note}\n" for note in profile.notes)
        path.write_text(f"# enip-farm profile learned from {capture.name} (device {profile.device}); values listed "
                        f"under unverified are placeholders or guesses.\n{notes}"
                        + yaml.safe_dump(profile.document, sort_keys=False))
        model = profile.model
        click.echo(f"{path}: device {profile.device}, model {profile.name}, {len(model['replay'])} replay entries, "
                   f"unverified: {', '.join(model['unverified']) or 'nothing'}")
        for note in profile.notes:
            click.echo(f"  {note}")


# -- RobotWare's I/O configuration (EIO.cfg) -----------------------------------------------------


@main.group()
def eio() -> None:
    """RobotWare's I/O configuration (EIO.cfg): import a controller's devices and signals, export the farm's."""


@eio.command("import")
@click.argument("cfg_path", metavar="EIO.cfg", type=click.Path(dir_okay=False, path_type=Path))
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="write the cell configuration here; default: stdout")
@click.option("--base-address", default=None, metavar="IP",
              help="renumber the devices from this address, e.g. 127.0.20.1 for a desk run (default: the "
                   "controller's addresses)")
def eio_import(cfg_path: Path, output: Path | None, base_address: str | None) -> None:
    """Make a cell configuration of a controller's EIO.cfg: each EtherNet/IP device it scans, with the
    identity, assemblies and sizes it expects, and its named signals. Warnings (one line each) say
    what was not imported or is unknown; nothing unknown is fatal."""
    from ipaddress import AddressValueError, IPv4Address

    from enip_farm.eio.cfg import CfgError, parse_cfg
    from enip_farm.eio.importer import EioError, import_eio

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
    if output is None:
        click.echo(result.yaml, nl=False)
        return
    output.write_text(result.yaml)
    click.echo(f"{output}: {result.device_count} devices, {result.signal_count} named signals, "
               f"{len(result.warnings)} warnings", err=True)


@eio.command("export")
@click.option("--config", "config_path", type=click.Path(path_type=Path), default=None,
              help="cell configuration (YAML); default: the shipped default cell")
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="write EIO.cfg here; default: stdout")
def eio_export(config_path: Path | None, output: Path | None) -> None:
    """Write the EIO.cfg entries a controller needs to scan the farm's devices (ETHERNETIP_DEVICE)
    and their named signals (EIO_SIGNAL)."""
    from enip_farm.eio.exporter import ExportError, export_eio

    config = _load(config_path, build=False)
    try:
        text = export_eio(config, shipped_catalogue())
    except (ConfigError, ExportError) as error:
        click.echo(str(error), err=True)
        sys.exit(2)
    if output is None:
        click.echo(text, nl=False)
        return
    output.write_text(text)
    click.echo(f"{output}: {len(config.devices)} devices, {sum(len(d.signals) for d in config.devices)} "
               "named signals", err=True)


# -- beyond one host: Docker Swarm, Kubernetes, the shards' one HTTP API (cli_engines.py) -----------

for _command in engine_commands:
    main.add_command(_command)
