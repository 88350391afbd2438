//! Sidecar + raw/gzip loader (`shearwarp_file::volume`).
//!
//! Input layout: `FLAGS SIDECAR_JSON 0x00 DATA`. The sidecar is written to `v.json` and
//! the data to one of four names in a private scratch directory (the loader works on
//! paths), then loaded through the sidecar or through the data file.
//!
//! FLAGS bits: 0–1 data file name (`v.u8.raw`, `v.u16.raw`, `v.u8.raw.gz`, `v.raw`);
//! 2: load through the data file instead of the sidecar; 3: prefer u16; 4: gzip DATA
//! before writing it (so the fuzzer reaches the decompressed-size checks easily).
//!
//! Sidecars that could name a file outside the scratch directory (a `/`, or a JSON escape
//! that could spell one) are skipped: the loader follows the names it is given.
//!
//! A loaded volume must be self-consistent; small ones are then classified and encoded.
#![no_main]

use std::io::Write;
use std::path::PathBuf;
use std::sync::OnceLock;

use libfuzzer_sys::fuzz_target;
use shearwarp_file::scene::{self, Classification};
use shearwarp_file::volume::{self, Prefer, Voxels, MAX_DIM, MAX_VOXELS};

const NAMES: [&str; 4] = ["v.u8.raw", "v.u16.raw", "v.u8.raw.gz", "v.raw"];

fn scratch() -> &'static PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let d = std::env::temp_dir().join(format!("shearwarp-fuzz-sidecar-{}", std::process::id()));
        std::fs::create_dir_all(&d).expect("scratch directory");
        d
    })
}

fn could_escape(json: &[u8]) -> bool {
    json.contains(&b'/')
        || json
            .windows(2)
            .any(|w| w[0] == b'\\' && (w[1] == b'/' || w[1] == b'u' || w[1] == b'U'))
}

fn gzip(data: &[u8]) -> Vec<u8> {
    let mut enc = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
    let _ = enc.write_all(data);
    enc.finish().unwrap_or_default()
}

fuzz_target!(|input: &[u8]| {
    let Some((&flags, rest)) = input.split_first() else {
        return;
    };
    let (json, data) = match rest.iter().position(|&b| b == 0) {
        Some(i) => (&rest[..i], &rest[i + 1..]),
        None => (rest, &[][..]),
    };
    if could_escape(json) {
        return;
    }
    let dir = scratch();
    for n in NAMES {
        let _ = std::fs::remove_file(dir.join(n));
    }
    let sidecar = dir.join("v.json");
    let data_path = dir.join(NAMES[(flags & 3) as usize]);
    let payload = if flags & 16 != 0 {
        gzip(data)
    } else {
        data.to_vec()
    };
    if std::fs::write(&sidecar, json).is_err() || std::fs::write(&data_path, &payload).is_err() {
        return;
    }
    let path = if flags & 4 != 0 { &data_path } else { &sidecar };
    let prefer = if flags & 8 != 0 {
        Prefer::U16
    } else {
        Prefer::U8
    };
    let vol = match volume::load_volume_with(path, prefer) {
        Ok(v) => v,
        Err(e) => {
            // Messages are user-facing: formatting them must not panic either.
            let _ = e.to_string();
            let _ = e.path();
            return;
        }
    };
    let [nx, ny, nz] = vol.dims;
    assert!(
        vol.dims.iter().all(|&d| (1..=MAX_DIM).contains(&d)),
        "{:?}",
        vol.dims
    );
    assert!((nx * ny * nz) as u64 <= MAX_VOXELS);
    assert_eq!(vol.voxels.len(), nx * ny * nz);
    assert!(vol.spacing.iter().all(|s| s.is_finite() && *s > 0.0));
    if vol.voxels.len() <= 4096 {
        let (lo, hi) = match &vol.voxels {
            Voxels::U8(_) => (0.0, 255.0),
            Voxels::U16(_) => (0.0, 65535.0),
        };
        let class = Classification {
            opacity: vec![(lo, 0.0), (hi, 1.0)],
            gradient: None,
            min_opacity: 0.0,
            cut: scene::Cut::NONE,
        };
        // Spacing the core refuses (e.g. > 1e6) is an error, never a panic.
        let _ = scene::encode(&vol, &class).map(|e| e.visible_voxels());
    }
});
