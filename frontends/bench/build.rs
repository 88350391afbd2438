//! Compiles the VolPack driver (`csrc/vpdriver.c`) when VolPack's header and library are
//! installed, and sets `cfg(has_volpack)` for the Rust side. Without VolPack the crate
//! still builds; the binary then explains how to install it and runs only shearwarp.
//!
//! Search order: `$VOLPACK_DIR/include` + `$VOLPACK_DIR/lib`, then the system prefixes
//! (`/usr`, `/usr/local`, with the Debian multiarch library directory). Set
//! `SHEARWARP_BENCH_NO_VOLPACK=1` to build without VolPack even when it is present.

use std::env;
use std::path::{Path, PathBuf};

fn multiarch() -> Option<String> {
    // x86_64-unknown-linux-gnu -> x86_64-linux-gnu
    let target = env::var("TARGET").ok()?;
    let parts: Vec<&str> = target.split('-').collect();
    match parts.as_slice() {
        [arch, _vendor, os, abi] => Some(format!("{arch}-{os}-{abi}")),
        _ => None,
    }
}

fn find_volpack() -> Option<(PathBuf, PathBuf)> {
    let mut prefixes: Vec<PathBuf> = Vec::new();
    if let Some(dir) = env::var_os("VOLPACK_DIR") {
        prefixes.push(PathBuf::from(dir));
    }
    prefixes.push(PathBuf::from("/usr"));
    prefixes.push(PathBuf::from("/usr/local"));
    let arch = multiarch();
    for prefix in &prefixes {
        let include = prefix.join("include");
        if !include.join("volpack.h").is_file() {
            continue;
        }
        let mut libdirs = Vec::new();
        if let Some(a) = &arch {
            libdirs.push(prefix.join("lib").join(a));
        }
        libdirs.push(prefix.join("lib"));
        libdirs.push(prefix.join("lib64"));
        for lib in libdirs {
            let has = |name: &str| lib.join(name).is_file();
            if has("libvolpack.a") || has("libvolpack.so") {
                return Some((include, lib));
            }
        }
    }
    None
}

/// First line of `cmd --version`, for the benchmark report.
fn version(cmd: &std::ffi::OsStr) -> String {
    std::process::Command::new(cmd)
        .arg("--version")
        .output()
        .ok()
        .and_then(|o| String::from_utf8(o.stdout).ok())
        .and_then(|s| s.lines().next().map(str::to_string))
        .unwrap_or_else(|| "unknown".into())
}

/// FNV-1a of the reference ray caster's source, so cached reference images are
/// recomputed whenever the caster changes.
fn reference_hash() -> u64 {
    let path = Path::new("../../tests/src/reference.rs");
    println!("cargo::rerun-if-changed={}", path.display());
    let bytes = std::fs::read(path).unwrap_or_default();
    bytes.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &b| {
        (h ^ u64::from(b)).wrapping_mul(0x100_0000_01b3)
    })
}

fn main() {
    println!(
        "cargo::rustc-env=BENCH_REFERENCE_HASH={:016x}",
        reference_hash()
    );
    let rustc = env::var_os("RUSTC").unwrap_or_else(|| "rustc".into());
    println!("cargo::rustc-env=BENCH_RUSTC_VERSION={}", version(&rustc));
    println!("cargo::rustc-check-cfg=cfg(has_volpack)");
    println!("cargo::rerun-if-changed=csrc/vpdriver.c");
    println!("cargo::rerun-if-env-changed=VOLPACK_DIR");
    println!("cargo::rerun-if-env-changed=SHEARWARP_BENCH_NO_VOLPACK");
    if env::var_os("SHEARWARP_BENCH_NO_VOLPACK").is_some_and(|v| v != "0") {
        println!("cargo::warning=VolPack disabled by SHEARWARP_BENCH_NO_VOLPACK");
        println!("cargo::rustc-env=BENCH_CC_VERSION=none (VolPack disabled)");
        return;
    }
    let Some((include, lib)) = find_volpack() else {
        // Not an error: the benchmark then runs the shearwarp side only.
        println!("cargo::rustc-env=BENCH_CC_VERSION=none (VolPack not found)");
        return;
    };
    println!(
        "cargo::rerun-if-changed={}",
        Path::new(&include).join("volpack.h").display()
    );
    let mut build = cc::Build::new();
    build
        .file("csrc/vpdriver.c")
        .include(&include)
        .warnings(true);
    let cc_version = version(build.get_compiler().path().as_os_str());
    println!("cargo::rustc-env=BENCH_CC_VERSION={cc_version}");
    build.compile("vpdriver");
    println!("cargo::rustc-link-search=native={}", lib.display());
    // Debian's libvolpack1-dev ships only the static archive; prefer it when present so
    // the binary does not depend on the runtime package.
    if lib.join("libvolpack.a").is_file() {
        println!("cargo::rustc-link-lib=static=volpack");
    } else {
        println!("cargo::rustc-link-lib=dylib=volpack");
    }
    println!("cargo::rustc-link-lib=dylib=m");
    println!("cargo::rustc-cfg=has_volpack");
}
