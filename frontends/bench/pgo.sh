#!/usr/bin/env bash
# Builds shearwarp-bench with a profile (frontends/pgo.sh) and runs it with this
# script's arguments (those of `cargo run --release -p shearwarp-bench --`).
#
# The training run is `shearwarp-bench --train`: a proton-density MR series and nested
# spheres of sides 96 and 192, none of which the benchmark times, rendered every way the
# benchmark renders (one and two threads, the SSE2 build, supersampled).
set -euo pipefail
cd "$(dirname "$0")/../.."
source frontends/pgo.sh

export SHEARWARP_BENCH_PGO="a proton-density MR brain series (256×256×20) and nested spheres of sides 96 and 192"

# The training run reads the data directory the timed run is given, and renders flat
# voxels the way it does: the rule's loops (`--flat-voxels excluded`, which `auto`
# picks for the training spheres) are instances of their own, which a profile of the
# other way does not cover.
train_args=()
args=("$@")
for ((i = 0; i < ${#args[@]}; i++)); do
    case "${args[i]}" in
    --data | --flat-voxels) train_args+=("${args[i]}" "${args[i + 1]:-}") ;;
    --data=* | --flat-voxels=*) train_args+=("${args[i]}") ;;
    esac
done

train() { "$1" --train --rounds 1 --prep-runs 1 "${train_args[@]}"; }
pgo_build shearwarp-bench shearwarp-bench train
exec "$PGO_BIN" "$@"
