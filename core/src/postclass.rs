//! Rendering an unclassified volume: post-classification, pre-integrated classification
//! between adjacent slices, and isosurfaces (Rezk-Salama 2001, ch. 3–4; the pre-integrated
//! shear-warp paper), with fast reclassification through min-max bricks
//! (Lacroute 1995, §4.3: a coherence structure plus a summed table over the transfer
//! function finds transparent regions without touching their voxels).
//!
//! The volume is kept dense (8-bit quantised scalar and normal code per voxel, the same
//! [`Voxel`] records as the classified path with the opacity ignored), so a new transfer
//! function costs one pass over the bricks, not a re-encode.
//!
//! - **Bricks.** 8³ voxels, each storing the min and max scalar over the brick grown by
//!   two voxels on every side: that halo covers every voxel a pixel of a slab can
//!   interpolate (two voxels in i, rows j..j+1 of both slices, which the shear can shift
//!   by one, and the next slice). A brick is skipped when the transfer function is zero
//!   over its whole value range, found in O(1) from a prefix count of visible values:
//!   testing the range, not the endpoints, matters for pre-integration, where two
//!   transparent endpoint values can enclose an opaque one.
//! - **Post-classification.** Each slice's scalar is interpolated bilinearly and then
//!   classified (opacity and colour interpolated linearly between table entries).
//! - **Pre-integration.** The slab between adjacent slices takes its front and back
//!   scalars from bilinear interpolation in each slice at the ray's position; a
//!   256×256 table holds the colour and opacity of a linear ramp between them,
//!   integrated front to back in 16 steps with opacity corrected for the slab length.
//!   It is built every frame: it depends on the transfer function and on the slab
//!   length, which changes with the view, so one or the other changes from frame to
//!   frame in a turn or while a transfer function is edited.
//! - **Isosurface.** The first slab whose front and back scalars bracket the isovalue
//!   sets the pixel to the isovalue's colour, shaded with the interpolated lighting, and
//!   makes it opaque.
//!
//! Shading uses the per-frame [`ShadeTable`]: each tap's diffuse and specular factors are
//! interpolated with the same weights as the scalar. Each voxel is a unit cell: a pixel
//! samples a slice only where its position lies within `[−0.5, n − 0.5]`, and taps
//! beyond the edge repeat the outer voxels.

use crate::classify::{ColorTable, Grid, Voxel};
use crate::clip::Clip;
use crate::composite::{Intermediate, Rgba};
use crate::crop::Crop;
use crate::error::{need, Error};
use crate::fixed::{self, ONE};
use crate::shade::ShadeTable;
use crate::view::{Camera, Factorization};
use crate::warp::{self, PixelSink};

/// Brick edge in voxels.
pub const BRICK: usize = 8;
const HALO: usize = 2;

/// Number of bricks for a volume of `dims`.
pub const fn brick_count(dims: [usize; 3]) -> usize {
    dims[0].div_ceil(BRICK) * dims[1].div_ceil(BRICK) * dims[2].div_ceil(BRICK)
}

/// Computes each brick's `(min, max)` scalar over the brick and its two-voxel halo.
pub fn build_bricks(grid: &Grid, voxels: &[Voxel], out: &mut [(u8, u8)]) -> Result<(), Error> {
    let d = grid.dims;
    need("voxels", grid.voxel_count(), voxels.len())?;
    need("bricks", brick_count(d), out.len())?;
    let nb = d.map(|n| n.div_ceil(BRICK));
    for bz in 0..nb[2] {
        for by in 0..nb[1] {
            for bx in 0..nb[0] {
                let range = |b: usize, n: usize| {
                    (
                        (b * BRICK).saturating_sub(HALO),
                        ((b + 1) * BRICK + HALO).min(n),
                    )
                };
                let (x0, x1) = range(bx, d[0]);
                let (y0, y1) = range(by, d[1]);
                let (z0, z1) = range(bz, d[2]);
                let mut lo = u8::MAX;
                let mut hi = 0u8;
                for z in z0..z1 {
                    for y in y0..y1 {
                        let row = (z * d[1] + y) * d[0];
                        // Inside the volume (`need` checked `voxels`).
                        let line = voxels.get(row + x0..row + x1).unwrap_or_default();
                        for v in line {
                            lo = lo.min(v.scalar);
                            hi = hi.max(v.scalar);
                        }
                    }
                }
                if let Some(o) = out.get_mut((bz * nb[1] + by) * nb[0] + bx) {
                    *o = (lo, hi);
                }
            }
        }
    }
    Ok(())
}

/// What to render.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum PostMode {
    /// Interpolate scalars in each slice, then classify.
    PostClassified,
    /// Classify the slab between adjacent slices with a pre-integrated table.
    PreIntegrated,
    /// First crossing of this 8-bit quantised scalar value (fractional allowed).
    Isosurface(f64),
}

/// Per-frame settings for [`render`].
pub struct PostSettings<'a> {
    /// Mode.
    pub mode: PostMode,
    /// Opacity per unit smallest spacing per quantised scalar, Q15.
    pub opacity: &'a [u16; 256],
    /// Colour per quantised scalar, Q15.
    pub color: &'a ColorTable,
    /// Lighting, or `None`.
    pub lighting: Option<&'a crate::shade::Lighting>,
    /// Early-ray-termination opacity.
    pub ert_threshold: f64,
    /// Samples outside this box's cells are left out ([`crate::crop`]); `None` keeps
    /// the whole volume.
    pub crop: Option<Crop>,
    /// Each sample's opacity is scaled by its coverage by these planes
    /// ([`crate::clip`]), made for this volume; [`Clip::NONE`] keeps every sample.
    pub clip: Clip,
}

/// Caller buffers for [`render`].
pub struct PostWorkspace<'a> {
    /// Intermediate pixels ([`crate::view::max_intermediate_pixels`]).
    pub pixels: &'a mut [Rgba],
    /// The opaque-pixel bitmap ([`crate::opaque::words`]`(width)` per scanline; as many
    /// as `pixels` is always enough).
    pub links: &'a mut [crate::opaque::Word],
    /// One flag per brick ([`brick_count`]).
    pub visible: &'a mut [bool],
    /// Pre-integration table, 65 536 entries (only for [`PostMode::PreIntegrated`]).
    pub preint: &'a mut [Rgba],
    /// Shading table.
    pub shade: &'a mut ShadeTable,
    /// One output row.
    pub out_row: &'a mut [[u8; 4]],
}

/// Flags bricks whose value range holds any scalar with non-zero opacity (for the
/// isosurface: any range containing the isovalue). Cost: one lookup per brick.
pub fn classify_bricks(
    bricks: &[(u8, u8)],
    opacity: &[u16; 256],
    mode: PostMode,
    visible: &mut [bool],
) -> Result<(), Error> {
    need("brick flags", bricks.len(), visible.len())?;
    // prefix[v + 1] = number of values <= v with non-zero opacity.
    let mut prefix = [0u16; 257];
    for v in 0..256 {
        prefix[v + 1] = prefix[v] + (opacity[v] != 0) as u16;
    }
    for (flag, &(lo, hi)) in visible.iter_mut().zip(bricks) {
        *flag = match mode {
            PostMode::Isosurface(iso) => (lo as f64) <= iso && iso <= hi as f64,
            _ => prefix[hi as usize + 1] != prefix[lo as usize],
        };
    }
    Ok(())
}

const SUBSTEPS: u32 = 16;

/// Builds the pre-integration table for slabs `ratio` smallest spacings long:
/// entry `front·256 + back` is the premultiplied RGBA of a linear ramp from `front` to
/// `back`, composited front to back in 16 steps.
pub fn build_preintegration(
    opacity: &[u16; 256],
    color: &ColorTable,
    ratio: f64,
    table: &mut [Rgba],
) -> Result<(), Error> {
    need("pre-integration table", 65536, table.len())?;
    let sub = crate::classify::opacity_correction(ratio / SUBSTEPS as f64);
    // Opacity per sub-step per scalar, from the 8-bit-indexed correction of the Q15 TF.
    let mut a_sub = [0u32; 256];
    for (v, a) in a_sub.iter_mut().enumerate() {
        // The correction of the nearest 8-bit opacity, as `render` does per slice.
        // Interpolating between the two nearest entries instead changed the golden
        // cases' PSNR by 0.00 to −0.02 dB: not worth a second lookup.
        let a8 = ((opacity[v] as u32 * 255 + (1 << 14)) >> 15).min(255) as usize;
        *a = sub[a8] as u32;
    }
    for f in 0..256u32 {
        for b in 0..256u32 {
            let mut acc = [0u32; 4];
            for t in 0..SUBSTEPS {
                // Sample at the sub-step midpoint, rounded to the nearest table entry.
                let num = f * (2 * SUBSTEPS - 2 * t - 1) + b * (2 * t + 1);
                // At most 255 (front and back are); `min` shows it to the compiler.
                let s = (((num + SUBSTEPS) / (2 * SUBSTEPS)) as usize).min(255);
                let a = a_sub[s];
                if a == 0 {
                    continue;
                }
                let w = fixed::mul(ONE - acc[3], a);
                let c = color[s];
                for ch in 0..3 {
                    acc[ch] += fixed::mul(c[ch] as u32, w);
                }
                acc[3] += w;
            }
            table[(f * 256 + b) as usize] = acc.map(|x| x.min(ONE) as u16);
        }
    }
    Ok(())
}

/// Dense access to the permuted volume.
struct Dense<'a> {
    voxels: &'a [Voxel],
    n: [usize; 3],
    stride: [usize; 3],
}

impl Dense<'_> {
    /// The voxel at `(i, j, k)`, coordinates clamped to the volume (the field extends
    /// to the faces of the outer voxels' unit cells, as in the reference).
    #[inline(always)]
    fn at(&self, i: i64, j: i64, k: usize) -> Option<&Voxel> {
        // `max` then `min` rather than `clamp`, which panics on an empty range (a grid
        // has no empty side, but the compiler does not know that).
        let i = i.max(0).min(self.n[0] as i64 - 1) as usize;
        let j = j.max(0).min(self.n[1] as i64 - 1) as usize;
        let k = k.min(self.n[2].saturating_sub(1));
        self.voxels
            .get(i * self.stride[0] + j * self.stride[1] + k * self.stride[2])
    }
}

/// A bilinear sample in one slice: scalar (Q8) and interpolated shading (Q15).
struct Sample {
    s: u32,
    d: [u32; 3],
    sp: [u32; 3],
}

#[inline(always)]
/// With `face`, the clipping planes (in the view's roles) whose face is shaded as a
/// surface: a tap in its layer is shaded by the plane's normal, as a classified
/// volume's voxel is ([`Clip::with_shaded_face`]).
#[allow(clippy::too_many_arguments)]
fn sample(
    vol: &Dense<'_>,
    shade: &ShadeTable,
    i: i64,
    j: i64,
    k: usize,
    w: &[u32; 4],
    face: Option<&Clip>,
) -> Sample {
    let taps = [(i, j), (i + 1, j), (i, j + 1), (i + 1, j + 1)];
    let mut s = 0u32;
    let mut d = [0u32; 3];
    let mut sp = [0u32; 3];
    for (&(ti, tj), &wt) in taps.iter().zip(w) {
        if wt == 0 {
            continue;
        }
        if let Some(v) = vol.at(ti, tj, k) {
            s += wt * v.scalar as u32;
            let normal = face
                .and_then(|c| c.face_code([ti, tj, k as i64], 0))
                .unwrap_or(v.normal);
            let e = shade.entry(normal);
            let (dd, ss) = (e.diffuse, e.specular);
            for c in 0..3 {
                d[c] += wt * dd[c] as u32;
                sp[c] += wt * ss[c] as u32;
            }
        }
    }
    Sample {
        s: (s + (1 << 6)) >> 7, // Q15 weights · u8 → Q8
        d: d.map(|x| (x + (1 << 14)) >> 15),
        sp: sp.map(|x| (x + (1 << 14)) >> 15),
    }
}

/// Linear interpolation in a 256-entry table at a Q8 position.
#[inline(always)]
fn lerp_table(t: &[u16; 256], s: u32) -> u32 {
    let i = ((s >> 8) as usize).min(255);
    let f = s & 255;
    let a = t[i] as u32;
    let b = t[(i + 1).min(255)] as u32;
    (a * (256 - f) + b * f + 128) >> 8
}

#[inline(always)]
fn lerp_color(t: &ColorTable, s: u32) -> [u32; 3] {
    let i = ((s >> 8) as usize).min(255);
    let f = s & 255;
    let a = t[i];
    let b = t[(i + 1).min(255)];
    [0, 1, 2].map(|c| (a[c] as u32 * (256 - f) + b[c] as u32 * f + 128) >> 8)
}

/// Renders one frame of a dense classified-free volume: [`prepare`], [`composite_band`]
/// over the whole intermediate image, then the warp.
#[allow(clippy::too_many_arguments)]
pub fn render(
    grid: &Grid,
    voxels: &[Voxel],
    bricks: &[(u8, u8)],
    camera: &Camera,
    settings: &PostSettings<'_>,
    ws: &mut PostWorkspace<'_>,
    sink: &mut impl PixelSink,
) -> Result<(), Error> {
    need("voxels", grid.voxel_count(), voxels.len())?;
    need("out row", camera.width, ws.out_row.len())?;
    let tables = PostTables {
        visible: &mut *ws.visible,
        preint: &mut *ws.preint,
        shade: &mut *ws.shade,
    };
    let frame = prepare(grid, bricks, camera, settings, tables)?;
    let [iw, ih] = frame.view.intermediate;
    let mut img = Intermediate::new(iw, ih, ws.pixels, ws.links)?;
    composite_band(&frame, voxels, &mut img)?;
    warp::warp(img.pixels(), &frame.view, ws.out_row, sink)
}

/// The per-frame tables [`prepare`] fills, caller-owned (see [`PostWorkspace`] for
/// their sizes).
pub struct PostTables<'a> {
    /// One flag per brick ([`brick_count`]).
    pub visible: &'a mut [bool],
    /// Pre-integration table, 65 536 entries (only for [`PostMode::PreIntegrated`]).
    pub preint: &'a mut [Rgba],
    /// Shading table.
    pub shade: &'a mut ShadeTable,
}

/// One frame's view and the tables its bands read: what [`prepare`] computes once, so
/// that several threads can composite disjoint bands of scanlines
/// ([`composite_band`]) into memory of their own, as with the classified volumes
/// (Lacroute 1995, ch. 6). Every scanline's pixels depend on that scanline alone, so any
/// split gives the image one band gives.
pub struct PostFrame<'a> {
    /// The factored view.
    pub view: Factorization,
    grid: Grid,
    mode: PostMode,
    color: &'a ColorTable,
    /// Post-classified opacity per quantised scalar, corrected for the slice distance.
    corr: [u16; 256],
    preint: &'a [Rgba],
    shade: &'a ShadeTable,
    visible: &'a [bool],
    /// Early-ray-termination opacity, Q15 (above one: never).
    ert: u32,
    /// The isovalue, Q8.
    iso_q8: u32,
    /// The cells samples are taken in along the view's axes (i, j, k), in half voxels
    /// ([`Crop::cells`]): the crop box's, or the whole volume's.
    cells: [(i64, i64); 3],
    /// The clipping planes, their coefficients in the view's roles (i, j, k).
    clip: Clip,
}

/// Validates `settings`, factors the view and fills `tables` for one frame.
pub fn prepare<'a>(
    grid: &Grid,
    bricks: &[(u8, u8)],
    camera: &Camera,
    settings: &PostSettings<'a>,
    tables: PostTables<'a>,
) -> Result<PostFrame<'a>, Error> {
    need("bricks", brick_count(grid.dims), bricks.len())?;
    let view = Factorization::new(grid, camera)?;
    let PostTables {
        visible,
        preint,
        shade,
    } = tables;
    match settings.lighting {
        Some(l) => shade.fill(l, &view.rotation)?,
        None => *shade = ShadeTable::UNSHADED,
    }
    classify_bricks(bricks, settings.opacity, settings.mode, visible)?;
    if !(settings.ert_threshold > 0.0 && settings.ert_threshold <= 1.0) {
        return Err(Error::BadParameter {
            reason: "early-ray-termination threshold must be in (0, 1]",
        });
    }
    let ert = if settings.ert_threshold >= 1.0 {
        ONE + 1
    } else {
        fixed::from_f64(settings.ert_threshold)
    };
    // Per-slice opacity for post-classification (correction applied in Q15).
    let mut corr = [0u16; 256];
    let c8 = crate::classify::opacity_correction(view.step_ratio);
    for (v, c) in corr.iter_mut().enumerate() {
        let a8 = ((settings.opacity[v] as u32 * 255 + (1 << 14)) >> 15).min(255) as usize;
        *c = c8[a8];
    }
    if settings.mode == PostMode::PreIntegrated {
        build_preintegration(settings.opacity, settings.color, view.step_ratio, preint)?;
    }
    // The box, checked against this volume (it may have been made for another).
    let c = settings.crop.unwrap_or(Crop::whole(grid.dims));
    let cells = Crop::new(c.lo(), c.hi(), grid.dims)?.cells();
    let iso_q8 = match settings.mode {
        PostMode::Isosurface(v) => {
            if !(v.is_finite() && (0.0..=255.0).contains(&v)) {
                return Err(Error::BadParameter {
                    reason: "isovalue must be within the quantised range 0..255",
                });
            }
            (v * 256.0 + 0.5) as u32
        }
        _ => 0,
    };
    Ok(PostFrame {
        view,
        grid: *grid,
        mode: settings.mode,
        color: settings.color,
        corr,
        preint,
        shade,
        visible,
        ert,
        iso_q8,
        cells: view.permute(cells),
        clip: settings.clip.permuted(|q| view.permute(q)),
    })
}

/// Composites every slab of `frame` into the scanlines `img` holds (the whole
/// intermediate image, or a band of it: [`Intermediate::band`]); `voxels` is the volume
/// `frame` was prepared for.
pub fn composite_band(
    frame: &PostFrame<'_>,
    voxels: &[Voxel],
    img: &mut Intermediate<'_>,
) -> Result<(), Error> {
    // Two builds of the loop: without planes, the coverage code is compiled out (it cost
    // 2–4 % more instructions in the band when it was only branched around).
    if frame.clip.is_empty() {
        composite_band_clipped::<false>(frame, voxels, img)
    } else {
        composite_band_clipped::<true>(frame, voxels, img)
    }
}

/// [`composite_band`], taking the clipping planes into account only if `CLIPPED`.
fn composite_band_clipped<const CLIPPED: bool>(
    frame: &PostFrame<'_>,
    voxels: &[Voxel],
    img: &mut Intermediate<'_>,
) -> Result<(), Error> {
    let (grid, view) = (&frame.grid, &frame.view);
    need("voxels", grid.voxel_count(), voxels.len())?;
    if [img.width(), img.height()] != view.intermediate {
        return Err(Error::BadParameter {
            reason: "band is not of the frame's intermediate image",
        });
    }
    let (ert, iso_q8, corr) = (frame.ert, frame.iso_q8, &frame.corr);
    // An isosurface ends at the cut rather than filling it: no face to shade there.
    let surface = matches!(frame.mode, PostMode::Isosurface(_));
    let face = (CLIPPED && !surface && frame.clip.shades_face()).then_some(&frame.clip);
    let (row0, rows) = (img.first_row(), img.rows());
    let [iw, _] = view.intermediate;
    let ostride = [1, grid.dims[0], grid.dims[0] * grid.dims[1]];
    let vol = Dense {
        voxels,
        n: view.dims,
        stride: view.permute(ostride),
    };
    let nb_obj = grid.dims.map(|n| n.div_ceil(BRICK));
    let nb = view.permute(nb_obj);
    let bstride_obj = [1, nb_obj[0], nb_obj[0] * nb_obj[1]];
    let bstride = view.permute(bstride_obj);
    let nk = view.dims[2];
    // Samples lie in the cells of the crop box (the whole volume without one), in Q15.
    let half = ONE as i64 / 2;
    let [(i_lo, i_hi), (j_lo, j_hi), (k_lo, k_hi)] = frame.cells;
    let (i_lo, i_hi, j_lo, j_hi) = (i_lo * half, i_hi * half, j_lo * half, j_hi * half);
    // A slice is inside when its cell's centre is: cells in half voxels, slices whole.
    let slice_in = |k: usize| (k_lo..=k_hi).contains(&(2 * k as i64));
    let q = ONE as i64;
    let slabs = match frame.mode {
        PostMode::PostClassified => nk,
        _ => nk.saturating_sub(1),
    };
    for idx in 0..slabs {
        let kf = view.slice_at(idx);
        let kb = if frame.mode == PostMode::PostClassified {
            kf
        } else {
            view.slice_at(idx + 1)
        };
        if !slice_in(kf) || !slice_in(kb) {
            continue;
        }
        let [fu, fv] = view.slice_offset(kf);
        let [bu, bv] = view.slice_offset(kb);
        let wf = fixed::bilinear_weights(fu.f, fv.f);
        let wb = fixed::bilinear_weights(bu.f, bv.f);
        let bk = (kf / BRICK).min(nb[2] - 1);
        let (kf_q, kb_q) = ((kf as i64) << 15, (kb as i64) << 15);
        for v in row0..row0 + rows {
            let jt = v as i64 - fv.n as i64 - 1;
            if jt < -1 || jt >= view.dims[1] as i64 {
                continue;
            }
            let jb = v as i64 - bv.n as i64 - 1;
            let vpos = (v as i64 - fv.n as i64) * ONE as i64 - fv.f as i64;
            let row_in = j_lo <= vpos && vpos <= j_hi;
            let vpos_b = (v as i64 - bv.n as i64) * q - bv.f as i64;
            let bj = (((jt + 1).max(0) as usize) / BRICK).min(nb[1] - 1);
            let brow = bk * bstride[2] + bj * bstride[1];
            for bi in 0..nb[0] {
                if !frame
                    .visible
                    .get(brow + bi * bstride[0])
                    .copied()
                    .unwrap_or(false)
                {
                    continue;
                }
                // Pixels whose right voxel (u − n − 1 + 1) falls in this brick; the last
                // brick also takes the pixel past the volume's edge.
                let r0 = bi * BRICK;
                let r1 = if bi + 1 == nb[0] {
                    view.dims[0] + 1
                } else {
                    r0 + BRICK
                };
                let u0 = (r0 as i64 + fu.n as i64).clamp(0, iw as i64) as usize;
                let u1 = (r1 as i64 + fu.n as i64).clamp(0, iw as i64) as usize;
                let (pixels, opaque) = img.scanline_mut(v - row0);
                let mut u = u0;
                while u < u1 {
                    if crate::opaque::is_opaque(opaque, u) {
                        u = crate::opaque::next_open(opaque, iw, u, u1);
                        continue;
                    }
                    let il = u as i64 - fu.n as i64 - 1;
                    // Position u − n − f of the sample in the slice, in halves of Q15.
                    let pos = (u as i64 - fu.n as i64) * ONE as i64 - fu.f as i64;
                    if pos < i_lo || pos > i_hi || !row_in {
                        u += 1;
                        continue;
                    }
                    // Coverage by the clipping planes, where the mode's sample is: the
                    // slice's sample, the middle of a slab, or (isosurfaces, below)
                    // the crossing.
                    let front = [pos, vpos, kf_q];
                    let back = || [(u as i64 - bu.n as i64) * q - bu.f as i64, vpos_b, kb_q];
                    let cov = match frame.mode {
                        _ if !CLIPPED => 1 << 16,
                        PostMode::PostClassified => frame.clip.coverage(front, 15),
                        PostMode::PreIntegrated => {
                            let b = back();
                            frame
                                .clip
                                .coverage([0, 1, 2].map(|a| (front[a] + b[a]) / 2), 15)
                        }
                        PostMode::Isosurface(_) => 1 << 16,
                    };
                    if cov == 0 {
                        u += 1;
                        continue;
                    }
                    let f = sample(&vol, frame.shade, il, jt, kf, &wf, face);
                    let Some(px) = pixels.get_mut(u) else {
                        break;
                    };
                    let (rgb, a) = match frame.mode {
                        PostMode::PostClassified => {
                            let a = ((lerp_table(corr, f.s) as u64 * cov as u64) >> 16) as u32;
                            let c = lerp_color(frame.color, f.s);
                            let rgb = [0, 1, 2]
                                .map(|ch| (fixed::mul(c[ch], f.d[ch]) + f.sp[ch]).min(ONE));
                            (rgb.map(|x| fixed::mul(x, a)), a)
                        }
                        PostMode::PreIntegrated => {
                            let ilb = u as i64 - bu.n as i64 - 1;
                            let b = sample(&vol, frame.shade, ilb, jb, kb, &wb, face);
                            let fi = ((f.s + 128) >> 8).min(255) as usize;
                            let bi_ = ((b.s + 128) >> 8).min(255) as usize;
                            let e = frame
                                .preint
                                .get(fi * 256 + bi_)
                                .copied()
                                .unwrap_or_default();
                            let part = |x: u16| ((x as u64 * cov as u64) >> 16) as u32;
                            let a = part(e[3]);
                            let rgb = [0, 1, 2].map(|ch| {
                                let d = (f.d[ch] + b.d[ch]) / 2;
                                let s = (f.sp[ch] + b.sp[ch]) / 2;
                                (fixed::mul(part(e[ch]), d) + fixed::mul(a, s)).min(a)
                            });
                            (rgb, a)
                        }
                        PostMode::Isosurface(_) => {
                            let ilb = u as i64 - bu.n as i64 - 1;
                            let b = sample(&vol, frame.shade, ilb, jb, kb, &wb, face);
                            let (lo, hi) = (f.s.min(b.s), f.s.max(b.s));
                            if iso_q8 < lo || iso_q8 > hi || lo == hi {
                                u += 1;
                                continue;
                            }
                            // Position of the crossing between front (0) and back (1).
                            let t = ((iso_q8 as i64 - f.s as i64) * ONE as i64
                                / (b.s as i64 - f.s as i64))
                                .clamp(0, ONE as i64) as u32;
                            // A crossing beyond a plane is cut away whole: the surface
                            // ends at the plane, which shows what it encloses.
                            if CLIPPED {
                                let b = back();
                                let at = [0, 1, 2]
                                    .map(|a| front[a] + (((b[a] - front[a]) * t as i64) >> 15));
                                if frame.clip.coverage(at, 15) < 1 << 15 {
                                    u += 1;
                                    continue;
                                }
                            }
                            let c = lerp_color(frame.color, iso_q8);
                            let rgb = [0, 1, 2].map(|ch| {
                                let d = fixed::mul(f.d[ch], ONE - t) + fixed::mul(b.d[ch], t);
                                let s = fixed::mul(f.sp[ch], ONE - t) + fixed::mul(b.sp[ch], t);
                                (fixed::mul(c[ch], d) + s).min(ONE)
                            });
                            (rgb, ONE)
                        }
                    };
                    if a != 0 {
                        let tr = ONE - px[3] as u32;
                        for ch in 0..3 {
                            px[ch] = (px[ch] as u32 + fixed::mul(rgb[ch], tr)).min(ONE) as u16;
                        }
                        px[3] = (px[3] as u32 + fixed::mul(a, tr)).min(ONE) as u16;
                        if px[3] as u32 >= ert {
                            crate::opaque::mark(opaque, u);
                        }
                    }
                    u += 1;
                }
            }
        }
    }
    Ok(())
}
