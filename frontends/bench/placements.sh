#!/usr/bin/env bash
# Times one-thread frames of the working tree against a base revision at several
# placements of the core's out-of-line code, so that a change is judged by what it does
# across placements rather than by one build.
#
# Why: the compositor is compiled where the frontend instantiates it, the core's
# out-of-line helpers (`Row::clear`, `Needed::reach`) with the core, some 590 KB later
# in the binary. Moving the helpers by 1.5-2.5 KB relative to the compositor made
# one-thread frames up to 5 % slower with the compositor's code unchanged
# (BENCHMARKS.md), as much as most single changes gain or lose. Each placement here is
# a build with PAD bytes in a code section of its own at the start of the core's code
# (a `global_asm!` block added to a checked-out copy, never to the repository).
#
# usage: frontends/bench/placements.sh [BASE_REV] [PASSES] [PAD...]
#   BASE_REV  the revision to compare with (default HEAD); the other side is the
#             working tree with its uncommitted changes to tracked files (`git stash
#             create`: new files must be added first)
#   PASSES    passes over all builds, alternating (default 2)
#   PAD       padding sizes in bytes (default 0 768 1536 2304)
# Prints, per build, each pass's one-thread medians at 256² (brainsmall, the head, the
# hires brain), then per side the median over all placements and passes.
set -euo pipefail
cd "$(dirname "$0")/../.."
root=$(pwd)
base_rev=${1:-HEAD}
passes=${2:-2}
shift $(($# < 2 ? $# : 2))
pads=("$@")
[ ${#pads[@]} -gt 0 ] || pads=(0 768 1536 2304)
data=${SHEARWARP_DATA:-$root/../shared/data}
out=$root/target/placements
mkdir -p "$out/bin"

work_rev=$(git stash create)
work_rev=${work_rev:-$(git rev-parse HEAD)}
cleanup() {
    for side in base work; do
        git worktree remove --force "$out/$side" >/dev/null 2>&1 || true
    done
}
trap cleanup EXIT

for side in base work; do
    rev=$base_rev
    [ "$side" = work ] && rev=$work_rev
    git worktree remove --force "$out/$side" >/dev/null 2>&1 || true
    git worktree add --detach -q "$out/$side" "$rev"
    lib="$out/$side/core/src/lib.rs"
    for pad in "${pads[@]}"; do
        git -C "$out/$side" checkout -q -- core/src/lib.rs
        if [ "$pad" -gt 0 ]; then
            sed -i 's/#!\[forbid(unsafe_code)\]/#![deny(unsafe_code)]/' "$lib"
            printf '#[allow(unsafe_code)]\nmod placement_pad {\n    core::arch::global_asm!(".pushsection .text.placement_pad,\\"axR\\",@progbits\\n.skip %d\\n.popsection");\n}\n' "$pad" >>"$lib"
        fi
        (cd "$out/$side" && cargo build --release -q -p shearwarp-bench --target-dir "$out/target-$side")
        cp "$out/target-$side/release/shearwarp-bench" "$out/bin/$side-$pad"
    done
done

results=$out/results.txt
: >"$results"
for ((p = 1; p <= passes; p++)); do
    for pad in "${pads[@]}"; do
        for side in base work; do
            ms=$("$out/bin/$side-$pad" --data "$data" \
                --scenes brainsmall,mr_head_colin27,mr_brain_colin27_hires --no-scaling \
                --rounds 3 --sizes 256 --no-psnr --no-volpack --threads 0 --prep-runs 1 \
                --no-baseline --supersample 1 2>&1 |
                awk '/^(brainsmall|mr_)/ {printf "%s ", $7}')
            echo "pass $p  $side  pad $pad  ms: $ms" | tee -a "$results"
        done
    done
done

echo "median over placements and passes (brainsmall, head, hires brain ms):"
for side in base work; do
    awk -v s="$side" '$3 == s { for (i = 7; i <= 9; i++) v[i - 6, ++n[i - 6]] = $i }
        END {
            printf "  %s:", s
            for (c = 1; c <= 3; c++) {
                m = n[c]
                for (i = 1; i <= m; i++) a[i] = v[c, i]
                for (i = 1; i <= m; i++) for (j = i + 1; j <= m; j++) if (a[j] < a[i]) { t = a[i]; a[i] = a[j]; a[j] = t }
                printf " %.2f", (m % 2 ? a[(m + 1) / 2] : (a[m / 2] + a[m / 2 + 1]) / 2)
            }
            printf "\n"
        }' "$results"
done
