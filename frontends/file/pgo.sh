#!/usr/bin/env bash
# Builds the `shearwarp` CLI with a profile (frontends/pgo.sh), prints the binary's
# path, and runs it with this script's arguments if there are any, e.g.
#   frontends/file/pgo.sh render fixtures/mr_head_colin27.json -o head.png --shading
#
# Training renders the small fixtures (the 64³ MR head and brain, the proton-density
# series) with `shearwarp bench` the common ways: shaded and unshaded, one and two
# threads, 256² and 512², maximum intensity, post-classified and perspective. On the
# Zen 2 of BENCHMARKS.md it took 7–11 % off the shaded frames of the full-size head
# and the hires brain, trained on their 64³ versions only (`shearwarp bench VOLUME
# --shading`, one thread, 256², three passes: 11.2–11.7 → 10.4 ms and 14.4–14.5 →
# 12.9–13.0 ms; two threads, the head, 5.8 → 5.3–5.5 ms). Thirteen renders (every
# mode, shadows, depth cueing, supersampling, perspective, 16-bit output, two
# threads) were byte-identical to the plain build's.
set -euo pipefail
cd "$(dirname "$0")/../.."
source frontends/pgo.sh

train() {
    local bin=$1 v t
    for v in fixtures/mr_head_colin27_64.json fixtures/mr_brain_colin27_hires_64.json \
        fixtures/mr_pd_brain_series.json; do
        for t in 1 2; do
            "$bin" bench "$v" --frames 36 --threads "$t" --shading
            "$bin" bench "$v" --frames 36 --threads "$t" --shading --size 512x512
            "$bin" bench "$v" --frames 12 --threads "$t"
        done
        "$bin" bench "$v" --frames 12 --mode mip
        "$bin" bench "$v" --frames 12 --mode post --shading
        "$bin" bench "$v" --frames 12 --shading --projection perspective
    done
}
pgo_build shearwarp-file shearwarp train
echo "$PGO_BIN"
if [ $# -gt 0 ]; then
    exec "$PGO_BIN" "$@"
fi
