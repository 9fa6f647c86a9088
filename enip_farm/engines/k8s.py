"""Kubernetes manifests for a cell: a StatefulSet whose pod with index K serves slice K+1/N, on the
nodes' own network (hostNetwork: the entrypoint adds the slice's addresses as aliases on the NIC
toward the controller), the cell in a ConfigMap, the token in a Secret, a headless Service that
lists the ready shards (readiness: the image's health check), the fleet's one HTTP API finding the
shards through it, and a one-shot tester Job. `enip-farm k8s` writes them."""

from __future__ import annotations

import secrets
from pathlib import Path

import yaml

from enip_farm.config import FarmConfig
from enip_farm.engines.compose import API_PORT, CONFIG_IN_CONTAINER
from enip_farm.engines.stack import check_cell

LABELS = {"app.kubernetes.io/name": "enip-farm"}
TOKEN_DIR = "/run/secrets/enip-farm"


class _Dumper(yaml.SafeDumper):
    def ignore_aliases(self, data: object) -> bool:
        return True


def _token_env() -> dict:
    return {"name": "ENIP_FARM_TOKEN_FILE", "value": f"{TOKEN_DIR}/token"}


def _volumes() -> tuple[list[dict], list[dict]]:
    volumes = [{"name": "cell", "configMap": {"name": "enip-farm-cell"}},
               {"name": "token", "secret": {"secretName": "enip-farm-token", "defaultMode": 0o440}}]
    mounts = [{"name": "cell", "mountPath": str(Path(CONFIG_IN_CONTAINER).parent), "readOnly": True},
              {"name": "token", "mountPath": TOKEN_DIR, "readOnly": True}]
    return volumes, mounts


def manifests(config: FarmConfig, config_text: str, shards: int, subnet: str, node_range: str,
              image: str = "enip-farm:latest", iface: str | None = None, token: str | None = None) -> dict[str, str]:
    """File name -> YAML text. `node_range`: where the nodes' own addresses are on the controller's
    subnet (no device may be there); `iface`: the NIC toward the controller on every node (default:
    the one the kernel routes the devices' subnet through); `token`: default a fresh random one."""
    check_cell(config, shards, subnet, node_range, others=0)
    volumes, mounts = _volumes()
    shard_labels = {**LABELS, "app.kubernetes.io/component": "shard"}
    env = [{"name": "ENIP_FARM_SHARDS", "value": str(shards)},
           {"name": "ENIP_FARM_POD_NAME", "valueFrom": {"fieldRef": {"fieldPath": "metadata.name"}}},
           _token_env()]
    if iface:
        env.append({"name": "ENIP_FARM_IFACE", "value": iface})
    probe = {"exec": {"command": ["/opt/enip-farm/docker/healthcheck.sh"]}, "periodSeconds": 5, "timeoutSeconds": 3,
             "failureThreshold": 3}
    statefulset = {
        "apiVersion": "apps/v1", "kind": "StatefulSet",
        "metadata": {"name": "farm", "labels": shard_labels},
        "spec": {
            "serviceName": "farm", "replicas": shards, "podManagementPolicy": "Parallel",
            "selector": {"matchLabels": shard_labels},
            "template": {
                "metadata": {"labels": shard_labels},
                "spec": {
                    # the node's own network: the slice's addresses become aliases on its NIC, so a
                    # controller on that LAN reaches them with no CNI plugin; one shard per node (each
                    # serves its HTTP API on the node's port 8044)
                    "hostNetwork": True, "dnsPolicy": "ClusterFirstWithHostNet",
                    "affinity": {"podAntiAffinity": {"requiredDuringSchedulingIgnoredDuringExecution": [
                        {"labelSelector": {"matchLabels": shard_labels}, "topologyKey": "kubernetes.io/hostname"}]}},
                    "terminationGracePeriodSeconds": 30,
                    "containers": [{
                        "name": "farm", "image": image, "imagePullPolicy": "IfNotPresent",
                        "args": ["serve", "--config", CONFIG_IN_CONTAINER, "--http", f"0.0.0.0:{API_PORT}"],
                        "env": env,
                        "ports": [{"name": "enip", "containerPort": 44818, "protocol": "TCP"},
                                  {"name": "enip-udp", "containerPort": 44818, "protocol": "UDP"},
                                  {"name": "io", "containerPort": 2222, "protocol": "UDP"},
                                  {"name": "api", "containerPort": API_PORT, "protocol": "TCP"}],
                        "securityContext": {"capabilities": {"add": ["NET_ADMIN"]}},
                        "readinessProbe": probe,
                        "livenessProbe": {**probe, "initialDelaySeconds": 60},
                        "volumeMounts": mounts,
                    }],
                    "volumes": volumes,
                },
            },
        },
    }
    service = {
        "apiVersion": "v1", "kind": "Service",
        "metadata": {"name": "farm", "labels": shard_labels},
        "spec": {"clusterIP": "None", "selector": shard_labels,  # headless: one DNS record per ready shard
                 "ports": [{"name": "api", "port": API_PORT, "targetPort": API_PORT, "protocol": "TCP"}]},
    }
    api_labels = {**LABELS, "app.kubernetes.io/component": "api"}
    api = {
        "apiVersion": "apps/v1", "kind": "Deployment",
        "metadata": {"name": "enip-farm-api", "labels": api_labels},
        "spec": {
            "replicas": 1, "selector": {"matchLabels": api_labels},
            "template": {"metadata": {"labels": api_labels}, "spec": {
                "containers": [{
                    "name": "api", "image": image, "imagePullPolicy": "IfNotPresent",
                    "args": ["fleet-api", "--config", CONFIG_IN_CONTAINER, "--shards", str(shards),
                             "--discover", f"farm:{API_PORT}", "--http", f"0.0.0.0:{API_PORT}"],
                    "env": [_token_env()],
                    "ports": [{"name": "api", "containerPort": API_PORT, "protocol": "TCP"}],
                    "readinessProbe": {"tcpSocket": {"port": API_PORT}, "periodSeconds": 5},
                    "volumeMounts": mounts,
                }],
                "volumes": volumes,
            }},
        },
    }
    api_service = {
        "apiVersion": "v1", "kind": "Service",
        "metadata": {"name": "enip-farm-api", "labels": api_labels},
        "spec": {"selector": api_labels, "ports": [{"name": "api", "port": API_PORT, "targetPort": API_PORT}]},
    }
    tester_labels = {**LABELS, "app.kubernetes.io/component": "tester"}
    tester = {
        "apiVersion": "batch/v1", "kind": "Job",
        "metadata": {"name": "enip-farm-tester", "labels": tester_labels},
        "spec": {"backoffLimit": 0, "template": {"metadata": {"labels": tester_labels}, "spec": {
            "hostNetwork": True, "dnsPolicy": "ClusterFirstWithHostNet",  # reaches the devices as the controller does
            "restartPolicy": "Never",
            "containers": [{
                "name": "tester", "image": image, "imagePullPolicy": "IfNotPresent",
                "command": ["python", "/opt/enip-farm/docker/tester.py", CONFIG_IN_CONTAINER, "--wait", "180"],
                "volumeMounts": mounts[:1],
            }],
            "volumes": volumes[:1],
        }}},
    }
    configmap = {"apiVersion": "v1", "kind": "ConfigMap", "metadata": {"name": "enip-farm-cell", "labels": LABELS},
                 "data": {Path(CONFIG_IN_CONTAINER).name: config_text}}
    secret = {"apiVersion": "v1", "kind": "Secret", "metadata": {"name": "enip-farm-token", "labels": LABELS},
              "type": "Opaque", "stringData": {"token": token or secrets.token_hex(16)}}

    def dump(*documents: dict) -> str:
        return yaml.dump_all(documents, Dumper=_Dumper, sort_keys=False, width=120)

    return {
        "cell.yaml": dump(configmap),
        "token.yaml": dump(secret),
        "farm.yaml": dump(service, statefulset),
        "api.yaml": dump(api_service, api),
        "tester.yaml": dump(tester),
    }
