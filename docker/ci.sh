#!/usr/bin/env bash
# CI's Docker part (.ci/run calls it once a Docker engine runs): build the image, `docker-compose up`
# the fleet of docker/compose.yaml, take the tester's exit status, bring the fleet down, print times.
# Where the registry's python:3.11-slim cannot be pulled, the image is built on a stand-in base made
# here: Debian bookworm by debootstrap (minbase; python3, pip, iproute2) with a wheelhouse of the
# project's dependencies, made on this host by `pip wheel`, for an offline `pip install`. It is kept
# under a tag naming pyproject.toml's hash, so a second run on the same machine reuses it.
set -euo pipefail
cd "$(dirname "$0")"
started=$SECONDS
lap() { echo "docker/ci.sh: $1 after $((SECONDS - started)) s" >&2; }

base=python:3.11-slim
if ! docker image inspect "$base" >/dev/null 2>&1 && ! timeout 120 docker pull -q "$base" >/dev/null 2>&1; then
    base=enip-farm-base:bookworm-$(sha256sum ../pyproject.toml | cut -c1-12)
    if ! docker image inspect "$base" >/dev/null 2>&1; then
        echo "docker/ci.sh: cannot pull python:3.11-slim; building the stand-in base $base" >&2
        work=$(mktemp -d)
        trap 'rm -rf "$work"' EXIT
        mirror=$(awk '/^URIs:/ {print $2; exit}' /etc/apt/sources.list.d/debian.sources 2>/dev/null || true)
        [ -n "$mirror" ] || mirror=$(awk '$1 == "deb" {print $2; exit}' /etc/apt/sources.list)
        if ! debootstrap --variant=minbase --include=python3,python3-pip,python-is-python3,iproute2 \
                bookworm "$work/rootfs" "$mirror" >"$work/debootstrap.log" 2>&1; then
            tail -30 "$work/debootstrap.log" >&2
            exit 1
        fi
        python3 -c 'import tomllib; print("\n".join(tomllib.load(open("../pyproject.toml", "rb"))["project"]["dependencies"]))' \
            >"$work/requirements.txt"
        # the Dockerfile installs the project and pycomm3; setuptools and wheel build the project
        python3 -m pip wheel -q -w "$work/rootfs/opt/wheelhouse" -r "$work/requirements.txt" pycomm3 setuptools wheel
        rm -f "$work"/rootfs/usr/lib/python3*/EXTERNALLY-MANAGED  # as in python:3.11-slim: pip installs
        rm -rf "$work"/rootfs/usr/share/{doc,man,info,locale}/* "$work"/rootfs/var/cache/apt/archives/*.deb \
            "$work"/rootfs/var/lib/apt/lists/*
        tar -C "$work/rootfs" -c . | docker import -c 'CMD ["python3"]' - "$base" >/dev/null
        # stand-ins for an older pyproject.toml are of no more use
        docker images --format '{{.Repository}}:{{.Tag}}' enip-farm-base | grep -vxF "$base" | xargs -r docker rmi >/dev/null 2>&1 || true
        rm -rf "$work"
        trap - EXIT
    fi
fi
lap "base $base ready"

export ENIP_FARM_BASE=$base
ENIP_FARM_TOKEN=ci-$(od -An -N8 -tx1 /dev/urandom | tr -d ' \n')
export ENIP_FARM_TOKEN
compose=(docker-compose -p enip-farm-ci -f compose.yaml)
"${compose[@]}" config -q
"${compose[@]}" build -q farm1  # every farm runs this one image
lap "image built"

up=$SECONDS
status=0
timeout 600 "${compose[@]}" up --no-build --no-color --exit-code-from tester >"${TMPDIR:-/tmp}/enip-farm-ci-up.log" 2>&1 \
    || status=$?
grep -E '^tester' "${TMPDIR:-/tmp}/enip-farm-ci-up.log" || true
# time to healthy: the first farm's start to the tester's start (it waits for every farm's health)
# shellcheck disable=SC2046
docker inspect $("${compose[@]}" ps -q) | python3 -c '
import json, sys
from datetime import datetime
started = {c["Name"]: datetime.fromisoformat(c["State"]["StartedAt"][:26].rstrip("Z")) for c in json.load(sys.stdin)}
farms = [t for name, t in started.items() if "tester" not in name]
tester = [t for name, t in started.items() if "tester" in name]
if farms and tester:
    print(f"docker/ci.sh: {len(farms)} farms healthy {(tester[0] - min(farms)).total_seconds():.1f} s after the first started",
          file=sys.stderr)
' || true
echo "docker/ci.sh: compose up to the tester's exit: $((SECONDS - up)) s, tester exit status $status" >&2
if [ "$status" != 0 ]; then
    tail -80 "${TMPDIR:-/tmp}/enip-farm-ci-up.log" >&2
fi
"${compose[@]}" down -t 10 >/dev/null 2>&1
lap "fleet down"
exit "$status"
