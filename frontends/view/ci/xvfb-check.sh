#!/usr/bin/env bash
# Runs shearwarp-view in a real X window under Xvfb: replays head.script, writes the final
# frame with --dump, takes a screenshot of the window with xwd, and checks the dump and the
# screenshot against the file frontend's rendering of the same view (the viewer prints the
# equivalent `shearwarp render` arguments as "cli-args: ...").
#
# Tolerance: every channel of every pixel within 2 of the file frontend's image (the
# viewer composites with the same core code and the window shows its frame unscaled on a
# 24-bit visual, so the expected difference is 0).
#
# Needs: xvfb (xvfb-run), x11-apps (xwd), x11-utils (xwininfo), release builds of
# shearwarp-view and shearwarp (cargo build --release -p shearwarp-view -p shearwarp-file).
set -euo pipefail
root="$(cd "$(dirname "$0")/../../.." && pwd)"
cd "$root"
bin="${CARGO_TARGET_DIR:-target}/release"
out="${VIEW_CI_OUT:-target/view-ci}"
vol=fixtures/mr_head_colin27.json
tolerance=2
mkdir -p "$out"
rm -f "$out"/view.png "$out"/window.xwd "$out"/window.png "$out"/file.png "$out"/view.log

# In the virtual display: start the viewer, wait for its dump, grab the window, let the
# viewer finish its hold time and exit by itself.
xvfb-run -a -s "-screen 0 1024x768x24" bash -c '
    set -euo pipefail
    bin=$1 vol=$2 script=$3 out=$4
    "$bin/shearwarp-view" "$vol" --rotate-x -70 --rotate-y -10 --threads 2 \
        --script "$script" --dump "$out/view.png" --hold-ms 3000 >"$out/view.log" 2>&1 &
    pid=$!
    for _ in $(seq 1800); do
        [ -s "$out/view.png" ] && break
        kill -0 "$pid" 2>/dev/null || break
        sleep 0.1
    done
    if [ ! -s "$out/view.png" ]; then
        echo "shearwarp-view wrote no dump"; cat "$out/view.log"; exit 1
    fi
    sleep 0.3
    id=$(xwininfo -root -tree | awk "/ - shearwarp-view\":/ { print \$1; exit }")
    [ -n "$id" ] || { echo "no shearwarp-view window on the display"; xwininfo -root -tree; exit 1; }
    xwd -silent -id "$id" -out "$out/window.xwd"
    wait "$pid"
' _ "$bin" "$vol" frontends/view/ci/head.script "$out"

grep -E "^(summary|wrote|no shadows)" "$out/view.log" || true
grep -q "^summary: preview frames [1-9]" "$out/view.log" || { echo "no preview frames"; exit 1; }
args=$(sed -n 's/^cli-args: //p' "$out/view.log" | tail -n 1)
[ -n "$args" ] || { echo "the viewer printed no cli-args"; cat "$out/view.log"; exit 1; }
case "$args" in
    *--shadows*--depth-cue*--clip-invert*) ;;
    *) echo "the final frame should have shadows, depth cueing and a corner cut: $args"; exit 1 ;;
esac
echo "reference: shearwarp render $args -o $out/file.png"
eval "\"$bin/shearwarp\" render $args -o \"$out/file.png\""
"$bin/shearwarp-view-compare" "$out/view.png" "$out/file.png" --tolerance "$tolerance"
"$bin/shearwarp-view-compare" "$out/window.xwd" "$out/file.png" --tolerance "$tolerance" \
    --save-a "$out/window.png"

# Perspective, without a window: the refined frame against `shearwarp render` of the
# printed arguments, which must ask for perspective and the viewer's clipping plane, and
# not for depth cueing.
"$bin/shearwarp-view" "$vol" --rotate-x -70 --rotate-y -10 --threads 2 --no-window \
    --perspective --fov 45 --script frontends/view/ci/perspective.script \
    --dump "$out/view-persp.png" >"$out/view-persp.log" 2>&1 \
    || { cat "$out/view-persp.log"; exit 1; }
args=$(sed -n 's/^cli-args: //p' "$out/view-persp.log" | tail -n 1)
case "$args" in
    *--depth-cue*) echo "depth cueing printed for a perspective frame: $args"; exit 1 ;;
    *"--projection perspective --fov 45"*--clip=*:-0.15*) ;;
    *) echo "the final frame should be in perspective and clipped: $args"; exit 1 ;;
esac
echo "reference: shearwarp render $args -o $out/file-persp.png"
eval "\"$bin/shearwarp\" render $args -o \"$out/file-persp.png\""
"$bin/shearwarp-view-compare" "$out/view-persp.png" "$out/file-persp.png" --tolerance "$tolerance"
