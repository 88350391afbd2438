//! NRRD (`.nrrd` with attached data, `.nhdr` with a detached `data file`), encodings
//! `raw` and `gzip`, either byte order, 3-D scalar data (a leading axis of size 1 is
//! dropped). Spacing comes from `spacings`, or from the lengths of `space directions`;
//! with `space directions` in a `space` of LPS or RAS the axes are reordered toward LPS.

use super::{bad, check_spacing, dims_from, orient_lps, read_capped, read_raw_block};
use super::{skip_bytes, stem_of};
use super::{volume_from_bytes, DataType, VolumeMeta};
use crate::volume::{LoadError, RawVolume};
use flate2::bufread::MultiGzDecoder;
use std::io::{BufRead, BufReader, Read};
use std::path::Path;

const MAX_HEADER: u64 = 1 << 20;

fn dtype(t: &str) -> Option<DataType> {
    Some(match t {
        "uchar" | "unsigned char" | "uint8" | "uint8_t" => DataType::U8,
        "signed char" | "int8" | "int8_t" => DataType::I8,
        "short" | "short int" | "signed short" | "signed short int" | "int16" | "int16_t" => {
            DataType::I16
        }
        "ushort" | "unsigned short" | "unsigned short int" | "uint16" | "uint16_t" => DataType::U16,
        "int" | "signed int" | "int32" | "int32_t" => DataType::I32,
        "uint" | "unsigned int" | "uint32" | "uint32_t" => DataType::U32,
        "float" => DataType::F32,
        "double" => DataType::F64,
        _ => return None,
    })
}

/// Parses `(a,b,c) (d,e,f) none ...` into vectors (`None` for `none`).
fn vectors(path: &Path, v: &str) -> Result<Vec<Option<[f64; 3]>>, LoadError> {
    let mut out = Vec::new();
    let mut rest = v.trim();
    while !rest.is_empty() {
        if let Some(r) = rest.strip_prefix("none") {
            out.push(None);
            rest = r.trim_start();
            continue;
        }
        let (Some(0), Some(end)) = (rest.find('('), rest.find(')')) else {
            return Err(bad(path, format!("invalid space directions \"{v}\"")));
        };
        let nums = super::floats(&rest[1..end])
            .filter(|n| n.len() == 3)
            .ok_or_else(|| bad(path, format!("invalid space directions \"{v}\"")))?;
        out.push(Some([nums[0], nums[1], nums[2]]));
        rest = rest[end + 1..].trim_start();
    }
    Ok(out)
}

/// Loads an NRRD volume.
pub fn load(path: &Path) -> Result<(RawVolume, VolumeMeta), LoadError> {
    let io = |p: &Path, source| LoadError::Io {
        path: p.to_path_buf(),
        source,
    };
    let f = std::fs::File::open(path).map_err(|e| io(path, e))?;
    let mut r = BufReader::new(f);
    let mut fields: Vec<(String, String)> = Vec::new();
    let mut first = true;
    let mut header_len = 0u64;
    loop {
        let mut line = Vec::new();
        let n = (&mut r)
            .take(MAX_HEADER)
            .read_until(b'\n', &mut line)
            .map_err(|e| io(path, e))?;
        header_len += n as u64;
        if header_len > MAX_HEADER {
            return Err(bad(path, "NRRD header too long"));
        }
        let line = String::from_utf8_lossy(&line);
        let line = line.trim_end_matches(['\n', '\r']);
        if first {
            if !line.starts_with("NRRD000") {
                return Err(bad(path, "not a NRRD file (no NRRD000X magic)"));
            }
            first = false;
            continue;
        }
        if n == 0 || line.is_empty() {
            break;
        }
        if line.starts_with('#') || line.contains(":=") {
            continue;
        }
        let Some((k, v)) = line.split_once(": ") else {
            return Err(bad(path, format!("malformed NRRD header line \"{line}\"")));
        };
        fields.push((k.trim().to_ascii_lowercase(), v.trim().to_string()));
    }
    let get = |k: &str| fields.iter().find(|(f, _)| f == k).map(|(_, v)| v.as_str());
    let need = |k: &str| get(k).ok_or_else(|| bad(path, format!("NRRD header has no \"{k}\"")));

    let t = need("type")?;
    let dt = dtype(t).ok_or_else(|| bad(path, format!("unsupported NRRD type \"{t}\"")))?;
    let ndim: usize = need("dimension")?
        .parse()
        .map_err(|_| bad(path, "invalid NRRD dimension"))?;
    let sizes: Vec<i64> = need("sizes")?
        .split_whitespace()
        .map(|s| s.parse().ok())
        .collect::<Option<_>>()
        .filter(|v: &Vec<i64>| v.len() == ndim)
        .ok_or_else(|| bad(path, "invalid NRRD sizes"))?;
    // Drop a leading axis of size 1 (e.g. a 1-component "vector" axis).
    let skip = match (ndim, sizes.first()) {
        (3, _) => 0,
        (4, Some(1)) => 1,
        _ => {
            return Err(bad(
                path,
                format!("{ndim}-dimensional NRRD with sizes {sizes:?}: only 3-D scalar volumes are supported"),
            ))
        }
    };
    let dims = dims_from(path, [sizes[skip], sizes[skip + 1], sizes[skip + 2]])?;

    // Directions and spacing.
    let dirs = get("space directions")
        .map(|v| vectors(path, v))
        .transpose()?
        .map(|v| v.into_iter().skip(skip).collect::<Vec<_>>());
    let space = get("space").map(|s| s.to_ascii_lowercase());
    let mut spacing = [1.0; 3];
    let mut lps_dirs = None;
    if let Some(d) = dirs
        .as_ref()
        .filter(|d| d.len() == 3 && d.iter().all(Option::is_some))
    {
        let d: Vec<[f64; 3]> = d.iter().flatten().copied().collect();
        for a in 0..3 {
            spacing[a] = (d[a][0].powi(2) + d[a][1].powi(2) + d[a][2].powi(2)).sqrt();
        }
        let sign = match space.as_deref() {
            Some("left-posterior-superior" | "lps" | "scanner-xyz") => Some([1.0, 1.0, 1.0]),
            Some("right-anterior-superior" | "ras") => Some([-1.0, -1.0, 1.0]),
            Some("left-anterior-superior" | "las") => Some([1.0, -1.0, 1.0]),
            _ => None,
        };
        if let Some(sg) = sign {
            lps_dirs = Some(std::array::from_fn(|a| {
                std::array::from_fn(|k| d[a][k] * sg[k] / spacing[a].max(1e-30))
            }));
        }
    } else if let Some(s) = get("spacings") {
        let v: Vec<f64> = s
            .split_whitespace()
            .map(|t| {
                if t == "nan" || t == "NaN" {
                    Some(1.0)
                } else {
                    t.parse().ok()
                }
            })
            .collect::<Option<_>>()
            .filter(|v: &Vec<f64>| v.len() == ndim)
            .ok_or_else(|| bad(path, format!("invalid NRRD spacings \"{s}\"")))?;
        spacing = [v[skip].abs(), v[skip + 1].abs(), v[skip + 2].abs()];
    }
    let spacing = check_spacing(path, spacing)?;

    let big = match get("endian") {
        Some("big") => true,
        Some("little") | None => false,
        Some(e) => return Err(bad(path, format!("invalid NRRD endian \"{e}\""))),
    };
    let gzip = match need("encoding")? {
        "raw" => false,
        "gzip" | "gz" => true,
        e => {
            return Err(bad(
                path,
                format!("unsupported NRRD encoding \"{e}\" (raw and gzip are read)"),
            ))
        }
    };
    let line_skip: u64 = get("line skip")
        .or(get("lineskip"))
        .map(|v| v.parse().map_err(|_| bad(path, "invalid line skip")))
        .transpose()?
        .unwrap_or(0);
    let byte_skip: i64 = get("byte skip")
        .or(get("byteskip"))
        .map(|v| v.parse().map_err(|_| bad(path, "invalid byte skip")))
        .transpose()?
        .unwrap_or(0);

    let count = (dims[0] * dims[1] * dims[2]) as u64;
    let need_bytes = count * dt.bytes() as u64;
    let data_file = get("data file").or(get("datafile"));
    let (data_path, mut reader): (std::path::PathBuf, Box<dyn BufRead>) = match data_file {
        None => (path.to_path_buf(), Box::new(r)),
        Some(df) => {
            if df.starts_with("LIST") || df.split_whitespace().count() > 1 {
                return Err(bad(
                    path,
                    "NRRD data split over several files is not supported",
                ));
            }
            let p = match path.parent() {
                Some(dir) => dir.join(df),
                None => df.into(),
            };
            let f = std::fs::File::open(&p).map_err(|e| io(&p, e))?;
            (p, Box::new(BufReader::new(f)))
        }
    };
    // Stop at the end of the data: a skip of 10^18 lines must not spin through them.
    for skipped in 0..line_skip {
        let mut l = Vec::new();
        let n = (&mut reader)
            .take(MAX_HEADER)
            .read_until(b'\n', &mut l)
            .map_err(|e| io(&data_path, e))?;
        if n == 0 {
            return Err(bad(
                path,
                format!("line skip {line_skip} runs past the end of the data ({skipped} lines)"),
            ));
        }
    }
    let data = if gzip {
        // The byte skip counts decompressed bytes: stream past them rather than hold
        // them (a small file can decompress to gigabytes).
        let mut d = MultiGzDecoder::new(reader);
        skip_bytes(&data_path, &mut d, byte_skip.max(0) as u64)?;
        read_capped(&data_path, d, need_bytes)?
    } else {
        read_raw_block(&data_path, reader, byte_skip, need_bytes)?
    };
    let name = stem_of(path, &[".nrrd", ".nhdr"]);
    let (vol, slope, intercept) =
        volume_from_bytes(&data_path, data, need_bytes, dims, dt, big, spacing, name)?;
    let (vol, orientation) = match lps_dirs {
        Some(d) => orient_lps(vol, d),
        None => (vol, String::new()),
    };
    Ok((
        vol,
        VolumeMeta {
            format: "nrrd",
            source_type: dt.name().into(),
            slope,
            intercept,
            modality: None,
            units: None,
            orientation,
        },
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::volume::Voxels;
    use std::io::Write;

    fn tmp(name: &str) -> std::path::PathBuf {
        std::env::temp_dir().join(format!("shearwarp-nrrd-{}-{name}", std::process::id()))
    }

    #[test]
    fn attached_detached_gzip_and_orientation() {
        let data: Vec<u8> = (0..24u16).flat_map(|v| v.to_be_bytes()).collect();
        let hdr = "NRRD0004\n# comment\ntype: unsigned short\ndimension: 3\nsizes: 2 3 4\n\
                   endian: big\nencoding: raw\nspace: right-anterior-superior\n\
                   space directions: (0.5,0,0) (0,1,0) (0,0,2)\nkey:=value\n\n";
        let p = tmp("a.nrrd");
        let mut f = hdr.as_bytes().to_vec();
        f.extend_from_slice(&data);
        std::fs::write(&p, &f).unwrap();
        let (v, m) = load(&p).unwrap();
        assert_eq!(v.dims, [2, 3, 4]);
        assert_eq!(v.spacing, [0.5, 1.0, 2.0]);
        assert_eq!(m.orientation, "x flipped, y flipped");
        let Voxels::U16(d) = &v.voxels else { panic!() };
        assert_eq!(d[0], 5); // input (1, 2, 0)

        // Detached + gzip.
        let hd = tmp("b.nhdr");
        let raw_name = format!("shearwarp-nrrd-{}-b.raw.gz", std::process::id());
        std::fs::write(
            &hd,
            format!("NRRD0004\ntype: uint16\ndimension: 3\nsizes: 2 3 4\nspacings: 1 2 3\nendian: big\nencoding: gzip\ndata file: {raw_name}\n"),
        )
        .unwrap();
        let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
        e.write_all(&data).unwrap();
        std::fs::write(hd.with_file_name(&raw_name), e.finish().unwrap()).unwrap();
        let (v, _) = load(&hd).unwrap();
        assert_eq!(v.spacing, [1.0, 2.0, 3.0]);
        assert_eq!(v.voxels, Voxels::U16((0..24).collect()));
        // A byte skip counts decompressed bytes; one past the end leaves nothing to read.
        let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
        e.write_all(b"abc").unwrap();
        e.write_all(&data).unwrap();
        std::fs::write(hd.with_file_name(&raw_name), e.finish().unwrap()).unwrap();
        let skipped = |skip: &str| {
            let h = format!("NRRD0004\ntype: uint16\ndimension: 3\nsizes: 2 3 4\nendian: big\nencoding: gzip\nbyte skip: {skip}\ndata file: {raw_name}\n");
            std::fs::write(&hd, h).unwrap();
            load(&hd)
        };
        assert_eq!(
            skipped("3").unwrap().0.voxels,
            Voxels::U16((0..24).collect())
        );
        let e = skipped("4000000000000000000").unwrap_err().to_string();
        assert!(e.contains("truncated"), "{e}");
        // Truncated detached data.
        std::fs::write(hd.with_file_name(&raw_name), b"\x1f\x8b junk").unwrap();
        let e = load(&hd).unwrap_err().to_string();
        assert!(e.contains(&raw_name), "{e}");
        let _ = std::fs::remove_file(hd.with_file_name(&raw_name));
        let e = load(&hd).unwrap_err().to_string();
        assert!(e.contains(&raw_name) && e.contains("not found"), "{e}");

        // Bad headers.
        for (h, want) in [
            (
                "NRRD0004\ntype: complex\ndimension: 3\nsizes: 1 1 1\nencoding: raw\n\n",
                "unsupported NRRD type",
            ),
            (
                "NRRD0004\ntype: uchar\ndimension: 2\nsizes: 1 1\nencoding: raw\n\n",
                "only 3-D",
            ),
            (
                "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 2 2\nencoding: bzip2\n\n",
                "unsupported NRRD encoding",
            ),
            (
                "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 2 2\nencoding: raw\n\nabc",
                "truncated",
            ),
            (
                "NRRD0004\ntype: uchar\ndimension: 3\nencoding: raw\n\n",
                "no \"sizes\"",
            ),
            (
                "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 2 2\nencoding: raw\n\
                 line skip: 4444444444444444213\n\nab\ncd\n",
                "line skip 4444444444444444213 runs past the end of the data (2 lines)",
            ),
            ("hello", "not a NRRD file"),
        ] {
            std::fs::write(&p, h).unwrap();
            let e = load(&p).unwrap_err().to_string();
            assert!(e.contains(want) && e.contains("a.nrrd"), "{h}: {e}");
        }
        let _ = std::fs::remove_file(&p);
        let _ = std::fs::remove_file(&hd);
    }
}
