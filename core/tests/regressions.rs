//! Replays of the inputs that fuzzing and property testing found to misbehave
//! (`fixtures/regressions/`), and minimal reproductions of the bugs behind them.
//!
//! Tests marked `#[ignore = "known bug: ..."]` reproduce bugs whose fix lies in a file
//! this suite does not own; each message names the file and the fix. Run them with
//! `cargo test -p shearwarp-core --test regressions -- --include-ignored`; drop the
//! `ignore` once fixed (and flip the matching `*_FIXED` constants in
//! `tests/properties.rs` and `fuzz/fuzz_targets/swv_render.rs`).

mod common;

use std::path::PathBuf;

use shearwarp_core::classify::{self, Grid, OpacityTf, Scalars, Voxel};
use shearwarp_core::composite::{Intermediate, Mode};
use shearwarp_core::depth::DepthCue;
use shearwarp_core::fixed::ONE;
use shearwarp_core::io::SliceReader;
use shearwarp_core::normal;
use shearwarp_core::render::{self, Frame, Settings};
use shearwarp_core::rle::{self, Axis, Layout, RleAxis, ScanIndex};
use shearwarp_core::shade::{Light, Lighting, ShadeTable};
use shearwarp_core::source::RleVolume;
use shearwarp_core::view::{self, Camera};

fn regression(name: &str) -> Vec<u8> {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../fixtures/regressions")
        .join(name);
    std::fs::read(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

const IDENTITY: [[f64; 3]; 3] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

/// `(diffuse, specular)` RGB of the normal facing the viewer, for one white light there.
fn facing_entry(ka: f64, kd: f64, ks: f64) -> ([u16; 3], [u16; 3]) {
    let mut lights = heapless::Vec::new();
    let _ = lights.push(Light {
        direction: [0.0, 0.0, 1.0],
        color: [1.0; 3],
    });
    let l = Lighting {
        ka,
        kd,
        ks,
        shininess: 1.0,
        lights,
    };
    let mut t = Box::new(ShadeTable::UNSHADED);
    t.fill(&l, &IDENTITY).unwrap();
    let code = normal::encode(0, 0, 1 << 20) as usize;
    let e = t.entries()[code];
    let rgb = |x: [u16; 4]| [x[0], x[1], x[2]];
    (rgb(e.diffuse), rgb(e.specular))
}

/// Found by the `swv_render` fuzz target within a minute: a `.swv` whose look block has
/// `ks = 4.5` (accepted: the lighting validation allows 0..16) makes
/// `ShadeTable::fill` overflow `u32` in `sp[c] += (s * l.ks[c] + (1 << 14)) >> 15`
/// (core/src/shade.rs:195): `s` reaches `q15(ks)` = 2^17 and more, times `l.ks[c]` up to
/// 2^15. With overflow checks (debug, `cargo fuzz`) it panics; in release it wraps and
/// the highlight silently vanishes. The same holds for `kd >= 4` in
/// `d[c] += fixed::mul(l.kd[c], nd)` (line 194, `fixed::mul` in `u32`).
///
/// Fix (shade.rs, in `fill`): do both products in `u64` and saturate, e.g.
/// `d[c] += ((l.kd[c] as u64 * nd as u64 + (1 << 14)) >> 15).min(1 << 20) as u32;` and
/// `sp[c] += ((s as u64 * l.ks[c] as u64 + (1 << 14)) >> 15).min(1 << 20) as u32;`
/// (the results are capped to `u16::MAX` and `ONE` when stored anyway).
#[test]
fn shade_table_saturates_for_large_coefficients() {
    // Within range: unchanged by the fix.
    let (d, s) = facing_entry(0.0, 1.0, 1.0);
    let near_one = |x: u16| (ONE as i32 - x as i32).abs() <= 64;
    assert!(d.iter().chain(&s).all(|&x| near_one(x)), "{d:?} {s:?}");
    // kd = 4.5 saturates the diffuse factor (capped at u16::MAX, about 2.0); ks = 4.5
    // the specular one (capped at 1.0). Today both wrap around to about 0.5.
    let (d, s) = facing_entry(0.0, 4.5, 4.5);
    assert_eq!(d, [u16::MAX; 3], "diffuse wrapped");
    assert_eq!(s, [ONE as u16; 3], "specular wrapped");
}

#[test]
fn replay_swv_shade_overflow() {
    for name in [
        "swv-shade-specular-overflow.swv",
        "swv-shade-diffuse-overflow.swv",
    ] {
        let b = regression(name);
        // The header is valid and the light shaded: this must not panic (it does with
        // overflow checks) and the table must be the saturated one (it wraps in release).
        let src = common::Src::open(SliceReader::new(&b)).unwrap();
        let l = src.header().look.lighting.clone().unwrap();
        assert!(l.kd >= 4.0 || l.ks >= 4.0, "{name}");
        let _ = common::open_and_render(&b);
        let (d, s) = facing_entry(l.ka, l.kd, l.ks);
        assert!(
            d[0] >= ONE as u16 && (l.ks < 4.0 || s[0] == ONE as u16),
            "{name}: {d:?} {s:?}"
        );
    }
}

/// The three run-length-encoded copies of a `grid` volume whose every voxel holds
/// `value`, classified with constant opacity `opacity`.
fn uniform_axes(
    grid: &Grid,
    value: u8,
    opacity: f64,
) -> Vec<(Vec<u8>, Vec<Voxel>, Vec<ScanIndex>)> {
    let data = vec![value; grid.voxel_count()];
    let pts = [(0.0, [opacity])];
    let mut table = [0u8; 256];
    OpacityTf::new(&pts).unwrap().build_table(&mut table);
    let mut dense = vec![Voxel::default(); grid.voxel_count()];
    classify::classify(grid, Scalars::U8(&data), &table, None, &mut dense).unwrap();
    Axis::ALL
        .iter()
        .map(|&a| {
            let sz = rle::measure(&dense, grid, a, 0).unwrap();
            let mut r = vec![0; sz.runs];
            let mut v = vec![Voxel::default(); sz.voxels];
            let mut s = vec![ScanIndex::default(); sz.scans];
            rle::encode(&dense, grid, a, 0, &mut r, &mut v, &mut s).unwrap();
            (r, v, s)
        })
        .collect()
}

/// The copies of [`uniform_axes`] as the core's axis views.
fn axes<'a>(grid: &Grid, store: &'a [(Vec<u8>, Vec<Voxel>, Vec<ScanIndex>)]) -> Vec<RleAxis<'a>> {
    Axis::ALL
        .iter()
        .map(|&a| {
            let (r, v, s) = &store[a as usize];
            RleAxis::new(grid, a, r, v, s).unwrap()
        })
        .collect()
}

/// Unlit compositing with `color`, no early ray termination, and `depth_cue`.
fn unlit(color: &[[u16; 3]; 256], depth_cue: Option<DepthCue>) -> Settings<'_> {
    Settings {
        mode: Mode::Composite,
        color,
        lighting: None,
        ert_threshold: 1.0,
        depth_cue,
        shadows: false,
        flat_voxels: Default::default(),
        clip: shearwarp_core::clip::Clip::NONE,
    }
}

/// Found by `properties::rendering_stays_within_opacity`: with depth cueing, an
/// intermediate pixel at the corner of the volume's footprint nearest the viewer can end
/// up with a colour above its alpha (here colour = 1.0, alpha = 0.55 in Q15), which the
/// warp turns into an invalid premultiplied output pixel (e.g. `[255, 255, 255, 141]`).
///
/// Cause (core/src/depth.rs): depth is normalised to 0..1 over the voxel-centre box, but
/// the compositor samples each slice on intermediate pixels that lie up to one voxel
/// outside that box (the bilinear footprint). There `d < 0`, so the fog
/// `front·e^(−density·d)` that `DepthFrame::apply_row` restores exceeds 1, and the
/// colour, clamped only at 1.0, passes its alpha.
///
/// Fix: in `DepthFrame::apply_row` (both branches) cap the restored colour at the pixel's
/// alpha, `*c = (... ).min(p[3] as u64) as u16` instead of `.min(ONE as u64)`; or
/// normalise depth over the box widened by one voxel along i and j in `DepthFrame::new`.
#[test]
fn depth_cue_keeps_colour_within_alpha() {
    let dims = [2, 2, 1];
    let grid = Grid::new(dims, [1.0; 3]).unwrap();
    let store = uniform_axes(&grid, 200, 0.5);
    let ax = axes(&grid, &store);
    let mut vol = RleVolume::new(grid, [ax[0], ax[1], ax[2]]).unwrap();
    let color = [[ONE as u16; 3]; 256];
    let settings = unlit(
        &color,
        Some(DepthCue {
            front: 1.0,
            density: 16.0,
        }),
    );
    let cam = Camera {
        rotate_x: 57.96,
        rotate_y: 25.992,
        width: 16,
        height: 16,
    };
    let mut shade = Box::new(ShadeTable::UNSHADED);
    let frame = Frame::new(&grid, &cam, &settings, &mut shade, None).unwrap();
    let [iw, ih] = frame.view.intermediate;
    let pix = view::max_intermediate_pixels(dims);
    let (mut px, mut links) = (vec![[0u16; 4]; pix], vec![0; pix]);
    let mut rows = vec![[0u16; 4]; 64];
    let tables = frame.tables(&shade, None);
    let mut img = Intermediate::new(iw, ih, &mut px, &mut links).unwrap();
    render::composite_band(&mut vol, &frame, &tables, &mut img, &mut rows, None).unwrap();
    for (i, p) in img.pixels().iter().enumerate() {
        assert!(
            p[0] <= p[3] && p[1] <= p[3] && p[2] <= p[3],
            "pixel {i}: colour above alpha {p:?}"
        );
    }
}

/// Found by the `swv_render` fuzz target after 160 000 inputs (10 minutes): a `.swv`
/// header with spacings of 3.6e-304, 1.8e-304 and 2 (accepted: finite and positive),
/// rendered in perspective at a field of view of 8°. So anisotropic a grid makes the
/// per-ray opacity correction's paraboloid nearly flat along one axis, with its centre
/// 4·10^304 pixels away; `RayGain` keeps that centre (clamped to 10^15 in Q4) and
/// squared the pixel's distance from it in `i64`, which overflowed (core/src/
/// perspective.rs, `row_term`; `apply` squares the other axis the same way). With
/// overflow checks it panicked; in release it wrapped and picked an arbitrary level.
/// The squares now saturate, and the coefficient they multiply is zero there anyway.
#[test]
fn perspective_gain_survives_a_far_paraboloid_centre() {
    // The cycle layout, as the fuzzer's version 1 file has it (`Grid::new` would run
    // the y copy's scanlines along x, and the far centre would lie on the other axis).
    let grid = Grid::new(
        [3, 1, 2],
        [3.645561009778199e-304, 1.8227805065666987e-304, 2.0],
    )
    .unwrap()
    .with_layout(Layout::CYCLE);
    let store = uniform_axes(&grid, 200, 0.5);
    let ax = axes(&grid, &store);
    let mut vol = RleVolume::new(grid, [ax[0], ax[1], ax[2]]).unwrap();
    let color = [[ONE as u16; 3]; 256];
    let settings = unlit(&color, None);
    let cam = Camera {
        rotate_x: 20.0,
        rotate_y: -35.0,
        width: 12,
        height: 12,
    };
    let mut shade = Box::new(ShadeTable::UNSHADED);
    let frame = Frame::perspective(&grid, &cam, 8.0, &settings, &mut shade).unwrap();
    let p = frame.view.perspective.as_ref().unwrap();
    assert!(
        p.ratio_sq[4].abs() > 1e300,
        "the centre is far: {:?}",
        p.ratio_sq
    );
    let pix = 4 * view::max_intermediate_pixels(grid.dims);
    let (mut px, mut links) = (vec![[0u16; 4]; pix], vec![0; pix]);
    let mut rows = vec![[0u16; 4]; 1 << 12];
    let mut out_row = vec![[0u8; 4]; cam.width];
    let mut image = vec![[0u8; 4]; cam.width * cam.height];
    let mut ws = render::Workspace {
        pixels: &mut px,
        links: &mut links,
        rows: &mut rows,
        out_row: &mut out_row,
        shade: &mut shade,
        shadow: None,
    };
    let mut sink = shearwarp_core::warp::FrameBuffer {
        width: cam.width,
        pixels: &mut image,
    };
    render::render_frame(&mut vol, &frame, &mut ws, &mut sink).unwrap();
    for p in &image {
        assert!(p[0] <= p[3] && p[1] <= p[3] && p[2] <= p[3], "{p:?}");
    }
    // The volume is a segment 2 long and 10^-304 wide, so it covers no pixel: an empty
    // image is the right one.
    assert!(
        image.iter().all(|p| p[3] == 0),
        "a sliver of no width drew {image:?}"
    );
}
