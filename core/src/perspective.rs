//! Compositing for perspective views (Lacroute 1995, §4.2).
//!
//! In a perspective factorization every slice is scaled by `σ(k) ≤ 1` as well as
//! translated, so an intermediate pixel covers `1/σ` voxels of a far slice. Each pixel is
//! resampled with the thesis's filter, a box reconstruction convolved with a box low-pass
//! as wide as the decimation (the tent of bilinear interpolation when `σ = 1`): voxel `i`
//! weighs `overlap([i − ½, i + ½], [x − W/2, x + W/2]) / W` at slice position `x`, with
//! `W = 1/σ`, and the 2D weight is the product of the two axes.
//!
//! The filter is separable and its horizontal weights do not depend on the scanline, so
//! each voxel row of a slice is filtered horizontally once, into an intermediate-width
//! row held in a small ring, and every intermediate scanline combines the few ring rows
//! under its footprint. Only pixel ranges touched by non-transparent voxel runs are
//! filtered, and opaque intermediate pixels are skipped through the opaque-pixel bitmap as
//! in the parallel path.
//!
//! Opacity correction differs from ray to ray (the step between slices along a ray from
//! the eye grows off-axis, §4.2.3), but is constant along each ray. Voxels are corrected
//! for the smallest step of the view, and each resampled pixel is then corrected from
//! there to its own ray's step through a small table of gains interpolated between
//! [`GAIN_LEVELS`] step lengths; on uniform material this equals correcting every voxel
//! for the pixel's own step.

use crate::classify::Voxel;
use crate::clip::RowCut;
use crate::composite::{
    Intermediate, Kernels, Mode, Rgba, Row, Shading, SliceJob, SliceTables, Spans, Way,
};
use crate::error::{need, Error};
use crate::fixed::ONE;
use crate::opaque;
use crate::view::{Factorization, Perspective, MAX_DECIMATION};

/// Step lengths at which the per-ray gain table is tabulated.
pub const GAIN_LEVELS: usize = 16;

/// Most voxels under one pixel's filter along an axis.
const MAX_TAPS: usize = MAX_DECIMATION + 3;

/// Fraction bits of slice positions.
const P: u32 = 16;
const P1: i64 = 1 << P;

/// Per-frame tables for the ray-dependent part of perspective opacity correction.
#[derive(Clone, Debug)]
pub struct RayGain {
    /// `gain[l][a]`: Q12 factor taking a pixel of opacity `(a + ½)/256`, corrected for
    /// the view's smallest step, to step level `l`.
    gain: [[u16; 256]; GAIN_LEVELS],
    /// Level position (Q8) = `(ka·du² + kb·dv² + c) >> 24`, `du`, `dv` in Q4 pixels
    /// from `(u0, v0)`.
    ka: i64,
    kb: i64,
    c: i64,
    u0: i64,
    v0: i64,
}

impl RayGain {
    /// Tables for a perspective view.
    pub fn new(p: &Perspective) -> Self {
        let [lo, hi] = p.ratio_sq_range;
        let span = hi - lo;
        let levels = (GAIN_LEVELS - 1) as f64;
        let per = if span > 1e-9 {
            levels * 256.0 / span
        } else {
            0.0
        };
        let r0 = libm::sqrt(lo);
        let mut gain = [[0u16; 256]; GAIN_LEVELS];
        for (l, row) in gain.iter_mut().enumerate() {
            let r = libm::sqrt(lo + span * l as f64 / levels);
            let e = if r0 > 0.0 { r / r0 } else { 1.0 };
            for (a, g) in row.iter_mut().enumerate() {
                let alpha = (a as f64 + 0.5) / 256.0;
                let corrected = 1.0 - libm::pow(1.0 - alpha, e);
                *g = libm::round(corrected / alpha * 4096.0).clamp(0.0, 65535.0) as u16;
            }
        }
        let q = |x: f64| libm::round(x.clamp(-1e15, 1e15)) as i64;
        RayGain {
            gain,
            ka: q(per * p.ratio_sq[1] * 65536.0),
            kb: q(per * p.ratio_sq[3] * 65536.0),
            c: q(per * (p.ratio_sq[0] - lo) * 16_777_216.0),
            u0: q(p.ratio_sq[2] * 16.0),
            v0: q(p.ratio_sq[4] * 16.0),
        }
    }

    /// The row term of pixel `(·, v)`'s level position.
    #[inline]
    fn row_term(&self, v: usize) -> i64 {
        let dv = (v as i64) * 16 - self.v0;
        // The centre may lie far outside the image (up to 10^15 in Q4, for a grid so
        // anisotropic that the paraboloid is nearly flat along this axis, `kb` then
        // 0): the square saturates instead of overflowing.
        self.kb
            .saturating_mul(dv.saturating_mul(dv))
            .saturating_add(self.c)
    }

    /// Applies the gain of pixel `u` (row term `rv`) to a resampled sample.
    #[inline]
    fn apply(&self, s: &mut [u32; 4], u: usize, rv: i64) {
        let du = (u as i64) * 16 - self.u0;
        let pos = (self
            .ka
            .saturating_mul(du.saturating_mul(du))
            .saturating_add(rv)
            >> 24)
            .clamp(0, (GAIN_LEVELS as i64 - 1) * 256);
        let (mut l, mut f) = ((pos >> 8) as usize, (pos & 255) as u32);
        if l >= GAIN_LEVELS - 1 {
            l = GAIN_LEVELS - 2;
            f = 256;
        }
        let a = (s[3] >> 7).min(255) as usize;
        let g = (self.gain[l][a] as u32 * (256 - f) + self.gain[l + 1][a] as u32 * f) >> 8;
        for c in s.iter_mut() {
            *c = ((*c * g + 2048) >> 12).min(ONE);
        }
    }
}

/// Row-buffer entries [`crate::composite::composite_slice`] needs for `view`: one shaded
/// voxel row plus a ring of filtered rows as wide as the intermediate image.
pub fn row_buffer_len(view: &Factorization) -> usize {
    view.dims[0] + 2 + ring_len(view) * view.intermediate[0]
}

/// Filtered rows held at once: the most voxel rows under one pixel's footprint.
fn ring_len(view: &Factorization) -> usize {
    match &view.perspective {
        Some(p) => ((1.0 / p.min_scale) as usize + 3).min(MAX_TAPS),
        None => 0,
    }
}

/// One axis of a slice's resampling: slice position `x(u) = u·w − a` (Q16).
#[derive(Clone, Copy)]
struct AxisMap {
    /// Footprint width `1/σ`, Q16.
    w: i64,
    /// Position of pixel 0, negated, Q16.
    a: i64,
    /// `2^31 / w`: turns a Q16 length inside the footprint into a Q15 weight.
    recip: i64,
}

impl AxisMap {
    fn new(scale: f64, origin: f64) -> Self {
        // At least one Q16 unit: a scale beyond 2^17 (or not a number) would round the
        // footprint to nothing, and [`AxisMap::pixels_of`] divides by it.
        let w = (libm::round(P1 as f64 / scale) as i64).max(1);
        AxisMap {
            w,
            a: libm::round(origin / scale * P1 as f64) as i64,
            recip: (1i64 << 31) / w,
        }
    }

    /// The taps of the footprint `[lo, lo + w)` (Q16), left to right.
    #[inline(always)]
    fn taps_from(&self, lo: i64) -> Taps {
        // The voxel whose cell holds `lo`.
        let first = (lo + P1 / 2) >> P;
        Taps {
            lo,
            hi: lo + self.w,
            recip: self.recip,
            voxel: first,
            edge: first * P1 + P1 / 2,
            prev: 0,
            left: MAX_TAPS,
        }
    }

    /// The left end of pixel `u`'s footprint, Q16: it moves right by `w` a pixel.
    #[inline(always)]
    fn left(&self, u: i64) -> i64 {
        u * self.w - self.a - self.w / 2
    }

    /// Voxels under pixel `u`'s footprint: the first index, and Q15 weights (summing to
    /// one) in `out`; returns the count. Voxels outside `0..n` keep their weight slot
    /// and are skipped by the caller.
    #[cfg_attr(target_arch = "x86_64", inline(always))]
    fn taps(&self, u: i64, out: &mut [u32; MAX_TAPS]) -> (i64, usize) {
        let taps = self.taps_from(self.left(u));
        let first = taps.voxel;
        let mut n = 0;
        for (o, (_, w)) in out.iter_mut().zip(taps) {
            *o = w;
            n += 1;
        }
        (first, n)
    }

    /// The voxels `first..end` under pixel `u`'s footprint.
    #[cfg_attr(target_arch = "x86_64", inline(always))]
    fn voxels(&self, u: i64) -> (i64, i64) {
        let taps = self.taps_from(self.left(u));
        let first = taps.voxel;
        (first, first + taps.count() as i64)
    }

    /// The footprint `[lo, lo + w)` filtered over the voxels of `row` (voxel `i` at
    /// `row[i + 1]`, entries outside the row reading as zero), rounded to Q15.
    #[inline(always)]
    fn filter(&self, lo: i64, row: &[Rgba]) -> Rgba {
        let mut acc = [0u32; 4];
        for (i, w) in self.taps_from(lo) {
            // Index i + 1 wraps for i < −1 and is then out of the row, as past its end.
            let px = row.get((i + 1) as usize).copied().unwrap_or_default();
            for c in 0..4 {
                acc[c] += w * px[c] as u32;
            }
        }
        acc.map(|x| ((x + (1 << 14)) >> 15).min(ONE) as u16)
    }

    /// Pixels whose footprint overlaps voxels `a..b`: `[lo, hi)` before clamping.
    fn pixels_of(&self, a: usize, b: usize) -> (i64, i64) {
        // `w >= 1` from `new`; the `max` shows the compiler the divisor is not zero.
        let w = self.w.max(1);
        let left = a as i64 * P1 - P1 / 2 - w / 2 + self.a;
        let right = b as i64 * P1 - P1 / 2 + w / 2 + self.a;
        (left.div_euclid(w) + 1, right.div_euclid(w) + 1)
    }
}

/// The taps of one footprint ([`AxisMap::taps_from`]), left to right: each voxel's index
/// and its Q15 weight, the overlap of its cell with the footprint over the footprint's
/// width, found from the cumulative overlap at the cell's right edge (the weights sum to
/// one). At most [`MAX_TAPS`].
struct Taps {
    lo: i64,
    hi: i64,
    recip: i64,
    /// The next tap's voxel, and its cell's right edge (Q16).
    voxel: i64,
    edge: i64,
    /// The cumulative weight up to the previous tap.
    prev: u32,
    /// Taps still allowed: zero after the one whose cell reaches the footprint's end.
    left: usize,
}

impl Iterator for Taps {
    type Item = (i64, u32);

    #[inline(always)]
    fn next(&mut self) -> Option<(i64, u32)> {
        if self.left == 0 {
            return None;
        }
        let last = self.edge >= self.hi;
        let cum = if last {
            ONE
        } else {
            (((self.edge - self.lo) * self.recip) >> 16).clamp(0, ONE as i64) as u32
        };
        let tap = (self.voxel, cum - self.prev.min(cum));
        self.prev = cum;
        self.left = if last { 0 } else { self.left - 1 };
        self.voxel += 1;
        self.edge += P1;
        Some(tap)
    }
}

/// A filtered row in the ring: which voxel row it holds and its non-zero pixel range.
#[derive(Clone, Copy)]
struct Slot {
    j: i64,
    lo: usize,
    hi: usize,
}

/// Composites slice `k` of a perspective view into the scanlines `img` holds. `rows`
/// must hold [`row_buffer_len`]`(view)` entries, all zero if `clean` (they are all zero
/// again on success). `kern` shades the voxels. The portable kernels call this, the
/// instruction-set builds [`composite_slice_in`] inlined into a function of their own.
pub(crate) fn composite_slice(job: SliceJob<'_, '_>, kern: &impl Kernels) -> Result<(), Error> {
    composite_slice_in(job, kern)
}

/// The body of [`composite_slice`].
#[inline(always)]
pub(crate) fn composite_slice_in(job: SliceJob<'_, '_>, kern: &impl Kernels) -> Result<(), Error> {
    let SliceJob {
        img,
        slice,
        k,
        view,
        tables,
        rows,
        clean,
    } = job;
    let gain = tables.ray_gain;
    let [ni, nj, _] = view.dims;
    let Some(ss) = view.slice_scale(k) else {
        return Err(Error::BadParameter {
            reason: "perspective compositing needs a perspective view",
        });
    };
    // At least 3 rows in a perspective view; `max` lets the compiler see it is not zero.
    let ring = ring_len(view).max(1);
    let width = img.width();
    need("perspective row buffer", row_buffer_len(view), rows.len())?;
    if width != view.intermediate[0] {
        return Err(Error::BadParameter {
            reason: "intermediate image does not match the frame",
        });
    }
    if tables.mode == Mode::Composite && gain.is_none() {
        return Err(Error::BadParameter {
            reason: "perspective compositing needs the per-ray opacity tables",
        });
    }
    let too_small = Error::BufferTooSmall {
        what: "perspective row buffer",
        needed: row_buffer_len(view),
        got: rows.len(),
    };
    let (voxel_row, ring_buf) = rows.split_at_mut_checked(ni + 2).ok_or(too_small)?;
    let mut row = Row::new(voxel_row, clean);
    // How the slice's voxels are shaded, by the rule the parallel compositor uses:
    // lit, or the scalar in MIP (perspective frames have neither shadows nor depth
    // cueing).
    let shading = Way::of(tables, None, ONE);
    let cut = tables.clip.and_then(|c| c.slice(k as i64, [ni, nj]));
    let ring_buf = ring_buf.get_mut(..ring * width).ok_or(too_small)?;
    if !clean {
        ring_buf.fill([0; 4]);
    }
    let mut slots = [Slot {
        j: i64::MIN,
        lo: 0,
        hi: 0,
    }; MAX_TAPS];
    let xs = AxisMap::new(ss.scale, ss.origin[0]);
    let ys = AxisMap::new(ss.scale, ss.origin[1]);
    let mut wy = [0u32; MAX_TAPS];
    let rows_held = img.pixels().len() / width.max(1);
    // Only scanlines with a tap on the rows from the first non-empty one to the last
    // composite anything.
    let Some((j_first, j_last)) = slice.visible_rows(0, nj) else {
        return Ok(());
    };
    for v in img.first_row()..img.first_row() + rows_held {
        let (j0, count) = ys.taps(v as i64, &mut wy);
        if j0 + count as i64 <= j_first as i64 || j0 > j_last as i64 {
            continue;
        }
        // Filter the voxel rows under this scanline that the ring lacks; list the ring
        // rows and weights the scanline combines.
        let mut lo = usize::MAX;
        let mut hi = 0;
        let mut under = [(0usize, 0u32); MAX_TAPS];
        let mut n_under = 0;
        for (t, &w) in wy.iter().take(count).enumerate() {
            let j = j0 + t as i64;
            if j < 0 || j >= nj as i64 || w == 0 {
                continue;
            }
            let s = j.rem_euclid(ring as i64) as usize;
            if slots[s].j != j {
                // The ring holds `ring` rows of `width` pixels and `s < ring`.
                let Some(out) = ring_buf.get_mut(s * width..(s + 1) * width) else {
                    continue;
                };
                if let Some(old) = out.get_mut(slots[s].lo..slots[s].hi) {
                    old.fill([0; 4]);
                }
                let (runs, voxels) = slice.scanline(j as usize);
                // The band's scanlines that read row j: a pixel opaque in all of them is
                // never composited again, so neither its filtered value nor the voxels
                // only it reads are needed.
                let readers = if tables.mode == Mode::Composite {
                    // Widened by a row each way: rounding at the footprint's edges must
                    // only ever add readers.
                    let (va, vb) = ys.pixels_of(j as usize, j as usize + 1);
                    let band = img.first_row() as i64..(img.first_row() + rows_held) as i64;
                    // `max` then `min`, not `clamp`, which the compiler cannot show
                    // never panics here (the firmware's build must link).
                    let va = (va - 1).max(band.start).min(band.end);
                    let vb = (vb + 1).max(band.start).min(band.end);
                    Some(Readers {
                        img: &*img,
                        first: (va - band.start) as usize,
                        count: (vb - va) as usize,
                    })
                } else {
                    None
                };
                row.clear();
                let row_cut = cut.as_ref().map(|c| c.row(j, ni));
                let mut shader = Shader::new(runs, voxels, ni, row_cut);
                let mut put =
                    |r: &mut Row<'_>, range| shader.upto(r, range, tables, j, kern, &shading);
                slots[s] = filter_row(out, &mut row, &mut put, runs, &xs, readers.as_ref());
                slots[s].j = j;
            }
            lo = lo.min(slots[s].lo);
            hi = hi.max(slots[s].hi);
            if let Some(slot) = under.get_mut(n_under) {
                *slot = (s * width, w);
                n_under += 1;
            }
        }
        let under = under.get(..n_under).unwrap_or_default();
        if lo >= hi {
            continue;
        }
        let (pixels, opaque_line) = img.scanline_mut(v - img.first_row());
        let rv = gain.map_or(0, |g| g.row_term(v));
        // The ring rows under the scanline, each from pixel `lo`, with their weights.
        let mut taps: [(&[Rgba], u32); MAX_TAPS] = [(&[], 0); MAX_TAPS];
        for (t, &(base, w)) in taps.iter_mut().zip(under) {
            *t = (ring_buf.get(base + lo..base + hi).unwrap_or_default(), w);
        }
        let taps = taps.get(..under.len()).unwrap_or_default();
        // Runs of open pixels: a pixel becomes opaque only as it is composited, so the
        // runs found before a run is composited stay open until then.
        let mut runs = opaque::OpenRuns::new(lo, hi);
        while let Some((u, e)) = runs.next(opaque_line, width) {
            for x in u..e {
                // Colours are premultiplied, so a pixel whose taps have no opacity has
                // no colour either: its opacity is summed first.
                let mut alpha = 0u32;
                for &(r, w) in taps {
                    if let Some(h) = r.get(x - lo) {
                        alpha += w * h[3] as u32;
                    }
                }
                if alpha == 0 {
                    continue;
                }
                let mut s = [0u32; 4];
                for &(r, w) in taps {
                    let h = r.get(x - lo).copied().unwrap_or_default();
                    for c in 0..4 {
                        s[c] += w * h[c] as u32;
                    }
                }
                let mut s = s.map(|x| ((x + (1 << 14)) >> 15).min(ONE));
                let Some(p) = pixels.get_mut(x) else {
                    break;
                };
                match tables.mode {
                    Mode::Composite => {
                        if s[3] != 0 {
                            if let Some(g) = gain {
                                g.apply(&mut s, x, rv);
                            }
                            let tr = ONE - p[3] as u32;
                            for c in 0..4 {
                                p[c] =
                                    (p[c] as u32 + ((s[c] * tr + (1 << 14)) >> 15)).min(ONE) as u16;
                            }
                            if p[3] as u32 >= tables.ert {
                                opaque::mark(opaque_line, x);
                            }
                        }
                    }
                    Mode::Mip => {
                        if s[0] > p[0] as u32 {
                            *p = [s[0] as u16; 4];
                        }
                    }
                }
            }
        }
    }
    row.clear();
    for (s, slot) in slots.iter().enumerate().take(ring) {
        if let Some(used) = ring_buf.get_mut(s * width + slot.lo..s * width + slot.hi) {
            used.fill([0; 4]);
        }
    }
    Ok(())
}

/// The scanlines of a band that read one voxel row: `count` rows from band row
/// `first` of `img`.
struct Readers<'a, 'b> {
    img: &'a Intermediate<'b>,
    first: usize,
    count: usize,
}

impl Readers<'_, '_> {
    /// Bit `t` set if pixel `u + t` is open in some reading scanline, for `t` in `0..64`
    /// (all set when no scanline of the band reads the row, as nothing is known closed).
    #[cfg_attr(target_arch = "x86_64", inline(always))]
    fn open_bits(&self, u: usize) -> u64 {
        if self.count == 0 {
            return u64::MAX;
        }
        (0..self.count).fold(0, |open, r| {
            let line = self.img.opaque_line(self.first + r);
            open | opaque::open_bits(line, self.img.width(), u as i64)
        })
    }
}

/// The runs of pixels in `u..end` that some reading scanline has open: the whole range
/// without readers (MIP, where no pixel closes).
struct OpenRuns<'r, 'a, 'b> {
    readers: Option<&'r Readers<'a, 'b>>,
    /// Open pixels `at + t` for the bits `t` set, not yet returned.
    bits: u64,
    at: usize,
    /// The first pixel whose bits are not loaded yet.
    next: usize,
    end: usize,
}

impl<'r, 'a, 'b> OpenRuns<'r, 'a, 'b> {
    fn new(readers: Option<&'r Readers<'a, 'b>>, u: usize, end: usize) -> Self {
        OpenRuns {
            readers,
            bits: 0,
            at: u,
            next: u,
            end,
        }
    }

    /// Loads the bits of the next 64 pixels (fewer at the end): `None` past the end.
    #[cfg_attr(target_arch = "x86_64", inline(always))]
    fn load(&mut self) -> Option<u64> {
        if self.next >= self.end {
            return None;
        }
        self.at = self.next;
        self.next = self.at.saturating_add(64);
        // A `match`, not `map_or`: left out of line, that kept the readers' bitmaps
        // out of the instruction-set builds.
        let open = match self.readers {
            Some(r) => r.open_bits(self.at),
            None => u64::MAX,
        };
        Some(open & opaque::ones(self.end - self.at))
    }
}

impl Iterator for OpenRuns<'_, '_, '_> {
    type Item = (usize, usize);

    #[cfg_attr(target_arch = "x86_64", inline(always))]
    fn next(&mut self) -> Option<(usize, usize)> {
        while self.bits == 0 {
            self.bits = self.load()?;
        }
        let z = self.bits.trailing_zeros() as usize;
        let start = self.at + z;
        // The ones from bit z: at most 64 − z, as the shift brings in zeros.
        let len = (!(self.bits >> z)).trailing_zeros() as usize;
        if z + len < 64 {
            self.bits &= !opaque::ones(z + len);
            return Some((start, self.at + z + len));
        }
        // The run reaches the window's last pixel and may go on into the next windows.
        self.bits = 0;
        let mut stop = self.next.min(self.end);
        while let Some(w) = self.load() {
            let more = (!w).trailing_zeros() as usize;
            stop = self.at + more.min(self.end - self.at);
            if more < 64 {
                self.bits = w & !opaque::ones(more);
                break;
            }
        }
        Some((start, stop))
    }
}

/// Shades a voxel row on demand, front to back: each call shades the visible voxels of
/// a range not shaded before, so a voxel no open pixel reads is never shaded.
struct Shader<'r> {
    spans: Spans<'r>,
    voxels: &'r [Voxel],
    /// The visible span at the cursor: voxels `a..b`, voxel `a` at `voxels[base]`.
    span: Option<(usize, usize, usize)>,
    /// Stored voxels before the next span.
    stored: usize,
    /// Voxels before this one are shaded or never needed.
    done: usize,
    ni: usize,
    /// The clipping planes along the row, if any: each piece is cut as it is shaded.
    cut: Option<RowCut>,
}

impl<'r> Shader<'r> {
    fn new(runs: &'r [u8], voxels: &'r [Voxel], ni: usize, cut: Option<RowCut>) -> Self {
        let mut s = Shader {
            spans: Spans::new(runs),
            voxels,
            span: None,
            stored: 0,
            done: 0,
            ni,
            cut,
        };
        s.advance();
        s
    }

    fn advance(&mut self) {
        self.span = self.spans.next().map(|(a, b)| {
            let base = self.stored;
            self.stored += b - a;
            (a, b, base)
        });
    }

    /// Shades the visible voxels of `from..to` (clamped to the row) that are not shaded
    /// yet. `from` must not decrease from call to call: voxels skipped over are taken as
    /// never needed.
    #[inline]
    fn upto(
        &mut self,
        row: &mut Row<'_>,
        (from, to): (i64, i64),
        t: &SliceTables<'_>,
        j: i64,
        k: &impl Kernels,
        shading: &impl Shading,
    ) {
        let clamp = |x: i64| x.clamp(0, self.ni as i64) as usize;
        let to = clamp(to);
        self.done = self.done.max(clamp(from));
        while self.done < to {
            let Some((a, b, base)) = self.span else {
                break;
            };
            if b <= self.done {
                self.advance();
                continue;
            }
            if a >= to {
                break;
            }
            // a < to and done < b, so x < y.
            let (x, y) = (a.max(self.done), b.min(to));
            let src = self.voxels.get(base + (x - a)..).unwrap_or_default();
            row.shade(src, (x, y), t, j, k, shading);
            if let Some(c) = &self.cut {
                if c.shades_face() {
                    row.shade_face_in(c, src, (x, y), t, j, k, shading);
                }
                row.cut(c, (x, y), t.mode);
            }
            self.done = y;
        }
        self.done = self.done.max(to);
    }
}

/// Filters the shaded voxel row `row` horizontally into `out` (zero on entry) over the
/// pixels its non-transparent runs reach, except pixels every reader has made opaque;
/// `shade` is asked for the voxels of each run of the other pixels before they are
/// filtered. Returns the written range.
/// Inlined on x86-64 so that the instruction-set builds compile it with their features.
#[cfg_attr(target_arch = "x86_64", inline(always))]
fn filter_row(
    out: &mut [Rgba],
    row: &mut Row<'_>,
    shade: &mut impl FnMut(&mut Row<'_>, (i64, i64)),
    runs: &[u8],
    xs: &AxisMap,
    readers: Option<&Readers<'_, '_>>,
) -> Slot {
    let width = out.len() as i64;
    let mut slot = Slot {
        j: 0,
        lo: usize::MAX,
        hi: 0,
    };
    let mut done = 0i64;
    for (a, b) in Spans::new(runs) {
        let (ua, ub) = xs.pixels_of(a, b);
        let ua = ua.max(done).clamp(0, width);
        let ub = ub.clamp(0, width);
        if ua >= ub {
            continue;
        }
        done = ub;
        for (p0, p1) in OpenRuns::new(readers, ua as usize, ub as usize) {
            // The taps move right with the pixel: the run reads voxels from its first
            // pixel's first tap to its last pixel's last.
            let ((first, _), (_, end)) = (xs.voxels(p0 as i64), xs.voxels(p1 as i64 - 1));
            shade(row, (first, end));
            let mut lo = xs.left(p0 as i64);
            for o in out.get_mut(p0..p1).unwrap_or_default() {
                *o = xs.filter(lo, row.buf);
                lo += xs.w;
            }
            slot.lo = slot.lo.min(p0);
            slot.hi = p1;
        }
    }
    if slot.lo > slot.hi {
        slot.lo = 0;
        slot.hi = 0;
    }
    slot
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::composite::{mark_random_stretches, Lit, Portable};

    fn weights(scale: f64, origin: f64, u: i64) -> (i64, heapless::Vec<u32, MAX_TAPS>) {
        let m = AxisMap::new(scale, origin);
        let mut w = [0; MAX_TAPS];
        let (first, n) = m.taps(u, &mut w);
        (first, w[..n].iter().copied().collect())
    }

    #[test]
    fn open_runs_are_the_pixels_some_reader_has_open() {
        // Random opaque bitmaps on four scanlines 200 pixels wide (runs cross the 64-pixel
        // windows), random readers among them and random ranges: the runs must be the
        // pixels of the range open in some reader (all of them without readers or with
        // none), in order, disjoint, non-empty and not touching.
        const W: usize = 200;
        let mut rng = crate::xorshift(0x0be5_4ea1);
        let mut next = |m: usize| (rng() % (m as u64 + 1)) as usize;
        for round in 0..400 {
            let mut pixels = [[0u16; 4]; 4 * W];
            let mut links = [0; 4 * W];
            let mut img = Intermediate::band(W, 20, 8, 4, &mut pixels, &mut links).unwrap();
            let dense = next(3);
            for r in 0..4 {
                let (_, line) = img.scanline_mut(r);
                mark_random_stretches(line, W, (150, 8), dense, &mut next);
            }
            let first = next(3);
            let count = next(4 - first);
            let readers = Readers {
                img: &img,
                first,
                count,
            };
            let (a, b) = (next(W), next(W));
            let (u, end) = (a.min(b), a.max(b));
            let with = round % 4 != 0;
            let open = |p: usize| {
                !with
                    || count == 0
                    || (first..first + count).any(|r| !opaque::is_opaque(img.opaque_line(r), p))
            };
            let mut seen = [false; W];
            let mut last_end = None;
            for (p0, p1) in OpenRuns::new(with.then_some(&readers), u, end) {
                assert!(
                    u <= p0 && p0 < p1 && p1 <= end,
                    "round {round}: run {p0}..{p1}"
                );
                if let Some(e) = last_end {
                    assert!(p0 > e, "round {round}: runs touch or overlap at {p0}");
                }
                last_end = Some(p1);
                seen[p0..p1].iter_mut().for_each(|s| *s = true);
            }
            for (p, &got) in seen.iter().enumerate() {
                let want = (u..end).contains(&p) && open(p);
                assert_eq!(got, want, "round {round}: pixel {p} of {u}..{end}");
            }
        }
    }

    #[test]
    fn the_shader_shades_each_asked_visible_voxel_once_and_nothing_else() {
        // Random scanlines (`random_scanline`) and random requests whose starts never
        // decrease: a visible voxel
        // must come out as the eager fill shades it when a request from its start on
        // covered it, and stay zero otherwise; the extent covers every shaded voxel.
        const NI: usize = 150;
        let mut rng = crate::xorshift(0x5ade_0f11);
        let mut next = |m: usize| (rng() % (m as u64 + 1)) as usize;
        let plain = crate::composite::PlainTables::new();
        let t = plain.get();
        for round in 0..300 {
            let (runs, voxels): (heapless::Vec<u8, 400>, heapless::Vec<Voxel, NI>) =
                crate::composite::random_scanline(NI, &mut |m| next(m as usize) as u32);
            let mut eager_buf = [[0u16; 4]; NI + 2];
            let mut eager = Row::new(&mut eager_buf, false);
            eager.fill((&runs, &voxels, &[]), &t, 0, None, None, &Portable, &Lit);
            let mut lazy_buf = [[3u16; 4]; NI + 2];
            let mut lazy = Row::new(&mut lazy_buf, false);
            let mut shader = Shader::new(&runs, &voxels, NI, None);
            let mut asked = [false; NI];
            let mut from = next(10) as i64 - 5;
            for _ in 0..next(6) {
                let to = from + next(60) as i64 - 10;
                shader.upto(&mut lazy, (from, to), &t, 0, &Portable, &Lit);
                for x in from.max(0)..to.min(NI as i64) {
                    asked[x as usize] = true;
                }
                from += next(50) as i64;
            }
            for (x, &was_asked) in asked.iter().enumerate() {
                let (e, l) = (eager.buf[x + 1], lazy.buf[x + 1]);
                if was_asked {
                    assert_eq!(l, e, "round {round}: voxel {x} was asked for");
                } else {
                    assert_eq!(l, [0; 4], "round {round}: voxel {x} was not asked for");
                }
            }
            assert!(lazy.zero_outside_extent());
        }
    }

    #[test]
    fn unit_scale_is_bilinear() {
        // Pixel 5 with voxel 0 at 1.3: slice position 3.7 → voxels 3 (0.3) and 4 (0.7).
        let (first, w) = weights(1.0, 1.3, 5);
        assert_eq!(first, 3);
        let ones: u32 = w.iter().sum();
        assert_eq!(ones, ONE);
        assert!((w[0] as f64 / ONE as f64 - 0.3).abs() < 1e-3, "{w:?}");
        assert!((w[1] as f64 / ONE as f64 - 0.7).abs() < 1e-3, "{w:?}");
    }

    #[test]
    fn decimated_weights_are_box_overlaps_summing_to_one() {
        for &scale in &[0.9, 0.5, 0.37, 0.125] {
            for u in 0..40 {
                let (first, w) = weights(scale, 2.25, u);
                assert_eq!(w.iter().sum::<u32>(), ONE, "scale {scale} u {u}");
                // Compare with the exact overlaps.
                let x = (u as f64 - 2.25) / scale;
                let wd = 1.0 / scale;
                for (t, &wt) in w.iter().enumerate() {
                    let i = (first + t as i64) as f64;
                    let ov = ((i + 0.5).min(x + wd / 2.0) - (i - 0.5).max(x - wd / 2.0)).max(0.0);
                    assert!(
                        (wt as f64 / ONE as f64 - ov / wd).abs() < 2e-4,
                        "{scale} {u} {t}"
                    );
                }
                assert!(w.len() <= (1.0 / scale) as usize + 2);
            }
        }
    }

    #[test]
    fn pixel_ranges_cover_every_pixel_a_run_reaches() {
        for &scale in &[1.0, 0.6, 0.3] {
            let m = AxisMap::new(scale, 3.4);
            let (lo, hi) = m.pixels_of(5, 9);
            let mut w = [0; MAX_TAPS];
            for u in lo - 3..hi + 3 {
                let (first, n) = m.taps(u, &mut w);
                let touches = (0..n).any(|t| {
                    let i = first + t as i64;
                    w[t] > 0 && (5..9).contains(&i)
                });
                if touches {
                    assert!(
                        u >= lo && u < hi,
                        "scale {scale}: pixel {u} outside {lo}..{hi}"
                    );
                }
            }
        }
    }
}
