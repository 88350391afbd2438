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
use crate::rle::{Axis, Layout};

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
    /// How the volume's copies are laid out ([`Grid::layout`]).
    pub layout: Layout,
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
    /// Map from final-image coordinates (pixel centres at `+0.5`) to intermediate
    /// coordinates, homogeneous: `(U, V, W) = m·(x, y, 1)`, `u = U/W`, `v = V/W`. For
    /// parallel projection the last row is `(0, 0, 1)` (an affine map); for perspective
    /// it is projective, normalised so that `W > 0` exactly on rays that reach the slices.
    pub image_to_intermediate: [[f64; 3]; 3],
    /// Object-to-camera rotation (for shading).
    pub rotation: [[f64; 3]; 3],
    /// Ray length between adjacent slices divided by the smallest spacing: the exponent
    /// of opacity correction.
    pub step_ratio: f64,
    /// Intermediate pixels per voxel along i and j (1: Lacroute's voxel-rate image).
    pub supersample: usize,
    /// The perspective part of the factorization, `None` for parallel projection.
    pub perspective: Option<Perspective>,
}

/// What a perspective factorization adds (Lacroute 1995, §3.3 and App. A.3): every slice
/// is translated and scaled uniformly about the eye's foot point, so that rays from the
/// eye become perpendicular to the slices.
///
/// In permuted index coordinates, voxel `(i, j)` of slice `k` lands at intermediate
/// `u = σ(k)·(i − e_i) + e_i + t_i` (and likewise `v`), where `σ(k) = (k_f − e_k)/(k −
/// e_k)` is 1 on the front slice `k_f` and shrinks behind it: the intermediate image is
/// the front slice's plane, seen from the eye.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Perspective {
    /// The eye in permuted index coordinates `(e_i, e_j, e_k)`.
    pub eye: [f64; 3],
    /// Front slice (scale 1).
    pub front: usize,
    /// Scale of the farthest slice, in `[1/MAX_DECIMATION, 1]`.
    pub min_scale: f64,
    /// Squared opacity-correction exponent of the ray through intermediate `(u, v)`:
    /// `r² = c + a·(u − u₀)² + b·(v − v₀)²`, stored as `[c, a, u₀, b, v₀]`. The step
    /// between slices along a ray from the eye is constant, so one exponent per ray.
    pub ratio_sq: [f64; 5],
    /// Smallest and largest `r²` over the intermediate image.
    pub ratio_sq_range: [f64; 2],
}

/// Largest accepted ratio between the front and the back slice's scale in perspective:
/// it bounds the filter footprint (and the row buffers) of the farthest slice.
pub const MAX_DECIMATION: usize = 8;

/// One slice's place in a perspective intermediate image.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SliceScale {
    /// Scale `σ(k)` in `(0, 1]`.
    pub scale: f64,
    /// Intermediate position of voxel `(0, 0)`: `(1 − σ)·e + t`.
    pub origin: [f64; 2],
}

impl Factorization {
    /// Object axes `(i, j, k)` of the principal axis's copy.
    pub fn perm(&self) -> [usize; 3] {
        self.layout.permutation(self.axis)
    }

    /// `v`, given per object axis, per role `(i, j, k)` in the principal axis's copy.
    pub fn permute<T: Copy>(&self, v: [T; 3]) -> [T; 3] {
        self.layout.permute(self.axis, v)
    }

    /// Factors the view of `grid` through `camera`.
    pub fn new(grid: &Grid, camera: &Camera) -> Result<Self, Error> {
        check_camera(camera)?;
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
        let dims = grid.permuted_dims(axis);
        let [ni, nj, nk] = dims;
        let [di, dj, dk] = grid.permute(axis, dir);
        let shear = [-di / dk, -dj / dk];
        let kspan = (nk - 1) as f64;
        let translate = shear.map(|s| if s < 0.0 { -s * kspan } else { 0.0 });
        let inter_w = libm::floor((ni - 1) as f64 + libm::fabs(shear[0]) * kspan) as usize + 2;
        let inter_h = libm::floor((nj - 1) as f64 + libm::fabs(shear[1]) * kspan) as usize + 2;

        // Object index point -> image coordinates: linear columns and the image of the
        // permuted origin.
        let (w, h) = (camera.width as f64, camera.height as f64);
        let scale = w.min(h) / grid.frame_diagonal();
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
        let [ci, cj, _] = grid.permute(axis, [unit(0), unit(1), unit(2)]);
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
        let image_to_intermediate = [row(0, translate[0]), row(1, translate[1]), [0.0, 0.0, 1.0]];

        let sp = grid.permute(axis, grid.spacing);
        let step = [shear[0] * sp[0], shear[1] * sp[1], sp[2]];
        let step_len = libm::sqrt(step[0] * step[0] + step[1] * step[1] + step[2] * step[2]);
        Ok(Factorization {
            axis,
            layout: grid.layout(),
            dims,
            shear,
            translate,
            k_increasing: dk > 0.0,
            intermediate: [inter_w, inter_h],
            image: [camera.width, camera.height],
            image_to_intermediate,
            rotation: rot,
            step_ratio: step_len / grid.opacity_unit(),
            supersample: 1,
            perspective: None,
        })
    }

    /// Factors a perspective view (Lacroute 1995, §3.3): the camera of the contract,
    /// moved from infinity to the distance on +Z at which the volume's bounding sphere
    /// just fills `fov_deg` across the shorter image side.
    ///
    /// The principal axis is chosen among the axes whose slab of slices does not contain
    /// the eye, as the one whose rays to the 8 corners are least oblique to it (the thesis
    /// splits the volume when corners disagree; here oblique rays are resampled along the
    /// slices more coarsely instead). Views whose farthest slice would be scaled below
    /// `1/MAX_DECIMATION` are refused.
    pub fn perspective(grid: &Grid, camera: &Camera, fov_deg: f64) -> Result<Self, Error> {
        check_camera(camera)?;
        if !(fov_deg.is_finite() && (1.0..=150.0).contains(&fov_deg)) {
            return Err(Error::BadParameter {
                reason: "field of view must be 1..=150 degrees",
            });
        }
        let rot = rotation(camera.rotate_x, camera.rotate_y);
        let half = fov_deg.to_radians() * 0.5;
        let radius = grid.frame_diagonal() * 0.5;
        let dist = radius / libm::sin(half);
        let (w, h) = (camera.width as f64, camera.height as f64);
        let focal = 0.5 * w.min(h) / libm::tan(half);
        let n = grid.dims.map(|d| (d - 1) as f64);
        // Eye: camera (0, 0, D) in object space is D·(third row of R); then index units.
        let eye_idx: [f64; 3] =
            core::array::from_fn(|a| dist * rot[2][a] / grid.spacing[a] + n[a] * 0.5);
        let mut best: Option<(Axis, f64)> = None;
        for axis in [Axis::Z, Axis::Y, Axis::X] {
            let [_, _, ek] = grid.permute(axis, eye_idx);
            let [_, _, nk] = grid.permute(axis, n);
            if ek > -1e-9 && ek < nk + 1e-9 {
                continue;
            }
            let mut worst = f64::INFINITY;
            for c in 0..8 {
                let corner: [f64; 3] =
                    core::array::from_fn(|a| if c >> a & 1 == 1 { n[a] } else { 0.0 });
                let d: [f64; 3] = core::array::from_fn(|a| libm::fabs(corner[a] - eye_idx[a]));
                let [di, dj, dk] = grid.permute(axis, d);
                worst = worst.min(dk / di.max(dj).max(1e-12));
            }
            if best.is_none_or(|(_, b)| worst > b) {
                best = Some((axis, worst));
            }
        }
        let Some((axis, _)) = best else {
            return Err(Error::BadParameter {
                reason: "the eye lies inside the volume",
            });
        };
        let dims = grid.permuted_dims(axis);
        let [ni, nj, nk] = dims;
        let e = grid.permute(axis, eye_idx);
        let k_increasing = e[2] < 0.0;
        let front = if k_increasing { 0 } else { nk - 1 };
        let back = if k_increasing { nk - 1 } else { 0 };
        let dk = front as f64 - e[2];
        let min_scale = dk / (back as f64 - e[2]);
        if !(min_scale.is_finite() && min_scale * MAX_DECIMATION as f64 >= 1.0) {
            return Err(Error::BadParameter {
                reason: "perspective too strong: the far side of the volume would be over 8 times smaller than the near side (narrow the field of view)",
            });
        }
        // Bounding box of the front and back slices' voxel centres, with one pixel of
        // margin for the reconstruction filter on each side.
        let span = |a: usize, last: usize| -> (f64, f64) {
            let mut lo = f64::INFINITY;
            let mut hi = f64::NEG_INFINITY;
            for s in [1.0, min_scale] {
                for x in [0.0, last as f64] {
                    let u = s * (x - e[a]) + e[a];
                    lo = lo.min(u);
                    hi = hi.max(u);
                }
            }
            (lo, hi)
        };
        let (ulo, uhi) = span(0, ni - 1);
        let (vlo, vhi) = span(1, nj - 1);
        let translate = [1.0 - ulo, 1.0 - vlo];
        let iw = libm::floor(uhi + translate[0]) + 2.0;
        let ih = libm::floor(vhi + translate[1]) + 2.0;
        if !(iw < u16::MAX as f64 && ih < u16::MAX as f64) {
            return Err(Error::BadParameter {
                reason: "perspective view needs an intermediate image over 65534 pixels wide",
            });
        }
        let intermediate = [iw as usize, ih as usize];

        // Image → intermediate: the ray through image point (x, y) has camera direction
        // ((x − w/2)/F, −(y − h/2)/F, −1), object direction Rᵀ·that, index direction
        // divided by the spacing; it meets the front slice at u = e_i + t_i + dk·d_i/d_k.
        let cam_rows = [
            [1.0 / focal, 0.0, -0.5 * w / focal],
            [0.0, -1.0 / focal, 0.5 * h / focal],
            [0.0, 0.0, -1.0],
        ];
        let p = grid.permutation(axis);
        let dir_row = |a: usize| -> [f64; 3] {
            // `p` is a permutation of 0..3; the `min` shows the compiler the index fits.
            let o = p[a].min(2);
            core::array::from_fn(|c| {
                (rot[0][o] * cam_rows[0][c]
                    + rot[1][o] * cam_rows[1][c]
                    + rot[2][o] * cam_rows[2][c])
                    / grid.spacing[o]
            })
        };
        let (di, dj, dkr) = (dir_row(0), dir_row(1), dir_row(2));
        let mut m = [
            core::array::from_fn(|c| (e[0] + translate[0]) * dkr[c] + dk * di[c]),
            core::array::from_fn(|c| (e[1] + translate[1]) * dkr[c] + dk * dj[c]),
            dkr,
        ];
        // Rays reach the slices when d_k has the sign of dk; scale so that W = 1 at the
        // image centre (the central ray always reaches them).
        let wc = dkr[0] * 0.5 * w + dkr[1] * 0.5 * h + dkr[2];
        if !(wc.is_finite() && libm::fabs(wc) > 1e-12 && wc * dk > 0.0) {
            return Err(Error::BadParameter {
                reason: "degenerate perspective view",
            });
        }
        for row in m.iter_mut() {
            for c in row.iter_mut() {
                *c /= wc;
            }
        }

        // Opacity correction: the step between slices along the ray through (u, v) is
        // the index vector (du/dk, dv/dk, 1) with du = u − t_i − e_i, in physical units.
        let sp = grid.permute(axis, grid.spacing);
        let s0 = grid.opacity_unit();
        let ratio_sq = [
            (sp[2] / s0) * (sp[2] / s0),
            (sp[0] / (dk * s0)) * (sp[0] / (dk * s0)),
            translate[0] + e[0],
            (sp[1] / (dk * s0)) * (sp[1] / (dk * s0)),
            translate[1] + e[1],
        ];
        let r2 = |u: f64, v: f64| {
            ratio_sq[0]
                + ratio_sq[1] * (u - ratio_sq[2]) * (u - ratio_sq[2])
                + ratio_sq[3] * (v - ratio_sq[4]) * (v - ratio_sq[4])
        };
        let (uw, vh) = ((iw - 1.0), (ih - 1.0));
        // `max` then `min`: `clamp` panics on an empty range or a NaN bound.
        let r2_min = r2(ratio_sq[2].max(0.0).min(uw), ratio_sq[4].max(0.0).min(vh));
        let r2_max = [(0.0, 0.0), (uw, 0.0), (0.0, vh), (uw, vh)]
            .iter()
            .map(|&(u, v)| r2(u, v))
            .fold(r2_min, f64::max);
        Ok(Factorization {
            axis,
            layout: grid.layout(),
            dims,
            shear: [0.0; 2],
            translate,
            k_increasing,
            intermediate,
            image: [camera.width, camera.height],
            image_to_intermediate: m,
            rotation: rot,
            step_ratio: libm::sqrt(r2_min),
            supersample: 1,
            perspective: Some(Perspective {
                eye: e,
                front,
                min_scale,
                ratio_sq,
                ratio_sq_range: [r2_min, r2_max],
            }),
        })
    }

    /// Scale and position of slice `k` in a perspective view (`None` for parallel).
    pub fn slice_scale(&self, k: usize) -> Option<SliceScale> {
        let p = self.perspective.as_ref()?;
        let scale = (p.front as f64 - p.eye[2]) / (k as f64 - p.eye[2]);
        Some(SliceScale {
            scale,
            origin: [0, 1].map(|a| (1.0 - scale) * p.eye[a] + self.translate[a]),
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
        if self.perspective.is_some() {
            return Err(Error::BadParameter {
                reason: "supersampling applies to parallel projection only",
            });
        }
        self.intermediate = self.intermediate.map(|n| s * n + 1);
        for row in self.image_to_intermediate.iter_mut().take(2) {
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

fn check_camera(camera: &Camera) -> Result<(), Error> {
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
    Ok(())
}

/// Upper bound of the intermediate image's pixel count over all views of `dims`, for
/// sizing buffers at compile time: `max over axes (ni + nk + 1)·(nj + nk + 1)`, the same
/// for either of a copy's layouts.
pub const fn max_intermediate_pixels(dims: [usize; 3]) -> usize {
    let axes = [Axis::X, Axis::Y, Axis::Z];
    let mut best = 0;
    let mut a = 0;
    while a < 3 {
        let d = Layout::CYCLE.permuted_dims(axes[a], dims);
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

    /// Projects object index point `idx` with the perspective camera directly.
    fn project(g: &Grid, c: &Camera, fov: f64, idx: [f64; 3]) -> [f64; 2] {
        let r = rotation(c.rotate_x, c.rotate_y);
        let half = fov.to_radians() / 2.0;
        let dist = g.diagonal() / 2.0 / libm::sin(half);
        let focal = 0.5 * (c.width.min(c.height) as f64) / libm::tan(half);
        let p: [f64; 3] =
            core::array::from_fn(|a| (idx[a] - (g.dims[a] - 1) as f64 * 0.5) * g.spacing[a]);
        let q: [f64; 3] =
            core::array::from_fn(|r_| r[r_][0] * p[0] + r[r_][1] * p[1] + r[r_][2] * p[2]);
        let z = dist - q[2];
        [
            c.width as f64 * 0.5 + focal * q[0] / z,
            c.height as f64 * 0.5 - focal * q[1] / z,
        ]
    }

    #[test]
    fn perspective_shear_scale_and_warp_reproduce_the_camera() {
        let g = Grid::new([17, 23, 31], [1.0, 0.7, 1.6]).unwrap();
        for (rx, ry) in [
            (0.0, 0.0),
            (30.0, 45.0),
            (-70.0, 120.0),
            (90.0, 0.0),
            (10.0, -95.0),
        ] {
            for fov in [10.0, 45.0, 90.0] {
                let c = cam(rx, ry);
                let f = Factorization::perspective(&g, &c, fov).unwrap();
                let p = f.perspective.unwrap();
                assert!(p.min_scale > 0.0 && p.min_scale <= 1.0);
                let perm = f.perm();
                let [ni, nj, nk] = f.dims;
                for (i, j, k) in [
                    (0, 0, 0),
                    (ni - 1, nj - 1, nk - 1),
                    (3, 7, nk / 2),
                    (ni / 2, 1, 2),
                ] {
                    let s = f.slice_scale(k).unwrap();
                    // Where the factorization puts the voxel in the intermediate image.
                    let u = s.scale * i as f64 + s.origin[0];
                    let v = s.scale * j as f64 + s.origin[1];
                    assert!(u > 0.0 && v > 0.0);
                    assert!(
                        u < f.intermediate[0] as f64 - 1.0 && v < f.intermediate[1] as f64 - 1.0
                    );
                    // Where the camera puts it, mapped through the warp.
                    let mut idx = [0.0; 3];
                    idx[perm[0]] = i as f64;
                    idx[perm[1]] = j as f64;
                    idx[perm[2]] = k as f64;
                    let [x, y] = project(&g, &c, fov, idx);
                    let m = f.image_to_intermediate;
                    let h: [f64; 3] = core::array::from_fn(|r| m[r][0] * x + m[r][1] * y + m[r][2]);
                    assert!(h[2] > 0.0);
                    let (wu, wv) = (h[0] / h[2], h[1] / h[2]);
                    assert!(
                        (wu - u).abs() < 1e-6 && (wv - v).abs() < 1e-6,
                        "{rx} {ry} {fov}: ({wu}, {wv}) vs ({u}, {v})"
                    );
                }
                // The front slice has scale one, the back slice the smallest.
                let front = if f.k_increasing { 0 } else { nk - 1 };
                let back = nk - 1 - front;
                assert!((f.slice_scale(front).unwrap().scale - 1.0).abs() < 1e-12);
                assert!((f.slice_scale(back).unwrap().scale - p.min_scale).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn perspective_rejects_bad_fields_of_view_and_narrows_to_parallel() {
        let g = grid([20, 20, 20]);
        for fov in [0.0, -5.0, 151.0, f64::NAN, f64::INFINITY] {
            assert!(
                Factorization::perspective(&g, &cam(0.0, 0.0), fov).is_err(),
                "{fov}"
            );
        }
        // A narrow field of view is nearly parallel: scales close to one.
        let f = Factorization::perspective(&g, &cam(20.0, 30.0), 1.0).unwrap();
        assert!(f.perspective.unwrap().min_scale > 0.97);
        assert!(Factorization::perspective(&g, &cam(0.0, 0.0), 30.0)
            .unwrap()
            .with_supersampling(2)
            .is_err());
    }
}
