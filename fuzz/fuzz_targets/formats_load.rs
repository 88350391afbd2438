//! The medical-format readers of `shearwarp_file::volume` (DICOM, NIfTI, NRRD,
//! MetaImage, VolPack `.den`), through the same dispatch `shearwarp render` uses, and the
//! CLI's whole-file `.swv` reader (`shearwarp_file::swvfile::read_swv`).
//!
//! Input layout: `KIND BYTES`. KIND picks the file name the bytes are written under in a
//! private scratch directory (`v.dcm`, `v.nii`, `v.nii.gz`, `v.nrrd`, `v.mha`, `v.den`,
//! `v.swv`),
//! so the extension-based dispatch reaches every reader; gzip-named inputs are
//! compressed first so the fuzzer gets past the gzip layer. Headers that could name another file (NRRD
//! detached data, MetaImage `ElementDataFile`) can only name files in the scratch
//! directory: inputs containing `/` or `\` are skipped.
//!
//! A loaded volume must be self-consistent.
#![no_main]

use std::io::Write;
use std::path::PathBuf;
use std::sync::OnceLock;

use libfuzzer_sys::fuzz_target;
use shearwarp_file::volume::{self, Prefer, Voxels};

const NAMES: [&str; 7] = [
    "v.dcm", "v.nii", "v.nii.gz", "v.nrrd", "v.mha", "v.den", "v.swv",
];

fn scratch() -> &'static PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let d = std::env::temp_dir().join(format!("shearwarp-fuzz-formats-{}", std::process::id()));
        std::fs::create_dir_all(&d).expect("scratch directory");
        d
    })
}

fuzz_target!(|input: &[u8]| {
    let Some((&kind, bytes)) = input.split_first() else {
        return;
    };
    if bytes.contains(&b'/') || bytes.contains(&b'\\') {
        return;
    }
    let name = NAMES[kind as usize % NAMES.len()];
    let dir = scratch();
    for entry in std::fs::read_dir(dir).into_iter().flatten().flatten() {
        let _ = std::fs::remove_file(entry.path());
    }
    let path = dir.join(name);
    let data = if name.ends_with(".gz") {
        let mut enc = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
        let _ = enc.write_all(bytes);
        enc.finish().unwrap_or_default()
    } else {
        let mut data = bytes.to_vec();
        // A `.swv` carries CRCs that mutation almost never keeps right: recompute them,
        // so that the reader's structural checks see the mutated bytes.
        if name.ends_with(".swv") {
            shearwarp_fuzz::fix_checksums(&mut data);
        }
        data
    };
    if std::fs::write(&path, &data).is_err() {
        return;
    }
    if name.ends_with(".swv") {
        // An accepted file must give a volume the core renders from.
        if let Ok((enc, _look)) = shearwarp_file::swvfile::read_swv(&path) {
            enc.volume().expect("an accepted .swv is a valid volume");
        }
        return;
    }
    if let Ok(v) = volume::load_volume_with(&path, Prefer::U8) {
        let n = v.dims[0] * v.dims[1] * v.dims[2];
        let len = match &v.voxels {
            Voxels::U8(d) => d.len(),
            Voxels::U16(d) => d.len(),
        };
        assert_eq!(n, len, "voxel count must match the dims");
        assert!(v.spacing.iter().all(|s| s.is_finite() && *s > 0.0));
    }
});
