//! Fast depth cueing (Lacroute 1995, §7.2): exponential fog `T(d) = front·e^(−density·d)`
//! applied to voxel colours, with depth `d` normalised to 0 at the volume's nearest corner
//! and 1 at its farthest.
//!
//! Depth is linear in object space, so in sheared space it splits as
//! `d(u, v, k) = P(u, v) + S(k)`. The compositor multiplies every voxel colour of slice `k`
//! by the per-slice factor `e^(−density·(S(k) + P_max))` (at most 1, one `exp` per slice)
//! and, once compositing is done, every intermediate pixel by
//! `front·e^(density·(P_max − P(u, v)))` (at least `front`, from a 257-entry table). The
//! product is exactly the fog at the sample's depth; choosing `P_max` keeps the slice
//! factor below one, so the Q15 intermediate image never overflows before it is restored.

use crate::error::Error;
use crate::fixed::ONE;
use crate::view::Factorization;

/// Fog parameters, as in VolPack's `vpSetDepthCueing`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DepthCue {
    /// Attenuation at the front (depth 0), in `(0, 1]`.
    pub front: f64,
    /// Exponential density per unit of normalised depth, in `[0, 16]`.
    pub density: f64,
}

impl DepthCue {
    /// Checks the parameters.
    pub fn validate(&self) -> Result<(), Error> {
        if !(self.front.is_finite() && self.front > 0.0 && self.front <= 1.0) {
            return Err(Error::BadParameter {
                reason: "depth-cue front factor must be in (0, 1]",
            });
        }
        if !(self.density.is_finite() && (0.0..=16.0).contains(&self.density)) {
            return Err(Error::BadParameter {
                reason: "depth-cue density must be in 0..16",
            });
        }
        Ok(())
    }
}

const STEPS: usize = 256;

/// Per-frame depth-cue state.
#[derive(Clone, Debug)]
pub struct DepthFrame {
    density: f64,
    /// `S(k) + P_max = slope·k + offset`.
    slope: f64,
    offset: f64,
    /// `P(u, v) = gu·u + gv·v`.
    gu: f64,
    gv: f64,
    pmax: f64,
    range: f64,
    /// `front·e^(density·x)` for `x = range·i/STEPS`, Q15 (may exceed ONE).
    table: [u32; STEPS + 1],
}

impl DepthFrame {
    /// Sets up depth cueing for `view` of a volume with `spacing` (object x, y, z).
    pub fn new(
        cue: &DepthCue,
        view: &Factorization,
        dims: [usize; 3],
        spacing: [f64; 3],
    ) -> Result<Self, Error> {
        cue.validate()?;
        let r = view.rotation;
        // Depth (−z in camera space) per unit of each object index axis.
        let per_axis: [f64; 3] = core::array::from_fn(|a| -r[2][a] * spacing[a]);
        // Extent over the voxel-centre box [0, n−1]³.
        let mut lo = 0.0;
        let mut hi = 0.0;
        for (a, &g) in per_axis.iter().enumerate() {
            let span = g * (dims[a] - 1) as f64;
            if span < 0.0 {
                lo += span;
            } else {
                hi += span;
            }
        }
        let extent = hi - lo;
        let scale = if extent > 0.0 { 1.0 / extent } else { 0.0 };
        // Normalised depth d = Σ g_a·x_a − lo·scale, with g_a = per_axis·scale.
        let [gi, gj, gk] = view.permute(per_axis).map(|g| g * scale);
        let e = -lo * scale;
        // Substitute i = u − s_i·k − t_i, j = v − s_j·k − t_j.
        let [si, sj] = view.shear;
        let [ti, tj] = view.translate;
        let slope_s = gk - gi * si - gj * sj;
        let off_s = e - gi * ti - gj * tj;
        let [w, h] = view.intermediate;
        // Per intermediate pixel (a supersampled image has `s` pixels per voxel).
        let ss = view.supersample.max(1) as f64;
        let (pgi, pgj) = (gi / ss, gj / ss);
        let (wm, hm) = ((w.max(1) - 1) as f64, (h.max(1) - 1) as f64);
        let corners = [0.0, pgi * wm, pgj * hm, pgi * wm + pgj * hm];
        let mut pmax = f64::NEG_INFINITY;
        let mut pmin = f64::INFINITY;
        for c in corners {
            pmax = pmax.max(c);
            pmin = pmin.min(c);
        }
        let range = pmax - pmin;
        let mut table = [0u32; STEPS + 1];
        for (i, t) in table.iter_mut().enumerate() {
            let x = range * i as f64 / STEPS as f64;
            let f = cue.front * libm::exp(cue.density * x);
            *t = (f * ONE as f64 + 0.5).min(u32::MAX as f64 / 2.0) as u32;
        }
        Ok(DepthFrame {
            density: cue.density,
            slope: slope_s,
            offset: off_s + pmax,
            gu: pgi,
            gv: pgj,
            pmax,
            range,
            table,
        })
    }

    /// Colour factor for slice `k`, Q15, at most ONE.
    pub fn slice_factor(&self, k: usize) -> u32 {
        let x = (self.slope * k as f64 + self.offset).max(0.0);
        (libm::exp(-self.density * x) * ONE as f64 + 0.5) as u32
    }

    /// Restores scanline `v` (pixels of width `row.len()`) by the per-pixel factor.
    pub fn apply_row(&self, v: usize, row: &mut [[u16; 4]]) {
        if self.range <= 0.0 {
            // Depth does not vary over the image: only the front factor remains.
            let f = self.table[0];
            for p in row.iter_mut() {
                // Premultiplied colour never exceeds alpha (the factor can pass 1 where
                // samples lie outside the voxel-centre box the depth is normalised over).
                let a = p[3] as u64;
                for c in p.iter_mut().take(3) {
                    *c = ((*c as u64 * f as u64 + (1 << 14)) >> 15).min(a) as u16;
                }
            }
            return;
        }
        // x(u) = P_max − P(u, v) in table steps, 16.16 fixed point, stepped along u.
        let to_steps = STEPS as f64 / self.range;
        let x0 = (self.pmax - self.gv * v as f64) * to_steps;
        let dx = -self.gu * to_steps;
        let mut x = libm::round(x0 * 65536.0) as i64;
        let step = libm::round(dx * 65536.0) as i64;
        for p in row.iter_mut() {
            let xi = x.clamp(0, (STEPS as i64) << 16);
            let i = (xi >> 16) as usize;
            let f = (xi & 0xFFFF) as u64;
            let lo = self.table[i] as u64;
            let hi = self.table[(i + 1).min(STEPS)] as u64;
            let factor = (lo * (65536 - f) + hi * f + (1 << 15)) >> 16;
            let a = p[3] as u64;
            for c in p.iter_mut().take(3) {
                *c = ((*c as u64 * factor + (1 << 14)) >> 15).min(a) as u16;
            }
            x += step;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::classify::Grid;
    use crate::view::Camera;

    fn frame(rx: f64, ry: f64, cue: DepthCue) -> (Factorization, DepthFrame) {
        let g = Grid::new([20, 30, 25], [1.0, 0.8, 1.5]).unwrap();
        let cam = Camera {
            rotate_x: rx,
            rotate_y: ry,
            width: 64,
            height: 64,
        };
        let v = Factorization::new(&g, &cam).unwrap();
        let d = DepthFrame::new(&cue, &v, g.dims, g.spacing).unwrap();
        (v, d)
    }

    #[test]
    fn factored_fog_equals_fog_at_the_voxel_depth() {
        let cue = DepthCue {
            front: 0.9,
            density: 1.5,
        };
        for (rx, ry) in [(0.0, 0.0), (30.0, 50.0), (-80.0, 20.0), (10.0, 100.0)] {
            let (v, d) = frame(rx, ry, cue);
            let r = v.rotation;
            let sp = [1.0, 0.8, 1.5];
            let dims = [20usize, 30, 25];
            // Exact normalised depth of a voxel.
            let depth = |x: [f64; 3]| -> f64 {
                let z =
                    |x: [f64; 3]| -> f64 { -(0..3).map(|a| r[2][a] * sp[a] * x[a]).sum::<f64>() };
                let mut lo = f64::INFINITY;
                let mut hi = f64::NEG_INFINITY;
                for c in 0..8 {
                    let corner = core::array::from_fn(|a| {
                        if c >> a & 1 == 1 {
                            (dims[a] - 1) as f64
                        } else {
                            0.0
                        }
                    });
                    lo = lo.min(z(corner));
                    hi = hi.max(z(corner));
                }
                (z(x) - lo) / (hi - lo)
            };
            let p = v.perm();
            for obj in [[0usize, 0, 0], [19, 29, 24], [5, 17, 3], [12, 2, 20]] {
                let (i, j, k) = (obj[p[0]], obj[p[1]], obj[p[2]]);
                let u = i as f64 + v.shear[0] * k as f64 + v.translate[0];
                let vv = j as f64 + v.shear[1] * k as f64 + v.translate[1];
                let slice = d.slice_factor(k) as f64 / ONE as f64;
                assert!(slice <= 1.0 + 1e-9);
                let pix = 0.9 * libm::exp(1.5 * (d.pmax - d.gu * u - d.gv * vv));
                let got = slice * pix;
                let want = 0.9 * libm::exp(-1.5 * depth(obj.map(|c| c as f64)));
                assert!(
                    (got - want).abs() < 2e-4,
                    "{rx} {ry} {obj:?}: {got} vs {want}"
                );
            }
        }
    }

    #[test]
    fn rejects_bad_parameters() {
        for (f, d) in [(0.0, 1.0), (1.5, 1.0), (0.5, -1.0), (0.5, f64::NAN)] {
            assert!(DepthCue {
                front: f,
                density: d
            }
            .validate()
            .is_err());
        }
    }
}
