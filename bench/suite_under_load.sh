#!/usr/bin/env bash
# The whole test suite N times in a row (default 5) on a busy machine: the quick-start farm
# (`enip-farm serve`, the default cell on 127.0.10.x and discovery on 0.0.0.0:44818) runs beside
# it, and two CPU hogs keep two cores busy during every run. Prints each run's counts and a total;
# exits 0 only if no run had a failure or an error. Everything it starts is stopped on exit.
#
#   bench/suite_under_load.sh [N]        e.g. bench/suite_under_load.sh 2
set -uo pipefail
cd "$(dirname "$0")/.."
runs=${1:-5}
run_limit_s=1800   # one run of the suite, at most
hog_s=900          # one hog, at most (hogs are started afresh for every run)
log=$(mktemp -d "${TMPDIR:-/tmp}/suite-under-load.XXXXXX")
farm=""
hogs=()

stop() {
    local pid
    for pid in "${hogs[@]}" $farm; do
        kill "$pid" 2>/dev/null
    done
    for pid in "${hogs[@]}" $farm; do
        wait "$pid" 2>/dev/null
    done
    hogs=()
}
trap 'stop; trap - EXIT; exit 130' INT TERM
trap stop EXIT

# the quick-start farm, from this tree; if one already serves the default cell, run beside that one
python -m enip_farm serve >"$log/farm.out" 2>"$log/farm.err" &
farm=$!
for _ in $(seq 600); do  # up to 60 s for its table
    if grep -q "listening" "$log/farm.err" || ! kill -0 "$farm" 2>/dev/null; then break; fi
    sleep 0.1
done
if ! kill -0 "$farm" 2>/dev/null; then
    wait "$farm" 2>/dev/null
    farm=""
    if grep -q "already in use" "$log/farm.err"; then
        echo "a farm already serves the default cell on this host: running beside that one"
    else
        echo "enip-farm serve did not start:" >&2
        cat "$log/farm.err" >&2
        exit 2
    fi
elif ! grep -q "listening" "$log/farm.err"; then
    echo "enip-farm serve printed no table within 60 s" >&2
    exit 2
else
    echo "enip-farm serve (default cell, pid $farm) runs beside the suite"
fi

total_passed=0 total_failed=0 total_errors=0 total_skipped=0 bad_runs=0
count() {  # count WORD SUMMARY: the number before WORD in pytest's summary line, or 0
    grep -oE "[0-9]+ $1" <<<"$2" | grep -oE "^[0-9]+" || echo 0
}
for run in $(seq "$runs"); do
    hogs=()
    for _ in 1 2; do
        timeout "$hog_s" sh -c 'while :; do :; done' &
        hogs+=($!)
    done
    start=$(date +%s)
    timeout "$run_limit_s" python -m pytest -q -p no:cacheprovider >"$log/run$run.out" 2>&1
    status=$?
    stop_hogs=("${hogs[@]}")
    for pid in "${stop_hogs[@]}"; do kill "$pid" 2>/dev/null; wait "$pid" 2>/dev/null; done
    hogs=()
    summary=$(grep -E "(passed|failed|error|no tests ran).* in [0-9.]+s" "$log/run$run.out" | tail -1)
    passed=$(count passed "$summary") failed=$(count failed "$summary")
    errors=$(count "errors?" "$summary") skipped=$(count skipped "$summary")
    if [ "$status" -ne 0 ] && [ "$failed" -eq 0 ] && [ "$errors" -eq 0 ]; then
        errors=1  # killed by the time limit, or pytest itself failed
        summary="exit status $status (see $log/run$run.out)"
    fi
    printf 'run %d/%d: %3d passed, %d failed, %d errors, %d skipped  (%ds)\n' "$run" "$runs" "$passed" "$failed" \
        "$errors" "$skipped" "$(($(date +%s) - start))"
    grep -E "^(FAILED|ERROR) " "$log/run$run.out" | sed 's/^/    /'
    total_passed=$((total_passed + passed)) total_failed=$((total_failed + failed))
    total_errors=$((total_errors + errors)) total_skipped=$((total_skipped + skipped))
    if [ "$failed" -ne 0 ] || [ "$errors" -ne 0 ]; then bad_runs=$((bad_runs + 1)); fi
done
echo "total over $runs runs: $total_passed passed, $total_failed failed, $total_errors errors," \
     "$total_skipped skipped; $bad_runs of $runs runs not clean (output in $log)"
[ "$bad_runs" -eq 0 ]
