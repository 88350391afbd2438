//! Cropping: an axis-aligned box of voxels, outside which the volume is left out.
//!
//! A box that cuts a volume open (the skull opened to show the brain, a quadrant taken
//! out of an organ) is what a user of a medical volume viewer reaches for first.
//! Lacroute sketches arbitrary clipping planes for shear-warp, scan-converted into loop
//! bounds per voxel scanline, and leaves them unbuilt (1995, §7.5). An axis-aligned box
//! needs no scan conversion, and is applied here where it costs a frame nothing:
//! - **Classified volumes**: every voxel outside the box is made transparent as the
//!   volume is classified ([`Crop::apply`]), so the run-length encoding drops it and
//!   frames skip it like air: a cropped frame is faster, never slower. The box is baked
//!   into the encoding, as the opacity transfer function is; a new box is a new
//!   encoding.
//! - **Unclassified volumes** (post-classification, pre-integration, isosurfaces): each
//!   frame keeps its samples inside the box's cells ([`Crop::cells`]), as it keeps them
//!   inside the volume's, so a new box costs nothing there.
//!
//! Either way the gradients near the cut are those of the whole volume: the cut face is
//! lit by the structure of the tissue it cuts through, not by the cut. The thesis asks
//! for opacity to fall off over a few voxels at a cut so that it does not alias; the
//! classified path's bilinear samples give a ramp one voxel wide (a kept voxel beside a
//! transparent one), the unclassified path cuts at the cells' faces.

use crate::classify::{Grid, Voxel};
use crate::error::{need, Error};

/// An inclusive box of voxel indices `lo[a]..=hi[a]` along each axis `a` (x, y, z) of
/// the volume it was made for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Crop {
    lo: [usize; 3],
    hi: [usize; 3],
}

impl Crop {
    /// The box `lo..=hi` of a volume of `dims` voxels; refused unless `lo[a] ≤ hi[a] <
    /// dims[a]` on every axis.
    pub fn new(lo: [usize; 3], hi: [usize; 3], dims: [usize; 3]) -> Result<Self, Error> {
        for ((l, h), n) in lo.iter().zip(&hi).zip(&dims) {
            if l > h {
                return Err(Error::BadParameter {
                    reason: "crop box: a lower bound is above its upper bound",
                });
            }
            if h >= n {
                return Err(Error::BadParameter {
                    reason: "crop box: an upper bound lies outside the volume",
                });
            }
        }
        Ok(Crop { lo, hi })
    }

    /// The first voxel index kept along each axis.
    pub fn lo(&self) -> [usize; 3] {
        self.lo
    }

    /// The last voxel index kept along each axis.
    pub fn hi(&self) -> [usize; 3] {
        self.hi
    }

    /// The box that keeps every voxel of a volume of `dims` (each side at least 1, as
    /// [`Grid`] has them).
    pub fn whole(dims: [usize; 3]) -> Self {
        Crop {
            lo: [0; 3],
            hi: dims.map(|n| n.saturating_sub(1)),
        }
    }

    /// Whether voxel `(x, y, z)` is kept.
    pub fn contains(&self, p: [usize; 3]) -> bool {
        (self.lo.iter().zip(&self.hi).zip(&p)).all(|((l, h), v)| l <= v && v <= h)
    }

    /// The kept cells along each axis as closed ranges of index-space position: voxel
    /// `i` is the unit cell `[i − ½, i + ½]`, so the box spans `[lo − ½, hi + ½]`, as a
    /// whole volume of `n` voxels spans `[−½, n − ½]`. Returned as `(2·lo − 1, 2·hi +
    /// 1)`, in half voxels, so that the bounds are integers.
    pub fn cells(&self) -> [(i64, i64); 3] {
        let half = |v: usize| 2 * v as i64;
        let [l0, l1, l2] = self.lo.map(half);
        let [h0, h1, h2] = self.hi.map(half);
        [(l0 - 1, h0 + 1), (l1 - 1, h1 + 1), (l2 - 1, h2 + 1)]
    }

    /// Makes the voxels of z slices `slices` of a volume of `grid` that lie outside the
    /// box transparent (opacity 0, no normal), in `out`, which holds those slices' records
    /// from its start as [`crate::classify::classify_slices`] writes them. Voxels inside
    /// are untouched.
    pub fn apply(
        &self,
        grid: &Grid,
        slices: core::ops::Range<usize>,
        out: &mut [Voxel],
    ) -> Result<(), Error> {
        let plane = slice_records(grid, &slices, out.len())?;
        if self.hi.iter().zip(&grid.dims).any(|(h, n)| h >= n) {
            return Err(Error::BadParameter {
                reason: "crop box: an upper bound lies outside the volume",
            });
        }
        let nx = grid.dims[0];
        let clear = |v: &mut [Voxel]| {
            for r in v {
                *r = Voxel {
                    opacity: 0,
                    scalar: r.scalar,
                    normal: crate::normal::ZERO_GRADIENT,
                };
            }
        };
        let [x0, y0, z0] = self.lo;
        let [x1, y1, z1] = self.hi;
        // `Grid` keeps every side at least 1; `max` says so to the compiler, so that
        // `chunks_exact_mut` keeps no panic path (the firmware links only without one).
        for (z, slice) in slices.zip(out.chunks_exact_mut(plane.max(1))) {
            if z < z0 || z > z1 {
                clear(slice);
                continue;
            }
            for (y, row) in slice.chunks_exact_mut(nx.max(1)).enumerate() {
                if y < y0 || y > y1 {
                    clear(row);
                } else {
                    clear(row.get_mut(..x0).unwrap_or_default());
                    clear(row.get_mut(x1 + 1..).unwrap_or_default());
                }
            }
        }
        Ok(())
    }

    /// This box on a coarser copy of the volume (a level of [`crate::lod`]): full
    /// dimensions `full`, the copy's `level_dims`, each of its voxels standing for
    /// `factor` (2^level) full voxels along each axis about the same centre. Keeps the
    /// copy's voxels whose centres lie in the box's cells; `None` when none does.
    pub fn at_level(
        &self,
        full: [usize; 3],
        level_dims: [usize; 3],
        factor: usize,
    ) -> Option<Crop> {
        let mut lo = [0; 3];
        let mut hi = [0; 3];
        let axes = lo.iter_mut().zip(hi.iter_mut());
        let sides = full.iter().zip(&level_dims).zip(self.cells());
        for ((lo, hi), ((&n, &m), (c0, c1))) in axes.zip(sides) {
            // A copy's voxel i is centred where the full volume's index
            // (n − 1)/2 + (i − (m − 1)/2)·factor is; in half voxels, to stay in integers:
            // 2·centre = (n − 1) + (2i − (m − 1))·factor.
            let (n, m, f) = (n as i64, m as i64, factor as i64);
            let centre2 = |i: i64| (n - 1) + (2 * i - (m - 1)) * f;
            let first = (0..m).find(|&i| centre2(i) >= c0)?;
            let last = (0..m).rev().find(|&i| centre2(i) <= c1)?;
            if first > last {
                return None;
            }
            (*lo, *hi) = (first as usize, last as usize);
        }
        Some(Crop { lo, hi })
    }
}

/// Checks that z slices `slices` lie in a volume of `grid` and that `len` records hold
/// them; returns the records a slice holds. For the cuts applied to classified slices
/// ([`Crop::apply`], [`crate::clip::Clip::apply`]).
pub(crate) fn slice_records(
    grid: &Grid,
    slices: &core::ops::Range<usize>,
    len: usize,
) -> Result<usize, Error> {
    let [nx, ny, nz] = grid.dims;
    if slices.start > slices.end || slices.end > nz {
        return Err(Error::BadParameter {
            reason: "slices lie outside the volume",
        });
    }
    need("voxels", slices.len() * nx * ny, len)?;
    Ok(nx * ny)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::normal::ZERO_GRADIENT;

    fn voxel(i: usize) -> Voxel {
        Voxel {
            opacity: 200,
            scalar: i as u8,
            normal: 7,
        }
    }

    #[test]
    fn apply_clears_exactly_the_voxels_outside() {
        let dims = [5, 4, 3];
        let grid = Grid::new(dims, [1.0; 3]).unwrap();
        let crop = Crop::new([1, 0, 1], [3, 2, 2], dims).unwrap();
        // Slices 1..3 only, as a classifier working a few slices at a time writes them.
        let mut out: [Voxel; 40] = core::array::from_fn(voxel);
        crop.apply(&grid, 1..3, &mut out).unwrap();
        for (n, v) in out.iter().enumerate() {
            let (x, y, z) = (n % 5, n / 5 % 4, 1 + n / 20);
            if crop.contains([x, y, z]) {
                assert_eq!(*v, voxel(n), "({x}, {y}, {z}) kept");
            } else {
                let cleared = Voxel {
                    opacity: 0,
                    scalar: n as u8,
                    normal: ZERO_GRADIENT,
                };
                assert_eq!(*v, cleared, "({x}, {y}, {z}) cleared");
            }
        }
        // 3 × 3 × 2 voxels kept.
        assert_eq!(out.iter().filter(|v| v.opacity > 0).count(), 18);
    }

    #[test]
    fn bad_boxes_and_buffers_are_refused() {
        let dims = [5, 4, 3];
        assert!(Crop::new([2, 0, 0], [1, 3, 2], dims).is_err());
        assert!(Crop::new([0, 0, 0], [4, 4, 2], dims).is_err());
        let crop = Crop::new([0; 3], [4, 3, 2], dims).unwrap();
        assert_eq!(crop, Crop::whole(dims));
        let grid = Grid::new(dims, [1.0; 3]).unwrap();
        let mut short = [Voxel::default(); 19];
        assert!(crop.apply(&grid, 0..1, &mut short).is_err());
        assert!(crop.apply(&grid, 2..4, &mut short).is_err());
        let small = Grid::new([5, 4, 2], [1.0; 3]).unwrap();
        assert!(crop.apply(&small, 0..1, &mut short).is_err());
    }

    #[test]
    fn levels_keep_the_voxels_centred_in_the_box() {
        // Odd side 9 → 5 (level voxel i at full 2i), even side 8 → 4 (at full 2i + ½).
        let full = [9, 8, 9];
        let crop = Crop::new([2, 2, 0], [5, 5, 8], full).unwrap();
        let l = crop.at_level(full, [5, 4, 5], 2).unwrap();
        // x: cells [1.5, 5.5] hold centres 2 and 4 (i = 1, 2); y: [1.5, 5.5] holds 2.5
        // and 4.5 (i = 1, 2); z: the whole side.
        assert_eq!((l.lo(), l.hi()), ([1, 1, 0], [2, 2, 4]));
        // A one-voxel box between two level centres holds none.
        let thin = Crop::new([3, 0, 0], [3, 7, 8], full).unwrap();
        assert_eq!(thin.at_level(full, [5, 4, 5], 2), None);
        // Level 0 is the box itself.
        assert_eq!(crop.at_level(full, full, 1), Some(crop));
    }
}
