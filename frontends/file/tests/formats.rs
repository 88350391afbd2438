//! Golden tests of the format readers: each format's copy of a fixture renders
//! identically to the same volume read as raw + JSON; the DICOM series of the shared data
//! set matches its raw conversion; bad inputs exit with code 2 and a one-line error
//! naming the file.

use shearwarp_core::composite::Mode;
use shearwarp_core::shade::Lighting;
use shearwarp_core::view::Camera;
use shearwarp_file::formats::{den, nifti};
use shearwarp_file::renderer::Renderer;
use shearwarp_file::scene::{self, Classification, Look};
use shearwarp_file::volume::{load_volume, load_volume_meta, Prefer, RawVolume, Voxels};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::Command;

fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures")
}

fn dicom_dir() -> Option<PathBuf> {
    let d =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/dicom/mr_pd_brain_series");
    d.is_dir().then_some(d)
}

struct Tmp(PathBuf);

impl Tmp {
    fn new(tag: &str) -> Tmp {
        let d =
            std::env::temp_dir().join(format!("shearwarp-formats-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        Tmp(d)
    }
    fn p(&self, name: &str) -> PathBuf {
        self.0.join(name)
    }
}

impl Drop for Tmp {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn gzip(data: &[u8]) -> Vec<u8> {
    let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
    e.write_all(data).unwrap();
    e.finish().unwrap()
}

fn zlib(data: &[u8]) -> Vec<u8> {
    let mut e = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::fast());
    e.write_all(data).unwrap();
    e.finish().unwrap()
}

/// Renders a shaded three-quarter view.
fn render(v: &RawVolume) -> Vec<[u8; 4]> {
    let range = match &v.voxels {
        Voxels::U8(_) => (0, 255),
        Voxels::U16(d) => (*d.iter().min().unwrap(), *d.iter().max().unwrap()),
    };
    let (lo, hi) = (range.0 as f64, range.1 as f64);
    let class = Classification {
        opacity: vec![(lo + 0.2 * (hi - lo), 0.0), (hi, 0.6)],
        gradient: None,
        min_opacity: 0.02,
        cut: scene::Cut::NONE,
    };
    let enc = scene::encode(v, &class).unwrap();
    let look = Look {
        mode: Mode::Composite,
        color: scene::color_table(&[(lo, [200, 150, 120]), (hi, [255, 255, 240])], range).unwrap(),
        lighting: Some(Lighting::default()),
        ert_threshold: 0.95,
        depth_cue: None,
        shadows: false,
    };
    let cam = Camera {
        rotate_x: -70.0,
        rotate_y: -35.0,
        width: 96,
        height: 96,
    };
    let mut r = Renderer::with_threads(&enc.grid, 1);
    r.render(&mut enc.volume().unwrap(), &cam, &look).unwrap()
}

fn u8_bytes(v: &RawVolume) -> &[u8] {
    match &v.voxels {
        Voxels::U8(d) => d,
        Voxels::U16(_) => panic!("expected u8"),
    }
}

/// The 64³ Colin27 fixture written as NIfTI, NRRD, MetaImage and .den renders exactly
/// like the raw + JSON original.
#[test]
fn every_format_renders_like_raw() {
    let raw = load_volume(&fixtures().join("mr_head_colin27_64.json")).unwrap();
    let reference = render(&raw);
    assert!(reference.iter().any(|p| p[3] > 0), "empty reference image");
    let t = Tmp::new("golden");
    let (d, s, bytes) = (raw.dims, raw.spacing, u8_bytes(&raw));
    let dims = format!("{} {} {}", d[0], d[1], d[2]);

    let mut files = Vec::new();
    for name in ["head.nii", "head.nii.gz"] {
        nifti::write(&t.p(name), d, s, 2, 8, (0.0, 0.0), bytes).unwrap();
        files.push(t.p(name));
    }
    // NRRD: attached raw (RAS space, so the directions are flipped back to LPS) ...
    let mut f = format!(
        "NRRD0004\ntype: uint8\ndimension: 3\nsizes: {dims}\nspace: right-anterior-superior\n\
         space directions: ({},0,0) (0,{},0) (0,0,{})\nencoding: raw\n\n",
        -s[0], -s[1], s[2]
    )
    .into_bytes();
    f.extend_from_slice(bytes);
    std::fs::write(t.p("head.nrrd"), f).unwrap();
    files.push(t.p("head.nrrd"));
    // ... and detached gzip.
    std::fs::write(
        t.p("head.nhdr"),
        format!(
            "NRRD0005\ntype: uchar\ndimension: 3\nsizes: {dims}\nspacings: {} {} {}\n\
             encoding: gzip\ndata file: head.raw.gz\n",
            s[0], s[1], s[2]
        ),
    )
    .unwrap();
    std::fs::write(t.p("head.raw.gz"), gzip(bytes)).unwrap();
    files.push(t.p("head.nhdr"));
    // MetaImage: detached raw and compressed .mha.
    let mhd = |local: &str, compressed: bool| {
        format!(
            "ObjectType = Image\nNDims = 3\nBinaryData = True\nBinaryDataByteOrderMSB = False\n\
             CompressedData = {}\nTransformMatrix = 1 0 0 0 1 0 0 0 1\nDimSize = {dims}\n\
             ElementSpacing = {} {} {}\nElementType = MET_UCHAR\nElementDataFile = {local}\n",
            if compressed { "True" } else { "False" },
            s[0],
            s[1],
            s[2]
        )
    };
    std::fs::write(t.p("head.mhd"), mhd("head.u8", false)).unwrap();
    std::fs::write(t.p("head.u8"), bytes).unwrap();
    files.push(t.p("head.mhd"));
    let mut mha = mhd("LOCAL", true).into_bytes();
    mha.extend_from_slice(&zlib(bytes));
    std::fs::write(t.p("head.mha"), mha).unwrap();
    files.push(t.p("head.mha"));
    // VolPack .den (no spacing in the format: 1 mm; rendered with the raw spacing).
    den::write(&t.p("head.den"), d, bytes).unwrap();
    files.push(t.p("head.den"));

    for f in &files {
        let (v, meta) = load_volume_meta(f, Prefer::U8).unwrap();
        assert_eq!(v.dims, raw.dims, "{}", f.display());
        if meta.format == "den" {
            assert_eq!(v.spacing, [1.0; 3]);
        }
        for a in (0..3).filter(|_| meta.format != "den") {
            assert!(
                (v.spacing[a] - raw.spacing[a]).abs() < 1e-5,
                "{}: {:?}",
                f.display(),
                v.spacing
            );
        }
        assert_eq!(v.voxels, raw.voxels, "{}", f.display());
        assert!(
            meta.orientation.is_empty(),
            "{}: {}",
            f.display(),
            meta.orientation
        );
        let img = render(&RawVolume {
            spacing: raw.spacing,
            ..v
        });
        assert!(img == reference, "{} renders differently", f.display());
    }
}

/// The shared DICOM series (first file padded) loads exactly like its raw conversion.
#[test]
fn dicom_series_matches_raw_conversion() {
    let Some(dir) = dicom_dir() else {
        eprintln!("skipped: shared/data/dicom not present");
        return;
    };
    let raw = load_volume_meta(&fixtures().join("mr_pd_brain_series.json"), Prefer::U16)
        .unwrap()
        .0;
    let (v, meta) = load_volume_meta(&dir, Prefer::U8).unwrap();
    assert_eq!(meta.format, "dicom");
    assert_eq!(meta.source_type, "i16");
    assert_eq!((meta.slope, meta.intercept), (1.0, 0.0));
    assert_eq!(meta.modality.as_deref(), Some("MR"));
    assert_eq!(v.dims, [256, 256, 20]);
    for a in 0..3 {
        assert!(
            (v.spacing[a] - raw.spacing[a]).abs() < 1e-5,
            "{:?}",
            v.spacing
        );
    }
    assert!(
        v.voxels == raw.voxels,
        "voxels differ from the raw conversion"
    );
    // One file of the series loads the whole series.
    let (one, _) = load_volume_meta(&dir.join("brain_007.dcm"), Prefer::U8).unwrap();
    assert!(one.voxels == v.voxels);
    // The raw conversion's JSON keeps the slice spacing to single precision (7.000524
    // against the series' 7.0005237), which may move a sample by a rounding step: the
    // images agree to one level in any channel.
    let (a, b) = (render(&v), render(&raw));
    let worst = a
        .iter()
        .zip(&b)
        .flat_map(|(p, q)| p.iter().zip(q).map(|(x, y)| x.abs_diff(*y)))
        .max();
    assert!(worst <= Some(1), "max channel error {worst:?}");
}

fn shearwarp(args: &[&str]) -> (i32, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_shearwarp"))
        .args(args)
        .output()
        .unwrap();
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn info_prints_dims_spacing_histogram_presets() {
    let (code, out, err) = shearwarp(&[
        "info",
        fixtures().join("mr_head_colin27_64.json").to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    for want in [
        "dims:        64 × 64 × 64",
        "spacing:",
        "values:      stored",
        "histogram",
        "--preset mr-default",
        "--preset mip",
    ] {
        assert!(out.contains(want), "missing {want:?} in\n{out}");
    }
    let (code, out, _) = shearwarp(&[
        "info",
        "--json",
        fixtures().join("mr_head_colin27_64.json").to_str().unwrap(),
    ]);
    assert_eq!(code, 0);
    let j: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(j["dims_xyz"], serde_json::json!([64, 64, 64]));
    if let Some(dir) = dicom_dir() {
        let (code, out, err) = shearwarp(&["info", dir.to_str().unwrap()]);
        assert_eq!(code, 0, "{err}");
        assert!(
            out.contains("256 × 256 × 20") && out.contains("7.000524"),
            "{out}"
        );
        assert!(out.contains("stored 0..1059"), "{out}");
    }
}

/// Every bad input: exit code 2, one line on stderr naming the file and the problem.
#[test]
fn bad_inputs_exit_2_with_one_line() {
    let t = Tmp::new("bad");
    let mut cases: Vec<(PathBuf, &str)> = Vec::new();

    std::fs::write(t.p("mystery.bin"), b"hello world").unwrap();
    cases.push((t.p("mystery.bin"), "unknown volume format"));
    cases.push((t.p("absent.nii"), "file not found"));

    let big = t.p("big.nrrd");
    std::fs::write(
        &big,
        "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 5000 1 1\nencoding: raw\n\n",
    )
    .unwrap();
    cases.push((big, "exceeds the maximum"));

    let short = t.p("short.nii");
    nifti::write(&short, [4, 4, 4], [1.0; 3], 2, 8, (0.0, 0.0), &[0; 64]).unwrap();
    let b = std::fs::read(&short).unwrap();
    std::fs::write(&short, &b[..b.len() - 10]).unwrap();
    cases.push((short, "truncated"));

    let mhd = t.p("m.mhd");
    std::fs::write(
        &mhd,
        "NDims = 3\nDimSize = 2 2 2\nElementType = MET_UCHAR\nElementDataFile = gone.raw\n",
    )
    .unwrap();
    // The missing detached data file is the one named.
    cases.push((mhd, "gone.raw: file not found"));

    // VolPack .den: truncated voxels, and a header whose dims are absurd.
    let den_short = t.p("short.den");
    den::write(&den_short, [4, 4, 4], &[7; 64]).unwrap();
    let b = std::fs::read(&den_short).unwrap();
    std::fs::write(&den_short, &b[..b.len() - 5]).unwrap();
    cases.push((den_short, "expected 64 bytes for 4×4×4 u8, found 59"));
    let den_big = t.p("big.den");
    den::write(&den_big, [4, 4, 4], &[7; 64]).unwrap();
    let mut b = std::fs::read(&den_big).unwrap();
    b[50..52].copy_from_slice(&5000i16.to_le_bytes()); // map_len x
    std::fs::write(&den_big, &b).unwrap();
    cases.push((den_big, "exceeds the maximum"));

    if let Some(dir) = dicom_dir() {
        // Unsupported transfer syntax: patch explicit VR LE into RLE lossless.
        let d1 = t.p("ts");
        std::fs::create_dir_all(&d1).unwrap();
        let mut b = std::fs::read(dir.join("brain_002.dcm")).unwrap();
        let at = b
            .windows(20)
            .position(|w| w == b"1.2.840.10008.1.2.1\0")
            .unwrap();
        b[at..at + 20].copy_from_slice(b"1.2.840.10008.1.2.5\0");
        std::fs::write(d1.join("x.dcm"), &b).unwrap();
        cases.push((d1, "unsupported transfer syntax"));
        // Truncated pixel data.
        let d2 = t.p("trunc");
        std::fs::create_dir_all(&d2).unwrap();
        let b = std::fs::read(dir.join("brain_002.dcm")).unwrap();
        std::fs::write(d2.join("y.dcm"), &b[..b.len() - 1000]).unwrap();
        cases.push((d2.join("y.dcm"), "truncated pixel data"));
        // A missing slice in the middle: uneven spacing.
        let d3 = t.p("gap");
        std::fs::create_dir_all(&d3).unwrap();
        for i in [2, 3, 4, 6, 7] {
            let n = format!("brain_{i:03}.dcm");
            std::fs::copy(dir.join(&n), d3.join(&n)).unwrap();
        }
        cases.push((d3, "uneven slice spacing"));
    }

    for (path, want) in &cases {
        let p = path.to_str().unwrap();
        for cmd in ["info", "render"] {
            let args: Vec<&str> = if cmd == "info" {
                vec!["info", p]
            } else {
                vec!["render", p, "-o", "/dev/null"]
            };
            let (code, _, err) = shearwarp(&args);
            assert_eq!(code, 2, "{cmd} {p}: {err}");
            let name = path.file_name().unwrap().to_string_lossy();
            assert_eq!(err.trim_end().lines().count(), 1, "{err}");
            assert!(err.starts_with("error: "), "{err}");
            assert!(
                err.contains(want) && (err.contains(&*name) || want.contains(".raw")),
                "{p}: {err}"
            );
        }
    }
}
