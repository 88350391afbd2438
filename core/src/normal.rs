//! Quantised surface normals.
//!
//! A normal is stored as a 13-bit code (Lacroute quantises to 13 bits as well; the grid
//! here is an octahedral one, which spreads codes more evenly over the sphere). The
//! gradient is projected onto the octahedron |x|+|y|+|z| = 1; its upper-hemisphere footprint,
//! rotated by 45°, fills the square [−1, 1]², which is cut into a 64×64 grid; one more bit
//! records the sign of z. Code [`ZERO_GRADIENT`] marks a vanishing gradient (homogeneous
//! regions), which shading treats as ambient plus unoriented diffuse light.
//!
//! Encoding is pure integer arithmetic (it runs per voxel); decoding runs once per code
//! per frame when the shading table is built.

use core::num::{NonZeroU32, NonZeroU64};

/// Number of grid cells per side of the rotated octahedral square.
pub const GRID: i64 = 64;
/// Number of codes for non-zero gradients.
pub const DIRECTIONS: usize = (2 * GRID * GRID) as usize;
/// Code for a zero gradient.
pub const ZERO_GRADIENT: u16 = DIRECTIONS as u16;
/// Size of tables indexed by normal code.
pub const CODES: usize = DIRECTIONS + 1;

/// Encodes an integer gradient (any common scale) into a normal code.
#[inline]
pub fn encode(gx: i64, gy: i64, gz: i64) -> u16 {
    // Only the direction counts: a gradient of 2^40 or more is scaled below it, so that
    // nothing below can overflow (the classifier's gradients are far smaller).
    let big = gx.unsigned_abs() | gy.unsigned_abs() | gz.unsigned_abs();
    let shift = (u64::BITS - big.leading_zeros()).saturating_sub(40);
    let (gx, gy, gz) = (gx >> shift, gy >> shift, gz >> shift);
    let l1 = gx.abs() + gy.abs() + gz.abs();
    let Some(d) = NonZeroU64::new(l1 as u64) else {
        return ZERO_GRADIENT;
    };
    let half = GRID / 2;
    // a = (gx - gy)/l1 and b = (gx + gy)/l1 are in [-1, 1]; map to cells 0..GRID-1. The
    // numerators are in [0, 2·half·l1], so the quotient is a plain unsigned division,
    // done in 32 bits when it fits (the same result, much cheaper than 64-bit). Divisors
    // typed non-zero divide without a check.
    let (na, nb) = (half * (gx - gy + l1), half * (gx + gy + l1));
    let d32 = NonZeroU32::new(l1 as u32).filter(|_| l1 < 1 << 25);
    let (a, b) = match d32 {
        Some(d) => ((na as u32 / d) as i64, (nb as u32 / d) as i64),
        None => ((na as u64 / d) as i64, (nb as u64 / d) as i64),
    };
    let (a, b) = (a.clamp(0, GRID - 1), b.clamp(0, GRID - 1));
    let neg = (gz < 0) as i64;
    ((neg * GRID + b) * GRID + a) as u16
}

/// Decodes a code into a unit vector (the cell centre's direction). `None` for
/// [`ZERO_GRADIENT`] or out-of-range codes.
pub fn decode(code: u16) -> Option<[f64; 3]> {
    if code as usize >= DIRECTIONS {
        return None;
    }
    let c = code as i64;
    let a_i = c % GRID;
    let b_i = (c / GRID) % GRID;
    let neg = c / (GRID * GRID) == 1;
    let half = (GRID / 2) as f64;
    let a = (a_i as f64 + 0.5) / half - 1.0;
    let b = (b_i as f64 + 0.5) / half - 1.0;
    let px = (a + b) * 0.5;
    let py = (b - a) * 0.5;
    let pz0 = (1.0 - libm::fabs(px) - libm::fabs(py)).max(0.0);
    let pz = if neg { -pz0 } else { pz0 };
    let len = libm::sqrt(px * px + py * py + pz * pz);
    Some([px / len, py / len, pz / len])
}

/// The code of the direction opposite `code`'s: `DIRECTIONS − 1 − code` (the other
/// hemisphere, both grid indices mirrored). [`UNIT`] holds exactly the negated vector
/// there, which lets a shading table, two-sided, fill one half and mirror it.
pub const fn antipode(code: u16) -> u16 {
    (DIRECTIONS - 1 - code as usize) as u16
}

/// Unit vector of every direction code in Q14 (`i16`, 16384 = 1.0), computed at compile
/// time with integer arithmetic so that shading tables need no floating point per code.
pub static UNIT: [[i16; 3]; DIRECTIONS] = unit_table();

/// `v·2^28 / len`, rounded half away from zero.
const fn div_round(v: i64, len: i64) -> i16 {
    let num = v << 28;
    let r = if num >= 0 {
        (num + len / 2) / len
    } else {
        (num - len / 2) / len
    };
    r as i16
}

const fn unit_table() -> [[i16; 3]; DIRECTIONS] {
    let mut t = [[0i16; 3]; DIRECTIONS];
    let mut code = 0;
    while code < DIRECTIONS {
        let c = code as i64;
        let a_i = c % GRID;
        let b_i = (c / GRID) % GRID;
        let neg = c / (GRID * GRID) == 1;
        // Cell centre in units of 1/(2·GRID): a = (2·a_i + 1 − GRID)/GRID.
        let a2 = 2 * a_i + 1 - GRID;
        let b2 = 2 * b_i + 1 - GRID;
        // p = ((a + b)/2, (b − a)/2, ±(1 − |px| − |py|)), scaled by 2·GRID.
        let px = a2 + b2;
        let py = b2 - a2;
        let mut pz = 2 * GRID - px.abs() - py.abs();
        if pz < 0 {
            pz = 0;
        }
        if neg {
            pz = -pz;
        }
        let len2 = (px * px + py * py + pz * pz) as u64;
        // |p|·2^14, so n = p·2^28 / (|p|·2^14) = p/|p| in Q14.
        let len = crate::fixed::isqrt(len2 << 28) as i64;
        t[code] = [div_round(px, len), div_round(py, len), div_round(pz, len)];
        code += 1;
    }
    t
}

#[cfg(test)]
mod tests {
    use super::*;

    fn angle_deg(a: [f64; 3], b: [f64; 3]) -> f64 {
        let d = (a[0] * b[0] + a[1] * b[1] + a[2] * b[2]).clamp(-1.0, 1.0);
        libm::acos(d).to_degrees()
    }

    /// The shading table's mirrored fill relies on this, bit for bit.
    #[test]
    fn opposite_codes_hold_exactly_negated_units() {
        for code in 0..DIRECTIONS as u16 {
            let (n, m) = (UNIT[code as usize], UNIT[antipode(code) as usize]);
            assert_eq!(m, n.map(|c| -c), "code {code}");
            assert_eq!(
                encode(
                    -1000 * n[0] as i64,
                    -1000 * n[1] as i64,
                    -1000 * n[2] as i64
                ),
                antipode(code)
            );
        }
    }

    /// Any i64 gradient encodes (no overflow, no division by zero, also with overflow
    /// checks on), and a huge one as the same direction scaled down.
    #[test]
    fn extreme_gradients_encode_as_their_direction() {
        let (min, max) = (i64::MIN, i64::MAX);
        assert_eq!(encode(min, 0, 0), encode(-1, 0, 0));
        assert_eq!(encode(0, max, 0), encode(0, 1, 0));
        assert_eq!(encode(max, max, min), encode(1, 1, -1));
        assert_eq!(encode(min, min, min), encode(-1, -1, -1));
        assert_eq!(encode(1 << 41, -(1 << 41), 1 << 40), encode(4, -4, 2));
        for g in [[min, max, 0], [max, 1, -1], [1 << 45, 3, min / 7]] {
            assert!((encode(g[0], g[1], g[2]) as usize) < DIRECTIONS, "{g:?}");
        }
    }

    #[test]
    fn round_trip_error_is_small_over_a_dense_set_of_directions() {
        let mut worst: f64 = 0.0;
        for gx in -20i64..=20 {
            for gy in -20i64..=20 {
                for gz in -20i64..=20 {
                    if gx == 0 && gy == 0 && gz == 0 {
                        continue;
                    }
                    let code = encode(gx, gy, gz);
                    let n = decode(code).unwrap();
                    let l = ((gx * gx + gy * gy + gz * gz) as f64).sqrt();
                    let g = [gx as f64 / l, gy as f64 / l, gz as f64 / l];
                    worst = worst.max(angle_deg(n, g));
                }
            }
        }
        // 8192 directions: mean spacing ~2.2°, worst cell half-diagonal a little more.
        assert!(worst < 3.5, "worst angular error {worst}°");
    }

    #[test]
    fn every_code_decodes_to_a_unit_vector_that_encodes_back_to_itself() {
        for code in 0..DIRECTIONS as u16 {
            let n = decode(code).unwrap();
            let s = 1u64 << 30;
            let g = n.map(|c| (c * s as f64) as i64);
            assert_eq!(encode(g[0], g[1], g[2]), code, "code {code} -> {n:?}");
        }
        assert_eq!(decode(ZERO_GRADIENT), None);
        assert_eq!(encode(0, 0, 0), ZERO_GRADIENT);
    }

    #[test]
    fn integer_unit_table_matches_float_decode() {
        for code in 0..DIRECTIONS as u16 {
            let f = decode(code).unwrap();
            let q = UNIT[code as usize];
            for c in 0..3 {
                assert!(
                    (q[c] as f64 / 16384.0 - f[c]).abs() < 1.0 / 16384.0,
                    "{code}"
                );
            }
        }
    }

    #[test]
    fn narrow_division_matches_the_wide_one() {
        let wide = |gx: i64, gy: i64, gz: i64| -> u16 {
            let l1 = gx.abs() + gy.abs() + gz.abs();
            if l1 == 0 {
                return ZERO_GRADIENT;
            }
            let half = GRID / 2;
            let a = ((half * (gx - gy + l1)).div_euclid(l1)).clamp(0, GRID - 1);
            let b = ((half * (gx + gy + l1)).div_euclid(l1)).clamp(0, GRID - 1);
            (((gz < 0) as i64 * GRID + b) * GRID + a) as u16
        };
        let mut s = 0x1234_5678_9abc_def0u64;
        for i in 0..200_000 {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            // Magnitudes around the 2^25 switch and far beyond it.
            let bits = 8 + (i % 30) as u32;
            let g = |k: u32| ((s >> (k * 20)) as i64 & ((1 << bits) - 1)) - (1 << (bits - 1));
            let (gx, gy, gz) = (g(0), g(1), g(2) / 3);
            assert_eq!(encode(gx, gy, gz), wide(gx, gy, gz), "{gx} {gy} {gz}");
        }
    }

    #[test]
    fn extreme_gradients_do_not_overflow() {
        let m = 1i64 << 40;
        for g in [[m, 0, 0], [-m, m, -m], [0, 0, -m]] {
            assert!(encode(g[0], g[1], g[2]) < ZERO_GRADIENT);
        }
    }
}
