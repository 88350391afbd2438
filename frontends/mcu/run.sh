#!/usr/bin/env bash
# Builds the Cortex-M3 firmware around a freshly encoded 64³ fixture, runs it on QEMU's
# mps2-an385 with semihosting, and checks its frame against the host renderer's frame of
# the same .swv and view: they must be bit-identical.
#
# Prints the firmware's instruction count (QEMU -icount shift=0), flash and static RAM.
# The build itself checks that no code path of the firmware can panic (see the panic
# handler in src/main.rs; `panics.sh` lists the paths when one appears).
set -euo pipefail
root="$(cd "$(dirname "$0")/../.." && pwd)"
out="$root/target/mcu"
mkdir -p "$out"

cargo build --release -q -p shearwarp-file --manifest-path "$root/Cargo.toml"
sw="$root/target/release/shearwarp"
"$sw" encode "$root/fixtures/mr_head_colin27_64.json" -o "$out/head64.swv" --shading

(cd "$root/frontends/mcu" && SHEARWARP_SWV="$out/head64.swv" cargo build --release -q \
    && SHEARWARP_SWV="$out/head64.swv" cargo clippy --release -q -- -D warnings)
elf="$root/frontends/mcu/target/thumbv7m-none-eabi/release/shearwarp-mcu"

rm -f "$out/mcu_frame.ppm"
(cd "$out" && timeout 600 qemu-system-arm -cpu cortex-m3 -machine mps2-an385 -nographic \
    -semihosting-config enable=on,target=native -icount shift=0 -kernel "$elf") \
    | tee "$out/mcu.log"

"$sw" render "$out/head64.swv" -o "$out/host_frame.png" --rotate-x -70 --rotate-y -35 --size 128x128
"$sw" compare "$out/host_frame.png" "$out/mcu_frame.ppm" --tolerance 0

# Flash = the sections loaded from the image; static RAM = .data + .bss (+ .uninit).
size_tool="$(ls "$(rustc --print sysroot)"/lib/rustlib/*/bin/llvm-size 2>/dev/null | head -1 || true)"
[ -n "$size_tool" ] || size_tool="$(command -v llvm-size || true)"
if [ -n "$size_tool" ]; then
    "$size_tool" -A "$elf" | tee "$out/size.txt"
else
    echo "(no llvm-size: run 'rustup component add llvm-tools' for flash/RAM figures)"
fi
echo "mcu: bit-identical to host; no panic paths (the release firmware links only without them)"
