#!/bin/bash
# The image's HEALTHCHECK: healthy when every device address the entrypoint added has a socket
# listening on TCP 44818, read from the kernel's table (/proc/net/tcp) rather than by connecting, so
# the probe costs no connection and adds no line to the farm's log, and when class-1 I/O runs: the
# farm sets its heartbeat file's time every second while its cyclic I/O thread turns (one file per
# worker, FILE.i), so a file older than HEARTBEAT_MAX_AGE seconds means a farm that answers explicit
# requests while no device sends T->O. Bash and stat only; the cost grows with the device count.
#   ENIP_FARM_ADDRESS_FILE  the entrypoint's list of addresses (default /run/enip-farm.addresses)
#   ENIP_FARM_HEARTBEAT     the farm's heartbeat file (the image sets it; unset: not checked)
#   ENIP_FARM_HEARTBEAT_MAX_AGE  seconds (default 10)
set -u
HEARTBEAT_MAX_AGE=${ENIP_FARM_HEARTBEAT_MAX_AGE:-10}
heartbeat=${ENIP_FARM_HEARTBEAT:-}
if [ -n "$heartbeat" ]; then
    now=$(printf '%(%s)T' -1)
    beats=0
    for beat in "$heartbeat" "$heartbeat".*; do
        [ -e "$beat" ] || continue
        beats=$((beats + 1))
        age=$((now - $(stat -c %Y "$beat")))
        if [ "$age" -gt "$HEARTBEAT_MAX_AGE" ]; then
            echo "class-1 I/O is not running: $beat was last set ${age} s ago" >&2
            exit 1
        fi
    done
    [ "$beats" -gt 0 ] || { echo "no heartbeat at $heartbeat yet: class-1 I/O is not running" >&2; exit 1; }
fi
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
counted="$count devices listen"
[ "$count" -eq 1 ] && counted="1 device listens"
echo "$counted on TCP 44818${heartbeat:+, class-1 I/O running}"
