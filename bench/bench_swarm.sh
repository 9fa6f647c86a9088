#!/usr/bin/env bash
# A 3000-device plant (bench/plant.yaml) as a Docker Swarm stack of N shards (default 3) on this one
# engine: `enip-farm stack` then `docker stack deploy`; prints the time until every shard is healthy,
# the tester's verdict and time (ListIdentity to all, then identity, inputs and outputs of every
# device with pycomm3), each shard's memory and CPU, then removes the stack and leaves the swarm.
# Needs the image enip-farm:latest (docker/ci.sh builds it) and an engine not in a swarm.
#   bench/bench_swarm.sh [SHARDS]
set -euo pipefail
cd "$(dirname "$0")/.."
shards=${1:-3}
work=$(mktemp -d)
od -An -N16 -tx1 /dev/urandom | tr -d ' \n' >"$work/token"
export ENIP_FARM_TOKEN_FILE=$work/token
cleanup() {
    set +e
    docker stack rm plant >/dev/null 2>&1
    for _ in $(seq 120); do [ -z "$(docker ps -aq -f label=com.docker.stack.namespace=plant)" ] && break; sleep 1; done
    for _ in $(seq 30); do docker network rm plant_fleet >/dev/null 2>&1 || break; sleep 1; done
    docker network rm enip-cell enip-cell-node >/dev/null 2>&1
    docker swarm leave --force >/dev/null 2>&1
    docker network rm docker_gwbridge >/dev/null 2>&1
    ip link del enipplant 2>/dev/null
    rm -rf "$work"
}
trap cleanup EXIT
# the parent of the macvlan network, standing for the NIC toward the controller: a veth pair (no dummy
# module on these machines)
ip link add enipplant type veth peer name enipplant-peer
ip link set enipplant-peer up
ip link set enipplant up
docker swarm init --advertise-addr 127.0.0.1 >/dev/null 2>&1 || docker swarm init >/dev/null
docker network create --config-only --subnet 192.168.112.0/20 --ip-range 192.168.127.240/28 -o parent=enipplant \
    enip-cell-node >/dev/null
docker network create -d macvlan --scope swarm --attachable --config-from enip-cell-node enip-cell >/dev/null
cp bench/plant.yaml "$work/plant.yaml"
python3 -m enip_farm stack --config "$work/plant.yaml" --shards "$shards" --subnet 192.168.112.0/20 \
    --container-range 192.168.127.240/28 --api-port 0 -o "$work/stack.yaml" 2>/dev/null
start=$(date +%s.%N)
docker stack deploy -c "$work/stack.yaml" plant >/dev/null 2>&1
for _ in $(seq 600); do
    [ "$(docker ps -q -f label=com.docker.swarm.service.name=plant_farm -f health=healthy | wc -l)" = "$shards" ] && break
    sleep 1
done
healthy=$(date +%s.%N)
echo "$shards shards healthy: $(echo "$healthy - $start" | bc) s after docker stack deploy"
docker stats --no-stream --format '{{.Name}} {{.MemUsage}} {{.CPUPerc}}' | grep plant_farm | sed 's/^/  /'
for _ in $(seq 1200); do
    state=$(docker inspect "$(docker service ps -q plant_tester | head -1)" --format '{{.Status.State}}' 2>/dev/null || true)
    case "$state" in complete | failed | rejected) break ;; esac
    sleep 1
done
done_at=$(date +%s.%N)
docker service logs --raw plant_tester 2>/dev/null | grep -E '^(waited|[0-9]+/[0-9]+ devices)' | sed 's/^/  tester: /'
echo "tester $state $(echo "$done_at - $start" | bc) s after docker stack deploy"
