//! Reader for the `.den` density files of VolPack's example programs (`brainsmall.den`).
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
//! map was extracted from an original scan. The format records no voxel spacing.

use std::fmt;
use std::path::Path;

/// Header size in bytes.
pub const HEADER_BYTES: usize = 62;
/// Largest accepted extent along an axis.
const MAX_DIM: usize = 4096;

/// A density volume.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Den {
    /// `map_len`: voxels along x, y, z.
    pub dims: [usize; 3],
    /// Densities, x fastest.
    pub data: Vec<u8>,
}

/// Why a `.den` file was rejected.
#[derive(Debug)]
pub enum DenError {
    Io(std::io::Error),
    TooShort { len: usize },
    BadVersion(u16),
    BadDims([i16; 3]),
    Inconsistent { dims: [usize; 3], map_length: i32 },
    Truncated { expected: usize, got: usize },
}

impl fmt::Display for DenError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            DenError::Io(e) => write!(f, "cannot read: {e}"),
            DenError::TooShort { len } => {
                write!(
                    f,
                    "{len} bytes is shorter than the {HEADER_BYTES}-byte header"
                )
            }
            DenError::BadVersion(v) => write!(f, "not a .den file (version field {v:#06x})"),
            DenError::BadDims(d) => write!(f, "bad dimensions {d:?}"),
            DenError::Inconsistent { dims, map_length } => write!(
                f,
                "header length {map_length} does not match dimensions {}x{}x{}",
                dims[0], dims[1], dims[2]
            ),
            DenError::Truncated { expected, got } => {
                write!(f, "expected {expected} voxel bytes, found {got}")
            }
        }
    }
}

impl std::error::Error for DenError {}

/// Parses a whole `.den` file held in memory.
pub fn parse(bytes: &[u8]) -> Result<Den, DenError> {
    if bytes.len() < HEADER_BYTES {
        return Err(DenError::TooShort { len: bytes.len() });
    }
    let version = u16::from_le_bytes([bytes[0], bytes[1]]);
    let big_endian = match version {
        1 => false,
        0x0100 => true,
        v => return Err(DenError::BadVersion(v)),
    };
    let i16_at = |off: usize| {
        let b = [bytes[off], bytes[off + 1]];
        if big_endian {
            i16::from_be_bytes(b)
        } else {
            i16::from_le_bytes(b)
        }
    };
    // map_len is the ninth triple of shorts after the version.
    let len_off = 2 + 8 * 6;
    let raw_dims = [i16_at(len_off), i16_at(len_off + 2), i16_at(len_off + 4)];
    if raw_dims.iter().any(|&d| d < 1 || d as usize > MAX_DIM) {
        return Err(DenError::BadDims(raw_dims));
    }
    let dims = raw_dims.map(|d| d as usize);
    let l = [bytes[58], bytes[59], bytes[60], bytes[61]];
    let map_length = if big_endian {
        i32::from_be_bytes(l)
    } else {
        i32::from_le_bytes(l)
    };
    let count = dims[0] * dims[1] * dims[2];
    if usize::try_from(map_length).ok() != Some(count) {
        return Err(DenError::Inconsistent { dims, map_length });
    }
    let body = &bytes[HEADER_BYTES..];
    if body.len() < count {
        return Err(DenError::Truncated {
            expected: count,
            got: body.len(),
        });
    }
    Ok(Den {
        dims,
        data: body[..count].to_vec(),
    })
}

/// Reads a `.den` file.
pub fn read(path: &Path) -> Result<Den, DenError> {
    parse(&std::fs::read(path).map_err(DenError::Io)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn header(dims: [i16; 3], big_endian: bool, length: i32) -> Vec<u8> {
        let mut shorts: Vec<i16> = vec![1];
        let [x, y, z] = dims;
        // orig, extr and map triples: min, max, len each.
        for _ in 0..3 {
            shorts.extend([0, 0, 0, x - 1, y - 1, z - 1, x, y, z]);
        }
        shorts.push(0); // warps
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

    #[test]
    fn reads_both_byte_orders() {
        for be in [false, true] {
            let mut f = header([3, 2, 2], be, 12);
            f.extend(0..12u8);
            let d = parse(&f).unwrap();
            assert_eq!(d.dims, [3, 2, 2]);
            assert_eq!(d.data, (0..12).collect::<Vec<u8>>());
        }
    }

    #[test]
    fn rejects_malformed_files() {
        assert!(matches!(
            parse(&[1, 0, 0]),
            Err(DenError::TooShort { len: 3 })
        ));
        let mut f = header([3, 2, 2], false, 12);
        f[0] = 7;
        f.extend([0; 12]);
        assert!(matches!(parse(&f), Err(DenError::BadVersion(7))));
        let mut f = header([3, 2, 2], false, 13);
        f.extend([0; 13]);
        assert!(matches!(parse(&f), Err(DenError::Inconsistent { .. })));
        let mut f = header([3, 0, 2], false, 0);
        f.extend([0; 4]);
        assert!(matches!(parse(&f), Err(DenError::BadDims(_))));
        let mut f = header([3, 2, 2], false, 12);
        f.extend([0; 11]);
        assert!(matches!(
            parse(&f),
            Err(DenError::Truncated {
                expected: 12,
                got: 11
            })
        ));
    }

    /// The real file, when VolPack's examples are installed.
    #[test]
    fn brainsmall_if_installed() {
        let p = Path::new(crate::scenes::BRAINSMALL_DEFAULT);
        if !p.is_file() {
            return;
        }
        let d = read(p).unwrap();
        assert_eq!(d.dims, [128, 128, 84]);
        assert_eq!(d.data.len(), 128 * 128 * 84);
    }
}
