//! Loading raw volumes described by JSON sidecars.
//!
//! The format is the one of the project's shared data set (see `fixtures/README.md`):
//! headerless voxels, x fastest, then y, then z, little-endian, optionally gzip
//! compressed, plus a sidecar `NAME.json` holding at least
//!
//! ```json
//! {
//!   "name": "mr_head_colin27_64",
//!   "dims_xyz": [64, 64, 64],
//!   "spacing_mm_xyz": [2.828125, 3.390625, 2.828125],
//!   "files": {
//!     "u8": { "file": "mr_head_colin27_64.u8.raw", "voxel_type": "u8",
//!             "bytes_uncompressed": 262144 }
//!   }
//! }
//! ```
//!
//! [`load_volume`] accepts either the sidecar or one of the data files. All input is
//! validated; nothing in here panics on malformed files, and decompression is capped at
//! the size the sidecar announces (plus one byte to detect oversized data), so a gzip
//! bomb cannot exhaust memory.

use std::fmt;
use std::fs::File;
use std::io::{self, BufRead, BufReader, Read};
use std::path::{Path, PathBuf};

use flate2::bufread::MultiGzDecoder;
use serde_json::{Map, Value};

/// Largest accepted extent along any axis (the core's limit).
pub const MAX_DIM: usize = shearwarp_core::classify::MAX_DIM;
/// Largest accepted total number of voxels (2^30): the core's limit
/// ([`shearwarp_core::classify::MAX_VOXELS`]), so a volume the renderer would refuse is
/// refused before its data is read.
pub const MAX_VOXELS: u64 = shearwarp_core::classify::MAX_VOXELS as u64;
/// Largest accepted sidecar file (bytes).
const MAX_SIDECAR_BYTES: u64 = 1 << 20;
/// Gzip magic bytes.
const GZIP_MAGIC: [u8; 2] = [0x1f, 0x8b];

/// Storage type of one voxel.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum VoxelType {
    U8,
    U16,
}

impl VoxelType {
    /// Bytes per voxel on disk.
    pub fn bytes(self) -> usize {
        match self {
            VoxelType::U8 => 1,
            VoxelType::U16 => 2,
        }
    }

    /// The name used in sidecars and file suffixes (`"u8"`, `"u16"`).
    pub fn as_str(self) -> &'static str {
        match self {
            VoxelType::U8 => "u8",
            VoxelType::U16 => "u16",
        }
    }

    /// Parses `"u8"` / `"u16"` (ASCII case-insensitive, surrounding whitespace ignored).
    pub fn parse(s: &str) -> Option<VoxelType> {
        let s = s.trim();
        if s.eq_ignore_ascii_case("u8") {
            Some(VoxelType::U8)
        } else if s.eq_ignore_ascii_case("u16") {
            Some(VoxelType::U16)
        } else {
            None
        }
    }
}

impl fmt::Display for VoxelType {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Voxel values, x fastest, then y, then z.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Voxels {
    U8(Vec<u8>),
    U16(Vec<u16>),
}

impl Voxels {
    pub fn voxel_type(&self) -> VoxelType {
        match self {
            Voxels::U8(_) => VoxelType::U8,
            Voxels::U16(_) => VoxelType::U16,
        }
    }

    /// Number of voxels.
    pub fn len(&self) -> usize {
        match self {
            Voxels::U8(v) => v.len(),
            Voxels::U16(v) => v.len(),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// A loaded volume: `voxels` holds `dims[0] * dims[1] * dims[2]` values.
#[derive(Clone, Debug, PartialEq)]
pub struct RawVolume {
    /// The sidecar's `"name"`, or the sidecar's file stem if it has none.
    pub name: String,
    /// Extent in voxels along x, y, z.
    pub dims: [usize; 3],
    /// Voxel spacing in mm along x, y, z (finite and > 0).
    pub spacing: [f64; 3],
    pub voxels: Voxels,
}

impl RawVolume {
    pub fn voxel_type(&self) -> VoxelType {
        self.voxels.voxel_type()
    }

    /// `dims[0] * dims[1] * dims[2]`.
    pub fn voxel_count(&self) -> usize {
        self.voxels.len()
    }
}

/// Which data file to pick when a sidecar lists several.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Prefer {
    /// The u8 file if it exists, else the u16 one.
    #[default]
    U8,
    /// The u16 file if it exists, else the u8 one.
    U16,
}

/// Everything that can go wrong while loading a volume.
#[derive(Debug)]
#[non_exhaustive]
pub enum LoadError {
    /// A file could not be opened or read (including "not found").
    Io { path: PathBuf, source: io::Error },
    /// A data file was given, but the sidecar derived from its name does not exist.
    SidecarNotFound { data: PathBuf, sidecar: PathBuf },
    /// The sidecar is not valid JSON (or not a JSON object, or far too large).
    InvalidJson { path: PathBuf, message: String },
    /// A required sidecar field is absent.
    MissingField { path: PathBuf, field: String },
    /// A sidecar field has the wrong type or an inconsistent value.
    InvalidField {
        path: PathBuf,
        field: String,
        reason: String,
    },
    /// `dims_xyz` contains a zero, an extent above [`MAX_DIM`], or more than
    /// [`MAX_VOXELS`] voxels in total.
    AbsurdDims {
        path: PathBuf,
        dims: [u64; 3],
        reason: String,
    },
    /// `spacing_mm_xyz` contains a value that is not finite or not > 0.
    InvalidSpacing { path: PathBuf, spacing: [f64; 3] },
    /// The (decompressed) data does not have the size implied by dims and voxel type.
    /// `exceeded` is set when a capped (gzip) read stopped at `found` = `expected + 1`
    /// bytes, so the real size is unknown.
    WrongSize {
        path: PathBuf,
        dims: [usize; 3],
        voxel_type: VoxelType,
        expected: u64,
        found: u64,
        exceeded: bool,
    },
    /// The gzip stream is malformed (bad header, corrupt deflate data, bad CRC,
    /// truncated).
    CorruptGzip { path: PathBuf, source: io::Error },
    /// The voxel type is not `u8`/`u16`, or could not be determined at all (`None`).
    UnknownVoxelType {
        path: PathBuf,
        voxel_type: Option<String>,
    },
    /// A DICOM/NIfTI/NRRD/MetaImage file is malformed or uses something unsupported
    /// (unknown format, unsupported transfer syntax, truncated pixel data, inconsistent
    /// slices, ...).
    Format { path: PathBuf, reason: String },
}

impl LoadError {
    /// The file the error is about.
    pub fn path(&self) -> &Path {
        match self {
            LoadError::Io { path, .. }
            | LoadError::InvalidJson { path, .. }
            | LoadError::MissingField { path, .. }
            | LoadError::InvalidField { path, .. }
            | LoadError::AbsurdDims { path, .. }
            | LoadError::InvalidSpacing { path, .. }
            | LoadError::WrongSize { path, .. }
            | LoadError::CorruptGzip { path, .. }
            | LoadError::UnknownVoxelType { path, .. }
            | LoadError::Format { path, .. } => path,
            LoadError::SidecarNotFound { data, .. } => data,
        }
    }
}

impl fmt::Display for LoadError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            LoadError::Io { path, source } => {
                if source.kind() == io::ErrorKind::NotFound {
                    write!(f, "{}: file not found", path.display())
                } else {
                    write!(f, "{}: cannot read: {source}", path.display())
                }
            }
            LoadError::SidecarNotFound { data, sidecar } => {
                let name = file_name_string(data);
                let raw_like = voxel_type_from_name(&name).is_some()
                    || strip_suffix_ci(data_file_base(&name), ".raw").is_some()
                    || name.to_ascii_lowercase().contains(".raw");
                if raw_like {
                    write!(
                        f,
                        "{}: no JSON sidecar found (looked for {})",
                        data.display(),
                        sidecar.display()
                    )
                } else {
                    write!(
                        f,
                        "{}: unknown volume format (not DICOM, NIfTI, NRRD, MetaImage or .den, and no \
                         JSON sidecar {} for raw data)",
                        data.display(),
                        sidecar.display()
                    )
                }
            }
            LoadError::InvalidJson { path, message } => {
                write!(f, "{}: invalid JSON sidecar: {message}", path.display())
            }
            LoadError::MissingField { path, field } => {
                write!(f, "{}: missing field \"{field}\"", path.display())
            }
            LoadError::InvalidField {
                path,
                field,
                reason,
            } => write!(f, "{}: invalid field \"{field}\": {reason}", path.display()),
            LoadError::AbsurdDims { path, dims, reason } => write!(
                f,
                "{}: unusable dims_xyz {}×{}×{}: {reason}",
                path.display(),
                dims[0],
                dims[1],
                dims[2]
            ),
            LoadError::InvalidSpacing { path, spacing } => write!(
                f,
                "{}: invalid spacing_mm_xyz [{}, {}, {}]: every spacing must be finite and > 0",
                path.display(),
                spacing[0],
                spacing[1],
                spacing[2]
            ),
            LoadError::WrongSize {
                path,
                dims,
                voxel_type,
                expected,
                found,
                exceeded,
            } => {
                write!(
                    f,
                    "{}: wrong data size: expected {expected} bytes for {}×{}×{} {voxel_type}, ",
                    path.display(),
                    dims[0],
                    dims[1],
                    dims[2]
                )?;
                if *exceeded {
                    write!(f, "found more than {expected}")
                } else {
                    write!(f, "found {found}")
                }
            }
            LoadError::CorruptGzip { path, source } => {
                write!(f, "{}: corrupt gzip stream: {source}", path.display())
            }
            LoadError::Format { path, reason } => write!(f, "{}: {reason}", path.display()),
            LoadError::UnknownVoxelType { path, voxel_type } => match voxel_type {
                Some(t) => write!(
                    f,
                    "{}: unknown voxel type \"{t}\" (supported: u8, u16)",
                    path.display()
                ),
                None => write!(
                    f,
                    "{}: cannot determine the voxel type (file not listed in the sidecar and \
                     its name has no .u8/.u16 suffix)",
                    path.display()
                ),
            },
        }
    }
}

impl std::error::Error for LoadError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            LoadError::Io { source, .. } | LoadError::CorruptGzip { source, .. } => Some(source),
            _ => None,
        }
    }
}

/// Loads a volume, preferring 8-bit data; see [`load_volume_with`].
pub fn load_volume(path: &Path) -> Result<RawVolume, LoadError> {
    load_volume_with(path, Prefer::U8)
}

/// Loads a volume from a sidecar (`NAME.json`) or from a data file (`X.u8.raw`,
/// `X.u16.raw.gz`, ...).
///
/// For a sidecar, the entry of `"files"` matching `prefer` is used if its file exists,
/// otherwise the other one. For a data file, the sidecar is found with
/// [`sidecar_path_for`] and the voxel type comes from the `"files"` entry naming that
/// file, or from the `.u8`/`.u16` suffix if none does. Data is gzip-decompressed if the
/// name ends in `.gz` or (when the size does not match raw data) the file starts with
/// the gzip magic bytes.
pub fn load_volume_with(path: &Path, prefer: Prefer) -> Result<RawVolume, LoadError> {
    load_volume_meta(path, prefer).map(|(v, _)| v)
}

/// The format of a volume path, decided by kind (directory → DICOM series), extension
/// and magic bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// Raw voxels with a JSON sidecar (the shared data set's format).
    RawJson,
    /// A directory of DICOM files, or one DICOM file (its series is loaded).
    Dicom,
    /// NIfTI-1 `.nii`, `.nii.gz`, `.hdr`/`.img`.
    Nifti,
    /// NRRD `.nrrd` (attached data) or `.nhdr` (detached).
    Nrrd,
    /// MetaImage `.mhd` or `.mha`.
    MetaImage,
    /// VolPack's `.den` density map.
    Den,
}

/// Decides the format of `path`; `LoadError::Format` for an unknown one.
pub fn detect_format(path: &Path) -> Result<Format, LoadError> {
    let meta = std::fs::metadata(path).map_err(|source| LoadError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    if meta.is_dir() {
        return Ok(Format::Dicom);
    }
    let lower = file_name_string(path).to_ascii_lowercase();
    let ends = |s: &str| lower.ends_with(s);
    if ends(".json") || ends(".raw") || ends(".raw.gz") {
        return Ok(Format::RawJson);
    }
    if ends(".nii") || ends(".nii.gz") || ends(".hdr") {
        return Ok(Format::Nifti);
    }
    if ends(".nrrd") || ends(".nhdr") {
        return Ok(Format::Nrrd);
    }
    if ends(".mhd") || ends(".mha") {
        return Ok(Format::MetaImage);
    }
    if ends(".den") {
        return Ok(Format::Den);
    }
    if ends(".dcm") || ends(".dicom") || ends(".ima") {
        return Ok(Format::Dicom);
    }
    // Sniff the first bytes.
    let mut head = [0u8; 352];
    let n = File::open(path)
        .and_then(|mut f| {
            let mut n = 0;
            loop {
                let k = f.read(&mut head[n..])?;
                if k == 0 || n + k == head.len() {
                    return Ok(n + k);
                }
                n += k;
            }
        })
        .map_err(|source| LoadError::Io {
            path: path.to_path_buf(),
            source,
        })?;
    let head = &head[..n];
    if head.len() >= 132 && &head[128..132] == b"DICM" {
        return Ok(Format::Dicom);
    }
    if head.starts_with(b"NRRD") {
        return Ok(Format::Nrrd);
    }
    if head.len() >= 348 && (&head[344..348] == b"n+1\0" || &head[344..348] == b"ni1\0") {
        return Ok(Format::Nifti);
    }
    if head.starts_with(b"ObjectType") || head.starts_with(b"NDims") {
        return Ok(Format::MetaImage);
    }
    if sidecar_path_for(path).is_file() {
        return Ok(Format::RawJson);
    }
    Err(LoadError::Format {
        path: path.to_path_buf(),
        reason: "unknown volume format (expected a DICOM directory or file, .nii, .nii.gz, \
                 .nrrd, .nhdr, .mhd, .mha, .den, or raw data with a JSON sidecar)"
            .into(),
    })
}

/// Loads a volume of any supported format (see [`detect_format`]) together with what is
/// known about its values; [`crate::formats`] describes how values become u8/u16.
pub fn load_volume_meta(
    path: &Path,
    prefer: Prefer,
) -> Result<(RawVolume, crate::formats::VolumeMeta), LoadError> {
    use crate::formats::{self, VolumeMeta};
    match detect_format(path) {
        Ok(Format::Dicom) => return formats::dicom::load(path),
        Ok(Format::Nifti) => return formats::nifti::load(path),
        Ok(Format::Nrrd) => return formats::nrrd::load(path),
        Ok(Format::MetaImage) => return formats::mhd::load(path),
        Ok(Format::Den) => return formats::den::load(path),
        // Missing files are reported by the sidecar loader below, as before.
        Ok(Format::RawJson) | Err(LoadError::Io { .. }) | Err(LoadError::Format { .. }) => {}
        Err(e) => return Err(e),
    }
    let v = load_raw_json(path, prefer)?;
    let t = v.voxel_type().as_str();
    let mut meta = VolumeMeta::identity("raw+json", t);
    let sidecar = if is_sidecar_name(path) {
        path.to_path_buf()
    } else {
        sidecar_path_for(path)
    };
    sidecar_value_mapping(&sidecar, v.voxel_type(), &mut meta)?;
    Ok((v, meta))
}

/// Reads what a sidecar says about the meaning of the stored values of the file of type
/// `vt` into `meta`: `"modality"` (top level) and, in the `"files"` entry of that voxel
/// type, either numeric `"value_slope"`/`"value_intercept"` (file value is stored times
/// slope plus intercept) with an optional `"value_units"`, or a `"mapping"` text of the shared
/// data set's form (`"u16 = HU + 1024"`, `"u8 = ... floor((HU + 1024) / 12) ..."`),
/// which gives Hounsfield units. Sidecars without these fields leave `meta` as it is.
fn sidecar_value_mapping(
    sidecar: &Path,
    vt: VoxelType,
    meta: &mut crate::formats::VolumeMeta,
) -> Result<(), LoadError> {
    let Ok(text) = std::fs::read(sidecar) else {
        return Ok(());
    };
    let Ok(Value::Object(root)) = serde_json::from_slice::<Value>(&text) else {
        return Ok(());
    };
    let invalid = |field: String, reason: &str| LoadError::InvalidField {
        path: sidecar.to_path_buf(),
        field,
        reason: reason.to_string(),
    };
    if let Some(m) = root.get("modality") {
        let m = m
            .as_str()
            .ok_or_else(|| invalid("modality".into(), "must be a string"))?;
        meta.modality = Some(m.trim().to_string()).filter(|m| !m.is_empty());
    }
    let Some(Value::Object(files)) = root.get("files") else {
        return Ok(());
    };
    let entry = files.iter().find(|(key, e)| {
        let t = e.get("voxel_type").and_then(Value::as_str).unwrap_or(key);
        VoxelType::parse(t) == Some(vt)
    });
    let Some((key, Value::Object(entry))) = entry else {
        return Ok(());
    };
    let num = |name: &str| -> Result<Option<f64>, LoadError> {
        match entry.get(name) {
            None => Ok(None),
            Some(v) => v
                .as_f64()
                .filter(|x| x.is_finite())
                .map(Some)
                .ok_or_else(|| invalid(format!("files.{key}.{name}"), "must be a finite number")),
        }
    };
    let (slope, intercept) = (num("value_slope")?, num("value_intercept")?);
    if slope.is_some() || intercept.is_some() {
        let slope = slope.unwrap_or(1.0);
        if slope <= 0.0 {
            return Err(invalid(format!("files.{key}.value_slope"), "must be > 0"));
        }
        meta.slope = slope;
        meta.intercept = intercept.unwrap_or(0.0);
        if let Some(u) = entry.get("value_units") {
            let u = u
                .as_str()
                .ok_or_else(|| invalid(format!("files.{key}.value_units"), "must be a string"))?;
            meta.units = Some(u.trim().to_string()).filter(|u| !u.is_empty());
        }
    } else if let Some((slope, intercept)) = entry
        .get("mapping")
        .and_then(Value::as_str)
        .and_then(parse_hu_mapping)
    {
        meta.slope = slope;
        meta.intercept = intercept;
        meta.units = Some("HU".into());
    }
    Ok(())
}

/// `(slope, intercept)` from HU = stored · slope + intercept for mapping texts of the
/// forms `"u16 = HU + K ..."` and `"u8 = ... floor((HU + K) / D) ..."` (K, D numbers, `+`
/// or `-`). With `floor`, a stored value stands for D consecutive integer HU values and
/// the intercept is their mean.
pub fn parse_hu_mapping(text: &str) -> Option<(f64, f64)> {
    let rhs = text.split_once('=')?.1;
    let at = rhs.find("HU")?;
    let rest = rhs[at + 2..].trim_start();
    let (sign, rest) = match rest.chars().next()? {
        '+' => (1.0, &rest[1..]),
        '-' | '−' => (-1.0, rest.trim_start_matches(['-', '−'])),
        _ => return None,
    };
    let rest = rest.trim_start();
    let end = rest
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(rest.len());
    let k: f64 = rest[..end].parse().ok()?;
    let k = sign * k;
    let after = rest[end..]
        .trim_start()
        .trim_start_matches(')')
        .trim_start();
    let d = match after.strip_prefix('/') {
        Some(r) => {
            let r = r.trim_start();
            let e = r
                .find(|c: char| !(c.is_ascii_digit() || c == '.'))
                .unwrap_or(r.len());
            let d: f64 = r[..e].parse().ok()?;
            (d.is_finite() && d > 0.0).then_some(d)?
        }
        None => 1.0,
    };
    let floor = rhs[..at].contains("floor");
    let centre = if floor { (d - 1.0) / 2.0 } else { 0.0 };
    Some((d, centre - k))
}

fn load_raw_json(path: &Path, prefer: Prefer) -> Result<RawVolume, LoadError> {
    if is_sidecar_name(path) {
        let sidecar = read_sidecar(path)?;
        let (data_path, voxel_type) = choose_file(path, &sidecar, prefer)?;
        read_volume(&sidecar, &data_path, voxel_type)
    } else {
        // Report a missing data file before a missing sidecar.
        if let Err(source) = std::fs::metadata(path) {
            return Err(LoadError::Io {
                path: path.to_path_buf(),
                source,
            });
        }
        let sidecar_path = sidecar_path_for(path);
        if !sidecar_path.is_file() {
            return Err(LoadError::SidecarNotFound {
                data: path.to_path_buf(),
                sidecar: sidecar_path,
            });
        }
        let sidecar = read_sidecar(&sidecar_path)?;
        let voxel_type = voxel_type_for_data_file(path, &sidecar)?;
        read_volume(&sidecar, path, voxel_type)
    }
}

/// The sidecar belonging to a data file: strips `.gz`, then `.raw`, then `.u8`/`.u16`
/// (each only if present) from the file name and appends `.json`, in the same
/// directory. `dir/mr_head_colin27.u8.raw.gz` → `dir/mr_head_colin27.json`.
pub fn sidecar_path_for(data: &Path) -> PathBuf {
    let name = data
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let base = data_file_base(&name);
    data.with_file_name(format!("{base}.json"))
}

/// Strips the `.gz`, `.raw`, `.u8`/`.u16` suffixes (in that order, each optional).
fn data_file_base(name: &str) -> &str {
    let mut base = strip_suffix_ci(name, ".gz").unwrap_or(name);
    base = strip_suffix_ci(base, ".raw").unwrap_or(base);
    strip_suffix_ci(base, ".u8")
        .or_else(|| strip_suffix_ci(base, ".u16"))
        .unwrap_or(base)
}

/// `s.strip_suffix(suffix)`, ASCII case-insensitive, never leaving an empty stem.
fn strip_suffix_ci<'a>(s: &'a str, suffix: &str) -> Option<&'a str> {
    if s.len() <= suffix.len() {
        return None;
    }
    let split = s.len() - suffix.len();
    if !s.is_char_boundary(split) {
        return None;
    }
    let (head, tail) = s.split_at(split);
    tail.eq_ignore_ascii_case(suffix).then_some(head)
}

fn file_name_string(path: &Path) -> String {
    path.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
}

fn is_sidecar_name(path: &Path) -> bool {
    path.extension()
        .is_some_and(|e| e.to_string_lossy().eq_ignore_ascii_case("json"))
}

fn has_gz_suffix(path: &Path) -> bool {
    path.extension()
        .is_some_and(|e| e.to_string_lossy().eq_ignore_ascii_case("gz"))
}

/// Voxel type implied by a `.u8`/`.u16` suffix (before optional `.raw`/`.gz`).
fn voxel_type_from_name(name: &str) -> Option<VoxelType> {
    let mut base = strip_suffix_ci(name, ".gz").unwrap_or(name);
    base = strip_suffix_ci(base, ".raw").unwrap_or(base);
    if strip_suffix_ci(base, ".u8").is_some() {
        Some(VoxelType::U8)
    } else if strip_suffix_ci(base, ".u16").is_some() {
        Some(VoxelType::U16)
    } else {
        None
    }
}

/// The validated contents of a sidecar.
#[derive(Debug)]
struct Sidecar {
    path: PathBuf,
    name: String,
    dims: [usize; 3],
    spacing: [f64; 3],
    /// `None` if the sidecar has no `"files"` field.
    files: Option<Vec<FileEntry>>,
}

#[derive(Debug)]
struct FileEntry {
    /// Key in `"files"`, e.g. `u8`.
    key: String,
    /// Field path for messages, e.g. `files.u8`.
    field: String,
    file: String,
    /// `Err(text)` for a voxel type this loader does not support.
    voxel_type: Result<VoxelType, String>,
    bytes_uncompressed: Option<u64>,
}

fn read_sidecar(path: &Path) -> Result<Sidecar, LoadError> {
    let io_err = |source| LoadError::Io {
        path: path.to_path_buf(),
        source,
    };
    let file = File::open(path).map_err(io_err)?;
    let mut text = Vec::new();
    file.take(MAX_SIDECAR_BYTES + 1)
        .read_to_end(&mut text)
        .map_err(io_err)?;
    if text.len() as u64 > MAX_SIDECAR_BYTES {
        return Err(LoadError::InvalidJson {
            path: path.to_path_buf(),
            message: format!("file is larger than {MAX_SIDECAR_BYTES} bytes"),
        });
    }
    let value: Value = serde_json::from_slice(&text).map_err(|e| LoadError::InvalidJson {
        path: path.to_path_buf(),
        message: e.to_string(),
    })?;
    parse_sidecar(path, &value)
}

fn parse_sidecar(path: &Path, value: &Value) -> Result<Sidecar, LoadError> {
    let Some(obj) = value.as_object() else {
        return Err(LoadError::InvalidJson {
            path: path.to_path_buf(),
            message: "top level is not a JSON object".into(),
        });
    };
    let invalid = |field: &str, reason: String| LoadError::InvalidField {
        path: path.to_path_buf(),
        field: field.to_string(),
        reason,
    };
    let missing = |field: &str| LoadError::MissingField {
        path: path.to_path_buf(),
        field: field.to_string(),
    };

    let name = match obj.get("name") {
        None | Some(Value::Null) => {
            let stem = file_name_string(path);
            strip_suffix_ci(&stem, ".json").unwrap_or(&stem).to_string()
        }
        Some(Value::String(s)) => s.clone(),
        Some(other) => {
            return Err(invalid(
                "name",
                format!("expected a string, found {}", brief(other)),
            ))
        }
    };

    // dims_xyz
    let dims_value = obj.get("dims_xyz").ok_or_else(|| missing("dims_xyz"))?;
    let dims_arr = three_elements(dims_value).ok_or_else(|| {
        invalid(
            "dims_xyz",
            format!(
                "expected an array of 3 integers, found {}",
                brief(dims_value)
            ),
        )
    })?;
    let mut dims64 = [0u64; 3];
    for (d, v) in dims64.iter_mut().zip(dims_arr) {
        *d = v.as_u64().ok_or_else(|| {
            invalid(
                "dims_xyz",
                format!("expected non-negative integers, found {}", brief(v)),
            )
        })?;
    }
    let dims = check_dims(path, dims64)?;

    // spacing_mm_xyz
    let spacing_value = obj
        .get("spacing_mm_xyz")
        .ok_or_else(|| missing("spacing_mm_xyz"))?;
    let spacing_arr = three_elements(spacing_value).ok_or_else(|| {
        invalid(
            "spacing_mm_xyz",
            format!(
                "expected an array of 3 numbers, found {}",
                brief(spacing_value)
            ),
        )
    })?;
    let mut spacing = [0f64; 3];
    for (s, v) in spacing.iter_mut().zip(spacing_arr) {
        *s = v.as_f64().ok_or_else(|| {
            invalid(
                "spacing_mm_xyz",
                format!("expected numbers, found {}", brief(v)),
            )
        })?;
    }
    if spacing.iter().any(|s| !(s.is_finite() && *s > 0.0)) {
        return Err(LoadError::InvalidSpacing {
            path: path.to_path_buf(),
            spacing,
        });
    }

    // files
    let files = match obj.get("files") {
        None | Some(Value::Null) => None,
        Some(Value::Object(map)) => Some(parse_files(path, map)?),
        Some(other) => {
            return Err(invalid(
                "files",
                format!("expected an object, found {}", json_kind(other)),
            ))
        }
    };

    Ok(Sidecar {
        path: path.to_path_buf(),
        name,
        dims,
        spacing,
        files,
    })
}

fn three_elements(v: &Value) -> Option<&[Value]> {
    match v.as_array() {
        Some(a) if a.len() == 3 => Some(a.as_slice()),
        _ => None,
    }
}

/// A JSON value for an error message, shortened to at most 60 characters.
fn brief(v: &Value) -> String {
    const MAX: usize = 60;
    let text = v.to_string();
    if text.chars().count() <= MAX {
        text
    } else {
        let mut short: String = text.chars().take(MAX).collect();
        short.push('…');
        short
    }
}

fn json_kind(v: &Value) -> &'static str {
    match v {
        Value::Null => "null",
        Value::Bool(_) => "a boolean",
        Value::Number(_) => "a number",
        Value::String(_) => "a string",
        Value::Array(_) => "an array",
        Value::Object(_) => "an object",
    }
}

thread_local! {
    static VOXEL_LIMIT: std::cell::Cell<u64> = const { std::cell::Cell::new(MAX_VOXELS) };
}

/// Runs `f` (loads on this thread) with the total voxel limit lowered to `limit` (at most
/// [`MAX_VOXELS`]): larger volumes are refused as `AbsurdDims` from their header, before
/// their data is read.
pub fn with_voxel_limit<T>(limit: u64, f: impl FnOnce() -> T) -> T {
    let old = VOXEL_LIMIT.with(|l| l.replace(limit.min(MAX_VOXELS)));
    let out = f();
    VOXEL_LIMIT.with(|l| l.set(old));
    out
}

/// Checks dims against the limits with overflow-free arithmetic.
pub(crate) fn check_dims(path: &Path, dims: [u64; 3]) -> Result<[usize; 3], LoadError> {
    let absurd = |reason: String| LoadError::AbsurdDims {
        path: path.to_path_buf(),
        dims,
        reason,
    };
    if dims.contains(&0) {
        return Err(absurd("every extent must be at least 1".into()));
    }
    if let Some(d) = dims.iter().find(|&&d| d > MAX_DIM as u64) {
        return Err(absurd(format!(
            "extent {d} exceeds the maximum of {MAX_DIM}"
        )));
    }
    let limit = VOXEL_LIMIT.with(|l| l.get());
    let total = dims
        .iter()
        .try_fold(1u64, |acc, &d| acc.checked_mul(d))
        .filter(|&t| t <= limit);
    let Some(total) = total else {
        return Err(absurd(format!("more than {limit} voxels in total")));
    };
    // Bytes for u16 must be addressable too (matters on 32-bit targets only).
    if usize::try_from(total.saturating_mul(2)).is_err() {
        return Err(absurd("too large for this platform's address space".into()));
    }
    // Each extent is <= MAX_DIM, so the conversions cannot fail.
    Ok([dims[0] as usize, dims[1] as usize, dims[2] as usize])
}

fn parse_files(path: &Path, map: &Map<String, Value>) -> Result<Vec<FileEntry>, LoadError> {
    let mut out = Vec::with_capacity(map.len());
    for (key, entry) in map {
        let field = format!("files.{key}");
        let invalid = |field: String, reason: String| LoadError::InvalidField {
            path: path.to_path_buf(),
            field,
            reason,
        };
        let Some(entry) = entry.as_object() else {
            return Err(invalid(
                field,
                format!("expected an object, found {}", json_kind(entry)),
            ));
        };
        let file = match entry.get("file") {
            Some(Value::String(s)) if !s.trim().is_empty() => s.clone(),
            Some(Value::String(_)) => {
                return Err(invalid(format!("{field}.file"), "empty file name".into()))
            }
            Some(other) => {
                return Err(invalid(
                    format!("{field}.file"),
                    format!("expected a string, found {}", json_kind(other)),
                ))
            }
            None => {
                return Err(LoadError::MissingField {
                    path: path.to_path_buf(),
                    field: format!("{field}.file"),
                })
            }
        };
        // The entry's "voxel_type", else its key (the format keys entries by type).
        let type_text = match entry.get("voxel_type") {
            Some(Value::String(s)) => s.clone(),
            None | Some(Value::Null) => key.clone(),
            Some(other) => {
                return Err(invalid(
                    format!("{field}.voxel_type"),
                    format!("expected a string, found {}", json_kind(other)),
                ))
            }
        };
        let voxel_type = VoxelType::parse(&type_text).ok_or(type_text);
        let bytes_uncompressed = match entry.get("bytes_uncompressed") {
            None | Some(Value::Null) => None,
            Some(v) => Some(v.as_u64().ok_or_else(|| {
                invalid(
                    format!("{field}.bytes_uncompressed"),
                    format!("expected a non-negative integer, found {}", brief(v)),
                )
            })?),
        };
        out.push(FileEntry {
            key: key.clone(),
            field,
            file,
            voxel_type,
            bytes_uncompressed,
        });
    }
    Ok(out)
}

/// Picks the data file of a sidecar according to `prefer`.
fn choose_file(
    sidecar_path: &Path,
    sidecar: &Sidecar,
    prefer: Prefer,
) -> Result<(PathBuf, VoxelType), LoadError> {
    let Some(files) = &sidecar.files else {
        return Err(LoadError::MissingField {
            path: sidecar_path.to_path_buf(),
            field: "files".into(),
        });
    };
    if files.is_empty() {
        return Err(LoadError::InvalidField {
            path: sidecar_path.to_path_buf(),
            field: "files".into(),
            reason: "no entries".into(),
        });
    }
    let order = match prefer {
        Prefer::U8 => [VoxelType::U8, VoxelType::U16],
        Prefer::U16 => [VoxelType::U16, VoxelType::U8],
    };
    // Per type, the entry keyed by the type's name ("u8", "u16") comes first.
    let mut candidates: Vec<(bool, usize, PathBuf, VoxelType)> = Vec::new();
    for (rank, &t) in order.iter().enumerate() {
        for e in files.iter().filter(|e| e.voxel_type == Ok(t)) {
            let off_key = !e.key.eq_ignore_ascii_case(t.as_str());
            candidates.push((off_key, rank, resolve_data_path(sidecar_path, &e.file), t));
        }
    }
    candidates.sort_by_key(|c| (c.1, c.0));
    let candidates: Vec<(PathBuf, VoxelType)> =
        candidates.into_iter().map(|(_, _, p, t)| (p, t)).collect();
    if let Some(found) = candidates.iter().find(|(p, _)| p.is_file()) {
        return Ok(found.clone());
    }
    match candidates.into_iter().next() {
        // None of the listed files exists: report the preferred one.
        Some((p, _)) => Err(LoadError::Io {
            path: p,
            source: io::Error::new(io::ErrorKind::NotFound, "file not found"),
        }),
        // Only unsupported voxel types are listed.
        None => Err(LoadError::UnknownVoxelType {
            path: sidecar_path.to_path_buf(),
            voxel_type: files.iter().find_map(|e| e.voxel_type.clone().err()),
        }),
    }
}

fn resolve_data_path(sidecar_path: &Path, file: &str) -> PathBuf {
    match sidecar_path.parent() {
        Some(dir) => dir.join(file),
        None => PathBuf::from(file),
    }
}

/// Voxel type of a data file given directly: its sidecar entry, else its suffix.
fn voxel_type_for_data_file(data: &Path, sidecar: &Sidecar) -> Result<VoxelType, LoadError> {
    let name = file_name_string(data);
    let listed = sidecar.files.as_ref().and_then(|files| {
        files.iter().find(|e| {
            Path::new(&e.file)
                .file_name()
                .is_some_and(|n| n.to_string_lossy() == name)
        })
    });
    match listed {
        Some(entry) => entry
            .voxel_type
            .clone()
            .map_err(|t| LoadError::UnknownVoxelType {
                path: sidecar.path.clone(),
                voxel_type: Some(t),
            }),
        None => voxel_type_from_name(&name).ok_or_else(|| LoadError::UnknownVoxelType {
            path: data.to_path_buf(),
            voxel_type: None,
        }),
    }
}

fn read_volume(
    sidecar: &Sidecar,
    data_path: &Path,
    voxel_type: VoxelType,
) -> Result<RawVolume, LoadError> {
    let [nx, ny, nz] = sidecar.dims;
    // check_dims guarantees these products fit in u64 and usize.
    let count = nx as u64 * ny as u64 * nz as u64;
    let expected = count * voxel_type.bytes() as u64;

    // A sidecar entry for this file must agree with dims × type.
    let name = file_name_string(data_path);
    if let Some(entry) = sidecar.files.iter().flatten().find(|e| {
        Path::new(&e.file)
            .file_name()
            .is_some_and(|n| n.to_string_lossy() == name)
    }) {
        if let Some(b) = entry.bytes_uncompressed {
            if b != expected {
                return Err(LoadError::InvalidField {
                    path: sidecar.path.clone(),
                    field: format!("{}.bytes_uncompressed", entry.field),
                    reason: format!(
                        "{b} does not match {nx}×{ny}×{nz} {voxel_type} = {expected} bytes"
                    ),
                });
            }
        }
    }

    let bytes = read_data(data_path, expected, sidecar.dims, voxel_type)?;
    let voxels = match voxel_type {
        VoxelType::U8 => Voxels::U8(bytes),
        VoxelType::U16 => Voxels::U16(
            bytes
                .chunks_exact(2)
                .map(|c| u16::from_le_bytes([c[0], c[1]]))
                .collect(),
        ),
    };
    Ok(RawVolume {
        name: sidecar.name.clone(),
        dims: sidecar.dims,
        spacing: sidecar.spacing,
        voxels,
    })
}

/// Reads exactly `expected` bytes of voxel data, decompressing if needed.
fn read_data(
    path: &Path,
    expected: u64,
    dims: [usize; 3],
    voxel_type: VoxelType,
) -> Result<Vec<u8>, LoadError> {
    let io_err = |source| LoadError::Io {
        path: path.to_path_buf(),
        source,
    };
    let wrong_size = |found: u64, exceeded: bool| LoadError::WrongSize {
        path: path.to_path_buf(),
        dims,
        voxel_type,
        expected,
        found,
        exceeded,
    };
    let file = File::open(path).map_err(io_err)?;
    let file_len = file.metadata().map_err(io_err)?.len();
    let mut reader = BufReader::new(file);
    let gzip = has_gz_suffix(path) || {
        // Sniff the magic only when the size rules out plain raw data.
        file_len != expected && reader.fill_buf().map_err(io_err)?.starts_with(&GZIP_MAGIC)
    };

    // Plain raw data of the wrong size is refused from its metadata alone, before any
    // buffer is reserved for it.
    if !gzip && file_len != expected {
        return Err(wrong_size(file_len, false));
    }
    // Never reserve more than the input can plausibly need up front; the cap on the
    // reader bounds the final size anyway.
    let cap = expected.saturating_add(1);
    let initial = if gzip {
        cap.min(file_len.saturating_mul(8)).min(64 << 20)
    } else {
        cap.min(file_len)
    };
    let mut bytes = Vec::with_capacity(usize::try_from(initial).unwrap_or(0));

    if gzip {
        let decoder = MultiGzDecoder::new(reader);
        decoder
            .take(cap)
            .read_to_end(&mut bytes)
            .map_err(|source| LoadError::CorruptGzip {
                path: path.to_path_buf(),
                source,
            })?;
    } else {
        reader.take(cap).read_to_end(&mut bytes).map_err(io_err)?;
    }
    if bytes.len() as u64 != expected {
        // Only a capped (gzip) read can stop short of the real size.
        let found = bytes.len() as u64;
        return Err(wrong_size(found, found > expected));
    }
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;
    use flate2::write::GzEncoder;
    use flate2::Compression;
    use std::io::Write;
    use std::sync::atomic::{AtomicUsize, Ordering};

    // ---------------------------------------------------------------- helpers

    fn fixtures() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures")
    }

    /// A unique scratch directory, removed on drop.
    struct TempDir(PathBuf);

    impl TempDir {
        fn new(tag: &str) -> TempDir {
            static COUNTER: AtomicUsize = AtomicUsize::new(0);
            let n = COUNTER.fetch_add(1, Ordering::Relaxed);
            let nanos = std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map(|d| d.as_nanos())
                .unwrap_or(0);
            let dir = std::env::temp_dir().join(format!(
                "shearwarp-volume-test-{}-{tag}-{n}-{nanos}",
                std::process::id()
            ));
            std::fs::create_dir_all(&dir).unwrap();
            TempDir(dir)
        }

        fn write(&self, name: &str, contents: &[u8]) -> PathBuf {
            let p = self.0.join(name);
            std::fs::write(&p, contents).unwrap();
            p
        }

        fn path(&self, name: &str) -> PathBuf {
            self.0.join(name)
        }
    }

    impl Drop for TempDir {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }

    fn gzip(data: &[u8]) -> Vec<u8> {
        let mut enc = GzEncoder::new(Vec::new(), Compression::fast());
        enc.write_all(data).unwrap();
        enc.finish().unwrap()
    }

    fn sidecar_json(dims: &str, spacing: &str, files: &str) -> String {
        format!(
            r#"{{"name": "test", "dims_xyz": {dims}, "spacing_mm_xyz": {spacing}, "files": {files}}}"#
        )
    }

    /// Sidecar "v.json" for 2×3×4 u8 in "v.u8.raw", plus the data file.
    fn small_u8(dir: &TempDir) -> (PathBuf, PathBuf) {
        let json = dir.write(
            "v.json",
            sidecar_json(
                "[2, 3, 4]",
                "[1.0, 0.5, 2.0]",
                r#"{"u8": {"file": "v.u8.raw", "voxel_type": "u8", "bytes_uncompressed": 24}}"#,
            )
            .as_bytes(),
        );
        let data: Vec<u8> = (0..24).collect();
        let raw = dir.write("v.u8.raw", &data);
        (json, raw)
    }

    fn err_of(path: &Path) -> LoadError {
        match load_volume(path) {
            Ok(v) => panic!(
                "expected an error for {}, loaded {:?}",
                path.display(),
                v.dims
            ),
            Err(e) => e,
        }
    }

    /// Minimal SHA-256 (FIPS 180-4), for checking fixtures against their sidecars.
    fn sha256_hex(data: &[u8]) -> String {
        const K: [u32; 64] = [
            0x428a2f98, 0x71374491, 0xb5c0fbcf, 0xe9b5dba5, 0x3956c25b, 0x59f111f1, 0x923f82a4,
            0xab1c5ed5, 0xd807aa98, 0x12835b01, 0x243185be, 0x550c7dc3, 0x72be5d74, 0x80deb1fe,
            0x9bdc06a7, 0xc19bf174, 0xe49b69c1, 0xefbe4786, 0x0fc19dc6, 0x240ca1cc, 0x2de92c6f,
            0x4a7484aa, 0x5cb0a9dc, 0x76f988da, 0x983e5152, 0xa831c66d, 0xb00327c8, 0xbf597fc7,
            0xc6e00bf3, 0xd5a79147, 0x06ca6351, 0x14292967, 0x27b70a85, 0x2e1b2138, 0x4d2c6dfc,
            0x53380d13, 0x650a7354, 0x766a0abb, 0x81c2c92e, 0x92722c85, 0xa2bfe8a1, 0xa81a664b,
            0xc24b8b70, 0xc76c51a3, 0xd192e819, 0xd6990624, 0xf40e3585, 0x106aa070, 0x19a4c116,
            0x1e376c08, 0x2748774c, 0x34b0bcb5, 0x391c0cb3, 0x4ed8aa4a, 0x5b9cca4f, 0x682e6ff3,
            0x748f82ee, 0x78a5636f, 0x84c87814, 0x8cc70208, 0x90befffa, 0xa4506ceb, 0xbef9a3f7,
            0xc67178f2,
        ];
        let mut h: [u32; 8] = [
            0x6a09e667, 0xbb67ae85, 0x3c6ef372, 0xa54ff53a, 0x510e527f, 0x9b05688c, 0x1f83d9ab,
            0x5be0cd19,
        ];
        let mut msg = data.to_vec();
        let bit_len = (data.len() as u64).wrapping_mul(8);
        msg.push(0x80);
        while msg.len() % 64 != 56 {
            msg.push(0);
        }
        msg.extend_from_slice(&bit_len.to_be_bytes());
        for block in msg.chunks_exact(64) {
            let mut w = [0u32; 64];
            for (i, word) in block.chunks_exact(4).enumerate() {
                w[i] = u32::from_be_bytes([word[0], word[1], word[2], word[3]]);
            }
            for i in 16..64 {
                let s0 = w[i - 15].rotate_right(7) ^ w[i - 15].rotate_right(18) ^ (w[i - 15] >> 3);
                let s1 = w[i - 2].rotate_right(17) ^ w[i - 2].rotate_right(19) ^ (w[i - 2] >> 10);
                w[i] = w[i - 16]
                    .wrapping_add(s0)
                    .wrapping_add(w[i - 7])
                    .wrapping_add(s1);
            }
            let [mut a, mut b, mut c, mut d, mut e, mut f, mut g, mut hh] = h;
            for i in 0..64 {
                let s1 = e.rotate_right(6) ^ e.rotate_right(11) ^ e.rotate_right(25);
                let ch = (e & f) ^ (!e & g);
                let t1 = hh
                    .wrapping_add(s1)
                    .wrapping_add(ch)
                    .wrapping_add(K[i])
                    .wrapping_add(w[i]);
                let s0 = a.rotate_right(2) ^ a.rotate_right(13) ^ a.rotate_right(22);
                let maj = (a & b) ^ (a & c) ^ (b & c);
                let t2 = s0.wrapping_add(maj);
                hh = g;
                g = f;
                f = e;
                e = d.wrapping_add(t1);
                d = c;
                c = b;
                b = a;
                a = t1.wrapping_add(t2);
            }
            for (x, y) in h.iter_mut().zip([a, b, c, d, e, f, g, hh]) {
                *x = x.wrapping_add(y);
            }
        }
        h.iter().map(|x| format!("{x:08x}")).collect()
    }

    fn voxel_bytes(v: &Voxels) -> Vec<u8> {
        match v {
            Voxels::U8(b) => b.clone(),
            Voxels::U16(w) => w.iter().flat_map(|x| x.to_le_bytes()).collect(),
        }
    }

    fn sidecar_sha(json: &Path, key: &str) -> String {
        let v: Value = serde_json::from_slice(&std::fs::read(json).unwrap()).unwrap();
        v["files"][key]["sha256_uncompressed"]
            .as_str()
            .unwrap()
            .to_string()
    }

    // ---------------------------------------------------------------- helpers' tests

    #[test]
    fn sha256_known_vectors() {
        assert_eq!(
            sha256_hex(b""),
            "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855"
        );
        assert_eq!(
            sha256_hex(b"abc"),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
        assert_eq!(
            sha256_hex(b"abcdbcdecdefdefgefghfghighijhijkijkljklmklmnlmnomnopnopq"),
            "248d6a61d20638b8e5c026930c3e6039a33ce45964ff2167f6ecedd419db06c1"
        );
    }

    #[test]
    fn sidecar_paths() {
        let d = Path::new("/some/dir");
        let cases = [
            ("mr_head_colin27_64.u8.raw", "mr_head_colin27_64.json"),
            ("mr_head_colin27.u8.raw.gz", "mr_head_colin27.json"),
            ("mr_pd_brain_series.u16.raw.gz", "mr_pd_brain_series.json"),
            ("x.raw", "x.json"),
            ("x.u16", "x.json"),
            ("x.bin", "x.bin.json"),
            ("x.RAW.GZ", "x.json"),
            (".raw", ".raw.json"),
        ];
        for (data, side) in cases {
            assert_eq!(sidecar_path_for(&d.join(data)), d.join(side), "{data}");
        }
        assert_eq!(voxel_type_from_name("a.u16.raw.gz"), Some(VoxelType::U16));
        assert_eq!(voxel_type_from_name("a.u8.raw"), Some(VoxelType::U8));
        assert_eq!(voxel_type_from_name("a.raw"), None);
    }

    // ---------------------------------------------------------------- fixtures

    #[test]
    fn fixtures_64_load_and_match_sha256() {
        for name in [
            "mr_head_colin27_64",
            "mr_brain_colin27_hires_64",
            "mr_pd_brain_series_64",
        ] {
            let json = fixtures().join(format!("{name}.json"));
            let raw = fixtures().join(format!("{name}.u8.raw"));
            let a = load_volume(&json).unwrap_or_else(|e| panic!("{e}"));
            let b = load_volume(&raw).unwrap_or_else(|e| panic!("{e}"));
            assert_eq!(a, b);
            assert_eq!(a.name, name);
            assert_eq!(a.dims, [64, 64, 64]);
            assert_eq!(a.voxel_type(), VoxelType::U8);
            assert_eq!(a.voxel_count(), 64 * 64 * 64);
            assert!(a.spacing.iter().all(|s| *s > 1.0 && *s < 4.0));
            assert_eq!(
                sha256_hex(&voxel_bytes(&a.voxels)),
                sidecar_sha(&json, "u8")
            );
        }
        let v = load_volume(&fixtures().join("mr_head_colin27_64.json")).unwrap();
        assert_eq!(v.spacing, [2.828125, 3.390625, 2.828125]);
    }

    #[test]
    fn fixture_full_colin27_gz() {
        let json = fixtures().join("mr_head_colin27.json");
        let gz = fixtures().join("mr_head_colin27.u8.raw.gz");
        let v = load_volume(&gz).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(v.name, "mr_head_colin27");
        assert_eq!(v.dims, [181, 217, 181]);
        assert_eq!(v.spacing, [1.0, 1.0, 1.0]);
        assert_eq!(v.voxel_count(), 181 * 217 * 181);
        assert_eq!(
            sha256_hex(&voxel_bytes(&v.voxels)),
            sidecar_sha(&json, "u8")
        );
        let w = load_volume_with(&json, Prefer::U16).unwrap();
        assert_eq!(w.voxel_type(), VoxelType::U8, "falls back to u8");
    }

    #[test]
    fn fixture_pd_series_u16() {
        let json = fixtures().join("mr_pd_brain_series.json");
        // Only the u16 file is in fixtures/, so u8 preference falls back to it.
        for v in [
            load_volume(&json).unwrap_or_else(|e| panic!("{e}")),
            load_volume_with(&json, Prefer::U16).unwrap(),
            load_volume(&fixtures().join("mr_pd_brain_series.u16.raw.gz")).unwrap(),
        ] {
            assert_eq!(v.dims, [256, 256, 20]);
            assert_eq!(v.spacing, [0.859375, 0.859375, 7.000524]);
            let Voxels::U16(w) = &v.voxels else {
                panic!("expected u16")
            };
            assert_eq!(w.len(), 256 * 256 * 20);
            assert_eq!(w.iter().copied().max(), Some(1059));
            assert_eq!(
                sha256_hex(&voxel_bytes(&v.voxels)),
                sidecar_sha(&json, "u16")
            );
        }
    }

    // ---------------------------------------------------------------- success paths

    #[test]
    fn loads_small_u8_via_sidecar_and_data() {
        let dir = TempDir::new("small");
        let (json, raw) = small_u8(&dir);
        let a = load_volume(&json).unwrap();
        let b = load_volume(&raw).unwrap();
        assert_eq!(a, b);
        assert_eq!(a.name, "test");
        assert_eq!(a.dims, [2, 3, 4]);
        assert_eq!(a.spacing, [1.0, 0.5, 2.0]);
        assert_eq!(a.voxels, Voxels::U8((0..24).collect()));
    }

    #[test]
    fn u16_is_little_endian_and_gzip_by_suffix_or_magic() {
        let dir = TempDir::new("u16");
        let words: Vec<u16> = (0..8).map(|i| 0x1234 + i * 0x0101).collect();
        let bytes: Vec<u8> = words.iter().flat_map(|w| w.to_le_bytes()).collect();
        // No "files" and no "name": type from suffix, name from the sidecar stem.
        dir.write(
            "w.json",
            br#"{"dims_xyz": [2, 2, 2], "spacing_mm_xyz": [1, 1, 1]}"#,
        );
        let raw = dir.write("w.u16.raw", &bytes);
        let v = load_volume(&raw).unwrap();
        assert_eq!(v.name, "w");
        assert_eq!(v.voxels, Voxels::U16(words.clone()));
        let gz = dir.write("w.u16.raw.gz", &gzip(&bytes));
        assert_eq!(load_volume(&gz).unwrap().voxels, Voxels::U16(words.clone()));
        // Gzip data without a .gz suffix is recognised by its magic bytes.
        let sneaky = dir.write("w.u16", &gzip(&bytes));
        assert_eq!(load_volume(&sneaky).unwrap().voxels, Voxels::U16(words));
    }

    #[test]
    fn raw_data_starting_with_gzip_magic_is_not_mistaken_for_gzip() {
        let dir = TempDir::new("magic");
        dir.write(
            "m.json",
            br#"{"dims_xyz": [4, 1, 1], "spacing_mm_xyz": [1, 1, 1]}"#,
        );
        let raw = dir.write("m.u8.raw", &[0x1f, 0x8b, 8, 0]);
        assert_eq!(
            load_volume(&raw).unwrap().voxels,
            Voxels::U8(vec![0x1f, 0x8b, 8, 0])
        );
    }

    #[test]
    fn sidecar_entry_type_overrides_suffix_and_prefer_selects() {
        let dir = TempDir::new("prefer");
        dir.write(
            "p.json",
            sidecar_json(
                "[2, 1, 1]",
                "[1, 1, 1]",
                r#"{"u8": {"file": "p.u8.raw.gz", "voxel_type": "u8"},
                    "u16": {"file": "p.u16.raw.gz", "voxel_type": "u16"},
                    "odd": {"file": "p.raw", "voxel_type": "u16"}}"#,
            )
            .as_bytes(),
        );
        dir.write("p.u8.raw.gz", &gzip(&[1, 2]));
        dir.write("p.u16.raw.gz", &gzip(&[1, 0, 2, 1]));
        dir.write("p.raw", &[3, 0, 4, 0]);
        dir.write("p.data", &[3, 0, 4, 0]);
        let json = dir.path("p.json");
        assert_eq!(load_volume(&json).unwrap().voxels, Voxels::U8(vec![1, 2]));
        assert_eq!(
            load_volume_with(&json, Prefer::U16).unwrap().voxels,
            Voxels::U16(vec![1, 0x0102])
        );
        // "p.raw" has no type suffix; its entry in p.json says u16.
        assert_eq!(
            load_volume(&dir.path("p.raw")).unwrap().voxels,
            Voxels::U16(vec![3, 4])
        );
        // "p.data" has sidecar "p.data.json", which does not exist.
        assert!(matches!(
            err_of(&dir.path("p.data")),
            LoadError::SidecarNotFound { .. }
        ));
        // Prefer::U8 with the u8 file missing falls back to u16.
        std::fs::remove_file(dir.path("p.u8.raw.gz")).unwrap();
        assert_eq!(
            load_volume(&json).unwrap().voxels,
            Voxels::U16(vec![1, 0x0102])
        );
    }

    // ---------------------------------------------------------------- errors

    #[test]
    fn hu_mappings_of_the_shared_sidecars() {
        assert_eq!(
            parse_hu_mapping("u16 = HU + 1024  (so HU = u16 - 1024; range 0..4010)"),
            Some((1.0, -1024.0))
        );
        assert_eq!(
            parse_hu_mapping(
                "u8 = min(255, max(0, floor((HU + 1024) / 12)))  (window -1024..2036 HU)"
            ),
            Some((12.0, -1018.5))
        );
        assert_eq!(parse_hu_mapping("u16 = HU - 20"), Some((1.0, 20.0)));
        for bad in [
            "",
            "u8 = value",
            "HU + 3",
            "u8 = HU * 2",
            "u8 = (HU + 1) / 0",
        ] {
            assert_eq!(parse_hu_mapping(bad), None, "{bad}");
        }
    }

    #[test]
    fn sidecar_value_fields_give_the_mapping() {
        let dir = TempDir::new("valuemap");
        dir.write("v.u16.raw", &[0; 48]);
        let json = dir.write(
            "v.json",
            br#"{"dims_xyz": [2, 3, 4], "spacing_mm_xyz": [1, 1, 1], "modality": "CT",
                "files": {"u16": {"file": "v.u16.raw", "value_slope": 2, "value_intercept": -1000,
                "value_units": "HU"}}}"#,
        );
        let (_, m) = load_volume_meta(&json, Prefer::U8).unwrap();
        assert_eq!((m.slope, m.intercept), (2.0, -1000.0));
        assert_eq!(
            (m.units.as_deref(), m.modality.as_deref()),
            (Some("HU"), Some("CT"))
        );
        dir.write(
            "v.json",
            br#"{"dims_xyz": [2, 3, 4], "spacing_mm_xyz": [1, 1, 1],
                "files": {"u16": {"file": "v.u16.raw", "value_slope": 0}}}"#,
        );
        let e = load_volume_meta(&json, Prefer::U8).unwrap_err();
        assert!(e.to_string().contains("files.u16.value_slope"), "{e}");
    }

    #[test]
    fn error_missing_data_file() {
        let dir = TempDir::new("missing");
        let p = dir.path("nothing.u8.raw");
        let e = err_of(&p);
        assert!(
            matches!(&e, LoadError::Io { source, .. } if source.kind() == io::ErrorKind::NotFound)
        );
        assert!(e.to_string().contains("nothing.u8.raw"), "{e}");
        assert!(e.to_string().contains("not found"), "{e}");
        assert!(std::error::Error::source(&e).is_some());
    }

    #[test]
    fn error_missing_sidecar_file_given_directly() {
        let dir = TempDir::new("missing-json");
        let e = err_of(&dir.path("nothing.json"));
        assert!(matches!(e, LoadError::Io { .. }));
        assert!(e.to_string().contains("nothing.json"), "{e}");
    }

    #[test]
    fn error_listed_data_file_missing() {
        let dir = TempDir::new("listed-missing");
        let (json, raw) = small_u8(&dir);
        std::fs::remove_file(&raw).unwrap();
        let e = err_of(&json);
        assert!(matches!(e, LoadError::Io { .. }));
        assert!(e.to_string().contains("v.u8.raw"), "{e}");
    }

    #[test]
    fn error_sidecar_not_found() {
        let dir = TempDir::new("nosidecar");
        let raw = dir.write("lonely.u8.raw.gz", &gzip(&[0; 8]));
        let e = err_of(&raw);
        assert!(matches!(e, LoadError::SidecarNotFound { .. }));
        let msg = e.to_string();
        assert!(
            msg.contains("lonely.u8.raw.gz") && msg.contains("lonely.json"),
            "{msg}"
        );
    }

    #[test]
    fn error_invalid_json() {
        let dir = TempDir::new("badjson");
        for (i, text) in [
            "{ not json",
            "",
            "[1, 2, 3]",
            "\"string\"",
            r#"{"dims_xyz": [1, 1, 1], "spacing_mm_xyz": [1e400, 1, 1]}"#,
        ]
        .iter()
        .enumerate()
        {
            let p = dir.write(&format!("j{i}.json"), text.as_bytes());
            let e = err_of(&p);
            assert!(matches!(e, LoadError::InvalidJson { .. }), "{text}: {e}");
            assert!(e.to_string().contains(&format!("j{i}.json")), "{e}");
        }
        // Huge sidecars are refused without reading them whole.
        let mut big = b"{\"pad\": \"".to_vec();
        big.resize(2 << 20, b'a');
        big.extend_from_slice(b"\"}");
        let p = dir.write("big.json", &big);
        assert!(matches!(err_of(&p), LoadError::InvalidJson { .. }));
    }

    #[test]
    fn error_missing_fields() {
        let dir = TempDir::new("missingfield");
        let cases = [
            (r#"{"spacing_mm_xyz": [1, 1, 1], "files": {}}"#, "dims_xyz"),
            (r#"{"dims_xyz": [1, 1, 1], "files": {}}"#, "spacing_mm_xyz"),
            (
                r#"{"dims_xyz": [1, 1, 1], "spacing_mm_xyz": [1, 1, 1]}"#,
                "files",
            ),
            (
                r#"{"dims_xyz": [1, 1, 1], "spacing_mm_xyz": [1, 1, 1], "files": {"u8": {"voxel_type": "u8"}}}"#,
                "files.u8.file",
            ),
        ];
        for (i, (text, field)) in cases.iter().enumerate() {
            let p = dir.write(&format!("m{i}.json"), text.as_bytes());
            let e = err_of(&p);
            match &e {
                LoadError::MissingField { field: f, .. } => assert_eq!(f, field),
                other => panic!("{text}: expected MissingField, got {other:?}"),
            }
            let msg = e.to_string();
            assert!(
                msg.contains(field) && msg.contains(&format!("m{i}.json")),
                "{msg}"
            );
        }
    }

    #[test]
    fn error_invalid_fields() {
        let dir = TempDir::new("invalidfield");
        let ok_files = r#"{"u8": {"file": "x.u8.raw"}}"#;
        let cases = [
            (sidecar_json("[1, 1]", "[1, 1, 1]", ok_files), "dims_xyz"),
            (sidecar_json("\"64\"", "[1, 1, 1]", ok_files), "dims_xyz"),
            (
                sidecar_json("[1, -1, 1]", "[1, 1, 1]", ok_files),
                "dims_xyz",
            ),
            (
                sidecar_json("[1, 1.5, 1]", "[1, 1, 1]", ok_files),
                "dims_xyz",
            ),
            (
                sidecar_json("[1, 1, 100000000000000000000000]", "[1, 1, 1]", ok_files),
                "dims_xyz",
            ),
            (
                sidecar_json("[1, 1, 1]", "[1, 1, 1, 1]", ok_files),
                "spacing_mm_xyz",
            ),
            (
                sidecar_json("[1, 1, 1]", "[1, \"a\", 1]", ok_files),
                "spacing_mm_xyz",
            ),
            (sidecar_json("[1, 1, 1]", "[1, 1, 1]", "[]"), "files"),
            (sidecar_json("[1, 1, 1]", "[1, 1, 1]", "{}"), "files"),
            (
                sidecar_json("[1, 1, 1]", "[1, 1, 1]", r#"{"u8": 3}"#),
                "files.u8",
            ),
            (
                sidecar_json("[1, 1, 1]", "[1, 1, 1]", r#"{"u8": {"file": 7}}"#),
                "files.u8.file",
            ),
            (
                sidecar_json(
                    "[1, 1, 1]",
                    "[1, 1, 1]",
                    r#"{"u8": {"file": "x", "voxel_type": 8}}"#,
                ),
                "files.u8.voxel_type",
            ),
            (
                sidecar_json(
                    "[1, 1, 1]",
                    "[1, 1, 1]",
                    r#"{"u8": {"file": "x", "bytes_uncompressed": -1}}"#,
                ),
                "files.u8.bytes_uncompressed",
            ),
            (
                r#"{"name": 5, "dims_xyz": [1, 1, 1], "spacing_mm_xyz": [1, 1, 1]}"#.to_string(),
                "name",
            ),
        ];
        for (i, (text, field)) in cases.iter().enumerate() {
            let p = dir.write(&format!("f{i}.json"), text.as_bytes());
            let e = err_of(&p);
            match &e {
                LoadError::InvalidField { field: f, .. } => assert_eq!(f, field, "{text}"),
                other => panic!("{text}: expected InvalidField, got {other:?}"),
            }
            assert!(e.to_string().contains(field), "{e}");
        }
    }

    #[test]
    fn error_messages_quote_long_values_briefly() {
        let dir = TempDir::new("brief");
        let long = format!("[{}]", vec!["1"; 10_000].join(","));
        let p = dir.write("l.json", sidecar_json(&long, "[1, 1, 1]", "{}").as_bytes());
        let e = err_of(&p);
        assert!(matches!(e, LoadError::InvalidField { .. }), "{e:?}");
        assert!(e.to_string().len() < 300, "{e}");
    }

    #[test]
    fn error_bytes_uncompressed_inconsistent() {
        let dir = TempDir::new("bytesmismatch");
        let p = dir.write(
            "b.json",
            sidecar_json(
                "[2, 3, 4]",
                "[1, 1, 1]",
                r#"{"u8": {"file": "b.u8.raw", "bytes_uncompressed": 25}}"#,
            )
            .as_bytes(),
        );
        dir.write("b.u8.raw", &[0; 24]);
        let e = err_of(&p);
        assert!(
            matches!(&e, LoadError::InvalidField { field, .. } if field == "files.u8.bytes_uncompressed"),
            "{e}"
        );
    }

    #[test]
    fn error_absurd_dims() {
        let dir = TempDir::new("absurd");
        for (i, dims) in [
            "[0, 10, 10]",
            "[10, 10, 0]",
            "[4097, 1, 1]",
            "[1, 1, 18446744073709551615]",
            "[4096, 4096, 4096]",
            "[4096, 4096, 129]",
            // Over the core's 2^30 voxels (the loader used to allow 2^31).
            "[4096, 4096, 65]",
        ]
        .iter()
        .enumerate()
        {
            let p = dir.write(
                &format!("a{i}.json"),
                sidecar_json(dims, "[1, 1, 1]", r#"{"u8": {"file": "a.u8.raw"}}"#).as_bytes(),
            );
            let e = err_of(&p);
            assert!(matches!(e, LoadError::AbsurdDims { .. }), "{dims}: {e:?}");
            assert!(e.to_string().contains("dims_xyz"), "{e}");
        }
        // Exactly at the limits is fine as far as dims go (then the data is missing).
        let p = dir.write(
            "limit.json",
            sidecar_json(
                "[4096, 4096, 64]",
                "[1, 1, 1]",
                r#"{"u8": {"file": "a.u8.raw"}}"#,
            )
            .as_bytes(),
        );
        assert!(matches!(err_of(&p), LoadError::Io { .. }));
    }

    #[test]
    fn error_invalid_spacing() {
        let dir = TempDir::new("spacing");
        for (i, s) in ["[0, 1, 1]", "[1, -0.5, 1]", "[1, 1, -0.0]"]
            .iter()
            .enumerate()
        {
            let p = dir.write(
                &format!("s{i}.json"),
                sidecar_json("[1, 1, 1]", s, r#"{"u8": {"file": "s.u8.raw"}}"#).as_bytes(),
            );
            let e = err_of(&p);
            assert!(matches!(e, LoadError::InvalidSpacing { .. }), "{s}: {e:?}");
            assert!(e.to_string().contains("spacing"), "{e}");
        }
    }

    #[test]
    fn error_wrong_size_raw() {
        let dir = TempDir::new("wrongsize");
        let (json, raw) = small_u8(&dir);
        std::fs::write(&raw, [0u8; 23]).unwrap();
        let e = err_of(&json);
        assert!(
            matches!(
                e,
                LoadError::WrongSize {
                    expected: 24,
                    found: 23,
                    exceeded: false,
                    ..
                }
            ),
            "{e:?}"
        );
        let msg = e.to_string();
        assert!(
            msg.contains("expected 24 bytes for 2×3×4 u8, found 23"),
            "{msg}"
        );
        assert!(msg.contains("v.u8.raw"), "{msg}");
        std::fs::write(&raw, [0u8; 25]).unwrap();
        let e = err_of(&raw);
        assert!(matches!(e, LoadError::WrongSize { found: 25, .. }), "{e:?}");
        std::fs::write(&raw, []).unwrap();
        assert!(matches!(
            err_of(&raw),
            LoadError::WrongSize { found: 0, .. }
        ));
    }

    #[test]
    fn error_wrong_size_gzip_and_bomb_is_capped() {
        let dir = TempDir::new("gzsize");
        dir.write(
            "g.json",
            br#"{"dims_xyz": [2, 3, 4], "spacing_mm_xyz": [1, 1, 1]}"#,
        );
        let short = dir.write("g.u8.raw.gz", &gzip(&[0; 10]));
        let e = err_of(&short);
        assert!(
            matches!(
                e,
                LoadError::WrongSize {
                    found: 10,
                    exceeded: false,
                    ..
                }
            ),
            "{e:?}"
        );
        // 64 MiB of zeros compresses to ~64 KiB; only 25 bytes may be decoded.
        let bomb = gzip(&vec![0u8; 64 << 20]);
        assert!(bomb.len() < 1 << 20);
        let p = dir.write("g.u8.raw.gz", &bomb);
        let e = err_of(&p);
        assert!(
            matches!(
                e,
                LoadError::WrongSize {
                    expected: 24,
                    found: 25,
                    exceeded: true,
                    ..
                }
            ),
            "{e:?}"
        );
        assert!(e.to_string().contains("found more than 24"), "{e}");
    }

    #[test]
    fn error_corrupt_gzip() {
        let dir = TempDir::new("corrupt");
        dir.write(
            "c.json",
            br#"{"dims_xyz": [2, 3, 4], "spacing_mm_xyz": [1, 1, 1]}"#,
        );
        let good = gzip(&(0..24).collect::<Vec<u8>>());
        let mut cases: Vec<Vec<u8>> = vec![
            b"definitely not gzip data".to_vec(),
            vec![0x1f, 0x8b],
            good[..good.len() - 4].to_vec(), // truncated trailer
            good[..good.len() / 2].to_vec(), // truncated body
        ];
        let mut bad_crc = good.clone();
        let n = bad_crc.len();
        bad_crc[n - 8] ^= 0xff;
        cases.push(bad_crc);
        let mut bad_body = good.clone();
        bad_body[10] = 0xff;
        bad_body[11] = 0xff;
        cases.push(bad_body);
        for (i, data) in cases.iter().enumerate() {
            let p = dir.write("c.u8.raw.gz", data);
            let e = err_of(&p);
            assert!(
                matches!(e, LoadError::CorruptGzip { .. }),
                "case {i}: expected CorruptGzip, got {e:?}"
            );
            assert!(e.to_string().contains("c.u8.raw.gz"), "{e}");
        }
    }

    #[test]
    fn error_unknown_voxel_type() {
        let dir = TempDir::new("vtype");
        // Listed with an unsupported type.
        let json = dir.write(
            "t.json",
            sidecar_json(
                "[1, 1, 1]",
                "[1, 1, 1]",
                r#"{"f32": {"file": "t.raw", "voxel_type": "f32"}}"#,
            )
            .as_bytes(),
        );
        let data = dir.write("t.raw", &[0; 4]);
        for p in [&json, &data] {
            let e = err_of(p);
            assert!(
                matches!(&e, LoadError::UnknownVoxelType { voxel_type: Some(t), .. } if t == "f32"),
                "{e:?}"
            );
            assert!(e.to_string().contains("\"f32\""), "{e}");
        }
        // Not listed and no suffix to go by.
        dir.write(
            "n.json",
            br#"{"dims_xyz": [1, 1, 1], "spacing_mm_xyz": [1, 1, 1]}"#,
        );
        let p = dir.write("n.raw", &[0]);
        let e = err_of(&p);
        assert!(
            matches!(
                e,
                LoadError::UnknownVoxelType {
                    voxel_type: None,
                    ..
                }
            ),
            "{e:?}"
        );
        assert!(e.to_string().contains("n.raw"), "{e}");
    }

    /// Mangled sidecars and data must produce errors, never panics.
    #[test]
    fn mangled_inputs_never_panic() {
        let dir = TempDir::new("fuzz");
        let base = sidecar_json(
            "[2, 3, 4]",
            "[1.0, 0.5, 2.0]",
            r#"{"u8": {"file": "z.u8.raw.gz", "voxel_type": "u8", "bytes_uncompressed": 24}}"#,
        )
        .into_bytes();
        let good_gz = gzip(&(0..24).collect::<Vec<u8>>());
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        let alphabet = b"{}[]\":,-0123456789.eE ufilesdimsxyz\\\x00\xff";
        for _ in 0..400 {
            let mut json = base.clone();
            for _ in 0..(next() % 4 + 1) {
                let i = (next() as usize) % json.len();
                json[i] = alphabet[(next() as usize) % alphabet.len()];
            }
            let mut gz = good_gz.clone();
            if next() % 2 == 0 {
                let i = (next() as usize) % gz.len();
                gz[i] = next() as u8;
            }
            let json_path = dir.write("z.json", &json);
            let gz_path = dir.write("z.u8.raw.gz", &gz);
            let _ = load_volume(&json_path).map_err(|e| e.to_string());
            let _ = load_volume_with(&gz_path, Prefer::U16).map_err(|e| e.to_string());
        }
    }
}
