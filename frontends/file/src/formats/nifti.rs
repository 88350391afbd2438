//! NIfTI-1: `.nii`, `.nii.gz` (single file, magic `n+1`) and `.hdr`/`.img` pairs
//! (magic `ni1`), either byte order.
//!
//! Types u8, i8, u16, i16, u32, i32, f32, f64 are read; values are
//! `scl_slope·raw + scl_inter` when `scl_slope` is non-zero and finite, then the value
//! rule of [`crate::formats`]. Spacing is `pixdim[1..=3]` (absolute values) in the unit
//! of `xyzt_units` (m, mm, µm; unknown counts as mm). Dimensions 4 to 7 must be 1.
//! Orientation comes from the sform (if `sform_code > 0`), else the qform (if
//! `qform_code > 0`); NIfTI's RAS+ world is turned into LPS and the axes are reordered
//! as described in [`crate::formats`]. Without either, the axes are kept as stored.

use super::{bad, check_spacing, dims_from, orient_lps, read_capped, stem_of, to_voxels};
use super::{DataType, Samples, VolumeMeta};
use crate::volume::{LoadError, RawVolume};
use flate2::bufread::MultiGzDecoder;
use std::io::{BufReader, Read};
use std::path::{Path, PathBuf};

struct Header {
    big: bool,
    dims: [usize; 3],
    dtype: DataType,
    pixdim: [f64; 3],
    vox_offset: u64,
    slope: f64,
    inter: f64,
    /// Directions of the index axes in LPS, when the header gives them.
    dirs: Option<[[f64; 3]; 3]>,
    single_file: bool,
}

fn parse_header(path: &Path, h: &[u8]) -> Result<Header, LoadError> {
    if h.len() < 348 {
        return Err(bad(
            path,
            format!("truncated NIfTI header ({} of 348 bytes)", h.len()),
        ));
    }
    let big = match (
        i32::from_le_bytes([h[0], h[1], h[2], h[3]]),
        i32::from_be_bytes([h[0], h[1], h[2], h[3]]),
    ) {
        (348, _) => false,
        (_, 348) => true,
        _ => return Err(bad(path, "not a NIfTI-1 file (sizeof_hdr is not 348)")),
    };
    let single_file = match &h[344..348] {
        b"n+1\0" => true,
        b"ni1\0" => false,
        _ => return Err(bad(path, "not a NIfTI-1 file (bad magic at byte 344)")),
    };
    let i16_at = |o: usize| {
        let a = [h[o], h[o + 1]];
        if big {
            i16::from_be_bytes(a)
        } else {
            i16::from_le_bytes(a)
        }
    };
    let f32_at = |o: usize| {
        let a = [h[o], h[o + 1], h[o + 2], h[o + 3]];
        (if big {
            f32::from_be_bytes(a)
        } else {
            f32::from_le_bytes(a)
        }) as f64
    };
    let dim: Vec<i64> = (0..8).map(|i| i16_at(40 + 2 * i) as i64).collect();
    if !(1..=7).contains(&dim[0]) {
        return Err(bad(path, format!("invalid dim[0] = {}", dim[0])));
    }
    let n = dim[0] as usize;
    let get = |i: usize| if i <= n { dim[i] } else { 1 };
    if let Some(i) = (4..=n).find(|&i| dim[i] != 1) {
        return Err(bad(
            path,
            format!(
                "{}-dimensional image (dim[{i}] = {}): only 3-D volumes are supported",
                n, dim[i]
            ),
        ));
    }
    let dims = dims_from(path, [get(1), get(2), get(3)])?;
    let code = i16_at(70);
    let dtype = match code {
        2 => DataType::U8,
        4 => DataType::I16,
        8 => DataType::I32,
        16 => DataType::F32,
        64 => DataType::F64,
        256 => DataType::I8,
        512 => DataType::U16,
        768 => DataType::U32,
        c => {
            return Err(bad(
                path,
                format!(
                "unsupported NIfTI datatype {c} (u8, i8, u16, i16, u32, i32, f32, f64 are read)"
            ),
            ))
        }
    };
    let unit = match h[123] & 7 {
        1 => 1000.0,
        3 => 0.001,
        _ => 1.0,
    };
    let pd = |i: usize| f32_at(76 + 4 * i).abs() * unit;
    let pixdim = [
        pd(1),
        if n >= 2 { pd(2) } else { 1.0 },
        if n >= 3 { pd(3) } else { 1.0 },
    ];
    let pixdim = check_spacing(path, pixdim)?;
    let vox_offset = f32_at(108);
    if single_file && !(348.0..1e12).contains(&vox_offset) {
        return Err(bad(path, format!("invalid vox_offset {vox_offset}")));
    }
    let (mut slope, mut inter) = (f32_at(112), f32_at(116));
    if slope == 0.0 || !slope.is_finite() || !inter.is_finite() {
        (slope, inter) = (1.0, 0.0);
    }
    // Orientation (RAS+ world).
    let qform_code = i16_at(252);
    let sform_code = i16_at(254);
    let ras: Option<[[f64; 3]; 3]> = if sform_code > 0 {
        // srow_x/y/z at 280, 296, 312: columns 0..2 are the index axes.
        Some(std::array::from_fn(|a| {
            std::array::from_fn(|r| f32_at(280 + 16 * r + 4 * a))
        }))
    } else if qform_code > 0 {
        let (b, c, d) = (f32_at(256), f32_at(260), f32_at(264));
        let a = (1.0 - (b * b + c * c + d * d)).max(0.0).sqrt();
        let qfac = if f32_at(76) < 0.0 { -1.0 } else { 1.0 };
        let r = [
            [
                a * a + b * b - c * c - d * d,
                2.0 * (b * c - a * d),
                2.0 * (b * d + a * c),
            ],
            [
                2.0 * (b * c + a * d),
                a * a + c * c - b * b - d * d,
                2.0 * (c * d - a * b),
            ],
            [
                2.0 * (b * d - a * c),
                2.0 * (c * d + a * b),
                a * a + d * d - c * c - b * b,
            ],
        ];
        Some(std::array::from_fn(|ax| {
            std::array::from_fn(|row| r[row][ax] * if ax == 2 { qfac } else { 1.0 })
        }))
    } else {
        None
    };
    let dirs = ras
        .filter(|m| m.iter().flatten().all(|x| x.is_finite()))
        .map(|m| m.map(|d| [-d[0], -d[1], d[2]]));
    Ok(Header {
        big,
        dims,
        dtype,
        pixdim,
        vox_offset: if single_file { vox_offset as u64 } else { 0 },
        slope,
        inter,
        dirs,
        single_file,
    })
}

fn is_gz(path: &Path) -> bool {
    path.to_string_lossy().to_ascii_lowercase().ends_with(".gz")
}

fn open(path: &Path) -> Result<Box<dyn Read>, LoadError> {
    let f = std::fs::File::open(path).map_err(|source| LoadError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let r = BufReader::new(f);
    Ok(if is_gz(path) {
        Box::new(MultiGzDecoder::new(r))
    } else {
        Box::new(r)
    })
}

/// Loads a NIfTI-1 volume.
pub fn load(path: &Path) -> Result<(RawVolume, VolumeMeta), LoadError> {
    let mut r = open(path)?;
    let head = read_capped(path, &mut r, 348)?;
    let h = parse_header(path, &head)?;
    let count = (h.dims[0] * h.dims[1] * h.dims[2]) as u64;
    let need = count * h.dtype.bytes() as u64;
    let (data, data_path) = if h.single_file {
        // Skip the extension bytes up to vox_offset.
        let skip = h.vox_offset - 348;
        let got = std::io::copy(&mut (&mut r).take(skip), &mut std::io::sink())
            .map_err(|e| bad(path, format!("cannot read up to vox_offset: {e}")))?;
        if got < skip {
            return Err(bad(path, "truncated NIfTI file (ends before vox_offset)"));
        }
        (read_capped(path, r, need)?, path.to_path_buf())
    } else {
        let img = image_path(path);
        let r = open(&img)?;
        (read_capped(&img, r, need)?, img)
    };
    if (data.len() as u64) < need {
        return Err(bad(
            &data_path,
            format!(
                "truncated voxel data: expected {need} bytes for {}×{}×{} {}, found {}",
                h.dims[0],
                h.dims[1],
                h.dims[2],
                h.dtype.name(),
                data.len()
            ),
        ));
    }
    let samples = Samples {
        bytes: &data,
        dtype: h.dtype,
        big_endian: h.big,
        rescale: vec![(h.slope, h.inter)],
        raw_map: None,
    };
    let (voxels, slope, intercept) = to_voxels(&data_path, h.dims, &samples)?;
    let vol = RawVolume {
        name: stem_of(path, &[".nii.gz", ".nii", ".hdr.gz", ".hdr"]),
        dims: h.dims,
        spacing: h.pixdim,
        voxels,
    };
    let (vol, orientation) = match h.dirs {
        Some(d) => orient_lps(vol, d),
        None => (vol, String::new()),
    };
    Ok((
        vol,
        VolumeMeta {
            format: "nifti",
            source_type: h.dtype.name().into(),
            slope,
            intercept,
            modality: None,
            units: None,
            orientation,
        },
    ))
}

/// `x.hdr` → `x.img` (`x.hdr.gz` → `x.img.gz`).
fn image_path(hdr: &Path) -> PathBuf {
    let name = hdr
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let lower = name.to_ascii_lowercase();
    let base = if let Some(i) = lower.rfind(".hdr") {
        format!("{}.img{}", &name[..i], &name[i + 4..])
    } else {
        format!("{name}.img")
    };
    hdr.with_file_name(base)
}

/// Writes a single-file NIfTI-1 (`.nii`, or `.nii.gz` when the name ends in `.gz`) with
/// an sform placing +x left, +y posterior, +z superior (so it loads unchanged), for tests
/// and conversions. `dtype_code` is the NIfTI datatype of `data`
/// (little-endian elements).
pub fn write(
    path: &Path,
    dims: [usize; 3],
    spacing: [f64; 3],
    dtype_code: i16,
    bitpix: i16,
    scl: (f32, f32),
    data: &[u8],
) -> std::io::Result<()> {
    let mut h = vec![0u8; 352];
    h[0..4].copy_from_slice(&348i32.to_le_bytes());
    let dim = [
        3i16,
        dims[0] as i16,
        dims[1] as i16,
        dims[2] as i16,
        1,
        1,
        1,
        1,
    ];
    for (i, d) in dim.iter().enumerate() {
        h[40 + 2 * i..42 + 2 * i].copy_from_slice(&d.to_le_bytes());
    }
    h[70..72].copy_from_slice(&dtype_code.to_le_bytes());
    h[72..74].copy_from_slice(&bitpix.to_le_bytes());
    let pixdim = [
        1.0f32,
        spacing[0] as f32,
        spacing[1] as f32,
        spacing[2] as f32,
    ];
    for (i, p) in pixdim.iter().enumerate() {
        h[76 + 4 * i..80 + 4 * i].copy_from_slice(&p.to_le_bytes());
    }
    h[108..112].copy_from_slice(&352f32.to_le_bytes());
    h[112..116].copy_from_slice(&scl.0.to_le_bytes());
    h[116..120].copy_from_slice(&scl.1.to_le_bytes());
    h[123] = 2; // mm
    h[254..256].copy_from_slice(&2i16.to_le_bytes()); // sform_code
                                                      // RAS: x axis → −R (left), y → −A (posterior), z → +S.
    let srow = [
        [-(spacing[0] as f32), 0.0, 0.0, 0.0],
        [0.0, -(spacing[1] as f32), 0.0, 0.0],
        [0.0, 0.0, spacing[2] as f32, 0.0],
    ];
    for (r, row) in srow.iter().enumerate() {
        for (c, v) in row.iter().enumerate() {
            let o = 280 + 16 * r + 4 * c;
            h[o..o + 4].copy_from_slice(&v.to_le_bytes());
        }
    }
    h[344..348].copy_from_slice(b"n+1\0");
    h.extend_from_slice(data);
    if is_gz(path) {
        use std::io::Write;
        let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
        e.write_all(&h)?;
        h = e.finish()?;
    }
    std::fs::write(path, h)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::volume::Voxels;

    fn tmp(name: &str) -> PathBuf {
        std::env::temp_dir().join(format!("shearwarp-nifti-{}-{name}", std::process::id()))
    }

    #[test]
    fn roundtrip_types_and_scaling() {
        let p = tmp("a.nii.gz");
        let data: Vec<u8> = [-5i16, 0, 7, 100, 200, 300]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        write(&p, [3, 2, 1], [1.0, 2.0, 3.0], 4, 16, (2.0, 10.0), &data).unwrap();
        let (v, m) = load(&p).unwrap();
        assert_eq!(v.dims, [3, 2, 1]);
        assert_eq!(v.spacing, [1.0, 2.0, 3.0]);
        assert_eq!(v.voxels, Voxels::U16(vec![0, 10, 24, 210, 410, 610]));
        assert_eq!((m.slope, m.intercept), (1.0, 0.0));
        let _ = std::fs::remove_file(&p);
    }

    #[test]
    fn errors_name_file_and_problem() {
        let p = tmp("bad.nii");
        write(&p, [2, 2, 2], [1.0; 3], 2, 8, (0.0, 0.0), &[1; 8]).unwrap();
        let good = std::fs::read(&p).unwrap();
        std::fs::write(&p, &good[..good.len() - 3]).unwrap();
        let e = load(&p).unwrap_err().to_string();
        assert!(e.contains("bad.nii") && e.contains("truncated"), "{e}");
        let mut b = good.clone();
        b[70] = 32; // complex64
        std::fs::write(&p, &b).unwrap();
        let e = load(&p).unwrap_err().to_string();
        assert!(e.contains("unsupported NIfTI datatype 32"), "{e}");
        let mut b = good.clone();
        b[344] = b'x';
        std::fs::write(&p, &b).unwrap();
        assert!(load(&p).unwrap_err().to_string().contains("magic"));
        let mut b = good.clone();
        b[40] = 4;
        b[48] = 5; // dim[4] = 5
        std::fs::write(&p, &b).unwrap();
        assert!(load(&p).unwrap_err().to_string().contains("only 3-D"));
        std::fs::write(&p, &good[..100]).unwrap();
        assert!(load(&p)
            .unwrap_err()
            .to_string()
            .contains("truncated NIfTI header"));
        let _ = std::fs::remove_file(&p);
    }
}
