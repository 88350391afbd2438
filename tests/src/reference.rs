//! Slow, finely sampled f64 ray caster used as the test oracle for the
//! fixed-point shear-warp renderer. It favours clarity and accuracy over
//! speed; only row-level threading is used so tests stay quick.

use std::sync::Mutex;

/// Scalar volume in f32; `range` maps MIP output to grey (for u8 data 0..255).
#[derive(Clone, Debug)]
pub struct RefVolume {
    pub dims: [usize; 3],
    pub spacing: [f64; 3],
    pub data: Vec<f32>,
    pub range: (f64, f64),
}

/// Phong parameters; light directions are in camera space (z toward viewer).
#[derive(Clone, Debug)]
pub struct RefShading {
    pub ka: f64,
    pub kd: f64,
    pub ks: f64,
    pub shininess: f64,
    pub lights: Vec<[f64; 3]>,
    /// RGB of each light; lights without an entry are white.
    pub light_colors: Vec<[f64; 3]>,
}

/// Piecewise-linear transfer functions over scalar value.
/// Opacity is per unit of the smallest voxel spacing.
#[derive(Clone, Debug)]
pub struct RefTf {
    pub opacity: Vec<(f64, f64)>,
    pub color: Vec<(f64, [f64; 3])>,
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub enum RefMode {
    Composite,
    Mip,
    /// First crossing of this scalar value, shaded with the trilinear gradient there.
    Iso(f64),
}

/// Rotation angles in degrees: Y is applied first, then X.
#[derive(Clone, Debug)]
pub struct RefView {
    pub rotate_x: f64,
    pub rotate_y: f64,
    pub width: usize,
    pub height: usize,
    /// Depth cueing `(front, density)`: colour × front·e^(−density·d), `d` the depth
    /// normalised to 0..1 over the volume's corners.
    pub depth_cue: Option<(f64, f64)>,
    /// Shadows cast toward the first light (needs shading).
    pub shadows: bool,
    /// Perspective field of view in degrees across the shorter side (camera on +Z at
    /// the distance where the bounding sphere fills it), or `None` for orthographic.
    pub fov: Option<f64>,
    /// Crop box `(lo, hi)`, inclusive voxel indices: samples outside its cells
    /// (`[lo − ½, hi + ½]` in index space) are left out, of the rays and of the shadows.
    pub crop: Option<([usize; 3], [usize; 3])>,
    /// Clipping planes `(normal, distance)`: the normal in physical x, y, z, pointing
    /// into the part cut away, the plane at `distance` (physical units) from the
    /// volume's centre along it. Each ray's span ends exactly at the planes (a hard
    /// cut); the shadow march takes no opacity beyond them.
    pub clip: Vec<([f64; 3], f64)>,
    /// Inverse clipping: the region behind every plane is cut away instead of kept.
    /// Rays then skip the samples in it (the region is convex, so that is one interval
    /// of each ray, hard-edged to the step).
    pub clip_inverse: bool,
    /// Thickness, in voxels of the smallest spacing, of the layer along the cut shaded
    /// as its face: samples within it of the nearest plane (on the kept side, or as
    /// far into the part cut away as the renderer's half-voxel ramp reaches) are lit by
    /// that plane's normal instead of the gradient. 0 for none.
    pub clip_face: f64,
}

impl RefVolume {
    pub fn from_u8(dims: [usize; 3], spacing: [f64; 3], data: &[u8]) -> Self {
        assert_eq!(data.len(), dims[0] * dims[1] * dims[2], "data size");
        RefVolume {
            dims,
            spacing,
            data: data.iter().map(|&v| f32::from(v)).collect(),
            range: (0.0, 255.0),
        }
    }

    /// 16-bit data has no canonical range, so the data's own min/max is used.
    pub fn from_u16(dims: [usize; 3], spacing: [f64; 3], data: &[u16]) -> Self {
        assert_eq!(data.len(), dims[0] * dims[1] * dims[2], "data size");
        let range = match (data.iter().min(), data.iter().max()) {
            (Some(&lo), Some(&hi)) => (f64::from(lo), f64::from(hi)),
            _ => (0.0, 0.0),
        };
        RefVolume {
            dims,
            spacing,
            data: data.iter().map(|&v| f32::from(v)).collect(),
            range,
        }
    }

    #[inline]
    fn at(&self, i: usize, j: usize, k: usize) -> f64 {
        f64::from(self.data[i + self.dims[0] * (j + self.dims[1] * k)])
    }

    /// Per-voxel gradient in physical units: central differences inside,
    /// one-sided at the borders, zero along axes of size 1.
    fn voxel_gradient(&self, i: usize, j: usize, k: usize) -> [f64; 3] {
        let idx = [i, j, k];
        let mut g = [0.0; 3];
        for (ax, g_ax) in g.iter_mut().enumerate() {
            let n = self.dims[ax];
            if n < 2 {
                continue;
            }
            let c = idx[ax];
            let (lo, hi) = (c.saturating_sub(1), (c + 1).min(n - 1));
            let mut a = idx;
            let mut b = idx;
            a[ax] = lo;
            b[ax] = hi;
            let dist = (hi - lo) as f64 * self.spacing[ax];
            *g_ax = (self.at(b[0], b[1], b[2]) - self.at(a[0], a[1], a[2])) / dist;
        }
        g
    }
}

/// The 8 voxels and weights for trilinear interpolation at an index-space point.
struct Cell {
    ijk: [[usize; 3]; 8],
    w: [f64; 8],
}

fn cell(dims: [usize; 3], p: [f64; 3]) -> Cell {
    let mut lo = [0usize; 3];
    let mut hi = [0usize; 3];
    let mut fr = [0.0f64; 3];
    for ax in 0..3 {
        let max = (dims[ax] - 1) as f64;
        let f = p[ax].clamp(0.0, max);
        let i0 = (f.floor() as usize).min(dims[ax] - 1);
        lo[ax] = i0;
        hi[ax] = (i0 + 1).min(dims[ax] - 1);
        fr[ax] = f - i0 as f64;
    }
    let mut c = Cell {
        ijk: [[0; 3]; 8],
        w: [0.0; 8],
    };
    for n in 0..8 {
        let mut w = 1.0;
        for ax in 0..3 {
            if n >> ax & 1 == 1 {
                c.ijk[n][ax] = hi[ax];
                w *= fr[ax];
            } else {
                c.ijk[n][ax] = lo[ax];
                w *= 1.0 - fr[ax];
            }
        }
        c.w[n] = w;
    }
    c
}

/// Piecewise-linear lookup; clamps to the end points, empty table gives zeros.
fn lookup<const N: usize>(pts: &[(f64, [f64; N])], v: f64) -> [f64; N] {
    if pts.is_empty() {
        return [0.0; N];
    }
    let idx = pts.partition_point(|p| p.0 <= v);
    if idx == 0 {
        return pts[0].1;
    }
    if idx == pts.len() {
        return pts[pts.len() - 1].1;
    }
    let (a, b) = (pts[idx - 1], pts[idx]);
    let t = (v - a.0) / (b.0 - a.0);
    std::array::from_fn(|c| a.1[c] + t * (b.1[c] - a.1[c]))
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn normalize(a: [f64; 3]) -> [f64; 3] {
    let l = dot(a, a).sqrt();
    if l > 0.0 {
        [a[0] / l, a[1] / l, a[2] / l]
    } else {
        [0.0; 3]
    }
}

fn mat_vec(m: &[[f64; 3]; 3], v: [f64; 3]) -> [f64; 3] {
    [dot(m[0], v), dot(m[1], v), dot(m[2], v)]
}

fn mat_t_vec(m: &[[f64; 3]; 3], v: [f64; 3]) -> [f64; 3] {
    let mut o = [0.0; 3];
    for (r, row) in m.iter().enumerate() {
        for c in 0..3 {
            o[c] += row[c] * v[r];
        }
    }
    o
}

/// R = Rx(rx) · Ry(ry), angles in degrees: the object-to-camera rotation.
fn rotation(rx_deg: f64, ry_deg: f64) -> [[f64; 3]; 3] {
    let (sy, cy) = ry_deg.to_radians().sin_cos();
    let (sx, cx) = rx_deg.to_radians().sin_cos();
    let ry = [[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]];
    let rx = [[1.0, 0.0, 0.0], [0.0, cx, -sx], [0.0, sx, cx]];
    let mut m = [[0.0; 3]; 3];
    for r in 0..3 {
        for c in 0..3 {
            m[r][c] = (0..3).map(|k| rx[r][k] * ry[k][c]).sum();
        }
    }
    m
}

struct Ctx<'a> {
    vol: &'a RefVolume,
    mode: RefMode,
    rot: [[f64; 3]; 3],
    opacity: Vec<(f64, [f64; 1])>,
    color: Vec<(f64, [f64; 3])>,
    shading: Option<&'a RefShading>,
    /// Normalised (L, H) and RGB per light.
    lights: Vec<([f64; 3], [f64; 3], [f64; 3])>,
    /// Index-space change per unit of physical ray length.
    dir_idx: [f64; 3],
    step: f64,
    alpha_exp: f64,
    scale: f64,
    width: usize,
    height: usize,
    /// `(front, density, depth lo, depth hi)` with depth = −z_camera.
    depth_cue: Option<(f64, f64, f64, f64)>,
    /// Transmittance toward the first light at every voxel.
    shadow: Option<Vec<f64>>,
    /// Perspective: (eye distance, focal length in pixels).
    perspective: Option<(f64, f64)>,
    /// The index-space box samples are taken in, per axis: the volume's cells
    /// `[−½, n − ½]`, or the crop box's.
    bounds: [[f64; 2]; 3],
    /// Clipping planes in index space: `(a, b)` with the kept side `a·p ≤ b`.
    planes: Vec<([f64; 3], f64)>,
    /// The planes cut away the region they would keep ([`RefView::clip_inverse`]).
    inverse: bool,
    /// [`RefView::clip_face`] in physical units, and the smallest spacing.
    face: f64,
    smin: f64,
}

impl Ctx<'_> {
    /// Camera-space depth (−z) of an index-space point.
    fn depth(&self, p: [f64; 3]) -> f64 {
        let d = self.vol.dims;
        let s = self.vol.spacing;
        let phys: [f64; 3] = std::array::from_fn(|a| (p[a] - (d[a] as f64 - 1.0) / 2.0) * s[a]);
        -dot(self.rot[2], phys)
    }

    /// Transmittance from voxel `(i, j, k)` toward the first light: post-classified
    /// opacity marched in steps of 0.25·s_min from one step away from the voxel.
    fn transmittance_at(&self, ijk: [usize; 3], to_light_idx: [f64; 3]) -> f64 {
        let d = self.vol.dims;
        let mut t = 1.0;
        let mut p = ijk.map(|c| c as f64);
        loop {
            for a in 0..3 {
                p[a] += to_light_idx[a] * self.step;
            }
            let outside = |a: usize| p[a] < self.bounds[a][0] || p[a] > self.bounds[a][1];
            if (0..3).any(|a| p[a] < 0.0 || p[a] > (d[a] - 1) as f64 || outside(a)) {
                return t;
            }
            if self.clipped(p) {
                continue;
            }
            let v = self.scalar(&cell(d, p));
            let a = lookup(&self.opacity, v)[0].clamp(0.0, 1.0);
            if a > 0.0 {
                t *= (1.0 - a).powf(self.alpha_exp);
                if t < 1e-4 {
                    return 0.0;
                }
            }
        }
    }

    fn shadow_at(&self, c: &Cell) -> f64 {
        match &self.shadow {
            None => 1.0,
            Some(g) => {
                let d = self.vol.dims;
                (0..8)
                    .map(|n| {
                        let [i, j, k] = c.ijk[n];
                        c.w[n] * g[i + d[0] * (j + d[1] * k)]
                    })
                    .sum()
            }
        }
    }

    /// Whether index-space point `p` is cut away: beyond a clipping plane, or inverted,
    /// behind all of them.
    fn clipped(&self, p: [f64; 3]) -> bool {
        if self.inverse {
            !self.planes.is_empty() && self.planes.iter().all(|&(a, b)| dot(a, p) <= b)
        } else {
            self.planes.iter().any(|&(a, b)| dot(a, p) > b)
        }
    }

    /// The normal (physical) a sample at index-space point `p` is shaded by when it
    /// lies in the layer shaded as the cut's face ([`RefView::clip_face`]): the
    /// nearest plane's, the one farthest out. Bounds as the renderer's, in distances
    /// from the plane: −½ − face to ½ voxel kept below it, or, inverted, −½ to ½ + face.
    fn face_normal(&self, p: [f64; 3]) -> Option<[f64; 3]> {
        if self.face <= 0.0 {
            return None;
        }
        let (sigma, a) = self
            .planes
            .iter()
            .map(|&(a, b)| (dot(a, p) - b, a))
            .max_by(|x, y| x.0.total_cmp(&y.0))?;
        let h = 0.5 * self.smin;
        let inside = if self.inverse {
            sigma > -h && sigma < h + self.face
        } else {
            sigma < h && sigma > -h - self.face
        };
        let s = self.vol.spacing;
        inside.then(|| [a[0] / s[0], a[1] / s[1], a[2] / s[2]])
    }

    /// Whether a ray's sample at `p` is cut away by inverse clipping (the span already
    /// leaves out what planes cut away otherwise).
    fn skipped(&self, p: [f64; 3]) -> bool {
        self.inverse && self.clipped(p)
    }

    fn to_index(&self, p: [f64; 3]) -> [f64; 3] {
        let d = self.vol.dims;
        let s = self.vol.spacing;
        [
            p[0] / s[0] + (d[0] as f64 - 1.0) / 2.0,
            p[1] / s[1] + (d[1] as f64 - 1.0) / 2.0,
            p[2] / s[2] + (d[2] as f64 - 1.0) / 2.0,
        ]
    }

    /// Parametric span [t0, t1] (physical length) of `origin + t·dir_idx`
    /// inside the index box, by the slab method.
    fn span(&self, origin: [f64; 3], dir_idx: [f64; 3]) -> Option<(f64, f64)> {
        const EPS: f64 = 1e-9;
        let mut t0 = f64::NEG_INFINITY;
        let mut t1 = f64::INFINITY;
        // Each voxel is a unit cell: the volume spans [−0.5, n − 0.5] in index space (a
        // crop box [lo − 0.5, hi + 0.5]), the field is extended to the faces by clamping
        // (as the shear-warp slices, one voxel thick, and their bilinear footprint do).
        for ((&a, &b), &[lo, hi]) in origin.iter().zip(&dir_idx).zip(&self.bounds) {
            if b.abs() < 1e-12 {
                if a < lo - EPS || a > hi + EPS {
                    return None;
                }
            } else {
                let ta = (lo - a) / b;
                let tb = (hi - a) / b;
                t0 = t0.max(ta.min(tb));
                t1 = t1.min(ta.max(tb));
            }
        }
        // Each plane `a·(origin + t·dir) ≤ b` bounds t on one side (inverted, the
        // samples are skipped one by one instead).
        for &(a, b) in self.planes.iter().filter(|_| !self.inverse) {
            let (at, slope) = (dot(a, origin), dot(a, dir_idx));
            if slope.abs() < 1e-12 {
                if at > b + EPS {
                    return None;
                }
            } else if slope > 0.0 {
                t1 = t1.min((b - at) / slope);
            } else {
                t0 = t0.max((b - at) / slope);
            }
        }
        (t0 <= t1 + EPS && t0.is_finite() && t1.is_finite()).then_some((t0, t1.max(t0)))
    }

    fn scalar(&self, c: &Cell) -> f64 {
        (0..8)
            .map(|n| c.w[n] * self.vol.at(c.ijk[n][0], c.ijk[n][1], c.ijk[n][2]))
            .sum()
    }

    fn gradient(&self, c: &Cell) -> [f64; 3] {
        let mut g = [0.0; 3];
        for n in 0..8 {
            if c.w[n] == 0.0 {
                continue;
            }
            let v = self
                .vol
                .voxel_gradient(c.ijk[n][0], c.ijk[n][1], c.ijk[n][2]);
            for ax in 0..3 {
                g[ax] += c.w[n] * v[ax];
            }
        }
        g
    }

    /// `t0` scales the first light (its shadow transmittance).
    fn shade(&self, sh: &RefShading, col: [f64; 3], g: [f64; 3], t0: f64) -> [f64; 3] {
        let len = dot(g, g).sqrt();
        let lt = |i: usize| if i == 0 { t0 } else { 1.0 };
        let mut d = [sh.ka; 3];
        let mut s = [0.0; 3];
        if len < 1e-9 {
            for (i, (_, _, c)) in self.lights.iter().enumerate() {
                for ch in 0..3 {
                    d[ch] += lt(i) * sh.kd * c[ch];
                }
            }
        } else {
            let n_obj = [-g[0] / len, -g[1] / len, -g[2] / len];
            let n = mat_vec(&self.rot, n_obj);
            for (i, (l, h, c)) in self.lights.iter().enumerate() {
                let diff = lt(i) * sh.kd * dot(n, *l).abs();
                let spec = lt(i) * sh.ks * dot(n, *h).abs().powf(sh.shininess);
                for ch in 0..3 {
                    d[ch] += diff * c[ch];
                    s[ch] += spec * c[ch];
                }
            }
        }
        [0, 1, 2].map(|ch| (col[ch] * d[ch] + s[ch]).min(1.0))
    }

    fn pixel(&self, px: usize, py: usize) -> [f64; 3] {
        let (origin, dir_idx) = match self.perspective {
            None => {
                let x = (px as f64 + 0.5 - self.width as f64 / 2.0) / self.scale;
                let y = (self.height as f64 / 2.0 - (py as f64 + 0.5)) / self.scale;
                (
                    self.to_index(mat_t_vec(&self.rot, [x, y, 0.0])),
                    self.dir_idx,
                )
            }
            Some((dist, focal)) => {
                let d = normalize([
                    (px as f64 + 0.5 - self.width as f64 / 2.0) / focal,
                    (self.height as f64 / 2.0 - (py as f64 + 0.5)) / focal,
                    -1.0,
                ]);
                let o = mat_t_vec(&self.rot, d);
                let s = self.vol.spacing;
                (
                    self.to_index(mat_t_vec(&self.rot, [0.0, 0.0, dist])),
                    [o[0] / s[0], o[1] / s[1], o[2] / s[2]],
                )
            }
        };
        let Some((t0, t1)) = self.span(origin, dir_idx) else {
            return [0.0; 3];
        };
        // Midpoint rule: `count` equal steps of about `self.step` cover [t0, t1] exactly.
        let count = ((t1 - t0) / self.step).round().max(1.0) as usize;
        let step = (t1 - t0) / count as f64;
        let alpha_exp = self.alpha_exp * step / self.step;
        let point = |k: usize| {
            let t = t0 + (k as f64 + 0.5) * step;
            [
                origin[0] + t * dir_idx[0],
                origin[1] + t * dir_idx[1],
                origin[2] + t * dir_idx[2],
            ]
        };
        match self.mode {
            RefMode::Iso(iso) => {
                let mut prev: Option<([f64; 3], f64)> = None;
                for k in 0..count {
                    let p = point(k);
                    if self.skipped(p) {
                        prev = None;
                        continue;
                    }
                    let v = self.scalar(&cell(self.vol.dims, p));
                    if let Some((pp, pv)) = prev {
                        if (pv - iso) * (v - iso) <= 0.0 && pv != v {
                            let t = (iso - pv) / (v - pv);
                            let x: [f64; 3] = std::array::from_fn(|a| pp[a] + t * (p[a] - pp[a]));
                            let c = cell(self.vol.dims, x);
                            let col = lookup(&self.color, iso);
                            return match self.shading {
                                Some(sh) => self.shade(sh, col, self.gradient(&c), 1.0),
                                None => col,
                            };
                        }
                    }
                    prev = Some((p, v));
                }
                [0.0; 3]
            }
            RefMode::Mip => {
                let mut max = f64::NEG_INFINITY;
                for k in (0..count).filter(|&k| !self.skipped(point(k))) {
                    max = max.max(self.scalar(&cell(self.vol.dims, point(k))));
                }
                let (lo, hi) = self.vol.range;
                // A degenerate range cannot be normalised; report black.
                let g = if hi > lo { (max - lo) / (hi - lo) } else { 0.0 };
                let g = g.clamp(0.0, 1.0);
                [g; 3]
            }
            RefMode::Composite => {
                let mut acc = [0.0f64; 3];
                let mut acc_a = 0.0f64;
                for k in 0..count {
                    if self.skipped(point(k)) {
                        continue;
                    }
                    let c = cell(self.vol.dims, point(k));
                    let v = self.scalar(&c);
                    let a = lookup(&self.opacity, v)[0].clamp(0.0, 1.0);
                    if a <= 0.0 {
                        continue;
                    }
                    let a_s = 1.0 - (1.0 - a).powf(alpha_exp);
                    let mut col = lookup(&self.color, v);
                    if let Some(sh) = self.shading {
                        let g = self
                            .face_normal(point(k))
                            .unwrap_or_else(|| self.gradient(&c));
                        col = self.shade(sh, col, g, self.shadow_at(&c));
                    }
                    if let Some((front, density, lo, hi)) = self.depth_cue {
                        let d = if hi > lo {
                            (self.depth(point(k)) - lo) / (hi - lo)
                        } else {
                            0.0
                        };
                        let f = front * (-density * d).exp();
                        col = col.map(|x| x * f);
                    }
                    let w = (1.0 - acc_a) * a_s;
                    for ch in 0..3 {
                        acc[ch] += w * col[ch];
                    }
                    acc_a += w;
                    if acc_a > 0.999 {
                        break;
                    }
                }
                acc.map(|v| v.clamp(0.0, 1.0))
            }
        }
    }
}

/// Returns width*height pixels, row 0 at top, linear RGB in 0..1.
pub fn render_reference(
    vol: &RefVolume,
    tf: &RefTf,
    shading: Option<&RefShading>,
    mode: RefMode,
    view: &RefView,
) -> Vec<[f64; 3]> {
    let [nx, ny, nz] = vol.dims;
    assert!(nx > 0 && ny > 0 && nz > 0, "empty volume");
    assert_eq!(vol.data.len(), nx * ny * nz, "data size");
    let (w, h) = (view.width, view.height);
    let mut out = vec![[0.0; 3]; w * h];
    if w == 0 || h == 0 {
        return out;
    }

    let s = vol.spacing;
    let smin = s[0].min(s[1]).min(s[2]);
    let step = 0.25 * smin;
    let diag =
        ((nx as f64 * s[0]).powi(2) + (ny as f64 * s[1]).powi(2) + (nz as f64 * s[2]).powi(2))
            .sqrt();
    let rot = rotation(view.rotate_x, view.rotate_y);
    let d_obj = mat_t_vec(&rot, [0.0, 0.0, -1.0]);

    let mut opacity: Vec<(f64, [f64; 1])> = tf.opacity.iter().map(|&(v, a)| (v, [a])).collect();
    let mut color = tf.color.clone();
    opacity.sort_by(|a, b| a.0.total_cmp(&b.0));
    color.sort_by(|a, b| a.0.total_cmp(&b.0));

    let lights = shading
        .map(|sh| {
            sh.lights
                .iter()
                .enumerate()
                .map(|(i, &l)| {
                    let l = normalize(l);
                    let c = sh.light_colors.get(i).copied().unwrap_or([1.0; 3]);
                    (l, normalize([l[0], l[1], l[2] + 1.0]), c)
                })
                .collect()
        })
        .unwrap_or_default();

    let depth_cue = view.depth_cue.map(|(front, density)| {
        let mut lo = f64::INFINITY;
        let mut hi = f64::NEG_INFINITY;
        for c in 0..8 {
            let phys: [f64; 3] = std::array::from_fn(|a| {
                let n = vol.dims[a] as f64 - 1.0;
                (if c >> a & 1 == 1 { n / 2.0 } else { -n / 2.0 }) * s[a]
            });
            let z = -dot(rot[2], phys);
            lo = lo.min(z);
            hi = hi.max(z);
        }
        (front, density, lo, hi)
    });
    let mut ctx = Ctx {
        depth_cue,
        shadow: None,
        vol,
        mode,
        rot,
        opacity,
        color,
        shading,
        lights,
        dir_idx: [d_obj[0] / s[0], d_obj[1] / s[1], d_obj[2] / s[2]],
        step,
        alpha_exp: step / smin,
        scale: w.min(h) as f64 / diag,
        width: w,
        height: h,
        bounds: std::array::from_fn(|a| match view.crop {
            Some((lo, hi)) => [lo[a] as f64 - 0.5, hi[a] as f64 + 0.5],
            None => [-0.5, vol.dims[a] as f64 - 0.5],
        }),
        // n̂·((p − c)⊙s) ≤ d, with c the centre voxel, as `a·p ≤ b`.
        planes: view
            .clip
            .iter()
            .map(|&(n, dist)| {
                let n = normalize(n);
                let a: [f64; 3] = std::array::from_fn(|i| n[i] * s[i]);
                let c: [f64; 3] = std::array::from_fn(|i| (vol.dims[i] as f64 - 1.0) / 2.0);
                (a, dist + dot(a, c))
            })
            .collect(),
        inverse: view.clip_inverse,
        face: view.clip_face * smin,
        smin,
        perspective: view.fov.map(|fov| {
            let half = fov.to_radians() / 2.0;
            (0.5 * diag / half.sin(), 0.5 * w.min(h) as f64 / half.tan())
        }),
    };

    let threads = std::thread::available_parallelism()
        .map_or(1, |n| n.get())
        .min(h);
    if view.shadows && !ctx.lights.is_empty() {
        // Direction toward the first light, in index units per unit physical length.
        let l_obj = mat_t_vec(&rot, ctx.lights[0].0);
        let to_light = [l_obj[0] / s[0], l_obj[1] / s[1], l_obj[2] / s[2]];
        let [nx, ny, nz] = vol.dims;
        let mut grid = vec![0.0; nx * ny * nz];
        let planes = Mutex::new(grid.chunks_mut(nx * ny).enumerate());
        let c = &ctx;
        std::thread::scope(|scope| {
            for _ in 0..threads.max(1) {
                scope.spawn(|| loop {
                    let next = planes.lock().unwrap().next();
                    let Some((k, plane)) = next else { break };
                    for j in 0..ny {
                        for i in 0..nx {
                            plane[i + nx * j] = c.transmittance_at([i, j, k], to_light);
                        }
                    }
                });
            }
        });
        ctx.shadow = Some(grid);
    }
    // Rows are handed out one at a time so uneven rows balance across threads.
    let rows = Mutex::new(out.chunks_mut(w).enumerate());
    std::thread::scope(|scope| {
        for _ in 0..threads {
            scope.spawn(|| loop {
                let next = rows.lock().unwrap().next();
                let Some((py, row)) = next else { break };
                for (px, p) in row.iter_mut().enumerate() {
                    *p = ctx.pixel(px, py);
                }
            });
        }
    });
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn vol_from_fn(dims: [usize; 3], f: impl Fn(usize, usize, usize) -> u8) -> Vec<u8> {
        let mut v = Vec::with_capacity(dims[0] * dims[1] * dims[2]);
        for k in 0..dims[2] {
            for j in 0..dims[1] {
                for i in 0..dims[0] {
                    v.push(f(i, j, k));
                }
            }
        }
        v
    }

    fn opaque_tf(threshold: f64, rgb: [f64; 3]) -> RefTf {
        RefTf {
            opacity: vec![(threshold - 1.0, 0.0), (threshold, 1.0)],
            color: vec![(0.0, rgb)],
        }
    }

    fn view(rx: f64, ry: f64, w: usize, h: usize) -> RefView {
        RefView {
            rotate_x: rx,
            rotate_y: ry,
            width: w,
            height: h,
            depth_cue: None,
            shadows: false,
            fov: None,
            crop: None,
            clip: Vec::new(),
            clip_inverse: false,
            clip_face: 0.0,
        }
    }

    fn close(a: [f64; 3], b: [f64; 3], tol: f64) -> bool {
        (0..3).all(|c| (a[c] - b[c]).abs() <= tol)
    }

    /// Mean brightness of the image's left and right halves, top and bottom halves.
    fn halves(img: &[[f64; 3]], w: usize, h: usize) -> (f64, f64, f64, f64) {
        let (mut l, mut r, mut t, mut b) = (0.0, 0.0, 0.0, 0.0);
        for py in 0..h {
            for px in 0..w {
                let v = img[py * w + px][0];
                if px < w / 2 {
                    l += v
                } else {
                    r += v
                }
                if py < h / 2 {
                    t += v
                } else {
                    b += v
                }
            }
        }
        let n = (w * h / 2) as f64;
        (l / n, r / n, t / n, b / n)
    }

    #[test]
    fn rotation_matrix_conventions() {
        let r = rotation(0.0, 90.0);
        assert!(close(mat_vec(&r, [1.0, 0.0, 0.0]), [0.0, 0.0, -1.0], 1e-12));
        let r = rotation(90.0, 0.0);
        assert!(close(mat_vec(&r, [0.0, 1.0, 0.0]), [0.0, 0.0, 1.0], 1e-12));
        // Y first, then X: +x -> -z -> +y.
        let r = rotation(90.0, 90.0);
        assert!(close(mat_vec(&r, [1.0, 0.0, 0.0]), [0.0, 1.0, 0.0], 1e-12));
    }

    #[test]
    fn lookup_clamps_and_interpolates() {
        let t = [(10.0, [0.0]), (20.0, [1.0]), (20.0, [0.5]), (30.0, [0.0])];
        assert_eq!(lookup(&t, 0.0)[0], 0.0);
        assert_eq!(lookup(&t, 15.0)[0], 0.5);
        assert_eq!(lookup(&t, 25.0)[0], 0.25);
        assert_eq!(lookup(&t, 99.0)[0], 0.0);
    }

    #[test]
    fn trilinear_midpoint_and_gradient() {
        let dims = [2, 2, 2];
        let data = vol_from_fn(dims, |i, j, k| (10 * i + 20 * j + 40 * k) as u8);
        let vol = RefVolume::from_u8(dims, [1.0, 2.0, 4.0], &data);
        let c = cell(dims, [0.5, 0.5, 0.5]);
        let v: f64 = (0..8)
            .map(|n| c.w[n] * vol.at(c.ijk[n][0], c.ijk[n][1], c.ijk[n][2]))
            .sum();
        assert!((v - 35.0).abs() < 1e-12);
        // One-sided differences at size-2 borders, in physical units.
        assert_eq!(vol.voxel_gradient(0, 1, 1), [10.0, 10.0, 10.0]);
    }

    #[test]
    fn opaque_slab_head_on_has_tf_colour() {
        let dims = [16, 12, 10];
        let data = vol_from_fn(dims, |_, _, k| if (3..7).contains(&k) { 200 } else { 0 });
        let vol = RefVolume::from_u8(dims, [1.0; 3], &data);
        let rgb = [0.2, 0.4, 0.6];
        let tf = opaque_tf(200.0, rgb);
        let (w, h) = (40, 40);
        let img = render_reference(&vol, &tf, None, RefMode::Composite, &view(0.0, 0.0, w, h));
        assert!(close(img[20 * w + 20], rgb, 1e-9), "{:?}", img[20 * w + 20]);
        // Outside the footprint the background stays black.
        assert_eq!(img[0], [0.0; 3]);
        assert_eq!(img[w * h - 1], [0.0; 3]);
    }

    #[test]
    fn semi_transparent_thickness_uses_corrected_alpha() {
        let dims = [8, 8, 9];
        let data = vec![100u8; 8 * 8 * 9];
        let vol = RefVolume::from_u8(dims, [1.0; 3], &data);
        let a = 0.05;
        let tf = RefTf {
            opacity: vec![(0.0, a)],
            color: vec![(0.0, [1.0; 3])],
        };
        let img = render_reference(&vol, &tf, None, RefMode::Composite, &view(0.0, 0.0, 32, 32));
        // 9 voxels deep (unit cells, [−0.5, 8.5]): 9 units of path.
        let expect = 1.0 - (1.0 - a).powf(9.0);
        let got = img[16 * 32 + 16][0];
        assert!((got - expect).abs() < 1e-9, "got {got}, expected {expect}");
    }

    #[test]
    fn rotate_y_90_moves_plus_x_to_back() {
        let dims = [16, 16, 16];
        let data = vol_from_fn(dims, |i, _, _| if i >= 8 { 255 } else { 0 });
        let vol = RefVolume::from_u8(dims, [1.0; 3], &data);
        let tf = opaque_tf(128.0, [1.0; 3]);
        let (w, h) = (32, 32);
        let img0 = render_reference(&vol, &tf, None, RefMode::Composite, &view(0.0, 0.0, w, h));
        let (l, r, _, _) = halves(&img0, w, h);
        assert!(l < 1e-12 && r > 0.3, "ry=0: l={l} r={r}");
        // At ry=90 +x faces away, so every ray through the volume reaches it.
        let img90 = render_reference(&vol, &tf, None, RefMode::Composite, &view(0.0, 90.0, w, h));
        let (l, r, _, _) = halves(&img90, w, h);
        assert!(l > 0.3 && (l - r).abs() < 1e-9, "ry=90: l={l} r={r}");
        for py in 10..22 {
            for px in 10..22 {
                assert!(close(img90[py * w + px], [1.0; 3], 1e-9));
            }
        }
    }

    #[test]
    fn rotation_signs_and_order() {
        let dims = [16, 16, 16];
        let tf = opaque_tf(128.0, [1.0; 3]);
        let (w, h) = (32, 32);
        let plus_z = vol_from_fn(dims, |_, _, k| if k >= 8 { 255 } else { 0 });
        let vz = RefVolume::from_u8(dims, [1.0; 3], &plus_z);
        // Ry(+90) sends +z to +x: right half lit.
        let img = render_reference(&vz, &tf, None, RefMode::Composite, &view(0.0, 90.0, w, h));
        let (l, r, _, _) = halves(&img, w, h);
        assert!(l < 1e-12 && r > 0.3, "ry=90: l={l} r={r}");
        let img = render_reference(&vz, &tf, None, RefMode::Composite, &view(0.0, -90.0, w, h));
        let (l, r, _, _) = halves(&img, w, h);
        assert!(r < 1e-12 && l > 0.3, "ry=-90: l={l} r={r}");
        // Rx(+90) sends +z to -y: bottom half lit.
        let img = render_reference(&vz, &tf, None, RefMode::Composite, &view(90.0, 0.0, w, h));
        let (_, _, t, b) = halves(&img, w, h);
        assert!(t < 1e-12 && b > 0.3, "rx=90: t={t} b={b}");
        // Y then X: +x -> -z -> +y, so the top half is lit.
        let plus_x = vol_from_fn(dims, |i, _, _| if i >= 8 { 255 } else { 0 });
        let vx = RefVolume::from_u8(dims, [1.0; 3], &plus_x);
        let img = render_reference(&vx, &tf, None, RefMode::Composite, &view(90.0, 90.0, w, h));
        let (_, _, t, b) = halves(&img, w, h);
        assert!(b < 1e-12 && t > 0.3, "rx=ry=90: t={t} b={b}");
    }

    #[test]
    fn mip_of_constant_volume() {
        let dims = [10, 12, 14];
        let data = vec![100u8; 10 * 12 * 14];
        let vol = RefVolume::from_u8(dims, [1.0, 1.0, 2.0], &data);
        let tf = opaque_tf(1.0, [1.0; 3]);
        let (w, h) = (24, 24);
        let img = render_reference(&vol, &tf, None, RefMode::Mip, &view(30.0, 40.0, w, h));
        assert!(close(img[12 * w + 12], [100.0 / 255.0; 3], 1e-6));
        assert_eq!(img[0], [0.0; 3]);
        let data16 = vec![7u16, 300, 300, 300, 300, 300, 300, 300];
        let v16 = RefVolume::from_u16([2, 2, 2], [1.0; 3], &data16);
        assert_eq!(v16.range, (7.0, 300.0));
    }

    #[test]
    fn shading_uses_rotated_gradient() {
        // Linear ramp in k: gradient +z everywhere, so n = -z in object space.
        let dims = [12, 12, 12];
        let data = vol_from_fn(dims, |_, _, k| (20 * k) as u8);
        let vol = RefVolume::from_u8(dims, [1.0; 3], &data);
        let c = 0.5;
        let tf = RefTf {
            opacity: vec![(0.0, 1.0)],
            color: vec![(0.0, [c; 3])],
        };
        let mut sh = RefShading {
            ka: 0.1,
            kd: 0.5,
            ks: 0.2,
            shininess: 8.0,
            lights: vec![[0.0, 0.0, 2.0]],
            light_colors: vec![],
        };
        let (w, h) = (24, 24);
        let centre = |sh: &RefShading, ry: f64| {
            render_reference(
                &vol,
                &tf,
                Some(sh),
                RefMode::Composite,
                &view(0.0, ry, w, h),
            )[12 * w + 12][0]
        };
        let head_on = c * (sh.ka + sh.kd) + sh.ks;
        assert!((centre(&sh, 0.0) - head_on).abs() < 1e-9);
        sh.lights = vec![[1.0, 0.0, 0.0]];
        let grazing = c * sh.ka + sh.ks * 0.5f64.sqrt().powf(sh.shininess);
        assert!((centre(&sh, 0.0) - grazing).abs() < 1e-9);
        // Ry(90) turns n into -x in camera space: the +x light hits it fully.
        let turned = c * (sh.ka + sh.kd) + sh.ks * 0.5f64.sqrt().powf(sh.shininess);
        assert!((centre(&sh, 90.0) - turned).abs() < 1e-9);
        // Flat field: no normal, so ambient plus full diffuse without specular.
        let flat = RefVolume::from_u8(dims, [1.0; 3], &vec![50u8; 12 * 12 * 12]);
        let px = render_reference(
            &flat,
            &tf,
            Some(&sh),
            RefMode::Composite,
            &view(0.0, 0.0, w, h),
        );
        assert!((px[12 * w + 12][0] - c * (sh.ka + sh.kd)).abs() < 1e-9);
    }

    #[test]
    fn anisotropic_spacing_keeps_footprint_centred() {
        let dims = [8, 8, 8];
        let data = vec![255u8; 512];
        let vol = RefVolume::from_u8(dims, [1.0, 1.0, 3.0], &data);
        let tf = opaque_tf(128.0, [1.0; 3]);
        let (w, h) = (30, 30);
        let img = render_reference(&vol, &tf, None, RefMode::Composite, &view(0.0, 0.0, w, h));
        // Footprint is symmetric about the image centre.
        for py in 0..h {
            for px in 0..w {
                let a = img[py * w + px][0];
                let b = img[(h - 1 - py) * w + (w - 1 - px)][0];
                assert!((a - b).abs() < 1e-12);
            }
        }
        // Rotated 90 about Y, the long z extent lies along X: wider than tall.
        let img = render_reference(&vol, &tf, None, RefMode::Composite, &view(0.0, 90.0, w, h));
        let row: usize = (0..w).filter(|&px| img[15 * w + px][0] > 0.5).count();
        let col: usize = (0..h).filter(|&py| img[py * w + 15][0] > 0.5).count();
        assert!(row > 2 * col, "row {row} col {col}");
    }
}
