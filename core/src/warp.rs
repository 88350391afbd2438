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

/// Warps the intermediate image `px` (the full `view.intermediate` size, row-major) into
/// the final image, one row at a time through `sink`. `row` must hold at least the image
/// width.
pub fn warp(
    px: &[Rgba],
    view: &Factorization,
    row: &mut [[u8; 4]],
    sink: &mut impl PixelSink,
) -> Result<(), Error> {
    warp_rows(px, view, 0..view.image[1], row, sink)
}

/// Warps output rows `rows` only (threads can split the final image between them; each
/// row is computed independently, so the result does not depend on the split).
pub fn warp_rows(
    px: &[Rgba],
    view: &Factorization,
    rows: core::ops::Range<usize>,
    row: &mut [[u8; 4]],
    sink: &mut impl PixelSink,
) -> Result<(), Error> {
    warp_generic(
        px,
        view,
        rows,
        row,
        |q| q.map(fixed::to_u8),
        |y, r| sink.put_row(y, r),
    )
}

/// As [`warp_rows`], handing out rows at the intermediate image's full precision:
/// premultiplied RGBA in Q15 (`0..=32768` is 0..1), for 16-bit output.
pub fn warp_rows_q15(
    px: &[Rgba],
    view: &Factorization,
    rows: core::ops::Range<usize>,
    row: &mut [[u16; 4]],
    mut put_row: impl FnMut(usize, &[[u16; 4]]) -> Result<(), Error>,
) -> Result<(), Error> {
    warp_generic(
        px,
        view,
        rows,
        row,
        |q| q.map(|c| c.min(ONE) as u16),
        |y, r| put_row(y, r),
    )
}

/// The warp loop, generic over the output pixel: `convert` turns a Q15 sample into it.
fn warp_generic<T: Copy>(
    px: &[Rgba],
    view: &Factorization,
    rows: core::ops::Range<usize>,
    row: &mut [T],
    convert: impl Fn([u32; 4]) -> T,
    mut put_row: impl FnMut(usize, &[T]) -> Result<(), Error>,
) -> Result<(), Error> {
    let zero = convert([0; 4]);
    let [w, h] = view.image;
    need("warp row", w, row.len())?;
    let [iwu, ihu] = view.intermediate;
    need("intermediate pixels", iwu * ihu, px.len())?;
    let row = &mut row[..w];
    let m = view.image_to_intermediate;
    let (iw, ih) = (iwu as i64, ihu as i64);
    let projective = m[2] != [0.0, 0.0, 1.0];
    let du = to_fixed(m[0][0]);
    let dv = to_fixed(m[1][0]);
    // Projective: numerators and denominator in Q24, stepped exactly along the row.
    let q = |x: f64| libm::round(x.clamp(-1.0e9, 1.0e9) * (1u64 << PFRAC) as f64) as i64;
    let step = [q(m[0][0]), q(m[1][0]), q(m[2][0])];
    for y in rows.start..rows.end.min(h) {
        let yc = y as f64 + 0.5;
        if projective {
            let at = |r: usize| q(m[r][0] * 0.5 + m[r][1] * yc + m[r][2]);
            let mut num = [at(0), at(1), at(2)];
            for out in row.iter_mut() {
                *out = match project(num) {
                    Some((u, v)) => convert(sample(px, iw, ih, u, v)),
                    None => zero,
                };
                for (n, s) in num.iter_mut().zip(step) {
                    *n = n.saturating_add(s);
                }
            }
        } else {
            let mut u = to_fixed(m[0][0] * 0.5 + m[0][1] * yc + m[0][2]);
            let mut v = to_fixed(m[1][0] * 0.5 + m[1][1] * yc + m[1][2]);
            for out in row.iter_mut() {
                *out = convert(sample(px, iw, ih, u, v));
                u += du;
                v += dv;
            }
        }
        put_row(y, row)?;
    }
    Ok(())
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

/// Bilinear reconstruction of the intermediate image at 16.16 `(u, v)`, Q15 per channel;
/// zero outside.
#[inline(always)]
fn sample(px: &[Rgba], iw: i64, ih: i64, u: i64, v: i64) -> [u32; 4] {
    let one = 1i64 << FRAC;
    let u0 = u >> FRAC;
    let v0 = v >> FRAC;
    if u0 < -1 || v0 < -1 || u0 >= iw || v0 >= ih {
        return [0; 4];
    }
    let fu = ((one - (u & (one - 1))) >> 1) as u32;
    let fv = ((one - (v & (one - 1))) >> 1) as u32;
    let wts = fixed::bilinear_weights(fu, fv);
    let mut acc = [0u32; 4];
    // Inside: all four taps exist; two 2-pixel reads, no per-tap checks.
    if u0 >= 0 && v0 >= 0 && u0 + 1 < iw && v0 + 1 < ih {
        let base = (v0 * iw + u0) as usize;
        let w = iw as usize;
        if let (Some(top), Some(bot)) = (px.get(base..base + 2), px.get(base + w..base + w + 2)) {
            // Empty background (most of a frame around a small volume) needs no weights.
            let any = |p: &Rgba| p.iter().fold(0, |a, &c| a | c);
            if any(&top[0]) | any(&top[1]) | any(&bot[0]) | any(&bot[1]) == 0 {
                return [0; 4];
            }
            for c in 0..4 {
                acc[c] = wts[0] * top[0][c] as u32
                    + wts[1] * top[1][c] as u32
                    + wts[2] * bot[0][c] as u32
                    + wts[3] * bot[1][c] as u32;
            }
            return [
                (acc[0] + (1 << 14)) >> 15,
                (acc[1] + (1 << 14)) >> 15,
                (acc[2] + (1 << 14)) >> 15,
                (acc[3] + (1 << 14)) >> 15,
            ];
        }
    }
    let taps = [(u0, v0), (u0 + 1, v0), (u0, v0 + 1), (u0 + 1, v0 + 1)];
    for (&(tu, tv), &wt) in taps.iter().zip(wts.iter()) {
        if wt != 0 && tu >= 0 && tv >= 0 && tu < iw && tv < ih {
            let p = px[(tv * iw + tu) as usize];
            for c in 0..4 {
                acc[c] += wt * p[c] as u32;
            }
        }
    }
    acc.map(|a| (a + (1 << 14)) >> 15)
}
