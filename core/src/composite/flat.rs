//! Flat voxels in a sample's colour: voxels with an exactly zero gradient (plateaus of
//! the data, [`crate::normal::ZERO_GRADIENT`]) have no direction to shade by, so they
//! are shaded as unoriented (ambient plus full diffuse light, the brightest shade there
//! is). Where a sample mixes them with voxels that have a direction, the sample takes
//! its colour from those alone, weighted as before, and keeps its opacity.
//!
//! Why: a ray caster that interpolates the gradient and normalises it per sample gives
//! a sample between a plateau and an edge the edge's direction whole, since the
//! plateau's zero gradient adds nothing to the sum. Shading per voxel and interpolating
//! the colours instead mixes the plateau's full light into it, which brightens the rims
//! of flat-shelled objects at grazing angles (the nested spheres' silhouette: 39.96 dB
//! against the reference ray caster this way, 40.46 dB with the rule,
//! [`super::FlatVoxels::Excluded`]). No per-voxel direction for the flat voxels
//! reproduces it: one taken from the neighbours darkens the face-on plateaus, which the
//! reference shades fully lit.
//!
//! A row keeps one bit per shaded voxel, set for flat ones, in words stored in the row
//! buffer's tail ([`super::row_buffer_len`]). Most samples mix no flat voxel; those that
//! may are found 64 pixels at a time from the two rows' bits and the slice's weights
//! ([`mixed`]), and only they are composited again, with [`recolour`]'s colour. The
//! compositing kernels themselves stay as they are.

use super::Rgba;
use crate::classify::Voxel;

/// Words of flat bits a row of `ni` voxels needs: one bit per buffer entry (`ni + 2`),
/// and one word more, so that 64 bits read from any entry's bit stay inside.
pub const fn words(ni: usize) -> usize {
    (ni + 2) / 64 + 2
}

/// A word of flat bits as it is stored in the row buffer: an [`Rgba`] entry is 64 bits.
#[inline(always)]
fn load(w: &Rgba) -> u64 {
    bytemuck::cast(*w)
}

/// Sets bit `at + i` of `words` for each flat voxel `src[i]` of the first `n`, found 64
/// at a time by `flat_bits` ([`super::Kernels::flat_bits`], which may read the voxels
/// after them); true if any was. Bits past the words are not set (the rows are sized
/// so there are none).
#[inline(always)]
pub(crate) fn mark(
    words: &mut [Rgba],
    at: usize,
    src: &[Voxel],
    n: usize,
    flat_bits: impl Fn(&[Voxel], usize) -> u64,
) -> bool {
    let n = n.min(src.len());
    let mut any = false;
    for c in 0..n.div_ceil(64) {
        let from = 64 * c;
        let m = flat_bits(src.get(from..).unwrap_or_default(), (n - from).min(64));
        if m != 0 {
            any = true;
            let pos = at + from;
            let (q, r) = (pos / 64, pos % 64);
            if let Some(w) = words.get_mut(q) {
                *w = bytemuck::cast(load(w) | m << r);
            }
            if r != 0 {
                if let Some(w) = words.get_mut(q + 1) {
                    *w = bytemuck::cast(load(w) | m >> (64 - r));
                }
            }
        }
    }
    any
}

/// Sets in `words` the bits `at..at + n` of `table` that are set (a row's words of a
/// table of flat voxels, laid out as `words`); true if any was.
#[inline(always)]
pub(crate) fn copy(words: &mut [Rgba], at: usize, table: &[Rgba], n: usize) -> bool {
    let end = at + n;
    let mut any = 0;
    for q in at / 64..end.div_ceil(64) {
        // The bits of word q inside at..end.
        let lo = if q == at / 64 {
            u64::MAX << (at % 64)
        } else {
            u64::MAX
        };
        let hi = match end - 64 * q {
            64.. => u64::MAX,
            e => (1u64 << e) - 1,
        };
        let (Some(w), Some(t)) = (words.get_mut(q), table.get(q)) else {
            break;
        };
        let bits = load(t) & lo & hi;
        *w = bytemuck::cast(load(w) | bits);
        any |= bits;
    }
    any != 0
}

/// Clears bit `pos` of `words` (if they hold it).
pub(crate) fn clear(words: &mut [Rgba], pos: usize) {
    if let Some(w) = words.get_mut(pos / 64) {
        *w = bytemuck::cast(load(w) & !(1u64 << (pos % 64)));
    }
}

/// Bit `pos` of `words`.
#[inline(always)]
pub(crate) fn bit(words: &[Rgba], pos: usize) -> bool {
    words.get(pos / 64).map_or(0, load) >> (pos % 64) & 1 != 0
}

/// The flat bits of the four taps of a pixel reading entries `bl` and `bl + 1` of rows
/// `top` and `bot`: bit 0 top-left, 1 top-right, 2 bottom-left, 3 bottom-right, the
/// order of the taps and their weights.
#[inline(always)]
pub(crate) fn taps(top: &[Rgba], bot: &[Rgba], bl: usize) -> u32 {
    bit(top, bl) as u32
        | (bit(top, bl + 1) as u32) << 1
        | (bit(bot, bl) as u32) << 2
        | (bit(bot, bl + 1) as u32) << 3
}

/// The flat bits of the 64 pixels reading entries `bl + i` and `bl + i + 1` of rows
/// `top` and `bot` (bits `i`): the four taps' words, top-left, top-right, bottom-left,
/// bottom-right.
#[inline(always)]
pub(crate) fn tap_words(top: &[Rgba], bot: &[Rgba], bl: usize) -> [u64; 4] {
    // The 65 bits from `bl` on of each row, as one 128-bit shift of two words: a left
    // and a right tap are the same bits one apart.
    let window = |words: &[Rgba]| {
        let (q, r) = (bl / 64, bl % 64);
        let lo = words.get(q).map_or(0, load) as u128;
        let hi = words.get(q + 1).map_or(0, load) as u128;
        (lo | hi << 64) >> r
    };
    let (t, b) = (window(top), window(bot));
    [t as u64, (t >> 1) as u64, b as u64, (b >> 1) as u64]
}

/// Of the `n <= 64` pixels whose taps have flat bits `f` ([`tap_words`]) and weights
/// `w`, those whose taps may mix flat and other voxels (bit `i`): of the taps with
/// weight, some are flat and not all. A superset of the pixels [`resample`] changes (it
/// also asks for opacity).
///
/// A tap without weight is left out because whole slices have them: a view turned
/// about the vertical axis alone shears the slices by whole rows, so every sample's
/// bottom taps weigh nothing. Counted in, they made every pixel between a flat row and
/// another a mixed one, resampled for nothing (spheres256, 36 views about the vertical
/// axis: 251 K pixels a frame, none changed, 3 ms of a 14.7 ms frame).
#[inline(always)]
pub(crate) fn mixed(f: &[u64; 4], w: [u32; 4], n: usize) -> u64 {
    // All ones for a tap with weight.
    let on = w.map(|x| ((x != 0) as u64).wrapping_neg());
    let any = (0..4).fold(0, |m, k| m | f[k] & on[k]);
    let all = (0..4).fold(u64::MAX, |m, k| m & (f[k] | !on[k]));
    let ones = if n >= 64 { u64::MAX } else { (1u64 << n) - 1 };
    any & !all & ones
}

/// Pixel `i`'s four flat bits from the taps' words ([`tap_words`]), as [`taps`] gives
/// them.
#[inline(always)]
pub(crate) fn pixel(f: &[u64; 4], i: usize) -> u32 {
    let b = |k: usize| (f[k] >> i & 1) as u32;
    b(0) | b(1) << 1 | b(2) << 2 | b(3) << 3
}

/// The bilinear sample of taps `t` with weights `w` (summing to one, Q15), each channel
/// rounded to Q15: the compositing kernels' sample.
#[inline(always)]
pub(crate) fn sample(t: &[Rgba; 4], w: [u32; 4]) -> [u32; 4] {
    core::array::from_fn(|c| {
        let sum = w[0] * t[0][c] as u32
            + w[1] * t[1][c] as u32
            + w[2] * t[2][c] as u32
            + w[3] * t[3][c] as u32;
        (sum + (1 << 14)) >> 15
    })
}

/// [`sample`], with the rule for flat voxels: when a tap with weight and opacity is flat
/// (bit `i` of `flat`) and another with weight and opacity is not, the colour is the
/// non-flat taps' weighted colour scaled to the sample's opacity, `Σ' wᵢcᵢ · α / Σ' wᵢαᵢ`
/// over the non-flat taps ([`recolour`]). Otherwise, and always for the opacity, it is
/// [`sample`].
#[inline(always)]
pub(crate) fn resample(t: &[Rgba; 4], w: [u32; 4], flat: u32) -> [u32; 4] {
    let mut s = sample(t, w);
    if let Some(c) = recolour(t, w, flat) {
        s[..3].copy_from_slice(&c);
    }
    s
}

/// The colour [`resample`] gives taps `t` with weights `w` and flat bits `flat` when the
/// rule applies, `None` when it does not (the sample is then [`sample`]'s): [`sums`],
/// then [`recolour_from`].
#[inline(always)]
pub(crate) fn recolour(t: &[Rgba; 4], w: [u32; 4], flat: u32) -> Option<[u32; 3]> {
    recolour_from(sums(t, w, flat))
}

/// The sums the rule takes of taps `t` with weights `w` and flat bits `flat`: each
/// channel's `Σ' wᵢcᵢ` over the taps that are not flat (red, green, blue, opacity), and
/// the opacity's `Σ wᵢαᵢ` over all of them. Exact for any 16-bit taps: the weights sum
/// to one (Q15), so every sum is below `2^31`. The compositor takes them from
/// [`super::Kernels::flat_sums`], which an instruction-set build may replace.
///
/// Taken two channels to a 64-bit word (red and blue, green and opacity, each in a
/// 32-bit field), without branches: written per channel, the compiler kept the channels
/// in scalar registers (spheres256, callgrind: 57 instructions a sample for the products
/// alone).
#[inline(always)]
pub(crate) fn sums(t: &[Rgba; 4], w: [u32; 4], flat: u32) -> ([u32; 4], u32) {
    const FIELDS: u64 = 0x0000_ffff_0000_ffff;
    let (mut kept, mut all) = ([0u64; 2], 0u64);
    for i in 0..4 {
        let v: u64 = bytemuck::cast(t[i]);
        // Each field's product, and its sum over the taps, is below 2^31: no field
        // carries into the next.
        let x = [(v & FIELDS) * w[i] as u64, (v >> 16 & FIELDS) * w[i] as u64];
        // All ones for a tap with a direction, zero for a flat one.
        let keep = (flat as u64 >> i & 1).wrapping_sub(1);
        kept[0] += x[0] & keep;
        kept[1] += x[1] & keep;
        all += x[1];
    }
    let lane = |c: usize| (kept[c & 1] >> (32 * (c >> 1))) as u32;
    ([lane(0), lane(1), lane(2), lane(3)], (all >> 32) as u32)
}

/// [`recolour`] from the rule's sums ([`sums`]): the non-flat taps' colour scaled to the
/// sample's opacity, `Σ' wᵢcᵢ · α / Σ' wᵢαᵢ`, or `None` when no tap with weight and
/// opacity is flat or none is not.
#[inline(always)]
pub(crate) fn recolour_from((kept, aa): ([u32; 4], u32)) -> Option<[u32; 3]> {
    let an = kept[3];
    if an == 0 || an == aa {
        return None;
    }
    // α / Σ' wᵢαᵢ in Q32 (α Q15, the sum Q30). Premultiplied colours are at most their
    // opacity, so Σ' wᵢcᵢ ≤ Σ' wᵢαᵢ (held to it for tables that break the rule) and each
    // product below is at most α·2^32 < 2^49.
    let alpha = ((aa + (1 << 14)) >> 15) as u64;
    let ratio = (alpha << 32) / an as u64;
    Some(core::array::from_fn(|c| {
        let kc = kept[c].min(an) as u64;
        ((kc * ratio + (1 << 31)) >> 32).min(alpha) as u32
    }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fixed::{bilinear_weights, ONE};
    use crate::normal::ZERO_GRADIENT;

    #[test]
    fn marked_bits_read_back_at_any_offset() {
        let mut rng = crate::xorshift(0xf1a7);
        for _ in 0..300 {
            let mut words = [[0u16; 4]; 6];
            let at = (rng() % 100) as usize;
            let n = (rng() % 150) as usize;
            let src: heapless::Vec<Voxel, 150> = (0..n)
                .map(|_| Voxel {
                    opacity: 1,
                    scalar: 0,
                    normal: if rng().is_multiple_of(3) {
                        ZERO_GRADIENT
                    } else {
                        (rng() % 8192) as u16
                    },
                })
                .collect();
            let any = mark(
                &mut words,
                at,
                &src,
                n,
                crate::composite::kernels::flat_bits,
            );
            assert_eq!(any, src.iter().any(|v| v.normal == ZERO_GRADIENT));
            for pos in 0..6 * 64 {
                let want = pos >= at && pos < at + n && src[pos - at].normal == ZERO_GRADIENT;
                assert_eq!(bit(&words, pos), want, "bit {pos}, at {at}, n {n}");
            }
            // Read back 64 at a time from any entry, as the taps' words, up to and past
            // the words' end (zero there).
            for pos in 0..6 * 64 {
                let window =
                    |from| (0..64).fold(0u64, |m, i| m | (bit(&words, from + i) as u64) << i);
                let f = tap_words(&words, &words, pos);
                assert_eq!(f[0], window(pos));
                assert_eq!(f[1], window(pos + 1));
            }
        }
    }

    #[test]
    fn copied_bits_are_the_tables_inside_the_range_only() {
        let mut rng = crate::xorshift(0xc0b1);
        for _ in 0..500 {
            let table: [Rgba; 5] = core::array::from_fn(|_| bytemuck::cast(rng()));
            let before: [Rgba; 5] = core::array::from_fn(|_| bytemuck::cast(rng() & rng()));
            let mut words = before;
            let at = (rng() % 200) as usize;
            let n = (rng() % 140) as usize;
            let any = copy(&mut words, at, &table, n);
            let mut copied = false;
            for pos in 0..5 * 64 {
                let inside = pos >= at && pos < at + n && bit(&table, pos);
                copied |= inside;
                assert_eq!(bit(&words, pos), bit(&before, pos) || inside, "bit {pos}");
            }
            assert_eq!(any, copied, "at {at}, n {n}");
        }
    }

    #[test]
    fn mixed_pixels_include_every_pixel_whose_taps_mix() {
        let mut rng = crate::xorshift(0x1111);
        for _ in 0..200 {
            let top: [Rgba; 4] = core::array::from_fn(|_| bytemuck::cast(rng() & rng()));
            let bot: [Rgba; 4] = core::array::from_fn(|_| bytemuck::cast(rng() & rng()));
            let bl = (rng() % 100) as usize;
            let n = 1 + (rng() % 64) as usize;
            // Weights with none zero, or with one or two zero (the bottom taps, as
            // views turned about the vertical axis alone have them, or the right ones).
            let w = match rng() % 4 {
                0 => bilinear_weights(ONE / 3, 0),
                1 => bilinear_weights(0, ONE / 5),
                2 => bilinear_weights(0, ONE),
                _ => bilinear_weights(ONE / 3, ONE / 5),
            };
            let weighed = w
                .iter()
                .enumerate()
                .fold(0, |m, (k, &x)| m | ((x != 0) as u32) << k);
            let f = tap_words(&top, &bot, bl);
            let m = mixed(&f, w, n);
            for i in 0..64 {
                let t = taps(&top, &bot, bl + i);
                assert_eq!(pixel(&f, i), t, "pixel {i}");
                // Of the taps with weight, some flat and not all.
                let flat = t & weighed;
                let want = i < n && flat != 0 && flat != weighed;
                assert_eq!(m >> i & 1 != 0, want, "pixel {i}, weights {w:?}");
            }
        }
    }

    #[test]
    fn a_flat_tap_gives_no_colour_but_keeps_its_opacity() {
        // A bright flat voxel (fully lit, as flat voxels are) beside a darker one with a
        // direction: the sample's colour is the darker one's, at the sample's opacity.
        let half = ONE as u16 / 2;
        let bright: Rgba = [half, half, half, half];
        let dark: Rgba = [half / 5, half / 4, half / 3, half];
        let w = bilinear_weights(ONE / 2, ONE);
        let t = [bright, dark, [0; 4], [0; 4]];
        let plain = sample(&t, w);
        let s = resample(&t, w, 0b0001);
        assert_eq!(s[3], plain[3]);
        for c in 0..3 {
            assert!(s[c].abs_diff(dark[c] as u32) <= 1, "{c}: {s:?} {dark:?}");
        }
        assert!(plain[0] > s[0] + 5000);
        // Flat everywhere, or nowhere, or only where the weight is zero: the plain sample.
        assert_eq!(resample(&t, w, 0b0011), plain);
        assert_eq!(resample(&t, w, 0), plain);
        let w_left = bilinear_weights(ONE, ONE);
        assert_eq!(resample(&t, w_left, 0b0010), sample(&t, w_left));
        // Flat beside transparent voxels only: nothing to take a colour from.
        assert_eq!(
            resample(&[bright, [0; 4], [0; 4], [0; 4]], w, 1),
            sample(&[bright, [0; 4], [0; 4], [0; 4]], w)
        );
    }

    /// The rule as it is defined, tap by tap in 64-bit arithmetic.
    fn resample_by_definition(t: &[Rgba; 4], w: [u32; 4], flat: u32) -> [u32; 4] {
        let mut s = sample(t, w);
        let (mut an, mut flat_wa, mut cn) = (0u64, 0u64, [0u64; 3]);
        for i in 0..4 {
            let wa = w[i] as u64 * t[i][3] as u64;
            if flat >> i & 1 != 0 {
                flat_wa += wa;
            } else {
                an += wa;
                for c in 0..3 {
                    cn[c] += w[i] as u64 * t[i][c] as u64;
                }
            }
        }
        if an > 0 && flat_wa > 0 {
            let alpha = s[3] as u64;
            for c in 0..3 {
                // Σ' wᵢcᵢ · α / Σ' wᵢαᵢ, rounded, at most α.
                let exact = (cn[c] as u128 * alpha as u128 * 2 + an as u128) / (2 * an as u128);
                s[c] = (exact as u64).min(alpha) as u32;
            }
        }
        s
    }

    #[test]
    fn the_rule_is_its_definition_within_a_unit() {
        let mut rng = crate::xorshift(0xdef1);
        for _ in 0..50_000 {
            let t: [Rgba; 4] = core::array::from_fn(|_| {
                let a = match rng() % 4 {
                    0 => 0,
                    1 => ONE as u16,
                    _ => (rng() % (ONE as u64 + 1)) as u16,
                };
                let c = |r: u64| (r % (a as u64 + 1)) as u16;
                [c(rng()), c(rng()), c(rng()), a]
            });
            let w = bilinear_weights(
                (rng() % (ONE as u64 + 1)) as u32,
                (rng() % (ONE as u64 + 1)) as u32,
            );
            let flat = (rng() % 16) as u32;
            let got = resample(&t, w, flat);
            let want = resample_by_definition(&t, w, flat);
            assert_eq!(got[3], want[3]);
            for c in 0..3 {
                assert!(
                    got[c].abs_diff(want[c]) <= 1,
                    "{t:?} {w:?} {flat}: {got:?} {want:?}"
                );
            }
        }
    }

    #[test]
    fn the_colour_never_exceeds_the_opacity() {
        let mut rng = crate::xorshift(0xc01);
        for _ in 0..20_000 {
            let t: [Rgba; 4] = core::array::from_fn(|_| {
                let a = (rng() % (ONE as u64 + 1)) as u16;
                let c = |r: u64| (r % (a as u64 + 1)) as u16;
                [c(rng()), c(rng()), c(rng()), a]
            });
            let w = bilinear_weights(
                (rng() % (ONE as u64 + 1)) as u32,
                (rng() % (ONE as u64 + 1)) as u32,
            );
            let s = resample(&t, w, (rng() % 16) as u32);
            assert!(s[..3].iter().all(|&c| c <= s[3]), "{t:?} {w:?} {s:?}");
            assert_eq!(s[3], sample(&t, w)[3]);
        }
    }
}
