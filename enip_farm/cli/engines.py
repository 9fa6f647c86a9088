"""`enip-farm stack`, `enip-farm k8s` and `enip-farm fleet-api`: a cell beyond one host, on an
existing engine (Docker Swarm, Kubernetes)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import NoReturn

import click


def _refuse(command: str, error: ValueError) -> NoReturn:
    click.echo(f"{command}: {error}", err=True)
    sys.exit(2)


@click.command()
@click.option("--config", "config_path", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="the cell (a swarm config made from this file, relative to the stack file)")
@click.option("--shards", type=click.IntRange(1, 256), required=True, help="replicas of the farm service")
@click.option("--subnet", default="192.168.125.0/24", show_default=True, help="the controller's subnet")
@click.option("--container-range", default="192.168.125.240/28", show_default=True,
              help="where the engine places containers on the cell's network (no device there)")
@click.option("--parent", default="eth1", show_default=True,
              help="the NIC toward the controller on every node (ENIP_FARM_PARENT at deploy overrides it)")
@click.option("--api-port", type=click.IntRange(0, 65535), default=8044, show_default=True,
              help="the fleet API's port on the node that runs it (0: not published)")
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="write the stack file here; default: stdout")
def stack(config_path: Path, shards: int, subnet: str, container_range: str, parent: str, api_port: int,
          output: Path | None) -> None:
    """Write a Docker Swarm stack: a farm service of SHARDS replicas (task slot I serves slice I/N), the
    fleet's HTTP API, a one-shot tester."""
    from enip_farm.cli.cell import load_cell
    from enip_farm.engines.stack import stack_file

    stack_dir = output.resolve().parent if output else Path.cwd()
    try:
        text = stack_file(load_cell(config_path), config_path, stack_dir, shards, subnet, container_range, parent,
                          api_port)
    except ValueError as error:
        _refuse("stack", error)
    if output:
        output.write_text(text)
        click.echo(f"wrote {output}", err=True)
    else:
        click.echo(text, nl=False)


@click.command()
@click.option("--config", "config_path", type=click.Path(dir_okay=False, path_type=Path), required=True)
@click.option("--shards", type=click.IntRange(1, 256), required=True, help="pods of the StatefulSet, one per node")
@click.option("--subnet", default="192.168.125.0/24", show_default=True, help="the controller's subnet")
@click.option("--node-range", default="192.168.125.240/28", show_default=True,
              help="the nodes' own addresses on that subnet (no device there)")
@click.option("--image", default="enip-farm:latest", show_default=True)
@click.option("--iface", default=None, help="the NIC toward the controller on every node (default: the route's)")
@click.option("-o", "--output", type=click.Path(file_okay=False, path_type=Path), required=True,
              help="directory for the manifests (kubectl apply -f DIR)")
def k8s(config_path: Path, shards: int, subnet: str, node_range: str, image: str, iface: str | None,
        output: Path) -> None:
    """Write Kubernetes manifests: StatefulSet (pod K serves slice K+1/N), ConfigMap, Secret, headless
    Service, the fleet's HTTP API, a tester Job."""
    from enip_farm.cli.cell import load_cell
    from enip_farm.engines.k8s import manifests

    try:
        files = manifests(load_cell(config_path), config_path.read_text(), shards, subnet, node_range, image, iface)
    except ValueError as error:
        _refuse("k8s", error)
    output.mkdir(parents=True, exist_ok=True)
    for name, text in files.items():
        (output / name).write_text(text)
    (output / "token.yaml").chmod(0o600)
    click.echo(f"wrote {', '.join(files)} in {output}", err=True)


@click.command("fleet-api")
@click.option("--config", "config_path", type=click.Path(dir_okay=False, path_type=Path), required=True)
@click.option("--shards", type=click.IntRange(1, 256), required=True)
@click.option("--discover", default=None, metavar="NAME:PORT",
              help="every address NAME resolves to is a shard (Swarm: tasks.farm:8044; Kubernetes: farm:8044)")
@click.option("--shard-url", "urls", multiple=True, metavar="URL", help="a shard's HTTP API (instead of --discover)")
@click.option("--http", "http", default="127.0.0.1:8044", show_default=True, metavar="HOST:PORT")
@click.option("--token", envvar="ENIP_FARM_TOKEN", default=None,
              help="the shards' token, also required of this API's clients")
def fleet_api(config_path: Path, shards: int, discover: str | None, urls: tuple[str, ...], http: str,
              token: str | None) -> None:
    """Serve one HTTP API for the shards of a cell wherever they run."""
    import signal
    import threading

    from enip_farm.cli.cell import load_cell
    from enip_farm.control.guard import needs_token
    from enip_farm.fleet.api import router_port, serving_router
    from enip_farm.fleet.shard_api import create_shard_router, dns_discovery, static_discovery
    from enip_farm.words import plural

    config = load_cell(config_path)
    host, _, port_text = http.rpartition(":")
    if not port_text.isdigit() or not host:
        raise click.BadParameter(f"{http!r}: expected HOST:PORT", param_hint="--http")
    if needs_token(host) and not token:
        click.echo(f"the HTTP API on {host} needs a token (--token or ENIP_FARM_TOKEN)", err=True)
        sys.exit(2)
    if bool(discover) == bool(urls):
        raise click.UsageError("give --discover NAME:PORT or --shard-url URL (one per shard)")
    if discover:
        name, _, dns_port = discover.rpartition(":")
        if not dns_port.isdigit() or not name:
            raise click.BadParameter(f"{discover!r}: expected NAME:PORT", param_hint="--discover")
        finder = dns_discovery(name, int(dns_port))
    else:
        finder = static_discovery([url.rstrip("/") for url in urls])
    try:
        app = create_shard_router(config, shards, finder, token)
    except ValueError as error:
        _refuse("fleet-api", error)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    try:
        with serving_router(app, host, int(port_text), token) as server:
            click.echo(f"fleet HTTP API on http://{host}:{router_port(server)} for "
                       f"{plural(len(config.devices), 'device')} in {plural(shards, 'shard')} "
                       f"({discover or ', '.join(urls)})", err=True)
            while not stop.wait(0.5) and server.started and not server.should_exit:
                pass
    except OSError as error:
        click.echo(error.strerror or str(error), err=True)
        sys.exit(1)


COMMANDS = (stack, k8s, fleet_api)
