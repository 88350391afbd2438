#!/usr/bin/env bash
# Lists the calls to the panic handler left in a release firmware binary
# (`panics.sh` for the renderer, `panics.sh audit` for the binary that links the core's
# other entry points), each by the innermost line of the core or the firmware it was
# inlined from, with a count.
#
# The release firmware does not link while any is left (see the panic handler in
# src/no_panic.rs); this builds it with the plain handler instead (SHEARWARP_LIST_PANICS, in
# a target directory of its own) and reads the calls out of its disassembly. Prints
# "no panic paths" and exits 0 when there are none.
set -euo pipefail
bin="${1:-shearwarp-mcu}"
here="$(cd "$(dirname "$0")" && pwd)"
root="$(cd "$here/../.." && pwd)"
swv="${SHEARWARP_SWV:-$root/target/mcu/head64.swv}"
if [ ! -f "$swv" ]; then
    cargo build --release -q -p shearwarp-file --manifest-path "$root/Cargo.toml"
    mkdir -p "$(dirname "$swv")"
    "$root/target/release/shearwarp" encode "$root/fixtures/mr_head_colin27_64.json" -o "$swv" --shading
fi
target="$here/target/panic-sites"
(cd "$here" && SHEARWARP_SWV="$swv" SHEARWARP_LIST_PANICS=1 CARGO_TARGET_DIR="$target" \
    cargo build --release -q --bin "$bin")
elf="$target/thumbv7m-none-eabi/release/$bin"
objdump="$(ls "$(rustc --print sysroot)"/lib/rustlib/*/bin/llvm-objdump 2>/dev/null | head -1 || true)"
[ -n "$objdump" ] || { echo "needs llvm-objdump: rustup component add llvm-tools" >&2; exit 2; }

# Branches (calls or jumps) into the panic machinery of `core` (the panicking functions
# and the `*_fail` helpers of slice indexing and copying), from outside it.
sites="$("$objdump" -d --no-show-raw-insn "$elf" | awk '
    /^[0-9a-f]+ <.*>:$/ { inside = ($2 ~ /panic|_fail/) }
    !inside && /\t(bl?|b\.w|b[a-z][a-z](\.w)?)\t.*<[^>]*(panic|_fail)[^>]*>/ {
        sub(":", "", $1); print "0x" $1 }')"
if [ -z "$sites" ]; then
    echo "no panic paths"
    exit 0
fi
echo "panic paths: $(echo "$sites" | wc -l)"
# addr2line prints the inline chain innermost first; keep the first frame in our code.
echo "$sites" | addr2line -e "$elf" -i -f -C -a | awk '
    /^0x/ { if (addr != "") print best; addr = $0; best = ""; fn = ""; next }
    fn == "" { fn = $0; next }
    { if (best == "" && $0 ~ /(core|mcu)\/src\/[a-z_]+\.rs:[0-9]+/ && $0 !~ /\/library\//) best = fn " " $0; fn = "" }
    END { if (addr != "") print best }' | sed 's# /[^ ]*/\(core\|mcu\)/src/# \1/src/#; s/ (discriminator.*)//' |
    sort | uniq -c | sort -rn
exit 1
