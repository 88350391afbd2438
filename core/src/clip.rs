//! Clipping planes: up to six half-spaces, in any orientation, outside which the volume
//! is left out.
//!
//! A crop box ([`crate::crop`]) cuts along the volume's axes; a plane cuts along the
//! anatomy (an oblique cut through the skull, a slab along an organ's axis). Lacroute
//! sketches clipping planes for shear-warp and leaves them unbuilt (1995, §7.5); he
//! also notes that a hard cut aliases, and asks for opacity to fall off on a smooth
//! ramp a few voxels wide at the plane. The ramp here is one voxel (of the smallest
//! spacing) wide, which the slices' bilinear resampling spreads over two: enough that
//! the cut face does not alias (it matches the reference's exact cut to 37 dB), while
//! keeping the face as sharp as the data's own edges. In integers:
//! - a plane is kept as the signed distance from it, in units of the grid's smallest
//!   spacing, as an affine function of the voxel index (`σ(p) = q·p − r`, Q16);
//! - a point's *coverage* is `clamp(½ − σ, 0, 1)`: 1 a half voxel inside, 0 a half
//!   voxel outside, and the smallest over the planes;
//! - classified volumes scale each voxel's opacity by its coverage as they are
//!   classified ([`Clip::apply`]), so the voxels beyond the plane become transparent and
//!   the run-length encoding drops them (a clipped frame costs less, never more), and
//!   the voxels the plane crosses fade with the part of their cell it leaves. The cut
//!   face is then a plane to within the bilinear samples' resolution, not a staircase of
//!   voxels;
//! - a classified volume encoded without them can also be cut as its slices are
//!   composited ([`crate::render::Settings::clip`]), the way Lacroute designs it: along
//!   each voxel row the planes become loop bounds ([`SliceCut::row`] steps each plane's
//!   σ from row to row and splits the row into voxels kept whole, dropped, and on a
//!   ramp), and the compositor zeroes the dropped voxels and scales the ramp's
//!   premultiplied colours once a row is shaded ([`RowCut::apply`]). The image is the
//!   baked cut's to within the rounding of scaling after shading instead of before,
//!   and moving a plane costs no encoding;
//! - unclassified volumes scale each sample's opacity by the coverage at the sample
//!   ([`Clip::coverage`]), per frame, so moving a plane costs nothing there.
//!
//! Planes are given in physical space, relative to the volume's centre, so one plane
//! means the same cut on every level of detail of a volume ([`crate::lod`] keeps the
//! centre and scales the spacing).

use crate::classify::{Grid, Voxel};
use crate::error::Error;

/// Most planes a [`Clip`] holds: six, enough for any convex cut a box can make.
pub const MAX_PLANES: usize = 6;

/// Q16 fixed point: 1.0.
const Q16: i64 = 1 << 16;

/// Largest ratio between a grid's largest and smallest spacing a plane accepts, so that
/// the Q16 coefficients stay far inside `i64` (`4096` voxels × `2^16` × `2^16`).
const MAX_ANISOTROPY: f64 = 65536.0;

/// Thickest layer [`Clip::with_shaded_face`] takes, in voxels: beyond a few voxels
/// the layer no longer reads as the cut's face but as a slab painted over the data.
pub const MAX_FACE: f64 = 16.0;

/// One half-space: signed distance `σ(p) = q·p / 2^frac − r` (Q16, units of the
/// grid's smallest spacing) at index-space position `p`; kept where `σ ≤ 0`. `code` is
/// its normal's ([`crate::normal`]), in object space, for shading its face.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct Plane {
    q: [i64; 3],
    r: i64,
    code: u16,
}

/// Up to [`MAX_PLANES`] clipping planes for one grid (a volume, or a level of one).
/// [`Clip::NONE`] keeps everything.
///
/// The planes keep the region behind all of them (each normal points into a part cut
/// away). [`Clip::inverted`] keeps the rest instead: the region behind all the planes
/// is what is cut away, so that a few planes take a wedge or a corner out of a volume
/// and leave the rest of it around the hole as context (inverse clipping,
/// Rezk-Salama 2001, §9.2).
///
/// With [`Clip::with_shaded_face`], the voxels in a thin layer along the cut are shaded
/// as the cut's face, by the nearest plane's normal instead of their own gradient.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Clip {
    planes: [Plane; MAX_PLANES],
    len: usize,
    inverse: bool,
    /// Thickness of the layer shaded as the face, Q16 units of the smallest spacing
    /// beyond the ramp; 0 for none.
    face: i64,
}

impl Default for Clip {
    fn default() -> Self {
        Clip::NONE
    }
}

impl Clip {
    /// No planes: every voxel kept.
    pub const NONE: Clip = Clip {
        planes: [Plane {
            q: [0; 3],
            r: 0,
            code: 0,
        }; MAX_PLANES],
        len: 0,
        inverse: false,
        face: 0,
    };

    /// This clip and one more plane, for a volume of `grid`: the plane at signed
    /// distance `distance` (physical units, as the spacing) from the volume's centre
    /// along `normal` (physical x, y, z; any length but zero), which points into the
    /// part cut away. Distance 0 halves the volume; a distance beyond the volume's
    /// extent keeps all of it (or none, negated).
    pub fn with_plane(self, grid: &Grid, normal: [f64; 3], distance: f64) -> Result<Clip, Error> {
        let bad = |reason| Err(Error::BadParameter { reason });
        if self.len >= MAX_PLANES {
            return bad("clip: more than six planes");
        }
        let len = length(normal);
        if !(len.is_finite() && len > 1e-12) {
            return bad("clip: a plane's normal is zero or not finite");
        }
        if !distance.is_finite() {
            return bad("clip: a plane's distance is not finite");
        }
        let s = grid.spacing;
        let smin = s[0].min(s[1]).min(s[2]);
        if s[0].max(s[1]).max(s[2]) / smin > MAX_ANISOTROPY {
            return bad("clip: voxel spacing too anisotropic for a clipping plane");
        }
        // σ(p) = (n̂·((p − c)⊙s) − d) / s_min, with c the centre voxel (dims − 1)/2.
        let n = normal.map(|v| v / len);
        let coef: [f64; 3] = core::array::from_fn(|a| n[a] * s[a] / smin);
        let centre: f64 = (0..3)
            .map(|a| coef[a] * (grid.dims[a] as f64 - 1.0) / 2.0)
            .sum();
        // Beyond 2^31 smallest spacings a plane is far outside any volume either way.
        let lim = (1u64 << 31) as f64;
        let r = (centre + (distance / smin).clamp(-lim, lim)) * Q16 as f64;
        let mut out = self;
        out.planes[self.len] = Plane {
            q: coef.map(|c| libm::round(c * Q16 as f64) as i64),
            r: libm::round(r) as i64,
            // The gradients the classifier encodes are physical, as `n` is.
            code: crate::normal::encode(
                libm::round(n[0] * (1 << 20) as f64) as i64,
                libm::round(n[1] * (1 << 20) as f64) as i64,
                libm::round(n[2] * (1 << 20) as f64) as i64,
            ),
        };
        out.len += 1;
        Ok(out)
    }

    /// This clip with the cut's face shaded as a surface: voxels within `thickness`
    /// voxels (of the smallest spacing, `0..=`[`MAX_FACE`]) of the cut, on its kept
    /// side, and those on its ramp, are shaded by the normal of the plane nearest them
    /// rather than by their gradient; 0 shades them by their gradient, as without.
    ///
    /// Why: a cut exposes the inside of tissue, where the data is nearly flat and its
    /// gradient is noise or nothing, so the face comes out mottled, or evenly bright
    /// (flat voxels have no direction to be lit from) and hard to read as a plane.
    /// Lacroute suggests a special shading at the cut (1995, §7.5); shading a layer by
    /// the clipping surface's normal is Weiskopf, Engel and Ertl's (2003), which
    /// Rezk-Salama's clipping chapter builds on. The face is then lit as the plane it
    /// is, and still shows the classified colours of what it cuts.
    pub fn with_shaded_face(self, thickness: f64) -> Result<Clip, Error> {
        if !(0.0..=MAX_FACE).contains(&thickness) {
            return Err(Error::BadParameter {
                reason: "clip: face thickness is not between 0 and 16 voxels",
            });
        }
        Ok(Clip {
            face: libm::round(thickness * Q16 as f64) as i64,
            ..self
        })
    }

    /// Whether some voxels are shaded as the cut's face: planes, and a layer for them.
    pub fn shades_face(&self) -> bool {
        self.face > 0 && !self.is_empty()
    }

    /// The thickness of the layer shaded as the cut's face, in voxels; 0 for none.
    pub fn face_thickness(&self) -> f64 {
        self.face as f64 / Q16 as f64
    }

    /// Whether `sigma`, the largest σ over the planes at a voxel, puts the voxel in the
    /// layer shaded as the face ([`Clip::with_shaded_face`]): on the ramp, or kept and
    /// within the layer's thickness of it.
    fn in_face(inverse: bool, face: i64, sigma: i64) -> bool {
        face > 0
            && if inverse {
                sigma > -Q16 / 2 && sigma < Q16 / 2 + face
            } else {
                sigma < Q16 / 2 && sigma > -Q16 / 2 - face
            }
    }

    /// The normal code a voxel at index-space position `p` (`frac` fractional bits, as
    /// [`Clip::coverage`] takes) is shaded by: the nearest plane's, where it lies in the
    /// layer shaded as the face, or `None`.
    pub fn face_code(&self, p: [i64; 3], frac: u32) -> Option<u16> {
        let frac = frac.min(16);
        // The first plane of those with the largest σ, as the rows find it.
        let mut near = (i64::MIN, 0);
        for pl in self.planes() {
            let dot = pl.q[0] * p[0] + pl.q[1] * p[1] + pl.q[2] * p[2];
            let sigma = (dot >> frac) - pl.r;
            if sigma > near.0 {
                near = (sigma, pl.code);
            }
        }
        Clip::in_face(self.inverse, self.face, near.0).then_some(near.1)
    }

    /// The distance from the centre of a volume of `grid` ([`Clip::with_plane`]'s) of the
    /// plane with `normal` placed `offset` of the way from the centre to the farthest
    /// corner of the volume's cells along the normal: 0 halves the volume, 1 keeps all
    /// of it, −1 none. A way to place planes that does not depend on the volume's size;
    /// give it the full volume's grid for every level of it. NaN for a zero normal.
    pub fn offset_distance(grid: &Grid, normal: [f64; 3], offset: f64) -> f64 {
        let len = length(normal);
        let half: f64 = (0..3)
            .map(|a| libm::fabs(normal[a] / len) * grid.dims[a] as f64 * grid.spacing[a] / 2.0)
            .sum();
        offset * half
    }

    /// Planes held.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether no plane is held (everything kept).
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// These planes cutting away the region behind all of them, which they otherwise
    /// keep; inverted again, the planes as they were. Without planes, still everything
    /// kept.
    pub fn inverted(self) -> Clip {
        Clip {
            inverse: !self.inverse && !self.is_empty(),
            ..self
        }
    }

    /// Whether the planes cut away the region behind all of them ([`Clip::inverted`]).
    pub fn is_inverse(&self) -> bool {
        self.inverse
    }

    fn planes(&self) -> &[Plane] {
        self.planes.get(..self.len).unwrap_or_default()
    }

    /// This clip with each plane's coefficients reordered as `v` is by `permute` (a
    /// view's object axes to its roles `(i, j, k)`: [`crate::view::Factorization::permute`]),
    /// so that [`Clip::coverage`] takes positions in those roles.
    pub fn permuted(&self, permute: impl Fn([i64; 3]) -> [i64; 3]) -> Clip {
        let mut out = *self;
        for p in out.planes.iter_mut() {
            p.q = permute(p.q);
        }
        out
    }

    /// Coverage at index-space position `p`, given with `frac` fractional bits (at
    /// most 16; positions at most 2^13 voxels from the origin): Q16, 0 (cut away) to
    /// 65536 (kept), falling from one to the other over the voxel the plane crosses.
    /// Inverted, its complement.
    pub fn coverage(&self, p: [i64; 3], frac: u32) -> u32 {
        let frac = frac.min(16);
        let mut cov = Q16;
        for pl in self.planes() {
            let dot = pl.q[0] * p[0] + pl.q[1] * p[1] + pl.q[2] * p[2];
            let sigma = (dot >> frac) - pl.r;
            cov = cov.min(plane_coverage(sigma));
        }
        kept(self.inverse, cov) as u32
    }

    /// Scales the opacity of the voxels of z slices `slices` of a volume of `grid` by
    /// their coverage, in `out`, which holds those slices' records from its start as
    /// [`crate::classify::classify_slices`] writes them. A voxel left with no opacity
    /// loses its normal too ([`crate::normal::ZERO_GRADIENT`]), as a cropped one does.
    pub fn apply(
        &self,
        grid: &Grid,
        slices: core::ops::Range<usize>,
        out: &mut [Voxel],
    ) -> Result<(), Error> {
        let plane = crate::crop::slice_records(grid, &slices, out.len())?;
        let nx = grid.dims[0];
        if self.is_empty() {
            return Ok(());
        }
        // `Grid` keeps every side at least 1; `max` says so to the compiler, so that
        // `chunks_exact_mut` keeps no panic path (the firmware links only without one).
        for (z, slice) in slices.zip(out.chunks_exact_mut(plane.max(1))) {
            for (y, row) in slice.chunks_exact_mut(nx.max(1)).enumerate() {
                // Each plane's σ along the row, stepping by its q_x from x = 0.
                let mut sigma = [0i64; MAX_PLANES];
                for (s, pl) in sigma.iter_mut().zip(self.planes()) {
                    *s = pl.q[1] * y as i64 + pl.q[2] * z as i64 - pl.r;
                }
                for v in row.iter_mut() {
                    // The largest σ (the least coverage) and its plane's normal.
                    let mut near = (i64::MIN, 0);
                    for (s, pl) in sigma.iter_mut().zip(self.planes()) {
                        if *s > near.0 {
                            near = (*s, pl.code);
                        }
                        *s += pl.q[0];
                    }
                    let cov = kept(self.inverse, plane_coverage(near.0));
                    if cov < Q16 {
                        let a = (v.opacity as i64 * cov + Q16 / 2) >> 16;
                        v.opacity = a as u8;
                        if a == 0 {
                            v.normal = crate::normal::ZERO_GRADIENT;
                        }
                    }
                    if v.opacity > 0 && Clip::in_face(self.inverse, self.face, near.0) {
                        v.normal = near.1;
                    }
                }
            }
        }
        Ok(())
    }
}

/// The planes over one slice of a view: each plane's σ at voxel `(0, 0)` of the slice
/// and its steps along the slice's rows (`i`) and from row to row (`j`), from a
/// [`Clip`] in the view's roles ([`Clip::permuted`]). Lacroute's way to clip a
/// classified volume at render time (1995, §7.5): the planes become bounds on the
/// loop over each voxel row, found by stepping from row to row.
#[derive(Clone, Copy, Debug)]
pub struct SliceCut {
    sigma: [i64; MAX_PLANES],
    qi: [i64; MAX_PLANES],
    qj: [i64; MAX_PLANES],
    codes: [u16; MAX_PLANES],
    len: usize,
    inverse: bool,
    face: i64,
}

/// The planes along one voxel row ([`SliceCut::row`]): the row's voxels split into
/// zones where coverage is nothing, everything or on the ramp between.
///
/// `outer` is where every plane covers some of the voxel and `inner` (inside it) where
/// every plane covers all of it; between them lie the voxels on a plane's ramp.
/// Outside `outer` the least coverage is 0 and inside `inner` it is 1, so the planes
/// keep `inner` whole and drop what lies outside `outer`, or, inverted, the reverse.
#[derive(Clone, Copy, Debug)]
pub struct RowCut {
    sigma: [i64; MAX_PLANES],
    step: [i64; MAX_PLANES],
    codes: [u16; MAX_PLANES],
    len: usize,
    inverse: bool,
    outer: (usize, usize),
    inner: (usize, usize),
    /// The voxels in the layer shaded as the cut's face ([`Clip::with_shaded_face`]):
    /// two ranges, either side of the deeper part of the row, either may be empty.
    face: [(usize, usize); 2],
}

impl Clip {
    /// The planes over slice `k`, `[ni, nj]` voxels, of a view, the clip given in the
    /// view's roles ([`Clip::permuted`]); `None` without planes, or where they keep
    /// the whole slice (so that its rows are not cut one by one: with a plane that
    /// cuts nothing, the Colin27 head took 11 % more instructions a frame than
    /// without one when every row was).
    pub fn slice(&self, k: i64, [ni, nj]: [usize; 2]) -> Option<SliceCut> {
        if self.is_empty() {
            return None;
        }
        // σ is affine, so its extremes over the slice are at its corners. A plane
        // covers the whole slice where σ ≤ −½ at every corner, and none of it where
        // σ ≥ ½ at every corner; a slice in the layer shaded as the face is cut all
        // the same, so the bounds move out by the layer's thickness.
        let corners = [(0, 0), (ni, 0), (0, nj), (ni, nj)]
            .map(|(i, j)| [(i as i64 - 1).max(0), (j as i64 - 1).max(0), k]);
        let sigma =
            |pl: &Plane, p: [i64; 3]| pl.q[0] * p[0] + pl.q[1] * p[1] + pl.q[2] * p[2] - pl.r;
        let whole = |pl: &Plane| {
            corners
                .iter()
                .all(|&p| sigma(pl, p) <= -Q16 / 2 - self.face)
        };
        let none = |pl: &Plane| corners.iter().all(|&p| sigma(pl, p) >= Q16 / 2 + self.face);
        let keeps_all = if self.inverse {
            self.planes().iter().any(none)
        } else {
            self.planes().iter().all(whole)
        };
        if keeps_all {
            return None;
        }
        let mut cut = SliceCut {
            sigma: [0; MAX_PLANES],
            qi: [0; MAX_PLANES],
            qj: [0; MAX_PLANES],
            codes: [0; MAX_PLANES],
            len: self.len,
            inverse: self.inverse,
            face: self.face,
        };
        let steps = cut
            .qi
            .iter_mut()
            .zip(cut.qj.iter_mut())
            .zip(cut.codes.iter_mut());
        for ((s, ((qi, qj), code)), pl) in cut.sigma.iter_mut().zip(steps).zip(self.planes()) {
            *s = pl.q[2] * k - pl.r;
            *qi = pl.q[0];
            *qj = pl.q[1];
            *code = pl.code;
        }
        Some(cut)
    }
}

/// The voxels `0..ni` of a row where `σ(i) = s + q·i ≤ t`: an interval, as the
/// half-line it is clamped to the row.
fn below(s: i64, q: i64, t: i64, ni: usize) -> (usize, usize) {
    let n = ni as i64;
    let (lo, hi) = match q {
        0 if s <= t => (0, n),
        0 => (0, 0),
        // i ≤ ⌊(t − s)/q⌋.
        q if q > 0 => (0, (t - s).div_euclid(q) + 1),
        // i ≥ ⌈(s − t)/−q⌉.
        q => (-(t - s).div_euclid(-q), n),
    };
    let (lo, hi) = (lo.clamp(0, n), hi.clamp(0, n));
    (lo as usize, hi.max(lo) as usize)
}

impl SliceCut {
    /// The planes along row `j` of the slice, `ni` voxels long.
    pub fn row(&self, j: i64, ni: usize) -> RowCut {
        let mut out = RowCut {
            sigma: [0; MAX_PLANES],
            step: self.qi,
            codes: self.codes,
            len: self.len,
            inverse: self.inverse,
            outer: (0, ni),
            inner: (0, ni),
            face: [(0, 0); 2],
        };
        // The face's layer lies between two levels of the largest σ: beyond the ramp
        // by the layer's thickness, on the kept side (inside it, or inverted, outside).
        let (deep, shallow) = match (self.face, self.inverse) {
            (0, _) => (0, 0),
            (f, false) => (-Q16 / 2 - f, Q16 / 2 - 1),
            (f, true) => (-Q16 / 2, Q16 / 2 + f - 1),
        };
        let mut layer = [(0, ni); 2];
        let intersect = |a: (usize, usize), b: (usize, usize)| (a.0.max(b.0), a.1.min(b.1));
        let n = self.len.min(MAX_PLANES);
        for p in 0..n {
            let s = self.sigma[p] + self.qj[p] * j;
            out.sigma[p] = s;
            // Coverage clamp(½ − σ, 0, 1) is above 0 where σ < ½ and 1 where σ ≤ −½.
            out.outer = intersect(out.outer, below(s, self.qi[p], Q16 / 2 - 1, ni));
            out.inner = intersect(out.inner, below(s, self.qi[p], -Q16 / 2, ni));
            if self.face > 0 {
                layer[0] = intersect(layer[0], below(s, self.qi[p], shallow, ni));
                layer[1] = intersect(layer[1], below(s, self.qi[p], deep, ni));
            }
        }
        // Kept as a range inside `outer` (it is one: covering all implies some).
        let (o0, o1) = (out.outer.0, out.outer.1.max(out.outer.0));
        let (i0, i1) = (out.inner.0.clamp(o0, o1), out.inner.1.clamp(o0, o1));
        out.outer = (o0, o1);
        out.inner = if i0 < i1 { (i0, i1) } else { (o0, o0) };
        if self.face > 0 {
            // Where σ is below the shallow level less where it is below the deep one
            // (an interval inside the first): up to two ranges.
            let (a0, a1) = (layer[0].0, layer[0].1.max(layer[0].0));
            let (b0, b1) = (layer[1].0.clamp(a0, a1), layer[1].1.clamp(a0, a1));
            out.face = if b0 < b1 {
                [(a0, b0), (b1, a1)]
            } else {
                [(a0, a1), (0, 0)]
            };
        }
        out
    }
}

impl RowCut {
    /// Whether the planes leave every voxel of the row as it is.
    pub fn keeps_all(&self, ni: usize) -> bool {
        if self.inverse {
            self.outer.0 >= self.outer.1
        } else {
            self.inner == (0, ni)
        }
    }

    /// The voxels `[lo, hi)` outside which the planes drop every voxel of the row, if
    /// they are one range (inverted planes drop a range inside the row instead).
    pub fn kept(&self) -> Option<(usize, usize)> {
        (!self.inverse).then_some(self.outer)
    }

    /// The voxels the planes do not drop, as two ranges in order (either may be
    /// empty): the one range they keep, or, inverted, those before and after the hole.
    pub fn kept_ranges(&self) -> [(usize, usize); 2] {
        if self.inverse {
            [(0, self.inner.0), (self.inner.1, usize::MAX)]
        } else {
            [self.outer, (0, 0)]
        }
    }

    /// The voxels of the row in the layer shaded as the cut's face, as two ranges
    /// (either may be empty; both are without [`Clip::with_shaded_face`]).
    pub fn face_ranges(&self) -> [(usize, usize); 2] {
        self.face
    }

    /// Whether some voxels of the row lie in the layer shaded as the cut's face.
    #[inline]
    pub fn shades_face(&self) -> bool {
        let [a, b] = self.face;
        a.0 < a.1 || b.0 < b.1
    }

    /// The normal code voxel `i` of the row is shaded by where it lies in the layer
    /// shaded as the face ([`RowCut::face_ranges`]): the nearest plane's, as
    /// [`Clip::face_code`] gives it.
    pub fn face_code(&self, i: usize) -> u16 {
        let i = i as i64;
        let mut near = (i64::MIN, 0);
        for p in 0..self.len.min(MAX_PLANES) {
            let s = self.sigma[p] + self.step[p] * i;
            if s > near.0 {
                near = (s, self.codes[p]);
            }
        }
        near.1
    }

    /// The coverage of voxel `i` (Q16), as [`Clip::coverage`] gives it.
    pub fn coverage(&self, i: usize) -> u32 {
        let i = i as i64;
        let mut least = Q16;
        for p in 0..self.len.min(MAX_PLANES) {
            least = least.min(plane_coverage(self.sigma[p] + self.step[p] * i));
        }
        kept(self.inverse, least) as u32
    }

    /// Cuts voxels `from..to` of the row in `entries`, voxel `i` at entry `i + 1` (the
    /// compositor's row buffers): entries the planes drop are set to the default
    /// (zero), entries on a ramp are handed to `scale` with their coverage
    /// (Q16, `0 < c < 2^16`), and the rest are left as they are.
    pub fn apply<E: Default>(
        &self,
        entries: &mut [E],
        (from, to): (usize, usize),
        scale: impl Fn(&mut E, u32),
    ) {
        let (o0, o1) = self.outer;
        let (i0, i1) = self.inner;
        // The row's zones in order: outside `outer`, the ramps, `inner`, the ramps,
        // outside again; the outside dropped (or kept, inverted) and `inner` the reverse.
        let zones = [(0, o0), (o0, i0), (i0, i1), (i1, o1), (o1, usize::MAX)];
        let (outside_kept, inner_kept) = (self.inverse, !self.inverse);
        for (z, &(a, b)) in zones.iter().enumerate() {
            let (a, b) = (a.max(from), b.min(to));
            if a >= b {
                continue;
            }
            let kept = match z {
                0 | 4 => Some(outside_kept),
                2 => Some(inner_kept),
                _ => None,
            };
            let Some(span) = entries.get_mut(a + 1..b.saturating_add(1).min(entries.len())) else {
                continue;
            };
            match kept {
                Some(true) => {}
                Some(false) => span.iter_mut().for_each(|e| *e = E::default()),
                None => {
                    for (n, e) in span.iter_mut().enumerate() {
                        match self.coverage(a + n) {
                            0 => *e = E::default(),
                            c if c < Q16 as u32 => scale(e, c),
                            _ => {}
                        }
                    }
                }
            }
        }
    }
}

/// One plane's coverage of a point at signed distance `sigma` from it (Q16):
/// `clamp(½ − σ, 0, 1)`.
fn plane_coverage(sigma: i64) -> i64 {
    (Q16 / 2 - sigma).clamp(0, Q16)
}

/// Coverage from the least coverage over the planes: itself, or its complement when
/// `inverse` (whose ramp is the same voxel, seen from the other side).
fn kept(inverse: bool, least: i64) -> i64 {
    if inverse {
        Q16 - least
    } else {
        least
    }
}

/// The Euclidean length of `v`.
fn length(v: [f64; 3]) -> f64 {
    libm::sqrt(v.iter().map(|c| c * c).sum::<f64>())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::normal::ZERO_GRADIENT;
    extern crate std;

    fn grid(dims: [usize; 3], spacing: [f64; 3]) -> Grid {
        Grid::new(dims, spacing).unwrap()
    }

    #[test]
    fn an_axis_plane_through_the_centre_keeps_the_lower_half() {
        let g = grid([9, 3, 3], [1.0; 3]);
        let clip = Clip::NONE.with_plane(&g, [2.0, 0.0, 0.0], 0.0).unwrap();
        // The plane is at x = 4: voxels below are kept, the one it halves keeps half
        // its opacity, the ones above are cut away.
        let cov: [u32; 9] = core::array::from_fn(|x| clip.coverage([x as i64, 1, 1], 0));
        assert_eq!(cov, [65536, 65536, 65536, 65536, 32768, 0, 0, 0, 0]);
        // Between voxels, in Q8: a quarter voxel below the plane keeps three quarters.
        assert_eq!(clip.coverage([(4 << 8) - 64, 0, 0], 8), 49152);
        // Moving the plane by 1.5 physical units moves the cut by as many voxels.
        let moved = Clip::NONE.with_plane(&g, [1.0, 0.0, 0.0], 1.5).unwrap();
        assert_eq!(moved.coverage([5, 0, 0], 0), 65536);
        assert_eq!(moved.coverage([6, 0, 0], 0), 0);
        // Offsets: the half-extent along x is 4.5 cells; along the diagonal of a square
        // face of 9 × 3 cells it is (4.5 + 1.5)/√2.
        assert_eq!(Clip::offset_distance(&g, [2.0, 0.0, 0.0], 1.0), 4.5);
        assert_eq!(Clip::offset_distance(&g, [-1.0, 0.0, 0.0], -0.5), -2.25);
        let d = Clip::offset_distance(&g, [1.0, -1.0, 0.0], 1.0);
        assert!((d - 6.0 / 2f64.sqrt()).abs() < 1e-12);
        assert!(Clip::offset_distance(&g, [0.0; 3], 0.5).is_nan());
    }

    #[test]
    fn spacing_scales_the_plane_and_the_ramp() {
        // x spacing 2: the plane 3 mm from the centre (x index 4) lies at index 5.5, and
        // one x voxel is two units of the smallest spacing, so the ramp is half a voxel.
        let g = grid([9, 3, 3], [2.0, 1.0, 1.0]);
        let clip = Clip::NONE.with_plane(&g, [1.0, 0.0, 0.0], 3.0).unwrap();
        let cov: [u32; 9] = core::array::from_fn(|x| clip.coverage([x as i64, 0, 0], 0));
        assert_eq!(cov, [65536, 65536, 65536, 65536, 65536, 65536, 0, 0, 0]);
        assert_eq!(clip.coverage([(11 << 2) / 2, 0, 0], 2), 32768);
    }

    #[test]
    fn oblique_planes_and_their_intersection() {
        let g = grid([8, 8, 8], [1.0; 3]);
        // x + y ≤ 7 (through the centre, 3.5 + 3.5), and z ≤ 3.5.
        let clip = Clip::NONE
            .with_plane(&g, [1.0, 1.0, 0.0], 0.0)
            .and_then(|c| c.with_plane(&g, [0.0, 0.0, 1.0], 0.0))
            .unwrap();
        assert_eq!(clip.len(), 2);
        assert_eq!(clip.coverage([0, 0, 0], 0), 65536);
        assert_eq!(clip.coverage([7, 7, 0], 0), 0);
        assert_eq!(clip.coverage([2, 2, 7], 0), 0);
        // On the diagonal plane: half.
        assert_eq!(clip.coverage([3, 4, 0], 0), 32768);
        // The planes in a view's roles (here i = z, j = x, k = y) give the same answer.
        let p = clip.permuted(|[x, y, z]| [z, x, y]);
        for pos in [[0, 0, 0], [7, 7, 0], [3, 4, 0], [2, 2, 7], [5, 1, 3]] {
            let [x, y, z] = pos;
            assert_eq!(p.coverage([z, x, y], 0), clip.coverage(pos, 0));
        }
    }

    #[test]
    fn apply_fades_the_voxels_the_planes_cross() {
        let dims = [6, 2, 2];
        let g = grid(dims, [1.0; 3]);
        let clip = Clip::NONE.with_plane(&g, [1.0, 0.0, 0.0], 0.0).unwrap();
        let mut out = [Voxel {
            opacity: 200,
            scalar: 9,
            normal: 5,
        }; 24];
        clip.apply(&g, 0..2, &mut out).unwrap();
        for (n, v) in out.iter().enumerate() {
            let x = n % 6;
            // The plane is at x = 2.5: voxel 2 is a half voxel inside, 3 a half outside.
            let (a, normal) = if x <= 2 {
                (200, 5)
            } else {
                (0, crate::normal::ZERO_GRADIENT)
            };
            assert_eq!((v.opacity, v.scalar, v.normal), (a, 9, normal), "x = {x}");
        }
        // Shifted by a quarter voxel, voxel 3 keeps a quarter.
        let mut out = [Voxel {
            opacity: 200,
            scalar: 9,
            normal: 5,
        }; 24];
        let q = Clip::NONE.with_plane(&g, [1.0, 0.0, 0.0], 0.25).unwrap();
        q.apply(&g, 0..2, &mut out).unwrap();
        assert_eq!(out[2].opacity, 200);
        assert_eq!(out[3].opacity, 50);
        assert_eq!(out[4].opacity, 0);
        // No planes: nothing changes.
        let mut same = out;
        Clip::NONE.apply(&g, 0..2, &mut same).unwrap();
        assert_eq!(same, out);
    }

    /// Random grids and planes: `apply` (σ stepped along each row) scales every voxel
    /// by exactly the coverage `coverage` gives its index (σ from scratch), coverage is
    /// the same at any number of fractional bits and in a view's axis order, and lies
    /// in 0..=1.
    #[test]
    fn apply_agrees_with_coverage_on_random_planes() {
        let mut rnd = crate::xorshift(0x9e37_79b9_7f4a_7c15);
        let mut unit = move || (rnd() >> 11) as f64 / (1u64 << 53) as f64;
        for case in 0..200 {
            let dims = [0; 3].map(|_: usize| 1 + (unit() * 9.0) as usize);
            let spacing = [0; 3].map(|_: usize| 0.25 + unit() * 3.0);
            let g = grid(dims, spacing);
            let mut clip = Clip::NONE;
            for _ in 0..1 + (unit() * 6.0) as usize {
                let n = [0; 3].map(|_: usize| unit() * 2.0 - 1.0);
                let d = (unit() * 2.0 - 1.0) * 10.0;
                clip = clip.with_plane(&g, n, d).unwrap_or(clip);
            }
            let [nx, ny, nz] = dims;
            let mut out: std::vec::Vec<Voxel> = (0..nx * ny * nz)
                .map(|i| Voxel {
                    opacity: (i * 37 % 256) as u8,
                    scalar: i as u8,
                    normal: 3,
                })
                .collect();
            let before = out.clone();
            clip.apply(&g, 0..nz, &mut out).unwrap();
            let swap = clip.permuted(|[x, y, z]| [y, z, x]);
            for (i, (v, w)) in before.iter().zip(&out).enumerate() {
                let p = [i % nx, i / nx % ny, i / (nx * ny)].map(|c| c as i64);
                let cov = clip.coverage(p, 0);
                assert!(cov <= 1 << 16, "case {case}");
                assert_eq!(clip.coverage(p.map(|c| c << 12), 12), cov, "case {case}");
                assert_eq!(swap.coverage([p[1], p[2], p[0]], 0), cov, "case {case}");
                let a = ((v.opacity as u64 * cov as u64 + (1 << 15)) >> 16) as u8;
                let normal = if a == 0 && cov < 1 << 16 {
                    ZERO_GRADIENT
                } else {
                    3
                };
                assert_eq!((w.opacity, w.normal), (a, normal), "case {case}, voxel {i}");
            }
        }
    }

    /// Random grids, planes and views' axis orders: cutting a row at render time
    /// ([`SliceCut::row`], [`RowCut::apply`]) drops, scales or keeps each voxel exactly
    /// as its coverage from scratch says, inverted or not, for any part of the row.
    #[test]
    fn row_cuts_agree_with_coverage_on_random_planes() {
        let mut rnd = crate::xorshift(0x2545_f491_4f6c_dd1d);
        let mut unit = move || (rnd() >> 11) as f64 / (1u64 << 53) as f64;
        for case in 0..300 {
            let dims = [0; 3].map(|_: usize| 1 + (unit() * 12.0) as usize);
            let spacing = [0; 3].map(|_: usize| 0.25 + unit() * 3.0);
            let g = grid(dims, spacing);
            let mut clip = Clip::NONE;
            for _ in 0..1 + (unit() * 6.0) as usize {
                // Now and then a plane along an axis, whose σ does not change along rows.
                let mut n = [0; 3].map(|_: usize| unit() * 2.0 - 1.0);
                if unit() < 0.3 {
                    n[(unit() * 3.0) as usize] = 0.0;
                }
                let d = (unit() * 2.0 - 1.0) * 8.0;
                clip = clip.with_plane(&g, n, d).unwrap_or(clip);
            }
            if unit() < 0.5 {
                clip = clip.inverted();
            }
            if unit() < 0.5 {
                // Now and then a whole or half voxel, which axis planes' σ meets exactly.
                let face = [0.5, 1.0, 1.5, 2.0, unit() * 3.0][(unit() * 5.0) as usize];
                clip = clip.with_shaded_face(face).unwrap();
            }
            let roles = [[0, 1, 2], [1, 2, 0], [2, 0, 1]][(unit() * 3.0) as usize];
            let view = clip.permuted(|q| roles.map(|a| q[a]));
            let [ni, nj, nk] = roles.map(|a| dims[a]);
            let (from, to) = (
                (unit() * ni as f64) as usize,
                ni.saturating_sub((unit() * 3.0) as usize),
            );
            // Now and then the whole row and beyond, as the shadow sweep asks.
            let to = if case % 4 == 0 { usize::MAX } else { to };
            for k in 0..nk {
                let Some(slice) = view.slice(k as i64, [ni, nj]) else {
                    // The planes keep the whole slice.
                    for (i, j) in (0..ni).flat_map(|i| (0..nj).map(move |j| (i, j))) {
                        let p = [i, j, k].map(|c| c as i64);
                        assert_eq!(view.coverage(p, 0), 1 << 16, "case {case}");
                        assert_eq!(view.face_code(p, 0), None, "case {case}");
                    }
                    continue;
                };
                for j in 0..nj {
                    let row = slice.row(j as i64, ni);
                    let mut entries = std::vec![7u32 << 16; ni + 2];
                    row.apply(&mut entries, (from, to.max(from)), |e, c| {
                        *e = (*e >> 16) * c
                    });
                    let mut all = true;
                    for i in 0..ni {
                        let p = [i, j, k].map(|c| c as i64);
                        let cov = view.coverage(p, 0);
                        assert_eq!(row.coverage(i), cov, "case {case}");
                        let [f0, f1] = row.face_ranges();
                        let in_face = (f0.0..f0.1).contains(&i) || (f1.0..f1.1).contains(&i);
                        let face = in_face.then(|| row.face_code(i));
                        assert_eq!(face, view.face_code(p, 0), "case {case}, voxel {i}");
                        // The layer lies where the planes keep some of the voxel.
                        assert!(face.is_none() || cov > 0, "case {case}, voxel {i}");
                        all &= cov == 1 << 16;
                        let want = if (from..to).contains(&i) {
                            7 * cov
                        } else {
                            7 << 16
                        };
                        assert_eq!(entries[i + 1], want, "case {case}, voxel {i}");
                    }
                    assert_eq!(row.keeps_all(ni), all, "case {case}");
                    assert_eq!(entries[0], 7 << 16);
                }
            }
        }
        assert!(Clip::NONE.slice(3, [4, 4]).is_none());
    }

    #[test]
    fn the_face_layer_is_the_ramp_and_the_given_thickness_behind_it() {
        // The plane at x = 4 (σ = x − 4): the voxels shaded as its face, by thickness,
        // kept below the plane or, inverted, above it. The layer's far bound is open.
        let g = grid([9, 3, 3], [1.0; 3]);
        let plane = Clip::NONE.with_plane(&g, [1.0, 0.0, 0.0], 0.0).unwrap();
        let code = crate::normal::encode(1, 0, 0);
        for (inverse, thickness, want) in [
            (false, 1.0, 3..5),
            (false, 1.5, 3..5),
            (false, 2.0, 2..5),
            (true, 1.0, 4..6),
            (true, 1.5, 4..6),
            (true, 2.0, 4..7),
        ] {
            let clip = if inverse { plane.inverted() } else { plane };
            let clip = clip.with_shaded_face(thickness).unwrap();
            assert_eq!(clip.face_thickness(), thickness);
            let row = clip.slice(1, [9, 3]).unwrap().row(1, 9);
            let layer: std::vec::Vec<usize> =
                row.face_ranges().iter().flat_map(|r| r.0..r.1).collect();
            assert_eq!(layer, want.clone().collect::<std::vec::Vec<_>>());
            for x in 0..9 {
                let face = clip.face_code([x, 1, 1], 0);
                assert_eq!(
                    face,
                    want.contains(&(x as usize)).then_some(code),
                    "{inverse} {x}"
                );
                assert_eq!(row.face_code(x as usize), code);
            }
            // Classified, the layer's voxels take the plane's normal; the others keep
            // theirs, and the voxels cut away lose theirs.
            let mut v = std::vec![Voxel { opacity: 200, scalar: 9, normal: 7 }; 9 * 3 * 3];
            clip.apply(&g, 0..3, &mut v).unwrap();
            for (x, v) in v.iter().take(9).enumerate() {
                let kept = if inverse { x >= 4 } else { x <= 4 };
                let want = match () {
                    _ if want.contains(&x) => code,
                    _ if kept => 7,
                    _ => ZERO_GRADIENT,
                };
                assert_eq!(v.normal, want, "{inverse} {x}");
            }
        }
        // No layer without a thickness, and none of an absurd one.
        assert_eq!(plane.face_code([4, 1, 1], 0), None);
        assert_eq!(
            plane.slice(1, [9, 3]).unwrap().row(1, 9).face_ranges(),
            [(0, 0); 2]
        );
        for bad in [-0.5, 16.5, f64::NAN, f64::INFINITY] {
            assert!(plane.with_shaded_face(bad).is_err());
        }
        // A slice the planes keep whole but the layer reaches is cut all the same.
        let far = Clip::NONE.with_plane(&g, [0.0, 0.0, 1.0], 0.0).unwrap();
        assert!(far.slice(2, [9, 3]).is_some() && far.slice(0, [9, 3]).is_none());
        let far = far.with_shaded_face(1.0).unwrap();
        assert!(far.slice(0, [9, 3]).is_some());
    }

    #[test]
    fn inverted_planes_cut_away_the_corner_they_would_keep() {
        let g = grid([8, 8, 8], [1.0; 3]);
        // x ≤ 3.5 and z ≤ 3.5 kept; inverted, that corner is the hole.
        let clip = Clip::NONE
            .with_plane(&g, [1.0, 0.0, 0.0], 0.0)
            .and_then(|c| c.with_plane(&g, [0.0, 0.0, 1.0], 0.0))
            .unwrap();
        let hole = clip.inverted();
        assert!(hole.is_inverse() && !clip.is_inverse());
        assert_eq!(hole.inverted(), clip);
        for p in [
            [0, 0, 0],
            [3, 7, 3],
            [4, 0, 0],
            [0, 5, 6],
            [7, 7, 7],
            [2, 2, 5],
        ] {
            assert_eq!(hole.coverage(p, 0), 65536 - clip.coverage(p, 0), "{p:?}");
        }
        assert_eq!(hole.coverage([1, 1, 1], 0), 0);
        assert_eq!(hole.coverage([1, 1, 6], 0), 65536);
        // About the hole's face at x = 3.5: a quarter voxel inside it, a quarter kept;
        // a quarter voxel outside, three quarters.
        assert_eq!(hole.coverage([(3 << 8) + 64, 0, 0], 8), 16384);
        assert_eq!(hole.coverage([(4 << 8) - 64, 0, 0], 8), 49152);
        // apply agrees.
        let mut out = [Voxel {
            opacity: 255,
            scalar: 0,
            normal: 1,
        }; 512];
        hole.apply(&g, 0..8, &mut out).unwrap();
        for (i, v) in out.iter().enumerate() {
            let p = [i % 8, i / 8 % 8, i / 64].map(|c| c as i64);
            let want = (255 * hole.coverage(p, 0) as u64 + (1 << 15)) >> 16;
            assert_eq!(v.opacity as u64, want, "{p:?}");
        }
        // Nothing to invert without planes.
        assert_eq!(Clip::NONE.inverted(), Clip::NONE);
    }

    #[test]
    fn bad_planes_and_buffers_are_refused() {
        let g = grid([4, 4, 4], [1.0; 3]);
        assert!(Clip::NONE.with_plane(&g, [0.0; 3], 0.0).is_err());
        assert!(Clip::NONE
            .with_plane(&g, [f64::NAN, 1.0, 0.0], 0.0)
            .is_err());
        assert!(Clip::NONE
            .with_plane(&g, [1.0, 0.0, 0.0], f64::INFINITY)
            .is_err());
        let mut full = Clip::NONE;
        for _ in 0..MAX_PLANES {
            full = full.with_plane(&g, [0.0, 1.0, 0.0], 0.0).unwrap();
        }
        assert!(full.with_plane(&g, [0.0, 1.0, 0.0], 0.0).is_err());
        let flat = grid([4, 4, 4], [1.0, 1.0, 1e6]);
        assert!(Clip::NONE.with_plane(&flat, [0.0, 0.0, 1.0], 0.0).is_err());
        // A huge distance keeps everything; its negation nothing.
        let far = Clip::NONE.with_plane(&g, [1.0, 0.0, 0.0], 1e300).unwrap();
        let none = Clip::NONE.with_plane(&g, [1.0, 0.0, 0.0], -1e300).unwrap();
        assert_eq!(far.coverage([3, 3, 3], 0), 65536);
        assert_eq!(none.coverage([0, 0, 0], 0), 0);
        let mut short = [Voxel::default(); 15];
        assert!(far.apply(&g, 0..1, &mut short).is_err());
        assert!(far.apply(&g, 3..5, &mut [Voxel::default(); 32]).is_err());
    }
}
