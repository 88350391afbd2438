//! VolPack's `.den` density files (the `brainsmall.den` of VolPack's examples).
//!
//! Layout (62-byte header, then the voxels):
//!
//! | offset | type | field |
//! |---|---|---|
//! | 0 | i16 | `map_version`, 1 (read byte-swapped as 0x0100 when the file was written on a machine of the other byte order) |
//! | 2 | 9 × 3 i16 | `orig_min`, `orig_max`, `orig_len`, `extr_min`, `extr_max`, `extr_len`, `map_min`, `map_max`, `map_len` (x, y, z each) |
//! | 56 | i16 | `map_warps` |
//! | 58 | i32 | `map_length` = product of `map_len` |
//! | 62 | u8 × `map_length` | densities, x fastest, then y, then z |
//!
//! Only `map_len` and `map_length` matter for rendering; the other fields describe how the
//! map was extracted from an original scan. The format records no voxel spacing, so the
//! spacing is 1 mm along every axis, and no orientation. Bytes after the voxels are
//! ignored (VolPack writes none).

use super::{bad, VolumeMeta};
use crate::volume::{check_dims, LoadError, RawVolume, Voxels};
use std::io::Read;
use std::path::Path;

/// Header size in bytes.
pub const HEADER_BYTES: usize = 62;

/// A density volume as the file holds it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Den {
    /// `map_len`: voxels along x, y, z.
    pub dims: [usize; 3],
    /// Densities, x fastest.
    pub data: Vec<u8>,
}

/// Parsed header: byte order and dims (checked against the loader limits).
fn header(path: &Path, h: &[u8]) -> Result<[usize; 3], LoadError> {
    if h.len() < HEADER_BYTES {
        return Err(bad(
            path,
            format!(
                "truncated .den header: {} bytes, the header has {HEADER_BYTES}",
                h.len()
            ),
        ));
    }
    let big_endian = match u16::from_le_bytes([h[0], h[1]]) {
        1 => false,
        0x0100 => true,
        v => {
            return Err(bad(
                path,
                format!("not a VolPack .den file (version field {v:#06x}, expected 1)"),
            ))
        }
    };
    let i16_at = |off: usize| {
        let b = [h[off], h[off + 1]];
        if big_endian {
            i16::from_be_bytes(b)
        } else {
            i16::from_le_bytes(b)
        }
    };
    // map_len is the ninth triple of shorts after the version.
    let len_off = 2 + 8 * 6;
    let d = [i16_at(len_off), i16_at(len_off + 2), i16_at(len_off + 4)];
    let dims = super::dims_from(path, d.map(i64::from))?;
    let l = [h[58], h[59], h[60], h[61]];
    let map_length = if big_endian {
        i32::from_be_bytes(l)
    } else {
        i32::from_le_bytes(l)
    };
    let count = dims[0] * dims[1] * dims[2];
    if usize::try_from(map_length).ok() != Some(count) {
        return Err(bad(
            path,
            format!(
                "inconsistent .den header: map_length {map_length} does not match map_len \
                 {}×{}×{}",
                dims[0], dims[1], dims[2]
            ),
        ));
    }
    Ok(dims)
}

/// Parses a whole `.den` file held in memory; `path` only names it in errors.
pub fn parse(path: &Path, bytes: &[u8]) -> Result<Den, LoadError> {
    let dims = header(path, bytes)?;
    let count = dims[0] * dims[1] * dims[2];
    let body = &bytes[HEADER_BYTES.min(bytes.len())..];
    if body.len() < count {
        return Err(truncated(path, dims, body.len()));
    }
    Ok(Den {
        dims,
        data: body[..count].to_vec(),
    })
}

fn truncated(path: &Path, dims: [usize; 3], found: usize) -> LoadError {
    bad(
        path,
        format!(
            "truncated voxel data: expected {} bytes for {}×{}×{} u8, found {found}",
            dims[0] * dims[1] * dims[2],
            dims[0],
            dims[1],
            dims[2]
        ),
    )
}

/// Reads a `.den` file: the header first, then exactly the voxels it announces (so an
/// absurd header is refused before any voxel is read).
pub fn read(path: &Path) -> Result<Den, LoadError> {
    let io = |source| LoadError::Io {
        path: path.to_path_buf(),
        source,
    };
    let mut f = std::fs::File::open(path).map_err(io)?;
    let mut h = Vec::with_capacity(HEADER_BYTES);
    (&mut f)
        .take(HEADER_BYTES as u64)
        .read_to_end(&mut h)
        .map_err(io)?;
    let dims = header(path, &h)?;
    let count = dims[0] * dims[1] * dims[2];
    let data = super::read_capped(path, f, count as u64)?;
    if data.len() < count {
        return Err(truncated(path, dims, data.len()));
    }
    Ok(Den { dims, data })
}

/// Loads a `.den` file as a volume (u8, spacing 1 mm).
pub fn load(path: &Path) -> Result<(RawVolume, VolumeMeta), LoadError> {
    let d = read(path)?;
    let vol = RawVolume {
        name: super::stem_of(path, &[".den"]),
        dims: d.dims,
        spacing: [1.0; 3],
        voxels: Voxels::U8(d.data),
    };
    Ok((vol, VolumeMeta::identity("den", "u8")))
}

/// Writes a `.den` file (little-endian; the original and extracted maps equal the map),
/// for tests and conversions.
pub fn write(path: &Path, dims: [usize; 3], data: &[u8]) -> Result<(), LoadError> {
    let d = check_dims(path, dims.map(|x| x as u64))?;
    let count = d[0] * d[1] * d[2];
    if d.iter().any(|&x| x > i16::MAX as usize) || data.len() != count {
        return Err(bad(path, "cannot write: dims or data length out of range"));
    }
    let [x, y, z] = d.map(|v| v as i16);
    let mut shorts: Vec<i16> = vec![1];
    for _ in 0..3 {
        shorts.extend([0, 0, 0, x - 1, y - 1, z - 1, x, y, z]);
    }
    shorts.push(0); // map_warps
    let mut out: Vec<u8> = shorts.iter().flat_map(|s| s.to_le_bytes()).collect();
    out.extend((count as i32).to_le_bytes());
    out.extend_from_slice(data);
    std::fs::write(path, out).map_err(|source| LoadError::Io {
        path: path.to_path_buf(),
        source,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn header_bytes(dims: [i16; 3], big_endian: bool, length: i32) -> Vec<u8> {
        let mut shorts: Vec<i16> = vec![1];
        let [x, y, z] = dims;
        for _ in 0..3 {
            shorts.extend([0, 0, 0, x - 1, y - 1, z - 1, x, y, z]);
        }
        shorts.push(0);
        let mut out = Vec::new();
        for s in shorts {
            out.extend(if big_endian {
                s.to_be_bytes()
            } else {
                s.to_le_bytes()
            });
        }
        out.extend(if big_endian {
            length.to_be_bytes()
        } else {
            length.to_le_bytes()
        });
        assert_eq!(out.len(), HEADER_BYTES);
        out
    }

    fn p() -> &'static Path {
        Path::new("x.den")
    }

    #[test]
    fn reads_both_byte_orders() {
        for be in [false, true] {
            let mut f = header_bytes([3, 2, 2], be, 12);
            f.extend(0..12u8);
            f.extend([9, 9]); // trailing bytes are ignored
            let d = parse(p(), &f).unwrap();
            assert_eq!(d.dims, [3, 2, 2]);
            assert_eq!(d.data, (0..12).collect::<Vec<u8>>());
        }
    }

    #[test]
    fn rejects_malformed_files() {
        let msg = |b: &[u8]| parse(p(), b).unwrap_err().to_string();
        assert!(msg(&[1, 0, 0]).contains("truncated .den header"));
        let mut f = header_bytes([3, 2, 2], false, 12);
        f[0] = 7;
        f.extend([0; 12]);
        assert!(msg(&f).contains("version field 0x0007"), "{}", msg(&f));
        let mut f = header_bytes([3, 2, 2], false, 13);
        f.extend([0; 13]);
        assert!(msg(&f).contains("map_length 13"), "{}", msg(&f));
        let mut f = header_bytes([3, 0, 2], false, 0);
        f.extend([0; 4]);
        assert!(msg(&f).contains("at least 1"), "{}", msg(&f));
        let mut f = header_bytes([3, -2, 2], false, -12);
        f.extend([0; 4]);
        assert!(msg(&f).contains("negative"), "{}", msg(&f));
        let mut f = header_bytes([3, 2, 2], false, 12);
        f.extend([0; 11]);
        assert!(
            msg(&f).contains("expected 12 bytes for 3×2×2 u8, found 11"),
            "{}",
            msg(&f)
        );
        for e in [msg(&[1, 0, 0]), msg(&f)] {
            assert!(e.starts_with("x.den: "), "{e}");
        }
    }

    #[test]
    fn write_then_load_round_trips() {
        let dir = std::env::temp_dir().join(format!("swden-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("t.den");
        let data: Vec<u8> = (0..60).map(|i| (i * 7) as u8).collect();
        write(&path, [5, 4, 3], &data).unwrap();
        let (v, meta) = load(&path).unwrap();
        assert_eq!((v.dims, v.spacing), ([5, 4, 3], [1.0; 3]));
        assert_eq!(v.voxels, Voxels::U8(data));
        assert_eq!(v.name, "t");
        assert_eq!(meta.format, "den");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// Mangled headers and bodies give errors or volumes, never panics.
    #[test]
    fn mangled_files_never_panic() {
        let mut good = header_bytes([4, 3, 2], false, 24);
        good.extend(0..24u8);
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        for _ in 0..2000 {
            let mut b = good.clone();
            for _ in 0..(next() % 4 + 1) {
                let i = (next() as usize) % b.len();
                b[i] = next() as u8;
            }
            b.truncate((next() as usize) % (b.len() + 1));
            if let Ok(d) = parse(p(), &b) {
                assert_eq!(d.data.len(), d.dims.iter().product::<usize>());
            }
        }
    }

    /// The real file, when VolPack's examples are installed.
    #[test]
    fn brainsmall_if_installed() {
        let p = Path::new("/usr/share/doc/libvolpack1-dev/examples/brainsmall.den");
        if !p.is_file() {
            return;
        }
        let d = read(p).unwrap();
        assert_eq!(d.dims, [128, 128, 84]);
        assert_eq!(d.data.len(), 128 * 128 * 84);
    }
}
