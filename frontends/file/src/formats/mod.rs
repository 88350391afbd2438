//! Readers for medical and scientific volume formats: DICOM series, NIfTI-1, NRRD,
//! MetaImage and VolPack's `.den`. Each returns the loader's [`RawVolume`] (u8 or u16 voxels, x fastest) plus
//! a [`VolumeMeta`] saying how stored values map back to the file's values.
//!
//! # Value rule (any source type → u8/u16)
//!
//! Let `v = raw · slope + intercept` be the file's value (slope/intercept from DICOM
//! RescaleSlope/Intercept or NIfTI `scl_slope`/`scl_inter`; 1 and 0 elsewhere).
//!
//! 1. u8 data without scaling stays u8; every other source whose values `v` are all
//!    integers in `0..=65535` is stored unchanged as u16 (identity).
//! 2. Otherwise, if all `v` are integers spanning at most 65535, the minimum is
//!    subtracted: `stored = v − min` (e.g. CT in Hounsfield units).
//! 3. Otherwise (fractions, or a wider span) `min..max` is stretched linearly onto
//!    `0..65535`, rounding to nearest. NaN voxels count as the minimum.
//!
//! In every case `v ≈ stored · meta.slope + meta.intercept`.
//!
//! # Orientation
//!
//! Where a format gives index-axis directions in patient space, the axes are permuted
//! and flipped so that stored +x, +y, +z point as nearly as possible toward the
//! project's DICOM LPS convention (+x left, +y posterior, +z superior). Oblique data is
//! kept in its own slice frame (not resampled).

pub mod den;
pub mod dicom;
pub mod mhd;
pub mod nifti;
pub mod nrrd;

use crate::volume::{check_dims, LoadError, RawVolume, Voxels};
use std::io::Read;
use std::path::Path;

/// Where the stored values came from and how they map back to the file's values.
#[derive(Clone, Debug, PartialEq)]
pub struct VolumeMeta {
    /// `"raw+json"`, `"dicom"`, `"nifti"`, `"nrrd"`, `"metaimage"` or `"den"`.
    pub format: &'static str,
    /// Element type in the file, e.g. `"i16"`.
    pub source_type: String,
    /// File value = stored · `slope` + `intercept`.
    pub slope: f64,
    /// See `slope`.
    pub intercept: f64,
    /// DICOM Modality (e.g. `"CT"`, `"MR"`) when the file says.
    pub modality: Option<String>,
    /// Unit of the file's values when known (e.g. `"HU"`).
    pub units: Option<String>,
    /// What was done to the axes, e.g. `"x flipped"`; empty when nothing.
    pub orientation: String,
}

impl VolumeMeta {
    /// Metadata of a volume stored exactly as in the file.
    pub fn identity(format: &'static str, source_type: &str) -> VolumeMeta {
        VolumeMeta {
            format,
            source_type: source_type.to_string(),
            slope: 1.0,
            intercept: 0.0,
            modality: None,
            units: None,
            orientation: String::new(),
        }
    }

    /// The file's value for a stored value.
    pub fn physical(&self, stored: f64) -> f64 {
        stored * self.slope + self.intercept
    }
}

/// `LoadError::Format` for `path`.
pub(crate) fn bad(path: &Path, reason: impl Into<String>) -> LoadError {
    LoadError::Format {
        path: path.to_path_buf(),
        reason: reason.into(),
    }
}

/// Element types found in the formats.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum DataType {
    U8,
    I8,
    U16,
    I16,
    U32,
    I32,
    F32,
    F64,
}

impl DataType {
    pub(crate) fn bytes(self) -> usize {
        match self {
            DataType::U8 | DataType::I8 => 1,
            DataType::U16 | DataType::I16 => 2,
            DataType::U32 | DataType::I32 | DataType::F32 => 4,
            DataType::F64 => 8,
        }
    }

    pub(crate) fn name(self) -> &'static str {
        match self {
            DataType::U8 => "u8",
            DataType::I8 => "i8",
            DataType::U16 => "u16",
            DataType::I16 => "i16",
            DataType::U32 => "u32",
            DataType::I32 => "i32",
            DataType::F32 => "f32",
            DataType::F64 => "f64",
        }
    }

    /// Value of element `i` of `bytes`.
    #[inline]
    fn get(self, bytes: &[u8], i: usize, big: bool) -> f64 {
        let n = self.bytes();
        let s = &bytes[i * n..i * n + n];
        macro_rules! num {
            ($t:ty, $k:expr) => {{
                let mut a = [0u8; $k];
                a.copy_from_slice(s);
                if big {
                    <$t>::from_be_bytes(a) as f64
                } else {
                    <$t>::from_le_bytes(a) as f64
                }
            }};
        }
        match self {
            DataType::U8 => s[0] as f64,
            DataType::I8 => s[0] as i8 as f64,
            DataType::U16 => num!(u16, 2),
            DataType::I16 => num!(i16, 2),
            DataType::U32 => num!(u32, 4),
            DataType::I32 => num!(i32, 4),
            DataType::F32 => num!(f32, 4),
            DataType::F64 => num!(f64, 8),
        }
    }
}

/// Voxel data as found in a file, before the value rule.
pub(crate) struct Samples<'a> {
    pub bytes: &'a [u8],
    pub dtype: DataType,
    pub big_endian: bool,
    /// `(slope, intercept)` per z slice (one entry applies to all slices).
    pub rescale: Vec<(f64, f64)>,
    /// Optional per-element transform applied to the raw element before rescaling
    /// (DICOM BitsStored masking / sign extension).
    pub raw_map: Option<&'a dyn Fn(f64) -> f64>,
}

/// Applies the value rule (see the module docs) to `count = nx·ny·nz` samples.
pub(crate) fn to_voxels(
    path: &Path,
    dims: [usize; 3],
    s: &Samples<'_>,
) -> Result<(Voxels, f64, f64), LoadError> {
    let count = dims[0] * dims[1] * dims[2];
    let need = count as u64 * s.dtype.bytes() as u64;
    if (s.bytes.len() as u64) < need {
        return Err(bad(
            path,
            format!(
                "truncated pixel data: expected {need} bytes for {}×{}×{} {}, found {}",
                dims[0],
                dims[1],
                dims[2],
                s.dtype.name(),
                s.bytes.len()
            ),
        ));
    }
    let plain = s.rescale.iter().all(|&(a, b)| a == 1.0 && b == 0.0) && s.raw_map.is_none();
    if plain && s.dtype == DataType::U8 {
        return Ok((Voxels::U8(s.bytes[..count].to_vec()), 1.0, 0.0));
    }
    if plain && s.dtype == DataType::U16 && !s.big_endian {
        let v = s.bytes[..count * 2]
            .chunks_exact(2)
            .map(|c| u16::from_le_bytes([c[0], c[1]]))
            .collect();
        return Ok((Voxels::U16(v), 1.0, 0.0));
    }
    let slice = (dims[0] * dims[1]).max(1);
    for &(a, b) in &s.rescale {
        if !(a.is_finite() && b.is_finite()) || a == 0.0 {
            return Err(bad(
                path,
                format!("invalid rescale slope {a} / intercept {b}"),
            ));
        }
    }
    let value = |i: usize| -> f64 {
        let mut r = s.dtype.get(s.bytes, i, s.big_endian);
        if let Some(m) = s.raw_map {
            r = m(r);
        }
        let (a, b) = s.rescale[(i / slice).min(s.rescale.len() - 1)];
        r * a + b
    };
    let (mut lo, mut hi, mut integral) = (f64::INFINITY, f64::NEG_INFINITY, true);
    for i in 0..count {
        let v = value(i);
        if v.is_nan() {
            continue;
        }
        if v.is_infinite() {
            return Err(bad(path, "voxel data contains infinite values"));
        }
        lo = lo.min(v);
        hi = hi.max(v);
        integral &= v.fract() == 0.0;
    }
    if lo > hi {
        // Every voxel is NaN.
        return Ok((Voxels::U16(vec![0; count]), 1.0, 0.0));
    }
    let mut out = Vec::with_capacity(count);
    if integral && lo >= 0.0 && hi <= 65535.0 {
        let nan = lo as u16;
        out.extend((0..count).map(|i| {
            let v = value(i);
            if v.is_nan() {
                nan
            } else {
                v as u16
            }
        }));
        Ok((Voxels::U16(out), 1.0, 0.0))
    } else if integral && hi - lo <= 65535.0 {
        out.extend((0..count).map(|i| {
            let v = value(i);
            if v.is_nan() {
                0
            } else {
                (v - lo) as u16
            }
        }));
        Ok((Voxels::U16(out), 1.0, lo))
    } else {
        let scale = 65535.0 / (hi - lo);
        out.extend((0..count).map(|i| {
            let v = value(i);
            if v.is_nan() {
                0
            } else {
                ((v - lo) * scale).round().clamp(0.0, 65535.0) as u16
            }
        }));
        Ok((Voxels::U16(out), (hi - lo) / 65535.0, lo))
    }
}

/// Checks dims given as signed/unsigned numbers from a header against the loader limits.
pub(crate) fn dims_from(path: &Path, d: [i64; 3]) -> Result<[usize; 3], LoadError> {
    if d.iter().any(|&x| x < 0) {
        return Err(bad(
            path,
            format!("negative dimension in {}×{}×{}", d[0], d[1], d[2]),
        ));
    }
    check_dims(path, [d[0] as u64, d[1] as u64, d[2] as u64])
}

/// Checks spacing: finite and > 0.
pub(crate) fn check_spacing(path: &Path, s: [f64; 3]) -> Result<[f64; 3], LoadError> {
    if s.iter().all(|x| x.is_finite() && *x > 0.0) {
        Ok(s)
    } else {
        Err(LoadError::InvalidSpacing {
            path: path.to_path_buf(),
            spacing: s,
        })
    }
}

/// Reads at most `cap` bytes from `r`.
pub(crate) fn read_capped(path: &Path, r: impl Read, cap: u64) -> Result<Vec<u8>, LoadError> {
    let mut v = Vec::new();
    r.take(cap)
        .read_to_end(&mut v)
        .map_err(|e| read_error(path, e))?;
    Ok(v)
}

/// Reads and drops up to `n` bytes of `r` (fewer at its end), without holding them.
pub(crate) fn skip_bytes(path: &Path, r: &mut impl Read, n: u64) -> Result<(), LoadError> {
    std::io::copy(&mut r.take(n), &mut std::io::sink()).map_err(|e| read_error(path, e))?;
    Ok(())
}

/// A read error of `path`: a decoder's complaint names the data as corrupt.
fn read_error(path: &Path, e: std::io::Error) -> LoadError {
    if e.kind() == std::io::ErrorKind::InvalidInput
        || e.kind() == std::io::ErrorKind::InvalidData
        || e.kind() == std::io::ErrorKind::UnexpectedEof
    {
        bad(path, format!("corrupt compressed data: {e}"))
    } else {
        LoadError::Io {
            path: path.to_path_buf(),
            source: e,
        }
    }
}

/// Reads `need_bytes` of uncompressed voxel data from `reader` after skipping `skip`
/// bytes, or, with `skip == -1` (NRRD `byte skip: -1`, MetaImage `HeaderSize = -1`), the
/// last `need_bytes` bytes of the file at `data_path`.
pub(crate) fn read_raw_block(
    data_path: &Path,
    mut reader: impl Read,
    skip: i64,
    need_bytes: u64,
) -> Result<Vec<u8>, LoadError> {
    let io = |source| LoadError::Io {
        path: data_path.to_path_buf(),
        source,
    };
    if skip == -1 {
        drop(reader);
        let mut f = std::fs::File::open(data_path).map_err(io)?;
        let len = f.metadata().map_err(io)?.len();
        if len < need_bytes {
            return Err(bad(
                data_path,
                format!("truncated voxel data: expected {need_bytes} bytes, file has {len}"),
            ));
        }
        std::io::Seek::seek(&mut f, std::io::SeekFrom::Start(len - need_bytes)).map_err(io)?;
        read_capped(data_path, f, need_bytes)
    } else {
        skip_bytes(data_path, &mut reader, skip.max(0) as u64)?;
        read_capped(data_path, reader, need_bytes)
    }
}

/// Turns `data` (at least `need_bytes` long, else a "truncated" error) of type `dt` into
/// a volume; returns it with the slope and intercept back to file values.
#[allow(clippy::too_many_arguments)]
pub(crate) fn volume_from_bytes(
    data_path: &Path,
    mut data: Vec<u8>,
    need_bytes: u64,
    dims: [usize; 3],
    dt: DataType,
    big_endian: bool,
    spacing: [f64; 3],
    name: String,
) -> Result<(RawVolume, f64, f64), LoadError> {
    data.truncate(need_bytes as usize);
    if (data.len() as u64) < need_bytes {
        return Err(bad(
            data_path,
            format!(
                "truncated voxel data: expected {need_bytes} bytes for {}×{}×{} {}, found {}",
                dims[0],
                dims[1],
                dims[2],
                dt.name(),
                data.len()
            ),
        ));
    }
    let samples = Samples {
        bytes: &data,
        dtype: dt,
        big_endian,
        rescale: vec![(1.0, 0.0)],
        raw_map: None,
    };
    let (voxels, slope, intercept) = to_voxels(data_path, dims, &samples)?;
    Ok((
        RawVolume {
            name,
            dims,
            spacing,
            voxels,
        },
        slope,
        intercept,
    ))
}

/// Permutes/flips axes so that stored axes point toward LPS as nearly as possible.
///
/// `dirs[a]` is the direction (in LPS) of index axis `a`. Returns the reordered volume
/// and a description of what was done.
pub(crate) fn orient_lps(vol: RawVolume, dirs: [[f64; 3]; 3]) -> (RawVolume, String) {
    // For each output axis (L, P, S) pick the input axis with the largest component.
    let mut perm = [usize::MAX; 3]; // perm[out] = input axis
    let mut used = [false; 3];
    // Greedy on the largest absolute components first.
    let mut cand: Vec<(f64, usize, usize)> = Vec::new();
    for (a, d) in dirs.iter().enumerate() {
        for (o, c) in d.iter().enumerate() {
            cand.push((c.abs(), a, o));
        }
    }
    cand.sort_by(|x, y| y.0.total_cmp(&x.0));
    for (_, a, o) in cand {
        if perm[o] == usize::MAX && !used[a] {
            perm[o] = a;
            used[a] = true;
        }
    }
    let flip: [bool; 3] = std::array::from_fn(|o| dirs[perm[o]][o] < 0.0);
    if perm == [0, 1, 2] && flip == [false; 3] {
        return (vol, String::new());
    }
    let mut what = Vec::new();
    if perm != [0, 1, 2] {
        what.push(format!(
            "axes permuted (x,y,z) ← ({},{},{})",
            ["x", "y", "z"][perm[0]],
            ["x", "y", "z"][perm[1]],
            ["x", "y", "z"][perm[2]]
        ));
    }
    for (o, f) in flip.iter().enumerate() {
        if *f {
            what.push(format!("{} flipped", ["x", "y", "z"][o]));
        }
    }
    let d = vol.dims;
    let nd: [usize; 3] = std::array::from_fn(|o| d[perm[o]]);
    let ns: [f64; 3] = std::array::from_fn(|o| vol.spacing[perm[o]]);
    let stride = [1, d[0], d[0] * d[1]];
    // Source index for each output index.
    let src = |o: [usize; 3]| -> usize {
        let mut idx = [0usize; 3];
        for k in 0..3 {
            idx[perm[k]] = if flip[k] { nd[k] - 1 - o[k] } else { o[k] };
        }
        idx[0] * stride[0] + idx[1] * stride[1] + idx[2] * stride[2]
    };
    fn reorder<T: Copy>(v: &[T], nd: [usize; 3], src: impl Fn([usize; 3]) -> usize) -> Vec<T> {
        let mut out = Vec::with_capacity(v.len());
        for z in 0..nd[2] {
            for y in 0..nd[1] {
                for x in 0..nd[0] {
                    out.push(v[src([x, y, z])]);
                }
            }
        }
        out
    }
    let voxels = match &vol.voxels {
        Voxels::U8(v) => Voxels::U8(reorder(v, nd, src)),
        Voxels::U16(v) => Voxels::U16(reorder(v, nd, src)),
    };
    (
        RawVolume {
            name: vol.name,
            dims: nd,
            spacing: ns,
            voxels,
        },
        what.join(", "),
    )
}

/// Splits `text` on whitespace/commas and parses floats.
pub(crate) fn floats(text: &str) -> Option<Vec<f64>> {
    text.split(|c: char| c.is_whitespace() || c == ',' || c == '\\')
        .filter(|t| !t.is_empty())
        .map(|t| t.parse::<f64>().ok())
        .collect()
}

/// The file name without directory, for volume names.
pub(crate) fn stem_of(path: &Path, suffixes: &[&str]) -> String {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let lower = name.to_ascii_lowercase();
    for s in suffixes {
        if lower.ends_with(s) && lower.len() > s.len() {
            return name[..name.len() - s.len()].to_string();
        }
    }
    name
}

#[cfg(test)]
mod tests {
    use super::*;

    fn vol(dims: [usize; 3]) -> RawVolume {
        let n = dims[0] * dims[1] * dims[2];
        RawVolume {
            name: "t".into(),
            dims,
            spacing: [1.0, 2.0, 3.0],
            voxels: Voxels::U8((0..n as u32).map(|i| i as u8).collect()),
        }
    }

    #[test]
    fn orient_identity_and_flip() {
        let v = vol([2, 3, 4]);
        let (o, what) = orient_lps(v.clone(), [[1., 0., 0.], [0., 1., 0.], [0., 0., 1.]]);
        assert_eq!(o, v);
        assert!(what.is_empty());
        let (o, what) = orient_lps(v.clone(), [[-1., 0., 0.], [0., -1., 0.], [0., 0., 1.]]);
        assert_eq!(what, "x flipped, y flipped");
        let Voxels::U8(d) = &o.voxels else { panic!() };
        assert_eq!(d[0], 5); // (1, 2, 0) of the input
                             // Permutation: input x points superior, z points left.
        let (o, _) = orient_lps(v, [[0., 0., 1.], [0., 1., 0.], [1., 0., 0.]]);
        assert_eq!(o.dims, [4, 3, 2]);
        assert_eq!(o.spacing, [3.0, 2.0, 1.0]);
        let Voxels::U8(d) = &o.voxels else { panic!() };
        assert_eq!(d[1], 6); // output x=1 → input z=1
    }

    #[test]
    fn value_rule() {
        let p = Path::new("x");
        let s = |bytes: &[u8], dtype, rescale| Samples {
            bytes: &bytes.to_vec().leak()[..],
            dtype,
            big_endian: false,
            rescale,
            raw_map: None,
        };
        // i16 non-negative → identity.
        let b: Vec<u8> = [3i16, 1000].iter().flat_map(|v| v.to_le_bytes()).collect();
        let (v, a, c) = to_voxels(p, [2, 1, 1], &s(&b, DataType::I16, vec![(1.0, 0.0)])).unwrap();
        assert_eq!((v, a, c), (Voxels::U16(vec![3, 1000]), 1.0, 0.0));
        // CT-like: shift.
        let (v, a, c) =
            to_voxels(p, [2, 1, 1], &s(&b, DataType::I16, vec![(1.0, -1024.0)])).unwrap();
        assert_eq!((v, a, c), (Voxels::U16(vec![0, 997]), 1.0, -1021.0));
        // Floats: stretch.
        let b: Vec<u8> = [0.5f32, 1.5, 1.0]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let (v, a, c) = to_voxels(p, [3, 1, 1], &s(&b, DataType::F32, vec![(1.0, 0.0)])).unwrap();
        assert_eq!(v, Voxels::U16(vec![0, 65535, 32768]));
        assert!((a - 1.0 / 65535.0).abs() < 1e-12 && c == 0.5);
        // Truncated.
        let e = to_voxels(p, [4, 1, 1], &s(&b, DataType::F32, vec![(1.0, 0.0)])).unwrap_err();
        assert!(e.to_string().contains("truncated"), "{e}");
    }
}
