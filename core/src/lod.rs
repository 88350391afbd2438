//! Levels of detail: a pyramid of ever coarser copies of the volume, each half the
//! resolution of the one below (after Ryan's progressive octree rendering), from which a
//! complete image of the same view can be drawn quickly and then refined.
//!
//! Every level voxel stores the mean, the minimum and the maximum of the voxels it stands
//! for. Levels are *centred*: along an axis of even length level voxel `I` stands for
//! voxels `2I, 2I + 1` (a box), along an odd length for `2I − 1, 2I, 2I + 1` with weights
//! ¼, ½, ¼ (a tent, clamped at the ends). Either way its centre falls exactly where the
//! contract's centred coordinates put it, so a level renders in the same place as the
//! full volume, and its [`Grid::as_level_of`] keeps the full volume's opacity unit and
//! framing, so it renders equally bright: a coarser level takes fewer, longer steps and
//! opacity correction lengthens each one's opacity accordingly.
//!
//! The caller owns every buffer; [`level_dims`] gives their size.

use crate::classify::Grid;
use crate::error::{need, Error};

/// Voxel types a pyramid can hold.
pub trait Sample: Copy {
    /// The value, widened.
    fn widen(self) -> u32;
    /// Narrows a value known to fit.
    fn narrow(v: u32) -> Self;
}

impl Sample for u8 {
    fn widen(self) -> u32 {
        self as u32
    }
    fn narrow(v: u32) -> Self {
        v.min(u8::MAX as u32) as u8
    }
}

impl Sample for u16 {
    fn widen(self) -> u32 {
        self as u32
    }
    fn narrow(v: u32) -> Self {
        v.min(u16::MAX as u32) as u16
    }
}

/// Dimensions of the level above a `dims` volume: `⌈n/2⌉` per axis.
pub const fn level_dims(dims: [usize; 3]) -> [usize; 3] {
    [
        dims[0].div_ceil(2),
        dims[1].div_ceil(2),
        dims[2].div_ceil(2),
    ]
}

/// Taps of level voxel `l` along an axis of `n` voxels: up to three `(index, weight)`,
/// weights summing to 4.
fn taps(l: usize, n: usize) -> [(usize, u32); 3] {
    if n == 1 {
        [(0, 4), (0, 0), (0, 0)]
    } else if n.is_multiple_of(2) {
        [(2 * l, 2), (2 * l + 1, 2), (0, 0)]
    } else {
        let c = 2 * l;
        [(c.saturating_sub(1), 1), (c, 2), ((c + 1).min(n - 1), 1)]
    }
}

/// Builds the level above `src` (a `grid.dims` volume, x fastest) into `mean`, `min`
/// and `max` (each [`level_dims`] voxels); returns the level's grid.
pub fn downsample<T: Sample>(
    src: &[T],
    grid: &Grid,
    mean: &mut [T],
    min: &mut [T],
    max: &mut [T],
) -> Result<Grid, Error> {
    let n = grid.dims;
    let m = level_dims(n);
    need("level source", grid.voxel_count(), src.len())?;
    let count = m[0] * m[1] * m[2];
    need("level mean", count, mean.len())?;
    need("level min", count, min.len())?;
    need("level max", count, max.len())?;
    let spacing = [0, 1, 2].map(|a| grid.spacing[a] * if n[a] == 1 { 1.0 } else { 2.0 });
    let level = Grid::new(m, spacing)?.as_level_of(grid);
    // The level's voxels in order, each with its three outputs (`need` checked that
    // each holds `count`).
    let mut outs = mean.iter_mut().zip(min.iter_mut()).zip(max.iter_mut());
    for z in 0..m[2] {
        let tz = taps(z, n[2]);
        for y in 0..m[1] {
            let ty = taps(y, n[1]);
            for x in 0..m[0] {
                let tx = taps(x, n[0]);
                let mut sum = 0u64;
                let mut lo = u32::MAX;
                let mut hi = 0u32;
                for &(k, wz) in tz.iter().filter(|t| t.1 > 0) {
                    for &(j, wy) in ty.iter().filter(|t| t.1 > 0) {
                        // Taps lie inside the volume (`taps` clamps them to each side).
                        let row = src.get((k * n[1] + j) * n[0]..).unwrap_or_default();
                        for &(i, wx) in tx.iter().filter(|t| t.1 > 0) {
                            let v = row.get(i).map_or(0, |v| v.widen());
                            sum += (wz * wy * wx) as u64 * v as u64;
                            lo = lo.min(v);
                            hi = hi.max(v);
                        }
                    }
                }
                let Some(((mean, min), max)) = outs.next() else {
                    return Ok(level);
                };
                *mean = T::narrow(((sum + 32) / 64) as u32);
                *min = T::narrow(lo);
                *max = T::narrow(hi);
            }
        }
    }
    Ok(level)
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use std::vec;

    #[test]
    fn taps_are_centred_and_sum_to_four() {
        for n in 1usize..9 {
            for l in 0..n.div_ceil(2) {
                let t = taps(l, n);
                assert_eq!(t.iter().map(|t| t.1).sum::<u32>(), 4);
                assert!(t.iter().all(|t| t.0 < n));
                if n > 1 {
                    // Weighted centre: 2l + ½ (even n) or 2l (odd n), away from clamping.
                    let c: f64 = t.iter().map(|&(i, w)| i as f64 * w as f64).sum::<f64>() / 4.0;
                    let want = if n.is_multiple_of(2) {
                        2.0 * l as f64 + 0.5
                    } else {
                        2.0 * l as f64
                    };
                    if l > 0 && 2 * l + 1 < n {
                        assert!((c - want).abs() < 1e-12, "n {n} l {l}");
                    }
                }
            }
        }
    }

    #[test]
    fn levels_keep_mean_range_and_the_full_volume_framing() {
        let dims = [5, 4, 3];
        let g = Grid::new(dims, [1.0, 2.0, 0.5]).unwrap();
        let src: std::vec::Vec<u8> = (0..60).map(|i| (i * 37 % 251) as u8).collect();
        let m = level_dims(dims);
        assert_eq!(m, [3, 2, 2]);
        let (mut mean, mut lo, mut hi) = (vec![0u8; 12], vec![0u8; 12], vec![0u8; 12]);
        let l = downsample(&src, &g, &mut mean, &mut lo, &mut hi).unwrap();
        assert_eq!(l.spacing, [2.0, 4.0, 1.0]);
        assert_eq!(l.opacity_unit(), 0.5);
        assert_eq!(l.frame_diagonal(), g.frame_diagonal());
        for i in 0..12 {
            assert!(lo[i] <= mean[i] && mean[i] <= hi[i], "{i}");
        }
        // A constant volume stays constant.
        let c = vec![77u8; 60];
        downsample(&c, &g, &mut mean, &mut lo, &mut hi).unwrap();
        assert!(mean.iter().chain(&lo).chain(&hi).all(|&v| v == 77));
        // Short buffers are errors.
        assert!(downsample(&src, &g, &mut mean[..11], &mut lo, &mut hi).is_err());
        // Level of a level keeps the original unit and framing.
        let mut m2 = [0u8; 4];
        let (mut a, mut b) = ([0u8; 4], [0u8; 4]);
        let l2 = downsample(&mean, &l, &mut m2, &mut a, &mut b).unwrap();
        assert_eq!(l2.opacity_unit(), 0.5);
        assert_eq!(l2.frame_diagonal(), g.frame_diagonal());
    }
}
