#!/bin/bash
# The image's HEALTHCHECK: healthy when every device address the entrypoint added accepts a TCP
# connection on 44818. Bash builtins only (no interpreter start per probe); the cost grows with
# this container's device count, not with the number of containers.
#   ENIP_FARM_ADDRESS_FILE  the entrypoint's list of addresses (default /run/enip-farm.addresses)
set -u
file=${ENIP_FARM_ADDRESS_FILE:-/run/enip-farm.addresses}
[ -s "$file" ] || { echo "no address list at $file yet" >&2; exit 1; }
count=0
while read -r address; do
    [ -n "$address" ] || continue
    if ! exec 3<>"/dev/tcp/$address/44818"; then
        echo "$address does not accept TCP 44818" >&2
        exit 1
    fi
    exec 3>&-
    count=$((count + 1))
done < "$file"
echo "$count devices accept TCP 44818"
