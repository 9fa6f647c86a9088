#!/usr/bin/env bash
# CI's Docker Swarm part (.ci/run calls it after docker/ci.sh, which built enip-farm:latest): the
# stack of docker/stack.yaml deployed for real, first on this engine alone, then with a second engine
# in a network namespace of its own joined as a worker. Each phase: swarm init, the macvlan network
# (its parent a veth pair between this namespace and the second node's, standing for the NIC toward
# the controller), `docker stack deploy`, every shard healthy (phase 1) or shards on both nodes
# (phase 2), the tester's `43/43 devices answered ...` and exit 0, the fleet API listing all 43 with
# every shard up, a write through it read back over EtherNet/IP from the device that got it; then
# `docker stack rm` and `docker swarm leave --force` must leave no container, service or network.
# Addresses: the cell's 192.168.125.0/24 only inside containers, the nodes' link on 198.18.0.0/30
# (a benchmarking range) on the veth pair this script makes. Prints the time of each step.
set -euo pipefail
cd "$(dirname "$0")"
started=$SECONDS
lap() { echo "docker/swarm.sh: $1 after $((SECONDS - started)) s" >&2; }
fail() { echo "docker/swarm.sh: FAILED: $1" >&2; exit 1; }

docker image inspect enip-farm:latest >/dev/null 2>&1 || fail "no image enip-farm:latest (docker/ci.sh builds it)"
[ "$(docker info --format '{{.Swarm.LocalNodeState}}')" = inactive ] || fail "this engine is already in a swarm"

work=$(mktemp -d)
dockerd2=""
node2=enipnode2
sock2=/run/enip-farm-node2.sock
d1=(docker)
d2=(docker -H "unix://$sock2")
od -An -N16 -tx1 /dev/urandom | tr -d ' \n' >"$work/token"
export ENIP_FARM_TOKEN_FILE=$work/token

cleanup() {
    set +e
    docker stack rm enip >/dev/null 2>&1
    for _ in $(seq 60); do
        [ -z "$(docker ps -aq -f label=com.docker.stack.namespace=enip)" ] && break
        sleep 1
    done
    for _ in $(seq 30); do docker network rm enip_fleet >/dev/null 2>&1 || break; sleep 1; done
    docker network rm enip-cell >/dev/null 2>&1
    docker network rm enip-cell-node >/dev/null 2>&1
    if [ -S "$sock2" ]; then
        "${d2[@]}" swarm leave --force >/dev/null 2>&1
        "${d2[@]}" network rm enip-cell-node >/dev/null 2>&1
    fi
    docker swarm leave --force >/dev/null 2>&1
    docker network rm docker_gwbridge >/dev/null 2>&1  # swarm's, made on the first task
    if [ -n "$dockerd2" ]; then
        kill "$dockerd2" 2>/dev/null
        for _ in $(seq 30); do kill -0 "$dockerd2" 2>/dev/null || break; sleep 1; done
        dockerd2=""
        rm -rf /run/enip-farm-node2 "$sock2"
    fi
    ip netns del "$node2" 2>/dev/null
    ip link del enipcell 2>/dev/null
    rm -rf "$work"
}
trap cleanup EXIT

# the two nodes' link: veth enipcell here, enipcell in the second node's namespace
ip netns add "$node2"
ip link add enipcell type veth peer name enipcell2
ip link set enipcell2 netns "$node2"
ip -n "$node2" link set enipcell2 name enipcell
ip addr add 198.18.0.1/30 dev enipcell
ip link set enipcell up
ip -n "$node2" addr add 198.18.0.2/30 dev enipcell
ip -n "$node2" link set enipcell up
ip -n "$node2" link set lo up

cell_network() {  # $1: docker command array name, $2: this node's part of the containers' range
    local -n cmd=$1
    "${cmd[@]}" network create --config-only --subnet 192.168.125.0/24 --ip-range "$2" -o parent=enipcell \
        enip-cell-node >/dev/null
}

deploy() {
    docker network create -d macvlan --scope swarm --attachable --config-from enip-cell-node enip-cell >/dev/null
    # from the checkout's top, as the README says (the stack file's paths are relative to its directory)
    (cd .. && docker stack deploy -c docker/stack.yaml enip) >/dev/null 2>"$work/deploy.err" || { cat "$work/deploy.err" >&2; fail "stack deploy"; }
}

tester_verdict() {  # wait for the one-shot tester; print its summary; its exit code
    local task state code
    for _ in $(seq 300); do
        task=$(docker service ps -q enip_tester 2>/dev/null | head -1)
        state=$( [ -n "$task" ] && docker inspect "$task" --format '{{.Status.State}}' 2>/dev/null || true)
        case "$state" in complete | failed | rejected) break ;; esac
        sleep 1
    done
    docker service logs --raw enip_tester 2>/dev/null | grep -E '^(waited|[0-9]+/[0-9]+ devices)' >&2 || true
    code=$(docker inspect "$task" --format '{{.Status.ContainerStatus.ExitCode}}' 2>/dev/null || echo "?")
    echo "docker/swarm.sh: tester task $state, exit code $code" >&2
    [ "$state" = complete ] && [ "$code" = 0 ]
}

api_check() {  # the fleet API, from inside its container: every device, every shard up; a write
    local api
    api=$(docker ps -q -f label=com.docker.swarm.service.name=enip_api | head -1)
    if [ -z "$api" ]; then  # on the other node
        api=$("${d2[@]}" ps -q -f label=com.docker.swarm.service.name=enip_api | head -1)
        [ -n "$api" ] || fail "no container of service enip_api"
        "${d2[@]}" exec -i -e "TOKEN=$(cat "$work/token")" "$api" python - <api_check.py
    else
        docker exec -i -e "TOKEN=$(cat "$work/token")" "$api" python - <api_check.py
    fi
    # the write, read back over EtherNet/IP on the cell's network: dio7 got DI3, dio6 nothing
    docker run --rm --network enip-cell --entrypoint python enip-farm:latest -c '
from pycomm3 import CIPDriver, Services
def inputs(address):
    with CIPDriver(address) as plc:
        return plc.generic_message(service=Services.get_attribute_single, class_code=4, instance=101,
                                   attribute=3, connected=False, route_path=False).value
got, other = inputs("192.168.125.136"), inputs("192.168.125.135")
print(f"dio7 inputs over EtherNet/IP {got.hex()}, dio6 {other.hex()}")
assert got == bytes([4, 0, 0, 0]) and other == bytes(4), "the write did not reach dio7 alone"
' >&2
}

# -- phase 1: this engine alone ------------------------------------------------------------------------
docker swarm init --advertise-addr 198.18.0.1 >/dev/null
cell_network d1 192.168.125.240/29
deploy
lap "phase 1: stack deployed"
healthy=0
for _ in $(seq 180); do
    healthy=$(docker ps -q -f label=com.docker.swarm.service.name=enip_farm -f health=healthy | wc -l)
    [ "$healthy" = 3 ] && break
    sleep 1
done
[ "$healthy" = 3 ] || fail "phase 1: $healthy of 3 shards healthy"
lap "phase 1: 3 shards healthy"
tester_verdict || fail "phase 1: the tester"
lap "phase 1: tester done"
api_check || fail "phase 1: the fleet API"
lap "phase 1: fleet API checked"
# a shard that dies: swarm starts another task in its slot, which serves the same devices again
victim=$(docker ps --format '{{.ID}} {{.Names}}' | awk '$2 ~ /^enip_farm\.1\./ {print $1}')
[ -n "$victim" ] || fail "phase 1: no task in slot 1"
docker kill "$victim" >/dev/null
back=""
for _ in $(seq 120); do
    back=$(docker ps -f health=healthy --format '{{.ID}} {{.Names}}' | awk -v old="$victim" \
        '$2 ~ /^enip_farm\.1\./ && index($1, old) != 1 && index(old, $1) != 1 {print $1}')
    [ -n "$back" ] && break
    sleep 1
done
[ -n "$back" ] || fail "phase 1: slot 1 was not restarted healthy"
probe=1
for _ in $(seq 30); do
    docker run --rm --network enip-cell enip-farm:latest probe --config /opt/enip-farm/docker/cell.yaml \
        >"$work/probe.out" 2>/dev/null && { probe=0; break; }
    sleep 2
done
cat "$work/probe.out" >&2
[ "$probe" = 0 ] || fail "phase 1: the restarted shard's devices do not all answer"
lap "phase 1: slot 1 killed, restarted by swarm, every device answers again"
docker stack rm enip >/dev/null
for _ in $(seq 60); do
    [ -z "$(docker ps -aq -f label=com.docker.stack.namespace=enip)" ] \
        && ! docker network inspect enip_fleet >/dev/null 2>&1 && break
    sleep 1
done
docker network rm enip-cell enip-cell-node >/dev/null
docker swarm leave --force >/dev/null
docker network rm docker_gwbridge >/dev/null
left=$(docker ps -aq | wc -l)
[ "$left" = 0 ] || fail "phase 1: $left containers left after stack rm"
[ "$(docker info --format '{{.Swarm.LocalNodeState}}')" = inactive ] || fail "phase 1: still in a swarm"
[ -z "$(docker network ls -q -f driver=overlay -f driver=macvlan)" ] || fail "phase 1: networks left"
lap "phase 1: stack removed, swarm left, nothing running"

# -- phase 2: a second engine in its own network namespace, joined as a worker -----------------------------
# nsenter, not `ip netns exec`: that mounts a sysfs of its own, without the cgroups dockerd needs
nsenter --net="/run/netns/$node2" dockerd --data-root "$work/docker2" --exec-root /run/enip-farm-node2 -H "unix://$sock2" \
    --pidfile "$work/dockerd2.pid" --storage-driver vfs --iptables=false --ip-masq=false --bridge=none \
    >"$work/dockerd2.log" 2>&1 &
dockerd2=$!
for _ in $(seq 60); do "${d2[@]}" info >/dev/null 2>&1 && break; sleep 1; done
"${d2[@]}" info >/dev/null 2>&1 || { tail -20 "$work/dockerd2.log" >&2; fail "phase 2: the second engine did not start"; }
docker save enip-farm:latest | "${d2[@]}" load -q >/dev/null
lap "phase 2: second engine up with the image"
docker swarm init --advertise-addr 198.18.0.1 >/dev/null
"${d2[@]}" swarm join --advertise-addr 198.18.0.2 --token "$(docker swarm join-token -q worker)" 198.18.0.1:2377 \
    >/dev/null
cell_network d1 192.168.125.240/29
cell_network d2 192.168.125.248/29
deploy
lap "phase 2: stack deployed on 2 nodes"
nodes=0
for _ in $(seq 180); do
    # shellcheck disable=SC2046
    nodes=$(docker inspect $(docker service ps -q -f desired-state=running enip_farm) \
        --format '{{.NodeID}} {{.Status.State}}' 2>/dev/null | awk '$2 == "running" {print $1}' | sort -u | wc -l)
    [ "$nodes" = 2 ] && break
    sleep 1
done
[ "$nodes" = 2 ] || fail "phase 2: shards running on $nodes node(s), not 2"
# shellcheck disable=SC2046
placed=$(docker inspect $(docker service ps -q -f desired-state=running enip_farm) --format '{{.NodeID}}' \
    | sort | uniq -c | awk '{print $1}' | paste -sd+)
lap "phase 2: shards running on both nodes ($placed)"
tester_verdict || fail "phase 2: the tester"
lap "phase 2: tester done"
api_check || fail "phase 2: the fleet API"
lap "phase 2: fleet API checked"
docker stack rm enip >/dev/null
for _ in $(seq 60); do
    [ -z "$(docker ps -aq -f label=com.docker.stack.namespace=enip)" ] \
        && [ -z "$("${d2[@]}" ps -aq -f label=com.docker.stack.namespace=enip)" ] && break
    sleep 1
done
lap "phase 2: stack removed"
cleanup
trap - EXIT
left=$(docker ps -aq | wc -l)
[ "$left" = 0 ] || fail "$left containers left"
[ "$(docker info --format '{{.Swarm.LocalNodeState}}')" = inactive ] || fail "still in a swarm"
lap "done: nothing left running"
