//! DICOM series: one slice per file, uncompressed (implicit or explicit VR little
//! endian), 8/16-bit monochrome.
//!
//! A directory loads the one series it holds (files that are not DICOM, and DICOM
//! files without pixel data such as `DICOMDIR`, are ignored); a single file loads every
//! file of its series in the same directory. Slices are sorted by ImagePositionPatient
//! along the slice normal (ImageOrientationPatient row × column); the z spacing is the
//! mean distance between neighbours; a position more than 5 % of that (+0.1 mm, for
//! rounded positions) off the uniform grid, or a gap 25 % off, is reported as uneven
//! spacing, as are duplicate positions, differing
//! orientations, sheared stacks (gantry tilt) and differing slice sizes. Values are
//! RescaleSlope·raw + RescaleIntercept (per slice), then the value rule of
//! [`crate::formats`]. Reading stops at the pixel data element, so trailing padding
//! is ignored.

use super::{bad, orient_lps, stem_of, to_voxels, DataType, Samples, VolumeMeta};
use crate::volume::{check_dims, LoadError, RawVolume};
use std::io::Read;
use std::path::{Path, PathBuf};

const IMPLICIT_LE: &str = "1.2.840.10008.1.2";
const EXPLICIT_LE: &str = "1.2.840.10008.1.2.1";
const UNDEFINED: u32 = 0xffff_ffff;
/// Largest DICOM file read (bytes).
const MAX_FILE: u64 = 1 << 30;

/// The header fields of one slice that matter here, and its pixel bytes.
#[derive(Debug, Default)]
struct Slice {
    path: PathBuf,
    transfer_syntax: String,
    series_uid: String,
    modality: Option<String>,
    rows: u32,
    cols: u32,
    samples: u32,
    frames: u32,
    bits_allocated: u32,
    bits_stored: u32,
    signed: bool,
    photometric: String,
    iop: Option<[f64; 6]>,
    ipp: Option<[f64; 3]>,
    pixel_spacing: Option<[f64; 2]>,
    imager_spacing: Option<[f64; 2]>,
    slice_thickness: Option<f64>,
    slope: Option<f64>,
    intercept: Option<f64>,
    pixels: Option<(usize, usize)>,
    bytes: Vec<u8>,
}

struct Cursor<'a> {
    path: &'a Path,
    b: &'a [u8],
    pos: usize,
}

impl Cursor<'_> {
    fn truncated(&self, what: &str) -> LoadError {
        bad(
            self.path,
            format!("truncated DICOM file ({what} at byte {})", self.pos),
        )
    }

    fn take(&mut self, n: usize, what: &str) -> Result<&[u8], LoadError> {
        if self.b.len() - self.pos < n {
            return Err(self.truncated(what));
        }
        let s = &self.b[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }

    fn u16(&mut self) -> Result<u16, LoadError> {
        let s = self.take(2, "element header")?;
        Ok(u16::from_le_bytes([s[0], s[1]]))
    }

    fn u32(&mut self) -> Result<u32, LoadError> {
        let s = self.take(4, "element header")?;
        Ok(u32::from_le_bytes([s[0], s[1], s[2], s[3]]))
    }

    /// Reads an element header: (tag, length).
    fn header(&mut self, explicit: bool) -> Result<(u32, u32), LoadError> {
        let group = self.u16()?;
        let elem = self.u16()?;
        let tag = (group as u32) << 16 | elem as u32;
        if group == 0xfffe || !explicit {
            return Ok((tag, self.u32()?));
        }
        let vr = self.take(2, "element header")?;
        let long = matches!(
            vr,
            b"OB"
                | b"OD"
                | b"OF"
                | b"OL"
                | b"OV"
                | b"OW"
                | b"SQ"
                | b"UC"
                | b"UN"
                | b"UR"
                | b"UT"
                | b"SV"
                | b"UV"
        );
        if long {
            self.take(2, "element header")?;
            Ok((tag, self.u32()?))
        } else {
            Ok((tag, self.u16()? as u32))
        }
    }

    /// Skips the items of an undefined-length element up to its sequence delimiter.
    fn skip_undefined(&mut self, explicit: bool, depth: u32) -> Result<(), LoadError> {
        if depth > 32 {
            return Err(bad(self.path, "DICOM sequences nested too deeply"));
        }
        loop {
            let (tag, len) = self.header(explicit)?;
            match tag {
                0xfffe_e0dd => return Ok(()),
                0xfffe_e000 if len != UNDEFINED => {
                    self.take(len as usize, "sequence item")?;
                }
                0xfffe_e000 => loop {
                    let (t, l) = self.header(explicit)?;
                    if t == 0xfffe_e00d {
                        break;
                    }
                    if l == UNDEFINED {
                        self.skip_undefined(explicit, depth + 1)?;
                    } else {
                        self.take(l as usize, "element value")?;
                    }
                },
                _ => {
                    return Err(bad(
                        self.path,
                        format!("malformed DICOM sequence at byte {}", self.pos),
                    ))
                }
            }
        }
    }
}

fn text(v: &[u8]) -> String {
    String::from_utf8_lossy(v)
        .trim_matches(|c: char| c == '\0' || c.is_whitespace())
        .to_string()
}

fn number(path: &Path, name: &str, v: &[u8]) -> Result<f64, LoadError> {
    let t = text(v);
    t.parse::<f64>()
        .ok()
        .filter(|x| x.is_finite())
        .ok_or_else(|| bad(path, format!("invalid {name} \"{t}\"")))
}

fn numbers<const N: usize>(path: &Path, name: &str, v: &[u8]) -> Result<[f64; N], LoadError> {
    let t = text(v);
    let parts: Vec<f64> = t
        .split('\\')
        .map(|p| p.trim().parse::<f64>().ok().filter(|x| x.is_finite()))
        .collect::<Option<_>>()
        .unwrap_or_default();
    parts
        .try_into()
        .map_err(|_| bad(path, format!("invalid {name} \"{t}\"")))
}

fn us(path: &Path, name: &str, v: &[u8]) -> Result<u32, LoadError> {
    match v {
        [a, b, ..] => Ok(u16::from_le_bytes([*a, *b]) as u32),
        _ => Err(bad(path, format!("invalid {name}"))),
    }
}

/// True if `path` starts like a DICOM Part 10 file.
fn has_magic(path: &Path) -> bool {
    let mut head = [0u8; 132];
    std::fs::File::open(path)
        .and_then(|mut f| f.read_exact(&mut head))
        .is_ok()
        && &head[128..] == b"DICM"
}

/// Parses one file. `Ok(None)` for a DICOM file without pixel data.
fn parse(path: &Path) -> Result<Option<Slice>, LoadError> {
    let io = |source| LoadError::Io {
        path: path.to_path_buf(),
        source,
    };
    let f = std::fs::File::open(path).map_err(io)?;
    let mut b = Vec::new();
    f.take(MAX_FILE).read_to_end(&mut b).map_err(io)?;
    if b.len() < 132 || &b[128..132] != b"DICM" {
        return Err(bad(
            path,
            "not a DICOM file (no \"DICM\" marker at byte 128)",
        ));
    }
    let mut c = Cursor {
        path,
        b: &b,
        pos: 132,
    };
    let mut s = Slice {
        path: path.to_path_buf(),
        samples: 1,
        frames: 1,
        photometric: "MONOCHROME2".into(),
        ..Slice::default()
    };
    let mut explicit = true;
    let mut checked_syntax = false;
    while c.pos < b.len() {
        let start = c.pos;
        let meta_group = c.b[c.pos..].starts_with(&[2, 0]);
        let (tag, len) = c.header(explicit || meta_group)?;
        if !meta_group && !checked_syntax {
            // End of the file meta group: the rest uses the transfer syntax.
            checked_syntax = true;
            match s.transfer_syntax.as_str() {
                EXPLICIT_LE => {}
                IMPLICIT_LE => {
                    explicit = false;
                    // This header was read as explicit; read it again.
                    c.pos = start;
                    continue;
                }
                "" => {
                    return Err(bad(
                        path,
                        "no transfer syntax in the DICOM file meta information",
                    ))
                }
                ts => {
                    return Err(bad(
                        path,
                        format!(
                            "unsupported transfer syntax {ts} ({}); only uncompressed little \
                             endian is read (convert with e.g. `gdcmconv --raw`)",
                            syntax_name(ts)
                        ),
                    ))
                }
            }
        }
        if tag == 0x7fe0_0010 {
            if len == UNDEFINED {
                return Err(bad(path, "encapsulated (compressed) pixel data"));
            }
            // A short value is reported as truncated pixel data once the needed size
            // is known.
            let avail = b.len() - c.pos;
            s.pixels = Some((c.pos, (len as usize).min(avail)));
            break;
        }
        if len == UNDEFINED {
            c.skip_undefined(explicit, 0)?;
            continue;
        }
        let v = c.take(len as usize, "element value")?;
        match tag {
            0x0002_0010 => s.transfer_syntax = text(v),
            0x0008_0060 => s.modality = Some(text(v)).filter(|m| !m.is_empty()),
            0x0018_0050 => s.slice_thickness = number(path, "SliceThickness", v).ok(),
            0x0018_1164 => s.imager_spacing = numbers(path, "ImagerPixelSpacing", v).ok(),
            0x0020_000e => s.series_uid = text(v),
            0x0020_0032 => s.ipp = Some(numbers(path, "ImagePositionPatient", v)?),
            0x0020_0037 => s.iop = Some(numbers(path, "ImageOrientationPatient", v)?),
            0x0028_0002 => s.samples = us(path, "SamplesPerPixel", v)?,
            0x0028_0004 => s.photometric = text(v),
            0x0028_0008 => {
                s.frames = text(v)
                    .parse()
                    .map_err(|_| bad(path, "invalid NumberOfFrames"))?
            }
            0x0028_0010 => s.rows = us(path, "Rows", v)?,
            0x0028_0011 => s.cols = us(path, "Columns", v)?,
            0x0028_0030 => s.pixel_spacing = Some(numbers(path, "PixelSpacing", v)?),
            0x0028_0100 => s.bits_allocated = us(path, "BitsAllocated", v)?,
            0x0028_0101 => s.bits_stored = us(path, "BitsStored", v)?,
            0x0028_0103 => s.signed = us(path, "PixelRepresentation", v)? == 1,
            0x0028_1052 => s.intercept = Some(number(path, "RescaleIntercept", v)?),
            0x0028_1053 => s.slope = Some(number(path, "RescaleSlope", v)?),
            _ => {}
        }
    }
    let Some((off, len)) = s.pixels else {
        return Ok(None);
    };
    b.truncate(off + len);
    b.drain(..off);
    s.bytes = b;
    Ok(Some(s))
}

fn syntax_name(ts: &str) -> &'static str {
    match ts {
        "1.2.840.10008.1.2.2" => "explicit VR big endian",
        "1.2.840.10008.1.2.1.99" => "deflated explicit VR little endian",
        "1.2.840.10008.1.2.5" => "RLE lossless",
        t if t.starts_with("1.2.840.10008.1.2.4.5")
            || t.starts_with("1.2.840.10008.1.2.4.6")
            || t.starts_with("1.2.840.10008.1.2.4.7") =>
        {
            "JPEG"
        }
        t if t.starts_with("1.2.840.10008.1.2.4.8") => "JPEG-LS",
        t if t.starts_with("1.2.840.10008.1.2.4.9") => "JPEG 2000",
        t if t.starts_with("1.2.840.10008.1.2.4.10") => "MPEG",
        _ => "unknown or compressed",
    }
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn file_name(p: &Path) -> String {
    p.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// Loads the series in directory `path`, or the series of DICOM file `path`.
pub fn load(path: &Path) -> Result<(RawVolume, VolumeMeta), LoadError> {
    let io = |p: &Path, source| LoadError::Io {
        path: p.to_path_buf(),
        source,
    };
    let (dir, only) = if path.is_dir() {
        (path.to_path_buf(), None)
    } else {
        let first =
            parse(path)?.ok_or_else(|| bad(path, "DICOM file has no pixel data (not an image)"))?;
        let dir = match path.parent() {
            Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
            _ => PathBuf::from("."),
        };
        (dir, Some(first))
    };
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .map_err(|e| io(&dir, e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file() && !file_name(p).starts_with('.'))
        .collect();
    files.sort();
    let mut slices = Vec::new();
    for f in files {
        if let Some(first) = &only {
            if f == first.path || !has_magic(&f) {
                continue;
            }
        } else if !has_magic(&f) {
            continue;
        }
        if let Some(s) = parse(&f)? {
            slices.push(s);
        }
    }
    let where_ = path;
    if let Some(first) = only {
        let uid = first.series_uid.clone();
        slices.retain(|s| s.series_uid == uid);
        slices.insert(0, first);
    } else {
        let mut uids: Vec<&str> = slices.iter().map(|s| s.series_uid.as_str()).collect();
        uids.sort_unstable();
        uids.dedup();
        if uids.len() > 1 {
            return Err(bad(
                where_,
                format!(
                    "directory holds {} DICOM series; pass one file of the wanted series",
                    uids.len()
                ),
            ));
        }
    }
    if slices.is_empty() {
        return Err(bad(where_, "no DICOM image files in the directory"));
    }
    // The series is named after its directory.
    let name = std::fs::canonicalize(&dir)
        .ok()
        .map(|d| file_name(&d))
        .filter(|n| !n.is_empty())
        .unwrap_or_else(|| stem_of(path, &[".dcm", ".dicom", ".ima"]));
    assemble(where_, name, slices)
}

fn assemble(
    where_: &Path,
    name: String,
    slices: Vec<Slice>,
) -> Result<(RawVolume, VolumeMeta), LoadError> {
    let f = &slices[0];
    let p0 = f.path.clone();
    if f.samples != 1 || !f.photometric.starts_with("MONOCHROME") {
        return Err(bad(
            &p0,
            format!(
                "unsupported colour image ({} samples per pixel, {})",
                f.samples, f.photometric
            ),
        ));
    }
    if f.frames != 1 {
        return Err(bad(
            &p0,
            format!("multi-frame DICOM ({} frames) is not supported", f.frames),
        ));
    }
    let dtype = match (f.bits_allocated, f.signed) {
        (8, false) => DataType::U8,
        (8, true) => DataType::I8,
        (16, false) => DataType::U16,
        (16, true) => DataType::I16,
        (32, false) => DataType::U32,
        (32, true) => DataType::I32,
        (b, _) => return Err(bad(&p0, format!("unsupported BitsAllocated {b}"))),
    };
    let bits_stored = if f.bits_stored == 0 {
        f.bits_allocated
    } else {
        f.bits_stored
    };
    if bits_stored > f.bits_allocated {
        return Err(bad(
            &p0,
            format!(
                "BitsStored {bits_stored} exceeds BitsAllocated {}",
                f.bits_allocated
            ),
        ));
    }
    for s in &slices[1..] {
        if (s.rows, s.cols) != (f.rows, f.cols) {
            return Err(bad(
                &s.path,
                format!(
                    "inconsistent slice sizes: {}×{} here, {}×{} in {}",
                    s.cols,
                    s.rows,
                    f.cols,
                    f.rows,
                    file_name(&p0)
                ),
            ));
        }
        if (s.bits_allocated, s.signed, s.samples, s.frames)
            != (f.bits_allocated, f.signed, f.samples, f.frames)
        {
            return Err(bad(
                &s.path,
                format!(
                    "inconsistent pixel format: differs from {} (bits, sign, samples or frames)",
                    file_name(&p0)
                ),
            ));
        }
    }
    let nz = slices.len();
    let dims = check_dims(where_, [f.cols as u64, f.rows as u64, nz as u64])?;
    let ps = f
        .pixel_spacing
        .or(f.imager_spacing)
        .ok_or_else(|| bad(&p0, "no PixelSpacing"))?;

    // Geometry: orientation, order, spacing.
    let (row, col) = match f.iop {
        Some(o) => ([o[0], o[1], o[2]], [o[3], o[4], o[5]]),
        None if nz == 1 => ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0]),
        None => return Err(bad(&p0, "no ImageOrientationPatient")),
    };
    let normal = cross(row, col);
    let nlen = dot(normal, normal).sqrt();
    if !(0.9..1.1).contains(&nlen) {
        return Err(bad(&p0, "invalid ImageOrientationPatient"));
    }
    let normal = normal.map(|x| x / nlen);
    let mut order: Vec<usize> = (0..nz).collect();
    let mut dz = f.slice_thickness.filter(|t| *t > 0.0).unwrap_or(ps[0]);
    if nz > 1 {
        for s in &slices {
            let Some(o) = s.iop else {
                return Err(bad(&s.path, "no ImageOrientationPatient"));
            };
            if s.ipp.is_none() {
                return Err(bad(&s.path, "no ImagePositionPatient"));
            }
            if o.iter()
                .zip([row, col].concat())
                .any(|(a, b)| (a - b).abs() > 1e-3)
            {
                return Err(bad(
                    &s.path,
                    format!("slice orientation differs from {}", file_name(&p0)),
                ));
            }
        }
        let pos = |s: &Slice| dot(normal, s.ipp.unwrap_or_default());
        order.sort_by(|&a, &b| pos(&slices[a]).total_cmp(&pos(&slices[b])));
        let d: Vec<f64> = order.iter().map(|&i| pos(&slices[i])).collect();
        let gaps: Vec<f64> = d.windows(2).map(|w| w[1] - w[0]).collect();
        for (i, g) in gaps.iter().enumerate() {
            if *g < 1e-3 {
                return Err(bad(
                    where_,
                    format!(
                        "two slices at the same position: {} and {}",
                        file_name(&slices[order[i]].path),
                        file_name(&slices[order[i + 1]].path)
                    ),
                ));
            }
        }
        let lo = gaps.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = gaps.iter().copied().fold(0.0, f64::max);
        dz = (d[nz - 1] - d[0]) / (nz - 1) as f64;
        // Positions are often rounded (to 0.1 mm, say): accept deviations from the
        // uniform grid of up to 5 % of the spacing + 0.1 mm, and gaps within ±25 %.
        let dev = d
            .iter()
            .enumerate()
            .map(|(i, x)| (x - d[0] - i as f64 * dz).abs())
            .fold(0.0, f64::max);
        if dev > 0.05 * dz + 0.1 || hi > 1.25 * dz || lo < 0.75 * dz {
            let at = gaps
                .iter()
                .enumerate()
                .max_by(|a, b| (a.1 - dz).abs().total_cmp(&(b.1 - dz).abs()))
                .map_or(0, |(i, _)| i);
            return Err(bad(
                where_,
                format!(
                    "uneven slice spacing: gaps from {lo:.3} to {hi:.3} mm (most off between \
                     {} and {}); missing slices?",
                    file_name(&slices[order[at]].path),
                    file_name(&slices[order[at + 1]].path)
                ),
            ));
        }
        // Shear: in-plane drift of the positions across the stack (gantry tilt).
        let a = slices[order[0]].ipp.unwrap_or_default();
        let b = slices[order[nz - 1]].ipp.unwrap_or_default();
        let delta = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
        let along = dot(delta, normal);
        let drift = [
            delta[0] - along * normal[0],
            delta[1] - along * normal[1],
            delta[2] - along * normal[2],
        ];
        let drift_len = dot(drift, drift).sqrt();
        if drift_len > 0.5 * ps[0].min(ps[1]) {
            return Err(bad(
                where_,
                format!(
                    "slices are sheared (gantry tilt of {:.1}°); resample the series first",
                    drift_len.atan2(along).to_degrees()
                ),
            ));
        }
    }
    let spacing = super::check_spacing(&p0, [ps[1], ps[0], dz])?;

    // Pixels.
    let slice_bytes = dims[0] * dims[1] * dtype.bytes();
    let mut bytes = Vec::with_capacity(slice_bytes * nz);
    let mut rescale = Vec::with_capacity(nz);
    for s in order.iter().map(|&i| &slices[i]) {
        if s.bytes.len() < slice_bytes {
            return Err(bad(
                &s.path,
                format!(
                    "truncated pixel data: expected {slice_bytes} bytes, found {}",
                    s.bytes.len()
                ),
            ));
        }
        bytes.extend_from_slice(&s.bytes[..slice_bytes]);
        rescale.push((s.slope.unwrap_or(1.0), s.intercept.unwrap_or(0.0)));
    }
    let bits = bits_stored;
    let full = bits == f.bits_allocated;
    let signed = f.signed;
    let mono1 = f.photometric == "MONOCHROME1";
    let map = move |r: f64| -> f64 {
        let mut v = r;
        if !full {
            let m = (1u64 << bits) as f64;
            v = v.rem_euclid(m);
            if signed && v >= m / 2.0 {
                v -= m;
            }
        }
        if mono1 {
            v = if signed {
                -v - 1.0
            } else {
                (1u64 << bits) as f64 - 1.0 - v
            };
        }
        v
    };
    let samples = Samples {
        bytes: &bytes,
        dtype,
        big_endian: false,
        rescale,
        raw_map: (!full || mono1).then_some(&map as &dyn Fn(f64) -> f64),
    };
    let (voxels, slope, intercept) = to_voxels(&p0, dims, &samples)?;
    let vol = RawVolume {
        name,
        dims,
        spacing,
        voxels,
    };
    let (vol, orientation) = orient_lps(vol, [row, col, normal]);
    let modality = f.modality.clone();
    let units = (modality.as_deref() == Some("CT")).then(|| "HU".to_string());
    Ok((
        vol,
        VolumeMeta {
            format: "dicom",
            source_type: dtype.name().to_string(),
            slope,
            intercept,
            modality,
            units,
            orientation,
        },
    ))
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// Writes a minimal explicit-VR-little-endian MR slice.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn write_slice(
        path: &Path,
        ts: &str,
        series: &str,
        cols: u16,
        rows: u16,
        ipp: [f64; 3],
        rescale: (f64, f64),
        pixels: &[i16],
    ) {
        fn el(out: &mut Vec<u8>, g: u16, e: u16, vr: &[u8; 2], v: &[u8]) {
            let mut v = v.to_vec();
            if v.len() % 2 == 1 {
                v.push(if vr == b"UI" { 0 } else { b' ' });
            }
            out.extend_from_slice(&g.to_le_bytes());
            out.extend_from_slice(&e.to_le_bytes());
            out.extend_from_slice(vr);
            if matches!(vr, b"OB" | b"OW" | b"SQ") {
                out.extend_from_slice(&[0, 0]);
                out.extend_from_slice(&(v.len() as u32).to_le_bytes());
            } else {
                out.extend_from_slice(&(v.len() as u16).to_le_bytes());
            }
            out.extend_from_slice(&v);
        }
        let mut b = vec![0u8; 128];
        b.extend_from_slice(b"DICM");
        el(&mut b, 2, 0x10, b"UI", ts.as_bytes());
        el(&mut b, 8, 0x60, b"CS", b"MR");
        // A sequence of undefined length with one undefined-length item, to be skipped.
        b.extend_from_slice(&[8, 0, 0x40, 0x11, b'S', b'Q', 0, 0, 0xff, 0xff, 0xff, 0xff]);
        b.extend_from_slice(&[0xfe, 0xff, 0, 0xe0, 0xff, 0xff, 0xff, 0xff]);
        el(&mut b, 8, 0x1150, b"UI", b"1.2.3");
        b.extend_from_slice(&[0xfe, 0xff, 0x0d, 0xe0, 0, 0, 0, 0]);
        b.extend_from_slice(&[0xfe, 0xff, 0xdd, 0xe0, 0, 0, 0, 0]);
        el(&mut b, 0x20, 0x0e, b"UI", series.as_bytes());
        let ipp_s = format!("{}\\{}\\{}", ipp[0], ipp[1], ipp[2]);
        el(&mut b, 0x20, 0x32, b"DS", ipp_s.as_bytes());
        el(&mut b, 0x20, 0x37, b"DS", b"1\\0\\0\\0\\1\\0");
        el(&mut b, 0x28, 0x02, b"US", &1u16.to_le_bytes());
        el(&mut b, 0x28, 0x04, b"CS", b"MONOCHROME2");
        el(&mut b, 0x28, 0x10, b"US", &rows.to_le_bytes());
        el(&mut b, 0x28, 0x11, b"US", &cols.to_le_bytes());
        el(&mut b, 0x28, 0x30, b"DS", b"0.5\\0.75");
        el(&mut b, 0x28, 0x100, b"US", &16u16.to_le_bytes());
        el(&mut b, 0x28, 0x101, b"US", &16u16.to_le_bytes());
        el(&mut b, 0x28, 0x103, b"US", &1u16.to_le_bytes());
        el(
            &mut b,
            0x28,
            0x1052,
            b"DS",
            rescale.1.to_string().as_bytes(),
        );
        el(
            &mut b,
            0x28,
            0x1053,
            b"DS",
            rescale.0.to_string().as_bytes(),
        );
        let px: Vec<u8> = pixels.iter().flat_map(|v| v.to_le_bytes()).collect();
        el(&mut b, 0x7fe0, 0x10, b"OW", &px);
        b.extend_from_slice(&[0; 100]); // trailing padding
        std::fs::write(path, b).unwrap();
    }

    fn tmp(tag: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!(
            "shearwarp-dicom-{tag}-{}-{:?}",
            std::process::id(),
            std::thread::current().id()
        ));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    fn series(dir: &Path, zs: &[f64], rescale: (f64, f64)) {
        for (i, z) in zs.iter().enumerate() {
            let px: Vec<i16> = (0..6).map(|k| (k + 10 * i) as i16 - 3).collect();
            write_slice(
                &dir.join(format!("s{i}.dcm")),
                EXPLICIT_LE,
                "1.9",
                3,
                2,
                [0.0, 0.0, *z],
                rescale,
                &px,
            );
        }
    }

    #[test]
    fn sorted_by_position_with_rescale() {
        let d = tmp("ok");
        // Files named out of order: s0 is at z=4, s1 at z=0, s2 at z=2.
        series(&d, &[4.0, 0.0, 2.0], (2.0, -1000.0));
        std::fs::write(d.join("README.txt"), "not dicom").unwrap();
        let (v, m) = load(&d).unwrap();
        assert_eq!(v.dims, [3, 2, 3]);
        assert_eq!(v.spacing, [0.75, 0.5, 2.0]);
        // Values: 2·raw − 1000; raw of slice i is k + 10i − 3. Sorted order: s1, s2, s0.
        let crate::volume::Voxels::U16(d16) = &v.voxels else {
            panic!()
        };
        let phys: Vec<f64> = d16.iter().map(|&s| m.physical(s as f64)).collect();
        assert_eq!(phys[0], 2.0 * (10.0 - 3.0) - 1000.0);
        assert_eq!(phys[6], 2.0 * (20.0 - 3.0) - 1000.0);
        assert_eq!(phys[12], 2.0 * (0.0 - 3.0) - 1000.0);
        // One file loads its series.
        let (v2, _) = load(&d.join("s2.dcm")).unwrap();
        assert_eq!(v2, v);
        let _ = std::fs::remove_dir_all(&d);
    }

    #[test]
    fn errors() {
        let d = tmp("uneven");
        series(&d, &[0.0, 2.0, 5.0], (1.0, 0.0));
        let e = load(&d).unwrap_err().to_string();
        assert!(e.contains("uneven slice spacing"), "{e}");
        let _ = std::fs::remove_dir_all(&d);

        let d = tmp("dup");
        series(&d, &[0.0, 2.0, 2.0], (1.0, 0.0));
        let e = load(&d).unwrap_err().to_string();
        assert!(e.contains("same position"), "{e}");
        let _ = std::fs::remove_dir_all(&d);

        let d = tmp("size");
        series(&d, &[0.0, 2.0], (1.0, 0.0));
        write_slice(
            &d.join("s9.dcm"),
            EXPLICIT_LE,
            "1.9",
            2,
            2,
            [0.0, 0.0, 4.0],
            (1.0, 0.0),
            &[0; 4],
        );
        let e = load(&d).unwrap_err().to_string();
        assert!(
            e.contains("inconsistent slice sizes") && e.contains("s9.dcm"),
            "{e}"
        );
        let _ = std::fs::remove_dir_all(&d);

        let d = tmp("ts");
        write_slice(
            &d.join("j.dcm"),
            "1.2.840.10008.1.2.4.90",
            "1",
            3,
            2,
            [0.0; 3],
            (1.0, 0.0),
            &[0; 6],
        );
        let e = load(&d).unwrap_err().to_string();
        assert!(
            e.contains("j.dcm")
                && e.contains("unsupported transfer syntax")
                && e.contains("JPEG 2000"),
            "{e}"
        );
        let _ = std::fs::remove_dir_all(&d);

        let d = tmp("trunc");
        write_slice(
            &d.join("t.dcm"),
            EXPLICIT_LE,
            "1",
            3,
            2,
            [0.0; 3],
            (1.0, 0.0),
            &[0; 6],
        );
        let full = std::fs::read(d.join("t.dcm")).unwrap();
        std::fs::write(d.join("t.dcm"), &full[..full.len() - 104]).unwrap();
        let e = load(&d).unwrap_err().to_string();
        assert!(e.contains("t.dcm") && e.contains("truncated"), "{e}");
        // Cut inside the header.
        std::fs::write(d.join("t.dcm"), &full[..200]).unwrap();
        let e = load(&d).unwrap_err().to_string();
        assert!(e.contains("t.dcm") && e.contains("truncated"), "{e}");
        let _ = std::fs::remove_dir_all(&d);

        let d = tmp("empty");
        let e = load(&d).unwrap_err().to_string();
        assert!(e.contains("no DICOM image files"), "{e}");
        let _ = std::fs::remove_dir_all(&d);
    }

    #[test]
    fn mangled_files_never_panic() {
        let d = tmp("fuzz");
        let f = d.join("f.dcm");
        write_slice(&f, EXPLICIT_LE, "1", 3, 2, [0.0; 3], (1.0, 0.0), &[7; 6]);
        let good = std::fs::read(&f).unwrap();
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        for _ in 0..500 {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            let mut b = good.clone();
            let i = 132 + (state as usize) % (b.len() - 132);
            b[i] = (state >> 32) as u8;
            if state.is_multiple_of(3) {
                b.truncate(132 + (state as usize >> 8) % (b.len() - 132));
            }
            std::fs::write(&f, &b).unwrap();
            let _ = load(&f).map(|_| ()).map_err(|e| e.to_string());
        }
        let _ = std::fs::remove_dir_all(&d);
    }
}
