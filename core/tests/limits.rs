//! Hostile inputs and resource limits in the core: every corrupt or absurd `.swv`, size,
//! capacity and parameter gets a specific error value, never a panic, an out-of-bounds
//! read or an allocation (the core has no allocator).
//!
//! `cargo test -p shearwarp-core --test limits -- --nocapture` prints each bad input with
//! the error it gets.

mod common;

use common::{entry_at, fix_checksums, open_and_render, swv_bytes, Src, CAP, DIMS, IMG, PIX, ROW};
use shearwarp_core::classify::{self, Grid, Scalars, Voxel};
use shearwarp_core::composite::{Intermediate, Mode};
use shearwarp_core::io::{IoError, SliceReader};
use shearwarp_core::render::{render, Settings, StaticWorkspace};
use shearwarp_core::rle::{self, Axis, ScanIndex};
use shearwarp_core::shade::Lighting;
use shearwarp_core::source::SliceSource;
use shearwarp_core::swv::{StreamSource, TABLES_START};
use shearwarp_core::view::Camera;
use shearwarp_core::warp::FrameBuffer;
use shearwarp_core::Error;

fn put(b: &mut [u8], o: usize, bytes: &[u8]) {
    b[o..o + bytes.len()].copy_from_slice(bytes);
}

fn u32_at(b: &[u8], o: usize) -> usize {
    u32::from_le_bytes(b[o..o + 4].try_into().unwrap()) as usize
}

/// Record offset of slice-table entry `e`.
fn record_of(b: &[u8], e: usize) -> usize {
    u32_at(b, entry_at(e))
}

/// Bytes of the scanline index of an x-axis slice record (nj = nz).
const SCANS_LEN: usize = 8 * (DIMS[2] + 1);

/// `(name, mutation, repair checksums, expected error)`.
type Case = (&'static str, fn(&mut Vec<u8>), bool, fn(&Error) -> bool);

fn format_err(what: &'static str) -> impl Fn(&Error) -> bool {
    move |e| matches!(e, Error::Format { reason } if reason.contains(what))
}

#[test]
fn hostile_swv_files_get_specific_errors() {
    // Entry 0 is slice 0 along x: nj = nz scanlines of ni = ny voxels, all transparent
    // (the ball does not reach the face), so its runs are [ny, 0] per scanline.
    let cases: Vec<Case> = vec![
        (
            "empty file",
            |b| b.clear(),
            false,
            |e| *e == Error::Io(IoError::UnexpectedEof),
        ),
        (
            "only the magic",
            |b| b.truncate(8),
            false,
            |e| *e == Error::Io(IoError::UnexpectedEof),
        ),
        (
            "PNG signature instead of the magic",
            |b| put(b, 1, b"PNG"),
            true,
            |e| format_err("magic")(e),
        ),
        (
            "version 3",
            |b| put(b, 8, &3u16.to_le_bytes()),
            true,
            |e| format_err("version")(e),
        ),
        (
            "a layout bit past the three axes",
            |b| b[53] |= 0x10,
            true,
            |e| format_err("layout")(e),
        ),
        (
            "header byte flipped, checksum stale",
            |b| b[20] ^= 1,
            false,
            |e| format_err("header checksum")(e),
        ),
        (
            "table byte flipped, checksum stale",
            |b| b[TABLES_START + 3] ^= 1,
            false,
            |e| format_err("table checksum")(e),
        ),
        (
            "voxel byte flipped, slice checksum stale",
            |b| {
                let n = b.len();
                b[n - 2] ^= 0x55
            },
            false,
            |e| format_err("slice checksum")(e),
        ),
        (
            "nx = 0",
            |b| put(b, 12, &0u32.to_le_bytes()),
            true,
            |e| matches!(e, Error::BadDimensions { .. }),
        ),
        (
            "ny = 4097",
            |b| put(b, 16, &4097u32.to_le_bytes()),
            true,
            |e| matches!(e, Error::BadDimensions { .. }),
        ),
        (
            "nz = 2^32 - 1",
            |b| put(b, 20, &u32::MAX.to_le_bytes()),
            true,
            |e| matches!(e, Error::BadDimensions { .. }),
        ),
        (
            "4096 x 4096 x 4096 (2^36 voxels)",
            |b| {
                for o in [12, 16, 20] {
                    put(b, o, &4096u32.to_le_bytes());
                }
            },
            true,
            |e| matches!(e, Error::BadDimensions { .. }),
        ),
        (
            "spacing NaN",
            |b| put(b, 24, &f64::NAN.to_le_bytes()),
            true,
            |e| *e == Error::BadSpacing,
        ),
        (
            "spacing -1",
            |b| put(b, 32, &(-1.0f64).to_le_bytes()),
            true,
            |e| *e == Error::BadSpacing,
        ),
        (
            "spacing 0",
            |b| put(b, 40, &0.0f64.to_le_bytes()),
            true,
            |e| *e == Error::BadSpacing,
        ),
        (
            "spacing +inf",
            |b| put(b, 24, &f64::INFINITY.to_le_bytes()),
            true,
            |e| *e == Error::BadSpacing,
        ),
        (
            "spacing 1e7",
            |b| put(b, 24, &1e7f64.to_le_bytes()),
            true,
            |e| *e == Error::BadSpacing,
        ),
        (
            "value range inverted",
            |b| put(b, 48, &[9, 0, 3, 0]),
            true,
            |e| format_err("inverted")(e),
        ),
        (
            "colour entry 1.0 + 1 ulp",
            |b| put(b, 64 + 6 * 7 + 2, &32769u16.to_le_bytes()),
            true,
            |e| format_err("colour table")(e),
        ),
        (
            "shading flag 2",
            |b| b[1600] = 2,
            true,
            |e| format_err("lighting block")(e),
        ),
        (
            "5 lights",
            |b| b[1601] = 5,
            true,
            |e| format_err("lighting block")(e),
        ),
        (
            "ka = NaN",
            |b| put(b, 1604, &f32::NAN.to_le_bytes()),
            true,
            |e| format_err("lighting block")(e),
        ),
        (
            "kd = 17",
            |b| put(b, 1608, &17f32.to_le_bytes()),
            true,
            |e| format_err("lighting block")(e),
        ),
        (
            "shininess = -1",
            |b| put(b, 1616, &(-1f32).to_le_bytes()),
            true,
            |e| format_err("lighting block")(e),
        ),
        (
            "light direction zero",
            |b| put(b, 1620, &[0; 12]),
            true,
            |e| format_err("lighting block")(e),
        ),
        (
            "light colour 2.0",
            |b| put(b, 1632, &2f32.to_le_bytes()),
            true,
            |e| format_err("lighting block")(e),
        ),
        (
            "tables cut short",
            |b| b.truncate(TABLES_START + 5),
            false,
            |e| *e == Error::Io(IoError::UnexpectedEof),
        ),
        (
            "last record cut short",
            |b| {
                let n = b.len();
                b.truncate(n - 3)
            },
            false,
            |e| *e == Error::Io(IoError::UnexpectedEof),
        ),
        (
            "slice offset past the end",
            |b| put(b, entry_at(0), &(1u64 << 40).to_le_bytes()),
            true,
            |e| *e == Error::Io(IoError::BadSeek),
        ),
        (
            "slice offset 2^64 - 1",
            |b| put(b, entry_at(0), &u64::MAX.to_le_bytes()),
            true,
            |e| *e == Error::Io(IoError::BadSeek),
        ),
        (
            "slice offset into the header",
            |b| put(b, entry_at(0), &100u64.to_le_bytes()),
            true,
            |e| format_err("offset points into")(e),
        ),
        (
            "run count 2^32 - 1",
            |b| put(b, entry_at(0) + 8, &u32::MAX.to_le_bytes()),
            true,
            |e| matches!(e, Error::BufferTooSmall { what, .. } if what.contains("run")),
        ),
        (
            "voxel count 2^32 - 1",
            |b| put(b, entry_at(0) + 12, &u32::MAX.to_le_bytes()),
            true,
            |e| matches!(e, Error::BufferTooSmall { what, .. } if what.contains("voxel")),
        ),
        (
            "run count one more than stored",
            |b| {
                let r = u32_at(b, entry_at(0) + 8) as u32;
                put(b, entry_at(0) + 8, &(r + 1).to_le_bytes())
            },
            true,
            |e| matches!(e, Error::MalformedRle { .. }),
        ),
        (
            "first scanline entry not (0, 0)",
            |b| {
                let o = record_of(b, 0);
                put(b, o, &2u32.to_le_bytes())
            },
            true,
            |e| matches!(e, Error::MalformedRle { .. }),
        ),
        (
            "scanline index not monotone",
            |b| {
                let o = record_of(b, 0) + 8;
                put(b, o, &1000u32.to_le_bytes())
            },
            true,
            |e| matches!(e, Error::MalformedRle { .. }),
        ),
        (
            "odd number of runs in a scanline",
            |b| {
                let o = record_of(b, 0) + 8;
                put(b, o, &1u32.to_le_bytes())
            },
            true,
            |e| matches!(e, Error::MalformedRle { reason } if reason.contains("odd")),
        ),
        (
            "runs do not sum to the scanline width",
            |b| {
                let o = record_of(b, 0) + SCANS_LEN;
                b[o] = b[o].wrapping_sub(1)
            },
            true,
            |e| matches!(e, Error::MalformedRle { reason } if reason.contains("sum")),
        ),
        (
            "run of 255 in a 7-voxel scanline",
            |b| {
                let o = record_of(b, 0) + SCANS_LEN;
                b[o] = 255
            },
            true,
            |e| matches!(e, Error::MalformedRle { reason } if reason.contains("sum")),
        ),
        (
            "voxel count does not match the runs",
            |b| {
                let o = record_of(b, 0) + 12;
                put(b, o, &1u32.to_le_bytes())
            },
            true,
            |e| matches!(e, Error::MalformedRle { .. }),
        ),
    ];
    let good = swv_bytes();
    assert!(open_and_render(&good).is_ok());
    for (name, mutate, repair, expect) in cases {
        let mut b = good.clone();
        mutate(&mut b);
        if repair {
            fix_checksums(&mut b);
        }
        match open_and_render(&b) {
            Ok(_) => panic!("{name}: accepted"),
            Err(e) => {
                println!("{name:45} -> {e:?}");
                assert!(expect(&e), "{name}: unexpected error {e:?}");
            }
        }
    }
}

#[test]
fn odd_but_valid_voxel_fields_render() {
    // Normal codes past the table, any scalar, any threshold byte: all defined.
    let mut b = swv_bytes();
    b[52] = 255;
    let n = b.len();
    put(&mut b, n - 2, &u16::MAX.to_le_bytes());
    b[n - 3] = 255;
    fix_checksums(&mut b);
    open_and_render(&b).unwrap();
}

#[test]
fn stream_capacity_limits_are_errors() {
    let good = swv_bytes();
    // Scanline capacity is checked at open, for every axis.
    let small = StreamSource::<_, 4, { CAP.1 }, { CAP.2 }>::open(SliceReader::new(&good));
    match small {
        Err(Error::BufferTooSmall { what, got: 4, .. }) => assert!(what.contains("scanline")),
        Err(e) => panic!("{e:?}"),
        Ok(_) => panic!("accepted"),
    }
    // Run and voxel capacities are checked per slice, before reading it.
    let mut s = StreamSource::<_, { CAP.0 }, 2, { CAP.2 }>::open(SliceReader::new(&good)).unwrap();
    let e = s.with_slice(Axis::Z, 2, |_| ()).unwrap_err();
    assert!(
        matches!(e, Error::BufferTooSmall { what, got: 2, .. } if what.contains("run")),
        "{e:?}"
    );
    let mut s = StreamSource::<_, { CAP.0 }, { CAP.1 }, 1>::open(SliceReader::new(&good)).unwrap();
    let e = s.with_slice(Axis::Z, 2, |_| ()).unwrap_err();
    assert!(
        matches!(e, Error::BufferTooSmall { what, got: 1, .. } if what.contains("voxel")),
        "{e:?}"
    );
    // Slices past the end.
    let mut s = Src::open(SliceReader::new(&good)).unwrap();
    let e = s.with_slice(Axis::X, DIMS[0], |_| ()).unwrap_err();
    assert!(matches!(e, Error::Source { .. }), "{e:?}");
}

fn fb(px: &mut [[u8; 4]]) -> FrameBuffer<'_> {
    FrameBuffer {
        width: IMG,
        pixels: px,
    }
}

fn settings(color: &shearwarp_core::classify::ColorTable) -> Settings<'_> {
    Settings {
        mode: Mode::Composite,
        color,
        lighting: None,
        ert_threshold: 0.95,
        depth_cue: None,
        shadows: false,
        flat_voxels: Default::default(),
        clip: shearwarp_core::clip::Clip::NONE,
    }
}

fn cam(width: usize, height: usize) -> Camera {
    Camera {
        rotate_x: 20.0,
        rotate_y: 30.0,
        width,
        height,
    }
}

#[test]
fn workspace_capacity_limits_are_errors() {
    let enc = common::sphere();
    let color = common::color();
    let s = settings(&color);
    let mut px = vec![[0u8; 4]; IMG * IMG];
    let too_small = |r: Result<(), Error>, what: &str| match r {
        Err(Error::BufferTooSmall { what: w, .. }) if w.contains(what) => {}
        other => panic!("expected BufferTooSmall for {what}, got {other:?}"),
    };
    // Intermediate image.
    let mut ws = Box::new(StaticWorkspace::<10, ROW, IMG>::new());
    too_small(
        render(
            &mut enc.volume(),
            &cam(IMG, IMG),
            &s,
            &mut ws.workspace(),
            &mut fb(&mut px),
        ),
        "intermediate",
    );
    // Voxel row buffers.
    let mut ws = Box::new(StaticWorkspace::<PIX, 3, IMG>::new());
    too_small(
        render(
            &mut enc.volume(),
            &cam(IMG, IMG),
            &s,
            &mut ws.workspace(),
            &mut fb(&mut px),
        ),
        "row",
    );
    // Output row narrower than the image.
    let mut ws = Box::new(StaticWorkspace::<PIX, ROW, 8>::new());
    too_small(
        render(
            &mut enc.volume(),
            &cam(IMG, IMG),
            &s,
            &mut ws.workspace(),
            &mut fb(&mut px),
        ),
        "row",
    );
    // Frame buffer smaller than the image.
    let mut ws = Box::new(StaticWorkspace::<PIX, ROW, IMG>::new());
    let mut few = vec![[0u8; 4]; IMG];
    let mut sink = FrameBuffer {
        width: IMG,
        pixels: &mut few,
    };
    too_small(
        render(
            &mut enc.volume(),
            &cam(IMG, IMG),
            &s,
            &mut ws.workspace(),
            &mut sink,
        ),
        "frame buffer",
    );
    // Shadows without a shadow workspace.
    let lit = Lighting::default();
    let shadowed = Settings {
        lighting: Some(&lit),
        shadows: true,
        ..settings(&color)
    };
    too_small(
        render(
            &mut enc.volume(),
            &cam(IMG, IMG),
            &shadowed,
            &mut ws.workspace(),
            &mut fb(&mut px),
        ),
        "shadow",
    );
    // Intermediate images wider than the link type can skip.
    let (mut p, mut l) = (vec![[0u16; 4]; 1], vec![0; 1]);
    assert!(matches!(
        Intermediate::new(65535, 1, &mut p, &mut l),
        Err(Error::BadParameter { .. })
    ));
    assert!(matches!(
        Intermediate::new(4, 4, &mut p, &mut l),
        Err(Error::BufferTooSmall { .. })
    ));
}

#[test]
fn classification_and_encoding_capacity_limits_are_errors() {
    let grid = Grid::new([4, 3, 2], [1.0; 3]).unwrap();
    let data = [7u8; 24];
    let table = [200u8; 256];
    let mut out = vec![Voxel::default(); 23];
    assert!(matches!(
        classify::classify(&grid, Scalars::U8(&data), &table, None, &mut out),
        Err(Error::BufferTooSmall {
            what: "voxels",
            needed: 24,
            got: 23
        })
    ));
    let mut out = vec![Voxel::default(); 24];
    assert!(matches!(
        classify::classify(&grid, Scalars::U8(&data[..23]), &table, None, &mut out),
        Err(Error::BadDimensions { .. })
    ));
    assert!(matches!(
        classify::classify(&grid, Scalars::U8(&data), &table[..255], None, &mut out),
        Err(Error::BufferTooSmall {
            what: "opacity table",
            ..
        })
    ));
    let wide = [7u16; 24];
    assert!(matches!(
        classify::classify(&grid, Scalars::U16(&wide), &table, None, &mut out),
        Err(Error::BufferTooSmall {
            what: "opacity table",
            needed: 65536,
            got: 256
        })
    ));
    classify::classify(&grid, Scalars::U8(&data), &table, None, &mut out).unwrap();
    assert!(matches!(
        rle::measure(&out[..20], &grid, Axis::Z, 0),
        Err(Error::BufferTooSmall {
            what: "dense voxels",
            ..
        })
    ));
    let sz = rle::measure(&out, &grid, Axis::Y, 0).unwrap();
    let mut r = vec![0u8; sz.runs];
    let mut v = vec![Voxel::default(); sz.voxels];
    let mut s = vec![ScanIndex::default(); sz.scans];
    for (runs, voxels, scans, what) in [
        (sz.runs - 1, sz.voxels, sz.scans, "runs"),
        (sz.runs, sz.voxels - 1, sz.scans, "voxels"),
        (sz.runs, sz.voxels, sz.scans - 1, "scans"),
    ] {
        let e = rle::encode(
            &out,
            &grid,
            Axis::Y,
            0,
            &mut r[..runs],
            &mut v[..voxels],
            &mut s[..scans],
        )
        .unwrap_err();
        assert!(
            matches!(e, Error::BufferTooSmall { what: w, .. } if w == what),
            "{e:?}"
        );
    }
    let a = rle::encode(&out, &grid, Axis::Y, 0, &mut r, &mut v, &mut s).unwrap();
    let mut back = vec![Voxel::default(); 23];
    assert!(matches!(
        a.decode(&mut back),
        Err(Error::BufferTooSmall { .. })
    ));
}

#[test]
fn absurd_dimensions_spacing_and_parameters_are_rejected() {
    for dims in [
        [0, 1, 1],
        [1, 0, 1],
        [4097, 1, 1],
        [1, 1, usize::MAX],
        [4096, 4096, 65],
        [2048, 2048, 257],
    ] {
        let e = Grid::new(dims, [1.0; 3]).unwrap_err();
        println!("dims {dims:?} -> {e:?}");
        assert!(matches!(e, Error::BadDimensions { .. }), "{dims:?}: {e:?}");
    }
    // Exactly 2^30 voxels is the largest accepted volume.
    Grid::new([4096, 4096, 64], [1.0; 3]).unwrap();
    for s in [0.0, -1.0, f64::NAN, f64::INFINITY, 1e7, -0.0] {
        let e = Grid::new([2, 2, 2], [1.0, s, 1.0]).unwrap_err();
        assert_eq!(e, Error::BadSpacing, "{s}");
    }
    let enc = common::sphere();
    let color = common::color();
    let mut ws = Box::new(StaticWorkspace::<PIX, ROW, IMG>::new());
    let mut px = vec![[0u8; 4]; IMG * IMG];
    let mut bad_param = |c: Camera, ert: f64| {
        let s = Settings {
            ert_threshold: ert,
            ..settings(&color)
        };
        let mut sink = FrameBuffer {
            width: IMG,
            pixels: &mut px,
        };
        let e = render(&mut enc.volume(), &c, &s, &mut ws.workspace(), &mut sink).unwrap_err();
        println!("camera {c:?}, ert {ert} -> {e:?}");
        assert!(
            matches!(e, Error::BadParameter { .. }),
            "{c:?} {ert}: {e:?}"
        );
    };
    bad_param(cam(0, 8), 0.95);
    bad_param(cam(8, 0), 0.95);
    bad_param(cam(16385, 8), 0.95);
    bad_param(cam(8, usize::MAX), 0.95);
    bad_param(
        Camera {
            rotate_x: f64::NAN,
            ..cam(8, 8)
        },
        0.95,
    );
    bad_param(
        Camera {
            rotate_y: f64::INFINITY,
            ..cam(8, 8)
        },
        0.95,
    );
    bad_param(cam(8, 8), 0.0);
    bad_param(cam(8, 8), 1.5);
    bad_param(cam(8, 8), f64::NAN);
}
