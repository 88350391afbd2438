#!/usr/bin/env bash
# Builds shearwarp-bench with a profile and runs it with this script's arguments (those
# of `cargo run --release -p shearwarp-bench --`).
#
# 1. An instrumented build (`-Cprofile-generate`) renders the training scenes
#    (`shearwarp-bench --train`: a proton-density MR series and nested spheres of sides
#    96 and 192, none of which the benchmark times), every way the benchmark renders.
#    Its counters are updated atomically: the benchmark renders on two threads at once,
#    and plain increments from both lose counts in the hottest loops; trained so, the
#    profile-guided build was no faster than the plain one (the hires brain, one thread,
#    256²: 13.1–13.3 against 13.3–13.4 ms; 12.1 trained on one thread alone).
# 2. `llvm-profdata` (rustup's `llvm-tools` component) merges the counts.
# 3. The release build is made again with `-Cprofile-use`: the counts steer inlining
#    and the layout of hot and cold code, nothing else, so the image is the same.
#
# The profile belongs to this binary: the compositor is generic, and another binary's
# instance of it (the `shearwarp` CLI's, say) is another symbol that this profile does
# not cover. Builds go to target/pgo/, so the plain build in target/release/ is kept.
set -euo pipefail
cd "$(dirname "$0")/../.."

dir="$PWD/target/pgo"
sysroot=$(rustc --print sysroot)
host=$(rustc -vV | sed -n 's/^host: //p')
profdata="$sysroot/lib/rustlib/$host/bin/llvm-profdata"
if [ ! -x "$profdata" ]; then
    rustup component add llvm-tools >&2
fi
if [ ! -x "$profdata" ]; then
    echo "pgo.sh: llvm-profdata not found at $profdata (rustup component add llvm-tools)" >&2
    exit 1
fi

trained="a proton-density MR brain series (256×256×20) and nested spheres of sides 96 and 192"
export SHEARWARP_BENCH_PGO="$trained"

# The training run reads the data directory the timed run is given.
data=()
args=("$@")
for ((i = 0; i < ${#args[@]}; i++)); do
    case "${args[i]}" in
    --data) data=(--data "${args[i + 1]:-}") ;;
    --data=*) data=("${args[i]}") ;;
    esac
done

echo "pgo.sh: instrumented build" >&2
rm -rf "$dir/raw"
RUSTFLAGS="${RUSTFLAGS:-} -Cprofile-generate=$dir/raw -Cllvm-args=-instrprof-atomic-counter-update-all" \
    CARGO_TARGET_DIR="$dir/gen" cargo build --release -p shearwarp-bench
echo "pgo.sh: training on $trained" >&2
"$dir/gen/release/shearwarp-bench" --train --rounds 1 --prep-runs 1 "${data[@]}" >&2
"$profdata" merge -o "$dir/bench.profdata" "$dir"/raw/*.profraw

echo "pgo.sh: profile-guided build" >&2
RUSTFLAGS="${RUSTFLAGS:-} -Cprofile-use=$dir/bench.profdata" CARGO_TARGET_DIR="$dir/use" \
    cargo build --release -p shearwarp-bench
exec "$dir/use/release/shearwarp-bench" "$@"
