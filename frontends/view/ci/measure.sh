#!/usr/bin/env bash
# Frame-rate measurements of the README's "Desktop preview" table: runs rotate.script,
# full.script and window-level.script RUNS times (default 3) in a real window under Xvfb
# on the Colin27 head (512x512, --threads 2) and prints the viewer's summaries.
# Needs xvfb and a release build of shearwarp-view. Other load on the machine shows in
# the numbers: run it on an idle machine and look at `uptime` before and after.
set -euo pipefail
cd "$(dirname "$0")/../../.."
bin="${CARGO_TARGET_DIR:-target}/release/shearwarp-view"
runs="${1:-3}"
out="$(mktemp -d)"
trap 'rm -rf "$out"' EXIT
uptime
for s in rotate full window-level; do
    for i in $(seq "$runs"); do
        echo "== $s.script, run $i"
        xvfb-run -a -s "-screen 0 1024x768x24" "$bin" fixtures/mr_head_colin27.json \
            --rotate-x -70 --rotate-y -35 --threads 2 \
            --script "frontends/view/ci/$s.script" --dump "$out/frame.png" |
            grep '^summary' | grep -v 'no dragging' || true
    done
done
uptime
