"""docker/swarm.sh's check of the fleet API, run inside the API's container (`python - < api_check.py`
with TOKEN set): every shard up, all devices of the cell listed in order, a write routed to the
device's shard, the merged metrics parsed back with prometheus_client."""

import os

import httpx
from prometheus_client.parser import text_string_to_metric_families

from enip_farm.config import load_config

names = [device.name for device in load_config("/etc/enip-farm/cell.yaml").devices]
api = httpx.Client(base_url="http://127.0.0.1:8044", headers={"Authorization": f"Bearer {os.environ['TOKEN']}"},
                   timeout=30)
assert httpx.get("http://127.0.0.1:8044/devices").status_code == 401, "the fleet API answered without the token"
shards = api.get("/shards").json()
assert [shard["up"] for shard in shards] == [True] * len(shards), shards
devices = api.get("/devices").json()
assert [device["name"] for device in devices] == names, [device["name"] for device in devices]
assert all(device["shard_up"] for device in devices)
reply = api.put("/devices/dio7/io", json={"signals": {"DI3": 1}})
assert reply.status_code == 200, reply.text
assert api.get("/devices/dio7/io/DI3").json()["value"] == 1
up = {}
shard_labels = set()
for family in text_string_to_metric_families(api.get("/metrics").text):
    for sample in family.samples:
        if sample.name == "enip_farm_shard_up":
            up[sample.labels["shard"]] = sample.value
        elif "shard" in sample.labels:
            shard_labels.add(sample.labels["shard"])
assert up == {str(i): 1.0 for i in range(1, len(shards) + 1)}, up
assert shard_labels == set(up), shard_labels
print(f"fleet API: {len(devices)}/{len(names)} devices listed, {len(shards)}/{len(shards)} shards up "
      f"({', '.join(sorted({s['endpoint'] for s in shards}))}), dio7 DI3=1 written through it, "
      f"metrics of {len(shard_labels)} shards merged")
