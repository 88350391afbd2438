//! One frame, end to end: factor the view, build the per-frame tables, composite every
//! slice front to back, warp.
//!
//! The caller owns every buffer, either as slices ([`Workspace`]) or as one
//! const-generic block ([`StaticWorkspace`]) whose size is fixed at compile time for a
//! maximum volume and image.

#[cfg(target_arch = "x86_64")]
use crate::classify::Voxel;
use crate::classify::{ColorLanes, ColorTable};
use crate::clip::Clip;
use crate::composite::{self, FlatVoxels, Intermediate, Mode, OpacityTable, Rgba, SliceTables};
use crate::depth::{DepthCue, DepthFrame};
use crate::error::{need, prefix, Error};
use crate::fixed;
use crate::perspective::RayGain;
use crate::shade::{Lighting, ShadeTable};
use crate::shadow::{self, ShadowFrame, ShadowLookup};
use crate::source::SliceSource;
use crate::view::{self, Camera, Factorization};
use crate::warp::{self, PixelSink};

/// How to render a frame.
#[derive(Clone, Debug)]
pub struct Settings<'a> {
    /// Compositing mode.
    pub mode: Mode,
    /// Colour per quantised scalar.
    pub color: &'a ColorTable,
    /// Lighting, or `None` for unshaded colours.
    pub lighting: Option<&'a Lighting>,
    /// Early-ray-termination opacity in `(0, 1]`; 1 disables termination.
    pub ert_threshold: f64,
    /// Depth cueing (fog), or `None`.
    pub depth_cue: Option<DepthCue>,
    /// Shadows cast toward the first light (needs lighting and a shadow workspace).
    pub shadows: bool,
    /// How voxels with a zero gradient enter a sample's colour.
    pub flat_voxels: FlatVoxels,
    /// Clipping planes applied as the slices are composited ([`crate::clip`]), made for
    /// the volume's grid; [`Clip::NONE`] keeps every voxel. Moving them costs nothing,
    /// unlike planes applied as the volume is classified ([`Clip::apply`]), which
    /// change the encoding and drop the voxels they cut from it.
    pub clip: Clip,
}

/// Caller-owned buffers for [`render`].
pub struct Workspace<'a> {
    /// Intermediate image pixels: at least [`view::max_intermediate_pixels`].
    pub pixels: &'a mut [Rgba],
    /// The opaque-pixel bitmap: [`crate::opaque::words`]`(width)` entries per
    /// intermediate scanline (as many as `pixels` is always enough).
    pub links: &'a mut [crate::opaque::Word],
    /// Voxel row buffers: [`composite::row_buffer_len`] of the largest volume side.
    pub rows: &'a mut [Rgba],
    /// One output row: the image width.
    pub out_row: &'a mut [[u8; 4]],
    /// Shading table, rebuilt each frame when lighting is on.
    pub shade: &'a mut ShadeTable,
    /// Buffers for shadows, needed only when [`Settings::shadows`] is set.
    pub shadow: Option<ShadowWorkspace<'a>>,
}

/// Buffers for the shadow sweep.
pub struct ShadowWorkspace<'a> {
    /// Shadow buffer opacity: [`view::max_intermediate_pixels`] entries.
    pub alpha: &'a mut [u16],
    /// Alpha row buffers: [`shadow::row_buffer_len`] of the largest side.
    pub rows: &'a mut [u16],
    /// Shading of the first light alone.
    pub shade0: &'a mut ShadeTable,
}

/// Buffers sized at compile time: `PIX` intermediate pixels, `ROW` row-buffer entries,
/// `W` image width.
///
/// Bytes: `(8 + w)·PIX + 8·ROW + 4·W + 102 448` (the shade table), where `w` is the size
/// of an [`crate::opaque::Word`] (2 on 32-bit targets, 8 on 64-bit ones): the word per
/// pixel holds the opaque-pixel bitmap, which uses a sixteenth or less of it. Use
/// [`view::max_intermediate_pixels`] and [`composite::row_buffer_len`] to choose `PIX`
/// and `ROW` for a maximum volume.
pub struct StaticWorkspace<const PIX: usize, const ROW: usize, const W: usize> {
    pixels: [Rgba; PIX],
    links: [crate::opaque::Word; PIX],
    rows: [Rgba; ROW],
    out_row: [[u8; 4]; W],
    shade: ShadeTable,
}

impl<const PIX: usize, const ROW: usize, const W: usize> StaticWorkspace<PIX, ROW, W> {
    /// Size in bytes.
    pub const BYTES: usize = core::mem::size_of::<Self>();

    /// A zeroed workspace (usable in a `static`).
    pub const fn new() -> Self {
        StaticWorkspace {
            pixels: [[0; 4]; PIX],
            links: [0; PIX],
            rows: [[0; 4]; ROW],
            out_row: [[0; 4]; W],
            shade: ShadeTable::UNSHADED,
        }
    }

    /// Borrows the buffers.
    pub fn workspace(&mut self) -> Workspace<'_> {
        Workspace {
            pixels: &mut self.pixels,
            links: &mut self.links,
            rows: &mut self.rows,
            out_row: &mut self.out_row,
            shade: &mut self.shade,
            shadow: None,
        }
    }
}

impl<const PIX: usize, const ROW: usize, const W: usize> Default for StaticWorkspace<PIX, ROW, W> {
    fn default() -> Self {
        Self::new()
    }
}

/// Per-frame state shared by every band of a frame: the factorization and the tables
/// that do not live in caller buffers.
#[derive(Clone, Debug)]
pub struct Frame {
    /// The factored view.
    pub view: Factorization,
    /// Opacity correction for this view's sample distance, Q15 per stored opacity.
    pub opacity: OpacityTable,
    /// The settings' colour table in the compositor's four-lane form.
    pub color: ColorLanes,
    /// Early-ray-termination threshold, Q15.
    pub ert: u32,
    /// Compositing mode.
    pub mode: Mode,
    /// Depth-cue state, if on.
    pub depth: Option<DepthFrame>,
    /// The light's factorization when shadows are on.
    pub shadow: Option<ShadowFrame>,
    /// Perspective views: the per-ray opacity-correction gains.
    pub ray_gain: Option<RayGain>,
    /// How flat voxels enter a sample's colour.
    pub flat_voxels: FlatVoxels,
    /// The settings' clipping planes, their coefficients in the view's roles (i, j, k).
    pub clip: Clip,
}

impl Frame {
    /// Factors the view and builds the per-frame tables, filling `shade` for the
    /// lighting (or with [`ShadeTable::UNSHADED`]).
    pub fn new(
        grid: &crate::classify::Grid,
        camera: &Camera,
        settings: &Settings<'_>,
        shade: &mut ShadeTable,
        shade0: Option<&mut ShadeTable>,
    ) -> Result<Self, Error> {
        Self::supersampled(grid, camera, settings, shade, shade0, 1)
    }

    /// As [`Frame::new`], compositing at `s` intermediate pixels per voxel
    /// ([`Factorization::with_supersampling`]).
    pub fn supersampled(
        grid: &crate::classify::Grid,
        camera: &Camera,
        settings: &Settings<'_>,
        shade: &mut ShadeTable,
        shade0: Option<&mut ShadeTable>,
        s: usize,
    ) -> Result<Self, Error> {
        let view = Factorization::new(grid, camera)?.with_supersampling(s)?;
        Self::with_view(grid, view, settings, shade, shade0)
    }

    /// As [`Frame::new`] for a perspective camera with a `fov_deg` field of view
    /// ([`Factorization::perspective`]). Depth cueing and shadows are not available in
    /// perspective.
    pub fn perspective(
        grid: &crate::classify::Grid,
        camera: &Camera,
        fov_deg: f64,
        settings: &Settings<'_>,
        shade: &mut ShadeTable,
    ) -> Result<Self, Error> {
        let view = Factorization::perspective(grid, camera, fov_deg)?;
        Self::with_view(grid, view, settings, shade, None)
    }

    /// Builds the per-frame tables for an already factored `view` of `grid`.
    pub fn with_view(
        grid: &crate::classify::Grid,
        view: Factorization,
        settings: &Settings<'_>,
        shade: &mut ShadeTable,
        shade0: Option<&mut ShadeTable>,
    ) -> Result<Self, Error> {
        if view.perspective.is_some() {
            if settings.shadows {
                return Err(Error::BadParameter {
                    reason: "shadows are not available in perspective views",
                });
            }
            if settings.depth_cue.is_some() {
                return Err(Error::BadParameter {
                    reason: "depth cueing is not available in perspective views",
                });
            }
        }
        if !(settings.ert_threshold > 0.0 && settings.ert_threshold <= 1.0) {
            return Err(Error::BadParameter {
                reason: "early-ray-termination threshold must be in (0, 1]",
            });
        }
        let mut shadow = None;
        match (settings.lighting, settings.shadows, settings.mode) {
            (Some(l), true, Mode::Composite) => {
                let Some(sh0) = shade0 else {
                    return Err(Error::BufferTooSmall {
                        what: "shadow workspace",
                        needed: 1,
                        got: 0,
                    });
                };
                let first = l.lights.first().ok_or(Error::BadParameter {
                    reason: "shadows need at least one light",
                })?;
                shadow = Some(ShadowFrame::new(&view, grid, first.direction)?);
                // Split: ambient and the other lights here, the first light alone in shade0.
                let mut rest = l.clone();
                rest.lights = heapless::Vec::from_slice(l.lights.get(1..).unwrap_or_default())
                    .map_err(|()| Error::BadParameter {
                        reason: "too many lights",
                    })?;
                shade.fill(&rest, &view.rotation)?;
                let mut only = l.clone();
                only.ka = 0.0;
                only.lights.truncate(1);
                sh0.fill(&only, &view.rotation)?;
            }
            (None, true, Mode::Composite) => {
                return Err(Error::BadParameter {
                    reason: "shadows need shading (a light)",
                })
            }
            (Some(l), _, _) => shade.fill(l, &view.rotation)?,
            (None, _, _) => *shade = ShadeTable::UNSHADED,
        }
        // ERT at 1.0 must never trigger: put the threshold out of reach.
        let ert = if settings.ert_threshold >= 1.0 {
            fixed::ONE + 1
        } else {
            fixed::from_f64(settings.ert_threshold)
        };
        let depth = match (&settings.depth_cue, settings.mode) {
            (Some(c), Mode::Composite) => Some(DepthFrame::new(c, &view, grid.dims, grid.spacing)?),
            _ => None,
        };
        let clip = settings.clip.permuted(|q| view.permute(q));
        Ok(Frame {
            ray_gain: view.perspective.as_ref().map(RayGain::new),
            shadow,
            depth,
            opacity: OpacityTable::from(crate::classify::opacity_correction(view.step_ratio)),
            color: crate::classify::color_lanes(settings.color),
            view,
            ert,
            mode: settings.mode,
            flat_voxels: settings.flat_voxels,
            clip,
        })
    }

    /// The tables the compositor reads (`shade0`: the first light's table when shadows
    /// are on).
    pub fn tables<'a>(
        &'a self,
        shade: &'a ShadeTable,
        shade0: Option<&'a ShadeTable>,
    ) -> SliceTables<'a> {
        SliceTables {
            shade0: if self.shadow.is_some() { shade0 } else { None },
            opacity: &self.opacity,
            color: &self.color,
            shade,
            mode: self.mode,
            ert: self.ert,
            depth: self.depth.as_ref(),
            ray_gain: self.ray_gain.as_ref(),
            flat_voxels: self.flat_voxels,
            clip: (!self.clip.is_empty()).then_some(&self.clip),
        }
    }
}

/// Composites every slice, front to back, into the scanlines `img` holds. Threads call
/// this with disjoint bands of one frame, each with its own source handle and row buffer.
/// With shadows the band must be the whole intermediate image and `shadow` must hold the
/// shadow buffer and its row buffers.
pub fn composite_band<S: SliceSource>(
    source: &mut S,
    frame: &Frame,
    tables: &SliceTables<'_>,
    img: &mut Intermediate<'_>,
    rows: &mut [Rgba],
    shadow: Option<(&mut [u16], &mut [u16])>,
) -> Result<(), Error> {
    let all = 0..frame.view.dims[2];
    composite_band_until(source, frame, tables, img, rows, shadow, all, &mut || true).map(|_| ())
}

/// Asks the cache for the 64-byte lines of a voxel row the compositor reads a few rows
/// later. Written where it is used, inside the x86-64-v3 and v4 compositors: the
/// prefetch intrinsic is safe to call only where the target features are enabled, and a
/// closure written inside such a function has them.
#[cfg(target_arch = "x86_64")]
macro_rules! prefetch {
    ($v:expr) => {
        for x in $v.iter().step_by(16) {
            core::arch::x86_64::_mm_prefetch::<{ core::arch::x86_64::_MM_HINT_T0 }>(
                x as *const Voxel as *const i8,
            );
        }
    };
}

/// Defines a band compositor `$name` with the attributes given: each is [`band`]
/// inlined, so the attributes (a `target_feature` list) decide how its loops compile.
/// `$kern` is its [`composite::Kernels`]: how it warms the cache for the rows ahead,
/// shades a voxel and composites a run of pixels.
macro_rules! band_compositor {
    ($(#[$attr:meta])* $name:ident, $kern:expr) => {
        $(#[$attr])*
        #[allow(clippy::too_many_arguments)]
        pub fn $name<S: SliceSource>(
            source: &mut S,
            frame: &Frame,
            tables: &SliceTables<'_>,
            img: &mut Intermediate<'_>,
            rows: &mut [Rgba],
            shadow: Option<(&mut [u16], &mut [u16])>,
            slices: core::ops::Range<usize>,
            keep_going: &mut dyn FnMut() -> bool,
        ) -> Result<usize, Error> {
            band(source, frame, tables, img, rows, shadow, slices, keep_going, $kern)
        }
    };
}

/// Defines an instruction-set build `$name` of the band compositor, compiled with the
/// target features `$features`, whose kernels are `[$warm, $premultiply, $over,
/// $closed, $bits]` ([`composite::With`]), and beside it `$persp` and `$flat`: the
/// perspective slice compositor and the slice loop with flat voxels excluded, compiled
/// with the same features and kernels, each in a function of its own
/// ([`composite::Kernels::perspective`], [`composite::Kernels::composite_flat`]).
#[cfg(target_arch = "x86_64")]
macro_rules! isa_band_compositor {
    (
        $(#[$attr:meta])*
        $name:ident, $persp:ident, $flat:ident, $features:literal,
        [$warm:expr, $premultiply:expr, $over:expr, $closed:expr, $bits:expr, $sums:expr $(,)?]
    ) => {
        band_compositor! {
            $(#[$attr])*
            #[target_feature(enable = $features)]
            $name,
            &isa_kernels!($persp, $flat, $warm, $premultiply, $over, $closed, $bits, $sums)
        }

        #[doc = concat!(
            "[`crate::perspective::composite_slice`] as [`", stringify!($name), "`] builds it."
        )]
        #[target_feature(enable = $features)]
        #[inline(never)]
        fn $persp(job: composite::SliceJob<'_, '_>) -> Result<(), Error> {
            let kern = isa_kernels!($persp, $flat, $warm, $premultiply, $over, $closed, $bits, $sums);
            crate::perspective::composite_slice_in(job, &kern)
        }

        #[doc = concat!(
            "[`composite::composite_rows_excluding`] as [`", stringify!($name), "`] builds it."
        )]
        #[target_feature(enable = $features)]
        #[inline(never)]
        fn $flat(
            job: composite::SliceJob<'_, '_>,
            way: composite::Way<'_, '_>,
        ) -> Result<(), Error> {
            let kern = isa_kernels!($persp, $flat, $warm, $premultiply, $over, $closed, $bits, $sums);
            composite::composite_rows_excluding(job, &kern, way)
        }
    };
}

/// The kernels of an instruction-set build ([`isa_band_compositor`]): written where the
/// build's target features are enabled, so the closures are compiled with them and may
/// call `$persp` and `$flat`.
#[cfg(target_arch = "x86_64")]
macro_rules! isa_kernels {
    (
        $persp:ident, $flat:ident, $warm:expr, $premultiply:expr, $over:expr, $closed:expr,
        $bits:expr, $sums:expr
    ) => {
        composite::With(
            $warm,
            $premultiply,
            $over,
            $closed,
            $bits,
            $sums,
            |job: composite::SliceJob<'_, '_>| $persp(job),
            |job: composite::SliceJob<'_, '_>, way: composite::Way<'_, '_>| $flat(job, way),
        )
    };
}

band_compositor! {
    /// [`composite_band`] for the slices at positions `slices` of the front-to-back
    /// order (`0..view.dims[2]` is the whole frame), asking `keep_going` before every
    /// slice and stopping when it says no. Returns the position reached: `slices.end`
    /// when every slice was composited, the position of the first slice left out
    /// otherwise.
    ///
    /// The band's pixels always hold the slices composited so far, front to back, so a
    /// caller may stop and go on later from the position returned: a frontend interrupts
    /// a frame that a newer view has made useless after at most one slice of work (the
    /// pixels are a usable, incomplete image), and a thread that runs out of work takes
    /// over the lower scanlines of another thread's band between two slices
    /// ([`Intermediate::split_off`]). Depth cueing is applied after the last slice
    /// (position `view.dims[2] - 1`) is composited. Shadows sweep their buffer with the
    /// slices, so with shadows `slices` must be the whole frame.
    composite_band_until,
    &composite::Portable
}

#[cfg(target_arch = "x86_64")]
isa_band_compositor! {
    /// [`composite_band_until`] for baseline x86-64 (SSE2): the portable kernels, but
    /// the rows ahead are warmed with prefetch instructions instead of loads, as in
    /// [`composite_band_until_x86_v3`] (alternating frame by frame with the loads, 256²:
    /// brainsmall 2.97 → 2.85 ms, head 14.91 → 13.31, hires brain 30.57 → 26.35,
    /// spheres256 44.35 → 40.36). The prefetch intrinsic needs a function that lists
    /// the SSE features it uses, even though every x86-64 CPU has them; hence this
    /// variant, which a caller may run on any x86-64 CPU.
    ///
    /// # Safety
    ///
    /// None beyond running on x86-64: SSE and SSE2 are part of its baseline. The
    /// function is `unsafe` to call only because it enables target features.
    composite_band_until_x86_64,
    perspective_x86_64,
    composite_flat_x86_64,
    "sse,sse2",
    [
        |v: &[Voxel]| prefetch!(v),
        composite::premultiply,
        composite::over_run_unranked,
        composite::closed_bits,
        composite::flat_bits,
        composite::flat_sums,
    ]
}

#[cfg(target_arch = "x86_64")]
isa_band_compositor! {
    /// [`composite_band_until`] compiled for x86-64-v3 (AVX2, BMI1/2, FMA, LZCNT,
    /// POPCNT): the compositing loops are the same integer code, so the image is
    /// bit-identical, but the compiler may use 256-bit vectors and 32-bit vector
    /// multiplies (baseline x86-64, SSE2, has no 32-bit vector multiply). It also warms
    /// the cache for the rows ahead with prefetch instructions instead of loads, which
    /// the core does not wait for (hires brain, 256², alternating runs: 18.2–18.9 →
    /// 15.0–15.8 ms a frame), shades a voxel's three channels as one vector with a
    /// bit-identical SSE4.1 kernel (`premultiply_sse41` in [`composite`]; spheres256,
    /// callgrind: 13 % fewer instructions a frame) and composites runs two pixels a step
    /// with an AVX2 one (`over_run_simd`: 38 % fewer from the start of both).
    /// `target_feature` functions are safe to define but a caller must know the CPU has
    /// the features.
    ///
    /// # Safety
    ///
    /// The CPU must have every feature listed above; running it on one that lacks any
    /// is undefined behaviour. Check at run time with `is_x86_feature_detected!` first
    /// (the file frontend's `isa` module does).
    composite_band_until_x86_v3,
    perspective_x86_v3,
    composite_flat_x86_v3,
    "avx2,bmi1,bmi2,fma,lzcnt,popcnt",
    [
        |v: &[Voxel]| prefetch!(v),
        composite::premultiply_sse41!(),
        composite::over_run_simd!(avx2),
        composite::closed_bits_avx2!(),
        composite::flat_bits_avx2!(),
        composite::flat_sums_avx2!(),
    ]
}

#[cfg(target_arch = "x86_64")]
isa_band_compositor! {
    /// [`composite_band_until`] compiled for x86-64-v4 (v3 plus AVX-512
    /// F/BW/VL/DQ/CD), bit-identical like [`composite_band_until_x86_v3`]; its over
    /// kernel takes four pixels a step.
    ///
    /// # Safety
    ///
    /// As for [`composite_band_until_x86_v3`], with the AVX-512 features too.
    composite_band_until_x86_v4,
    perspective_x86_v4,
    composite_flat_x86_v4,
    "avx2,bmi1,bmi2,fma,lzcnt,popcnt,avx512f,avx512bw,avx512vl,avx512dq,avx512cd",
    [
        |v: &[Voxel]| prefetch!(v),
        composite::premultiply_sse41!(),
        composite::over_run_simd!(avx512),
        composite::closed_bits_avx2!(),
        composite::flat_bits_avx2!(),
        composite::flat_sums_avx2!(),
    ]
}

/// The body of the `composite_band_until` variants, inlined into each so that it and the
/// loops inlined into it are compiled for that variant's instruction set.
#[cfg_attr(target_arch = "x86_64", inline(always))]
#[allow(clippy::too_many_arguments)]
fn band<S: SliceSource>(
    source: &mut S,
    frame: &Frame,
    tables: &SliceTables<'_>,
    img: &mut Intermediate<'_>,
    rows: &mut [Rgba],
    mut shadow: Option<(&mut [u16], &mut [u16])>,
    slices: core::ops::Range<usize>,
    keep_going: &mut dyn FnMut() -> bool,
    kern: &impl composite::Kernels,
) -> Result<usize, Error> {
    let view = &frame.view;
    let nk = view.dims[2];
    if slices.start > slices.end || slices.end > nk {
        return Err(Error::BadParameter {
            reason: "slice range lies outside the volume",
        });
    }
    let row_len = composite::rows_needed(view);
    need("row buffer", row_len, rows.len())?;
    // Cleared once here; every slice leaves the rows zero again.
    rows[..row_len].fill([0; 4]);
    if img.width() != view.intermediate[0] || img.height() != view.intermediate[1] {
        return Err(Error::BadParameter {
            reason: "intermediate image does not match the frame",
        });
    }
    if let Some(sf) = &frame.shadow {
        if slices != (0..nk) {
            return Err(Error::BadParameter {
                reason: "shadows are computed over every slice in one call",
            });
        }
        if img.first_row() != 0 || img.pixels().len() != img.width() * img.height() {
            return Err(Error::BadParameter {
                reason: "shadows are computed in a single band covering the whole image",
            });
        }
        let Some((alpha, _)) = shadow.as_mut() else {
            return Err(Error::BufferTooSmall {
                what: "shadow buffer",
                needed: sf.size[0] * sf.size[1],
                got: 0,
            });
        };
        need("shadow buffer", sf.size[0] * sf.size[1], alpha.len())?;
        alpha[..sf.size[0] * sf.size[1]].fill(0);
    }
    for idx in slices.clone() {
        if !keep_going() {
            return Ok(idx);
        }
        let k = view.slice_at(idx);
        match (&frame.shadow, shadow.as_mut()) {
            (Some(sf), Some((alpha, srows))) => {
                let [w, h] = sf.size;
                source.with_slice(
                    view.axis,
                    k,
                    #[cfg_attr(target_arch = "x86_64", inline(always))]
                    |slice| {
                        let look = ShadowLookup {
                            alpha: prefix("shadow buffer", alpha, w * h)?,
                            width: w,
                            height: h,
                            off: sf.slice_offset(k),
                        };
                        composite::composite_slice_in(
                            img,
                            slice,
                            k,
                            view,
                            tables,
                            rows,
                            Some(&look),
                            true,
                            kern,
                        )?;
                        shadow::accumulate_slice(alpha, slice, k, sf, srows, tables.clip)
                    },
                )??;
            }
            _ => {
                source.with_slice(
                    view.axis,
                    k,
                    #[cfg_attr(target_arch = "x86_64", inline(always))]
                    |slice| {
                        composite::composite_slice_in(
                            img, slice, k, view, tables, rows, None, true, kern,
                        )
                    },
                )??;
            }
        }
    }
    // Once per scanline: when the last slice has been composited into it.
    if !slices.is_empty() && slices.end == nk {
        if let Some(d) = &frame.depth {
            img.apply_depth_cue(d);
        }
    }
    Ok(slices.end)
}

/// Renders one frame of `source` into `sink` on the calling thread.
pub fn render<S: SliceSource, P: PixelSink>(
    source: &mut S,
    camera: &Camera,
    settings: &Settings<'_>,
    ws: &mut Workspace<'_>,
    sink: &mut P,
) -> Result<(), Error> {
    let grid = source.grid();
    let sh0 = ws.shadow.as_mut().map(|s| &mut *s.shade0);
    let frame = Frame::new(&grid, camera, settings, ws.shade, sh0)?;
    render_frame(source, &frame, ws, sink)
}

/// Renders `source` for a frame built beforehand (with `ws.shade`, and the shadow
/// workspace's `shade0` when shadows are on), e.g. a perspective one from
/// [`Frame::perspective`]. A perspective frame's row buffer must hold
/// [`composite::rows_needed`] entries, more than a parallel one's; a smaller one is a
/// `BufferTooSmall` error.
pub fn render_frame<S: SliceSource, P: PixelSink>(
    source: &mut S,
    frame: &Frame,
    ws: &mut Workspace<'_>,
    sink: &mut P,
) -> Result<(), Error> {
    need("out row", frame.view.image[0], ws.out_row.len())?;
    let [iw, ih] = frame.view.intermediate;
    let (shadow_bufs, shade0) = match ws.shadow.as_mut() {
        Some(s) => (Some((&mut *s.alpha, &mut *s.rows)), Some(&*s.shade0)),
        None => (None, None),
    };
    let tables = frame.tables(ws.shade, shade0);
    let mut img = Intermediate::new(iw, ih, ws.pixels, ws.links)?;
    composite_band(source, frame, &tables, &mut img, ws.rows, shadow_bufs)?;
    warp::warp(img.pixels(), &frame.view, ws.out_row, sink)
}

/// Bytes of a [`StaticWorkspace`] able to render any view of a `dims` volume at width
/// `width`.
pub const fn workspace_bytes(dims: [usize; 3], width: usize) -> usize {
    let pix = view::max_intermediate_pixels(dims);
    let mut m = dims[0];
    if dims[1] > m {
        m = dims[1];
    }
    if dims[2] > m {
        m = dims[2];
    }
    pix * (8 + core::mem::size_of::<crate::opaque::Word>())
        + composite::row_buffer_len(m) * 8
        + width * 4
        + core::mem::size_of::<ShadeTable>()
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use crate::classify::{self, Grid, OpacityTf, Scalars, Voxel};
    use crate::composite::Intermediate;
    use crate::fixed::ONE;
    use crate::normal;
    use crate::rle::{self, Axis, Layout, RleAxis, ScanIndex};
    use crate::shade::Lighting;
    use crate::source::RleVolume;
    use crate::warp::FrameBuffer;
    use std::vec;
    use std::vec::Vec;

    /// A lumpy test volume: two blobs plus noise, so runs start and stop everywhere.
    fn volume(dims: [usize; 3]) -> Vec<u8> {
        let mut s = 12345u32;
        let mut out = Vec::new();
        for z in 0..dims[2] {
            for y in 0..dims[1] {
                for x in 0..dims[0] {
                    s = s.wrapping_mul(1103515245).wrapping_add(12345);
                    let p = [x, y, z].map(|c| c as f64);
                    let c = dims.map(|d| d as f64 * 0.4);
                    let r2 = (p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2) + (p[2] - c[2]).powi(2);
                    let blob = (220.0 - 12.0 * r2.sqrt()).max(0.0);
                    let noise = if (s >> 27) == 0 { 150.0 } else { 0.0 };
                    out.push((blob + noise).min(255.0) as u8);
                }
            }
        }
        out
    }

    /// Composites every pixel of every slice from the dense classified volume with the
    /// same fixed-point arithmetic but no run-length or opaque-pixel skipping.
    fn dense_composite(
        dense: &[Voxel],
        grid: &Grid,
        view: &Factorization,
        tables: &SliceTables<'_>,
        img: &mut Intermediate<'_>,
    ) {
        let [ni, nj, nk] = view.dims;
        let [si, sj, sk] = view.permute([1, grid.dims[0], grid.dims[0] * grid.dims[1]]);
        let get = |i: i64, j: i64, k: usize| -> Rgba {
            if i < 0 || j < 0 || i >= ni as i64 || j >= nj as i64 {
                return [0; 4];
            }
            let v = dense[i as usize * si + j as usize * sj + k * sk];
            if v.opacity <= 3 {
                return [0; 4];
            }
            let a = tables.opacity.get(v.opacity);
            let [r, g, b, _] = tables.color[v.scalar as usize];
            let c = tables.shade.shade(v.normal, [r, g, b]);
            [
                fixed::mul(c[0], a) as u16,
                fixed::mul(c[1], a) as u16,
                fixed::mul(c[2], a) as u16,
                a as u16,
            ]
        };
        let (w, h) = (img.width(), img.height());
        for idx in 0..nk {
            let k = view.slice_at(idx);
            let [ou, ov] = view.slice_offset(k);
            let wt = fixed::bilinear_weights(ou.f, ov.f);
            for v in 0..h {
                for u in 0..w {
                    let px = &mut img.pixels[v * w + u];
                    if px[3] as u32 >= tables.ert {
                        continue;
                    }
                    let il = u as i64 - ou.n as i64 - 1;
                    let jt = v as i64 - ov.n as i64 - 1;
                    let taps = [
                        get(il, jt, k),
                        get(il + 1, jt, k),
                        get(il, jt + 1, k),
                        get(il + 1, jt + 1, k),
                    ];
                    let mut s = [0u32; 4];
                    for c in 0..4 {
                        s[c] = (wt[0] * taps[0][c] as u32
                            + wt[1] * taps[1][c] as u32
                            + wt[2] * taps[2][c] as u32
                            + wt[3] * taps[3][c] as u32
                            + (1 << 14))
                            >> 15;
                    }
                    if s[3] != 0 {
                        let tr = ONE - px[3] as u32;
                        for c in 0..4 {
                            px[c] = (px[c] as u32 + fixed::mul(s[c], tr)).min(ONE) as u16;
                        }
                    }
                }
            }
        }
    }

    /// [`volume`] on `grid`, classified with an opacity ramp from 40 to 255.
    fn classified(grid: &Grid) -> Vec<Voxel> {
        let data = volume(grid.dims);
        let pts = [(40.0, [0.0]), (120.0, [0.6]), (255.0, [1.0])];
        let mut table = [0u8; 256];
        OpacityTf::new(&pts).unwrap().build_table(&mut table);
        let mut dense = vec![Voxel::default(); grid.voxel_count()];
        classify::classify(grid, Scalars::U8(&data), &table, None, &mut dense).unwrap();
        dense
    }

    /// One run-length-encoded copy per axis of `dense` (opacity threshold 3).
    fn encode_all(dense: &[Voxel], grid: &Grid) -> Vec<(Vec<u8>, Vec<Voxel>, Vec<ScanIndex>)> {
        let threshold = 3;
        let mut store = Vec::new();
        for axis in Axis::ALL {
            let sz = rle::measure(dense, grid, axis, threshold).unwrap();
            let mut r = vec![0; sz.runs];
            let mut v = vec![Voxel::default(); sz.voxels];
            let mut s = vec![ScanIndex::default(); sz.scans];
            rle::encode(dense, grid, axis, threshold, &mut r, &mut v, &mut s).unwrap();
            store.push((r, v, s));
        }
        store
    }

    /// The volume `store` ([`encode_all`]) encodes on `grid`.
    fn rle_volume(grid: Grid, store: &[(Vec<u8>, Vec<Voxel>, Vec<ScanIndex>)]) -> RleVolume<'_> {
        let axes = Axis::ALL.map(|a| {
            let (r, v, s) = &store[a as usize];
            RleAxis::new(&grid, a, r, v, s).unwrap()
        });
        RleVolume::new(grid, axes).unwrap()
    }

    /// A 48×40 view turned `rx`, `ry` degrees.
    fn view48(rx: f64, ry: f64) -> Camera {
        Camera {
            rotate_x: rx,
            rotate_y: ry,
            width: 48,
            height: 40,
        }
    }

    /// `frame` of `vol` (a [`view48`] camera's) rendered with buffers for any view of it,
    /// and for shadows when `shade0` (the first light's table) is given.
    fn render48(
        vol: &mut RleVolume<'_>,
        frame: &Frame,
        shade: &mut ShadeTable,
        shade0: Option<&mut ShadeTable>,
    ) -> Vec<[u8; 4]> {
        let pix = 4 * view::max_intermediate_pixels(vol.grid().dims);
        let (mut pixels, mut links) = (vec![[0u16; 4]; pix], vec![0; pix]);
        let mut rows = vec![[0u16; 4]; 1 << 12];
        let mut out_row = [[0u8; 4]; 48];
        let (mut alpha, mut srows) = (vec![0u16; pix], vec![0u16; 1 << 12]);
        let mut ws = Workspace {
            pixels: &mut pixels,
            links: &mut links,
            rows: &mut rows,
            out_row: &mut out_row,
            shade,
            shadow: shade0.map(|shade0| ShadowWorkspace {
                alpha: &mut alpha,
                rows: &mut srows,
                shade0,
            }),
        };
        let mut image = vec![[0u8; 4]; 48 * 40];
        let mut sink = FrameBuffer {
            width: 48,
            pixels: &mut image,
        };
        render_frame(vol, frame, &mut ws, &mut sink).unwrap();
        image
    }

    /// Unshaded compositing with `color`, early ray termination at 0.95.
    fn unlit(color: &ColorTable) -> Settings<'_> {
        Settings {
            mode: Mode::Composite,
            color,
            lighting: None,
            ert_threshold: 0.95,
            depth_cue: None,
            shadows: false,
            flat_voxels: Default::default(),
            clip: crate::clip::Clip::NONE,
        }
    }

    /// A 16×16 view, turned a little about both axes.
    fn small_camera() -> Camera {
        Camera {
            rotate_x: 10.0,
            rotate_y: 20.0,
            width: 16,
            height: 16,
        }
    }

    /// Red rising and green falling with the scalar.
    fn ramp_colours() -> ColorTable {
        core::array::from_fn(|q| {
            let x = (q as u32 * ONE / 255) as u16;
            [x, (ONE as u16) - x, ONE as u16 / 2]
        })
    }

    #[test]
    fn rle_renderer_equals_dense_compositing_for_many_views() {
        let grid = Grid::new([23, 17, 29], [1.0, 1.3, 0.8]).unwrap();
        let dense = classified(&grid);
        let store = encode_all(&dense, &grid);
        let mut vol = rle_volume(grid, &store);
        let color = ramp_colours();
        let lighting = Lighting::default();
        let mut shade = ShadeTable::UNSHADED;
        let mut checked = 0;
        for (rx, ry) in [
            (0.0, 0.0),
            (20.0, 35.0),
            (-60.0, 10.0),
            (90.0, 0.0),
            (10.0, 100.0),
            (45.0, 45.0),
            (170.0, -80.0),
        ] {
            for (ert, lit) in [(0.95, true), (1.0, false), (0.5, true)] {
                let cam = view48(rx, ry);
                let settings = Settings {
                    mode: Mode::Composite,
                    color: &color,
                    lighting: if lit { Some(&lighting) } else { None },
                    ert_threshold: ert,
                    depth_cue: None,
                    shadows: false,
                    flat_voxels: Default::default(),
                    clip: crate::clip::Clip::NONE,
                };
                let view = Factorization::new(&grid, &cam).unwrap();
                let whole = Frame::new(&grid, &cam, &settings, &mut shade, None).unwrap();
                let frame = render48(&mut vol, &whole, &mut shade, None);
                // Dense path with the same tables.
                let opacity = OpacityTable::from(classify::opacity_correction(view.step_ratio));
                let lanes = classify::color_lanes(&color);
                let tables = SliceTables {
                    opacity: &opacity,
                    color: &lanes,
                    shade: &shade,
                    mode: Mode::Composite,
                    ert: if ert >= 1.0 {
                        ONE + 1
                    } else {
                        fixed::from_f64(ert)
                    },
                    depth: None,
                    shade0: None,
                    ray_gain: None,
                    flat_voxels: FlatVoxels::Blended,
                    clip: None,
                };
                let [iw, ih] = view.intermediate;
                let mut p2 = vec![[0u16; 4]; iw * ih];
                let mut l2 = vec![0; iw * ih];
                let mut img = Intermediate::new(iw, ih, &mut p2, &mut l2).unwrap();
                dense_composite(&dense, &grid, &view, &tables, &mut img);
                let mut frame2 = vec![[0u8; 4]; 48 * 40];
                let mut sink2 = FrameBuffer {
                    width: 48,
                    pixels: &mut frame2,
                };
                let mut out_row = [[0u8; 4]; 48];
                warp::warp(img.pixels(), &view, &mut out_row, &mut sink2).unwrap();
                assert_eq!(frame, frame2, "view {rx} {ry} ert {ert}");
                assert!(
                    frame.iter().any(|p| p[3] > 100),
                    "view {rx} {ry} renders something"
                );
                checked += 1;
            }
        }
        assert_eq!(checked, 21);
    }

    /// The layout of the copies changes nothing a user sees: with the scanlines of each
    /// copy along either of its in-slice axes, every mode renders the image of the
    /// cycle's layout, in parallel and in perspective, supersampled, with depth cueing
    /// and with shadows, for views along all three axes. The intermediate image is
    /// transposed and the warp reads it so; a sample's weights, taps and opacity are
    /// the same, and only the warp's coordinates may round differently (at most one
    /// level in a channel).
    #[test]
    fn every_layout_renders_the_cycles_image() {
        let cycle = Grid::new([23, 17, 29], [1.0, 1.3, 0.8])
            .unwrap()
            .with_layout(Layout::CYCLE);
        let dense = classified(&cycle);
        let color = ramp_colours();
        let lighting = Lighting::default();
        let cue = crate::depth::DepthCue {
            front: 0.9,
            density: 1.5,
        };
        let settings = |mode, lit: bool, depth_cue, shadows| Settings {
            mode,
            color: &color,
            lighting: lit.then_some(&lighting),
            ert_threshold: 0.95,
            depth_cue,
            shadows,
            flat_voxels: Default::default(),
            clip: crate::clip::Clip::NONE,
        };
        // (settings, supersampling, perspective field of view).
        let ways = [
            (settings(Mode::Composite, true, None, false), 1, None),
            (settings(Mode::Composite, false, None, false), 1, None),
            (settings(Mode::Mip, false, None, false), 1, None),
            (settings(Mode::Composite, true, Some(cue), false), 1, None),
            (settings(Mode::Composite, true, None, true), 1, None),
            (settings(Mode::Composite, true, None, false), 2, None),
            (settings(Mode::Composite, true, None, false), 1, Some(30.0)),
        ];
        let render_as = |layout: Layout, cam: &Camera, way: usize| -> Vec<[u8; 4]> {
            let grid = cycle.with_layout(layout);
            let store = encode_all(&dense, &grid);
            let mut vol = rle_volume(grid, &store);
            let (settings, s, fov) = &ways[way];
            let (mut shade, mut shade0) = (ShadeTable::UNSHADED, ShadeTable::UNSHADED);
            let frame = match fov {
                Some(fov) => Frame::perspective(&grid, cam, *fov, settings, &mut shade),
                None if settings.shadows => {
                    Frame::supersampled(&grid, cam, settings, &mut shade, Some(&mut shade0), *s)
                }
                None => Frame::supersampled(&grid, cam, settings, &mut shade, None, *s),
            }
            .unwrap();
            let shade0 = settings.shadows.then_some(&mut shade0);
            render48(&mut vol, &frame, &mut shade, shade0)
        };
        let mut axes = [false; 3];
        for (rx, ry) in [(20.0, 35.0), (-10.0, 80.0), (75.0, 10.0), (190.0, -20.0)] {
            let cam = view48(rx, ry);
            axes[Factorization::new(&cycle, &cam).unwrap().axis as usize] = true;
            for way in 0..ways.len() {
                let want = render_as(Layout::CYCLE, &cam, way);
                assert!(want.iter().any(|p| p[3] > 100), "view {rx} {ry} way {way}");
                for bits in 1..8 {
                    let got = render_as(Layout::from_bits(bits).unwrap(), &cam, way);
                    let worst = want
                        .iter()
                        .zip(&got)
                        .flat_map(|(p, q)| p.iter().zip(q).map(|(a, b)| a.abs_diff(*b)))
                        .max();
                    assert!(
                        worst <= Some(1),
                        "view {rx} {ry} way {way} layout {bits}: max channel error {worst:?}"
                    );
                }
            }
        }
        assert_eq!(axes, [true; 3], "views along every axis");
    }

    /// Flat voxels left out of samples' colours change colours only: on a ball whose
    /// core is a plateau (zero gradients) inside a shell with outward normals, lit, the
    /// frames with flat voxels excluded and blended have the same opacity everywhere, in
    /// parallel projection plain and supersampled and with shadows, and differ in colour
    /// (the rule was applied). Without flat voxels the two are the same frame.
    #[test]
    fn excluding_flat_voxels_changes_colour_only() {
        let grid = Grid::new([24, 22, 26], [1.0; 3]).unwrap();
        let [nx, ny, nz] = grid.dims;
        let c = [11.5, 10.5, 12.5];
        // The core: flat (a plateau), or every voxel with its own direction, or all with
        // one direction (records that repeat, as a plateau's do, but none flat).
        #[derive(Clone, Copy, PartialEq)]
        enum Core {
            Flat,
            Directed,
            OneDirection,
        }
        let ball = |core: Core| -> Vec<Voxel> {
            let mut v = Vec::with_capacity(nx * ny * nz);
            for z in 0..nz {
                for y in 0..ny {
                    for x in 0..nx {
                        let d = [x as f64 - c[0], y as f64 - c[1], z as f64 - c[2]];
                        let r = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                        let g = d.map(|e| (e * 64.0) as i64);
                        v.push(match r {
                            r if r < 6.0 => Voxel {
                                opacity: 40,
                                scalar: 200,
                                normal: match core {
                                    Core::Flat => normal::ZERO_GRADIENT,
                                    Core::Directed => normal::encode(g[0], g[1], g[2] + 1),
                                    Core::OneDirection => normal::encode(20, -30, 64),
                                },
                            },
                            r if r < 9.0 => Voxel {
                                opacity: 90,
                                scalar: 120,
                                normal: normal::encode(g[0], g[1], g[2]),
                            },
                            _ => Voxel::default(),
                        });
                    }
                }
            }
            v
        };
        let color = ramp_colours();
        let lighting = Lighting::default();
        let settings = |flat_voxels, shadows| Settings {
            mode: Mode::Composite,
            color: &color,
            lighting: Some(&lighting),
            ert_threshold: 0.95,
            depth_cue: None,
            shadows,
            flat_voxels,
            clip: Clip::NONE,
        };
        let render = |dense: &[Voxel], flat, shadows: bool, s: usize| -> Vec<[u8; 4]> {
            let store = encode_all(dense, &grid);
            let mut vol = rle_volume(grid, &store);
            let cam = view48(20.0, 35.0);
            let (mut shade, mut shade0) = (ShadeTable::UNSHADED, ShadeTable::UNSHADED);
            let st = settings(flat, shadows);
            let frame = match shadows {
                true => Frame::supersampled(&grid, &cam, &st, &mut shade, Some(&mut shade0), s),
                false => Frame::supersampled(&grid, &cam, &st, &mut shade, None, s),
            }
            .unwrap();
            render48(&mut vol, &frame, &mut shade, shadows.then_some(&mut shade0))
        };
        let plateau = ball(Core::Flat);
        for (shadows, s) in [(false, 1), (false, 2), (true, 1)] {
            let blended = render(&plateau, FlatVoxels::Blended, shadows, s);
            let excluded = render(&plateau, FlatVoxels::Excluded, shadows, s);
            assert!(
                blended.iter().any(|p| p[3] > 100),
                "shadows {shadows}, {s}x"
            );
            let alpha = |f: &[[u8; 4]]| f.iter().map(|p| p[3]).collect::<Vec<_>>();
            assert_eq!(alpha(&blended), alpha(&excluded), "shadows {shadows}, {s}x");
            assert!(
                blended != excluded,
                "the rule changed nothing: shadows {shadows}, {s}x"
            );
            // Excluded, runs of equal records are shaded once (`shade_repeats`);
            // blended, voxel by voxel.
            for core in [Core::Directed, Core::OneDirection] {
                let v = ball(core);
                assert_eq!(
                    render(&v, FlatVoxels::Blended, shadows, s),
                    render(&v, FlatVoxels::Excluded, shadows, s),
                    "no flat voxel: shadows {shadows}, {s}x"
                );
            }
        }
    }

    /// A band composited up to some slice, split, and both parts composited from there
    /// to the last slice (what a thread does when it takes over half of another's band)
    /// give the pixels of the band composited in one go, depth cueing included. Fails
    /// if a split loses or repeats a slice, if the tail lands on the wrong scanlines, or
    /// if depth cueing is applied before the last slice or twice.
    #[test]
    fn a_band_split_between_slices_composites_like_the_whole() {
        let grid = Grid::new([23, 17, 29], [1.0, 1.3, 0.8]).unwrap();
        let dense = classified(&grid);
        let store = encode_all(&dense, &grid);
        let mut vol = rle_volume(grid, &store);
        let color = ramp_colours();
        let lighting = Lighting::default();
        let mut shade = ShadeTable::UNSHADED;
        let mut rows = vec![[0u16; 4]; 128];
        let mut splits = 0;
        for (rx, ry) in [(20.0, 35.0), (-60.0, 10.0), (10.0, 100.0)] {
            let cam = view48(rx, ry);
            let settings = Settings {
                mode: Mode::Composite,
                color: &color,
                lighting: Some(&lighting),
                ert_threshold: 0.9,
                depth_cue: Some(crate::depth::DepthCue {
                    front: 0.9,
                    density: 1.5,
                }),
                shadows: false,
                flat_voxels: Default::default(),
                clip: crate::clip::Clip::NONE,
            };
            let frame = Frame::new(&grid, &cam, &settings, &mut shade, None).unwrap();
            let tables = frame.tables(&shade, None);
            let [iw, ih] = frame.view.intermediate;
            let nk = frame.view.dims[2];
            let go = &mut || true;
            let mut whole = vec![[0u16; 4]; iw * ih];
            let mut links = vec![0; iw * ih];
            let mut img = Intermediate::new(iw, ih, &mut whole, &mut links).unwrap();
            let reached = composite_band_until(
                &mut vol,
                &frame,
                &tables,
                &mut img,
                &mut rows,
                None,
                0..nk,
                go,
            )
            .unwrap();
            assert_eq!(reached, nk);
            for at in [0, 1, nk / 3, nk - 1, nk] {
                for cut in [0, 1, ih / 2, ih] {
                    let mut px = vec![[0u16; 4]; iw * ih];
                    let mut links = vec![0; iw * ih];
                    let mut top = Intermediate::new(iw, ih, &mut px, &mut links).unwrap();
                    let mut run = |img: &mut Intermediate<'_>, slices| {
                        composite_band_until(
                            &mut vol, &frame, &tables, img, &mut rows, None, slices, go,
                        )
                        .unwrap()
                    };
                    assert_eq!(run(&mut top, 0..at), at);
                    let mut bottom = top.split_off(cut).unwrap();
                    assert_eq!((top.rows(), bottom.first_row()), (cut, cut));
                    assert_eq!(run(&mut bottom, at..nk), nk);
                    assert_eq!(run(&mut top, at..nk), nk);
                    let _ = (top, bottom);
                    assert!(
                        px == whole,
                        "view {rx} {ry}: split at slice {at}, row {cut}"
                    );
                    splits += 1;
                }
            }
            assert!(
                whole.iter().any(|p| p[3] > 1000),
                "view {rx} {ry} composites"
            );
        }
        assert_eq!(splits, 60);
    }

    /// `keep_going` stops the band before a slice and the position returned is that
    /// slice's; slice ranges outside the volume and splits past the band are errors.
    #[test]
    fn stopping_reports_the_position_and_bad_ranges_are_errors() {
        let grid = Grid::new([9, 7, 11], [1.0; 3]).unwrap();
        let dense = classified(&grid);
        let store = encode_all(&dense, &grid);
        let mut vol = rle_volume(grid, &store);
        let color = ramp_colours();
        let settings = unlit(&color);
        let cam = small_camera();
        let mut shade = ShadeTable::UNSHADED;
        let frame = Frame::new(&grid, &cam, &settings, &mut shade, None).unwrap();
        let tables = frame.tables(&shade, None);
        let [iw, ih] = frame.view.intermediate;
        let nk = frame.view.dims[2];
        let mut px = vec![[0u16; 4]; iw * ih];
        let mut links = vec![0; iw * ih];
        let mut img = Intermediate::new(iw, ih, &mut px, &mut links).unwrap();
        let mut rows = vec![[0u16; 4]; 128];
        let mut asked = 0;
        let mut three = || {
            asked += 1;
            asked <= 3
        };
        let r = composite_band_until(
            &mut vol,
            &frame,
            &tables,
            &mut img,
            &mut rows,
            None,
            2..nk,
            &mut three,
        );
        assert_eq!(r.unwrap(), 5);
        let go = &mut || true;
        for bad in [(3, 2), (0, nk + 1)].map(|(a, b)| a..b) {
            let r = composite_band_until(
                &mut vol, &frame, &tables, &mut img, &mut rows, None, bad, go,
            );
            assert!(matches!(r, Err(Error::BadParameter { .. })));
        }
        assert!(img.split_off(ih + 1).is_err());
    }

    #[test]
    fn small_buffers_are_errors_not_panics() {
        let grid = Grid::new([4, 4, 4], [1.0; 3]).unwrap();
        let dense = [Voxel {
            opacity: 200,
            scalar: 100,
            normal: 0,
        }; 64];
        let mut r = [0u8; 64];
        let mut v = [Voxel::default(); 64];
        let mut s = [ScanIndex::default(); 17];
        let a = rle::encode(&dense, &grid, Axis::Z, 0, &mut r, &mut v, &mut s).unwrap();
        let mut r2 = [0u8; 64];
        let mut v2 = [Voxel::default(); 64];
        let mut s2 = [ScanIndex::default(); 17];
        let b = rle::encode(&dense, &grid, Axis::Y, 0, &mut r2, &mut v2, &mut s2).unwrap();
        let mut r3 = [0u8; 64];
        let mut v3 = [Voxel::default(); 64];
        let mut s3 = [ScanIndex::default(); 17];
        let c = rle::encode(&dense, &grid, Axis::X, 0, &mut r3, &mut v3, &mut s3).unwrap();
        let mut vol = RleVolume::new(grid, [c, b, a]).unwrap();
        let color = [[ONE as u16; 3]; 256];
        let settings = unlit(&color);
        let cam = small_camera();
        let mut ws_full = StaticWorkspace::<200, 16, 16>::new();
        let mut frame = [[0u8; 4]; 256];
        let mut sink = FrameBuffer {
            width: 16,
            pixels: &mut frame,
        };
        assert!(render(
            &mut vol,
            &cam,
            &settings,
            &mut ws_full.workspace(),
            &mut sink
        )
        .is_ok());
        let mut small_pix = StaticWorkspace::<20, 16, 16>::new();
        assert!(matches!(
            render(
                &mut vol,
                &cam,
                &settings,
                &mut small_pix.workspace(),
                &mut sink
            ),
            Err(Error::BufferTooSmall { .. })
        ));
        let mut small_row = StaticWorkspace::<200, 16, 8>::new();
        assert!(render(
            &mut vol,
            &cam,
            &settings,
            &mut small_row.workspace(),
            &mut sink
        )
        .is_err());
        let mut small_frame = [[0u8; 4]; 100];
        let mut sink2 = FrameBuffer {
            width: 16,
            pixels: &mut small_frame,
        };
        assert!(render(
            &mut vol,
            &cam,
            &settings,
            &mut ws_full.workspace(),
            &mut sink2
        )
        .is_err());
    }
}
