#!/bin/sh
# Container entrypoint: add the address of every device this farm serves (its --config, and its
# --shard if given) as an alias on the container's interface, then serve as the unprivileged user
# `farm` where it exists. Needs NET_ADMIN.
#   ENIP_FARM_IFACE         interface for the aliases (default: the default route's, else eth0)
#   ENIP_FARM_ALIASES_ONLY  1: add the aliases and exit (the tests run this inside a namespace)
#   ENIP_FARM_ADDRESS_FILE  where to list the addresses for docker/healthcheck.sh
#                           (default /run/enip-farm.addresses)
#   ENIP_FARM_SHARD         I/N: serve that slice when the command gives no --shard (compose)
#   ENIP_FARM_TOKEN         the HTTP API's bearer token; empty or unset: one is made up and logged
set -eu

config=/etc/enip-farm/cell.yaml
shard=${ENIP_FARM_SHARD:-}
previous=""
for arg in "$@"; do
    case "$previous" in
        --config) config=$arg ;;
        --shard) shard=$arg ;;
    esac
    previous=$arg
done

iface=${ENIP_FARM_IFACE:-$(ip -o route show default 2>/dev/null | awk '{print $5; exit}')}
iface=${iface:-eth0}

if [ -n "$shard" ]; then
    addresses=$(enip-farm addresses --config "$config" --shard "$shard")
else
    addresses=$(enip-farm addresses --config "$config")
fi

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
if [ -z "${ENIP_FARM_TOKEN:-}" ]; then
    ENIP_FARM_TOKEN=$(od -An -N16 -tx1 /dev/urandom | tr -d ' \n')
    echo "enip-farm: no ENIP_FARM_TOKEN given; this container's HTTP API token: $ENIP_FARM_TOKEN" >&2
fi
export ENIP_FARM_TOKEN
if [ "$(id -u)" = 0 ] && id farm >/dev/null 2>&1; then
    exec setpriv --reuid=farm --regid=farm --init-groups enip-farm "$@"
fi
exec enip-farm "$@"
