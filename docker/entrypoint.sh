#!/bin/sh
# Container entrypoint: for `serve`, add the address of every device this farm serves (its --config,
# and its --shard if given) as an alias on the interface toward the devices' subnet, then run the
# command (serve, fleet-api, ...) as the unprivileged user `farm` where it exists. Needs NET_ADMIN.
#   ENIP_FARM_IFACE         interface for the aliases (default: the one the kernel routes the first
#                           device address through, else the default route's, else eth0)
#   ENIP_FARM_ALIASES_ONLY  1: add the aliases and exit (the tests run this inside a namespace)
#   ENIP_FARM_ADDRESS_FILE  where to list the addresses for docker/healthcheck.sh
#                           (default /run/enip-farm.addresses)
#   ENIP_FARM_SHARD         I/N: serve that slice when the command gives no --shard (compose; Swarm
#                           gives {{.Task.Slot}}/N)
#   ENIP_FARM_POD_NAME, ENIP_FARM_SHARDS   Kubernetes: a StatefulSet's pod NAME-K serves slice K+1/N
#   ENIP_FARM_TOKEN         the HTTP API's bearer token; empty or unset: one is made up and logged
#   ENIP_FARM_TOKEN_FILE    read the token from this file (a Swarm or Kubernetes secret) instead
set -eu

run() {
    if [ -n "${ENIP_FARM_TOKEN_FILE:-}" ]; then
        ENIP_FARM_TOKEN=$(tr -d ' \r\n' < "$ENIP_FARM_TOKEN_FILE")
    fi
    if [ -z "${ENIP_FARM_TOKEN:-}" ]; then
        ENIP_FARM_TOKEN=$(od -An -N16 -tx1 /dev/urandom | tr -d ' \n')
        echo "enip-farm: no ENIP_FARM_TOKEN given; this container's HTTP API token: $ENIP_FARM_TOKEN" >&2
    fi
    export ENIP_FARM_TOKEN
    if [ "$(id -u)" = 0 ] && id farm >/dev/null 2>&1; then
        exec setpriv --reuid=farm --regid=farm --init-groups enip-farm "$@"
    fi
    exec enip-farm "$@"
}
if [ "${1:-}" != serve ]; then  # fleet-api, probe, ...: no device addresses of their own
    run "$@"
fi

config=/etc/enip-farm/cell.yaml
shard=${ENIP_FARM_SHARD:-}
if [ -z "$shard" ] && [ -n "${ENIP_FARM_POD_NAME:-}" ] && [ -n "${ENIP_FARM_SHARDS:-}" ]; then
    shard=$((${ENIP_FARM_POD_NAME##*-} + 1))/$ENIP_FARM_SHARDS
    export ENIP_FARM_SHARD=$shard
fi
previous=""
for arg in "$@"; do
    case "$previous" in
        --config) config=$arg ;;
        --shard) shard=$arg ;;
    esac
    previous=$arg
done

if [ -n "$shard" ]; then
    addresses=$(enip-farm addresses --config "$config" --shard "$shard")
else
    addresses=$(enip-farm addresses --config "$config")
fi

iface=${ENIP_FARM_IFACE:-}
if [ -z "$iface" ]; then  # several networks (Swarm: the cell's and an overlay): the cell's
    first=$(echo "$addresses" | awk 'NF {print; exit}')
    [ -z "$first" ] || iface=$(ip -o route get "$first" 2>/dev/null | awk '{for (i = 1; i < NF; i++) if ($i == "dev") {print $(i + 1); exit}}')
fi
iface=${iface:-$(ip -o route show default 2>/dev/null | awk '{print $5; exit}')}
iface=${iface:-eth0}

address_file=${ENIP_FARM_ADDRESS_FILE:-/run/enip-farm.addresses}
: > "$address_file.new"
count=0
for address in $addresses; do
    echo "$address" >> "$address_file.new"
    if ! ip -o addr show dev "$iface" | grep -q " inet $address/"; then
        ip addr add "$address/32" dev "$iface"
    fi
    count=$((count + 1))
done
mv "$address_file.new" "$address_file"
echo "enip-farm: $count device addresses on $iface" >&2

if [ "${ENIP_FARM_ALIASES_ONLY:-0}" = 1 ]; then
    exit 0
fi
run "$@"
