//! Shadows with a 2D shadow buffer (Lacroute 1995, §7.3).
//!
//! A second factorization, for the first light, shares the view's principal axis, so
//! one front-to-back sweep over the slices serves both: before slice `k` is composited
//! into the image, each of its voxels looks up how much opacity lies between it and the
//! light in the shadow buffer; after, the slice's own opacity is composited into the
//! shadow buffer, sheared along the light direction. The light's contribution to a
//! voxel's shade is scaled by the transmittance `1 − A`.
//!
//! Constraint: the light's direction must share the view's principal axis and reach the
//! slices in the same order as the viewer (in voxel-index space,
//! `|l_k| ≥ |l_i|, |l_j|` with `l_k` of the same sign as the view's), otherwise one sweep
//! cannot serve both. [`ShadowFrame::new`] returns an error naming this, never a wrong
//! image. Shadows are computed over the whole intermediate image in one band.

use crate::classify::Grid;
use crate::clip::{Clip, RowCut};
use crate::composite::{MergedSpans, Spans};
use crate::error::{need, Error};
use crate::fixed::{self, ONE};
use crate::rle::RleSlice;
use crate::view::{Factorization, SliceOffset};

/// The light's factorization for one frame.
#[derive(Clone, Debug)]
pub struct ShadowFrame {
    shear: [f64; 2],
    translate: [f64; 2],
    /// Shadow buffer size.
    pub size: [usize; 2],
    /// Opacity corrected for the light's step between slices, Q15 per stored opacity.
    pub opacity: [u16; 256],
}

impl ShadowFrame {
    /// Factors the first light's direction (camera space, toward the light) for `view`.
    pub fn new(view: &Factorization, grid: &Grid, light: [f64; 3]) -> Result<Self, Error> {
        let r = view.rotation;
        // Direction the light travels, in object space, then index units.
        let obj: [f64; 3] = core::array::from_fn(|a| {
            -(r[0][a] * light[0] + r[1][a] * light[1] + r[2][a] * light[2])
        });
        let idx: [f64; 3] = core::array::from_fn(|a| obj[a] / grid.spacing[a]);
        let [li, lj, lk] = view.permute(idx);
        let aligned = libm::fabs(lk) >= libm::fabs(li) && libm::fabs(lk) >= libm::fabs(lj);
        if !(aligned && lk != 0.0 && (lk > 0.0) == view.k_increasing) {
            return Err(Error::BadParameter {
                reason: "shadows need the first light within the view's principal-axis cone \
                         (|l_k| >= |l_i|, |l_j| in voxel units) and on the viewer's side of the \
                         slices; move the light closer to the viewing direction",
            });
        }
        let shear = [-li / lk, -lj / lk];
        let [ni, nj, nk] = view.dims;
        let kspan = (nk - 1) as f64;
        let translate = shear.map(|s| if s < 0.0 { -s * kspan } else { 0.0 });
        let size = [
            libm::floor((ni - 1) as f64 + libm::fabs(shear[0]) * kspan) as usize + 2,
            libm::floor((nj - 1) as f64 + libm::fabs(shear[1]) * kspan) as usize + 2,
        ];
        let sp = view.permute(grid.spacing);
        let st = [shear[0] * sp[0], shear[1] * sp[1], sp[2]];
        let len = libm::sqrt(st[0] * st[0] + st[1] * st[1] + st[2] * st[2]);
        Ok(ShadowFrame {
            shear,
            translate,
            size,
            opacity: crate::classify::opacity_correction(len / grid.opacity_unit()),
        })
    }

    /// Offsets of slice `k` in the shadow buffer (as [`Factorization::slice_offset`]).
    pub fn slice_offset(&self, k: usize) -> [SliceOffset; 2] {
        [0, 1].map(|a| SliceOffset::of(self.shear[a] * k as f64 + self.translate[a]))
    }
}

/// Read access to the shadow buffer for the voxels of one slice.
#[derive(Clone, Copy)]
pub struct ShadowLookup<'b> {
    pub(crate) alpha: &'b [u16],
    pub(crate) width: usize,
    pub(crate) height: usize,
    pub(crate) off: [SliceOffset; 2],
}

impl ShadowLookup<'_> {
    /// The buffer's opacity at `(x, y)`, zero outside it.
    fn at(&self, x: i64, y: i64) -> u32 {
        if x < 0 || y < 0 || x >= self.width as i64 || y >= self.height as i64 {
            0
        } else {
            let a = self.alpha.get(y as usize * self.width + x as usize);
            a.map_or(0, |&a| a as u32)
        }
    }

    /// Transmittance toward the light at voxel `(i, j)` of the slice, Q15.
    #[inline]
    pub fn transmittance(&self, i: usize, j: i64) -> u32 {
        // Voxel i sits at i + n + f: pixels i + n (weight 1 − f) and i + n + 1 (weight f).
        let [ou, ov] = self.off;
        let x = i as i64 + ou.n as i64;
        let y = j + ov.n as i64;
        let w = fixed::bilinear_weights(ONE - ou.f, ONE - ov.f);
        let a = (w[0] * self.at(x, y)
            + w[1] * self.at(x + 1, y)
            + w[2] * self.at(x, y + 1)
            + w[3] * self.at(x + 1, y + 1)
            + (1 << 14))
            >> 15;
        ONE - a.min(ONE)
    }
}

/// Entries of the alpha row buffers [`accumulate_slice`] needs for slices `ni` wide.
pub const fn row_buffer_len(ni: usize) -> usize {
    2 * (ni + 2)
}

/// Fills `row` (voxel `i` at entry `i + 1`) with the opacity of row `runs`, `voxels`,
/// cut by the clipping planes along it, if any, as the compositor cuts its colours:
/// what the planes cut away casts no shadow.
fn fill_alpha(
    row: &mut [u16],
    (runs, voxels): (&[u8], &[crate::classify::Voxel]),
    opacity: &[u16; 256],
    cut: Option<RowCut>,
) {
    row.fill(0);
    let mut v = 0;
    for (a, b) in Spans::new(runs) {
        // In bounds for a validated slice and a row of `ni + 2` entries.
        let dst = row.get_mut(a + 1..b + 1).unwrap_or_default();
        for (o, vox) in dst.iter_mut().zip(voxels.get(v..).unwrap_or_default()) {
            *o = opacity[vox.opacity as usize];
        }
        v += b - a;
    }
    if let Some(c) = cut {
        c.apply(row, (0, usize::MAX), |a, c| {
            *a = ((*a as u32 * c + (1 << 15)) >> 16) as u16
        });
    }
}

/// Composites slice `k`'s opacity into the shadow buffer `alpha` (`frame.size`), sheared
/// along the light, cut by the clipping planes `clip` (in the view's roles) if any.
pub fn accumulate_slice(
    alpha: &mut [u16],
    slice: &RleSlice<'_>,
    k: usize,
    frame: &ShadowFrame,
    rows: &mut [u16],
    clip: Option<&Clip>,
) -> Result<(), Error> {
    let (ni, nj) = (slice.ni, slice.nj);
    let [w, h] = frame.size;
    need("shadow buffer", w * h, alpha.len())?;
    need("shadow rows", row_buffer_len(ni), rows.len())?;
    let [ou, ov] = frame.slice_offset(k);
    let wt = fixed::bilinear_weights(ou.f, ov.f);
    let rows = rows.get_mut(..row_buffer_len(ni)).unwrap_or_default();
    let (mut top, mut bot) = rows.split_at_mut_checked(ni + 2).unwrap_or_default();
    let empty: (&[u8], &[crate::classify::Voxel]) = (&[], &[]);
    let row_of = |j: i64| {
        if j >= 0 && (j as usize) < nj {
            slice.scanline(j as usize)
        } else {
            empty
        }
    };
    let cut = clip.and_then(|c| c.slice(k as i64, [ni, nj]));
    let row_cut = |j: i64| cut.as_ref().map(|c| c.row(j, ni));
    let first = row_of(-1);
    fill_alpha(top, first, &frame.opacity, row_cut(-1));
    let mut top_runs = first.0;
    for jt in -1..nj as i64 {
        let next = row_of(jt + 1);
        fill_alpha(bot, next, &frame.opacity, row_cut(jt + 1));
        let q = jt + ov.n as i64 + 1;
        if q >= 0 && (q as usize) < h {
            let line = alpha
                .get_mut(q as usize * w..(q as usize + 1) * w)
                .unwrap_or_default();
            let spans = MergedSpans {
                a: Spans::new(top_runs).peekable(),
                b: Spans::new(next.0).peekable(),
            };
            for (a, b) in spans {
                let pa = (a as i64 + ou.n as i64).clamp(0, w as i64) as usize;
                let pb = (b as i64 + ou.n as i64).clamp(0, w as i64) as usize;
                for (p, px) in line.iter_mut().enumerate().take(pb).skip(pa) {
                    let bl = (p as i64 - ou.n as i64) as usize;
                    // Entries past the rows (never read: `p < pb`) count as clear.
                    let at = |r: &[u16], i: usize| r.get(i).map_or(0, |&a| a as u32);
                    let s = (wt[0] * at(top, bl)
                        + wt[1] * at(top, bl + 1)
                        + wt[2] * at(bot, bl)
                        + wt[3] * at(bot, bl + 1)
                        + (1 << 14))
                        >> 15;
                    let a0 = *px as u32;
                    *px = (a0 + fixed::mul(s, ONE - a0)).min(ONE) as u16;
                }
            }
        }
        core::mem::swap(&mut top, &mut bot);
        top_runs = next.0;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::classify::Voxel;
    use crate::rle::ScanIndex;
    use crate::view::Camera;

    #[test]
    fn an_opaque_half_slice_shadows_exactly_the_voxels_behind_it() {
        // 8×8×8, looking down −z with the light straight behind the viewer: the light
        // shares the axis and has no shear, so slice k's shadow falls on the same (i, j).
        let grid = Grid::new([8, 8, 8], [1.0; 3]).unwrap();
        let cam = Camera {
            rotate_x: 0.0,
            rotate_y: 0.0,
            width: 16,
            height: 16,
        };
        let view = Factorization::new(&grid, &cam).unwrap();
        let f = ShadowFrame::new(&view, &grid, [0.0, 0.0, 1.0]).unwrap();
        assert_eq!(f.size, [9, 9]);
        // Slice: left half (i < 4) opaque, right half empty, every scanline.
        let runs = [[0u8, 4, 4, 0]; 8];
        let runs: &[u8] = runs.as_flattened();
        let vox = [Voxel {
            opacity: 255,
            scalar: 0,
            normal: 0,
        }; 32];
        let scans: [ScanIndex; 9] = core::array::from_fn(|j| ScanIndex {
            run: 4 * j as u32,
            voxel: 4 * j as u32,
        });
        let slice = RleSlice {
            ni: 8,
            nj: 8,
            base: ScanIndex::default(),
            runs,
            voxels: &vox,
            scans: &scans,
            flat: &[],
        };
        slice.validate().unwrap();
        let mut alpha = [0u16; 81];
        let mut rows = [0u16; 20];
        accumulate_slice(&mut alpha, &slice, 7, &f, &mut rows, None).unwrap();
        let look = ShadowLookup {
            alpha: &alpha,
            width: 9,
            height: 9,
            off: f.slice_offset(6),
        };
        for j in 0..8 {
            for i in 0..8 {
                let t = look.transmittance(i, j);
                let expect = if i < 4 { 0 } else { ONE };
                assert_eq!(t, expect, "voxel ({i}, {j})");
            }
        }
        // A light outside the view's principal-axis cone is refused.
        assert!(ShadowFrame::new(&view, &grid, [1.0, 0.0, 0.2]).is_err());
        // So is a light behind the volume (the sweep would run against it).
        assert!(ShadowFrame::new(&view, &grid, [0.0, 0.0, -1.0]).is_err());
    }
}
