//! Front-to-back compositing of sheared slices into the intermediate image
//! (Lacroute 1995, §4.1).
//!
//! For each slice the two voxel scanlines that straddle an intermediate scanline are
//! resampled bilinearly (the weights are the same for every pixel of the slice, because
//! the shear translates whole slices) and composited with the "over" operator.
//!
//! Work is skipped in two ways, both exact:
//! - the run-length-encoded voxel scanlines are walked in lockstep and only pixels whose
//!   footprint touches a non-transparent voxel are visited;
//! - pixels that reached the early-ray-termination opacity are skipped through a bitmap
//!   of opaque pixels ([`crate::opaque`]), which also tells each voxel row which of its
//!   voxels an open pixel will read, so only those are shaded.
//!
//! All arithmetic is Q15 integer. Voxel colours are shaded once per voxel row and slice
//! into a row buffer (premultiplied RGBA); each row is used by two intermediate scanlines.

mod flat;
pub(crate) use flat::words as flat_words;

/// Sets bit `at + i` of `words` for each flat voxel `src[i]` ([`flat::mark`] with the
/// portable kernel): how a table of flat voxels is filled
/// ([`crate::rle::RleAxis::fill_flat_rows`]), as the compositor marks its rows.
pub(crate) fn mark_flat(words: &mut [Rgba], at: usize, src: &[Voxel]) -> bool {
    flat::mark(words, at, src, src.len(), kernels::flat_bits)
}
mod kernels;
mod row;
mod shading;

#[cfg(target_arch = "x86_64")]
pub(crate) use flat::sums as flat_sums;
#[cfg(target_arch = "x86_64")]
pub(crate) use kernels::{
    by_steps, closed_bits, closed_bits_avx2, flat_bits, flat_bits_avx2, flat_sums_avx2, highest,
    over_run, over_run_simd, over_run_unranked, premultiply, premultiply_sse41, With,
};
pub(crate) use kernels::{Kernels, Portable};
pub(crate) use row::{MergedSpans, Row, Spans};
use row::{Needed, Reach};
#[cfg(target_arch = "x86_64")]
pub(crate) use shading::{Cued, ExcludingFlat, Lit, Mip};
pub(crate) use shading::{FlatRule, Shading, Way};

use crate::classify::{ColorLanes, Voxel};
use crate::clip::{RowCut, SliceCut};
use crate::error::{need, Error};
use crate::fixed::{self, ONE};
use crate::opaque;
use crate::rle::RleSlice;
use crate::shade::ShadeTable;
use crate::shadow::ShadowLookup;
use crate::view::{Factorization, SliceOffset};

/// Premultiplied RGBA, Q15 per channel.
pub type Rgba = [u16; 4];

/// Compositing mode.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// Front-to-back "over" compositing of shaded, classified samples.
    Composite,
    /// Maximum intensity projection of the resampled 8-bit scalar (grey output).
    /// Voxels classified transparent count as zero, so the opacity transfer function
    /// acts as a window.
    Mip,
}

/// Opacity-corrected Q15 opacity per stored 8-bit opacity. The entries are 32 bits wide
/// so that the vector shading kernels broadcast one straight from memory, but hold
/// 16-bit values: a table is made only from a `[u16; 256]`, so an opacity times any
/// Q15 factor fits 32 bits and every kernel reads the same value.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(transparent)]
pub struct OpacityTable([u32; 256]);

impl From<[u16; 256]> for OpacityTable {
    fn from(t: [u16; 256]) -> Self {
        OpacityTable(t.map(u32::from))
    }
}

impl OpacityTable {
    /// The corrected opacity of stored opacity `stored`.
    #[inline(always)]
    pub fn get(&self, stored: u8) -> u32 {
        self.0[stored as usize]
    }
}

/// Per-frame lookup tables the compositor reads.
#[derive(Clone, Copy)]
pub struct SliceTables<'a> {
    /// Opacity-corrected Q15 opacity per stored 8-bit opacity.
    pub opacity: &'a OpacityTable,
    /// Q15 RGB (and a padding lane) per quantised scalar.
    pub color: &'a ColorLanes,
    /// Shading per normal code ([`ShadeTable::UNSHADED`] for none).
    pub shade: &'a ShadeTable,
    /// Mode.
    pub mode: Mode,
    /// Early-ray-termination opacity, Q15; pixels at or above it are never touched again.
    pub ert: u32,
    /// Depth cueing, if on.
    pub depth: Option<&'a crate::depth::DepthFrame>,
    /// With shadows: the shading of the first light alone (then `shade` holds the
    /// ambient term and the other lights).
    pub shade0: Option<&'a ShadeTable>,
    /// Perspective views: the per-ray opacity-correction gains.
    pub ray_gain: Option<&'a crate::perspective::RayGain>,
    /// How flat voxels enter a sample's colour ([`FlatVoxels`]).
    pub flat_voxels: FlatVoxels,
    /// Clipping planes in the view's roles, if any ([`crate::clip::Clip::permuted`]):
    /// each voxel row is cut as it is shaded ([`crate::clip::RowCut`]).
    pub clip: Option<&'a crate::clip::Clip>,
}

/// How voxels with an exactly zero gradient (plateaus of the data, shaded as
/// unoriented: ambient plus full diffuse light) enter a resampled sample's colour.
///
/// A ray caster that interpolates gradients and normalises them per sample gives a
/// sample between a plateau and an edge the edge's direction whole. Shading per voxel
/// and interpolating colours, as shear-warp does, mixes the plateau's full light into
/// it instead, which lights up the rims of objects made of plateaus at grazing angles
/// (segmented or synthetic volumes; scanned data has almost no exact plateaus). See
/// BENCHMARKS.md for what each costs. The default here is `Blended`, which costs
/// nothing to find; the frontends take [`FlatVoxels::for_volume`]'s way for the volume
/// unless told otherwise (`--flat-voxels`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum FlatVoxels {
    /// Interpolated like every other voxel: the fastest.
    #[default]
    Blended,
    /// Left out of the colour of a sample that also has voxels with a direction (their
    /// weighted colour is scaled to the sample's opacity, which is unchanged): the
    /// per-sample normalisation's result, in parallel projection (perspective views
    /// blend them).
    Excluded,
}

impl FlatVoxels {
    /// A volume's flat voxels are excluded when at least one in `AUTO_SHARE` of its
    /// voxels with opacity is flat. Measured at the benchmark's looks: the MR heads and
    /// brains have 0.04–1.7 % flat voxels, where the rule moves PSNR by 0.001 dB at most
    /// and costs 2–6 % of a frame; the nested spheres 42–94 %, where it gains 0.5 dB
    /// (256³) to 5.8 dB (64³) against the reference ray caster.
    pub const AUTO_SHARE: u64 = 16;

    /// Its name in the frontends' options and reports: `blended` or `excluded`.
    pub const fn name(self) -> &'static str {
        match self {
            FlatVoxels::Blended => "blended",
            FlatVoxels::Excluded => "excluded",
        }
    }

    /// The way for a volume with `visible` voxels of some opacity, `flat` of them with a
    /// zero gradient: [`FlatVoxels::Excluded`] when the flat ones are at least one in
    /// [`FlatVoxels::AUTO_SHARE`], where samples that mix them with edges are common
    /// enough to show; [`FlatVoxels::Blended`] otherwise, where the rule would cost time
    /// and change nothing to see.
    pub const fn for_volume(flat: u64, visible: u64) -> Self {
        if flat > 0 && flat.saturating_mul(Self::AUTO_SHARE) >= visible {
            FlatVoxels::Excluded
        } else {
            FlatVoxels::Blended
        }
    }
}

/// The intermediate image, or a band of its scanlines: pixels plus the bitmap of opaque
/// pixels. Bands let several threads composite disjoint scanline ranges of one frame into
/// caller-owned memory (Lacroute 1995, ch. 6 partitions the intermediate image the same
/// way).
pub struct Intermediate<'a> {
    width: usize,
    height: usize,
    row0: usize,
    rows: usize,
    pub(crate) pixels: &'a mut [Rgba],
    /// Opaque-pixel bitmap, [`opaque::words`]`(width)` words per scanline.
    opaque: &'a mut [opaque::Word],
    stride: usize,
}

impl<'a> Intermediate<'a> {
    /// Borrows `pixels` (at least `width·height` entries) and `links` and clears them.
    /// `links` holds the opaque-pixel bitmap: at least [`opaque::words`]`(width)` entries
    /// per scanline. `width·height`, which the per-pixel links of earlier versions took,
    /// is always enough, so existing callers keep working.
    pub fn new(
        width: usize,
        height: usize,
        pixels: &'a mut [Rgba],
        links: &'a mut [opaque::Word],
    ) -> Result<Self, Error> {
        Self::band(width, height, 0, height, pixels, links)
    }

    /// Scanlines `row0..row0 + rows` of a `width×height` intermediate image, stored in
    /// `pixels` (at least `width·rows` entries) and `links` (at least
    /// [`opaque::words`]`(width)·rows`), both cleared here.
    pub fn band(
        width: usize,
        height: usize,
        row0: usize,
        rows: usize,
        pixels: &'a mut [Rgba],
        links: &'a mut [opaque::Word],
    ) -> Result<Self, Error> {
        if width >= u16::MAX as usize {
            return Err(Error::BadParameter {
                reason: "intermediate image wider than 65534 pixels",
            });
        }
        if row0 > height || rows > height - row0 {
            return Err(Error::BadParameter {
                reason: "band lies outside the intermediate image",
            });
        }
        let n = width * rows;
        let stride = opaque::words(width);
        need("intermediate pixels", n, pixels.len())?;
        need("intermediate links", stride * rows, links.len())?;
        let pixels = &mut pixels[..n];
        let opaque = &mut links[..stride * rows];
        pixels.fill([0; 4]);
        opaque.fill(0);
        Ok(Intermediate {
            width,
            height,
            row0,
            rows,
            pixels,
            opaque,
            stride,
        })
    }

    /// Keeps the first `rows` scanlines and returns the others, with their pixels and
    /// opaque bits as they are, as a band of their own. A thread that has run out of
    /// work takes over half of another's band this way between two slices, and
    /// composites the remaining slices into it ([`crate::render::composite_band_until`]
    /// from the position the other reached): the two bands then give the same pixels
    /// as the one would have.
    pub fn split_off(&mut self, rows: usize) -> Result<Intermediate<'a>, Error> {
        if rows > self.rows {
            return Err(Error::BadParameter {
                reason: "band split below its last scanline",
            });
        }
        let (p, tail_p) = core::mem::take(&mut self.pixels).split_at_mut(rows * self.width);
        let (o, tail_o) = core::mem::take(&mut self.opaque).split_at_mut(rows * self.stride);
        self.pixels = p;
        self.opaque = o;
        let tail = Intermediate {
            width: self.width,
            height: self.height,
            row0: self.row0 + rows,
            rows: self.rows - rows,
            pixels: tail_p,
            opaque: tail_o,
            stride: self.stride,
        };
        self.rows = rows;
        Ok(tail)
    }

    /// Scanlines held.
    pub fn rows(&self) -> usize {
        self.rows
    }

    /// Width in pixels.
    pub fn width(&self) -> usize {
        self.width
    }
    /// Height of the whole intermediate image.
    pub fn height(&self) -> usize {
        self.height
    }
    /// First scanline held.
    pub fn first_row(&self) -> usize {
        self.row0
    }
    /// Pixels of the held scanlines, row-major.
    pub fn pixels(&self) -> &[Rgba] {
        self.pixels
    }

    /// The opaque-pixel bitmap of held scanline `r` (relative to the band), or an empty
    /// slice (every pixel open) past the band.
    pub(crate) fn opaque_line(&self, r: usize) -> &[opaque::Word] {
        self.opaque
            .get(r * self.stride..(r + 1) * self.stride)
            .unwrap_or_default()
    }

    /// Pixels and opaque-pixel bitmap of held scanline `r` (relative to the band), or
    /// two empty slices past the band.
    #[cfg_attr(target_arch = "x86_64", inline(always))]
    pub(crate) fn scanline_mut(&mut self, r: usize) -> (&mut [Rgba], &mut [opaque::Word]) {
        let (w, s) = (self.width, self.stride);
        match (
            self.pixels.get_mut(r * w..(r + 1) * w),
            self.opaque.get_mut(r * s..(r + 1) * s),
        ) {
            (Some(p), Some(o)) => (p, o),
            _ => (&mut [], &mut []),
        }
    }

    /// Applies the per-pixel depth-cue factor to every held scanline.
    pub fn apply_depth_cue(&mut self, d: &crate::depth::DepthFrame) {
        if self.width == 0 {
            return;
        }
        for (r, row) in self.pixels.chunks_mut(self.width).enumerate() {
            d.apply_row(self.row0 + r, row);
        }
    }
}

/// Row-buffer entries the compositor needs for slices `ni` voxels wide in parallel
/// projection: two rows with a guard entry on each side, and each row's bits for its
/// flat voxels (see [`FlatVoxels`]), one per entry in 64-bit words.
pub const fn row_buffer_len(ni: usize) -> usize {
    2 * (ni + 2) + 2 * flat::words(ni)
}

/// Row-buffer entries [`composite_slice`] needs for `view` (perspective views need a
/// ring of intermediate-width rows, see [`crate::perspective::row_buffer_len`]).
pub fn rows_needed(view: &Factorization) -> usize {
    match view.perspective {
        Some(_) => crate::perspective::row_buffer_len(view),
        None => row_buffer_len(view.dims[0]),
    }
}

/// One slice to composite: slice `k` into the scanlines `img` holds, with `rows` as the
/// row buffer, all zero if `clean` ([`Kernels::perspective`], and the parallel scanline
/// loop).
pub(crate) struct SliceJob<'a, 'b> {
    pub img: &'a mut Intermediate<'b>,
    pub slice: &'a RleSlice<'a>,
    pub k: usize,
    pub view: &'a Factorization,
    pub tables: &'a SliceTables<'a>,
    pub rows: &'a mut [Rgba],
    pub clean: bool,
}

/// Composites slice `k` into the scanlines `img` holds. `rows` must hold
/// [`rows_needed`]`(view)` entries (any contents: they are cleared first).
pub fn composite_slice(
    img: &mut Intermediate<'_>,
    slice: &RleSlice<'_>,
    k: usize,
    view: &Factorization,
    tables: &SliceTables<'_>,
    rows: &mut [Rgba],
    shadow: Option<&ShadowLookup<'_>>,
) -> Result<(), Error> {
    composite_slice_in(img, slice, k, view, tables, rows, shadow, false, &Portable)
}

/// [`composite_slice`] with `clean` saying whether `rows` is all zero on entry (every
/// path leaves it all zero again on success, so a caller compositing slice after slice
/// clears it once instead of once per slice and band), and `warm` called on each voxel
/// row two rows before the loop reads it ([`kernels::touch`], or a prefetch).
// Inlined on x86-64 so that the instruction-set builds of
// [`crate::render::composite_band_until`] compile this loop for their own features (a
// function that is not inlined keeps the baseline build); bare-metal targets keep one
// copy, for flash.
#[allow(clippy::too_many_arguments)]
#[cfg_attr(target_arch = "x86_64", inline(always))]
pub(crate) fn composite_slice_in(
    img: &mut Intermediate<'_>,
    slice: &RleSlice<'_>,
    k: usize,
    view: &Factorization,
    tables: &SliceTables<'_>,
    rows: &mut [Rgba],
    shadow: Option<&ShadowLookup<'_>>,
    clean: bool,
    kern: &impl Kernels,
) -> Result<(), Error> {
    let [ni, nj, _] = view.dims;
    if slice.ni != ni || slice.nj != nj {
        return Err(Error::MalformedRle {
            reason: "slice dimensions do not match the view",
        });
    }
    let job = SliceJob {
        img,
        slice,
        k,
        view,
        tables,
        rows,
        clean,
    };
    if view.perspective.is_some() {
        if shadow.is_some() {
            return Err(Error::BadParameter {
                reason: "shadows are not available in perspective views",
            });
        }
        return kern.perspective(job);
    }
    need("row buffer", row_buffer_len(ni), job.rows.len())?;
    if view.supersample > 1 {
        let SliceJob { img, rows, .. } = job;
        return composite_slice_supersampled(
            img, slice, k, view, tables, rows, shadow, clean, kern,
        );
    }
    let scale = tables.depth.map_or(ONE, |d| d.slice_factor(k));
    let way = Way::of(tables, shadow, scale);
    // Slices cut by clipping planes take a loop of their own, out of line, which asks
    // the way on every run: the loops of slices without planes, or that the planes keep
    // whole, stay as they were (with the planes' bounds in them, the Colin27 head's
    // unclipped frames took 6 % more instructions).
    let cut = tables.clip.and_then(|c| c.slice(k as i64, [ni, nj]));
    #[cfg(target_arch = "x86_64")]
    if let Some(cut) = &cut {
        return composite_rows_cut(job, kern, way, cut);
    }
    #[cfg(target_arch = "x86_64")]
    if way.excludes_flat(tables) {
        return kern.composite_flat(job, way);
    }
    #[cfg(target_arch = "x86_64")]
    match way {
        Way::Lit => composite_rows(job, kern, &Lit, None),
        Way::Cued(scale) => composite_rows(job, kern, &Cued(scale), None),
        Way::Shadowed(s) => composite_rows(job, kern, &s, None),
        Way::Mip => composite_rows(job, kern, &Mip, None),
    }
    #[cfg(not(target_arch = "x86_64"))]
    composite_rows(job, kern, &way, cut.as_ref())
}

/// [`composite_rows`] for a slice cut by clipping planes `cut`, shaded `way`.
#[cfg(target_arch = "x86_64")]
#[inline(never)]
fn composite_rows_cut(
    job: SliceJob<'_, '_>,
    kern: &impl Kernels,
    way: Way<'_, '_>,
    cut: &SliceCut,
) -> Result<(), Error> {
    composite_rows(job, kern, &way, Some(cut))
}

/// [`composite_rows`] for a slice shaded `way` with flat voxels excluded from samples'
/// colours ([`FlatVoxels::Excluded`]): the slice loop of [`ExcludingFlat`] ways, which
/// marks the rows' flat voxels and composites the spans they reach inline. Targets
/// that compile one loop for every way apply the rule in it instead, as the tables
/// ask ([`shading::FlatRule::AsAsked`]): a second loop there took 15 KB more flash
/// on the Cortex-M3, and changed how the first was compiled (1 % more instructions a
/// frame).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) fn composite_rows_excluding(
    job: SliceJob<'_, '_>,
    kern: &impl Kernels,
    way: Way<'_, '_>,
) -> Result<(), Error> {
    match way {
        Way::Lit => composite_rows(job, kern, &ExcludingFlat(Lit), None),
        Way::Cued(scale) => composite_rows(job, kern, &ExcludingFlat(Cued(scale)), None),
        Way::Shadowed(s) => composite_rows(job, kern, &ExcludingFlat(s), None),
        // MIP has no shading, so no flat voxels to exclude.
        Way::Mip => composite_rows(job, kern, &Mip, None),
    }
}

/// [`composite_rows_excluding`] with the portable kernels, in a function of its own:
/// [`Kernels::composite_flat`] of [`Portable`].
#[cfg(target_arch = "x86_64")]
#[inline(never)]
pub(crate) fn composite_flat_portable(
    job: SliceJob<'_, '_>,
    way: Way<'_, '_>,
) -> Result<(), Error> {
    composite_rows_excluding(job, &Portable, way)
}

/// The scanline loop of [`composite_slice_in`] for one [`Shading`], cutting each row
/// by the clipping planes over the slice, `cut`, if any (the callers that have none
/// pass `None` itself, so that their inlined loops hold no cutting).
#[cfg_attr(target_arch = "x86_64", inline(always))]
fn composite_rows<S: Shading>(
    job: SliceJob<'_, '_>,
    kern: &impl Kernels,
    shading: &S,
    cut: Option<&SliceCut>,
) -> Result<(), Error> {
    let SliceJob {
        img,
        slice,
        k,
        view,
        tables,
        rows,
        clean,
    } = job;
    let [ni, nj, _] = view.dims;
    let [ou, ov]: [SliceOffset; 2] = view.slice_offset(k);
    let (mut r0, mut r1) = Row::pair(rows, ni, clean);
    // The loops that always apply the rule copy a row's flat bits from the slice's table
    // of flat voxels ([`crate::rle::RleAxis::with_flat_rows`]), when it has one, instead
    // of finding them in the voxels. The others are given none.
    let table = S::FLAT == FlatRule::Always && !slice.flat.is_empty();
    let flat_of = |j: i64| if table { slice.flat_row(j) } else { &[] };
    // Swapped by reference: a row carries its written runs, too large to swap by value
    // every scanline.
    let (mut top, mut bot) = (&mut r0, &mut r1);
    // Weights: f weighs the left column / top row.
    let w = fixed::bilinear_weights(ou.f, ov.f);
    let width = img.width;
    // Scanline v reads voxel rows jt = v − n_v − 1 and jt + 1.
    let band_lo = img.row0 as i64;
    let band_hi = (img.row0 + img.rows) as i64;
    let jt_lo = (band_lo - ov.n as i64 - 1).max(-1);
    let jt_hi = (band_hi - ov.n as i64 - 1).min(nj as i64 - 1);
    if jt_lo > jt_hi {
        return Ok(());
    }
    // Scanline jt reads rows jt and jt + 1: only those from the row before the first
    // non-empty one to the last non-empty one composite anything (a brain slice's empty
    // rows lie mostly at its two ends).
    let Some((j_first, j_last)) = slice.visible_rows(jt_lo.max(0) as usize, (jt_hi + 1) as usize)
    else {
        return Ok(());
    };
    let jt_lo = jt_lo.max(j_first as i64 - 1);
    let jt_hi = jt_hi.min(j_last as i64);
    let empty: (&[u8], &[Voxel]) = (&[], &[]);
    let row_of = |j: i64| slice.row(j);
    let first = row_of(jt_lo);
    // Row j is read by scanlines j + n_v (as the bottom row) and j + n_v + 1 (top).
    // In MIP no pixel becomes opaque, so every voxel is needed.
    let skip_opaque_voxels = tables.mode == Mode::Composite;
    // Clipping planes cut each row as it is shaded.
    let row_cut = |j: i64| cut.map(|c| c.row(j, ni));
    {
        let need = Needed::lines(img, jt_lo + ov.n as i64, ou.n as i64);
        let need = skip_opaque_voxels.then_some(&need);
        top.fill(
            (first.0, first.1, flat_of(jt_lo)),
            tables,
            jt_lo,
            need,
            row_cut(jt_lo).as_ref(),
            kern,
            shading,
        );
    }
    // What open pixels read of the rows two rows ahead, by row index mod 4. A row whose
    // every voxel only closed pixels read is neither streamed into the cache nor walked:
    // pixels only ever close, so a row hidden then is still hidden when its turn comes.
    // A row whose reach held no closed pixel then is shaded whole, without the
    // per-voxel test of which voxels open pixels read: voxels that only pixels closed
    // since then read are shaded for nothing, and no pixel reads them.
    // In MIP no pixel closes: every row is read whole. The first two rows' reach is
    // asked here, as the loop asks each later row's: since the slice starts at its first
    // non-empty row, they are rarely empty (the Cortex-M3 frame: 1.7 % fewer
    // instructions than taking them as read in part).
    let first_reach = if skip_opaque_voxels {
        Reach::Some
    } else {
        Reach::Everything
    };
    let mut reach = [first_reach; 4];
    // The scanlines of rows jt + 1 ..= jt + 3 by row index mod 4, each looked up once.
    let mut scans = [empty; 4];
    for j in jt_lo + 1..jt_lo + 3 {
        let row = row_of(j);
        scans[j.rem_euclid(4) as usize] = row;
        if skip_opaque_voxels {
            let r = Needed::lines(img, j + ov.n as i64, ou.n as i64).reach(row.0, ni);
            reach[j.rem_euclid(4) as usize] = r;
        }
    }
    // A half-open range: an inclusive one carries an exhaustion flag through every step
    // (the hires brain, callgrind: 0.6 % fewer instructions a frame; 0.8 % less time).
    // On x86-64 rows jt + 3 are taken in order, each from where the one before ended
    // (the hires brain, callgrind: 1.2 % fewer instructions a frame than a lookup of
    // each; alternating, 0.5–1 % less time). The Cortex-M3 frame took 1.2 % more
    // instructions so: there each is looked up.
    #[cfg(target_arch = "x86_64")]
    let mut rows_ahead = slice.scanlines_from(jt_lo + 3);
    for jt in jt_lo..jt_hi + 1 {
        let next = scans[(jt + 1).rem_euclid(4) as usize];
        #[cfg(target_arch = "x86_64")]
        let ahead = rows_ahead.next_row();
        #[cfg(not(target_arch = "x86_64"))]
        let ahead = row_of(jt + 3);
        scans[(jt + 3).rem_euclid(4) as usize] = ahead;
        let r = if skip_opaque_voxels {
            Needed::lines(img, jt + 3 + ov.n as i64, ou.n as i64).reach(ahead.0, ni)
        } else {
            Reach::Everything
        };
        reach[(jt + 3).rem_euclid(4) as usize] = r;
        // A row read whole is warmed whole. Of a row read in part, open pixels mostly
        // read the voxels at its two ends (the rim of what is already opaque), so only
        // its first and last 32 voxels (two cache lines each) are warmed: warming it
        // whole streamed the rest of it into the cache for nothing, and cost more time
        // than the instructions it took (alternating runs, one thread, 256²: brainsmall
        // 1.11 → 1.04 ms, the head 4.86 → 4.45, the hires brain 13.97 → 13.23,
        // spheres256 17.01 → 16.14; warming none of it, the hires brain took 15.0 ms).
        // Bare-metal targets have no data cache to warm. `touch` does nothing there
        // either; this arm also spares the slices it would be handed (the Cortex-M3
        // frame: 0.5 % fewer instructions).
        match r {
            _ if cfg!(target_os = "none") => {}
            Reach::Nothing => {}
            Reach::Everything => kern.warm(ahead.1),
            Reach::Some => {
                let v = ahead.1;
                let n = v.len().min(32);
                kern.warm(v.get(..n).unwrap_or_default());
                kern.warm(v.get(v.len() - n..).unwrap_or_default());
            }
        }
        let next_reach = reach[(jt + 1).rem_euclid(4) as usize];
        // A hidden row after an empty one, with the other buffer already clear: scanline
        // jt + n_v + 1 reads nothing, so the row is passed over without clearing,
        // looking up or compositing anything (the back slices of a head are mostly such
        // rows; the hires brain, callgrind: 2.4 % fewer instructions a frame; alternating,
        // one thread, 256²: 1–4 % less time). Not on bare-metal targets, whose small
        // volumes have few of them (the Cortex-M3 frame: 1.1 % more instructions).
        if !cfg!(target_os = "none")
            && next_reach == Reach::Nothing
            && top.extent().is_none()
            && bot.extent().is_none()
        {
            core::mem::swap(&mut top, &mut bot);
            continue;
        }
        match next_reach {
            Reach::Nothing => bot.clear(),
            Reach::Everything => {
                bot.fill(
                    (next.0, next.1, flat_of(jt + 1)),
                    tables,
                    jt + 1,
                    None,
                    row_cut(jt + 1).as_ref(),
                    kern,
                    shading,
                );
            }
            Reach::Some => {
                let need = Needed::lines(img, jt + 1 + ov.n as i64, ou.n as i64);
                bot.fill(
                    (next.0, next.1, flat_of(jt + 1)),
                    tables,
                    jt + 1,
                    Some(&need),
                    row_cut(jt + 1).as_ref(),
                    kern,
                    shading,
                );
            }
        }
        let v = jt + ov.n as i64 + 1;
        if v >= band_lo && v < band_hi {
            let (pixels, opaque) = img.scanline_mut(v as usize - img.row0);
            // Pixel u reads buffer entries u − n and u − n + 1: visit the pixels that
            // reach the non-zero extent of either row (zero taps leave a pixel as it is).
            let (lo, hi) = match (top.extent(), bot.extent()) {
                (Some(a), Some(b)) => (a.0.min(b.0), a.1.max(b.1)),
                (Some(a), None) | (None, Some(a)) => a,
                (None, None) => (0, 0),
            };
            if lo < hi {
                let n = ou.n as i64;
                let ua = (lo as i64 + n - 1).clamp(0, width as i64) as usize;
                let ub = (hi as i64 + n).clamp(0, width as i64) as usize;
                let taps = Taps {
                    top: top.buf,
                    bot: bot.buf,
                    n: ou.n,
                    w,
                };
                // Rows with flat voxels (only ever marked in composite mode, and only
                // by ways that may exclude them: a compile-time constant, so the loops
                // of the others hold no such path) go to a compositor of their own.
                if S::FLAT != FlatRule::Never && (top.has_flat || bot.has_flat) {
                    over_span_flat(
                        FlatSpan {
                            pixels,
                            opaque,
                            taps,
                            flat: (top.flat, bot.flat),
                            us: ua..ub,
                            ert: tables.ert,
                        },
                        kern,
                    );
                } else {
                    composite_span(pixels, opaque, &taps, ua..ub, tables, kern);
                }
            }
        }
        core::mem::swap(&mut top, &mut bot);
    }
    top.clear();
    bot.clear();
    Ok(())
}

/// [`composite_slice`] for an intermediate image with `s = view.supersample` pixels per
/// voxel: pixel `u` samples the slice at `u/s − T`, so weights vary from pixel to pixel
/// (with period `s`: composite mode takes each phase as a plain scanline,
/// [`over_phases`]), and each pair of voxel rows serves `s` scanlines. Out of line on
/// targets that compile one compositor: inlined beside the parallel scanline loop, it
/// changed how that loop was compiled (the Cortex-M3 frame: 2.7 % more instructions).
#[allow(clippy::too_many_arguments)]
#[cfg_attr(not(target_arch = "x86_64"), inline(never))]
fn composite_slice_supersampled(
    img: &mut Intermediate<'_>,
    slice: &RleSlice<'_>,
    k: usize,
    view: &Factorization,
    tables: &SliceTables<'_>,
    rows: &mut [Rgba],
    shadow: Option<&ShadowLookup<'_>>,
    clean: bool,
    kern: &impl Kernels,
) -> Result<(), Error> {
    let [ni, nj, _] = view.dims;
    // At least one (the caller sends s > 1): said here, the divisions below cannot fail.
    let ss = (view.supersample as i64).max(1);
    let one = ONE as i64;
    // Pixel u samples at u·ONE/s (floored): stepped from pixel to pixel as a quotient
    // and a remainder, one division a run instead of one a pixel (a 64-bit division
    // takes tens of cycles).
    let (step, carry) = (one / ss, one % ss);
    let [ou, ov]: [SliceOffset; 2] = view.slice_offset(k);
    // Slice translation T in Q15.
    let tu = ou.n as i64 * one + ou.f as i64;
    let tv = ov.n as i64 * one + ov.f as i64;
    let (mut r0, mut r1) = Row::pair(rows, ni, clean);
    // Swapped by reference: a row carries its written runs, too large to swap by value
    // every scanline.
    let (mut top, mut bot) = (&mut r0, &mut r1);
    let scale = tables.depth.map_or(ONE, |d| d.slice_factor(k));
    let shading = Way::of(tables, shadow, scale);
    let cut = tables.clip.and_then(|c| c.slice(k as i64, [ni, nj]));
    let width = img.width;
    let row_of = |j: i64| slice.row(j);
    // Scanlines reading rows jt and jt + 1 composite something only for jt from the row
    // before the first non-empty one to the last non-empty one.
    let Some((j_first, j_last)) = slice.visible_rows(0, nj) else {
        return Ok(());
    };
    // Rows held in `top` / `bot` (voxel row indices), i64::MIN when none.
    let mut held = i64::MIN;
    for v in img.row0..img.row0 + img.rows {
        let (jt, frv) = sample_at(v, ss, tv);
        if jt < j_first as i64 - 1 || jt > j_last as i64 {
            continue;
        }
        if jt != held {
            let (r0, r1) = (row_of(jt), row_of(jt + 1));
            // The scanlines v..end that read rows jt and jt + 1, and those up to `next`
            // that read rows jt + 1 and jt + 2. Row jt + 1 is shaded for both groups that
            // read it, so that it serves the next group as its top row as it is.
            let band_end = img.row0 + img.rows;
            let end = group_end(v + 1..band_end, jt, ss, tv);
            let next = group_end(end..band_end, jt + 1, ss, tv);
            let fill = |row: &mut Row<'_>, r, j, vs| {
                let place = (tu, ss, ni);
                let cut = cut.as_ref().map(|c| c.row(j, ni));
                fill_supersampled(row, r, j, img, vs, place, cut, tables, kern, &shading);
            };
            if jt == held + 1 {
                core::mem::swap(&mut top, &mut bot);
            } else {
                fill(top, r0, jt, v..end);
            }
            fill(bot, r1, jt + 1, v..next);
            held = jt;
        }
        let (pixels, opaque) = img.scanline_mut(v - img.row0);
        // Composite mode, the kernels' case: the pixels that reach the rows' non-zero
        // entries, phase by phase.
        if tables.mode == Mode::Composite {
            let (lo, hi) = match (top.extent(), bot.extent()) {
                (Some(a), Some(b)) => (a.0.min(b.0), a.1.max(b.1)),
                (Some(a), None) | (None, Some(a)) => a,
                (None, None) => (0, 0),
            };
            let rows = Phases {
                top: top.buf,
                bot: bot.buf,
                flat: (top.has_flat || bot.has_flat).then_some((&*top.flat, &*bot.flat)),
            };
            over_phases(pixels, opaque, rows, (lo, hi), (tu, ss, frv), tables, kern);
            continue;
        }
        // MIP: each pixel the rows' runs reach, pixel by pixel. No pixel ever becomes
        // opaque, and MIP rows hold no flat bits (MIP has no shading to exclude them
        // from).
        let (top_runs, bot_runs) = (row_of(jt).0, row_of(jt + 1).0);
        let spans = MergedSpans {
            a: Spans::new(top_runs).peekable(),
            b: Spans::new(bot_runs).peekable(),
        };
        for (a, b) in spans {
            // The merged span [a, b) already includes the voxel to the right of each run
            // (b = last + 2).
            let (ua, ub) = span_pixels(a, b, tu, ss);
            let (ua, ub) = (ua.clamp(0, width as i64), ub.clamp(0, width as i64));
            let (ua, ub) = (ua as usize, ub as usize);
            let (mut q, mut r) = ((ua as i64 * one) / ss, (ua as i64 * one) % ss);
            for px in pixels.iter_mut().take(ub).skip(ua) {
                let pu = q - tu;
                q += step;
                r += carry;
                if r >= ss {
                    q += 1;
                    r -= ss;
                }
                let il = pu.div_euclid(one);
                let fru = pu.rem_euclid(one) as u32;
                if il < -1 || il >= ni as i64 {
                    continue;
                }
                let w = fixed::bilinear_weights(ONE - fru, ONE - frv);
                composite_pixel(px, top.buf, bot.buf, (il + 1) as usize, w, 0, tables);
            }
        }
    }
    top.clear();
    bot.clear();
    Ok(())
}

/// The two rows a supersampled scanline reads, for [`over_phases`]: their entries, and
/// their flat bits when they hold flat voxels that samples leave out of their colour.
struct Phases<'r> {
    top: &'r [Rgba],
    bot: &'r [Rgba],
    flat: Option<(&'r [Rgba], &'r [Rgba])>,
}

/// The pixels of a scanline of a slice supersampled `ss` times (Q15 offset `tu`, the
/// scanline's vertical fraction `frv`) that read entries `lo..hi` of its rows (their
/// non-zero extent), in composite mode: each run of open pixels composited by the
/// kernels one phase at a time (with flat voxels excluded, by [`over_run_flat`]).
///
/// The pixels `u ≡ p (mod ss)` of a scanline sample the slice at one fraction, a voxel
/// apart: pixel `ss·m + p` samples at `m + ⌊p·ONE/ss⌋ − tu` (in Q15, since
/// `⌊(x + ss)·ONE/ss⌋ = ⌊x·ONE/ss⌋ + ONE`), which is a plain slice's scanline with its
/// own weights. So a phase's pixels in an open run are gathered 64 at a time,
/// composited by the build's kernel and put back; the result is [`composite_pixel`]'s
/// bit for bit. Runs shorter than [`PHASED_RUN`] are composited pixel by pixel.
///
/// Pixel by pixel, every pixel a scalar sample and blend, 2×2 supersampled frames took
/// 4.6–11.6 times the plain ones' time (512², one thread, 36 views); by phases
/// 2.8–4.2 times, about the four times as many pixels. Alternating runs: spheres256
/// 127–128 → 45.5–46.0 ms, the head 22.9 → 12.7–13.0, brainsmall 4.0 → 2.4–2.5. The
/// head's four frames took half the instructions (callgrind, x86-64-v3: 1280 M → 655 M).
#[inline(always)]
fn over_phases(
    pixels: &mut [Rgba],
    opaque: &mut [opaque::Word],
    Phases { top, bot, flat }: Phases<'_>,
    (lo, hi): (usize, usize),
    (tu, ss, frv): (i64, i64, u32),
    t: &SliceTables<'_>,
    kern: &impl Kernels,
) {
    const CHUNK: usize = 64;
    if lo >= hi {
        return;
    }
    let ss = ss.max(1);
    let width = pixels.len();
    let thr = t.ert.max(1);
    // The pixels whose left entry lies in lo − 1..hi.
    let (ua, ub) = span_pixels(lo.saturating_sub(1), hi, tu, ss);
    let (ua, ub) = (
        ua.clamp(0, width as i64) as usize,
        ub.clamp(0, width as i64) as usize,
    );
    // Each phase's first entry and weights (factors are at most 4; larger ones go
    // pixel by pixel).
    let phases: [(i64, [u32; 4]); 4] = core::array::from_fn(|p| {
        let (d, fru) = sample_at(p, ss, tu);
        (d + 1, fixed::bilinear_weights(ONE - fru, ONE - frv))
    });
    let cap = top.len().min(bot.len()) as i64;
    let mut px = [[0u16; 4]; CHUNK];
    // The pixels [`over_run_flat`] composites again, as they were.
    let mut kept = [[0u16; 4]; CHUNK];
    let mut runs = opaque::OpenRuns::new(ua, ub);
    while let Some((u, e)) = runs.next(opaque, width) {
        if e - u < PHASED_RUN || ss > phases.len() as i64 {
            for (x, q) in pixels.iter_mut().enumerate().take(e).skip(u) {
                let (il, fru) = sample_at(x, ss, tu);
                let w = fixed::bilinear_weights(ONE - fru, ONE - frv);
                let bl = (il + 1).max(0) as usize;
                let f = flat.map_or(0, |(ft, fb)| flat::taps(ft, fb, bl));
                if il >= -1 && composite_pixel(q, top, bot, bl, w, f, t) {
                    opaque::mark(opaque, x);
                }
            }
            continue;
        }
        for (p, &(d1, w)) in phases.iter().enumerate().take(ss as usize) {
            let p = p as i64;
            // Pixel ss·m + p, for the m whose pixel lies in u..e, reads entries m + d1
            // and m + d1 + 1: those inside both rows (a pixel reading past them, as
            // [`composite_pixel`] reads them, is left as it is).
            let m_of = |x: usize| (x as i64 - p + ss - 1).div_euclid(ss);
            let (mut m, m_end) = (m_of(u).max(-d1), m_of(e).min(cap - 1 - d1));
            while m < m_end {
                let len = ((m_end - m) as usize).min(CHUNK);
                let (u0, step) = ((ss * m + p) as usize, ss as usize);
                let first = usize::try_from(m + d1);
                m += len as i64;
                let Ok(bl) = first else {
                    continue;
                };
                let (Some(chunk), Some(tt), Some(bb)) = (
                    px.get_mut(..len),
                    top.get(bl..bl + len + 1),
                    bot.get(bl..bl + len + 1),
                ) else {
                    continue;
                };
                for (j, q) in chunk.iter_mut().enumerate() {
                    *q = pixels.get(u0 + step * j).copied().unwrap_or_default();
                }
                let highest = match flat {
                    Some(f) => over_run_flat(chunk, tt, bb, w, f, bl, &mut kept, kern),
                    None => kern.over_run(chunk, tt, bb, w),
                };
                for (j, q) in chunk.iter().enumerate() {
                    let x = u0 + step * j;
                    if let Some(o) = pixels.get_mut(x) {
                        *o = *q;
                    }
                }
                if highest as u32 >= thr {
                    for (j, q) in chunk.iter().enumerate() {
                        if q[3] as u32 >= thr {
                            opaque::mark(opaque, u0 + step * j);
                        }
                    }
                }
            }
        }
    }
}

/// Open runs shorter than this many pixels are composited by [`over_phases`] pixel by
/// pixel: gathered, a phase has too few of them for the kernel's call. The head's four
/// supersampled frames at 512² (callgrind, x86-64-v3) took 874, 872, 873, 912 and 1034 M
/// instructions with 1, 2, 4, 8 and 16.
const PHASED_RUN: usize = 4;

/// The first scanline of `vs` that does not read rows `jt` and `jt + 1` of a slice at
/// Q15 offset `tv` (`ss` scanlines per voxel row), `vs.end` if all do.
#[inline(never)]
fn group_end(vs: core::ops::Range<usize>, jt: i64, ss: i64, tv: i64) -> usize {
    // At least one, as the caller's is: said here, the division below cannot fail.
    let ss = ss.max(1);
    let end = vs.end;
    vs.into_iter()
        .find(|&w| sample_at(w, ss, tv).0 != jt)
        .unwrap_or(end)
}

/// Where scanline or pixel `x` of a slice supersampled `ss` times (`ss >= 1`) at Q15
/// offset `t` samples it: at `⌊x·ONE/ss⌋ − t`, as the voxel row or column before the
/// sample and the Q15 fraction past it.
#[inline(always)]
fn sample_at(x: usize, ss: i64, t: i64) -> (i64, u32) {
    let one = ONE as i64;
    let p = x as i64 * one / ss - t;
    (p.div_euclid(one), p.rem_euclid(one) as u32)
}

/// The pixels `[ua, ub)` of a scanline of a slice supersampled `ss` times at Q15 offset
/// `tu` whose left voxel ([`sample_at`]) lies in `a − 1 .. b − 1`, before clamping to
/// the scanline. The pixel whose sample falls exactly on voxel `a − 1` is left out: it
/// gives voxel `a` a weight of zero.
#[inline(always)]
fn span_pixels(a: usize, b: usize, tu: i64, ss: i64) -> (i64, i64) {
    let one = ONE as i64;
    let edge = |v: usize| (((v as i64 - 1) * one + tu) * ss).div_euclid(one) + 1;
    (edge(a), edge(b))
}

/// Shades row `j` (its runs and voxels) of a supersampled slice for the scanlines `vs`
/// that read it: in composite mode only the voxels their open pixels read
/// ([`supersampled_needs`]), in MIP every voxel; then cuts it by the clipping planes
/// along it, `cut`, if any. Out of line, as is [`group_end`]:
/// with both inlined, the pixel loop beside them compiled to 6 % more instructions a
/// frame (spheres256 at 512², 2×2).
#[allow(clippy::too_many_arguments)]
#[inline(never)]
fn fill_supersampled(
    row: &mut Row<'_>,
    (runs, voxels): (&[u8], &[Voxel]),
    j: i64,
    img: &Intermediate<'_>,
    vs: core::ops::Range<usize>,
    place: (i64, i64, usize),
    cut: Option<RowCut>,
    tables: &SliceTables<'_>,
    kern: &impl Kernels,
    shading: &impl Shading,
) {
    let mut needed = NeedRanges::new();
    let lazy =
        tables.mode == Mode::Composite && supersampled_needs(img, vs, runs, place, &mut needed);
    // A row shaded whole is one range over every voxel: with `Row::fill` for it as
    // well, the Cortex-M3 firmware's code was 2.8 KB larger.
    let all = [(0, usize::MAX)];
    let needed = if lazy { &needed[..] } else { &all[..] };
    let face = cut.filter(|c| c.shades_face() && tables.mode != Mode::Mip);
    row.fill_in(
        runs,
        voxels,
        tables,
        j,
        needed,
        face.as_ref(),
        kern,
        shading,
    );
    if let Some(c) = &cut {
        row.cut_all(c, tables.mode);
    }
}

/// Voxel ranges a supersampled row pair is shaded in: sorted, disjoint, `[start, end)`.
type NeedRanges = heapless::Vec<(usize, usize), 48>;

/// The voxels of the row with runs `runs` that open pixels of the scanlines `vs` read,
/// in a supersampled slice (translation `tu` in Q15, `ss` pixels per voxel, `ni` voxels
/// a row), as ranges into `out`: each open pixel reads the voxel left of its sample and
/// the one after it. False when the row has no visible voxel, or there are more ranges
/// than `out` holds (the row is then shaded whole).
fn supersampled_needs(
    img: &Intermediate<'_>,
    vs: core::ops::Range<usize>,
    runs: &[u8],
    (tu, ss, ni): (i64, i64, usize),
    out: &mut NeedRanges,
) -> bool {
    // At least one, as the caller's is: said here, the divisions below cannot fail.
    let ss = ss.max(1);
    let Some((first, last)) = row::visible_extent(runs, ni) else {
        return false;
    };
    // The pixels whose left voxel lies in first − 1 ..= last (as the compositor finds
    // a span's pixels, for the span first..last + 1), one more at each end.
    let width = img.width;
    let (ua, ub) = span_pixels(first, last + 1, tu, ss);
    let ua = (ua - 1).clamp(0, width as i64) as usize;
    let ub = (ub + 1).clamp(0, width as i64) as usize;
    // The voxel left of pixel u's sample.
    let left = |u: usize| sample_at(u, ss, tu).0;
    let mut p = ua & !63;
    while p < ub {
        // Open in any of the scanlines.
        let mut open = 0;
        for v in vs.clone() {
            open |= opaque::open_bits(img.opaque_line(v - img.row0), width, p as i64);
        }
        open &= opaque::ones(ub - p) & !opaque::ones(ua.saturating_sub(p));
        while open != 0 {
            let z = open.trailing_zeros() as usize;
            let len = (!(open >> z)).trailing_zeros() as usize;
            open &= !opaque::ones(z + len);
            let (u, e) = (p + z, p + z + len);
            let a = left(u).clamp(0, ni as i64) as usize;
            let b = (left(e - 1) + 2).clamp(0, ni as i64) as usize;
            if a >= b {
                continue;
            }
            match out.last_mut() {
                Some(last) if a <= last.1 => last.1 = last.1.max(b),
                _ => {
                    if out.push((a, b)).is_err() {
                        return false;
                    }
                }
            }
        }
        p += 64;
    }
    true
}

/// Resamples and composites one pixel from voxel buffer index `bl` (left) and `bl + 1`,
/// whose taps have flat bits `flat` ([`flat::taps`]); true if the pixel became opaque
/// (reached the early-ray-termination opacity).
#[inline(always)]
fn composite_pixel(
    p: &mut Rgba,
    top: &[Rgba],
    bot: &[Rgba],
    bl: usize,
    w: [u32; 4],
    flat: u32,
    t: &SliceTables<'_>,
) -> bool {
    // Entries past a buffer read as transparent (they are never asked for: the
    // compositors keep `bl + 1` inside the row buffers).
    let at = |r: &[Rgba], i: usize| r.get(i).copied().unwrap_or_default();
    let taps = [at(top, bl), at(top, bl + 1), at(bot, bl), at(bot, bl + 1)];
    let s = match flat {
        0 => flat::sample(&taps, w),
        f => flat::resample(&taps, w, f),
    };
    match t.mode {
        Mode::Composite => {
            if s[3] != 0 {
                let tr = ONE - p[3] as u32;
                for c in 0..4 {
                    p[c] = (p[c] as u32 + fixed::mul(s[c], tr)).min(ONE) as u16;
                }
                return p[3] as u32 >= t.ert;
            }
            false
        }
        Mode::Mip => {
            if s[0] > p[0] as u32 {
                *p = [s[0] as u16; 4];
            }
            false
        }
    }
}

/// Two shaded voxel rows placed on a scanline: pixel `u` reads buffer entries `u − n` and
/// `u − n + 1` of both rows with the slice's bilinear weights `w`.
#[derive(Clone, Copy)]
pub(crate) struct Taps<'r> {
    top: &'r [Rgba],
    bot: &'r [Rgba],
    n: i32,
    w: [u32; 4],
}

/// The inner loop: pixels `us` of one scanline.
#[cfg_attr(target_arch = "x86_64", inline(always))]
#[cfg_attr(not(target_arch = "x86_64"), inline)]
fn composite_span(
    pixels: &mut [Rgba],
    opaque: &mut [opaque::Word],
    taps: &Taps<'_>,
    us: core::ops::Range<usize>,
    t: &SliceTables<'_>,
    kern: &impl Kernels,
) {
    if t.mode == Mode::Composite {
        return over_span(pixels, opaque, taps, us, t.ert, kern);
    }
    // MIP: no pixel ever becomes opaque.
    let first = us.start;
    for (u, p) in pixels.iter_mut().enumerate().take(us.end).skip(first) {
        // Buffer index of the left voxel: (u − n − 1) + 1.
        let bl = (u as i64 - taps.n as i64) as usize;
        composite_pixel(p, taps.top, taps.bot, bl, taps.w, 0, t);
    }
}

/// [`composite_span`] for [`Mode::Composite`]: each run of pixels that are not opaque
/// is composited by [`over_run`], a loop without branches that the compiler vectorises,
/// and the pixels that reached the early-ray-termination opacity are marked opaque
/// afterwards. Bit-identical to [`composite_pixel`], which the tests check.
#[cfg_attr(target_arch = "x86_64", inline(always))]
#[cfg_attr(not(target_arch = "x86_64"), inline)]
fn over_span(
    pixels: &mut [Rgba],
    opaque: &mut [opaque::Word],
    taps: &Taps<'_>,
    us: core::ops::Range<usize>,
    ert: u32,
    kern: &impl Kernels,
) {
    over_runs(pixels, opaque, taps, us, ert, kern, |px, top, bot, _| {
        kern.over_run(px, top, bot, taps.w)
    })
}

/// A span of a scanline whose rows hold flat voxels, with bits `flat` (top row, bottom
/// row): [`over_span_flat`].
pub(crate) struct FlatSpan<'a, 'r> {
    pixels: &'a mut [Rgba],
    opaque: &'a mut [opaque::Word],
    taps: Taps<'r>,
    flat: (&'r [Rgba], &'r [Rgba]),
    us: core::ops::Range<usize>,
    ert: u32,
}

/// [`over_span`] for rows that hold flat voxels, each run by [`over_run_flat`]. Only the
/// slice loops of ways that may exclude flat voxels hold it ([`FlatRule`]): inlined
/// beside the default loop's common path, it made that path's code longer where rows
/// have no flat voxel (the MR head, callgrind: 4 % more instructions a frame, where
/// 0.3 % of the runs have flat voxels).
#[inline(always)]
pub(crate) fn over_span_flat(span: FlatSpan<'_, '_>, kern: &impl Kernels) {
    let FlatSpan {
        pixels,
        opaque,
        taps,
        flat,
        us,
        ert,
    } = span;
    // The pixels of a chunk composited again, as they were before the kernel: one
    // array a span, zeroed once.
    let mut kept = [[0u16; 4]; 64];
    over_runs(
        pixels,
        opaque,
        &taps,
        us,
        ert,
        kern,
        #[inline(always)]
        |px, top, bot, bl| over_run_flat(px, top, bot, taps.w, flat, bl, &mut kept, kern),
    )
}

/// The loop of [`over_span`] over the open runs of the span, each composited by `run`
/// (given the run's pixels, both rows from its first tap on and that tap's index).
#[inline(always)]
fn over_runs(
    pixels: &mut [Rgba],
    opaque: &mut [opaque::Word],
    taps: &Taps<'_>,
    us: core::ops::Range<usize>,
    ert: u32,
    kern: &impl Kernels,
    mut run: impl FnMut(&mut [Rgba], &[Rgba], &[Rgba], usize) -> u16,
) {
    let width = pixels.len();
    let end = us.end.min(width);
    // A pixel still at zero opacity was never composited, so it is not marked even when
    // the threshold is zero (as in the per-pixel kernel).
    let thr = ert.max(1);
    let mut runs = opaque::OpenRuns::new(us.start, end);
    while let Some((u, e)) = runs.next(opaque, width) {
        // Pixels u..e read buffer entries u − n ..= e − n of both rows.
        let bl = (u as i64 - taps.n as i64) as usize;
        // In bounds: the compositors place the span inside the scanline and the taps
        // inside the row buffers. The kernels read `px.len() + 1` entries of each row.
        let (Some(px), Some(top), Some(bot)) =
            (pixels.get_mut(u..e), taps.top.get(bl..), taps.bot.get(bl..))
        else {
            return;
        };
        let highest = run(px, top, bot, bl);
        // Most runs have no pixel that reached the threshold, and the run's highest
        // opacity says so without a look at each pixel (spheres256, callgrind: 9.7 %
        // fewer instructions a frame).
        if highest as u32 >= thr {
            mark_closed(opaque, u, px, thr, kern);
        }
    }
}

/// [`Kernels::over_run`] for a run reading entries `bl..` of rows that hold flat voxels
/// (bits `ft`, `fb`): 64 pixels at a time, the pixels whose taps may mix flat and other
/// voxels ([`flat::mixed`]) are kept in `kept` as they were, the rest composited by the
/// kernel, and those whose colour the rule changes ([`flat::recolour`]) composited
/// again from where they were. The rule changes a sample's colour only, so the kernel's
/// opacity and highest opacity still hold.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn over_run_flat(
    px: &mut [Rgba],
    top: &[Rgba],
    bot: &[Rgba],
    w: [u32; 4],
    (ft, fb): (&[Rgba], &[Rgba]),
    bl: usize,
    kept: &mut [Rgba; 64],
    kern: &impl Kernels,
) -> u16 {
    let mut highest = 0;
    for (c, chunk) in px.chunks_mut(64).enumerate() {
        let i0 = 64 * c;
        let (Some(t), Some(b)) = (top.get(i0..), bot.get(i0..)) else {
            break;
        };
        let f = flat::tap_words(ft, fb, bl + i0);
        let mixed = flat::mixed(&f, w, chunk.len());
        if mixed == 0 {
            highest = highest.max(kern.over_run(chunk, t, b, w));
            continue;
        }
        let mut m = mixed;
        while m != 0 {
            let i = m.trailing_zeros() as usize;
            m &= m - 1;
            if let (Some(k), Some(p)) = (kept.get_mut(i), chunk.get(i)) {
                *k = *p;
            }
        }
        highest = highest.max(kern.over_run(chunk, t, b, w));
        let mut m = mixed;
        while m != 0 {
            let i = m.trailing_zeros() as usize;
            m &= m - 1;
            let (Some(p), Some(k), Some(tt), Some(bb)) = (
                chunk.get_mut(i),
                kept.get(i),
                t.get(i..i + 2),
                b.get(i..i + 2),
            ) else {
                break;
            };
            let taps = [tt[0], tt[1], bb[0], bb[1]];
            if let Some(col) = flat::recolour_from(kern.flat_sums(&taps, w, flat::pixel(&f, i))) {
                let tr = ONE - k[3] as u32;
                for c in 0..3 {
                    p[c] = (k[c] as u32 + fixed::mul(col[c], tr)).min(ONE) as u16;
                }
            }
        }
    }
    highest
}

/// Marks opaque the pixels of `px` (pixel `u` first) whose opacity reached `thr`.
///
/// With 64-bit words a mask of 64 pixels is built and ORed into the bitmap at once
/// (spheres256, x86-64-v3: 2 % fewer instructions per frame than a test and bit-set per
/// pixel). On 32-bit targets the 64-bit shifts cost more than they save (the Cortex-M3
/// firmware: 42 565 200 instructions per frame against 40 838 680), so they mark pixel
/// by pixel.
#[cfg(target_pointer_width = "64")]
#[inline(always)]
fn mark_closed(opaque: &mut [opaque::Word], u: usize, px: &[Rgba], thr: u32, k: &impl Kernels) {
    mark_closed_words(opaque, u, px, thr, k);
}

/// [`mark_closed`] on 32-bit targets.
#[cfg(not(target_pointer_width = "64"))]
#[inline(always)]
fn mark_closed(opaque: &mut [opaque::Word], u: usize, px: &[Rgba], thr: u32, _: &impl Kernels) {
    mark_closed_each(opaque, u, px, thr);
}

/// [`mark_closed`] 64 pixels at a time.
#[cfg_attr(not(any(test, target_pointer_width = "64")), allow(dead_code))]
#[inline(always)]
fn mark_closed_words<W: opaque::BitWord>(
    opaque: &mut [W],
    u: usize,
    px: &[Rgba],
    thr: u32,
    k: &impl Kernels,
) {
    for (c, chunk) in px.chunks(64).enumerate() {
        let m = k.closed_bits(chunk, thr);
        if m != 0 {
            opaque::mark_bits(opaque, u + 64 * c, m);
        }
    }
}

/// [`mark_closed`] pixel by pixel.
#[cfg_attr(all(not(test), target_pointer_width = "64"), allow(dead_code))]
#[inline(always)]
fn mark_closed_each<W: opaque::BitWord>(opaque: &mut [W], u: usize, px: &[Rgba], thr: u32) {
    for (i, p) in px.iter().enumerate() {
        if p[3] as u32 >= thr {
            opaque::mark(opaque, u + i);
        }
    }
}

/// Uniform values in `0..=m` from a xorshift stream, for tests.
#[cfg(test)]
pub(crate) fn rng(seed: u64) -> impl FnMut(u32) -> u32 {
    let mut r = crate::xorshift(seed);
    move |m: u32| ((r() >> 20) % (m as u64 + 1)) as u32
}

/// Unshaded tables for tests: colour rising with the scalar, opacity with the stored
/// byte, no termination.
#[cfg(test)]
pub(crate) struct PlainTables {
    color: ColorLanes,
    shade: ShadeTable,
    opacity: OpacityTable,
}

#[cfg(test)]
impl PlainTables {
    pub(crate) fn new() -> Self {
        PlainTables {
            color: core::array::from_fn(|i| [i as u16 * 64, 7, 9, 0]),
            shade: ShadeTable::UNSHADED,
            opacity: OpacityTable::from(core::array::from_fn(|i| (i * 128) as u16)),
        }
    }

    pub(crate) fn get(&self) -> SliceTables<'_> {
        SliceTables {
            opacity: &self.opacity,
            color: &self.color,
            shade: &self.shade,
            mode: Mode::Composite,
            ert: ONE,
            depth: None,
            shade0: None,
            ray_gain: None,
            flat_voxels: FlatVoxels::Excluded,
            clip: None,
        }
    }
}

/// Marks random stretches of the `w`-pixel scanline `line` opaque, for tests: stretches
/// up to `long` pixels when `density` is 0, up to `short` otherwise, each opaque with
/// odds growing with `density`. `next(m)` gives values in `0..=m`.
#[cfg(test)]
pub(crate) fn mark_random_stretches(
    line: &mut [opaque::Word],
    w: usize,
    (long, short): (usize, usize),
    density: usize,
    next: &mut impl FnMut(usize) -> usize,
) {
    let mut u = 0;
    while u < w {
        let len = 1 + next(if density == 0 { long } else { short });
        if next(3) < density.max(1) {
            (u..(u + len).min(w)).for_each(|p| opaque::mark(line, p));
        }
        u += len;
    }
}

/// A random scanline `ni` voxels wide, for tests: transparent and visible runs in turn,
/// mostly short and now and then long (split at 255 by empty continuations), with random
/// visible voxels. `next(m)` gives values in `0..=m`.
#[cfg(test)]
pub(crate) fn random_scanline<const R: usize, const N: usize>(
    ni: usize,
    next: &mut impl FnMut(u32) -> u32,
) -> (heapless::Vec<u8, R>, heapless::Vec<Voxel, N>) {
    let mut runs = heapless::Vec::new();
    let mut voxels = heapless::Vec::new();
    let (mut i, mut visible) = (0usize, false);
    while i < ni {
        let long = next(9) == 0;
        let len = (if long { next(300) } else { next(12) } as usize).min(ni - i);
        let mut left = len;
        loop {
            let piece = left.min(255);
            runs.push(piece as u8).unwrap();
            left -= piece;
            if left == 0 {
                break;
            }
            runs.push(0).unwrap();
        }
        if visible {
            for _ in 0..len {
                let v = Voxel {
                    opacity: 1 + next(254) as u8,
                    scalar: next(255) as u8,
                    normal: 0,
                };
                voxels.push(v).unwrap();
            }
        }
        i += len;
        visible = !visible;
    }
    if runs.len() % 2 == 1 {
        runs.push(0).unwrap();
    }
    (runs, voxels)
}

#[cfg(test)]
mod tests {
    use super::kernels::touch;
    use super::*;
    use crate::shade::ShadeEntry;

    #[test]
    fn both_ways_of_marking_closed_pixels_agree() {
        let mut rng = crate::xorshift(0xc105ed);
        for case in 0..400 {
            let width = 1 + (rng() % 300) as usize;
            let u = (rng() % width as u64) as usize;
            let n = (rng() % (width - u) as u64) as usize + 1;
            let px: heapless::Vec<Rgba, 300> = (0..n)
                .map(|_| [0, 0, 0, (rng() % (ONE as u64 + 1)) as u16])
                .collect();
            let thr = 1 + (rng() % ONE as u64) as u32;
            // Both word widths, whichever this target stores.
            let mut a = [0u16; 19];
            a.iter_mut().for_each(|w| *w = rng() as u16 & rng() as u16);
            let mut b = a;
            mark_closed_words(&mut a[..width.div_ceil(16)], u, &px, thr, &Portable);
            mark_closed_each(&mut b[..width.div_ceil(16)], u, &px, thr);
            assert_eq!(a, b, "case {case}");
            let mut a = [0u64; 5];
            a.iter_mut().for_each(|w| *w = rng() & rng());
            let mut b = a;
            mark_closed_words(&mut a[..width.div_ceil(64)], u, &px, thr, &Portable);
            mark_closed_each(&mut b[..width.div_ceil(64)], u, &px, thr);
            assert_eq!(a, b, "case {case}");
        }
    }

    #[test]
    fn flat_voxels_are_excluded_where_they_are_common() {
        use FlatVoxels::{Blended, Excluded};
        assert_eq!(FlatVoxels::for_volume(0, 0), Blended);
        assert_eq!(FlatVoxels::for_volume(0, 100), Blended);
        assert_eq!(FlatVoxels::for_volume(107, 271_338), Blended); // brainsmall
        assert_eq!(FlatVoxels::for_volume(222_012, 13_023_138), Blended); // the hires brain
        assert_eq!(FlatVoxels::for_volume(21_432, 51_128), Excluded); // spheres64
        assert_eq!(FlatVoxels::for_volume(1, 16), Excluded);
        assert_eq!(FlatVoxels::for_volume(1, 17), Blended);
        assert_eq!(FlatVoxels::for_volume(u64::MAX, u64::MAX), Excluded);
        // Counts that disagree (more flat than visible) still give an answer.
        assert_eq!(FlatVoxels::for_volume(5, 3), Excluded);
    }

    #[test]
    fn over_span_matches_the_per_pixel_kernel() {
        // Random premultiplied rows (channels up to alpha, alpha up to ONE, edge values
        // and transparent stretches included) composited under random pixels that are
        // not yet opaque (alpha below the threshold, or zero) through both kernels. Rows
        // of 300 voxels, so that open runs span several chunks of 64 pixels.
        const N: usize = 300;
        let mut rand = crate::xorshift(0x9e37_79b9_7f4a_7c15);
        let mut next = |m: u32| {
            let seed = rand();
            let r = (seed >> 20) as u32 % (m + 1);
            match seed & 7 {
                0 => m,
                1 => 0,
                _ => r,
            }
        };
        let color: ColorLanes = [[0; 4]; 256];
        let shade = ShadeTable::UNSHADED;
        let opacity = OpacityTable::from([0u16; 256]);
        for round in 0..400 {
            let ert = if round % 8 == 0 { 0 } else { next(ONE) };
            let px = |next: &mut dyn FnMut(u32) -> u32, max_alpha: u32| {
                let a = next(max_alpha);
                [next(a) as u16, next(a) as u16, next(a) as u16, a as u16]
            };
            let top: [Rgba; N + 4] = core::array::from_fn(|_| px(&mut next, ONE));
            let bot: [Rgba; N + 4] = core::array::from_fn(|_| px(&mut next, ONE));
            let open = ert.saturating_sub(1);
            let start: [Rgba; N + 10] = core::array::from_fn(|_| px(&mut next, open));
            let w = fixed::bilinear_weights(next(ONE), next(ONE));
            let t = SliceTables {
                opacity: &opacity,
                color: &color,
                shade: &shade,
                mode: Mode::Composite,
                ert,
                depth: None,
                shade0: None,
                ray_gain: None,
                flat_voxels: FlatVoxels::Excluded,
                clip: None,
            };
            let (mut fast, mut slow) = (start, start);
            // Some pixels already opaque: both kernels must leave them alone. In a third
            // of the rounds none are, so that runs are as long as the span.
            let mut lf = [0 as opaque::Word; opaque::words(N + 10)];
            for u in 0..N + 10 {
                if round % 3 != 0 && next(7) == 0 {
                    opaque::mark(&mut lf, u);
                }
            }
            let mut ls = lf;
            // Flat voxels in every other round: none, a few, or most (then most pixels of
            // every chunk of 64 mix flat and other voxels).
            let density = [0, 0, 1, 6][round % 4];
            let mut flat_bits = [[[0u16; 4]; flat::words(N + 2)]; 2];
            for f in flat_bits.iter_mut() {
                for i in 0..N + 4 {
                    if density > 0 && next(7) < density {
                        let mut word: u64 = bytemuck::cast(f[i / 64]);
                        word |= 1 << (i % 64);
                        f[i / 64] = bytemuck::cast(word);
                    }
                }
            }
            let taps = Taps {
                top: &top,
                bot: &bot,
                n: 3,
                w,
            };
            let (mut exact, mut le) = (fast, lf);
            if density == 0 {
                over_span(&mut fast, &mut lf, &taps, 3..N + 6, ert, &Portable);
                over_span(&mut exact, &mut le, &taps, 3..N + 6, ert, &Exact);
            } else {
                let flat = (&flat_bits[0][..], &flat_bits[1][..]);
                let span = |pixels, opaque| FlatSpan {
                    pixels,
                    opaque,
                    taps,
                    flat,
                    us: 3..N + 6,
                    ert,
                };
                over_span_flat(span(&mut fast, &mut lf), &Portable);
                over_span_flat(span(&mut exact, &mut le), &Exact);
            }
            for (u, p) in slow.iter_mut().enumerate().take(N + 6).skip(3) {
                let f = flat::taps(&flat_bits[0], &flat_bits[1], u - 3);
                if !opaque::is_opaque(&ls, u) && composite_pixel(p, &top, &bot, u - 3, w, f, &t) {
                    opaque::mark(&mut ls, u);
                }
            }
            assert_eq!(fast, slow);
            assert_eq!(lf, ls);
            assert_eq!(exact, slow);
            assert_eq!(le, ls);
        }
    }

    /// The portable kernels returning the run's exact highest opacity, as the vector
    /// builds' over kernels do (the portable one returns `u16::MAX`).
    struct Exact;

    impl Kernels for Exact {
        fn warm(&self, voxels: &[Voxel]) {
            touch(voxels)
        }
        fn premultiply(&self, c: &[u16; 4], e: &ShadeEntry, alpha: u32) -> Rgba {
            premultiply(c, e, alpha)
        }
        fn over_run(&self, px: &mut [Rgba], top: &[Rgba], bot: &[Rgba], w: [u32; 4]) -> u16 {
            over_run(px, top, bot, w);
            highest(px)
        }
        fn closed_bits(&self, px: &[Rgba], thr: u32) -> u64 {
            closed_bits(px, thr)
        }
        fn flat_bits(&self, voxels: &[Voxel], n: usize) -> u64 {
            flat_bits(voxels, n)
        }
        fn flat_sums(&self, t: &[Rgba; 4], w: [u32; 4], flat: u32) -> ([u32; 4], u32) {
            flat::sums(t, w, flat)
        }
        fn perspective(&self, job: SliceJob<'_, '_>) -> Result<(), Error> {
            crate::perspective::composite_slice(job, self)
        }
        #[cfg(target_arch = "x86_64")]
        fn composite_flat(&self, job: SliceJob<'_, '_>, way: Way<'_, '_>) -> Result<(), Error> {
            composite_rows_excluding(job, self, way)
        }
    }

    /// A run is marked only where a pixel reached the threshold, and a pixel that
    /// reaches it exactly is marked: the run's highest opacity decides whether its
    /// pixels are looked at, wherever the pixel lies in the run.
    #[test]
    fn a_pixel_that_reaches_the_threshold_exactly_is_marked() {
        check_exact_threshold(&Portable);
        check_exact_threshold(&Exact);
    }

    fn check_exact_threshold(kern: &impl Kernels) {
        let a = 20_000u16;
        for len in 1..=9 {
            for at in 0..len {
                // Weights all on the top-left tap: pixel u reads top[u - n] alone.
                let w = [ONE, 0, 0, 0];
                let mut top = [[0u16; 4]; 12];
                top[at] = [a / 2, a / 3, a / 4, a];
                let bot = [[7u16; 4]; 12];
                for (ert, marked) in [(a as u32, true), (a as u32 + 1, false)] {
                    let mut px = [[0u16; 4]; 10];
                    let mut op = [0 as opaque::Word; opaque::words(10)];
                    let taps = Taps {
                        top: &top,
                        bot: &bot,
                        n: 0,
                        w,
                    };
                    over_span(&mut px, &mut op, &taps, 0..len, ert, kern);
                    assert_eq!(px[at][3], a, "length {len}, pixel {at}");
                    for u in 0..len {
                        let want = marked && u == at;
                        assert_eq!(opaque::is_opaque(&op, u), want, "length {len}, pixel {u}");
                    }
                }
            }
        }
    }

    /// The supersampled compositor's phases against the per-pixel definition: random
    /// rows (non-zero inside random extents, some reaching the buffer's end; in half the
    /// cases a third of their voxels flat and left out of samples' colours), random
    /// scanlines with opaque stretches, supersampling factors 2 to 4 at offsets that are
    /// whole voxels or not, and termination thresholds from zero to one. Every pixel
    /// and every opaque bit must come out as [`composite_pixel`] leaves it.
    #[test]
    fn phases_composite_like_pixel_by_pixel() {
        let mut rng = crate::xorshift(0x5a3e_9d1c);
        let mut next = |m: usize| (rng() % (m as u64 + 1)) as usize;
        let plain = PlainTables::new();
        for case in 0..600 {
            let ni = 1 + next(150);
            let ss = 2 + next(2) as i64;
            let width = 1 + next(ss as usize * (ni + 6));
            let mut rows = [[[0u16; 4]; 160]; 2];
            let (lo, hi) = {
                let a = 1 + next(ni);
                let b = if next(3) == 0 {
                    ni + 1
                } else {
                    a + next(ni + 1 - a)
                };
                (a, b.max(a))
            };
            for r in rows.iter_mut() {
                for e in r.get_mut(lo..hi).unwrap_or_default() {
                    let a = next(ONE as usize) as u16;
                    *e = [next(a as usize) as u16, next(a as usize) as u16, 0, a];
                }
            }
            let (top, bot) = (&rows[0][..ni + 2], &rows[1][..ni + 2]);
            // Flat voxels in half the cases, with the rule applied to them.
            let mut flats = [[[0u16; 4]; flat::words(160)]; 2];
            let with_flat = next(1) == 0;
            if with_flat {
                for f in flats.iter_mut() {
                    for e in lo..hi {
                        if next(2) == 0 {
                            let w = &mut f[e / 64];
                            let bits = bytemuck::cast::<Rgba, u64>(*w) | 1 << (e % 64);
                            *w = bytemuck::cast(bits);
                        }
                    }
                }
            }
            let (ft, fb) = (&flats[0][..flat::words(ni)], &flats[1][..flat::words(ni)]);
            let tu = match next(2) {
                0 => (next(width / ss as usize + 2) * ONE as usize) as i64,
                _ => next(ONE as usize * (width / ss as usize + 2)) as i64,
            };
            let frv = if next(3) == 0 {
                0
            } else {
                next(ONE as usize - 1) as u32
            };
            let mut t = plain.get();
            t.ert = [0, ONE * 95 / 100, ONE][next(2)];
            let mut px = [[0u16; 4]; 620];
            let mut closed = [0 as opaque::Word; opaque::words(620)];
            mark_random_stretches(&mut closed, width, (40, 6), next(3), &mut next);
            for (u, p) in px.iter_mut().enumerate().take(width) {
                // Open pixels lie under the threshold, as compositing leaves them.
                let most = match opaque::is_opaque(&closed, u) {
                    true => ONE as usize,
                    false => (t.ert as usize).saturating_sub(1),
                };
                let a = next(most) as u16;
                *p = [next(a as usize) as u16, 0, next(a as usize) as u16, a];
            }
            let (mut want, mut want_closed) = (px, closed);
            for (u, p) in want.iter_mut().enumerate().take(width) {
                if opaque::is_opaque(&want_closed, u) {
                    continue;
                }
                let (il, fru) = sample_at(u, ss, tu);
                let w = fixed::bilinear_weights(ONE - fru, ONE - frv);
                let bl = (il + 1).max(0) as usize;
                let f = if with_flat { flat::taps(ft, fb, bl) } else { 0 };
                if il >= -1 && il < ni as i64 && composite_pixel(p, top, bot, bl, w, f, &t) {
                    opaque::mark(&mut want_closed, u);
                }
            }
            let (pixels, words) = (&mut px[..width], &mut closed[..opaque::words(width)]);
            let rows = Phases {
                top,
                bot,
                flat: with_flat.then_some((ft, fb)),
            };
            over_phases(pixels, words, rows, (lo, hi), (tu, ss, frv), &t, &Portable);
            assert_eq!(px[..width], want[..width], "case {case}: pixels");
            assert_eq!(closed, want_closed, "case {case}: opaque bits");
        }
    }

    /// The supersampled compositor's lazy shading: random scanlines shaded for random
    /// opaque bitmaps of the scanlines that read them, at random offsets and 2 to 4
    /// pixels a voxel. Every voxel an open pixel of those scanlines reads (the voxel left
    /// of its sample and the next) must come out as eager shading gives it, and no other
    /// entry may hold anything else.
    #[test]
    fn supersampled_lazy_shading_shades_every_voxel_an_open_pixel_reads() {
        const NI: usize = 120;
        const W: usize = 4 * (NI + 12);
        let mut next = rng(0x5eed_5a4f_1e55_0001);
        let plain = PlainTables::new();
        let t = plain.get();
        let one = ONE as i64;
        for round in 0..300 {
            let (runs, voxels): (heapless::Vec<u8, 300>, heapless::Vec<Voxel, NI>) =
                random_scanline(NI, &mut next);
            let ss = 2 + next(2) as i64;
            let tu = next(8 * ONE) as i64;
            let mut pixels = [[0u16; 4]; 3 * W];
            let mut links = [0; 3 * W];
            let mut img = Intermediate::band(W, 10, 4, 3, &mut pixels, &mut links).unwrap();
            let density = next(3) as usize;
            for r in 0..3 {
                let (_, line) = img.scanline_mut(r);
                let next = &mut |m: usize| next(m as u32) as usize;
                mark_random_stretches(line, W, (150, 8), density, next);
            }
            // One, two or all three scanlines read the row.
            let vs = 4..5 + (round % 3);
            let mut eager_buf = [[0u16; 4]; NI + 2];
            let mut lazy_buf = [[1u16; 4]; NI + 2];
            let mut eager = Row::new(&mut eager_buf, false);
            eager.fill((&runs, &voxels, &[]), &t, 0, None, None, &Portable, &Lit);
            let mut lazy = Row::new(&mut lazy_buf, false);
            let place = (tu, ss, NI);
            fill_supersampled(
                &mut lazy,
                (&runs, &voxels),
                0,
                &img,
                vs.clone(),
                place,
                None,
                &t,
                &Portable,
                &Lit,
            );
            let mut read = [false; NI];
            for u in 0..W {
                let open = vs
                    .clone()
                    .any(|v| !opaque::is_opaque(img.opaque_line(v - 4), u));
                let il = ((u as i64 * one) / ss - tu).div_euclid(one);
                for i in [il, il + 1] {
                    if open && (0..NI as i64).contains(&i) {
                        read[i as usize] = true;
                    }
                }
            }
            for (i, &read) in read.iter().enumerate() {
                let (e, l) = (eager.buf[i + 1], lazy.buf[i + 1]);
                if read {
                    assert_eq!(
                        l, e,
                        "round {round}: voxel {i} is read but shaded differently"
                    );
                } else {
                    assert!(
                        l == e || l == [0; 4],
                        "round {round}: voxel {i} holds {l:?}"
                    );
                }
            }
            assert!(lazy.zero_outside_extent());
        }
    }
}
