//! The shear-warp factorization for parallel projection (Lacroute 1995, §3.2).
//!
//! The viewing transform is split into a shear of the volume's slices, which makes all
//! viewing rays parallel to the principal axis, and a 2D affine warp of the composited
//! (intermediate) image into the final image. The principal axis is the object axis most
//! parallel to the viewing direction, measured in voxel-index space so that both shear
//! coefficients are at most 1 in magnitude and the slices are resampled at no less than
//! the voxel rate.
//!
//! Camera convention (the project's contract; see README): voxel `(i, j, k)` sits at
//! `((i − (nx−1)/2)·sx, (j − (ny−1)/2)·sy, (k − (nz−1)/2)·sz)`; the object is rotated
//! about Y by `rotate_y` degrees, then about X by `rotate_x` (right-handed); an
//! orthographic camera on +Z looks toward −Z with image right = +X, up = +Y, row 0 at the
//! top; the shorter image side spans the volume's diagonal.

use crate::classify::Grid;
use crate::error::Error;
use crate::fixed::ONE;
use crate::rle::Axis;

/// Largest accepted image side.
pub const MAX_IMAGE: usize = 16384;

/// View parameters of a frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Rotation about X in degrees, applied second.
    pub rotate_x: f64,
    /// Rotation about Y in degrees, applied first.
    pub rotate_y: f64,
    /// Image width in pixels.
    pub width: usize,
    /// Image height in pixels.
    pub height: usize,
}

/// `R = Rx(rx) · Ry(ry)`, row-major.
pub fn rotation(rotate_x_deg: f64, rotate_y_deg: f64) -> [[f64; 3]; 3] {
    let (sx, cx) = sincos_deg(rotate_x_deg);
    let (sy, cy) = sincos_deg(rotate_y_deg);
    // Rx = [[1,0,0],[0,cx,-sx],[0,sx,cx]], Ry = [[cy,0,sy],[0,1,0],[-sy,0,cy]].
    [
        [cy, 0.0, sy],
        [sx * sy, cx, -sx * cy],
        [-cx * sy, sx, cx * cy],
    ]
}

/// Sine and cosine of an angle in degrees, exact at multiples of 90° so that axis-aligned
/// views are exactly axis-aligned.
fn sincos_deg(deg: f64) -> (f64, f64) {
    let r = libm::fmod(deg, 360.0);
    let r = if r < 0.0 { r + 360.0 } else { r };
    if r == 0.0 {
        (0.0, 1.0)
    } else if r == 90.0 {
        (1.0, 0.0)
    } else if r == 180.0 {
        (0.0, -1.0)
    } else if r == 270.0 {
        (-1.0, 0.0)
    } else {
        let rad = r * (core::f64::consts::PI / 180.0);
        (libm::sin(rad), libm::cos(rad))
    }
}

/// Where slice `k` lands in the intermediate image along one axis, split for the
/// compositor: voxel `i` of the slice sits at intermediate coordinate `i + n + f`, so
/// pixel `u` interpolates voxels `u − n − 1` (weight `f`) and `u − n` (weight `1 − f`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SliceOffset {
    /// Integer part of the translation.
    pub n: i32,
    /// Fractional part, Q15 in `0..ONE`.
    pub f: u32,
}

impl SliceOffset {
    /// Splits a translation into whole pixels and a Q15 fraction (a fraction that rounds
    /// to one carries into the whole part).
    pub fn of(t: f64) -> Self {
        let mut n = libm::floor(t);
        let mut f = libm::round((t - n) * ONE as f64) as u32;
        if f >= ONE {
            n += 1.0;
            f = 0;
        }
        SliceOffset { n: n as i32, f }
    }
}

/// The factored view.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Factorization {
    /// Principal axis.
    pub axis: Axis,
    /// Permuted dimensions `(ni, nj, nk)`.
    pub dims: [usize; 3],
    /// Shear coefficients `(s_i, s_j)`: slice `k` moves by `s·k` pixels.
    pub shear: [f64; 2],
    /// Translation `(t_i, t_j)` that keeps all slices at non-negative coordinates.
    pub translate: [f64; 2],
    /// True if slice 0 is nearest the viewer (compositing runs k = 0, 1, ...).
    pub k_increasing: bool,
    /// Intermediate image size `(width, height)`.
    pub intermediate: [usize; 2],
    /// Final image size `(width, height)`.
    pub image: [usize; 2],
    /// Affine map from final-image coordinates (pixel centres at `+0.5`) to intermediate
    /// coordinates: `u = m[0]·(x, y, 1)`, `v = m[1]·(x, y, 1)`.
    pub image_to_intermediate: [[f64; 3]; 2],
    /// Object-to-camera rotation (for shading).
    pub rotation: [[f64; 3]; 3],
    /// Ray length between adjacent slices divided by the smallest spacing: the exponent
    /// of opacity correction.
    pub step_ratio: f64,
    /// Intermediate pixels per voxel along i and j (1: Lacroute's voxel-rate image).
    pub supersample: usize,
}

impl Factorization {
    /// Factors the view of `grid` through `camera`.
    pub fn new(grid: &Grid, camera: &Camera) -> Result<Self, Error> {
        if camera.width == 0
            || camera.height == 0
            || camera.width > MAX_IMAGE
            || camera.height > MAX_IMAGE
        {
            return Err(Error::BadParameter {
                reason: "image size must be 1..=16384 on each side",
            });
        }
        if !(camera.rotate_x.is_finite() && camera.rotate_y.is_finite()) {
            return Err(Error::BadParameter {
                reason: "rotation angles must be finite",
            });
        }
        let rot = rotation(camera.rotate_x, camera.rotate_y);
        // Ray direction toward the scene: object space −(third row of R), in index units.
        let dir = [
            -rot[2][0] / grid.spacing[0],
            -rot[2][1] / grid.spacing[1],
            -rot[2][2] / grid.spacing[2],
        ];
        let mut axis = Axis::Z;
        let mag = dir.map(libm::fabs);
        if mag[0] >= mag[1] && mag[0] >= mag[2] {
            axis = Axis::X;
        } else if mag[1] >= mag[2] {
            axis = Axis::Y;
        }
        let p = axis.permutation();
        let dims = axis.permuted_dims(grid.dims);
        let [ni, nj, nk] = dims;
        let (di, dj, dk) = (dir[p[0]], dir[p[1]], dir[p[2]]);
        let shear = [-di / dk, -dj / dk];
        let kspan = (nk - 1) as f64;
        let translate = shear.map(|s| if s < 0.0 { -s * kspan } else { 0.0 });
        let inter_w = libm::floor((ni - 1) as f64 + libm::fabs(shear[0]) * kspan) as usize + 2;
        let inter_h = libm::floor((nj - 1) as f64 + libm::fabs(shear[1]) * kspan) as usize + 2;

        // Object index point -> image coordinates: linear columns and the image of the
        // permuted origin.
        let (w, h) = (camera.width as f64, camera.height as f64);
        let scale = w.min(h) / grid.diagonal();
        let to_image = |obj: [f64; 3]| -> [f64; 2] {
            let q = [
                rot[0][0] * obj[0] + rot[0][1] * obj[1] + rot[0][2] * obj[2],
                rot[1][0] * obj[0] + rot[1][1] * obj[1] + rot[1][2] * obj[2],
            ];
            [w * 0.5 + scale * q[0], h * 0.5 - scale * q[1]]
        };
        let unit = |a: usize| -> [f64; 2] {
            let mut e = [0.0; 3];
            e[a] = grid.spacing[a];
            let i0 = to_image([0.0; 3]);
            let i1 = to_image(e);
            [i1[0] - i0[0], i1[1] - i0[1]]
        };
        let ci = unit(p[0]);
        let cj = unit(p[1]);
        let origin = to_image([
            -((grid.dims[0] - 1) as f64) * 0.5 * grid.spacing[0],
            -((grid.dims[1] - 1) as f64) * 0.5 * grid.spacing[1],
            -((grid.dims[2] - 1) as f64) * 0.5 * grid.spacing[2],
        ]);
        // image = [ci cj]·(u − t_i, v − t_j) + origin; invert the 2×2.
        let det = ci[0] * cj[1] - cj[0] * ci[1];
        if !(det.is_finite() && libm::fabs(det) > 1e-300) {
            return Err(Error::BadParameter {
                reason: "degenerate view (singular warp)",
            });
        }
        let inv = [[cj[1] / det, -cj[0] / det], [-ci[1] / det, ci[0] / det]];
        let row = |r: usize, t: f64| -> [f64; 3] {
            [
                inv[r][0],
                inv[r][1],
                t - inv[r][0] * origin[0] - inv[r][1] * origin[1],
            ]
        };
        let image_to_intermediate = [row(0, translate[0]), row(1, translate[1])];

        let sp = [grid.spacing[p[0]], grid.spacing[p[1]], grid.spacing[p[2]]];
        let step = [shear[0] * sp[0], shear[1] * sp[1], sp[2]];
        let step_len = libm::sqrt(step[0] * step[0] + step[1] * step[1] + step[2] * step[2]);
        Ok(Factorization {
            axis,
            dims,
            shear,
            translate,
            k_increasing: dk > 0.0,
            intermediate: [inter_w, inter_h],
            image: [camera.width, camera.height],
            image_to_intermediate,
            rotation: rot,
            step_ratio: step_len / grid.min_spacing(),
            supersample: 1,
        })
    }

    /// Composites at `s` intermediate pixels per voxel in each slice direction (1..=4),
    /// so that a final image larger than the volume's projection gets detail from
    /// bilinear resampling of the slices instead of from magnifying the intermediate
    /// image. Costs about `s²` more compositing.
    pub fn with_supersampling(mut self, s: usize) -> Result<Self, Error> {
        if !(1..=4).contains(&s) {
            return Err(Error::BadParameter {
                reason: "supersampling factor must be 1..=4",
            });
        }
        if s == 1 {
            return Ok(self);
        }
        self.intermediate = self.intermediate.map(|n| s * n + 1);
        for row in self.image_to_intermediate.iter_mut() {
            for c in row.iter_mut() {
                *c *= s as f64;
            }
        }
        self.supersample = s;
        Ok(self)
    }

    /// The `idx`-th slice in front-to-back order.
    pub fn slice_at(&self, idx: usize) -> usize {
        if self.k_increasing {
            idx
        } else {
            self.dims[2] - 1 - idx
        }
    }

    /// Offsets of slice `k` along i and j.
    pub fn slice_offset(&self, k: usize) -> [SliceOffset; 2] {
        [0, 1].map(|a| SliceOffset::of(self.shear[a] * k as f64 + self.translate[a]))
    }
}

/// Upper bound of the intermediate image's pixel count over all views of `dims`, for
/// sizing buffers at compile time: `max over axes (ni + nk + 1)·(nj + nk + 1)`.
pub const fn max_intermediate_pixels(dims: [usize; 3]) -> usize {
    let axes = [Axis::X, Axis::Y, Axis::Z];
    let mut best = 0;
    let mut a = 0;
    while a < 3 {
        let d = axes[a].permuted_dims(dims);
        let n = (d[0] + d[2] + 1) * (d[1] + d[2] + 1);
        if n > best {
            best = n;
        }
        a += 1;
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(d: [usize; 3]) -> Grid {
        Grid::new(d, [1.0; 3]).unwrap()
    }

    fn cam(rx: f64, ry: f64) -> Camera {
        Camera {
            rotate_x: rx,
            rotate_y: ry,
            width: 100,
            height: 100,
        }
    }

    #[test]
    fn axis_aligned_views_choose_the_expected_principal_axis() {
        let g = grid([10, 20, 30]);
        let f = Factorization::new(&g, &cam(0.0, 0.0)).unwrap();
        assert_eq!(f.axis, Axis::Z);
        assert_eq!(f.shear, [0.0, 0.0]);
        // Looking toward −Z: the viewer is at high z, so slices run from k = nz−1 down.
        assert!(!f.k_increasing);
        let f = Factorization::new(&g, &cam(0.0, 90.0)).unwrap();
        assert_eq!(f.axis, Axis::X);
        let f = Factorization::new(&g, &cam(90.0, 0.0)).unwrap();
        assert_eq!(f.axis, Axis::Y);
        assert!((f.step_ratio - 1.0).abs() < 1e-12);
    }

    #[test]
    fn shear_is_bounded_and_the_intermediate_image_covers_every_slice() {
        let g = grid([17, 23, 31]);
        for rx in (-180..180).step_by(23) {
            for ry in (-180..180).step_by(19) {
                let f = Factorization::new(&g, &cam(rx as f64, ry as f64)).unwrap();
                assert!(f.shear.iter().all(|s| s.abs() <= 1.0 + 1e-12));
                let [ni, nj, nk] = f.dims;
                for k in [0, nk - 1] {
                    let o = f.slice_offset(k);
                    // Voxel 0 lands at n + 1 − f ≥ 0 and the last voxel's right footprint
                    // stays inside the intermediate image.
                    assert!(o[0].n >= -1 && o[1].n >= -1);
                    assert!(((ni as i32) + o[0].n) < f.intermediate[0] as i32 + 1);
                    assert!(((nj as i32) + o[1].n) < f.intermediate[1] as i32 + 1);
                }
                assert!(f.intermediate[0] * f.intermediate[1] <= max_intermediate_pixels(g.dims));
            }
        }
    }

    #[test]
    fn warp_maps_the_volume_centre_to_the_image_centre() {
        let g = Grid::new([11, 21, 7], [1.0, 0.5, 2.0]).unwrap();
        for (rx, ry) in [(0.0, 0.0), (30.0, 45.0), (-70.0, 120.0), (90.0, 0.0)] {
            let f = Factorization::new(&g, &cam(rx, ry)).unwrap();
            let m = f.image_to_intermediate;
            let u = m[0][0] * 50.0 + m[0][1] * 50.0 + m[0][2];
            let v = m[1][0] * 50.0 + m[1][1] * 50.0 + m[1][2];
            // The centre voxel column: permuted centre (ci, cj, ck) projects to
            // (ci + s_i·ck + t_i, cj + s_j·ck + t_j).
            let c = f.dims.map(|d| (d - 1) as f64 * 0.5);
            let eu = c[0] + f.shear[0] * c[2] + f.translate[0];
            let ev = c[1] + f.shear[1] * c[2] + f.translate[1];
            assert!((u - eu).abs() < 1e-9 && (v - ev).abs() < 1e-9, "{rx} {ry}");
        }
    }

    #[test]
    fn rejects_bad_cameras() {
        let g = grid([4, 4, 4]);
        let mut c = cam(0.0, 0.0);
        c.width = 0;
        assert!(Factorization::new(&g, &c).is_err());
        assert!(Factorization::new(&g, &cam(f64::NAN, 0.0)).is_err());
    }

    #[test]
    fn rotation_convention_is_right_handed() {
        // Ry(90°) takes +X to −Z; Rx(90°) takes +Y to +Z.
        let r = rotation(0.0, 90.0);
        assert_eq!([r[0][0], r[1][0], r[2][0]], [0.0, 0.0, -1.0]);
        let r = rotation(90.0, 0.0);
        assert_eq!([r[0][1], r[1][1], r[2][1]], [0.0, 0.0, 1.0]);
    }
}
