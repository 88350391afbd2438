//! Puts `memory.x` on the linker path and points the firmware at the `.swv` volume to
//! embed (environment variable `SHEARWARP_SWV`, an absolute path).
use std::path::PathBuf;

fn main() {
    let out = PathBuf::from(std::env::var("OUT_DIR").expect("OUT_DIR"));
    std::fs::copy("memory.x", out.join("memory.x")).expect("copy memory.x");
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed=memory.x");
    println!("cargo:rerun-if-env-changed=SHEARWARP_SWV");
    // `panics.sh` links the plain panic handler, to list the calls the linker check of
    // `src/main.rs` refuses.
    println!("cargo:rustc-check-cfg=cfg(list_panics)");
    println!("cargo:rerun-if-env-changed=SHEARWARP_LIST_PANICS");
    if std::env::var_os("SHEARWARP_LIST_PANICS").is_some() {
        println!("cargo:rustc-cfg=list_panics");
    }
    match std::env::var("SHEARWARP_SWV") {
        Ok(p) => println!("cargo:rerun-if-changed={p}"),
        Err(_) => panic!(
            "set SHEARWARP_SWV to the absolute path of a 64³ .swv volume \
             (e.g. `shearwarp encode fixtures/mr_head_colin27_64.json -o /tmp/head64.swv --shading`)"
        ),
    }
}
