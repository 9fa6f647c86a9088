#!/bin/bash
# The image's HEALTHCHECK: healthy when every device address the entrypoint added has a socket
# listening on TCP 44818, read from the kernel's table (/proc/net/tcp) rather than by connecting, so
# the probe costs no connection and adds no line to the farm's log. Bash builtins only (no
# interpreter start per probe); the cost grows with this container's device count.
#   ENIP_FARM_ADDRESS_FILE  the entrypoint's list of addresses (default /run/enip-farm.addresses)
set -u
file=${ENIP_FARM_ADDRESS_FILE:-/run/enip-farm.addresses}
[ -s "$file" ] || { echo "no address list at $file yet" >&2; exit 1; }
# /proc/net/tcp: "sl local_address rem_address st ...", the address as 8 hex digits of the
# little-endian word (127.0.10.1 -> 010A007F), the port in hex (44818 = AF12), st 0A = LISTEN.
declare -A listening=()
while read -r _ local _ state _; do
    [ "$state" = "0A" ] && [ "${local#*:}" = "AF12" ] && listening[${local%:*}]=1
done < /proc/net/tcp
count=0
while read -r address; do
    [ -n "$address" ] || continue
    IFS=. read -r a b c d <<< "$address"
    printf -v key '%02X%02X%02X%02X' "$d" "$c" "$b" "$a"
    if [ -z "${listening[$key]:-}" ] && [ -z "${listening[00000000]:-}" ]; then
        echo "$address does not listen on TCP 44818" >&2
        exit 1
    fi
    count=$((count + 1))
done < "$file"
echo "$count devices listen on TCP 44818"
