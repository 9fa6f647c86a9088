"""Beyond one host on an existing engine: the Swarm stack (`enip-farm stack`, docker/stack.yaml), the
Kubernetes manifests (`enip-farm k8s`, validated against the schemas with kubernetes-validate and by
`kubectl apply --dry-run=client` where it runs without a cluster), the shards' one HTTP API
(`enip-farm fleet-api`) over real farms, with a shard down. docker/swarm.sh deploys the stack for
real (CI)."""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
from pathlib import Path

import httpx
import kubernetes_validate
import pytest
import yaml
from prometheus_client.parser import text_string_to_metric_families

from enip_farm.config import load_config, parse_config
from enip_farm.control.client import ApiClient
from enip_farm.engines.k8s import manifests
from enip_farm.engines.stack import check_cell, stack_file
from enip_farm.fleet.api import serving_router
from enip_farm.fleet.reports import merge_metrics
from enip_farm.fleet.shard_api import create_shard_router, static_discovery
from enip_farm.fleet.slices import shard, split
from tests.helpers import CLI, ROOT, STARTUP_S

CELL = ROOT / "docker" / "cell.yaml"
SUBNET, RANGE = "192.168.125.0/24", "192.168.125.240/28"


def test_stack_file_is_the_generators_output() -> None:
    generated = stack_file(load_config(CELL), CELL, ROOT / "docker", 3, SUBNET, RANGE)
    assert (ROOT / "docker" / "stack.yaml").read_text() == generated
    document = yaml.safe_load(generated)
    farm = document["services"]["farm"]
    assert farm["deploy"]["replicas"] == 3 and farm["deploy"]["endpoint_mode"] == "dnsrr"
    assert farm["environment"]["ENIP_FARM_SHARD"] == "{{.Task.Slot}}/3"
    assert farm["configs"] == [{"source": "cell", "target": "/etc/enip-farm/cell.yaml", "mode": 0o444}]
    assert farm["secrets"] == ["enip_farm_token"] and farm["cap_add"] == ["NET_ADMIN"]
    assert farm["healthcheck"]["test"] == ["CMD", "/opt/enip-farm/docker/healthcheck.sh"]
    assert document["configs"] == {"cell": {"file": "cell.yaml"}}
    assert document["networks"]["cell"] == {"external": True, "name": "enip-cell"}
    api = document["services"]["api"]["command"]
    assert api[api.index("--discover") + 1] == "tasks.farm:8044" and api[api.index("--shards") + 1] == "3"
    tester = document["services"]["tester"]
    assert tester["deploy"]["restart_policy"] == {"condition": "none"} and tester["healthcheck"] == {"disable": True}


@pytest.mark.parametrize(("change", "shards", "reason"), [
    ({"address": "192.168.126.10"}, 3,
     "device 'x' (192.168.126.10) is outside the controller's subnet 192.168.125.0/24"),
    ({"address": "192.168.125.241"}, 3,
     "device 'x' (192.168.125.241) is inside 192.168.125.240/28, where the engine places its containers"),
    ({}, 45, "45 shards for 43 groups of devices (devices joined by wires or rules stay together): at most 43 shards"),
    ({}, 14, "14 shards and 1 other container(s) need 15 addresses; 192.168.125.240/28 holds 14"),
])
def test_stack_and_manifests_refuse_a_bad_cell_in_one_line(change: dict, shards: int, reason: str) -> None:
    data = yaml.safe_load(CELL.read_text())
    data["devices"].append({"name": "x", "model": "DSQC1030", "address": "192.168.125.99", **change})
    config = parse_config(data, "cell.yaml")
    with pytest.raises(ValueError) as refused:
        stack_file(config, CELL, ROOT / "docker", shards, SUBNET, RANGE)
    assert str(refused.value) == reason
    if shards != 14:  # the nodes' range holds no containers of the engine
        with pytest.raises(ValueError) as refused:
            manifests(config, "", shards, SUBNET, RANGE)
        assert str(refused.value) == reason


def test_shards_never_overlap_and_cover_the_cell() -> None:
    parts = check_cell(load_config(CELL), 3, SUBNET, RANGE, others=1)
    names = [device.name for part in parts for device in part.devices]
    assert sorted(names) == sorted(device.name for device in load_config(CELL).devices) and len(set(names)) == 43


def _documents(directory: Path) -> list[dict]:
    return [doc for path in sorted(directory.glob("*.yaml")) for doc in yaml.safe_load_all(path.read_text())]


def test_manifests_validate_against_the_kubernetes_schemas() -> None:
    files = manifests(load_config(CELL), CELL.read_text(), 3, SUBNET, RANGE, iface="eth1", token="t0ken")
    documents = [doc for text in files.values() for doc in yaml.safe_load_all(text)]
    assert sorted(f"{d['kind']}/{d['metadata']['name']}" for d in documents) == [
        "ConfigMap/enip-farm-cell", "Deployment/enip-farm-api", "Job/enip-farm-tester", "Secret/enip-farm-token",
        "Service/enip-farm-api", "Service/farm", "StatefulSet/farm"]
    for document in documents:  # offline: the schemas ship with the package; strict: no unknown field
        kubernetes_validate.validate(document, "1.30.0", strict=True)
    statefulset = next(d for d in documents if d["kind"] == "StatefulSet")
    pod = statefulset["spec"]["template"]["spec"]
    env = {e["name"]: e.get("value", e.get("valueFrom")) for e in pod["containers"][0]["env"]}
    assert env["ENIP_FARM_SHARDS"] == "3" and env["ENIP_FARM_POD_NAME"] == {"fieldRef": {"fieldPath": "metadata.name"}}
    assert pod["hostNetwork"] is True and statefulset["spec"]["replicas"] == 3
    assert pod["containers"][0]["readinessProbe"]["exec"]["command"] == ["/opt/enip-farm/docker/healthcheck.sh"]
    service = next(d for d in documents if d["kind"] == "Service" and d["metadata"]["name"] == "farm")
    assert service["spec"]["clusterIP"] == "None"
    configmap = next(d for d in documents if d["kind"] == "ConfigMap")
    assert configmap["data"]["cell.yaml"] == CELL.read_text()
    broken = {**statefulset, "spec": {**statefulset["spec"], "replicas": "three"}}
    with pytest.raises(kubernetes_validate.ValidationError, match="^'three' is not of type 'integer', 'null'"):
        kubernetes_validate.validate(broken, "1.30.0", strict=True)


@pytest.mark.system
def test_k8s_command_writes_manifests_kubectl_accepts(tmp_path: Path) -> None:
    result = subprocess.run([*CLI, "k8s", "--config", str(CELL), "--shards", "3", "-o", str(tmp_path / "k8s")],
                            capture_output=True, text=True, timeout=STARTUP_S)
    assert result.returncode == 0, result.stderr
    assert (tmp_path / "k8s" / "token.yaml").stat().st_mode & 0o077 == 0
    assert len(_documents(tmp_path / "k8s")) == 7
    refused = subprocess.run([*CLI, "k8s", "--config", str(CELL), "--shards", "45", "-o", str(tmp_path / "no")],
                             capture_output=True, text=True, timeout=STARTUP_S)
    assert refused.returncode == 2 and refused.stderr.startswith("k8s: 45 shards for 42 groups")
    assert refused.stderr.count("\n") == 1 and not (tmp_path / "no").exists()
    kubectl = shutil.which("kubectl")
    if kubectl is None:
        pytest.skip("kubectl is not installed (the schemas were checked offline by the unit test)")
    # kubectl's own reading of the files, offline: `apply`/`create --dry-run=client` ask a server for the
    # kinds' REST mapping (no cluster here, none on CI), `label --local` decodes each object without one
    dry = subprocess.run([kubectl, "label", "--local", "-o", "name", "-f", str(tmp_path / "k8s"), "checked=offline"],
                         capture_output=True, text=True, timeout=STARTUP_S,
                         env={"KUBECONFIG": str(tmp_path / "no-cluster"), "PATH": "/usr/bin:/bin"})
    assert dry.returncode == 0, dry.stderr
    assert sorted(dry.stdout.split()) == sorted([
        "configmap/enip-farm-cell", "deployment.apps/enip-farm-api", "job.batch/enip-farm-tester",
        "secret/enip-farm-token", "service/enip-farm-api", "service/farm", "statefulset.apps/farm"])


def test_merged_metrics_keep_every_shards_samples() -> None:
    one = ('# HELP enip_farm_requests_total Requests\n# TYPE enip_farm_requests_total counter\n'
           'enip_farm_requests_total{device="a"} 3.0\n')
    two = one.replace('"a"} 3.0', '"b"} 5.0')
    merged = merge_metrics([one, two], [{"shard": "1"}, {"shard": "2"}])
    assert merged.count("# HELP enip_farm_requests_total") == 1
    (family,) = text_string_to_metric_families(merged)
    assert [(s.labels, s.value) for s in family.samples] == [({"device": "a", "shard": "1"}, 3.0),
                                                            ({"device": "b", "shard": "2"}, 5.0)]


def _closed_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@pytest.mark.integration
def test_the_fleet_api_finds_routes_merges_and_shows_a_shard_down(enip_farm) -> None:
    cell = {"devices": [{"name": f"io{n}", "model": "DSQC1030", "address": f"127.0.0.{n}"} for n in range(1, 7)],
            "discovery": False}
    config = parse_config(cell, "cell")
    parts = split(config, 3)
    farms = [enip_farm(part.model_dump(mode="json", by_alias=True), http=True) for part in parts[:2]]
    urls = [f"http://127.0.0.1:{farm.http.port}" for farm in farms]
    dead = f"http://127.0.0.1:{_closed_port()}"  # shard 3's task, gone
    router = create_shard_router(config, 3, static_discovery([urls[1], dead, urls[0]]), None)
    with serving_router(router, "127.0.0.1", 0, None) as server, \
            httpx.Client(base_url=f"http://127.0.0.1:{server.servers[0].sockets[0].getsockname()[1]}",
                         timeout=STARTUP_S) as api:
        shards = api.get("/shards").json()
        assert [(s["shard"], s["up"], s["endpoint"]) for s in shards] == [(1, True, urls[0]), (2, True, urls[1]),
                                                                          (3, False, None)]
        devices = api.get("/devices").json()
        assert [d["name"] for d in devices] == [f"io{n}" for n in range(1, 7)]  # configuration order
        down = {d["name"] for d in devices if not d["shard_up"]}
        assert down == {d.name for d in parts[2].devices} and len(down) == 2
        assert all("identity" in d for d in devices if d["shard_up"])  # the shard's own listing
        first, second, third = ([d.name for d in part.devices][0] for part in parts)
        assert api.put(f"/devices/{second}/io", json={"signals": {"DI3": 1}}).status_code == 200
        assert farms[1][second].get("DI3") == 1 and farms[0][first].get("DI3") == 0  # the right shard's device
        assert api.get(f"/devices/{second}/io/DI3").json()["value"] == 1
        refused = api.put(f"/devices/{third}/io", json={"signals": {"DI3": 1}})
        down_names = [d.name for d in parts[2].devices]
        assert refused.status_code == 503 and refused.json() == {
            "detail": f"shard 3/3 (devices {down_names[0]}..{down_names[-1]}) is down"}
        known = ", ".join(f"io{n}" for n in range(1, 7))
        assert api.get("/devices/nope").json() == {"detail": f"no device named 'nope'; known: {known}"}
        assert api.post(f"/devices/{first}/faults", json={"kind": "delay", "delay_ms": 1}).status_code == 201
        assert [f["kind"] for f in farms[0][first].faults] == ["delay"]
        up = {}
        for family in text_string_to_metric_families(api.get("/metrics").text):
            for sample in family.samples:
                if sample.name == "enip_farm_shard_up":
                    up[sample.labels["shard"]] = sample.value
        assert up == {"1": 1.0, "2": 1.0, "3": 0.0}
        state = api.get("/state", params={"device": [third, second]}).json()
        assert [(d["name"], d["shard_up"]) for d in state] == [(third, False), (second, True)]
        assert state[0]["connections"] == [] and state[0]["signals"] == []  # the shape the dashboard reads
        with ApiClient(str(api.base_url), timeout=10) as client, \
                client.events({"kind": "fault injected"}, STARTUP_S) as events:  # both shards' streams, merged
            for name in (second, first):
                assert api.post(f"/devices/{name}/faults", json={"kind": "delay", "delay_ms": 2}).status_code == 201
            seen = set()
            for event in events:  # bounded by the client's timeout; ends once both were seen
                seen.add(event.json()["device"])
                if seen == {first, second}:
                    break
            assert seen == {first, second}


@pytest.mark.system
def test_entrypoint_takes_a_pods_shard_and_the_cells_interface(tmp_path: Path) -> None:
    """Kubernetes' pod farm-1 of 3 serves slice 2/3; with no ENIP_FARM_IFACE the aliases go on the
    interface that routes the cell (here a second one, not the default route's), in a namespace."""
    if shutil.which("ip") is None or os.geteuid() != 0:
        pytest.skip("needs root and iproute2")
    namespace = f"enipfarm{os.getpid()}k"
    subprocess.run(["ip", "netns", "add", namespace], check=True, timeout=STARTUP_S)

    def run(*command: str, **env: str) -> subprocess.CompletedProcess:
        return subprocess.run(["ip", "netns", "exec", namespace, *command], capture_output=True, text=True,
                              timeout=2 * STARTUP_S, env={**os.environ, "PATH": path, **env})

    path = f"{Path(sys.executable).parent}:{os.environ['PATH']}"
    try:
        for nic, address in (("uplink", "198.18.0.2/24"), ("cellnic", "192.168.125.240/24")):
            for command in (["ip", "link", "add", nic, "type", "veth", "peer", "name", f"{nic}-peer"],
                            ["ip", "addr", "add", address, "dev", nic], ["ip", "link", "set", f"{nic}-peer", "up"],
                            ["ip", "link", "set", nic, "up"]):
                assert run(*command).returncode == 0, command
        assert run("ip", "route", "add", "default", "via", "198.18.0.1").returncode == 0
        aliases = run(str(ROOT / "docker" / "entrypoint.sh"), "serve", "--config", str(CELL),
                      ENIP_FARM_ALIASES_ONLY="1", ENIP_FARM_POD_NAME="farm-1", ENIP_FARM_SHARDS="3",
                      ENIP_FARM_ADDRESS_FILE=str(tmp_path / "addresses"))
        assert aliases.returncode == 0 and "on cellnic" in aliases.stderr, aliases.stderr
        expected = [str(device.address) for device in shard(load_config(CELL), "2/3").devices]
        assert (tmp_path / "addresses").read_text().split() == expected
        shown = run("ip", "-o", "addr", "show", "dev", "cellnic").stdout
        assert sorted(line.split()[3] for line in shown.splitlines() if " inet " in line) == sorted(
            [*(f"{address}/32" for address in expected), "192.168.125.240/24"])
        assert " inet 192.168.125." not in run("ip", "-o", "addr", "show", "dev", "uplink").stdout
    finally:
        subprocess.run(["ip", "netns", "del", namespace], timeout=STARTUP_S)
