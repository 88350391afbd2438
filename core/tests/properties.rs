//! Property tests over random small volumes, transfer functions, lighting and views:
//!
//! - rendering never panics, and never exceeds full opacity or produces a colour above
//!   its (premultiplied) opacity, in the Q15 intermediate image or the 8-bit output;
//! - run-length encoding then decoding preserves every voxel on every axis, and any
//!   change of a single run length is caught by validation;
//! - a volume written as `.swv` and streamed renders exactly like the in-memory volume,
//!   for any read chunk size, and the documented worst-case capacities always suffice.
//!
//! The case count is modest so `cargo test` stays fast; set `PROPTEST_CASES` for a longer
//! run (e.g. `PROPTEST_CASES=5000 cargo test --release -p shearwarp-core --test properties`).

use proptest::prelude::*;
use proptest::test_runner::{Config, TestCaseError};

use shearwarp_core::classify::{
    self, ColorTable, ColorTf, GradientTf, Grid, OpacityTf, Scalars, Voxel,
};
use shearwarp_core::composite::{self, Intermediate, Mode, Rgba};
use shearwarp_core::depth::DepthCue;
use shearwarp_core::fixed::ONE;
use shearwarp_core::io::{IoError, SliceReader};
use shearwarp_core::render::{self, Frame, Settings, ShadowWorkspace, Workspace};
use shearwarp_core::rle::{self, Axis, RleAxis, ScanIndex};
use shearwarp_core::shade::{Light, Lighting, ShadeTable};
use shearwarp_core::shadow;
use shearwarp_core::source::{RleVolume, SliceSource};
use shearwarp_core::swv::{self, StreamSource};
use shearwarp_core::view::{self, Camera};
use shearwarp_core::warp::{self, FrameBuffer};
use shearwarp_core::Error;

/// Largest side of the random volumes.
const MAX_SIDE: usize = 12;
/// Largest side of the random images.
const MAX_IMAGE: usize = 24;
const CAP: (usize, usize, usize) = swv::worst_case_capacity([MAX_SIDE; 3]);
/// Flip to `true` once `DepthFrame::apply_row` caps restored colours at the pixel's alpha
/// (see `tests/regressions.rs`).
const DEPTH_CUE_FIXED: bool = true;
/// Flip to `true` once `ShadeTable::fill` no longer overflows for `kd` or `ks` >= 4 (see
/// `tests/regressions.rs`); until then the coefficients stay below 4 (the lighting
/// validation accepts up to 16).
const SHADE_OVERFLOW_FIXED: bool = true;
const MAX_KD_KS: f64 = if SHADE_OVERFLOW_FIXED { 16.0 } else { 3.9 };
type Stream<'a> = StreamSource<SliceReader<'a>, { CAP.0 }, { CAP.1 }, { CAP.2 }>;

fn config(default_cases: u32) -> Config {
    let cases = std::env::var("PROPTEST_CASES")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(default_cases);
    Config {
        cases,
        // Shrinking a failure is worth a few seconds, not minutes.
        max_shrink_iters: 2000,
        ..Config::default()
    }
}

// ------------------------------------------------------------------ generators

#[derive(Clone, Debug)]
enum Data {
    U8(Vec<u8>),
    U16(Vec<u16>),
}

impl Data {
    fn scalars(&self) -> Scalars<'_> {
        match self {
            Data::U8(d) => Scalars::U8(d),
            Data::U16(d) => Scalars::U16(d),
        }
    }
}

#[derive(Clone, Debug)]
struct Volume {
    dims: [usize; 3],
    spacing: [f64; 3],
    data: Data,
}

fn dims() -> impl Strategy<Value = [usize; 3]> {
    [1..=MAX_SIDE, 1..=MAX_SIDE, 1..=MAX_SIDE]
}

fn spacing() -> impl Strategy<Value = [f64; 3]> {
    let s = || prop_oneof![Just(1.0), 0.5..=3.0f64];
    [s(), s(), s()]
}

/// Voxel values: blobs of constant value (long runs) mixed with noise.
fn values(n: usize, max: u16) -> impl Strategy<Value = Vec<u16>> {
    prop::collection::vec((0..=max, 0..4u8), n).prop_map(|v| {
        let mut out = Vec::with_capacity(v.len());
        let mut hold = 0u16;
        for (x, mode) in v {
            // mode 0: keep the previous value, otherwise a new one.
            if mode != 0 {
                hold = x;
            }
            out.push(hold);
        }
        out
    })
}

fn volume() -> impl Strategy<Value = Volume> {
    (dims(), spacing(), any::<bool>()).prop_flat_map(|(dims, spacing, wide)| {
        let n = dims[0] * dims[1] * dims[2];
        let data = if wide {
            values(n, 2000).prop_map(Data::U16).boxed()
        } else {
            values(n, 255)
                .prop_map(|v| Data::U8(v.into_iter().map(|x| x as u8).collect()))
                .boxed()
        };
        data.prop_map(move |data| Volume {
            dims,
            spacing,
            data,
        })
    })
}

fn unit() -> impl Strategy<Value = f64> {
    prop_oneof![Just(0.0), Just(1.0), 0.0..=1.0f64]
}

/// Strictly increasing breakpoints over `0..=max_x` with `N` values each in `0..=1`.
fn points<const N: usize>(max_x: f64) -> impl Strategy<Value = Vec<(f64, [f64; N])>> {
    prop::collection::vec((0.0..=max_x, prop::array::uniform(unit())), 1..6).prop_map(|mut v| {
        v.sort_by(|a, b| a.0.total_cmp(&b.0));
        v.dedup_by(|a, b| a.0 == b.0);
        v
    })
}

#[derive(Clone, Debug)]
struct Classification {
    opacity: Vec<(f64, [f64; 1])>,
    gradient: Option<Vec<(f64, [f64; 1])>>,
    color: Vec<(f64, [f64; 3])>,
    threshold: u8,
}

fn classification() -> impl Strategy<Value = Classification> {
    (
        points::<1>(2100.0),
        prop::option::of(points::<1>(300.0)),
        points::<3>(2100.0),
        prop_oneof![Just(0u8), any::<u8>()],
    )
        .prop_map(|(opacity, gradient, color, threshold)| Classification {
            opacity,
            gradient,
            color,
            threshold,
        })
}

fn lighting() -> impl Strategy<Value = Lighting> {
    let coef = || prop_oneof![0.0..=1.0f64, 0.0..=MAX_KD_KS];
    let light = (
        prop::array::uniform3(-1.0..=1.0f64),
        prop::array::uniform3(unit()),
    )
        .prop_filter("zero light direction", |(d, _)| {
            d.iter().map(|c| c * c).sum::<f64>() > 1e-6
        })
        .prop_map(|(direction, color)| Light { direction, color });
    (
        prop_oneof![0.0..=1.0f64, 0.0..=16.0f64],
        coef(),
        coef(),
        prop_oneof![0.0..=200.0f64, Just(10000.0)],
        prop::collection::vec(light, 1..=4),
    )
        .prop_map(|(ka, kd, ks, shininess, ls)| {
            let mut lights = heapless::Vec::new();
            for l in ls {
                let _ = lights.push(l);
            }
            Lighting {
                ka,
                kd,
                ks,
                shininess,
                lights,
            }
        })
}

#[derive(Clone, Debug)]
struct View {
    camera: Camera,
    mip: bool,
    ert: f64,
    depth: Option<DepthCue>,
    lighting: Option<Lighting>,
    shadows: bool,
}

fn angle() -> impl Strategy<Value = f64> {
    prop_oneof![-720.0..=720.0f64, (-8i32..=8).prop_map(|k| k as f64 * 45.0),]
}

fn view_params() -> impl Strategy<Value = View> {
    (
        angle(),
        angle(),
        1..=MAX_IMAGE,
        1..=MAX_IMAGE,
        prop_oneof![Just(false), Just(false), Just(false), Just(true)],
        prop_oneof![Just(1.0), Just(0.95), 0.01..=1.0f64],
        prop::option::of((0.01..=1.0f64, 0.0..=16.0f64)),
        prop::option::of(lighting()),
        any::<bool>(),
    )
        .prop_map(|(rx, ry, w, h, mip, ert, depth, lighting, shadows)| View {
            camera: Camera {
                rotate_x: rx,
                rotate_y: ry,
                width: w,
                height: h,
            },
            mip,
            ert,
            depth: depth.map(|(front, density)| DepthCue { front, density }),
            lighting,
            shadows,
        })
}

// ------------------------------------------------------------------ helpers

/// Classified, encoded volume: one `(runs, voxels, scans)` per axis.
struct Encoded {
    grid: Grid,
    range: (u16, u16),
    color: ColorTable,
    threshold: u8,
    axes: Vec<(Vec<u8>, Vec<Voxel>, Vec<ScanIndex>)>,
}

impl Encoded {
    fn volume(&self) -> RleVolume<'_> {
        let a: Vec<RleAxis<'_>> = Axis::ALL
            .iter()
            .map(|&axis| {
                let (r, v, s) = &self.axes[axis as usize];
                RleAxis::new(&self.grid, axis, r, v, s).expect("encoder output validates")
            })
            .collect();
        RleVolume::new(self.grid, [a[0], a[1], a[2]]).expect("axis copies match")
    }
}

fn encode_axes(
    dense: &[Voxel],
    grid: &Grid,
    threshold: u8,
) -> Vec<(Vec<u8>, Vec<Voxel>, Vec<ScanIndex>)> {
    Axis::ALL
        .iter()
        .map(|&axis| {
            let sz = rle::measure(dense, grid, axis, threshold).expect("measure");
            let mut r = vec![0u8; sz.runs];
            let mut v = vec![Voxel::default(); sz.voxels];
            let mut s = vec![ScanIndex::default(); sz.scans];
            rle::encode(dense, grid, axis, threshold, &mut r, &mut v, &mut s).expect("encode");
            (r, v, s)
        })
        .collect()
}

fn classify_and_encode(vol: &Volume, class: &Classification) -> Encoded {
    let grid = Grid::new(vol.dims, vol.spacing).expect("valid grid");
    let scalars = vol.data.scalars();
    let mut table = vec![0u8; scalars.value_count()];
    OpacityTf::new(&class.opacity)
        .expect("valid opacity tf")
        .build_table(&mut table);
    let gtable = class
        .gradient
        .as_ref()
        .map(|g| GradientTf::new(g).expect("valid gradient tf").build_table());
    let range = scalars.range();
    let color = ColorTf::new(&class.color)
        .expect("valid colour tf")
        .build_table(range);
    let mut dense = vec![Voxel::default(); grid.voxel_count()];
    classify::classify(&grid, scalars, &table, gtable.as_ref(), &mut dense).expect("classify");
    let axes = encode_axes(&dense, &grid, class.threshold);
    Encoded {
        grid,
        range,
        color,
        threshold: class.threshold,
        axes,
    }
}

/// Heap buffers sized exactly by the documented formulas for `dims` and `width`.
struct Buffers {
    pixels: Vec<Rgba>,
    links: Vec<shearwarp_core::opaque::Word>,
    rows: Vec<Rgba>,
    out_row: Vec<[u8; 4]>,
    shade: Box<ShadeTable>,
    shadow_alpha: Vec<u16>,
    shadow_rows: Vec<u16>,
    shade0: Box<ShadeTable>,
}

impl Buffers {
    fn new(dims: [usize; 3], width: usize) -> Self {
        let pix = view::max_intermediate_pixels(dims);
        let side = dims.iter().copied().max().unwrap_or(1);
        Buffers {
            pixels: vec![[0; 4]; pix],
            links: vec![0; pix],
            rows: vec![[0; 4]; composite::row_buffer_len(side)],
            out_row: vec![[0; 4]; width],
            shade: Box::new(ShadeTable::UNSHADED),
            shadow_alpha: vec![0; pix],
            shadow_rows: vec![0; shadow::row_buffer_len(side)],
            shade0: Box::new(ShadeTable::UNSHADED),
        }
    }

    fn workspace(&mut self) -> Workspace<'_> {
        Workspace {
            pixels: &mut self.pixels,
            links: &mut self.links,
            rows: &mut self.rows,
            out_row: &mut self.out_row,
            shade: &mut self.shade,
            shadow: Some(ShadowWorkspace {
                alpha: &mut self.shadow_alpha,
                rows: &mut self.shadow_rows,
                shade0: &mut self.shade0,
            }),
        }
    }
}

fn settings<'a>(v: &'a View, color: &'a ColorTable) -> Settings<'a> {
    Settings {
        mode: if v.mip { Mode::Mip } else { Mode::Composite },
        color,
        lighting: v.lighting.as_ref(),
        ert_threshold: v.ert,
        depth_cue: v.depth,
        shadows: v.shadows,
        flat_voxels: Default::default(),
        clip: shearwarp_core::clip::Clip::NONE,
    }
}

/// Shadows are refused (not mis-drawn) when the first light is outside the principal
/// axis' cone or there is no light; every other failure is a bug.
fn acceptable_refusal(v: &View, e: &Error) -> bool {
    v.shadows && !v.mip && matches!(e, Error::BadParameter { .. })
}

/// Renders `src` to an RGBA8 image; `None` if the view was legitimately refused.
fn render_image<S: SliceSource>(
    src: &mut S,
    v: &View,
    color: &ColorTable,
) -> Result<Option<Vec<[u8; 4]>>, TestCaseError> {
    let grid = src.grid();
    let mut bufs = Buffers::new(grid.dims, v.camera.width);
    let mut px = vec![[0u8; 4]; v.camera.width * v.camera.height];
    let mut sink = FrameBuffer {
        width: v.camera.width,
        pixels: &mut px,
    };
    let s = settings(v, color);
    match render::render(src, &v.camera, &s, &mut bufs.workspace(), &mut sink) {
        Ok(()) => Ok(Some(px)),
        Err(e) if acceptable_refusal(v, &e) => Ok(None),
        Err(e) => Err(TestCaseError::fail(format!("render failed: {e:?}"))),
    }
}

/// Composites `src` into the Q15 intermediate image and returns it (what `render` warps).
fn intermediate<S: SliceSource>(
    src: &mut S,
    v: &View,
    color: &ColorTable,
) -> Result<Option<Vec<Rgba>>, TestCaseError> {
    let grid = src.grid();
    let mut b = Buffers::new(grid.dims, v.camera.width);
    let s = settings(v, color);
    let frame = match Frame::new(&grid, &v.camera, &s, &mut b.shade, Some(&mut b.shade0)) {
        Ok(f) => f,
        Err(e) if acceptable_refusal(v, &e) => return Ok(None),
        Err(e) => return Err(TestCaseError::fail(format!("frame failed: {e:?}"))),
    };
    let [iw, ih] = frame.view.intermediate;
    let tables = frame.tables(&b.shade, Some(&b.shade0));
    let mut img = Intermediate::new(iw, ih, &mut b.pixels, &mut b.links)
        .map_err(|e| TestCaseError::fail(format!("intermediate: {e:?}")))?;
    let shadow = Some((&mut b.shadow_alpha[..], &mut b.shadow_rows[..]));
    render::composite_band(src, &frame, &tables, &mut img, &mut b.rows, shadow)
        .map_err(|e| TestCaseError::fail(format!("composite failed: {e:?}")))?;
    Ok(Some(img.pixels().to_vec()))
}

// ------------------------------------------------------------------ properties

proptest! {
    #![proptest_config(config(48))]

    /// Compositing never exceeds full opacity, colours never exceed their opacity, and
    /// nothing panics, whatever the volume, transfer functions, lighting and view.
    #[test]
    fn rendering_stays_within_opacity(
        vol in volume(),
        class in classification(),
        v in view_params(),
    ) {
        let enc = classify_and_encode(&vol, &class);
        let mut src = enc.volume();
        // Known bug (see `regressions::depth_cue_keeps_colour_within_alpha`): depth
        // cueing can restore a colour above its alpha at the footprint's nearest corner.
        // Until `depth.rs` is fixed, depth-cued frames are held to the 1.0 bound only.
        let strict = v.depth.is_none() || DEPTH_CUE_FIXED;
        if let Some(px) = intermediate(&mut src, &v, &enc.color)? {
            for (i, p) in px.iter().enumerate() {
                prop_assert!(p[3] as u32 <= ONE, "pixel {i}: alpha {} > 1.0 ({p:?})", p[3]);
                for c in 0..3 {
                    prop_assert!(p[c] as u32 <= ONE, "pixel {i}: channel {c} > 1.0 ({p:?})");
                    prop_assert!(
                        !strict || p[c] <= p[3],
                        "pixel {i}: channel {c} = {} above alpha {} ({p:?})", p[c], p[3]
                    );
                }
                if v.mip {
                    prop_assert!(p[0] == p[1] && p[1] == p[2] && p[2] == p[3], "MIP pixel {p:?}");
                }
            }
        }
        if let Some(img) = render_image(&mut src, &v, &enc.color)? {
            for (i, p) in img.iter().enumerate() {
                for c in 0..3 {
                    prop_assert!(
                        !strict || p[c] <= p[3],
                        "output pixel {i}: {p:?} has colour above alpha"
                    );
                }
            }
        }
    }

    /// Perspective views of any volume, with any field of view, either succeed within
    /// opacity or are refused with a parameter error (too strong a perspective), and
    /// never panic; threads' bands give the same image as one band.
    #[test]
    fn perspective_stays_within_opacity(
        vol in volume(),
        class in classification(),
        v in view_params(),
        fov in prop_oneof![1.0..=150.0f64, Just(90.0), Just(150.0)],
    ) {
        let enc = classify_and_encode(&vol, &class);
        let mut src = enc.volume();
        let grid = src.grid();
        let mut plain = v.clone();
        plain.depth = None;
        plain.shadows = false;
        plain.camera.width = plain.camera.width.min(300);
        plain.camera.height = plain.camera.height.min(300);
        let s = settings(&plain, &enc.color);
        let mut shade = Box::new(ShadeTable::UNSHADED);
        let frame = match Frame::perspective(&grid, &plain.camera, fov, &s, &mut shade) {
            Ok(f) => f,
            Err(Error::BadParameter { .. }) => return Ok(()),
            Err(e) => return Err(TestCaseError::fail(format!("frame failed: {e:?}"))),
        };
        let [iw, ih] = frame.view.intermediate;
        let tables = frame.tables(&shade, None);
        let mut rows = vec![[0u16; 4]; composite::rows_needed(&frame.view)];
        let mut whole = vec![[0u16; 4]; iw * ih];
        let mut links = vec![0; iw * ih];
        {
            let mut img = Intermediate::new(iw, ih, &mut whole, &mut links)
                .map_err(|e| TestCaseError::fail(format!("intermediate: {e:?}")))?;
            render::composite_band(&mut src, &frame, &tables, &mut img, &mut rows, None)
                .map_err(|e| TestCaseError::fail(format!("composite failed: {e:?}")))?;
        }
        for (i, p) in whole.iter().enumerate() {
            prop_assert!(p[3] as u32 <= ONE, "pixel {i}: alpha {} > 1.0 ({p:?})", p[3]);
            for c in 0..3 {
                prop_assert!(p[c] <= p[3] || plain.mip, "pixel {i}: colour above alpha ({p:?})");
            }
        }
        // Bands of 3 scanlines give the same pixels.
        let mut banded = vec![[0u16; 4]; iw * ih];
        let mut blinks = vec![0; iw * ih];
        for (b, (p, l)) in banded.chunks_mut(3 * iw).zip(blinks.chunks_mut(3 * iw)).enumerate() {
            let n = p.len() / iw;
            let mut img = Intermediate::band(iw, ih, 3 * b, n, p, l)
                .map_err(|e| TestCaseError::fail(format!("band: {e:?}")))?;
            render::composite_band(&mut src, &frame, &tables, &mut img, &mut rows, None)
                .map_err(|e| TestCaseError::fail(format!("band composite failed: {e:?}")))?;
        }
        prop_assert!(banded == whole, "bands differ from the whole image");
        // MIP reads the voxels' scalars, never their colours: other colours give the
        // same image (a perspective frame once shaded MIP slices as lit ones).
        if plain.mip {
            let other: ColorTable = [[ONE as u16, 0, ONE as u16 / 3]; 256];
            let s = settings(&plain, &other);
            let mut shade = Box::new(ShadeTable::UNSHADED);
            let frame = Frame::perspective(&grid, &plain.camera, fov, &s, &mut shade)
                .map_err(|e| TestCaseError::fail(format!("recoloured frame failed: {e:?}")))?;
            let tables = frame.tables(&shade, None);
            let mut recoloured = vec![[0u16; 4]; iw * ih];
            let mut img = Intermediate::new(iw, ih, &mut recoloured, &mut links)
                .map_err(|e| TestCaseError::fail(format!("intermediate: {e:?}")))?;
            render::composite_band(&mut src, &frame, &tables, &mut img, &mut rows, None)
                .map_err(|e| TestCaseError::fail(format!("composite failed: {e:?}")))?;
            prop_assert!(recoloured == whole, "MIP depends on the colours");
        }
        let mut out = vec![[0u8; 4]; plain.camera.width * plain.camera.height];
        let mut row = vec![[0u8; 4]; plain.camera.width];
        let mut sink = FrameBuffer { width: plain.camera.width, pixels: &mut out };
        warp::warp(&whole, &frame.view, &mut row, &mut sink)
            .map_err(|e| TestCaseError::fail(format!("warp failed: {e:?}")))?;
    }

    /// The `.swv` stream renders bit-identically to the in-memory volume, for any read
    /// chunk size, and round-trips its header; the documented worst-case capacities
    /// (`swv::worst_case_capacity`) hold every slice of every axis.
    #[test]
    fn streamed_equals_in_memory(
        vol in volume(),
        class in classification(),
        v in view_params(),
        chunk in prop_oneof![Just(256usize), 1..=300usize],
    ) {
        let enc = classify_and_encode(&vol, &class);
        let mem = enc.volume();
        let look = swv::Look { color: enc.color, lighting: v.lighting.clone() };
        let mut bytes = Vec::new();
        swv::write(&mut VecWriter(&mut bytes), &mem, enc.range, enc.threshold, &look)
            .map_err(|e| TestCaseError::fail(format!("write failed: {e:?}")))?;

        let mut stream = Stream::open(SliceReader::new(&bytes))
            .map_err(|e| TestCaseError::fail(format!("open failed: {e:?}")))?;
        stream.set_chunk(chunk);
        let h = stream.header().clone();
        prop_assert_eq!(h.grid, enc.grid);
        prop_assert_eq!(h.range, enc.range);
        prop_assert_eq!(h.threshold, enc.threshold);
        prop_assert_eq!(h.look.color, enc.color);
        prop_assert_eq!(h.look.lighting.is_some(), v.lighting.is_some());

        let mut mem_src = mem;
        let a = render_image(&mut mem_src, &v, &enc.color)?;
        let b = render_image(&mut stream, &v, &enc.color)?;
        prop_assert!(a == b, "streamed image differs from the in-memory one");

        // Exactly the documented capacities, no more.
        let (scans, runs, voxels) = swv::worst_case_capacity(enc.grid.dims);
        let mut sb = vec![ScanIndex::default(); scans];
        let mut rb = vec![0u8; runs];
        let mut vb = vec![Voxel::default(); voxels];
        let mut r = SliceReader::new(&bytes);
        for axis in Axis::ALL {
            let [_, _, nk] = enc.grid.permuted_dims(axis);
            for k in 0..nk {
                let e = swv::read_entry(&mut r, &h, axis, k)
                    .map_err(|e| TestCaseError::fail(format!("entry {axis:?} {k}: {e:?}")))?;
                let s = swv::read_slice(&mut r, &h, axis, &e, chunk, &mut sb, &mut rb, &mut vb)
                    .map_err(|e| TestCaseError::fail(format!("slice {axis:?} {k}: {e:?}")))?;
                let want = mem.axis(axis).slice(k).expect("slice in range");
                prop_assert_eq!(s.runs, want.runs);
                prop_assert_eq!(s.voxels, want.voxels);
            }
        }
    }
}

struct VecWriter<'a>(&'a mut Vec<u8>);

impl swv::Write for VecWriter<'_> {
    fn write_all(&mut self, buf: &[u8]) -> Result<(), IoError> {
        self.0.extend_from_slice(buf);
        Ok(())
    }
}

// ------------------------------------------------------------------ RLE round trip

fn voxel() -> impl Strategy<Value = Voxel> {
    (
        prop_oneof![Just(0u8), Just(0u8), Just(255u8), any::<u8>()],
        any::<u8>(),
        any::<u16>(),
    )
        .prop_map(|(opacity, scalar, normal)| Voxel {
            opacity,
            scalar,
            normal,
        })
}

/// Dense voxels with runs: each generated voxel is repeated 1..40 times, so scanlines
/// longer than 255 (in the long-scanline strategy) get runs that must be split.
fn dense(n: usize) -> impl Strategy<Value = Vec<Voxel>> {
    prop::collection::vec((voxel(), 1..40usize), 1..=n).prop_map(move |groups| {
        groups
            .into_iter()
            .flat_map(|(v, rep)| std::iter::repeat_n(v, rep))
            .cycle()
            .take(n)
            .collect()
    })
}

fn rle_case() -> impl Strategy<Value = ([usize; 3], Vec<Voxel>, u8)> {
    let small = dims().boxed();
    // Scanlines of up to 700 voxels along one axis exercise the 255-split.
    let long = (1..=700usize, 1..=3usize, 1..=2usize, 0..3usize)
        .prop_map(|(a, b, c, rot)| {
            let mut d = [a, b, c];
            d.rotate_right(rot);
            d
        })
        .boxed();
    prop_oneof![3 => small, 1 => long].prop_flat_map(|d| {
        let n = d[0] * d[1] * d[2];
        (
            Just(d),
            dense(n),
            prop_oneof![Just(0u8), Just(254u8), any::<u8>()],
        )
    })
}

proptest! {
    #![proptest_config(config(96))]

    /// encode → decode preserves every voxel above the threshold (and clears the rest) on
    /// every axis; every slice validates; changing any single run length is rejected.
    #[test]
    fn rle_round_trip((d, voxels, threshold) in rle_case(), pick in any::<prop::sample::Index>(), delta in 1..=255u8) {
        let grid = Grid::new(d, [1.0; 3]).expect("valid grid");
        let axes = encode_axes(&voxels, &grid, threshold);
        for (axis, (r, v, s)) in Axis::ALL.iter().zip(&axes) {
            let copy = RleAxis::new(&grid, *axis, r, v, s)
                .map_err(|e| TestCaseError::fail(format!("{axis:?}: {e:?}")))?;
            let mut back = vec![Voxel { opacity: 7, scalar: 7, normal: 7 }; voxels.len()];
            copy.decode(&mut back).map_err(|e| TestCaseError::fail(format!("{e:?}")))?;
            for (i, (a, b)) in voxels.iter().zip(&back).enumerate() {
                let want = if rle::is_visible(a, threshold) { *a } else { Voxel::default() };
                prop_assert_eq!(want, *b, "axis {:?} voxel {}", axis, i);
            }
            let visible = voxels.iter().filter(|x| rle::is_visible(x, threshold)).count();
            prop_assert_eq!(v.len(), visible);
            let [_, _, nk] = grid.permuted_dims(*axis);
            for k in 0..nk {
                let sl = copy.slice(k).expect("slice in range");
                prop_assert!(sl.validate().is_ok());
            }
            prop_assert!(copy.slice(nk).is_none());
            // Any single changed run length breaks a scanline's sum and must be caught.
            let mut bad = r.clone();
            let i = pick.index(bad.len());
            bad[i] = bad[i].wrapping_add(delta);
            prop_assert!(
                RleAxis::new(&grid, *axis, &bad, v, s).is_err(),
                "corrupted run {} accepted on axis {:?}", i, axis
            );
        }
    }
}
