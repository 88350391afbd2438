//! Classification and run-length encoding of a loaded volume, in memory (the core's
//! three axis copies, held in owned buffers), and the per-frame look.

use crate::bigbuf;
use crate::reslice;
use crate::volume::{RawVolume, Voxels};
use shearwarp_core::classify::{ColorTable, ColorTf, GradientTf, Grid, OpacityTf, Scalars, Voxel};
use shearwarp_core::clip::Clip;
use shearwarp_core::composite::{FlatVoxels, Mode};
use shearwarp_core::crop::Crop;
use shearwarp_core::depth::DepthCue;
use shearwarp_core::rle::{self, Axis, RleAxis, ScanIndex};
use shearwarp_core::shade::Lighting;
use shearwarp_core::source::RleVolume;
use shearwarp_core::Error;

/// Everything about appearance that is decided when the volume is encoded.
#[derive(Clone, Debug)]
pub struct Classification {
    /// Opacity transfer function `(raw value, opacity per smallest spacing)`.
    pub opacity: Vec<(f64, f64)>,
    /// Optional opacity factor over gradient magnitude.
    pub gradient: Option<Vec<(f64, f64)>>,
    /// Voxels with opacity at or below this (0..1) are stored as transparent.
    pub min_opacity: f64,
    /// What is cut away of the volume classified: its voxels are made transparent, or
    /// faded, as they are classified, and stored as transparent where nothing is left.
    pub cut: Cut,
}

/// What is cut away of a volume: the voxels (or samples) outside a crop box's cells
/// ([`shearwarp_core::crop`]), and those faded by their coverage by clipping planes
/// ([`shearwarp_core::clip`]), both made for the volume (or level of it) they cut.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Cut {
    /// The box, or `None` for the whole volume.
    pub crop: Option<Crop>,
    /// The planes.
    pub clip: Clip,
}

impl Cut {
    /// Nothing cut away.
    pub const NONE: Cut = Cut {
        crop: None,
        clip: Clip::NONE,
    };

    /// Cuts the classified records of z slices `slices` of a volume of `grid`, held in
    /// `out` from its start: the box's outside made transparent, then the planes'
    /// coverage applied.
    pub fn apply(
        &self,
        grid: &Grid,
        slices: core::ops::Range<usize>,
        out: &mut [Voxel],
    ) -> Result<(), Error> {
        if let Some(crop) = &self.crop {
            crop.apply(grid, slices.clone(), out)?;
        }
        self.clip.apply(grid, slices, out)
    }
}

/// How frames take voxels with a zero gradient (`--flat-voxels` of the CLI and the
/// bench): a fixed [`FlatVoxels`], or `Auto`, as each volume's share of them says
/// ([`Encoded::auto_flat_voxels`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum FlatVoxelsArg {
    // The variants' doc comments are the CLIs' help text, so they name no Rust items.
    /// Excluded when at least one in 16 visible voxels is flat, blended otherwise.
    Auto,
    /// Blended into samples' colours like the other voxels.
    Blended,
    /// Left out of the colour of samples that mix them with voxels that have a direction.
    Excluded,
}

impl FlatVoxelsArg {
    /// The way for `enc`: as asked, or as its share of flat voxels says.
    pub fn resolve(self, enc: &Encoded) -> FlatVoxels {
        match self {
            FlatVoxelsArg::Auto => enc.auto_flat_voxels(),
            FlatVoxelsArg::Blended => FlatVoxels::Blended,
            FlatVoxelsArg::Excluded => FlatVoxels::Excluded,
        }
    }
}

/// The classified volume, run-length encoded along all three axes.
pub struct Encoded {
    /// Geometry.
    pub grid: Grid,
    /// Raw value range that the 8-bit scalars were quantised over.
    pub range: (u16, u16),
    /// Opacity threshold used for transparency.
    pub threshold: u8,
    /// Per axis copy (indexed by [`Axis`]): run lengths, non-transparent voxels and
    /// each scanline's start in both, as the core's [`RleAxis`] reads them. Written only
    /// by this crate's encoders and the `.swv` reader, which checks them with
    /// [`Encoded::volume`].
    pub(crate) runs: [Vec<u8>; 3],
    pub(crate) voxels: [Vec<Voxel>; 3],
    pub(crate) scans: [Vec<ScanIndex>; 3],
    /// Per axis copy, its table of flat voxels ([`Encoded::build_flat_rows`]), or empty.
    pub(crate) flat: [Vec<u64>; 3],
}

pub(crate) fn opacity_points(p: &[(f64, f64)]) -> Vec<(f64, [f64; 1])> {
    p.iter().map(|&(v, a)| (v, [a])).collect()
}

/// Classifies and encodes `raw`.
pub fn encode(raw: &RawVolume, class: &Classification) -> Result<Encoded, Error> {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    encode_threads(raw, class, cores)
}

/// As [`encode`], on up to `threads` threads (1: all on the calling thread, as the
/// single-thread benchmark measures it). No dense classified copy of the volume is made:
/// the z copy is classified and encoded a few slices at a time, its slices split between
/// the threads, and the x and y copies are re-sliced from it ([`reslice`]). Against
/// classifying into a dense copy and transposing it for x and y (which the viewer still
/// does, see [`encode_axis`]): one thread, medians of five, alternating runs, nested
/// spheres 256³ 156–191 → 115–138 ms, the MR heads within the spread; peak memory
/// encoding the hires brain 363 → 246 MB.
pub fn encode_threads(
    raw: &RawVolume,
    class: &Classification,
    threads: usize,
) -> Result<Encoded, Error> {
    let grid = Grid::new(raw.dims, raw.spacing)?;
    let scalars = match &raw.voxels {
        Voxels::U8(d) => Scalars::U8(d),
        Voxels::U16(d) => Scalars::U16(d),
    };
    let pts = opacity_points(&class.opacity);
    let tf = OpacityTf::new(&pts)?;
    let mut table = vec![0u8; scalars.value_count()];
    tf.build_table(&mut table);
    let gpts = class.gradient.as_deref().map(opacity_points);
    let gtable = match &gpts {
        Some(g) => Some(GradientTf::new(g)?.build_table()),
        None => None,
    };
    if !(0.0..1.0).contains(&class.min_opacity) {
        return Err(Error::BadParameter {
            reason: "minimum opacity must be in [0, 1)",
        });
    }
    let threshold = (class.min_opacity * 255.0).floor() as u8;
    let classifier = reslice::Classifier {
        grid: &grid,
        scalars,
        opacity_table: &table,
        gradient_table: gtable.as_ref(),
        threshold,
        cut: class.cut,
    };
    let [x, y, z] = reslice::encode_all(&classifier, threads)?;
    let runs = [x.0, y.0, z.0];
    let voxels = [x.1, y.1, z.1];
    let scans = [x.2, y.2, z.2];
    Ok(Encoded {
        grid,
        range: scalars.range(),
        threshold,
        runs,
        voxels,
        scans,
        flat: Default::default(),
    })
}

/// The table of `copy`'s flat voxels ([`RleAxis::fill_flat_rows`]), which
/// [`RleAxis::with_flat_rows`] lends the compositor.
pub fn flat_rows(copy: &RleAxis<'_>) -> Result<Vec<u64>, Error> {
    let mut table = vec![0; copy.flat_rows_len()];
    copy.fill_flat_rows(&mut table)?;
    Ok(table)
}

/// The run-length copy of `dense` along `axis` as owned arrays (the route of a caller
/// that keeps a dense classified copy anyway, as the viewer does to re-classify
/// quickly), for a volume with `visible` voxels above `threshold`
/// ([`rle::is_visible`]): runs are allocated for the worst case (`ni + 2` per scanline,
/// zero pages until written) and trimmed, so no counting pass is needed.
pub fn encode_axis(
    dense: &[Voxel],
    grid: &Grid,
    axis: Axis,
    threshold: u8,
    visible: usize,
) -> Result<AxisArrays, Error> {
    let [ni, nj, nk] = grid.permuted_dims(axis);
    let mut runs = bigbuf::zeroed_bytes(nj * nk * (ni + 2));
    let mut voxels = bigbuf::filled(visible, Voxel::default());
    let mut scans = bigbuf::filled(nj * nk + 1, ScanIndex::default());
    let used = encode_slabs(
        dense,
        grid,
        axis,
        threshold,
        &mut runs,
        &mut voxels,
        &mut scans,
    )?;
    runs.truncate(used);
    runs.shrink_to_fit();
    Ok((runs, voxels, scans))
}

/// x slices transposed together by [`encode_slabs`]: each volume row then gives 256
/// contiguous bytes (four cache lines) per slab. Measured on a 256³ volume: 16 slices
/// 93 ms, 32 slices 73 ms, 64 slices 67 ms for the x copy (the strided walk: 122 ms).
const X_SLAB: usize = 64;

/// Voxels in a 64-byte cache line: the padding between transposed slices.
const LINE: usize = 16;

/// `rle::encode` of `dense` along `axis`, returning the number of runs used. The x and y
/// copies read the volume across its storage order; instead of walking it with a stride
/// (which misses the cache on nearly every voxel), slices are transposed into a buffer a
/// few at a time, reading the volume in order, and fed to the core's [`rle::Encoder`].
/// The result is the same as `rle::encode` (tested).
pub fn encode_slabs(
    dense: &[Voxel],
    grid: &Grid,
    axis: Axis,
    threshold: u8,
    runs: &mut [u8],
    voxels: &mut [Voxel],
    scans: &mut [ScanIndex],
) -> Result<usize, Error> {
    let [nx, ny, nz] = grid.dims;
    let [ni, nj, nk] = grid.permuted_dims(axis);
    if dense.len() < grid.voxel_count() {
        return Err(Error::BufferTooSmall {
            what: "dense voxels",
            needed: grid.voxel_count(),
            got: dense.len(),
        });
    }
    let mut enc = rle::Encoder::new(grid, axis, threshold, runs, voxels, scans)?;
    let plane = ni * nj;
    // The object axis the copy's scanlines run along.
    let along = grid.permutation(axis)[0];
    if (axis, along) == (Axis::Z, 0) {
        for k in 0..nk {
            enc.push_slice(&dense[k * plane..(k + 1) * plane])?;
        }
    } else {
        // An x slice uses one voxel of each volume row, so [`X_SLAB`] of them are
        // gathered together, a cache line further apart than their size (so the lines a
        // tile writes do not share a cache set). A y or z slice is gathered from whole
        // rows of the volume, one slice at a time, which stays in the cache while it is
        // written.
        let (group, pitch) = match axis {
            Axis::X => (X_SLAB, plane + LINE),
            _ => (1, plane),
        };
        let mut slab = bigbuf::filled(group * pitch, Voxel::default());
        let at = |offset, stride| Strided { offset, stride };
        for k0 in (0..nk).step_by(group) {
            let g = group.min(nk - k0);
            match (axis, along) {
                // Slice x = k0 + s holds (i, j) = (y, z): per z, the rows y of the
                // volume become columns of the slices.
                (Axis::X, 1) => {
                    for z in 0..nz {
                        let (src, dst) = (at(z * ny * nx + k0, nx), at(z * ny, pitch));
                        transpose(dense, src, &mut slab, dst, [ny, g]);
                    }
                }
                // (i, j) = (z, y): per y, the rows z.
                (Axis::X, _) => {
                    for y in 0..ny {
                        let (src, dst) = (at(y * nx + k0, nx * ny), at(y * nz, pitch));
                        transpose(dense, src, &mut slab, dst, [nz, g]);
                    }
                }
                // Slice y = k0 holds (i, j) = (z, x): the rows z of the volume become
                // its columns.
                (Axis::Y, 2) => {
                    let (src, dst) = (at(k0 * nx, nx * ny), at(0, nz));
                    transpose(dense, src, &mut slab, dst, [nz, nx]);
                }
                // (i, j) = (x, z): the volume's rows, one per z.
                (Axis::Y, _) => {
                    for (z, row) in slab.chunks_exact_mut(nx).take(nz).enumerate() {
                        let from = z * nx * ny + k0 * nx;
                        row.copy_from_slice(&dense[from..from + nx]);
                    }
                }
                // Slice z = k0 with (i, j) = (y, x): the slice transposed.
                (Axis::Z, _) => {
                    let (src, dst) = (at(k0 * nx * ny, nx), at(0, ny));
                    transpose(dense, src, &mut slab, dst, [ny, nx]);
                }
            }
            for s in 0..g {
                enc.push_slice(&slab[s * pitch..s * pitch + plane])?;
            }
        }
    }
    Ok(enc.finish()?.parts().0.len())
}

/// A matrix inside a flat array: element `(r, c)` at `offset + r·stride + c`.
#[derive(Clone, Copy)]
pub(crate) struct Strided {
    pub offset: usize,
    pub stride: usize,
}

/// Writes the `rows × cols` matrix `src` transposed into `dst` (`dst(c, r) = src(r,
/// c)`), in 16×16 tiles so that both sides touch whole cache lines.
pub(crate) fn transpose(
    src: &[Voxel],
    s: Strided,
    dst: &mut [Voxel],
    d: Strided,
    [rows, cols]: [usize; 2],
) {
    const T: usize = 16;
    let mut tile = [[Voxel::default(); T]; T];
    for r0 in (0..rows).step_by(T) {
        let tr = T.min(rows - r0);
        for c0 in (0..cols).step_by(T) {
            let tc = T.min(cols - c0);
            // Whole tile rows in, whole tile columns out: both sides move contiguous
            // runs of voxels, and the shuffle happens in the local tile.
            for (r, line) in tile.iter_mut().enumerate().take(tr) {
                let at = s.offset + (r0 + r) * s.stride + c0;
                let from = &src[at..at + tc];
                match <&[Voxel; T]>::try_from(from) {
                    // A fixed-size copy: a few vector moves instead of a memmove call.
                    Ok(full) => *line = *full,
                    Err(_) => line[..tc].copy_from_slice(from),
                }
            }
            for c in 0..tc {
                let at = d.offset + (c0 + c) * d.stride + r0;
                for (o, line) in dst[at..at + tr].iter_mut().zip(&tile) {
                    *o = line[c];
                }
            }
        }
    }
}

/// Runs, voxels and scanline index of one axis copy.
pub type AxisArrays = (Vec<u8>, Vec<Voxel>, Vec<ScanIndex>);

/// Level `level` of `raw`'s level-of-detail pyramid (0: `raw` itself), built with the
/// core's centred 2×2×2 means ([`shearwarp_core::lod`]); returns the volume and its grid,
/// which keeps `raw`'s opacity unit and framing (set it on the encoded level with
/// [`Encoded::as_level`]).
pub fn lod(raw: &RawVolume, level: usize) -> Result<(RawVolume, Grid), Error> {
    let mut grid = Grid::new(raw.dims, raw.spacing)?;
    // The level being halved: `raw` itself at first (borrowed, not copied).
    let mut built: Option<RawVolume> = None;
    for _ in 0..level {
        let current = built.as_ref().unwrap_or(raw);
        let (voxels, next) = match &current.voxels {
            Voxels::U8(d) => halve(d, &grid).map(|(m, g)| (Voxels::U8(m), g))?,
            Voxels::U16(d) => halve(d, &grid).map(|(m, g)| (Voxels::U16(m), g))?,
        };
        grid = next;
        built = Some(RawVolume {
            name: raw.name.clone(),
            dims: grid.dims,
            spacing: grid.spacing,
            voxels,
        });
    }
    Ok((built.unwrap_or_else(|| raw.clone()), grid))
}

/// The means of the level above `d` (a `grid` volume) and that level's grid.
fn halve<T: shearwarp_core::lod::Sample + Default + Clone>(
    d: &[T],
    grid: &Grid,
) -> Result<(Vec<T>, Grid), Error> {
    let n = shearwarp_core::lod::level_dims(grid.dims);
    let count = n[0] * n[1] * n[2];
    let (mut mean, mut lo, mut hi) = (
        vec![T::default(); count],
        vec![T::default(); count],
        vec![T::default(); count],
    );
    let level = shearwarp_core::lod::downsample(d, grid, &mut mean, &mut lo, &mut hi)?;
    Ok((mean, level))
}

impl Encoded {
    /// Marks this encoding as a level of detail of `full` (see [`Grid::as_level_of`]).
    pub fn as_level(mut self, full: &Grid) -> Self {
        self.grid = self.grid.as_level_of(full);
        self
    }

    /// Borrows the encoded copies as a renderable source, with their tables of flat
    /// voxels if [`Encoded::build_flat_rows`] made them.
    pub fn volume(&self) -> Result<RleVolume<'_>, Error> {
        let axis = |a: Axis| {
            let i = a as usize;
            let copy = RleAxis::new(
                &self.grid,
                a,
                &self.runs[i],
                &self.voxels[i],
                &self.scans[i],
            )?;
            if self.flat[i].is_empty() {
                Ok(copy)
            } else {
                copy.with_flat_rows(&self.flat[i])
            }
        };
        RleVolume::new(self.grid, [axis(Axis::X)?, axis(Axis::Y)?, axis(Axis::Z)?])
    }

    /// Makes each copy's table of flat voxels ([`RleAxis::fill_flat_rows`]), which
    /// [`Encoded::volume`] then lends the compositor: rendering with flat voxels excluded
    /// from samples' colours (`FlatVoxels::Excluded`), it copies the flat bits of the runs
    /// it shades from the table instead of finding them in the voxels. One bit per
    /// voxel position and copy (spheres256: 3 × 3.1 MB).
    pub fn build_flat_rows(&mut self) -> Result<(), Error> {
        let vol = self.volume()?;
        let mut tables: [Vec<u64>; 3] = Default::default();
        for (a, table) in Axis::ALL.into_iter().zip(&mut tables) {
            *table = flat_rows(vol.axis(a))?;
        }
        self.flat = tables;
        Ok(())
    }

    /// How to take this volume's flat voxels when the caller leaves it to the data:
    /// [`FlatVoxels::for_volume`] of its voxels with a zero gradient among those stored
    /// (one pass over a copy's voxels: 2 ms for spheres256's 3.8 M). A caller that
    /// gets [`FlatVoxels::Excluded`] builds the tables with [`Encoded::build_flat_rows`].
    pub fn auto_flat_voxels(&self) -> FlatVoxels {
        FlatVoxels::for_volume(self.flat_voxels() as u64, self.visible_voxels() as u64)
    }

    /// Voxels stored with a zero gradient (per axis copy), of [`Encoded::visible_voxels`].
    pub fn flat_voxels(&self) -> usize {
        self.voxels[2]
            .iter()
            .filter(|v| v.normal == shearwarp_core::normal::ZERO_GRADIENT)
            .count()
    }

    /// Non-transparent voxels stored (per axis copy).
    pub fn visible_voxels(&self) -> usize {
        self.voxels[2].len()
    }

    /// Total bytes of the three copies.
    pub fn bytes(&self) -> usize {
        (0..3)
            .map(|a| self.runs[a].len() + 4 * self.voxels[a].len() + 8 * self.scans[a].len())
            .sum()
    }
}

/// Builds the colour table for data quantised over `range`.
pub fn color_table(points: &[(f64, [u8; 3])], range: (u16, u16)) -> Result<ColorTable, Error> {
    let pts: Vec<(f64, [f64; 3])> = points
        .iter()
        .map(|&(v, c)| (v, c.map(|x| x as f64 / 255.0)))
        .collect();
    Ok(ColorTf::new(&pts)?.build_table(range))
}

/// Per-frame appearance.
#[derive(Clone, Debug)]
pub struct Look {
    /// Compositing mode.
    pub mode: Mode,
    /// Colour table.
    pub color: ColorTable,
    /// Lighting, or `None` for unshaded.
    pub lighting: Option<Lighting>,
    /// Early-ray-termination threshold.
    pub ert_threshold: f64,
    /// Depth cueing (fog), or `None`.
    pub depth_cue: Option<DepthCue>,
    /// Shadows toward the first light (rendered on one thread: the shadow buffer is
    /// swept with the slices).
    pub shadows: bool,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slab_encoding_equals_the_core_walk() {
        // Sizes that are not multiples of the slab, and a pattern with runs of every
        // length (split visible and transparent runs included: 300 voxels along x).
        let grid = Grid::new([300, 7, 37], [1.0, 2.0, 0.5]).unwrap();
        let n = grid.voxel_count();
        let dense: Vec<Voxel> = (0..n)
            .map(|i| {
                let h = (i as u32).wrapping_mul(2_654_435_761) >> 24;
                let opacity = match (i / 300) % 3 {
                    0 => 200,
                    1 => 0,
                    _ => (h % 8) as u8 * 30,
                };
                Voxel {
                    opacity,
                    scalar: h as u8,
                    normal: (i % 8192) as u16,
                }
            })
            .collect();
        // Every axis in both of its layouts.
        for (axis, bits) in Axis::ALL.into_iter().flat_map(|a| [(a, 0), (a, 7)]) {
            let grid = grid.with_layout(rle::Layout::from_bits(bits).unwrap());
            let sz = rle::measure(&dense, &grid, axis, 40).unwrap();
            let mut a = (
                vec![0u8; sz.runs],
                vec![Voxel::default(); sz.voxels],
                vec![ScanIndex::default(); sz.scans],
            );
            let mut b = a.clone();
            rle::encode(&dense, &grid, axis, 40, &mut a.0, &mut a.1, &mut a.2).unwrap();
            let used = encode_slabs(&dense, &grid, axis, 40, &mut b.0, &mut b.1, &mut b.2);
            assert_eq!(used.unwrap(), sz.runs, "{axis:?} {bits}");
            assert!(a == b, "{axis:?} {bits}");
        }
    }
}
