//! The 2D warp from the intermediate image to the final image (Lacroute 1995, §3.2.3).
//!
//! Each output pixel centre is mapped through the inverse affine warp into the
//! intermediate image and reconstructed bilinearly. Positions are 16.16 fixed point: the
//! start of each output row is computed from the exact affine map (so error does not
//! accumulate across rows) and stepped by a constant increment along the row.
//!
//! A perspective view's warp is projective (§3.3): the homogeneous coordinates are
//! stepped along the row in Q24 and divided per pixel.

use crate::composite::Rgba;
use crate::error::{need, Error};
use crate::fixed::{self, ONE};
use crate::view::Factorization;

/// Receives finished image rows: RGBA8, premultiplied over a black background.
pub trait PixelSink {
    /// Row `y` (0 at the top) of the final image, `width` pixels.
    fn put_row(&mut self, y: usize, row: &[[u8; 4]]) -> Result<(), Error>;
}

/// The sink of a warp whose row buffer is the frame itself: [`warp_rows`] leaves each
/// row it warps in the buffer (row `rows.start + i` at width `i`, when the buffer holds
/// the rows' widths and no more than [`TILE_ROWS`]), so there is nothing to copy. A
/// frontend warping a strip of its frame at a time passes that strip as the buffer and
/// saves a copy of every output pixel (1.5 % of the head's 512² frame in `perf`).
pub struct InPlace;

impl PixelSink for InPlace {
    fn put_row(&mut self, _: usize, _: &[[u8; 4]]) -> Result<(), Error> {
        Ok(())
    }
}

/// A sink writing into a caller-owned row-major frame buffer.
pub struct FrameBuffer<'a> {
    /// Width in pixels.
    pub width: usize,
    /// Pixels, row-major.
    pub pixels: &'a mut [[u8; 4]],
}

impl PixelSink for FrameBuffer<'_> {
    fn put_row(&mut self, y: usize, row: &[[u8; 4]]) -> Result<(), Error> {
        let start = y * self.width;
        let got = self.pixels.len();
        let dst = self
            .pixels
            .get_mut(start..start + row.len())
            .ok_or(Error::BufferTooSmall {
                what: "frame buffer",
                needed: start + row.len(),
                got,
            })?;
        dst.copy_from_slice(row);
        Ok(())
    }
}

const FRAC: u32 = 16;

fn to_fixed(x: f64) -> i64 {
    // Clamp far-away coordinates: anything beyond ±2^40 is outside the image anyway.
    let c = x.clamp(-1.0e12, 1.0e12);
    libm::round(c * (1u64 << FRAC) as f64) as i64
}

/// [`inside_run`] for 8-bit output in AVX2, four pixels a step, with the bilinear sums
/// taken by 16-bit multiply-adds (`vpmaddwd`), which multiply and add a pixel's two
/// horizontal taps in one instruction: a 128-bit half of a register holds one pixel's
/// left and right tap, channel by channel (one shuffle of the two neighbouring pixels as
/// stored). A version in 32-bit lanes spent four multiplies per two pixels and loaded
/// each tap on its own; this one spends two multiply-adds per two pixels and loads each
/// pair of taps whole.
///
/// The multiply-add is signed, 16 by 16 bits, and a tap may be [`ONE`] (`0x8000`), so
/// the taps are offset by `−2^14` to `−2^14..=2^14`. The weights sum to [`ONE`], so the
/// offset takes exactly `2^14·2^15 = 2^29` from every sum, and adding it back gives the
/// sum [`interior`] takes: bit-identical to [`inside_run`] with [`Texel::inner`] for
/// `[u8; 4]` (the weights are [`weights`]'s, taken from the low 16 bits of wrapping
/// 32-bit positions: only the fractions are needed). A weight can be `ONE` itself (a
/// position on the grid in both directions, or on it in one and a step short in the
/// other), and a caller's taps may exceed `ONE` (no compositor writes them): a step with
/// either goes to [`inside_run`], as do steps with a tap outside the image (only if the
/// caller's interval were wrong) and the pixels left over. Rounding to bytes is
/// `vpmulhrsw` by 255, which is exactly `(q·255 + 2^14) >> 15`, after a saturating pack
/// that turns `q = ONE` into `ONE − 1` (both give 255).
#[cfg(target_arch = "x86_64")]
macro_rules! inside_run_madd {
    () => {
        |px: &[Rgba],
         iw: usize,
         (u, du): (i64, i64),
         (v, dv): (i64, i64),
         out: &mut [[u8; 4]],
         zero: [u8; 4]| {
            use core::arch::x86_64::*;
            let lanes = _mm_setr_epi32(0, 1, 2, 3);
            // Positions of the four pixels of a step after the first, wrapping in 32
            // bits: only their fractions (the low 16 bits) are used.
            let pdu = _mm_mullo_epi32(lanes, _mm_set1_epi32(du as i32));
            let pdv = _mm_mullo_epi32(lanes, _mm_set1_epi32(dv as i32));
            let (frac, whole) = (_mm_set1_epi32(0xffff), _mm_set1_epi32(0x1_0000));
            let one = _mm_set1_epi32(ONE as i32);
            // Left and right tap of a pixel, channel by channel: bytes of [l, r].
            let interleave = _mm256_setr_epi8(
                0, 1, 8, 9, 2, 3, 10, 11, 4, 5, 12, 13, 6, 7, 14, 15, //
                0, 1, 8, 9, 2, 3, 10, 11, 4, 5, 12, 13, 6, 7, 14, 15,
            );
            let offset = _mm256_set1_epi16(1 << 14);
            let top_bit = _mm256_set1_epi16(ONE as u16 as i16);
            let bias = _mm256_set1_epi32((1 << 29) + (1 << 14));
            let c255 = _mm256_set1_epi16(255);
            // A pixel's weight pair into the four 32-bit lanes of its half.
            let (pick01, pick23) = (
                _mm256_setr_epi32(0, 0, 0, 0, 1, 1, 1, 1),
                _mm256_setr_epi32(2, 2, 2, 2, 3, 3, 3, 3),
            );
            // Bytes of pixels 0, 2 (low half) and 1, 3 (high half) in pixel order.
            let order = _mm256_setr_epi32(0, 4, 1, 5, 0, 0, 0, 0);
            // The top and the bottom pair of taps of pixel x, each one 16-byte load.
            let taps = |x: i64| -> Option<(__m128i, __m128i)> {
                let (ux, vx) = (u + x * du, v + x * dv);
                let base = (vx >> FRAC) as usize * iw + (ux >> FRAC) as usize;
                let q = px.get(base..base.checked_add(iw + 2)?)?;
                let load = |p: &[Rgba]| bytemuck::pod_read_unaligned(bytemuck::cast_slice(p));
                Some((load(&q[..2]), load(&q[iw..])))
            };
            let steps = out.len() / 4;
            for (k, o) in out.chunks_exact_mut(4).enumerate() {
                let x = 4 * k as i64;
                let (ux, vx) = (u + x * du, v + x * dv);
                let (Some(t0), Some(t1), Some(t2), Some(t3)) =
                    (taps(x), taps(x + 1), taps(x + 2), taps(x + 3))
                else {
                    inside_run(px, iw, (ux, du), (vx, dv), o, zero);
                    continue;
                };
                // Taps of two pixels, a in the low half.
                let (top01, bot01) = (_mm256_set_m128i(t1.0, t0.0), _mm256_set_m128i(t1.1, t0.1));
                let (top23, bot23) = (_mm256_set_m128i(t3.0, t2.0), _mm256_set_m128i(t3.1, t2.1));
                let max = _mm256_max_epu16(
                    _mm256_max_epu16(top01, bot01),
                    _mm256_max_epu16(top23, bot23),
                );
                if _mm256_testz_si256(max, max) != 0 {
                    o.fill(zero);
                    continue;
                }
                // Weights of the four pixels, as `weights` computes them.
                let uu = _mm_add_epi32(_mm_set1_epi32(ux as i32), pdu);
                let vv = _mm_add_epi32(_mm_set1_epi32(vx as i32), pdv);
                let fu = _mm_srli_epi32::<1>(_mm_sub_epi32(whole, _mm_and_si128(uu, frac)));
                let fv = _mm_srli_epi32::<1>(_mm_sub_epi32(whole, _mm_and_si128(vv, frac)));
                let fb = _mm_sub_epi32(one, fv);
                let tl = _mm_srli_epi32::<15>(_mm_mullo_epi32(fv, fu));
                let bl = _mm_srli_epi32::<15>(_mm_mullo_epi32(fb, fu));
                let (tr, br) = (_mm_sub_epi32(fv, tl), _mm_sub_epi32(fb, bl));
                let wmax = _mm_max_epu32(_mm_max_epu32(tl, tr), _mm_max_epu32(bl, br));
                let big = _mm256_subs_epu16(max, top_bit);
                let wide_weight = _mm_movemask_epi8(_mm_cmpeq_epi32(wmax, one));
                if _mm256_testz_si256(big, big) == 0 || wide_weight != 0 {
                    inside_run(px, iw, (ux, du), (vx, dv), o, zero);
                    continue;
                }
                let wt = _mm256_castsi128_si256(_mm_or_si128(tl, _mm_slli_epi32::<16>(tr)));
                let wb = _mm256_castsi128_si256(_mm_or_si128(bl, _mm_slli_epi32::<16>(br)));
                let sum = |top: __m256i, bot: __m256i, pick: __m256i| -> __m256i {
                    let t = _mm256_sub_epi16(_mm256_shuffle_epi8(top, interleave), offset);
                    let b = _mm256_sub_epi16(_mm256_shuffle_epi8(bot, interleave), offset);
                    let s = _mm256_add_epi32(
                        _mm256_madd_epi16(t, _mm256_permutevar8x32_epi32(wt, pick)),
                        _mm256_madd_epi16(b, _mm256_permutevar8x32_epi32(wb, pick)),
                    );
                    _mm256_srli_epi32::<15>(_mm256_add_epi32(s, bias))
                };
                let q = _mm256_packs_epi32(sum(top01, bot01, pick01), sum(top23, bot23, pick23));
                let b = _mm256_mulhrs_epi16(q, c255);
                let bytes = _mm256_permutevar8x32_epi32(_mm256_packus_epi16(b, b), order);
                o.copy_from_slice(&bytemuck::cast::<_, [[u8; 4]; 4]>(_mm256_castsi256_si128(
                    bytes,
                )));
            }
            let x = 4 * steps as i64;
            let rest = &mut out[4 * steps..];
            inside_run(px, iw, (u + x * du, du), (v + x * dv, dv), rest, zero);
        }
    };
}

/// Warps the intermediate image `px` (the full `view.intermediate` size, row-major) into
/// the final image, one row at a time through `sink`. `row` must hold at least the image
/// width.
pub fn warp(
    px: &[Rgba],
    view: &Factorization,
    row: &mut [[u8; 4]],
    sink: &mut impl PixelSink,
) -> Result<(), Error> {
    warp_rows(px, None, view, 0..view.image[1], row, sink)
}

/// Warps output rows `rows` only (threads can split the final image between them; each
/// row is computed independently, so the result does not depend on the split). `row`
/// holds at least the image width; given `k` widths (`k` up to [`TILE_ROWS`]), `k`
/// rows are warped together, in tiles that keep the intermediate pixels they read in
/// cache (same result). Row `rows.start + i` is handed to `sink` from width `i % k` of
/// `row`, and stays there: a `row` that is the frame's own strip of rows needs no sink
/// ([`InPlace`]).
///
/// `extents`, when given, are the intermediate image's [`extents`]: runs of output
/// pixels whose taps all fall outside them are filled with the background without being
/// sampled (bit-identical: they would sample only zero pixels).
pub fn warp_rows(
    px: &[Rgba],
    extents: Option<&[[u32; 2]]>,
    view: &Factorization,
    rows: core::ops::Range<usize>,
    row: &mut [[u8; 4]],
    sink: &mut impl PixelSink,
) -> Result<(), Error> {
    let put = |y, r: &[[u8; 4]]| sink.put_row(y, r);
    warp_generic(px, extents, view, rows, row, put, &inside_run)
}

/// [`warp_rows`] compiled for x86-64-v3 (AVX2, BMI1/2, FMA, LZCNT, POPCNT), bit-identical:
/// the pixels whose four taps lie inside the intermediate image are warped four at a
/// time by `inside_run_madd` (brainsmall at 512², frames alternating with the
/// 32-bit-lane version in one process: 1.83 → 1.61 ms a frame, the head 5.83 → 5.58).
///
/// # Safety
///
/// The CPU must have every feature enabled here (as for
/// [`crate::render::composite_band_until_x86_v3`]); the file frontend's `isa` module
/// checks before it calls.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,bmi1,bmi2,fma,lzcnt,popcnt")]
pub fn warp_rows_x86_v3(
    px: &[Rgba],
    extents: Option<&[[u32; 2]]>,
    view: &Factorization,
    rows: core::ops::Range<usize>,
    row: &mut [[u8; 4]],
    sink: &mut impl PixelSink,
) -> Result<(), Error> {
    let put = |y, r: &[[u8; 4]]| sink.put_row(y, r);
    warp_generic(px, extents, view, rows, row, put, &inside_run_madd!())
}

/// [`warp_rows`] compiled for x86-64-v4 (AVX-512 F/BW/VL/DQ/CD on top of x86-64-v3),
/// bit-identical: the same kernel as [`warp_rows_x86_v3`], `inside_run_madd`, which
/// the compiler encodes with AVX-512's extra registers. An AVX-512 kernel of its own,
/// four pixels a step in 32-bit lanes with 32-bit multiplies, was slower on a Zen 4
/// than the 16-bit multiply-adds: warping the same frame alternately with both in one
/// process (median of 144), 0.57 against 0.44 ms on the head at 512², 0.10 against
/// 0.08 ms on brainsmall at 256²; compiled here, `inside_run_madd` takes 4–8 % less
/// than in the x86-64-v3 build.
///
/// # Safety
///
/// The CPU must have every feature enabled here (as for
/// [`crate::render::composite_band_until_x86_v4`]); the file frontend's `isa` module
/// checks before it calls.
#[cfg(target_arch = "x86_64")]
#[target_feature(
    enable = "avx2,bmi1,bmi2,fma,lzcnt,popcnt,avx512f,avx512bw,avx512vl,avx512dq,avx512cd"
)]
pub fn warp_rows_x86_v4(
    px: &[Rgba],
    extents: Option<&[[u32; 2]]>,
    view: &Factorization,
    rows: core::ops::Range<usize>,
    row: &mut [[u8; 4]],
    sink: &mut impl PixelSink,
) -> Result<(), Error> {
    let put = |y, r: &[[u8; 4]]| sink.put_row(y, r);
    warp_generic(px, extents, view, rows, row, put, &inside_run_madd!())
}

/// As [`warp_rows`], handing out rows at the intermediate image's full precision:
/// premultiplied RGBA in Q15 (`0..=32768` is 0..1), for 16-bit output.
pub fn warp_rows_q15(
    px: &[Rgba],
    extents: Option<&[[u32; 2]]>,
    view: &Factorization,
    rows: core::ops::Range<usize>,
    row: &mut [[u16; 4]],
    mut put_row: impl FnMut(usize, &[[u16; 4]]) -> Result<(), Error>,
) -> Result<(), Error> {
    let put = |y, r: &[[u16; 4]]| put_row(y, r);
    warp_generic(px, extents, view, rows, row, put, &inside_run)
}

/// For each scanline of the intermediate image `px` (`iw` pixels wide), the columns
/// `[first, last + 1)` from its first to its last pixel that is not zero (`[0, 0]` for
/// an empty scanline), into `out` (one entry per scanline). The scan stops at the first
/// such pixel from either end, so it reads little more than the background.
pub fn extents(px: &[Rgba], iw: usize, out: &mut [[u32; 2]]) -> Result<(), Error> {
    if iw == 0 {
        return Ok(());
    }
    need("warp extents", px.len() / iw, out.len())?;
    for (line, e) in px.chunks_exact(iw).zip(out.iter_mut()) {
        let set = |p: &Rgba| pack(p) != 0;
        *e = match (line.iter().position(set), line.iter().rposition(set)) {
            (Some(a), Some(b)) => [a as u32, b as u32 + 1],
            _ => [0, 0],
        };
    }
    Ok(())
}

/// Output pixels per test against the extents: long enough that a test costs little per
/// pixel, short enough to follow an object's outline.
const SKIP_RUN: usize = 16;

/// True if no pixel of the output run from 16.16 position `a` to `b` (its first and
/// last pixel, all taps inside the image) can read a pixel that is not zero: every
/// scanline its taps touch is empty over the columns they touch. The positions between
/// `a` and `b` lie on the segment between them, so their taps lie in the box of the
/// taps of the two ends.
#[inline(always)]
fn background(extents: &[[u32; 2]], a: (i64, i64), b: (i64, i64)) -> bool {
    let (u0, u1) = (
        (a.0.min(b.0) >> FRAC) as u32,
        (a.0.max(b.0) >> FRAC) as u32 + 1,
    );
    let (v0, v1) = (
        (a.1.min(b.1) >> FRAC) as usize,
        (a.1.max(b.1) >> FRAC) as usize + 1,
    );
    extents
        .get(v0..=v1)
        .is_some_and(|lines| lines.iter().all(|&[f, l]| f >= l || u1 < f || u0 >= l))
}

/// True if every inside pixel of a tile (columns `c0..c1` of rows whose start positions
/// and inside pixels `xi..xj` are `rows`, the positions stepping by `(du, dv)`) reads
/// only background: one test of the box of the tile's corners against the extents,
/// where [`background`] makes one per [`SKIP_RUN`] pixels of each row. The rows' starts
/// are rounded from one affine map, so they are monotone in the row and every position
/// of the tile lies in the box of its four corners. A box reaching past the image's top
/// or left edge is not background.
#[inline(always)]
fn tile_is_background(
    extents: &[[u32; 2]],
    rows: &[(i64, i64, usize, usize)],
    (c0, c1): (usize, usize),
    (du, dv): (i64, i64),
) -> bool {
    let (mut a, mut b) = (usize::MAX, 0);
    for &(_, _, xi, xj) in rows {
        let (ra, rb) = (xi.max(c0), xj.min(c1));
        if ra < rb {
            (a, b) = (a.min(ra), b.max(rb));
        }
    }
    let (Some(first), Some(last)) = (rows.first(), rows.last()) else {
        return false;
    };
    if a >= b {
        return false;
    }
    let at = |r: &(i64, i64, usize, usize), x: usize| (r.0 + x as i64 * du, r.1 + x as i64 * dv);
    let corners = [at(first, a), at(first, b - 1), at(last, a), at(last, b - 1)];
    let lo = corners
        .iter()
        .fold((i64::MAX, i64::MAX), |m, p| (m.0.min(p.0), m.1.min(p.1)));
    let hi = corners
        .iter()
        .fold((i64::MIN, i64::MIN), |m, p| (m.0.max(p.0), m.1.max(p.1)));
    lo.0 >= 0 && lo.1 >= 0 && background(extents, lo, hi)
}

/// An output pixel of the warp. A trait rather than a pair of closures: the closures
/// were called out of line from the pixel loop (a tenth of `perf`'s samples of a
/// brainsmall run at 512²).
trait Texel: Copy {
    /// The pixel of a Q15 sample.
    fn convert(q: [u32; 4]) -> Self;
    /// `convert` of [`interior`] for a sample whose four taps (top left, top right,
    /// bottom left, bottom right, each [`pack`]ed) lie inside the intermediate image
    /// (most of them, so a faster one pays).
    #[inline(always)]
    fn inner(taps: [u64; 4], w: [u32; 4]) -> Self {
        Self::convert(interior_packed(taps, w))
    }
}

impl Texel for [u8; 4] {
    #[inline(always)]
    fn convert(q: [u32; 4]) -> Self {
        q.map(fixed::to_u8)
    }
    #[inline(always)]
    fn inner(taps: [u64; 4], w: [u32; 4]) -> Self {
        interior_u8(taps, w)
    }
}

impl Texel for [u16; 4] {
    #[inline(always)]
    fn convert(q: [u32; 4]) -> Self {
        q.map(|c| c.min(ONE) as u16)
    }
}

/// The warp loop, generic over the output pixel and over the loop for pixels whose taps
/// are all inside (inlined into each caller, so that an instruction-set build compiles
/// it with its features).
#[cfg_attr(target_arch = "x86_64", inline(always))]
fn warp_generic<T: Texel>(
    px: &[Rgba],
    extents: Option<&[[u32; 2]]>,
    view: &Factorization,
    rows: core::ops::Range<usize>,
    row: &mut [T],
    mut put_row: impl FnMut(usize, &[T]) -> Result<(), Error>,
    run: &impl Fn(&[Rgba], usize, (i64, i64), (i64, i64), &mut [T], T),
) -> Result<(), Error> {
    let zero = T::convert([0; 4]);
    let [w, h] = view.image;
    need("warp row", w, row.len())?;
    let [iwu, ihu] = view.intermediate;
    need("intermediate pixels", iwu * ihu, px.len())?;
    let m = view.image_to_intermediate;
    let (iw, ih) = (iwu as i64, ihu as i64);
    let du = to_fixed(m[0][0]);
    let dv = to_fixed(m[1][0]);
    let rows = rows.start..rows.end.min(h);
    // As many rows at a time as `row` holds, up to TILE_ROWS; row `rows.start + i` is
    // left at width `i % strip` of the buffer (see [`InPlace`]).
    let strip = (row.len() / w.max(1)).clamp(1, TILE_ROWS);
    if m[2] != [0.0, 0.0, 1.0] {
        // Projective: numerators and denominator in Q24, stepped exactly along the row.
        let q = |x: f64| libm::round(x.clamp(-1.0e9, 1.0e9) * (1u64 << PFRAC) as f64) as i64;
        let step = [q(m[0][0]), q(m[1][0]), q(m[2][0])];
        let got = row.len();
        for (i, y) in rows.enumerate() {
            // Inside `row`: `strip` rows of `w` fit in it.
            let row = row.get_mut(i % strip * w..).and_then(|r| r.get_mut(..w));
            let row = row.ok_or(Error::BufferTooSmall {
                what: "warp row",
                needed: w,
                got,
            })?;
            let yc = y as f64 + 0.5;
            let at = |r: usize| q(m[r][0] * 0.5 + m[r][1] * yc + m[r][2]);
            let mut num = [at(0), at(1), at(2)];
            for out in row.iter_mut() {
                *out = match project(num) {
                    Some((u, v)) => sample(px, iw, ih, u, v, zero),
                    None => zero,
                };
                for (n, s) in num.iter_mut().zip(step) {
                    *n = n.saturating_add(s);
                }
            }
            put_row(y, row)?;
        }
        return Ok(());
    }
    if w == 0 {
        for y in rows {
            put_row(y, &[])?;
        }
        return Ok(());
    }
    let one = 1i64 << FRAC;
    let mut y0 = rows.start;
    while y0 < rows.end {
        let n = strip.min(rows.end - y0);
        // Per row: its start position and the pixels xi..xj whose four taps lie inside.
        let mut inner = [(0i64, 0i64, 0usize, 0usize); TILE_ROWS];
        for (r, (out, plan)) in row.chunks_exact_mut(w).zip(&mut inner).take(n).enumerate() {
            let yc = (y0 + r) as f64 + 0.5;
            let u = to_fixed(m[0][0] * 0.5 + m[0][1] * yc + m[0][2]);
            let v = to_fixed(m[1][0] * 0.5 + m[1][1] * yc + m[1][2]);
            // Only pixels xa..xb of the row reach the intermediate image at all, and of
            // those, xi..xj have all four taps inside it (most of them): the edge pixels
            // take the checked path here, the others a loop without per-tap tests below.
            let (xa, xb) = reach(u, du, v, dv, [-one, iw * one], [-one, ih * one], w);
            let (xi, xj) = reach(u, du, v, dv, [0, (iw - 1) * one], [0, (ih - 1) * one], w);
            let (xi, xj) = if xi < xj { (xi, xj) } else { (xb, xb) };
            // xa <= xi <= xj <= xb <= w: every range lies in the row.
            out.get_mut(..xa).unwrap_or_default().fill(zero);
            out.get_mut(xb..).unwrap_or_default().fill(zero);
            for x in (xa..xi).chain(xj..xb) {
                let (pu, pv) = (u + x as i64 * du, v + x as i64 * dv);
                if let Some(o) = out.get_mut(x) {
                    *o = sample(px, iw, ih, pu, pv, zero);
                }
            }
            *plan = (u, v, xi, xj);
        }
        // The inside pixels in tiles of TILE_COLS columns by the strip's rows: when the
        // intermediate image is walked across its scanlines (a view whose principal
        // axis turns the image), each output row reads a new cache line per pixel, and
        // a tile's rows reuse them while they are still cached.
        for c0 in (0..w).step_by(TILE_COLS) {
            let c1 = (c0 + TILE_COLS).min(w);
            let empty_tile =
                extents.is_some_and(|e| tile_is_background(e, &inner[..n], (c0, c1), (du, dv)));
            for (out, &(u, v, xi, xj)) in row.chunks_exact_mut(w).zip(&inner).take(n) {
                let at = |x: usize| (u + x as i64 * du, v + x as i64 * dv);
                let inside = |from: usize, to: usize, out: &mut [T]| {
                    let (u, v) = at(from);
                    // from <= to <= w, the row's width.
                    let pixels = out.get_mut(from..to).unwrap_or_default();
                    run(px, iwu, (u, du), (v, dv), pixels, zero);
                };
                let (a, b) = (xi.max(c0), xj.min(c1));
                match extents {
                    _ if a >= b => {}
                    _ if empty_tile => out.get_mut(a..b).unwrap_or_default().fill(zero),
                    None => inside(a, b, out),
                    Some(ext) => {
                        // Runs of SKIP_RUN pixels over background are filled; the pixels
                        // between them go to the inside loop in one call.
                        let mut start = a;
                        for x in (a..b).step_by(SKIP_RUN) {
                            let end = (x + SKIP_RUN).min(b);
                            if background(ext, at(x), at(end - 1)) {
                                inside(start, x, out);
                                out.get_mut(x..end).unwrap_or_default().fill(zero);
                                start = end;
                            }
                        }
                        inside(start, b, out);
                    }
                }
            }
        }
        for (r, out) in row.chunks_exact(w).take(n).enumerate() {
            put_row(y0 + r, out)?;
        }
        y0 += n;
    }
    Ok(())
}

/// Most output rows `warp_generic` warps together (when its row buffer holds them).
pub const TILE_ROWS: usize = 16;

/// Output columns per tile of [`warp_generic`]'s inside pixels.
const TILE_COLS: usize = 64;

/// True if the 16.16 position `(u, v)` has a tap inside an `iw×ih` intermediate image
/// (the test [`sample`] makes before it reads anything).
#[inline(always)]
fn reaches(u: i64, v: i64, iw: i64, ih: i64) -> bool {
    let (u0, v0) = (u >> FRAC, v >> FRAC);
    u0 >= -1 && v0 >= -1 && u0 < iw && v0 < ih
}

/// The pixels `xa..xb` of a `w`-pixel row, starting at the 16.16 position `(u, v)` and
/// stepping by `(du, dv)`, whose position lies in the box `bu[0] ≤ u < bu[1]`,
/// `bv[0] ≤ v < bv[1]`: with the box `[-1, n)` (in pixels) the pixels that reach the
/// intermediate image ([`reaches`]), with `[0, n − 1)` those whose four taps lie inside
/// it. The positions are affine in x, so these pixels are one interval; it is estimated
/// in floating point and then settled with the exact test at both ends.
fn reach(u: i64, du: i64, v: i64, dv: i64, bu: [i64; 2], bv: [i64; 2], w: usize) -> (usize, usize) {
    // x with lo ≤ p + x·dp < hi, as a real interval.
    let span = |p: i64, dp: i64, b: [i64; 2]| -> (f64, f64) {
        let (lo, hi) = ((b[0] - p) as f64, (b[1] - p) as f64);
        match dp {
            0 if lo <= 0.0 && hi > 0.0 => (f64::NEG_INFINITY, f64::INFINITY),
            0 => (0.0, 0.0),
            d if d > 0 => (lo / d as f64, hi / d as f64),
            d => (hi / d as f64, lo / d as f64),
        }
    };
    let (a0, b0) = span(u, du, bu);
    let (a1, b1) = span(v, dv, bv);
    let wf = w as f64;
    let mut xa = libm::ceil(a0.max(a1)).clamp(0.0, wf) as usize;
    let mut xb = libm::ceil(b0.min(b1)).clamp(0.0, wf) as usize;
    xb = xb.max(xa);
    let within = |p: i64, b: [i64; 2]| p >= b[0] && p < b[1];
    let at = |x: usize| within(u + x as i64 * du, bu) && within(v + x as i64 * dv, bv);
    while xa > 0 && at(xa - 1) {
        xa -= 1;
    }
    while xa < xb && !at(xa) {
        xa += 1;
    }
    xb = xb.max(xa);
    while xb < w && at(xb) {
        xb += 1;
    }
    while xb > xa && !at(xb - 1) {
        xb -= 1;
    }
    (xa, xb)
}

/// Fraction bits of the projective warp's homogeneous coordinates.
const PFRAC: u32 = 24;

/// `(U/W, V/W)` in 16.16 from Q24 homogeneous coordinates, or `None` where the ray does
/// not reach the slices (`W ≤ 0`) or lands far outside any intermediate image.
#[inline]
fn project(n: [i64; 3]) -> Option<(i64, i64)> {
    let w = n[2];
    if w <= 0 || w > 1 << 40 {
        return None;
    }
    // Whole and fractional parts separately, so nothing overflows: |n| < 2^54, w < 2^40.
    let div = |a: i64| -> Option<i64> {
        let q = a.div_euclid(w);
        if !(-(1 << 20)..1 << 20).contains(&q) {
            return None;
        }
        Some((q << FRAC) + (a.rem_euclid(w) << FRAC) / w)
    };
    Some((div(n[0])?, div(n[1])?))
}

/// Bilinear reconstruction of the intermediate image at 16.16 `(u, v)`, as
/// [`Texel::convert`] of the Q15 sample ([`Texel::inner`] where all four taps are
/// inside); `zero` outside.
#[inline(always)]
fn sample<T: Texel>(px: &[Rgba], iw: i64, ih: i64, u: i64, v: i64, zero: T) -> T {
    let u0 = u >> FRAC;
    let v0 = v >> FRAC;
    if !reaches(u, v, iw, ih) {
        return zero;
    }
    // Inside: all four taps exist.
    if u0 >= 0 && v0 >= 0 && u0 + 1 < iw && v0 + 1 < ih {
        if let Some(t) = inside(px, iw as usize, u, v, zero) {
            return t;
        }
    }
    let wts = weights(u, v);
    // At the image's edge, the taps outside it read as zero.
    let tap = |tu: i64, tv: i64| -> Rgba {
        let inside = tu >= 0 && tv >= 0 && tu < iw && tv < ih;
        let at = (tv * iw + tu) as usize;
        inside
            .then(|| px.get(at).copied())
            .flatten()
            .unwrap_or([0; 4])
    };
    let top = [tap(u0, v0), tap(u0 + 1, v0)];
    let bot = [tap(u0, v0 + 1), tap(u0 + 1, v0 + 1)];
    T::convert(interior(&top, &bot, wts))
}

/// The bilinear weights of the 16.16 position `(u, v)`.
#[inline(always)]
fn weights(u: i64, v: i64) -> [u32; 4] {
    let one = 1i64 << FRAC;
    let fu = ((one - (u & (one - 1))) >> 1) as u32;
    let fv = ((one - (v & (one - 1))) >> 1) as u32;
    fixed::bilinear_weights(fu, fv)
}

/// [`Texel::inner`] of the four taps of the 16.16 position `(u, v)` in the intermediate
/// image `px`, `iw` pixels wide, where they all lie inside it (`None` if they do not).
#[inline(always)]
fn inside<T: Texel>(px: &[Rgba], iw: usize, u: i64, v: i64, zero: T) -> Option<T> {
    let taps = taps_at(px, iw, u, v)?;
    // Empty background (most of a frame around a small volume) needs no weights.
    if taps[0] | taps[1] | taps[2] | taps[3] == 0 {
        return Some(zero);
    }
    Some(T::inner(taps, weights(u, v)))
}

/// The four taps of the 16.16 position `(u, v)` in the intermediate image `px`, `iw`
/// pixels wide, each [`pack`]ed (top left, top right, bottom left, bottom right), or
/// `None` if they do not all lie inside it: one bounds check for all four.
#[inline(always)]
fn taps_at(px: &[Rgba], iw: usize, u: i64, v: i64) -> Option<[u64; 4]> {
    let base = (v >> FRAC) as usize * iw + (u >> FRAC) as usize;
    let q = px.get(base..base.checked_add(iw + 2)?)?;
    // `q` is `iw + 2` long: its last two entries are `q[iw]` and `q[iw + 1]`.
    let ([tl, tr], [bl, br]) = (q.first_chunk::<2>()?, q.last_chunk::<2>()?);
    Some([pack(tl), pack(tr), pack(bl), pack(br)])
}

/// The pixels `out` of a row whose four taps all lie inside the intermediate image `px`
/// (`iw` pixels wide), the first at the 16.16 position `u.0, v.0` and each next one a
/// step `(u.1, v.1)` further: [`sample`] without its tests at the image's edge.
#[inline(always)]
fn inside_run<T: Texel>(
    px: &[Rgba],
    iw: usize,
    (mut u, du): (i64, i64),
    (mut v, dv): (i64, i64),
    out: &mut [T],
    zero: T,
) {
    for o in out {
        // `None` only if the caller's interval were wrong: the pixel stays blank.
        *o = inside(px, iw, u, v, zero).unwrap_or(zero);
        u += du;
        v += dv;
    }
}

/// The Q15 bilinear sample of the taps `top` and `bot` (left, right) with weights `w`
/// (top left, top right, bottom left, bottom right), rounded.
#[inline(always)]
fn interior(top: &[Rgba; 2], bot: &[Rgba; 2], w: [u32; 4]) -> [u32; 4] {
    let mut acc = [0u32; 4];
    for c in 0..4 {
        acc[c] = w[0] * top[0][c] as u32
            + w[1] * top[1][c] as u32
            + w[2] * bot[0][c] as u32
            + w[3] * bot[1][c] as u32;
    }
    acc.map(|a| (a + (1 << 14)) >> 15)
}

/// [`interior`] of four [`pack`]ed taps: top left, top right, bottom left, bottom right.
#[inline(always)]
fn interior_packed(taps: [u64; 4], w: [u32; 4]) -> [u32; 4] {
    let [tl, tr, bl, br] = taps.map(unpack);
    interior(&[tl, tr], &[bl, br], w)
}

/// The four channels of `p` in one word, channel 0 lowest. On little-endian targets
/// that is the pixel's memory as it is: one 64-bit load. Written as shifts, LLVM kept
/// sixteen 16-bit loads per sample and spilled them (a fifth of the warp's
/// instructions).
#[inline(always)]
fn pack(p: &Rgba) -> u64 {
    if cfg!(target_endian = "little") {
        bytemuck::cast(*p)
    } else {
        p[0] as u64 | (p[1] as u64) << 16 | (p[2] as u64) << 32 | (p[3] as u64) << 48
    }
}

/// The inverse of [`pack`].
#[inline(always)]
fn unpack(x: u64) -> Rgba {
    core::array::from_fn(|c| (x >> (16 * c)) as u16)
}

/// Two channels per 64-bit word, 32 bits each: `c0 | c2 << 32` and `c1 | c3 << 32`.
const LANES: u64 = 0x0000_FFFF_0000_FFFF;

/// `fixed::to_u8` of [`interior`], two channels per 64-bit multiply: each lane's
/// products and sums stay below 2^31 (weights and channels are at most 2^15 and the
/// weights sum to 2^15), so the lanes never carry into each other and every rounding is
/// the per-channel one. A channel above `ONE` (which no compositor writes) takes the
/// per-channel path, which clamps it.
#[inline(always)]
fn interior_u8(taps: [u64; 4], w: [u32; 4]) -> [u8; 4] {
    let (mut even, mut odd) = (0u64, 0u64);
    for (&x, &wt) in taps.iter().zip(w.iter()) {
        even += wt as u64 * (x & LANES);
        odd += wt as u64 * ((x >> 16) & LANES);
    }
    const HALF: u64 = 1 << 14 | 1 << 46;
    let even = ((even + HALF) >> 15) & LANES;
    let odd = ((odd + HALF) >> 15) & LANES;
    // A lane above 0x8000 sets bit 16 of its lane when 0x7FFF is added.
    const OVER: u64 = 0x7FFF | 0x7FFF << 32;
    if ((even + OVER) | (odd + OVER)) & (1 << 16 | 1 << 48) != 0 {
        return interior_packed(taps, w).map(fixed::to_u8);
    }
    const BYTES: u64 = 0xFF | 0xFF << 32;
    let to8 = |x: u64| ((x * 255 + HALF) >> 15) & BYTES;
    let (even, odd) = (to8(even), to8(odd));
    [even as u8, odd as u8, (even >> 32) as u8, (odd >> 32) as u8]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_intervals_are_exactly_the_pixels_that_reach_the_image_and_lie_inside_it() {
        let mut rand = crate::xorshift(0x2545_f491_4f6c_dd1d);
        let mut next = |m: i64| (rand() >> 11) as i64 % (2 * m + 1) - m;
        let one = 1i64 << FRAC;
        for round in 0..20_000 {
            let (iw, ih) = (1 + next(60).abs(), 1 + next(60).abs());
            let w = next(150).unsigned_abs() as usize;
            let (u, v) = (next(100 * one), next(100 * one));
            // Steps of all sizes and signs, zero and near-zero ones included.
            let step = |next: &mut dyn FnMut(i64) -> i64| match round % 4 {
                0 => 0,
                1 => next(3),
                _ => next(3 * one),
            };
            let (du, dv) = (step(&mut next), step(&mut next));
            let (xa, xb) = reach(u, du, v, dv, [-one, iw * one], [-one, ih * one], w);
            let box_in = [[0, (iw - 1) * one], [0, (ih - 1) * one]];
            let (xi, xj) = reach(u, du, v, dv, box_in[0], box_in[1], w);
            for x in 0..w {
                let (pu, pv) = (u + x as i64 * du, v + x as i64 * dv);
                let r = reaches(pu, pv, iw, ih);
                assert_eq!(r, x >= xa && x < xb, "round {round}: x {x} in {xa}..{xb}");
                // All four taps inside, as sample tests it.
                let (u0, v0) = (pu >> FRAC, pv >> FRAC);
                let all = u0 >= 0 && v0 >= 0 && u0 + 1 < iw && v0 + 1 < ih;
                assert_eq!(all, x >= xi && x < xj, "round {round}: x {x} in {xi}..{xj}");
            }
        }
    }

    /// The image of `view` warped from `px` in strips of `k` rows, each strip the warp's
    /// row buffer and its destination ([`InPlace`]).
    fn in_place(px: &[Rgba], view: &Factorization, k: usize) -> [[u8; 4]; 160 * 64] {
        let [w, h] = view.image;
        let mut frame = [[1u8; 4]; 160 * 64];
        for (i, strip) in frame[..w * h].chunks_mut(k * w).enumerate() {
            let rows = i * k..i * k + strip.len() / w;
            assert!(warp_rows(px, None, view, rows, strip, &mut InPlace).is_ok());
        }
        frame
    }

    /// Intermediate images holding a blob (an ellipse of random pixels, now and then a
    /// stray pixel outside it) in background, warped through random views one row at a
    /// time, in tiles of rows, skipping background by the extents, and in place in strips
    /// of the frame (in a perspective view of the same grid too): every output pixel is
    /// the same, and the extents bound exactly the pixels that are not zero.
    #[test]
    fn skipping_background_by_extents_changes_no_pixel() {
        use crate::classify::Grid;
        use crate::view::Camera;
        let mut rand = crate::xorshift(0x6a09_e667_f3bc_c909);
        let mut skipped = 0;
        for case in 0..60 {
            let mut next = |m: u64| (rand() >> 16) % m;
            let dims = [
                6 + next(11) as usize,
                6 + next(11) as usize,
                6 + next(11) as usize,
            ];
            let Ok(grid) = Grid::new(dims, [1.0, 1.0 + next(3) as f64 * 0.25, 1.0]) else {
                panic!("case {case}: grid {dims:?}");
            };
            let (w, h) = (8 + next(150) as usize, 8 + next(57) as usize);
            let cam = Camera {
                rotate_x: next(360) as f64 - 180.0 + 0.3,
                rotate_y: next(360) as f64 - 180.0 + 0.7,
                width: w,
                height: h,
            };
            let Ok(view) = Factorization::new(&grid, &cam) else {
                panic!("case {case}: view");
            };
            let [iw, ih] = view.intermediate;
            let mut px = [[0u16; 4]; 64 * 64];
            assert!(iw * ih <= px.len() && ih <= 64, "case {case}: {iw}x{ih}");
            let px = &mut px[..iw * ih];
            let (cx, cy) = (next(iw as u64) as i64, next(ih as u64) as i64);
            let (rx, ry) = (
                1 + next(iw as u64 / 2 + 1) as i64,
                1 + next(ih as u64 / 2 + 1) as i64,
            );
            for (i, p) in px.iter_mut().enumerate() {
                let (dx, dy) = (i as i64 % iw as i64 - cx, i as i64 / iw as i64 - cy);
                let stray = next(200) == 0;
                if dx * dx * ry * ry + dy * dy * rx * rx <= rx * rx * ry * ry || stray {
                    let r = next(u64::MAX);
                    *p = core::array::from_fn(|c| ((r >> (15 * c)) % (1 << 15)) as u16);
                }
            }
            let mut ext = [[9u32; 2]; 64];
            let ext = &mut ext[..ih];
            assert!(extents(px, iw, ext).is_ok());
            for (line, &[f, l]) in px.chunks_exact(iw).zip(ext.iter()) {
                let set: [bool; 64] = core::array::from_fn(|x| x < iw && pack(&line[x]) != 0);
                let first = set.iter().position(|&b| b);
                let last = set.iter().rposition(|&b| b);
                match (first, last) {
                    (Some(a), Some(b)) => assert_eq!([f, l], [a as u32, b as u32 + 1]),
                    _ => assert_eq!([f, l], [0, 0]),
                }
            }
            // One row at a time; with extents and whole tiles of rows; tiles of 3 rows.
            let mut frames = [[[0u8; 4]; 160 * 64]; 3];
            let mut row = [[0u8; 4]; 160 * TILE_ROWS];
            for (k, frame) in frames.iter_mut().enumerate() {
                let mut sink = FrameBuffer {
                    width: w,
                    pixels: &mut frame[..w * h],
                };
                let ext = (k == 1).then_some(&ext[..]);
                let row = &mut row[..w * [1, TILE_ROWS, 3][k]];
                assert!(warp_rows(px, ext, &view, 0..h, row, &mut sink).is_ok());
            }
            assert!(
                frames[0] == frames[1],
                "case {case}: the skipping warp differs"
            );
            assert!(
                frames[0] == frames[2],
                "case {case}: the tiled warp differs"
            );
            let flat = in_place(px, &view, 5);
            assert!(flat[..w * h] == frames[0][..w * h], "case {case}: in place");
            // The same in a perspective view of this grid (a projective warp).
            if let Ok(p) = Factorization::perspective(&grid, &cam, 40.0) {
                let [pw, ph] = p.intermediate;
                if pw * ph <= px.len() {
                    let px = &px[..pw * ph];
                    let mut frame = [[0u8; 4]; 160 * 64];
                    let mut sink = FrameBuffer {
                        width: w,
                        pixels: &mut frame[..w * h],
                    };
                    let mut row = [[0u8; 4]; 160];
                    assert!(warp_rows(px, None, &p, 0..h, &mut row[..w], &mut sink).is_ok());
                    let flat = in_place(px, &p, 3);
                    assert!(flat[..w * h] == frame[..w * h], "case {case}: perspective");
                }
            }
            // Count the runs the test exercises, as `warp_generic` finds them.
            let m = view.image_to_intermediate;
            for y in 0..h {
                let yc = y as f64 + 0.5;
                let u = to_fixed(m[0][0] * 0.5 + m[0][1] * yc + m[0][2]);
                let v = to_fixed(m[1][0] * 0.5 + m[1][1] * yc + m[1][2]);
                let (du, dv) = (to_fixed(m[0][0]), to_fixed(m[1][0]));
                let one = 1i64 << FRAC;
                let (bu, bv) = ([0, (iw as i64 - 1) * one], [0, (ih as i64 - 1) * one]);
                let (xi, xj) = reach(u, du, v, dv, bu, bv, w);
                for x in (xi..xj).step_by(SKIP_RUN) {
                    let e = (x + SKIP_RUN).min(xj) - 1;
                    let at = |x: usize| (u + x as i64 * du, v + x as i64 * dv);
                    skipped += background(ext, at(x), at(e)) as usize;
                }
            }
        }
        assert!(
            skipped > 100,
            "only {skipped} runs skipped: the test misses the path"
        );
    }

    #[test]
    fn two_lane_interior_equals_the_per_channel_sample() {
        let mut rand = crate::xorshift(0x853c_49e6_748f_ea9b);
        let mut next = |m: u32| {
            let seed = rand();
            match seed & 7 {
                0 => m,
                1 => 0,
                _ => ((seed >> 24) % (m as u64 + 1)) as u32,
            }
        };
        for round in 0..20_000 {
            // Channels up to ONE, and now and then past it (the clamped path).
            let max = if round % 16 == 0 { 0xFFFF } else { ONE };
            let mut px = || -> Rgba { core::array::from_fn(|_| next(max) as u16) };
            let top = [px(), px()];
            let bot = [px(), px()];
            let w = fixed::bilinear_weights(next(ONE), next(ONE));
            let want = interior(&top, &bot, w).map(fixed::to_u8);
            let taps = [pack(&top[0]), pack(&top[1]), pack(&bot[0]), pack(&bot[1])];
            assert_eq!(interior_u8(taps, w), want, "{top:?} {bot:?} {w:?}");
            assert_eq!(taps.map(unpack), [top[0], top[1], bot[0], bot[1]]);
        }
    }
}
