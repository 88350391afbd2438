//! Classification: transfer functions, their lookup tables, gradients, and the voxel
//! record the renderer consumes.
//!
//! Transfer functions are piecewise linear over the scalar value. They are compiled once
//! into tables so that classifying a voxel is a lookup (Lacroute 1995, §2.2): opacity is
//! indexed by the raw scalar (256 entries for `u8` data, 65536 for `u16`), colour by the
//! scalar quantised to 8 bits, which every voxel record carries. Because the colour table
//! is applied per frame, colours can change without re-encoding the volume; opacity is
//! baked into the run-length encoding because it decides which voxels are transparent.

use crate::error::{need, Error};
use crate::fixed::{self, ONE};
use crate::normal;
use crate::rle::{Axis, Layout};

/// One classified voxel: 4 bytes, the unit the run-length encoding stores.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Voxel {
    /// Opacity per unit of the smallest voxel spacing, 0..=255 ↦ 0..=1, before opacity
    /// correction for the viewing direction.
    pub opacity: u8,
    /// Scalar value quantised to 8 bits over the data range; indexes the colour table.
    pub scalar: u8,
    /// Encoded normal ([`crate::normal`]).
    pub normal: u16,
}

/// Scalar data of a volume: 8- or 16-bit voxels, x fastest, then y, then z.
#[derive(Clone, Copy, Debug)]
pub enum Scalars<'a> {
    /// 8-bit voxels; the quantised scalar is the value itself.
    U8(&'a [u8]),
    /// 16-bit voxels; quantised linearly over `[min, max]` of the volume.
    U16(&'a [u16]),
}

impl Scalars<'_> {
    /// Number of voxels.
    pub fn len(&self) -> usize {
        match self {
            Scalars::U8(d) => d.len(),
            Scalars::U16(d) => d.len(),
        }
    }
    /// True if there are no voxels.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Number of distinct raw values, which is the opacity table length.
    pub fn value_count(&self) -> usize {
        match self {
            Scalars::U8(_) => 256,
            Scalars::U16(_) => 65536,
        }
    }
    /// Minimum and maximum raw value (`(0, 255)` for u8 data, which is quantised as is).
    pub fn range(&self) -> (u16, u16) {
        match self {
            Scalars::U8(_) => (0, 255),
            Scalars::U16(d) => {
                let mut lo = u16::MAX;
                let mut hi = 0;
                for &v in d.iter() {
                    lo = lo.min(v);
                    hi = hi.max(v);
                }
                if lo > hi {
                    (0, 0)
                } else {
                    (lo, hi)
                }
            }
        }
    }
}

/// Largest accepted volume side; keeps every index product inside `u32`.
pub const MAX_DIM: usize = 4096;
/// Largest accepted voxel count.
pub const MAX_VOXELS: usize = 1 << 30;

/// Grid geometry of a volume: dimensions and physical voxel spacing.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Grid {
    /// Voxels along x, y, z.
    pub dims: [usize; 3],
    /// Voxel spacing along x, y, z (any unit, typically mm).
    pub spacing: [f64; 3],
    /// Length opacities are given per: the smallest spacing, or the full-resolution
    /// volume's for a level of detail ([`Grid::as_level_of`]).
    opacity_unit: f64,
    /// Diagonal the image is framed on: this volume's, or the full-resolution one's for
    /// a level of detail.
    frame_diagonal: f64,
    /// Which axis each run-length-encoded copy runs its scanlines along.
    layout: Layout,
}

impl Grid {
    /// Validates dimensions and spacing.
    pub fn new(dims: [usize; 3], spacing: [f64; 3]) -> Result<Self, Error> {
        if dims.contains(&0) {
            return Err(Error::BadDimensions {
                reason: "a dimension is zero",
            });
        }
        if dims.iter().any(|&d| d > MAX_DIM) {
            return Err(Error::BadDimensions {
                reason: "a dimension exceeds 4096",
            });
        }
        if dims[0] * dims[1] * dims[2] > MAX_VOXELS {
            return Err(Error::BadDimensions {
                reason: "more than 2^30 voxels",
            });
        }
        if spacing
            .iter()
            .any(|s| !s.is_finite() || *s <= 0.0 || *s > 1e6)
        {
            return Err(Error::BadSpacing);
        }
        let mut g = Grid {
            dims,
            spacing,
            opacity_unit: 0.0,
            frame_diagonal: 0.0,
            layout: Layout::fewest_rows(dims),
        };
        g.opacity_unit = g.min_spacing();
        g.frame_diagonal = g.diagonal();
        Ok(g)
    }

    /// This grid as a level of detail of `full`: opacities keep `full`'s unit length (so
    /// the coarser level, with fewer and longer steps, composites equally bright) and
    /// the image keeps `full`'s framing.
    pub fn as_level_of(mut self, full: &Grid) -> Grid {
        self.opacity_unit = full.opacity_unit;
        self.frame_diagonal = full.frame_diagonal;
        self
    }

    /// This grid with its copies laid out as `layout` (a file's; [`Grid::new`] gives
    /// [`Layout::fewest_rows`]).
    pub fn with_layout(mut self, layout: Layout) -> Grid {
        self.layout = layout;
        self
    }

    /// How the run-length-encoded copies of this volume are laid out.
    pub fn layout(&self) -> Layout {
        self.layout
    }

    /// Object axes `(i, j, k)` of `axis`'s copy.
    pub fn permutation(&self, axis: Axis) -> [usize; 3] {
        self.layout.permutation(axis)
    }

    /// Sizes `(ni, nj, nk)` of `axis`'s copy.
    pub fn permuted_dims(&self, axis: Axis) -> [usize; 3] {
        self.layout.permuted_dims(axis, self.dims)
    }

    /// `v`, given per object axis, per role `(i, j, k)` in `axis`'s copy.
    pub fn permute<T: Copy>(&self, axis: Axis, v: [T; 3]) -> [T; 3] {
        self.layout.permute(axis, v)
    }

    /// Length that transfer-function opacities are given per.
    pub fn opacity_unit(&self) -> f64 {
        self.opacity_unit
    }

    /// Diagonal the image's shorter side spans (the camera contract).
    pub fn frame_diagonal(&self) -> f64 {
        self.frame_diagonal
    }
    /// Total voxel count.
    pub fn voxel_count(&self) -> usize {
        self.dims[0] * self.dims[1] * self.dims[2]
    }
    /// Smallest spacing: the unit opacities are expressed in.
    pub fn min_spacing(&self) -> f64 {
        self.spacing[0].min(self.spacing[1]).min(self.spacing[2])
    }
    /// Physical diagonal length of the volume.
    pub fn diagonal(&self) -> f64 {
        let e = [
            self.dims[0] as f64 * self.spacing[0],
            self.dims[1] as f64 * self.spacing[1],
            self.dims[2] as f64 * self.spacing[2],
        ];
        libm::sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2])
    }
}

/// Checks the breakpoints of a piecewise-linear function: at least one, finite, strictly
/// increasing positions.
fn check_positions(xs: impl Iterator<Item = f64>) -> Result<(), Error> {
    let mut prev = f64::NEG_INFINITY;
    let mut n = 0;
    for x in xs {
        if !x.is_finite() {
            return Err(Error::BadTransferFunction {
                reason: "a breakpoint value is not finite",
            });
        }
        if x <= prev {
            return Err(Error::BadTransferFunction {
                reason: "breakpoint values are not strictly increasing",
            });
        }
        prev = x;
        n += 1;
    }
    if n == 0 {
        return Err(Error::BadTransferFunction {
            reason: "no breakpoints",
        });
    }
    Ok(())
}

/// Evaluates a piecewise-linear function given as sorted `(x, y)` breakpoints; constant
/// beyond the end points.
fn eval<const N: usize>(points: &[(f64, [f64; N])], x: f64) -> [f64; N] {
    // Never empty: the transfer functions refuse fewer than one point.
    let (Some(&first), Some(&last)) = (points.first(), points.last()) else {
        return [0.0; N];
    };
    if x <= first.0 {
        return first.1;
    }
    for w in points.windows(2) {
        let (x0, y0) = w[0];
        let (x1, y1) = w[1];
        if x <= x1 {
            let t = (x - x0) / (x1 - x0);
            let mut out = [0.0; N];
            for c in 0..N {
                out[c] = y0[c] + t * (y1[c] - y0[c]);
            }
            return out;
        }
    }
    last.1
}

/// Piecewise-linear opacity transfer function: `(scalar value, opacity per unit of the
/// smallest spacing)` breakpoints.
#[derive(Clone, Copy, Debug)]
pub struct OpacityTf<'a> {
    points: &'a [(f64, [f64; 1])],
}

impl<'a> OpacityTf<'a> {
    /// Validates breakpoints: strictly increasing finite values, opacities in `[0, 1]`.
    pub fn new(points: &'a [(f64, [f64; 1])]) -> Result<Self, Error> {
        check_positions(points.iter().map(|p| p.0))?;
        if points
            .iter()
            .any(|p| !(p.1[0].is_finite() && (0.0..=1.0).contains(&p.1[0])))
        {
            return Err(Error::BadTransferFunction {
                reason: "an opacity is outside 0..1",
            });
        }
        Ok(OpacityTf { points })
    }

    /// Opacity per 8-bit quantised scalar for data quantised over raw `range` (see
    /// [`quantizer`]), Q15: the table post-classification and pre-integration use.
    pub fn build_quantized(&self, range: (u16, u16)) -> [u16; 256] {
        let mut t = [0u16; 256];
        let (lo, hi) = (range.0 as f64, range.1 as f64);
        for (q, out) in t.iter_mut().enumerate() {
            let v = lo + q as f64 * (hi - lo) / 255.0;
            *out = fixed::from_f64(eval(self.points, v)[0]) as u16;
        }
        t
    }

    /// Fills `table[v]` with the 8-bit opacity of raw value `v`. `table` must hold
    /// [`Scalars::value_count`] entries for the data it will classify.
    pub fn build_table(&self, table: &mut [u8]) {
        for (v, out) in table.iter_mut().enumerate() {
            let a = eval(self.points, v as f64)[0];
            *out = (a.clamp(0.0, 1.0) * 255.0 + 0.5) as u8;
        }
    }
}

/// Piecewise-linear colour transfer function: `(scalar value, [r, g, b] in 0..1)`.
#[derive(Clone, Copy, Debug)]
pub struct ColorTf<'a> {
    points: &'a [(f64, [f64; 3])],
}

/// Colour lookup table indexed by the 8-bit quantised scalar, Q15 RGB.
pub type ColorTable = [[u16; 3]; 256];

/// A [`ColorTable`] padded to four lanes (the fourth is zero and never used), the form
/// the compositor reads: one 8-byte load a voxel, which the x86 compositors shade as one
/// four-lane vector with the padded shading entry ([`crate::shade::ShadeEntry`]).
pub type ColorLanes = [[u16; 4]; 256];

/// `t` padded to four lanes.
pub fn color_lanes(t: &ColorTable) -> ColorLanes {
    core::array::from_fn(|q| [t[q][0], t[q][1], t[q][2], 0])
}

impl<'a> ColorTf<'a> {
    /// Validates breakpoints: strictly increasing finite values, channels in `[0, 1]`.
    pub fn new(points: &'a [(f64, [f64; 3])]) -> Result<Self, Error> {
        check_positions(points.iter().map(|p| p.0))?;
        if points.iter().any(|p| {
            p.1.iter()
                .any(|c| !(c.is_finite() && (0.0..=1.0).contains(c)))
        }) {
            return Err(Error::BadTransferFunction {
                reason: "a colour channel is outside 0..1",
            });
        }
        Ok(ColorTf { points })
    }

    /// Builds the table for data whose raw range `(lo, hi)` was quantised to 8 bits
    /// (see [`quantizer`]); entry `q` holds the colour at raw value `lo + q·(hi−lo)/255`.
    pub fn build_table(&self, range: (u16, u16)) -> ColorTable {
        let mut t = [[0u16; 3]; 256];
        let (lo, hi) = (range.0 as f64, range.1 as f64);
        for (q, out) in t.iter_mut().enumerate() {
            let v = lo + q as f64 * (hi - lo) / 255.0;
            let c = eval(self.points, v);
            *out = c.map(|x| fixed::from_f64(x) as u16);
        }
        t
    }
}

/// Opacity modulation by gradient magnitude (Levoy's surface emphasis): a
/// piecewise-linear factor in `[0, 1]` over the gradient magnitude, measured in raw
/// scalar units per smallest voxel spacing and clamped to 255 before lookup (a table of
/// 256 entries, like Lacroute's gradient-magnitude classification).
#[derive(Clone, Copy, Debug)]
pub struct GradientTf<'a> {
    points: &'a [(f64, [f64; 1])],
}

impl<'a> GradientTf<'a> {
    /// Validates breakpoints: strictly increasing finite magnitudes, factors in `[0, 1]`.
    pub fn new(points: &'a [(f64, [f64; 1])]) -> Result<Self, Error> {
        OpacityTf::new(points)?;
        Ok(GradientTf { points })
    }
    /// Q15 factor per clamped magnitude 0..=255.
    pub fn build_table(&self) -> [u16; 256] {
        let mut t = [0u16; 256];
        for (m, out) in t.iter_mut().enumerate() {
            *out = fixed::from_f64(eval(self.points, m as f64)[0]) as u16;
        }
        t
    }
}

/// Maps raw values of range `(lo, hi)` to 8 bits with rounding; returns `(offset,
/// multiplier Q16)` so the per-voxel step is integer: `q = ((v−lo)·m + 2^15) >> 16`.
pub fn quantizer(range: (u16, u16)) -> (u32, u32) {
    let span = range.1.saturating_sub(range.0) as u64;
    if span == 0 {
        return (range.0 as u32, 0);
    }
    ((range.0) as u32, ((255u64 << 16) / span) as u32)
}

/// Fixed-point factors that turn index differences into physical gradients measured per
/// smallest spacing: `w_axis = round(2^12 · s_min / s_axis)`.
fn gradient_weights(grid: &Grid) -> [i64; 3] {
    let smin = grid.opacity_unit();
    grid.spacing
        .map(|s| libm::round(4096.0 * smin / s).max(1.0) as i64)
}

/// Classifies a dense scalar volume into voxel records (`out` in the same x-fastest
/// order). Opacity comes from `opacity_table` (indexed by raw value, see
/// [`OpacityTf::build_table`]), optionally scaled by `gradient_table` of the gradient
/// magnitude; normals come from central differences that honour the spacing (one-sided at
/// the faces).
pub fn classify(
    grid: &Grid,
    scalars: Scalars<'_>,
    opacity_table: &[u8],
    gradient_table: Option<&[u16; 256]>,
    out: &mut [Voxel],
) -> Result<(), Error> {
    classify_above(grid, scalars, opacity_table, gradient_table, None, out)
}

/// [`classify`] for a volume that will be run-length encoded with opacity threshold
/// `threshold` ([`crate::rle::is_visible`]): the records of voxels above it are those
/// of [`classify`]; voxels at or below it are dropped by the encoder, so their normal is
/// not computed (their record holds [`normal::ZERO_GRADIENT`], their scalar, and an
/// opacity at or below the threshold). When the opacity table alone puts a voxel at or
/// below the threshold (a gradient factor only lowers it), its gradient is skipped too.
/// The gradient's six reads and the normal's two divisions are most of a voxel's cost,
/// and most voxels of a typical volume are transparent.
pub fn classify_above(
    grid: &Grid,
    scalars: Scalars<'_>,
    opacity_table: &[u8],
    gradient_table: Option<&[u16; 256]>,
    threshold: Option<u8>,
    out: &mut [Voxel],
) -> Result<(), Error> {
    let slices = 0..grid.dims[2];
    classify_slices(
        grid,
        scalars,
        opacity_table,
        gradient_table,
        threshold,
        slices,
        out,
    )
}

/// [`classify_above`] of the z slices `slices` only, written to `out` from its start
/// (`out[0]` is voxel `(0, 0, slices.start)`); the records are those [`classify_above`]
/// gives them (neighbours in the slices on either side are read from `scalars`). An
/// encoder that consumes slices as they come needs no classified copy of the whole
/// volume, only a few slices of one.
pub fn classify_slices(
    grid: &Grid,
    scalars: Scalars<'_>,
    opacity_table: &[u8],
    gradient_table: Option<&[u16; 256]>,
    threshold: Option<u8>,
    slices: core::ops::Range<usize>,
    out: &mut [Voxel],
) -> Result<(), Error> {
    let n = grid.voxel_count();
    if scalars.len() != n {
        return Err(Error::BadDimensions {
            reason: "data length does not match the dimensions",
        });
    }
    if slices.start > slices.end || slices.end > grid.dims[2] {
        return Err(Error::BadParameter {
            reason: "slices lie outside the volume",
        });
    }
    let plane = grid.dims[0] * grid.dims[1];
    need("voxels", slices.len() * plane, out.len())?;
    need("opacity table", scalars.value_count(), opacity_table.len())?;
    let range = scalars.range();
    let k = Kernel {
        dims: grid.dims,
        w: gradient_weights(grid),
        quant: quantizer(range),
        opacity_table,
        gradient_table,
        normals_above: threshold,
    };
    let out = &mut out[..slices.len() * plane];
    match scalars {
        Scalars::U8(d) => k.run(d, slices, out),
        Scalars::U16(d) => k.run(d, slices, out),
    }
    Ok(())
}

/// The per-voxel part of [`classify`], monomorphised over the sample type so the inner
/// loop reads a plain slice.
struct Kernel<'a> {
    dims: [usize; 3],
    w: [i64; 3],
    quant: (u32, u32),
    opacity_table: &'a [u8],
    gradient_table: Option<&'a [u16; 256]>,
    /// Normals only for opacities above this.
    normals_above: Option<u8>,
}

impl Kernel<'_> {
    /// Slices `slices` of `d` into `out` (which starts at the first of them).
    fn run<T: Copy + Into<i32>>(
        &self,
        d: &[T],
        slices: core::ops::Range<usize>,
        out: &mut [Voxel],
    ) {
        let [nx, ny, nz] = self.dims;
        let (sy, sz) = (nx, nx * ny);
        for z in slices.clone() {
            for y in 0..ny {
                let row = z * sz + y * sy;
                let at = row - slices.start * sz;
                // Inside `out`, which holds the slices (checked by the caller).
                let Some(dst) = out.get_mut(at..at + nx) else {
                    return;
                };
                // y and z are fixed along the row: their differences are interior or not
                // for the whole row; x is interior except at the two ends.
                let around = d.get(row.wrapping_sub(sz)..row + sz + nx);
                if let (true, Some(around)) = (
                    nx >= 3 && y > 0 && y + 1 < ny && z > 0 && z + 1 < nz,
                    around,
                ) {
                    self.voxel(d, 0, y, z, dst);
                    self.inner_row(around, sz, sy, nx, dst);
                    self.voxel(d, nx - 1, y, z, dst);
                } else {
                    for x in 0..nx {
                        self.voxel(d, x, y, z, dst);
                    }
                }
            }
        }
    }

    /// Voxel `(x, y, z)`, written to `dst[x]` (`dst` its row), with boundary handling on
    /// every axis: central differences, twice the one-sided difference at the faces so
    /// both have the same scale.
    fn voxel<T: Copy + Into<i32>>(&self, d: &[T], x: usize, y: usize, z: usize, dst: &mut [Voxel]) {
        let [nx, ny, nz] = self.dims;
        // Every index below lies in the volume (the differences are one-sided at the
        // faces).
        let at = |i: usize| -> i64 { d.get(i).map_or(0, |&v| v.into() as i64) };
        let diff = |idx: usize, c: usize, len: usize, st: usize| -> i64 {
            if len == 1 {
                0
            } else if c == 0 {
                2 * (at(idx + st) - at(idx))
            } else if c == len - 1 {
                2 * (at(idx) - at(idx - st))
            } else {
                at(idx + st) - at(idx - st)
            }
        };
        let idx = (z * ny + y) * nx + x;
        let v = at(idx);
        let alpha = self.table_alpha(v);
        let Some(o) = dst.get_mut(x) else {
            return;
        };
        if let Some(dropped) = self.dropped(v, alpha) {
            *o = dropped;
            return;
        }
        let g = [
            diff(idx, x, nx, 1) * self.w[0],
            diff(idx, y, ny, nx) * self.w[1],
            diff(idx, z, nz, nx * ny) * self.w[2],
        ];
        *o = self.record(v, alpha, g);
    }

    /// Voxels `1..nx − 1` of a row whose neighbours exist on every axis; `src` starts
    /// one slice before the row and ends one slice after it.
    #[inline]
    fn inner_row<T: Copy + Into<i32>>(
        &self,
        src: &[T],
        sz: usize,
        sy: usize,
        nx: usize,
        dst: &mut [Voxel],
    ) {
        // The row and its four neighbours, each `nx` long: slicing them once lets the
        // loop read them without a bounds check per voxel.
        let row = |start: usize| src.get(start..).and_then(|r| r.get(..nx));
        let rows = [row(sz), row(sz - sy), row(sz + sy), row(0), row(2 * sz)];
        let [Some(c), Some(ym), Some(yp), Some(zm), Some(zp)] = rows else {
            return;
        };
        let at = |t: &T| -> i64 { (*t).into() as i64 };
        fn tail<T>(r: &[T]) -> &[T] {
            r.get(1..).unwrap_or_default()
        }
        let inner = dst.get_mut(1..nx - 1).unwrap_or_default();
        let neighbours = tail(ym)
            .iter()
            .zip(tail(yp))
            .zip(tail(zm).iter().zip(tail(zp)));
        for ((o, x), ((ym, yp), (zm, zp))) in inner.iter_mut().zip(c.windows(3)).zip(neighbours) {
            let &[left, mid, right] = x else {
                continue;
            };
            let v = at(&mid);
            let alpha = self.table_alpha(v);
            if let Some(dropped) = self.dropped(v, alpha) {
                *o = dropped;
                continue;
            }
            let g = [
                (at(&right) - at(&left)) * self.w[0],
                (at(yp) - at(ym)) * self.w[1],
                (at(zp) - at(zm)) * self.w[2],
            ];
            *o = self.record(v, alpha, g);
        }
    }

    /// The opacity table's entry for value `v`, before any gradient factor.
    #[inline(always)]
    fn table_alpha(&self, v: i64) -> u8 {
        self.opacity_table.get(v as usize).copied().unwrap_or(0)
    }

    /// With a threshold: the record of a voxel of value `v` whose opacity before the
    /// gradient factor (`alpha`, which the factor only lowers) is already at or below
    /// the threshold, so that the encoder drops it whatever its gradient. The gradient
    /// is not computed.
    #[inline(always)]
    fn dropped(&self, v: i64, alpha: u8) -> Option<Voxel> {
        let t = self.normals_above?;
        (alpha <= t).then(|| Voxel {
            opacity: alpha,
            scalar: self.quantize(v),
            normal: normal::ZERO_GRADIENT,
        })
    }

    #[inline(always)]
    fn quantize(&self, v: i64) -> u8 {
        let (q_off, q_mul) = self.quant;
        (((v as u32).wrapping_sub(q_off) * q_mul + (1 << 15)) >> 16).min(255) as u8
    }

    /// The record of a voxel of value `v`, table opacity `alpha` and gradient `g`
    /// (weighted differences).
    #[inline(always)]
    fn record(&self, v: i64, alpha: u8, g: [i64; 3]) -> Voxel {
        let mut alpha = alpha as u32;
        if let Some(gt) = self.gradient_table {
            // |g| in raw units per opacity unit: the differences span 2 voxels and the
            // weights carry 2^12.
            let m2 = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]) as u64;
            let mag = fixed::isqrt(m2) >> 13;
            let f = gt[mag.min(255) as usize] as u32;
            alpha = fixed::mul(alpha, f);
        }
        let needed = self.normals_above.is_none_or(|t| alpha as u8 > t);
        Voxel {
            opacity: alpha as u8,
            scalar: self.quantize(v),
            normal: if needed {
                normal::encode(g[0], g[1], g[2])
            } else {
                normal::ZERO_GRADIENT
            },
        }
    }
}

/// Per-frame opacity correction (Lacroute 1995, §2.2.2): the stored opacity is for a path
/// of length `s_min`; a sample that stands for a path of `ratio · s_min` has opacity
/// `1 − (1 − α)^ratio`. Returns the corrected opacity in Q15 for each 8-bit opacity.
///
/// `(1 − α)^ratio` is evaluated as `exp(ratio · ln(1 − α))` from the table `LN_CLEAR`:
/// one `exp` an entry instead of a `pow`. On a Cortex-M3 without FPU, where both are
/// soft-float, that took a turned view's setup from 2.97 M to 1.22 M instructions (the
/// firmware's frame from 36.0 M to 34.2 M); on x86-64 the two cost about the same. A
/// test checks that both forms give the same Q15 table over a fine grid of ratios.
pub fn opacity_correction(ratio: f64) -> [u16; 256] {
    let mut t = [ONE as u16; 256];
    for (out, ln) in t.iter_mut().zip(LN_CLEAR) {
        let c = 1.0 - libm::exp(ratio * ln);
        *out = fixed::from_f64(c).min(ONE) as u16;
    }
    t
}

/// `ln(1 − a/255)` for each stored opacity `a` below 255, as `libm::log` computes it (a
/// test checks every entry); stored opacity 255 is opaque at any ratio.
#[rustfmt::skip]
const LN_CLEAR: [f64; 255] = [
    0.0, -0.00392927813988955, -0.007874056430905883, -0.011834457647002796,
    -0.015810606026642204, -0.019802627296179754, -0.02381064869371856, -0.027834798993443988,
    -0.03187520853044895, -0.03593200922606333, -0.04000533461369913, -0.04409531986522423,
    -0.04820210181787775, -0.05232581900173979, -0.05646661166777118, -0.060624621816434854,
    -0.06479999322691547, -0.06899287148695143, -0.07320340402329494, -0.07743174013281603,
    -0.08167803101426713, -0.08594242980072477, -0.09022509159272561, -0.0945261734921162,
    -0.0988458346366326, -0.10318423623523075, -0.10754154160418647, -0.11191791620398533,
    -0.11631352767702353, -0.12072854588614032, -0.12516314295400605, -0.12961749330338632,
    -0.13409177369830738, -0.13858616328614667, -0.1431008436406733, -0.14763599880606457,
    -0.15219181534192527, -0.1567684823693372, -0.16136619161796661, -0.16598513747426116,
    -0.17062551703076334, -0.17528753013657464, -0.179971379449001, -0.18467727048641377,
    -0.18940541168235972, -0.1941560144409575, -0.1989292931936152, -0.20372546545710818,
    -0.20854475189305707, -0.21338737636884506, -0.21825356602001794, -0.2231435513142097,
    -0.22805756611663874, -0.23299584775722143, -0.23795863709935042, -0.24294617861038947,
    -0.24795872043393374, -0.2529965144638909, -0.2580598164204376, -0.263148885927909,
    -0.2682639865946794, -0.27340538609509807, -0.2785733562535406, -0.2837681731306446,
    -0.2889901171117963, -0.29423947299793995, -0.2995165300987837, -0.3048215823284769,
    -0.31015492830383945, -0.3155168714452248, -0.3209077200801014, -0.32632778754944053,
    -0.3317773923170052, -0.33725685808163075, -0.3427665138926005, -0.34830669426821587,
    -0.35387773931767125, -0.3594799948663411, -0.365113812584597, -0.37077955012027436,
    -0.3764775712349121, -0.3822082459438971, -0.38797195066064716, -0.39376906834497305,
    -0.3995999886557662, -0.4054651081081643, -0.4113648302353527, -0.41729956575516725,
    -0.423269732741671, -0.4292757568018829, -0.43531807125784566, -0.4413971173342278,
    -0.4475133443516639, -0.45366720992604215, -0.4598591801739632, -0.46608972992459924,
    -0.4723593429381946, -0.47866851213145933, -0.48501773981011803, -0.491407537908889,
    -0.49783842823917945, -0.5043109427447969, -0.5108256237659907, -0.5173830243121498,
    -0.5239837083435018, -0.5306282510621704, -0.5373172392129671, -0.5440512713943112,
    -0.55083095837969, -0.5576569234500898, -0.5645298027378518, -0.5714502455824255,
    -0.5784189148985188, -0.5854364875571654, -0.5925036547802578, -0.5996211225491217,
    -0.6067896120277343, -0.6140098600012214, -0.6212826193303013, -0.6286086594223741,
    -0.6359887667199967, -0.6434237452075148, -0.6509144169366725, -0.6584616225720554,
    -0.6660662219572747, -0.6737290947028438, -0.6814511407967541, -0.689233281238809,
    -0.6970764586998348, -0.7049816382069481, -0.7129498078561249, -0.7209819795533892,
    -0.7290791897860087, -0.7372425004251697, -0.7454729995616851, -0.7537718023763802,
    -0.7621400520468967, -0.7705789206927613, -0.7790896103606699, -0.7876733540520614,
    -0.7963314167951762, -0.8050650967639308, -0.8138757264460856, -0.8227646738633316,
    -0.831733343846092, -0.8407831793660099, -0.8499156629292823, -0.8591323180342063,
    -0.8684347106965201, -0.8778244510463591, -0.8873031950009028, -0.8968726460170535,
    -0.9065345569287904, -0.916290731874155, -0.9261430283171666, -0.9360933591703346,
    -0.9461436950238363, -0.9562960664878544, -0.9665525666550434, -0.9769153536905899,
    -0.9873866535578852, -0.9979687628884222, -1.0086640520051702, -1.0194749681093858,
    -1.0304040386415763, -1.0414538748281612, -1.0526271754262864, -1.0639267306802198,
    -1.0753554265038425, -1.0869162489049184, -1.0986122886681096, -1.1104467463151124,
    -1.1224229373618284, -1.134544297894173, -1.1468143904859875, -1.1592369104845446,
    -1.1718156926914047, -1.1845547184688343, -1.197458123304742, -1.210530204872095,
    -1.2237754316221159, -1.2371984519542565, -1.250804104010035, -1.264597426142371,
    -1.2785836681171108, -1.292768303109067, -1.3071570405611665, -1.3217558399823193,
    -1.3365709257674603, -1.3516088031320008, -1.3668762752627892, -1.3823804617987543,
    -1.3981288187668934, -1.4141291601133346, -1.4303896809851147, -1.4469189829363251,
    -1.463726101252707, -1.480820534612007, -1.498212277323876, -1.515911854423277,
    -1.533930359925955, -1.5522794985941517, -1.570971631606304, -1.5900198265769985,
    -1.6094379124341005, -1.6292405397302803, -1.6494432470477995, -1.6700625342505353,
    -1.6911159434483676, -1.712622148669331, -1.7346010553881062, -1.7570739112401648,
    -1.7800634294648638, -1.803593926875058, -1.8276914784541185, -1.85238409104449,
    -1.8777018990287797, -1.9036773854320401, -1.9303456325142014, -1.9577446067023159,
    -1.9859154836690127, -2.014903020542265, -2.044755983691946, -2.0755276423586997,
    -2.10727634067328, -2.1400661634962708, -2.1739677151719516, -2.2090590349832215,
    -2.2454266791540975, -2.2831670071369445, -2.3223877202902257, -2.3632097148104805,
    -2.405769329229276, -2.45022109180011, -2.4967411074350028, -2.5455312716044345,
    -2.5968245659919864, -2.6508917872622617, -2.7080502011022105, -2.768674822918645,
    -2.8332133440562157, -2.902206215543167, -2.9763141876968886, -3.0563568953704245,
    -3.1433682723600564, -3.238678452164381, -3.344038967822207, -3.46182200347859,
    -3.5953533961031123, -3.74950407593037, -3.9318256327243235, -4.154969184038532,
    -4.44265125649032, -4.848116364598485, -5.541263545158429,
];

#[cfg(test)]
mod tests {
    use super::*;

    /// The table holds `libm::log(1 − a/255)` exactly, and the correction built from it
    /// equals the `pow` form `1 − (1 − α)^ratio` entry for entry, after rounding to Q15,
    /// over ratios from 0.01 to 8 (every 0.0037).
    #[test]
    fn opacity_correction_equals_the_pow_form() {
        for (a, ln) in LN_CLEAR.iter().enumerate() {
            assert_eq!(*ln, libm::log(1.0 - a as f64 / 255.0), "entry {a}");
        }
        let mut ratio = 0.01;
        while ratio < 8.0 {
            let t = opacity_correction(ratio);
            for (a, got) in t.iter().enumerate() {
                let alpha = a as f64 / 255.0;
                let c = if a == 255 {
                    1.0
                } else {
                    1.0 - libm::pow(1.0 - alpha, ratio)
                };
                let want = fixed::from_f64(c).min(ONE) as u16;
                assert_eq!(*got, want, "ratio {ratio}, opacity {a}");
            }
            ratio += 0.0037;
        }
    }

    #[test]
    fn opacity_table_interpolates_and_clamps() {
        let pts = [(10.0, [0.0]), (20.0, [1.0])];
        let tf = OpacityTf::new(&pts).unwrap();
        let mut t = [0u8; 256];
        tf.build_table(&mut t);
        assert_eq!(t[0], 0);
        assert_eq!(t[10], 0);
        assert_eq!(t[15], 128);
        assert_eq!(t[20], 255);
        assert_eq!(t[255], 255);
    }

    #[test]
    fn invalid_transfer_functions_are_rejected() {
        assert!(OpacityTf::new(&[]).is_err());
        assert!(OpacityTf::new(&[(1.0, [0.0]), (1.0, [0.5])]).is_err());
        assert!(OpacityTf::new(&[(1.0, [1.5])]).is_err());
        assert!(OpacityTf::new(&[(f64::NAN, [0.5])]).is_err());
        assert!(ColorTf::new(&[(0.0, [0.0, -0.1, 0.0])]).is_err());
    }

    /// Classifying a volume a few slices at a time gives the records of classifying it
    /// whole, whatever the cut (the slices' neighbours come from the scalars).
    #[test]
    fn slices_classify_as_the_whole_volume_does() {
        let dims = [5, 4, 7];
        let grid = Grid::new(dims, [1.0, 0.5, 2.0]).unwrap();
        let data: [u8; 140] =
            core::array::from_fn(|n| ((n as u32).wrapping_mul(2_654_435_761) >> 24) as u8);
        let mut table = [0u8; 256];
        for (v, a) in table.iter_mut().enumerate() {
            *a = (v as u8).saturating_sub(60);
        }
        let s = Scalars::U8(&data);
        let mut whole = [Voxel::default(); 140];
        classify_above(&grid, s, &table, None, Some(20), &mut whole).unwrap();
        let plane = 20;
        for step in 1..=7 {
            let mut parts = [Voxel::default(); 140];
            for z0 in (0..7).step_by(step) {
                let z1 = (z0 + step).min(7);
                let out = &mut parts[z0 * plane..z1 * plane];
                classify_slices(&grid, s, &table, None, Some(20), z0..z1, out).unwrap();
            }
            assert_eq!(parts, whole, "{step} slices at a time");
        }
        let mut out = [Voxel::default(); 140];
        assert!(classify_slices(&grid, s, &table, None, None, 6..8, &mut out).is_err());
        assert!(classify_slices(&grid, s, &table, None, None, 2..4, &mut out[..39]).is_err());
    }

    /// The row kernel with its interior fast path equals the plain per-voxel
    /// definition (central differences, doubled one-sided ones at the faces) on every
    /// shape, including sides of 1 and 2, for both sample widths.
    #[test]
    fn classify_equals_the_per_voxel_definition() {
        extern crate std;
        use std::vec::Vec;
        let mut seed = 99u32;
        let mut next = || {
            seed = seed.wrapping_mul(1664525).wrapping_add(1013904223);
            seed >> 8
        };
        for dims in [
            [1, 1, 1],
            [2, 3, 1],
            [3, 3, 3],
            [5, 1, 4],
            [4, 6, 5],
            [7, 2, 3],
        ] {
            let grid = Grid::new(dims, [1.0, 0.7, 2.5]).unwrap();
            let n = grid.voxel_count();
            let v8: Vec<u8> = (0..n).map(|_| next() as u8).collect();
            let v16: Vec<u16> = (0..n).map(|_| (next() % 3000) as u16).collect();
            let gt = [200u16; 256];
            for (scalars, vals) in [
                (
                    Scalars::U8(&v8),
                    v8.iter().map(|&x| x as i64).collect::<Vec<_>>(),
                ),
                (Scalars::U16(&v16), v16.iter().map(|&x| x as i64).collect()),
            ] {
                let table: Vec<u8> = (0..scalars.value_count())
                    .map(|i| (i % 251) as u8)
                    .collect();
                let mut out = std::vec![Voxel::default(); n];
                classify(&grid, scalars, &table, Some(&gt), &mut out).unwrap();
                let w = gradient_weights(&grid);
                let (q_off, q_mul) = quantizer(scalars.range());
                let [nx, ny, nz] = dims;
                let at = |x: usize, y: usize, z: usize| vals[(z * ny + y) * nx + x];
                let d = |c: usize, len: usize, f: &dyn Fn(usize) -> i64| -> i64 {
                    if len == 1 {
                        0
                    } else if c == 0 {
                        2 * (f(1) - f(0))
                    } else if c == len - 1 {
                        2 * (f(c) - f(c - 1))
                    } else {
                        f(c + 1) - f(c - 1)
                    }
                };
                for z in 0..nz {
                    for y in 0..ny {
                        for x in 0..nx {
                            let g = [
                                d(x, nx, &|c| at(c, y, z)) * w[0],
                                d(y, ny, &|c| at(x, c, z)) * w[1],
                                d(z, nz, &|c| at(x, y, c)) * w[2],
                            ];
                            let v = at(x, y, z);
                            let mag =
                                fixed::isqrt((g[0] * g[0] + g[1] * g[1] + g[2] * g[2]) as u64)
                                    >> 13;
                            let alpha = fixed::mul(
                                table[v as usize] as u32,
                                gt[mag.min(255) as usize] as u32,
                            );
                            let q = (((v as u32 - q_off) * q_mul + (1 << 15)) >> 16).min(255);
                            let want = Voxel {
                                opacity: alpha as u8,
                                scalar: q as u8,
                                normal: normal::encode(g[0], g[1], g[2]),
                            };
                            assert_eq!(out[(z * ny + y) * nx + x], want, "{dims:?} ({x},{y},{z})");
                        }
                    }
                }
                // With a threshold, the records the encoder keeps are the same; the
                // others keep their scalar and stay at or below the threshold.
                let mut above = std::vec![Voxel::default(); n];
                classify_above(&grid, scalars, &table, Some(&gt), Some(90), &mut above).unwrap();
                for (a, full) in above.iter().zip(&out) {
                    if full.opacity > 90 {
                        assert_eq!(a, full);
                    } else {
                        assert!(a.opacity <= 90, "{a:?}");
                        assert_eq!((a.scalar, a.normal), (full.scalar, normal::ZERO_GRADIENT));
                    }
                }
            }
        }
    }

    #[test]
    fn quantizer_maps_the_range_onto_0_255() {
        for range in [(0u16, 255u16), (0, 1059), (1000, 4010), (7, 8)] {
            let (o, m) = quantizer(range);
            let q = |v: u16| ((v as u32 - o) * m + (1 << 15)) >> 16;
            assert_eq!(q(range.0), 0);
            let top = q(range.1);
            assert!(top == 255 || top == 254, "{range:?} -> {top}");
        }
        assert_eq!(quantizer((5, 5)).1, 0);
    }

    #[test]
    fn gradient_of_a_linear_ramp_points_along_the_ramp_and_honours_spacing() {
        // f = 10·x on a 4×3×3 grid with spacing (2, 1, 1): physical gradient along +x.
        let grid = Grid::new([4, 3, 3], [2.0, 1.0, 1.0]).unwrap();
        let data: [u8; 36] = core::array::from_fn(|i| (10 * (i % 4)) as u8);
        let table: [u8; 256] = core::array::from_fn(|_| 255);
        let mut out = [Voxel::default(); 36];
        classify(&grid, Scalars::U8(&data), &table, None, &mut out).unwrap();
        for v in out {
            let n = normal::decode(v.normal).unwrap();
            assert!(n[0] > 0.99, "{n:?}");
        }
        // A ramp along y with the same index step is twice as steep physically, which
        // only the gradient-magnitude path can see: 20 units per s_min = 1.
        let data_y: [u8; 36] = core::array::from_fn(|i| (10 * ((i / 4) % 3)) as u8);
        let pts = [(0.0, [0.0]), (40.0, [1.0])];
        let gt = GradientTf::new(&pts).unwrap().build_table();
        classify(&grid, Scalars::U8(&data_y), &table, Some(&gt), &mut out).unwrap();
        // Magnitude 10 per voxel = 10 per s_min along y → factor 0.25.
        assert!(
            (out[4 + 1].opacity as i32 - 64).abs() <= 2,
            "{}",
            out[5].opacity
        );
    }

    #[test]
    fn classify_rejects_mismatched_buffers() {
        let grid = Grid::new([2, 2, 2], [1.0; 3]).unwrap();
        let data = [0u8; 8];
        let table = [0u8; 256];
        let mut small = [Voxel::default(); 7];
        assert!(matches!(
            classify(&grid, Scalars::U8(&data), &table, None, &mut small),
            Err(Error::BufferTooSmall { .. })
        ));
        let mut out = [Voxel::default(); 8];
        assert!(classify(&grid, Scalars::U8(&data[..7]), &table, None, &mut out).is_err());
        assert!(classify(&grid, Scalars::U8(&data), &table[..10], None, &mut out).is_err());
    }

    #[test]
    fn bad_grids_are_rejected() {
        assert!(Grid::new([0, 1, 1], [1.0; 3]).is_err());
        assert!(Grid::new([5000, 1, 1], [1.0; 3]).is_err());
        assert!(Grid::new([4096, 4096, 4096], [1.0; 3]).is_err());
        assert!(Grid::new([1, 1, 1], [1.0, 0.0, 1.0]).is_err());
        assert!(Grid::new([1, 1, 1], [1.0, f64::INFINITY, 1.0]).is_err());
    }

    #[test]
    fn opacity_correction_is_identity_at_ratio_one_and_monotone() {
        let t = opacity_correction(1.0);
        for (a, &v) in t.iter().enumerate() {
            assert!((v as i32 - fixed::from_u8(a as u8) as i32).abs() <= 1);
        }
        let t2 = opacity_correction(2.0);
        assert!(t2.windows(2).all(|w| w[0] <= w[1]));
        assert_eq!(t2[255] as u32, ONE);
        // 1-(1-0.5)^2 = 0.75
        assert!((t2[128] as f64 / ONE as f64 - 0.7539).abs() < 0.01);
    }
}
