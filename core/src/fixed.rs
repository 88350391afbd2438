//! Q15 fixed-point helpers.
//!
//! Colours, opacities and interpolation weights are unsigned Q15: `ONE = 1 << 15` stands
//! for 1.0. The value fits a `u16` for storage while products of two Q15 numbers fit a
//! `u32`, which keeps every inner loop in 32-bit integer arithmetic (Cortex-M3 has a
//! single-cycle 32×32 multiply and no FPU).

/// Number of fractional bits.
pub const SHIFT: u32 = 15;
/// 1.0 in Q15.
pub const ONE: u32 = 1 << SHIFT;
const HALF: u32 = 1 << (SHIFT - 1);

/// Product of two Q15 numbers, rounded to nearest (ties up).
#[inline(always)]
pub const fn mul(a: u32, b: u32) -> u32 {
    (a * b + HALF) >> SHIFT
}

/// Converts a float in `[0, 1]` (clamped) to Q15, rounding to nearest.
pub fn from_f64(x: f64) -> u32 {
    let c = if x.is_nan() { 0.0 } else { x.clamp(0.0, 1.0) };
    (c * ONE as f64 + 0.5) as u32
}

/// Converts Q15 in `[0, ONE]` to an 8-bit channel, rounding to nearest.
#[inline(always)]
pub const fn to_u8(x: u32) -> u8 {
    let x = if x > ONE { ONE } else { x };
    ((x * 255 + HALF) >> SHIFT) as u8
}

/// Converts an 8-bit value to Q15 exactly scaled (255 ↦ ONE).
#[inline(always)]
pub const fn from_u8(x: u8) -> u32 {
    (x as u32 * ONE + 127) / 255
}

/// Splits a bilinear weight pair `(fu, fv)` (each Q15 in `[0, ONE]`) into four weights
/// that are non-negative and sum to exactly `ONE`, so a constant field interpolates to
/// itself without drift.
///
/// Returns `[w_top_left, w_top_right, w_bottom_left, w_bottom_right]` where `fv` weighs the
/// top row and `fu` the left column.
#[inline(always)]
pub const fn bilinear_weights(fu: u32, fv: u32) -> [u32; 4] {
    let top = fv;
    let bottom = ONE - fv;
    let tl = (top * fu) >> SHIFT;
    let bl = (bottom * fu) >> SHIFT;
    [tl, top - tl, bl, bottom - bl]
}

/// Integer square root (floor) of a `u64`, for gradient magnitudes: the standard
/// library's, which has no division that could fail (the Newton iteration this was
/// divided by its estimate, which the compiler could not prove non-zero).
pub const fn isqrt(n: u64) -> u64 {
    n.isqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mul_matches_rounded_real_product_on_a_grid() {
        for a in (0..=ONE).step_by(7) {
            for b in (0..=ONE).step_by(131) {
                let exact = a as f64 * b as f64 / ONE as f64;
                let got = mul(a, b) as f64;
                assert!((got - exact).abs() <= 0.5, "{a}*{b}: {got} vs {exact}");
            }
        }
        assert_eq!(mul(ONE, ONE), ONE);
        assert_eq!(mul(ONE, 12345), 12345);
    }

    #[test]
    fn u8_round_trip_is_exact_for_every_byte() {
        for v in 0..=255u8 {
            assert_eq!(to_u8(from_u8(v)), v);
        }
        assert_eq!(from_u8(255), ONE);
        assert_eq!(from_u8(0), 0);
    }

    #[test]
    fn bilinear_weights_are_exhaustively_nonnegative_and_sum_to_one() {
        // Exhaustive over a 9-bit grid of both weights (the composite loop uses these).
        for fu in (0..=ONE).step_by(64) {
            for fv in (0..=ONE).step_by(64) {
                let w = bilinear_weights(fu, fv);
                assert_eq!(w.iter().sum::<u32>(), ONE);
                let exact_tl = fu as f64 * fv as f64 / ONE as f64;
                assert!((w[0] as f64 - exact_tl).abs() < 1.0);
            }
        }
    }

    #[test]
    fn isqrt_is_floor_sqrt() {
        for n in 0..100_000u64 {
            let r = isqrt(n);
            assert!(r * r <= n && (r + 1) * (r + 1) > n, "{n}");
        }
        let big = u64::MAX;
        let r = isqrt(big);
        assert!(r as u128 * r as u128 <= big as u128);
        assert!((r as u128 + 1) * (r as u128 + 1) > big as u128);
    }

    #[test]
    fn from_f64_clamps_and_rounds() {
        assert_eq!(from_f64(-1.0), 0);
        assert_eq!(from_f64(2.0), ONE);
        assert_eq!(from_f64(f64::NAN), 0);
        assert_eq!(from_f64(0.5), ONE / 2);
    }
}
