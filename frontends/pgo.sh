# Profile-guided builds of a frontend binary; sourced by frontends/bench/pgo.sh (the
# benchmark) and frontends/file/pgo.sh (the `shearwarp` CLI), from the repository root.
#
# pgo_build PACKAGE BINARY TRAIN:
# 1. builds PACKAGE instrumented (`-Cprofile-generate`) into target/pgo/PACKAGE/gen;
# 2. calls the shell function TRAIN with the instrumented BINARY's path, which renders
#    what the profile should stand for;
# 3. merges the counts with `llvm-profdata` (rustup's `llvm-tools` component, added if
#    missing);
# 4. builds PACKAGE again with `-Cprofile-use` into target/pgo/PACKAGE/use, and sets
#    PGO_BIN to the binary there.
# The counts steer inlining and the layout of hot and cold code, nothing else, so the
# binary computes what the plain build computes.
#
# The counters are updated atomically: training renders on two threads at once, and
# plain increments from both lose counts in the hottest loops; so trained, the bench's
# profile-guided build was no faster than the plain one (the hires brain, one thread,
# 256²: 13.1–13.3 against 13.3–13.4 ms; 12.1 trained on one thread alone).
#
# A profile belongs to the binary it was recorded in: the compositor is generic, and
# each binary's instance of it is its own symbol, which another binary's profile does
# not cover. Builds go to target/pgo/, so the plain build in target/release/ is kept.

pgo_build() {
    local package=$1 binary=$2 train=$3
    local dir="$PWD/target/pgo/$package"
    local sysroot host profdata
    sysroot=$(rustc --print sysroot)
    host=$(rustc -vV | sed -n 's/^host: //p')
    profdata="$sysroot/lib/rustlib/$host/bin/llvm-profdata"
    if [ ! -x "$profdata" ]; then
        rustup component add llvm-tools >&2
    fi
    if [ ! -x "$profdata" ]; then
        echo "pgo: llvm-profdata not found at $profdata (rustup component add llvm-tools)" >&2
        return 1
    fi
    echo "pgo: instrumented build of $package" >&2
    rm -rf "$dir/raw"
    RUSTFLAGS="${RUSTFLAGS:-} -Cprofile-generate=$dir/raw -Cllvm-args=-instrprof-atomic-counter-update-all" \
        CARGO_TARGET_DIR="$dir/gen" cargo build --release -p "$package" >&2
    echo "pgo: training $binary" >&2
    "$train" "$dir/gen/release/$binary" >&2
    "$profdata" merge -o "$dir/merged.profdata" "$dir"/raw/*.profraw
    echo "pgo: profile-guided build of $package" >&2
    RUSTFLAGS="${RUSTFLAGS:-} -Cprofile-use=$dir/merged.profdata" CARGO_TARGET_DIR="$dir/use" \
        cargo build --release -p "$package" >&2
    PGO_BIN="$dir/use/release/$binary"
}
