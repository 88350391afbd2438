//! Which instruction-set build of the core's compositing and warp loops to run.
//!
//! On x86-64 the core compiles its band compositor for three levels: the baseline
//! (SSE2, `render::composite_band_until_x86_64`, which enables only SSE and SSE2 and
//! so runs on every x86-64 CPU), x86-64-v3 (AVX2) and x86-64-v4 (AVX-512), and its warp
//! for the same three. All three compositors prefetch the rows ahead instead of loading
//! them; the wider builds also shade voxels and composite pixels with vector kernels
//! that multiply 32-bit lanes (which SSE2 cannot do in one instruction), and warp
//! pixels with AVX2's 16-bit multiply-adds (the same kernel in v3 and v4: on a Zen 4 it
//! beat an AVX-512 one in 32-bit lanes).
//! Every kernel does the portable one's integer arithmetic, so the images are
//! bit-identical (the tests here and the goldens check). The core may not call these
//! builds itself (it has no way to ask the CPU and forbids `unsafe`), so this module
//! asks at run time and dispatches.

use shearwarp_core::composite::{Intermediate, Rgba, SliceTables};
use shearwarp_core::render::{self, Frame};
use shearwarp_core::shade::{Lighting, ShadeTable};
use shearwarp_core::source::SliceSource;
use shearwarp_core::view::Factorization;
use shearwarp_core::warp::{self, PixelSink};
use shearwarp_core::Error;

/// An instruction-set level of the compositing loop.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Isa {
    /// The build every CPU of the target runs (SSE2 on x86-64).
    Baseline,
    /// x86-64-v3: AVX2, BMI1/2, FMA, LZCNT, POPCNT.
    X86V3,
    /// x86-64-v4: v3 plus AVX-512 F/BW/VL/DQ/CD.
    X86V4,
}

impl Isa {
    /// Every level, lowest first.
    pub const ALL: [Isa; 3] = [Isa::Baseline, Isa::X86V3, Isa::X86V4];

    /// The highest level this CPU runs.
    pub fn detect() -> Isa {
        Isa::X86V4.effective()
    }

    /// The level that runs when this one is asked for: the highest level at or below it
    /// that this CPU has.
    pub fn effective(self) -> Isa {
        Isa::ALL
            .into_iter()
            .rev()
            .find(|i| *i <= self && i.available())
            .unwrap_or(Isa::Baseline)
    }

    /// Whether this CPU runs the level (the standard library caches the answer, so this
    /// is a load and a test).
    pub fn available(self) -> bool {
        match self {
            Isa::Baseline => true,
            #[cfg(target_arch = "x86_64")]
            Isa::X86V3 => v3(),
            #[cfg(target_arch = "x86_64")]
            Isa::X86V4 => v3() && v4(),
            #[cfg(not(target_arch = "x86_64"))]
            _ => false,
        }
    }

    /// The level's name, as `--isa` takes it.
    pub fn name(self) -> &'static str {
        match self {
            Isa::Baseline => "baseline",
            Isa::X86V3 => "x86-64-v3",
            Isa::X86V4 => "x86-64-v4",
        }
    }

    /// The level named `s` (see [`Isa::name`]).
    pub fn parse(s: &str) -> Option<Isa> {
        Isa::ALL.into_iter().find(|i| i.name() == s)
    }
}

impl std::str::FromStr for Isa {
    type Err = String;

    fn from_str(s: &str) -> Result<Isa, String> {
        Isa::parse(s).ok_or_else(|| {
            let names: Vec<&str> = Isa::ALL.iter().map(|i| i.name()).collect();
            format!(
                "unknown instruction-set level {s:?} (one of {})",
                names.join(", ")
            )
        })
    }
}

#[cfg(target_arch = "x86_64")]
fn v3() -> bool {
    std::is_x86_feature_detected!("avx2")
        && std::is_x86_feature_detected!("bmi1")
        && std::is_x86_feature_detected!("bmi2")
        && std::is_x86_feature_detected!("fma")
        && std::is_x86_feature_detected!("lzcnt")
        && std::is_x86_feature_detected!("popcnt")
}

#[cfg(target_arch = "x86_64")]
fn v4() -> bool {
    std::is_x86_feature_detected!("avx512f")
        && std::is_x86_feature_detected!("avx512bw")
        && std::is_x86_feature_detected!("avx512vl")
        && std::is_x86_feature_detected!("avx512dq")
        && std::is_x86_feature_detected!("avx512cd")
}

/// [`render::composite_band_until`] in the build for `isa`, or the highest available
/// level below it when this CPU lacks it (so any `Isa` value is safe to pass).
#[allow(clippy::too_many_arguments)]
pub fn composite_band_until<S: SliceSource>(
    isa: Isa,
    source: &mut S,
    frame: &Frame,
    tables: &SliceTables<'_>,
    img: &mut Intermediate<'_>,
    rows: &mut [Rgba],
    shadow: Option<(&mut [u16], &mut [u16])>,
    slices: std::ops::Range<usize>,
    keep_going: &mut dyn FnMut() -> bool,
) -> Result<usize, Error> {
    match isa.effective() {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `effective` returns only levels whose features this CPU has.
        Isa::X86V4 => unsafe {
            render::composite_band_until_x86_v4(
                source, frame, tables, img, rows, shadow, slices, keep_going,
            )
        },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: as above.
        Isa::X86V3 => unsafe {
            render::composite_band_until_x86_v3(
                source, frame, tables, img, rows, shadow, slices, keep_going,
            )
        },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: SSE and SSE2, the features this build enables, are part of x86-64's
        // baseline: every CPU this code runs on has them.
        Isa::Baseline => unsafe {
            render::composite_band_until_x86_64(
                source, frame, tables, img, rows, shadow, slices, keep_going,
            )
        },
        #[cfg(not(target_arch = "x86_64"))]
        _ => render::composite_band_until(
            source, frame, tables, img, rows, shadow, slices, keep_going,
        ),
    }
}

/// [`warp::warp_rows`] in the build for `isa`, or the highest available level below it.
pub fn warp_rows(
    isa: Isa,
    px: &[Rgba],
    extents: Option<&[[u32; 2]]>,
    view: &Factorization,
    rows: std::ops::Range<usize>,
    row: &mut [[u8; 4]],
    sink: &mut impl PixelSink,
) -> Result<(), Error> {
    match isa.effective() {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `effective` returns only levels whose features this CPU has.
        Isa::X86V4 => unsafe { warp::warp_rows_x86_v4(px, extents, view, rows, row, sink) },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: as above.
        Isa::X86V3 => unsafe { warp::warp_rows_x86_v3(px, extents, view, rows, row, sink) },
        _ => warp::warp_rows(px, extents, view, rows, row, sink),
    }
}

/// [`ShadeTable::fill`] in the build for `isa`, or the portable one when this CPU
/// lacks it. Every build fills the same entries.
pub fn fill_shade(
    isa: Isa,
    shade: &mut ShadeTable,
    lighting: &Lighting,
    rot: &[[f64; 3]; 3],
) -> Result<(), Error> {
    match isa.effective() {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `effective` returns only levels whose features this CPU has.
        Isa::X86V4 => unsafe { shade.fill_x86_v4(lighting, rot) },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: as above.
        Isa::X86V3 => unsafe { shade.fill_x86_v3(lighting, rot) },
        _ => shade.fill(lighting, rot),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use shearwarp_core::classify::{Grid, Voxel};
    use shearwarp_core::composite::{FlatVoxels, Mode, OpacityTable};
    use shearwarp_core::depth::DepthCue;
    use shearwarp_core::normal;
    use shearwarp_core::render::Settings;
    use shearwarp_core::rle::{self, Axis, RleAxis, ScanIndex};
    use shearwarp_core::shade::{ShadeEntry, ShadeTable};
    use shearwarp_core::source::RleVolume;
    use shearwarp_core::view::{self, Camera};

    /// A xorshift64 stream for the random cases.
    fn xorshift(mut seed: u64) -> impl FnMut() -> u64 {
        move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            seed
        }
    }

    /// The wider builds replace the per-voxel shading step and the per-pixel "over" step
    /// with vector code; with every table entry drawn from the whole `u16` range
    /// (colours, shading factors and opacities a real lighting never produces, normal
    /// codes past the table, a quarter of the voxels flat) they must still give the
    /// pixels of the core's portable compositor bit for bit, as must the baseline build,
    /// with and without depth cueing, with flat voxels blended and excluded.
    #[test]
    fn wider_builds_shade_extreme_tables_like_the_baseline() {
        let mut rnd = xorshift(0x2545_f491_4f6c_dd1d);
        let dims = [41, 37, 35];
        let grid = Grid::new(dims, [1.0, 1.2, 0.9]).unwrap();
        let dense: Vec<Voxel> = (0..grid.voxel_count())
            .map(|i| {
                let r = rnd();
                let (x, y, z) = (i % 41, i / 41 % 37, i / (41 * 37));
                Voxel {
                    // A third transparent, so runs of both kinds occur: at random in
                    // part of the volume, and elsewhere in blocks, so that runs of 32
                    // voxels and more (which the vector marking of flat voxels takes
                    // whole) occur along every axis.
                    opacity: if (x + y + z) < 40 && r.is_multiple_of(3)
                        || (x + y + z) >= 40 && (x / 20 + y / 20 + z / 20) % 3 == 0
                    {
                        0
                    } else {
                        (r >> 8) as u8
                    },
                    scalar: (r >> 16) as u8,
                    // A quarter flat, so samples mix them with the others.
                    normal: if (r >> 40).is_multiple_of(4) {
                        normal::ZERO_GRADIENT
                    } else {
                        (r >> 24) as u16 % 8400
                    },
                }
            })
            .collect();
        let store: Vec<(Vec<u8>, Vec<Voxel>, Vec<ScanIndex>)> = Axis::ALL
            .iter()
            .map(|&a| {
                let sz = rle::measure(&dense, &grid, a, 0).unwrap();
                let mut r = vec![0u8; sz.runs];
                let mut v = vec![Voxel::default(); sz.voxels];
                let mut s = vec![ScanIndex::default(); sz.scans];
                rle::encode(&dense, &grid, a, 0, &mut r, &mut v, &mut s).unwrap();
                (r, v, s)
            })
            .collect();
        let axes: Vec<RleAxis<'_>> = Axis::ALL
            .iter()
            .map(|&a| {
                let (r, v, s) = &store[a as usize];
                RleAxis::new(&grid, a, r, v, s).unwrap()
            })
            .collect();
        // Each copy's table of flat voxels, from which excluded slices copy the flat bits
        // of the runs they shade instead of finding them: the same frames with it and
        // without.
        let tables: Vec<Vec<u64>> = axes
            .iter()
            .map(|a| {
                let mut t = vec![0; a.flat_rows_len()];
                a.fill_flat_rows(&mut t).unwrap();
                t
            })
            .collect();
        let tabled: Vec<RleAxis<'_>> = axes
            .iter()
            .zip(&tables)
            .map(|(a, t)| a.with_flat_rows(t).unwrap())
            .collect();
        let color = [[0u16; 3]; 256];
        let mut shade = Box::new(ShadeTable::UNSHADED);
        let lane = |x: u64| -> [u16; 4] { core::array::from_fn(|c| (x >> (16 * c)) as u16) };
        for e in shade.entries_mut().iter_mut() {
            *e = ShadeEntry {
                diffuse: lane(rnd()),
                specular: lane(rnd()),
            };
        }
        let levels: Vec<Isa> = Isa::ALL.into_iter().filter(|i| i.available()).collect();
        let cue = Some(DepthCue {
            front: 0.9,
            density: 2.0,
        });
        let mut portables = Vec::new();
        for (depth_cue, flat_voxels) in [
            (None, FlatVoxels::Blended),
            (cue, FlatVoxels::Blended),
            (None, FlatVoxels::Excluded),
            (cue, FlatVoxels::Excluded),
        ] {
            let settings = Settings {
                mode: Mode::Composite,
                color: &color,
                lighting: None,
                ert_threshold: 0.97,
                depth_cue,
                shadows: false,
                flat_voxels,
                clip: shearwarp_core::clip::Clip::NONE,
            };
            let cam = Camera {
                rotate_x: 21.0,
                rotate_y: 38.0,
                width: 64,
                height: 64,
            };
            // Plain, and supersampled (whose phases the kernels composite).
            for ss in [1, 2] {
                let mut unused = Box::new(ShadeTable::UNSHADED);
                let mut frame =
                    Frame::supersampled(&grid, &cam, &settings, &mut unused, None, ss).unwrap();
                // Opacities past one too: the vector kernels must match the scalar ones for
                // any 16-bit input, not only for the tables a frame builds.
                let mut opacity = [0u16; 256];
                for (o, c) in opacity.iter_mut().zip(frame.color.iter_mut()) {
                    *o = rnd() as u16;
                    *c = lane(rnd());
                }
                frame.opacity = OpacityTable::from(opacity);
                let tables = frame.tables(&shade, None);
                let [iw, ih] = frame.view.intermediate;
                let pix = view::max_intermediate_pixels(dims).max(iw * ih);
                // One composite of the frame by the build for `isa`, or by the core's
                // portable compositor (what non-x86 targets run) for `None`: the reference
                // for every build, the baseline x86-64 one included.
                let composite_from = |isa: Option<Isa>, axes: &[RleAxis<'_>]| -> Vec<Rgba> {
                    let mut vol = RleVolume::new(grid, [axes[0], axes[1], axes[2]]).unwrap();
                    let (mut px, mut links) = (vec![[0u16; 4]; pix], vec![0; pix]);
                    let mut rows = vec![[0u16; 4]; 128];
                    let mut img = Intermediate::new(iw, ih, &mut px, &mut links).unwrap();
                    let go = &mut || true;
                    let all = 0..frame.view.dims[2];
                    match isa {
                        Some(isa) => composite_band_until(
                            isa, &mut vol, &frame, &tables, &mut img, &mut rows, None, all, go,
                        ),
                        None => render::composite_band_until(
                            &mut vol, &frame, &tables, &mut img, &mut rows, None, all, go,
                        ),
                    }
                    .unwrap();
                    img.pixels().to_vec()
                };
                let composite = |isa: Option<Isa>| composite_from(isa, &axes);
                let portable = composite(None);
                // With the rows' flat bits copied from the tables (only the x86-64 loops that
                // always exclude flat voxels do), every build's frame is the one it marks the
                // rows for.
                for isa in levels.iter().map(|&i| Some(i)).chain([None]) {
                    assert!(
                        composite_from(isa, &tabled) == portable,
                        "{} differs with the tables of flat voxels",
                        isa.map_or("the portable compositor", Isa::name)
                    );
                }
                assert!(portable.iter().any(|p| p[3] != 0), "nothing was composited");
                let images: Vec<Vec<Rgba>> =
                    levels.iter().map(|&isa| composite(Some(isa))).collect();
                for (isa, img) in levels.iter().zip(&images) {
                    assert!(
                        img == &portable,
                        "{} differs from the portable compositor",
                        isa.name()
                    );
                }
                if ss == 1 {
                    portables.push(portable);
                }
            }
        }
        // The rule for flat voxels was exercised: it changed the frame.
        assert!(portables[0] != portables[2] && portables[1] != portables[3]);
    }

    /// The x86-64-v3 and v4 warps against the portable one, each also skipping background
    /// by the image's extents: random intermediate images (channels past one included,
    /// which the 8-bit conversion clamps; half of them a disc in background) through
    /// random views and output sizes, every output pixel compared.
    /// Every build fills the shading table alike: random lights (one white, several
    /// coloured, extreme coefficients) through random rotations, every entry compared.
    /// A table filled by the wider build is then refilled by the portable one for the
    /// same lights, which must find it filled and leave it as it is.
    #[test]
    fn every_build_fills_the_shading_table_alike() {
        use shearwarp_core::shade::Light;
        let mut rnd = xorshift(0x2545_f491_4f6c_dd1d);
        let mut unit = || (rnd() % 2001) as f64 / 1000.0 - 1.0;
        for case in 0..40 {
            let mut l = Lighting::default();
            if case % 2 == 1 {
                l.ka = (unit() + 1.0) / 2.0;
                l.kd = (unit() + 1.0) * 8.0;
                l.ks = (unit() + 1.0) * 8.0;
                l.shininess = (unit() + 1.0) * 60.0;
                l.lights.clear();
                for _ in 0..1 + case % 4 {
                    let light = Light {
                        direction: [unit(), unit(), unit() + 0.01],
                        color: [0.5 + unit() / 2.0, 0.5 + unit() / 2.0, 0.5 + unit() / 2.0],
                    };
                    l.lights.push(light).unwrap();
                }
            }
            let cam = Camera {
                rotate_x: unit() * 180.0,
                rotate_y: unit() * 180.0,
                width: 8,
                height: 8,
            };
            let grid = Grid::new([9, 9, 9], [1.0; 3]).unwrap();
            let rot = view::Factorization::new(&grid, &cam).unwrap().rotation;
            let mut base = Box::new(ShadeTable::UNSHADED);
            base.fill(&l, &rot).unwrap();
            for isa in Isa::ALL.into_iter().filter(|i| i.available()) {
                let mut t = Box::new(ShadeTable::UNSHADED);
                fill_shade(isa, &mut t, &l, &rot).unwrap();
                assert!(
                    t.entries() == base.entries(),
                    "case {case}: {isa:?} differs"
                );
                t.fill(&l, &rot).unwrap();
                assert!(t.entries() == base.entries(), "case {case}: refilled");
            }
        }
    }

    #[test]
    fn the_wider_warp_is_bit_identical_to_the_portable_one() {
        use shearwarp_core::warp::FrameBuffer;
        let wider: Vec<Isa> = [Isa::X86V3, Isa::X86V4]
            .into_iter()
            .filter(|i| i.available())
            .collect();
        if wider.is_empty() {
            eprintln!("no x86-64-v3 on this CPU: nothing to compare");
            return;
        }
        let mut rnd = xorshift(0x9e37_79b9_7f4a_7c15);
        for case in 0..24 {
            let dims = [
                5 + (rnd() % 60) as usize,
                5 + (rnd() % 60) as usize,
                5 + (rnd() % 60) as usize,
            ];
            let grid = Grid::new(dims, [1.0, 1.0 + (case % 3) as f64 * 0.3, 1.0]).unwrap();
            let size = 16 + (rnd() % 200) as usize;
            let cam = Camera {
                rotate_x: (rnd() % 360) as f64 - 180.0,
                rotate_y: (rnd() % 360) as f64 - 180.0 + 0.37,
                width: size,
                height: size + case,
            };
            let mut view = view::Factorization::new(&grid, &cam).unwrap();
            // Every sixth case maps output pixel centres onto the intermediate grid (as
            // a caller may, the map is the caller's to change), where one weight is all
            // of one.
            if case % 6 == 5 {
                view.image_to_intermediate = [[1.0, 0.0, -0.5], [0.0, 1.0, -0.5], [0.0, 0.0, 1.0]];
            }
            let [iw, ih] = view.intermediate;
            // Odd cases: background outside a disc, so the extents have something to skip.
            let (cx, cy, r2) = (iw as f64 / 2.0, ih as f64 / 2.0, (iw * iw) as f64 / 9.0);
            let px: Vec<Rgba> = (0..iw * ih)
                .map(|i| {
                    let r = rnd();
                    let (dx, dy) = ((i % iw) as f64 - cx, (i / iw) as f64 - cy);
                    if case % 2 == 1 && dx * dx + dy * dy > r2 {
                        return [0; 4];
                    }
                    match r % 4 {
                        0 => [0; 4],
                        // Cases 2 and 3 mod 4: at most one, often exactly one (opaque
                        // pixels), as a compositor leaves them; the others: any u16.
                        1 if case % 4 >= 2 => core::array::from_fn(|c| {
                            ((r >> (16 * c)) as u16).min(shearwarp_core::fixed::ONE as u16)
                        }),
                        1 => core::array::from_fn(|c| (r >> (16 * c)) as u16),
                        _ => core::array::from_fn(|c| ((r >> (15 * c)) % (1 << 15)) as u16),
                    }
                })
                .collect();
            let [w, h] = view.image;
            let mut ext = vec![[0u32; 2]; ih];
            warp::extents(&px, iw, &mut ext).unwrap();
            let render = |isa: Isa, ext: Option<&[[u32; 2]]>| {
                let mut frame = vec![[0u8; 4]; w * h];
                // Tiles of rows with the extents, one row at a time without.
                let rows = if ext.is_some() { warp::TILE_ROWS } else { 1 };
                let mut row = vec![[0u8; 4]; rows * w];
                let mut sink = FrameBuffer {
                    width: w,
                    pixels: &mut frame,
                };
                warp_rows(isa, &px, ext, &view, 0..h, &mut row, &mut sink).unwrap();
                frame
            };
            let base = render(Isa::Baseline, None);
            assert!(
                base.iter().any(|p| p[3] != 0),
                "case {case}: nothing warped"
            );
            for &isa in &wider {
                assert!(
                    render(isa, None) == base,
                    "case {case}: {} differs",
                    isa.name()
                );
            }
            for isa in std::iter::once(Isa::Baseline).chain(wider.iter().copied()) {
                let skipping = render(isa, Some(&ext));
                assert!(
                    skipping == base,
                    "case {case}: {} with extents differs",
                    isa.name()
                );
            }
        }
    }
}
