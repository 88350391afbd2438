#!/usr/bin/env bash
# Runs every fuzz target (or the ones named) for a bounded time each:
#
#   fuzz/run.sh SECONDS [TARGET...]
#
# Targets: swv_render, sidecar_load, tfspec, formats_load, tffile, dense_render. Needs the nightly toolchain and cargo-fuzz
# (`cargo install cargo-fuzz`). Builds with debug assertions and overflow checks, so an
# integer overflow is a crash too. The growing corpus lives in fuzz/corpus/TARGET
# (ignored by git; fuzz/seeds/TARGET, checked in, is read as well), crashes land in
# fuzz/artifacts/TARGET, and the libFuzzer log in fuzz/logs/TARGET.log.
#
# Environment: FUZZ_JOBS (parallel workers per target, default 1), FUZZ_SANITIZER
# (default none: the core forbids unsafe code, so ASan mostly costs speed; use
# `address` to check the dependencies too).
#
# Exits non-zero if any target found a crash; prints executions per target.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
cd "$here"

if [ $# -lt 1 ] || ! [[ "$1" =~ ^[0-9]+$ ]]; then
    echo "usage: $0 SECONDS [TARGET...]" >&2
    exit 2
fi
secs="$1"
shift
targets=("$@")
[ ${#targets[@]} -gt 0 ] || targets=(swv_render sidecar_load tfspec formats_load tffile dense_render)
jobs="${FUZZ_JOBS:-1}"
san="${FUZZ_SANITIZER:-none}"

max_len() {
    case "$1" in
    swv_render) echo 40000 ;;
    sidecar_load) echo 4096 ;;
    tfspec) echo 256 ;;
    formats_load) echo 8192 ;;
    tffile) echo 4096 ;;
    dense_render) echo 8192 ;;
    *) echo 4096 ;;
    esac
}

mkdir -p logs
# Build once, then run the binaries directly (no rebuild between targets).
cargo +nightly fuzz build -a -s "$san"
bin="target/$(rustc +nightly -vV | sed -n 's/^host: //p')/release"

failed=0
summary=()
for t in "${targets[@]}"; do
    mkdir -p "corpus/$t" "artifacts/$t"
    log="logs/$t.log"
    before=$(find "artifacts/$t" -type f | wc -l)
    par=()
    [ "$jobs" -gt 1 ] && par=(-jobs="$jobs" -workers="$jobs")
    rm -f fuzz-*.log
    set +e
    "$bin/$t" -artifact_prefix="artifacts/$t/" -max_total_time="$secs" \
        -max_len="$(max_len "$t")" -timeout=10 -rss_limit_mb=4096 -print_final_stats=1 \
        "${par[@]}" "corpus/$t" "seeds/$t" >"$log" 2>&1
    rc=$?
    set -e
    # With -jobs > 1 each worker logs to fuzz-N.log in the current directory.
    stats=("$log")
    if compgen -G 'fuzz-*.log' >/dev/null; then
        stats=(fuzz-*.log)
    fi
    execs=$({ grep -h 'stat::number_of_executed_units' "${stats[@]}" || true; } |
        awk '{s += $2} END {print s + 0}')
    if [ "${stats[0]}" != "$log" ]; then
        cat "${stats[@]}" >>"$log"
        rm -f "${stats[@]}"
    fi
    after=$(find "artifacts/$t" -type f | wc -l)
    status="ok"
    if [ "$rc" -ne 0 ] || [ "$after" -gt "$before" ]; then
        status="CRASH (exit $rc, see $log and artifacts/$t)"
        failed=1
    fi
    summary+=("$t: ${secs}s, $execs executions, corpus $(find "corpus/$t" -type f | wc -l) files: $status")
done

printf '%s\n' "${summary[@]}"
exit "$failed"
