//! MetaImage: `.mhd` with a separate data file, or `.mha` with `ElementDataFile = LOCAL`.
//! 3-D, one channel, raw or zlib-compressed (`CompressedData = True`), either byte
//! order. Spacing is `ElementSpacing` (else `ElementSize`); `TransformMatrix` (row `a` =
//! direction of index axis `a`, in ITK's LPS world) reorders the axes toward LPS.

use super::{bad, check_spacing, dims_from, floats, orient_lps, read_capped, stem_of};
use super::{read_raw_block, volume_from_bytes, DataType, VolumeMeta};
use crate::volume::{LoadError, RawVolume};
use flate2::bufread::ZlibDecoder;
use std::io::{BufRead, BufReader, Read};
use std::path::Path;

const MAX_HEADER: u64 = 1 << 20;

/// Loads a MetaImage volume.
pub fn load(path: &Path) -> Result<(RawVolume, VolumeMeta), LoadError> {
    let io = |p: &Path, source| LoadError::Io {
        path: p.to_path_buf(),
        source,
    };
    let f = std::fs::File::open(path).map_err(|e| io(path, e))?;
    let mut r = BufReader::new(f);
    let mut fields: Vec<(String, String)> = Vec::new();
    let mut header_len = 0u64;
    loop {
        let mut line = Vec::new();
        let n = (&mut r)
            .take(MAX_HEADER)
            .read_until(b'\n', &mut line)
            .map_err(|e| io(path, e))?;
        header_len += n as u64;
        if header_len > MAX_HEADER {
            return Err(bad(path, "MetaImage header too long"));
        }
        if n == 0 {
            break;
        }
        let text = String::from_utf8_lossy(&line);
        let text = text.trim();
        if text.is_empty() {
            continue;
        }
        let Some((k, v)) = text.split_once('=') else {
            return Err(bad(
                path,
                format!("malformed MetaImage header line \"{text}\""),
            ));
        };
        let k = k.trim().to_string();
        let v = v.trim().to_string();
        let last = k.eq_ignore_ascii_case("ElementDataFile");
        fields.push((k, v));
        if last {
            break;
        }
    }
    let get = |k: &str| {
        fields
            .iter()
            .find(|(f, _)| f.eq_ignore_ascii_case(k))
            .map(|(_, v)| v.as_str())
    };
    let need =
        |k: &str| get(k).ok_or_else(|| bad(path, format!("MetaImage header has no \"{k}\"")));
    let truthy = |k: &str| get(k).is_some_and(|v| v.eq_ignore_ascii_case("true"));

    let ndims: usize = need("NDims")?
        .parse()
        .map_err(|_| bad(path, "invalid NDims"))?;
    if ndims != 3 {
        return Err(bad(
            path,
            format!("NDims = {ndims}: only 3-D volumes are supported"),
        ));
    }
    if let Some(c) = get("ElementNumberOfChannels") {
        if c.trim() != "1" {
            return Err(bad(
                path,
                format!("{c} channels: only scalar volumes are supported"),
            ));
        }
    }
    let ds = floats(need("DimSize")?)
        .filter(|v| v.len() == 3 && v.iter().all(|x| x.fract() == 0.0 && x.abs() < 1e15))
        .ok_or_else(|| bad(path, "invalid DimSize"))?;
    let dims = dims_from(path, [ds[0] as i64, ds[1] as i64, ds[2] as i64])?;
    let sp = match get("ElementSpacing").or(get("ElementSize")) {
        Some(s) => floats(s)
            .filter(|v| v.len() == 3)
            .ok_or_else(|| bad(path, format!("invalid ElementSpacing \"{s}\"")))?,
        None => vec![1.0; 3],
    };
    let spacing = check_spacing(path, [sp[0].abs(), sp[1].abs(), sp[2].abs()])?;
    let et = need("ElementType")?;
    let dt = match et.to_ascii_uppercase().as_str() {
        "MET_UCHAR" => DataType::U8,
        "MET_CHAR" => DataType::I8,
        "MET_USHORT" => DataType::U16,
        "MET_SHORT" => DataType::I16,
        "MET_UINT" | "MET_ULONG" => DataType::U32,
        "MET_INT" | "MET_LONG" => DataType::I32,
        "MET_FLOAT" => DataType::F32,
        "MET_DOUBLE" => DataType::F64,
        _ => return Err(bad(path, format!("unsupported ElementType \"{et}\""))),
    };
    let big = truthy("BinaryDataByteOrderMSB") || truthy("ElementByteOrderMSB");
    let compressed = truthy("CompressedData");
    let dirs = match get("TransformMatrix")
        .or(get("Orientation"))
        .or(get("Rotation"))
    {
        Some(s) => {
            let m = floats(s)
                .filter(|v| v.len() == 9)
                .ok_or_else(|| bad(path, format!("invalid TransformMatrix \"{s}\"")))?;
            Some(std::array::from_fn(|a| {
                [m[3 * a], m[3 * a + 1], m[3 * a + 2]]
            }))
        }
        None => None,
    };
    let header_size: i64 = get("HeaderSize")
        .map(|v| v.parse().map_err(|_| bad(path, "invalid HeaderSize")))
        .transpose()?
        .unwrap_or(0);

    let count = (dims[0] * dims[1] * dims[2]) as u64;
    let need_bytes = count * dt.bytes() as u64;
    let df = need("ElementDataFile")?;
    let (data_path, reader): (std::path::PathBuf, Box<dyn BufRead>) =
        if df.eq_ignore_ascii_case("LOCAL") {
            (path.to_path_buf(), Box::new(r))
        } else {
            if df.starts_with("LIST") || df.contains('%') || df.split_whitespace().count() > 1 {
                return Err(bad(
                    path,
                    "MetaImage data split over several files is not supported",
                ));
            }
            drop(r);
            let p = match path.parent() {
                Some(dir) => dir.join(df),
                None => df.into(),
            };
            let f = std::fs::File::open(&p).map_err(|e| io(&p, e))?;
            (p, Box::new(BufReader::new(f)))
        };
    let data = if compressed {
        read_capped(&data_path, ZlibDecoder::new(reader), need_bytes)?
    } else {
        read_raw_block(&data_path, reader, header_size, need_bytes)?
    };
    let name = stem_of(path, &[".mhd", ".mha"]);
    let (vol, slope, intercept) =
        volume_from_bytes(&data_path, data, need_bytes, dims, dt, big, spacing, name)?;
    let (vol, orientation) = match dirs {
        Some(d) => orient_lps(vol, d),
        None => (vol, String::new()),
    };
    let modality = get("Modality").map(|m| m.trim_start_matches("MET_MOD_").to_string());
    Ok((
        vol,
        VolumeMeta {
            format: "metaimage",
            source_type: dt.name().into(),
            slope,
            intercept,
            units: (modality.as_deref() == Some("CT")).then(|| "HU".into()),
            modality,
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
        std::env::temp_dir().join(format!("shearwarp-mhd-{}-{name}", std::process::id()))
    }

    #[test]
    fn detached_local_compressed_and_errors() {
        let data: Vec<u8> = (0..24i16).flat_map(|v| (v - 1000).to_le_bytes()).collect();
        let raw = tmp("a.raw");
        std::fs::write(&raw, &data).unwrap();
        let p = tmp("a.mhd");
        let raw_name = raw.file_name().unwrap().to_string_lossy().into_owned();
        std::fs::write(
            &p,
            format!(
                "ObjectType = Image\nNDims = 3\nDimSize = 2 3 4\nElementSpacing = 0.5 1 2\n\
                 TransformMatrix = 1 0 0 0 1 0 0 0 1\nModality = MET_MOD_CT\n\
                 ElementType = MET_SHORT\nElementDataFile = {raw_name}\n"
            ),
        )
        .unwrap();
        let (v, m) = load(&p).unwrap();
        assert_eq!(v.spacing, [0.5, 1.0, 2.0]);
        assert_eq!(v.voxels, Voxels::U16((0..24).collect()));
        assert_eq!((m.intercept, m.units.as_deref()), (-1000.0, Some("HU")));

        // .mha with zlib-compressed local data.
        let mut e = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::fast());
        e.write_all(&data).unwrap();
        let mut f = b"NDims = 3\nDimSize = 2 3 4\nElementType = MET_SHORT\nCompressedData = True\nElementDataFile = LOCAL\n".to_vec();
        f.extend_from_slice(&e.finish().unwrap());
        let mha = tmp("b.mha");
        std::fs::write(&mha, &f).unwrap();
        assert_eq!(load(&mha).unwrap().0.voxels, v.voxels);

        std::fs::write(&raw, &data[..40]).unwrap();
        let e = load(&p).unwrap_err().to_string();
        assert!(e.contains("a.raw") && e.contains("truncated"), "{e}");
        std::fs::write(&p, "NDims = 2\nDimSize = 2 3\n").unwrap();
        assert!(load(&p).unwrap_err().to_string().contains("only 3-D"));
        std::fs::write(
            &p,
            "NDims = 3\nDimSize = 2 3 4\nElementType = MET_FLOAT_ARRAY\nElementDataFile = x\n",
        )
        .unwrap();
        assert!(load(&p)
            .unwrap_err()
            .to_string()
            .contains("unsupported ElementType"));
        for f in [&p, &raw, &mha] {
            let _ = std::fs::remove_file(f);
        }
    }
}
