//! Run-length-encoded classified volumes (Lacroute 1995, §4.1.1).
//!
//! For each principal axis the volume is stored as slices perpendicular to that axis;
//! each scanline of a slice is a sequence of run lengths (`u8`), alternating transparent
//! and non-transparent and always starting with a transparent run (possibly of length 0),
//! plus the non-transparent voxels themselves. Runs longer than 255 are split by a
//! zero-length run of the other kind; each scanline holds an even number of runs, so the
//! run stream can be entered at any scanline. A scanline index gives, for each scanline,
//! the offset of its first run and first voxel; slice `k` starts at scanline `k·nj`.
//!
//! Three copies exist because the compositor streams slices in storage order along
//! whichever axis is principal for the view.
//!
//! The principal axis is always `k`. Which of the other two runs along the scanlines
//! (`i`) is the volume's [`Layout`]: the thesis keeps the right-handed cycle (principal
//! x → (i, j, k) = (y, z, x); y → (z, x, y); z → (x, y, z)); shearwarp runs the
//! scanlines along the longer of the two instead ([`Layout::fewest_rows`]), since a
//! slice's cost is mostly per scanline.

use crate::classify::{Grid, Voxel};
use crate::composite::Rgba;
use crate::error::{need, prefix_mut, Error};

/// Scanline start offsets into the run and voxel arrays.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ScanIndex {
    /// Index of the scanline's first run length.
    pub run: u32,
    /// Index of the scanline's first non-transparent voxel.
    pub voxel: u32,
}

/// A principal axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Axis {
    /// x is principal.
    X = 0,
    /// y is principal.
    Y = 1,
    /// z is principal.
    Z = 2,
}

impl Axis {
    /// All three, in storage order.
    pub const ALL: [Axis; 3] = [Axis::X, Axis::Y, Axis::Z];

    /// Object axes `(i, j, k)` of the thesis' right-handed cycle with this axis principal.
    pub const fn cycle(self) -> [usize; 3] {
        Layout::CYCLE.permutation(self)
    }
}

/// Which object axis each axis copy runs its scanlines along: per principal axis, the
/// first of the cycle's other two ([`Axis::cycle`]) or, with its bit set, the second.
///
/// A slice costs the compositor mostly per scanline (each voxel row is tested against the
/// opaque pixels, its spans walked, its pixels' runs found), little per voxel, so a
/// slice of fewer, longer scanlines is cheaper: the hires Colin27 brain (301×370×316)
/// seen along z is 370 rows of 301 voxels in the cycle, 301 rows of 370 across it. The
/// image is the same to a level: the intermediate image is transposed and the warp maps
/// it back (its coordinates may round differently).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Layout(u8);

impl Layout {
    /// The thesis' cycle for every axis (`.swv` version 1 files).
    pub const CYCLE: Layout = Layout(0);
    /// Every copy across the cycle (with [`Layout::CYCLE`], bounds buffer sizes for any
    /// layout).
    pub const ALL_SWAPPED: Layout = Layout(7);

    /// Scanlines along the longer of the two in-slice axes of every copy (the cycle's
    /// first on a tie): the layout [`Grid::new`] gives a volume.
    pub const fn fewest_rows(dims: [usize; 3]) -> Layout {
        let mut bits = 0;
        let mut a = 0;
        while a < 3 {
            let [ni, nj, _] = Layout::CYCLE.permute(Axis::ALL[a], dims);
            if nj > ni {
                bits |= 1 << a;
            }
            a += 1;
        }
        Layout(bits)
    }

    /// The layout stored as `bits` (bit `a` for axis `a`), `None` if a bit past the
    /// three is set.
    pub const fn from_bits(bits: u8) -> Option<Layout> {
        if bits < 8 {
            Some(Layout(bits))
        } else {
            None
        }
    }

    /// Bit `a` set if axis `a`'s copy runs its scanlines along the cycle's `j`.
    pub const fn bits(self) -> u8 {
        self.0
    }

    /// `v`, given per object axis (x, y, z), per role `(i, j, k)` in `axis`'s copy.
    /// Written out per case, so that no index is computed: the bare-metal build proves
    /// it has no panic path, and a permutation read from memory would need bounds checks.
    pub const fn permute<T: Copy>(self, axis: Axis, v: [T; 3]) -> [T; 3] {
        let [x, y, z] = v;
        match (axis, self.0 >> axis as u8 & 1 != 0) {
            (Axis::X, false) => [y, z, x],
            (Axis::X, true) => [z, y, x],
            (Axis::Y, false) => [z, x, y],
            (Axis::Y, true) => [x, z, y],
            (Axis::Z, false) => [x, y, z],
            (Axis::Z, true) => [y, x, z],
        }
    }

    /// Object axes that play the roles `(i, j, k)` in `axis`'s copy.
    pub const fn permutation(self, axis: Axis) -> [usize; 3] {
        self.permute(axis, [0, 1, 2])
    }

    /// Sizes `(ni, nj, nk)` of `axis`'s copy of a volume of `dims`.
    pub const fn permuted_dims(self, axis: Axis, dims: [usize; 3]) -> [usize; 3] {
        self.permute(axis, dims)
    }
}

/// Whether a voxel is stored as non-transparent.
#[inline(always)]
pub const fn is_visible(v: &Voxel, threshold: u8) -> bool {
    v.opacity > threshold
}

/// Lengths of the arrays one axis copy needs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct AxisSizes {
    /// Run lengths.
    pub runs: usize,
    /// Non-transparent voxels.
    pub voxels: usize,
    /// Scanline index entries (`nj·nk + 1`, the last one a sentinel).
    pub scans: usize,
}

/// A transparent voxel.
const CLEAR: Voxel = Voxel {
    opacity: 0,
    scalar: 0,
    normal: crate::normal::ZERO_GRADIENT,
};

/// Walks the dense volume along the permuted scanlines of `axis`, calling `f(Some(voxel))`
/// per voxel and `f(None)` at each scanline end.
fn walk(dense: &[Voxel], grid: &Grid, axis: Axis, mut f: impl FnMut(Option<&Voxel>)) {
    let [ni, nj, nk] = grid.permuted_dims(axis);
    let stride = [1, grid.dims[0], grid.dims[0] * grid.dims[1]];
    let [si, sj, sk] = grid.permute(axis, stride);
    for k in 0..nk {
        for j in 0..nj {
            let base = k * sk + j * sj;
            for i in 0..ni {
                // Inside `dense` (its length is checked against the grid first); a voxel
                // past it would be encoded as transparent.
                f(Some(dense.get(base + i * si).unwrap_or(&CLEAR)));
            }
            f(None);
        }
    }
}

/// Stores run length `len` as run `*n` of `runs` and counts it. Past the end of the
/// array (or without one) only the count grows: `encode` reports the size needed.
#[inline(always)]
fn put_run(runs: &mut Option<&mut [u8]>, n: &mut usize, len: u8) {
    if let Some(slot) = runs.as_deref_mut().and_then(|r| r.get_mut(*n)) {
        *slot = len;
    }
    *n += 1;
}

/// Run-length state machine shared by counting and filling.
struct RunWriter<'a> {
    runs: Option<&'a mut [u8]>,
    voxels: Option<&'a mut [Voxel]>,
    n_runs: usize,
    n_vox: usize,
    cur_visible: bool,
    cur_len: u32,
}

impl<'a> RunWriter<'a> {
    /// A writer at the start of an encoding; without arrays it only counts.
    fn new(runs: Option<&'a mut [u8]>, voxels: Option<&'a mut [Voxel]>) -> Self {
        RunWriter {
            runs,
            voxels,
            n_runs: 0,
            n_vox: 0,
            cur_visible: false,
            cur_len: 0,
        }
    }
    fn emit(&mut self, len: u8) {
        put_run(&mut self.runs, &mut self.n_runs, len);
    }
    fn push(&mut self, v: &Voxel, visible: bool) {
        if visible != self.cur_visible {
            self.flush();
            self.cur_visible = visible;
        }
        if self.cur_len == 255 {
            // Split: close this run, insert an empty run of the other kind.
            self.emit(255);
            self.emit(0);
            self.cur_len = 0;
        }
        self.cur_len += 1;
        if visible {
            if let Some(out) = self.voxels.as_deref_mut() {
                if let Some(slot) = out.get_mut(self.n_vox) {
                    *slot = *v;
                }
            }
            self.n_vox += 1;
        }
    }
    fn flush(&mut self) {
        self.emit(self.cur_len as u8);
        self.cur_len = 0;
    }
    /// A whole scanline at once, run by run (the same output as `push` per voxel and
    /// `end_scanline`, which the tests check): the visibility tests are a tight loop
    /// and each visible run is copied in one go.
    fn scanline(&mut self, row: &[Voxel], threshold: u8) {
        debug_assert!(!self.cur_visible && self.cur_len == 0);
        let RunWriter {
            runs,
            voxels,
            n_runs,
            n_vox,
            ..
        } = self;
        let copied = visible_spans(row, threshold).inspect(|&(i, seen)| {
            let dst = voxels
                .as_deref_mut()
                .and_then(|o| o.get_mut(*n_vox..*n_vox + seen));
            // Both `seen` long: the span lies in the row.
            if let (Some(dst), Some(src)) = (dst, row.get(i..i + seen)) {
                if seen < 16 {
                    // Short runs are most runs: a loop beats a memmove call.
                    for (d, v) in dst.iter_mut().zip(src) {
                        *d = *v;
                    }
                } else {
                    dst.copy_from_slice(src);
                }
            }
            *n_vox += seen;
        });
        scanline_runs(copied, row.len(), |b| put_run(runs, n_runs, b));
    }
    fn end_scanline(&mut self) {
        self.flush();
        if self.cur_visible {
            // Scanlines close on a non-transparent run: runs come in pairs.
        } else {
            self.emit(0);
        }
        self.cur_visible = false;
    }
}

/// The run lengths of a run of `len` voxels of one kind, passed to `emit` in order: runs
/// longer than 255 are split into 255, an empty run of the other kind, and the rest (the
/// format's rule, shared with encoders outside the core).
#[inline(always)]
pub fn split_run(mut len: usize, mut emit: impl FnMut(u8)) {
    while len > 255 {
        emit(255);
        emit(0);
        len -= 255;
    }
    emit(len as u8);
}

/// The run lengths of one scanline of `width` voxels, passed to `emit` in order, from
/// the spans of its visible voxels (`(start, length)`: in order, non-empty, within the
/// scanline, and separated by at least one transparent voxel). This is the format's
/// rule, shared with encoders outside the core: a transparent run (maybe empty) before
/// each visible run, runs longer than 255 split ([`split_run`]), and a scanline that
/// ends transparent, or holds no visible voxel, closed by an empty visible run, so that
/// runs come in pairs.
#[inline(always)]
pub fn scanline_runs(
    visible: impl Iterator<Item = (usize, usize)>,
    width: usize,
    mut emit: impl FnMut(u8),
) {
    let (mut at, mut any) = (0, false);
    for (start, len) in visible {
        // Saturating: spans out of order give wrong runs, which the reader's checks
        // reject, rather than a panic.
        split_run(start.saturating_sub(at), &mut emit);
        split_run(len, &mut emit);
        at = start.saturating_add(len);
        any = true;
    }
    if at < width || !any {
        split_run(width.saturating_sub(at), &mut emit);
        emit(0);
    }
}

/// The spans `(start, length)` of `row`'s voxels visible at `threshold`, in order.
#[inline(always)]
fn visible_spans(row: &[Voxel], threshold: u8) -> impl Iterator<Item = (usize, usize)> + '_ {
    let mut i = 0;
    core::iter::from_fn(move || {
        // `i` never passes the row's end.
        let start = i + row
            .get(i..)
            .unwrap_or_default()
            .iter()
            .position(|v| is_visible(v, threshold))
            .unwrap_or(row.len() - i);
        if start == row.len() {
            return None;
        }
        let len = row
            .get(start..)
            .unwrap_or_default()
            .iter()
            .position(|v| !is_visible(v, threshold))
            .unwrap_or(row.len() - start);
        i = start + len;
        Some((start, len))
    })
}

/// Counts the arrays needed to encode `dense` along `axis` with opacity `threshold`.
pub fn measure(
    dense: &[Voxel],
    grid: &Grid,
    axis: Axis,
    threshold: u8,
) -> Result<AxisSizes, Error> {
    need("dense voxels", grid.voxel_count(), dense.len())?;
    let mut w = RunWriter::new(None, None);
    walk(dense, grid, axis, |v| match v {
        Some(v) => w.push(v, is_visible(v, threshold)),
        None => w.end_scanline(),
    });
    let [_, nj, nk] = grid.permuted_dims(axis);
    Ok(AxisSizes {
        runs: w.n_runs,
        voxels: w.n_vox,
        scans: nj * nk + 1,
    })
}

/// Encodes `dense` along `axis` into caller arrays sized by [`measure`], returning the
/// encoded axis copy (validated).
pub fn encode<'a>(
    dense: &[Voxel],
    grid: &Grid,
    axis: Axis,
    threshold: u8,
    runs: &'a mut [u8],
    voxels: &'a mut [Voxel],
    scans: &'a mut [ScanIndex],
) -> Result<RleAxis<'a>, Error> {
    need("dense voxels", grid.voxel_count(), dense.len())?;
    let mut enc = Encoder::new(grid, axis, threshold, runs, voxels, scans)?;
    walk(dense, grid, axis, |v| match v {
        Some(v) => enc.push(v),
        None => enc.end_scanline(),
    });
    enc.finish()
}

/// Run-length encoder of one axis copy fed slice by slice, each slice in the permuted
/// order (`i` fastest, then `j`). [`encode`] reads the dense volume along the permuted
/// axes itself; for the x and y copies that is a strided walk through memory, so a caller
/// with memory to spare can transpose a few slices at a time into a buffer (reading the
/// volume in order) and feed them here instead, with the same result.
pub struct Encoder<'a> {
    writer: RunWriter<'a>,
    scans: &'a mut [ScanIndex],
    grid: Grid,
    axis: Axis,
    threshold: u8,
    /// Scanlines finished so far.
    line: usize,
}

impl<'a> Encoder<'a> {
    /// An encoder writing into caller arrays sized by [`measure`] (smaller ones make
    /// [`Encoder::finish`] report the size needed).
    pub fn new(
        grid: &Grid,
        axis: Axis,
        threshold: u8,
        runs: &'a mut [u8],
        voxels: &'a mut [Voxel],
        scans: &'a mut [ScanIndex],
    ) -> Result<Self, Error> {
        let [_, nj, nk] = grid.permuted_dims(axis);
        let scans = prefix_mut("scans", scans, nj * nk + 1)?;
        if let Some(first) = scans.first_mut() {
            *first = ScanIndex { run: 0, voxel: 0 };
        }
        Ok(Encoder {
            writer: RunWriter::new(Some(runs), Some(voxels)),
            scans,
            grid: *grid,
            axis,
            threshold,
            line: 0,
        })
    }

    /// Appends the next slice: `ni·nj` voxels, `i` fastest.
    pub fn push_slice(&mut self, slice: &[Voxel]) -> Result<(), Error> {
        let [ni, nj, _] = self.grid.permuted_dims(self.axis);
        if slice.len() != ni * nj {
            return Err(Error::BadParameter {
                reason: "slice length is not ni·nj of the axis copy",
            });
        }
        if self.line + nj >= self.scans.len() {
            return Err(Error::BadParameter {
                reason: "more slices than the axis copy holds",
            });
        }
        if ni == 0 {
            for _ in 0..nj {
                self.end_scanline();
            }
            return Ok(());
        }
        for row in slice.chunks_exact(ni) {
            self.writer.scanline(row, self.threshold);
            self.line += 1;
            // `new` sized the index for every scanline.
            if let Some(entry) = self.scans.get_mut(self.line) {
                *entry = ScanIndex {
                    run: self.writer.n_runs as u32,
                    voxel: self.writer.n_vox as u32,
                };
            }
        }
        Ok(())
    }

    #[inline(always)]
    fn push(&mut self, v: &Voxel) {
        self.writer.push(v, is_visible(v, self.threshold));
    }

    fn end_scanline(&mut self) {
        self.writer.end_scanline();
        self.line += 1;
        if let Some(s) = self.scans.get_mut(self.line) {
            *s = ScanIndex {
                run: self.writer.n_runs as u32,
                voxel: self.writer.n_vox as u32,
            };
        }
    }

    /// Checks that every slice arrived and the arrays were large enough, and returns
    /// the encoded copy (validated).
    pub fn finish(self) -> Result<RleAxis<'a>, Error> {
        if self.line + 1 != self.scans.len() {
            return Err(Error::BadParameter {
                reason: "fewer slices than the axis copy holds",
            });
        }
        let (n_runs, n_vox) = (self.writer.n_runs, self.writer.n_vox);
        if n_runs > u32::MAX as usize || n_vox > u32::MAX as usize {
            return Err(Error::BadDimensions {
                reason: "encoded volume exceeds 2^32 runs or voxels",
            });
        }
        let runs = self.writer.runs.unwrap_or_default();
        let voxels = self.writer.voxels.unwrap_or_default();
        need("runs", n_runs, runs.len())?;
        need("voxels", n_vox, voxels.len())?;
        let runs = &runs[..n_runs];
        let voxels = &voxels[..n_vox];
        RleAxis::new(&self.grid, self.axis, runs, voxels, self.scans)
    }
}

/// One encoded axis copy, borrowed. Construction validates it completely, so traversal
/// cannot index out of bounds.
#[derive(Clone, Copy, Debug)]
pub struct RleAxis<'a> {
    axis: Axis,
    dims: [usize; 3],
    layout: Layout,
    runs: &'a [u8],
    voxels: &'a [Voxel],
    scans: &'a [ScanIndex],
    /// The table of flat voxels ([`RleAxis::with_flat_rows`]), empty without one.
    flat: &'a [u64],
}

/// Words a scanline of `ni` voxels takes in a table of flat voxels
/// ([`RleAxis::fill_flat_rows`]): one bit per voxel, at bit `i + 1` for voxel `i`, as the
/// compositor's row buffers keep them, and room to read 64 bits from any of them.
pub const fn flat_row_words(ni: usize) -> usize {
    crate::composite::flat_words(ni)
}

impl<'a> RleAxis<'a> {
    /// Wraps and validates arrays (from [`encode`] or from a file): every scanline's runs
    /// must sum to its width, come in pairs, and account for exactly its voxels.
    pub fn new(
        grid: &Grid,
        axis: Axis,
        runs: &'a [u8],
        voxels: &'a [Voxel],
        scans: &'a [ScanIndex],
    ) -> Result<Self, Error> {
        let [ni, nj, nk] = grid.permuted_dims(axis);
        let lines = nj.checked_mul(nk).ok_or(Error::BadDimensions {
            reason: "too many scanlines",
        })?;
        let (true, Some(first), Some(last)) =
            (scans.len() == lines + 1, scans.first(), scans.last())
        else {
            return Err(Error::MalformedRle {
                reason: "scanline index length is not nj·nk + 1",
            });
        };
        if *first != (ScanIndex { run: 0, voxel: 0 })
            || last.run as usize != runs.len()
            || last.voxel as usize != voxels.len()
        {
            return Err(Error::MalformedRle {
                reason: "scanline index does not span the run and voxel arrays",
            });
        }
        for w in scans.windows(2) {
            check_scanline(ni, runs, w[0], w[1])?;
        }
        Ok(RleAxis {
            axis,
            dims: grid.dims,
            layout: grid.layout(),
            runs,
            voxels,
            scans,
            flat: &[],
        })
    }

    /// Words of this copy's table of flat voxels: [`flat_row_words`] for each scanline of
    /// each slice.
    pub fn flat_rows_len(&self) -> usize {
        let [ni, nj, nk] = self.permuted_dims();
        nk.saturating_mul(nj).saturating_mul(flat_row_words(ni))
    }

    /// Fills `out` ([`RleAxis::flat_rows_len`] words) with this copy's table of flat
    /// voxels, those with an exactly zero gradient ([`crate::normal::ZERO_GRADIENT`]),
    /// scanline after scanline, slice after slice ([`flat_row_words`] each), marked as
    /// the compositor marks its rows.
    ///
    /// Why: with flat voxels excluded from samples' colours
    /// ([`crate::composite::FlatVoxels::Excluded`]) the compositor needs each row's flat
    /// voxels as bits. Without a table it finds them in the voxels of each run it
    /// shades, every frame (spheres256, 256²: 103 K runs a frame, 0.7 ms of a 13.8 ms
    /// frame); with one ([`RleAxis::with_flat_rows`]) it copies each run's bits from
    /// the table.
    ///
    /// The bits are copied run by run, for the voxels shaded, rather than read whole:
    /// read whole, a row's flat voxels behind opaque pixels, never shaded, sent its
    /// scanlines to the slower compositor of rows with flat voxels (the MR head and the
    /// hires brain, whose flat voxels are few: 5–15 % slower frames).
    pub fn fill_flat_rows(&self, out: &mut [u64]) -> Result<(), Error> {
        self.check_flat_rows(out)?;
        out.fill(0);
        let [ni, nj, nk] = self.permuted_dims();
        let w = flat_row_words(ni);
        for (k, rows) in out.chunks_exact_mut(nj * w).take(nk).enumerate() {
            let Some(s) = self.slice(k) else { break };
            for (j, row) in rows.chunks_exact_mut(w).enumerate() {
                // A `u64` is an `Rgba` of the same size: never an error.
                let Ok(row) = bytemuck::try_cast_slice_mut::<u64, Rgba>(row) else {
                    continue;
                };
                s.for_each_run(j, |x, voxels| {
                    crate::composite::mark_flat(row, x + 1, voxels);
                });
            }
        }
        Ok(())
    }

    /// This copy with `rows`, its table of flat voxels as [`RleAxis::fill_flat_rows`]
    /// fills it, from which the compositor then copies the flat bits of the runs it
    /// shades instead of finding them in the voxels. A table that does not match the
    /// copy's voxels makes the rule for flat voxels apply to the wrong ones; one of the
    /// wrong length is an error.
    pub fn with_flat_rows(mut self, rows: &'a [u64]) -> Result<Self, Error> {
        self.check_flat_rows(rows)?;
        self.flat = rows;
        Ok(self)
    }

    /// An error unless `rows` is as long as this copy's table of flat voxels.
    fn check_flat_rows(&self, rows: &[u64]) -> Result<(), Error> {
        match rows.len() == self.flat_rows_len() {
            true => Ok(()),
            false => Err(Error::BadParameter {
                reason: "flat-voxel table length is not flat_rows_len()",
            }),
        }
    }

    /// The principal axis this copy is for.
    pub fn axis(&self) -> Axis {
        self.axis
    }

    /// Volume dimensions (object x, y, z).
    pub fn dims(&self) -> [usize; 3] {
        self.dims
    }

    /// Object axes `(i, j, k)` of this copy.
    pub fn permutation(&self) -> [usize; 3] {
        self.layout.permutation(self.axis)
    }

    /// Sizes `(ni, nj, nk)` of this copy's slices and scanlines.
    pub fn permuted_dims(&self) -> [usize; 3] {
        self.layout.permuted_dims(self.axis, self.dims)
    }

    /// Borrowed arrays `(runs, voxels, scans)`, e.g. for serialisation.
    pub fn parts(&self) -> (&'a [u8], &'a [Voxel], &'a [ScanIndex]) {
        (self.runs, self.voxels, self.scans)
    }

    /// Slice `k` (in the permuted grid), or `None` past the end.
    pub fn slice(&self, k: usize) -> Option<RleSlice<'a>> {
        let [ni, nj, nk] = self.permuted_dims();
        if k >= nk {
            return None;
        }
        // All in range for a validated axis copy (`new` checked the index).
        let scans = self.scans.get(k * nj..=(k + 1) * nj)?;
        let (&base, &end) = (scans.first()?, scans.last()?);
        let w = nj * flat_row_words(ni);
        Some(RleSlice {
            ni,
            nj,
            base,
            runs: self.runs.get(base.run as usize..end.run as usize)?,
            voxels: self.voxels.get(base.voxel as usize..end.voxel as usize)?,
            scans,
            flat: self.flat.get(k * w..(k + 1) * w).unwrap_or_default(),
        })
    }

    /// Decodes back into a dense volume (x fastest); transparent voxels become
    /// `Voxel::default()`. Used to check the encoder and by tools.
    pub fn decode(&self, out: &mut [Voxel]) -> Result<(), Error> {
        let n = self.dims[0] * self.dims[1] * self.dims[2];
        need("dense voxels", n, out.len())?;
        let [_, nj, nk] = self.permuted_dims();
        let stride = [1, self.dims[0], self.dims[0] * self.dims[1]];
        let [si, sj, sk] = self.layout.permute(self.axis, stride);
        for v in out.iter_mut().take(n) {
            *v = Voxel::default();
        }
        for k in 0..nk {
            let Some(s) = self.slice(k) else { break };
            for j in 0..nj {
                let base = k * sk + j * sj;
                s.for_each_visible(j, |i, v| {
                    if let Some(o) = out.get_mut(base + i * si) {
                        *o = *v;
                    }
                });
            }
        }
        Ok(())
    }
}

fn check_scanline(ni: usize, runs: &[u8], a: ScanIndex, b: ScanIndex) -> Result<(), Error> {
    if b.run < a.run || b.voxel < a.voxel || b.run as usize > runs.len() {
        return Err(Error::MalformedRle {
            reason: "scanline index is not monotone",
        });
    }
    let r = &runs[a.run as usize..b.run as usize];
    if !r.len().is_multiple_of(2) {
        return Err(Error::MalformedRle {
            reason: "a scanline has an odd number of runs",
        });
    }
    let mut total = 0usize;
    let mut visible = 0usize;
    for pair in r.chunks_exact(2) {
        total += pair[0] as usize + pair[1] as usize;
        visible += pair[1] as usize;
    }
    if total != ni {
        return Err(Error::MalformedRle {
            reason: "runs of a scanline do not sum to its width",
        });
    }
    if visible != (b.voxel - a.voxel) as usize {
        return Err(Error::MalformedRle {
            reason: "runs of a scanline do not match its voxel count",
        });
    }
    Ok(())
}

/// The scanlines of a slice from one on, in order, then empty ones: a walk down the
/// slice reads one new index entry per scanline and cuts the scanline off the front of
/// the runs and voxels left, instead of looking both ends of each up (the compositor's
/// row loop on x86-64: 46 instructions a row for the lookup).
#[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
pub(crate) struct Scanlines<'a> {
    /// The index entries from the next scanline's on.
    scans: &'a [ScanIndex],
    /// The runs and voxels from the next scanline's on.
    runs: &'a [u8],
    voxels: &'a [Voxel],
}

#[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
impl<'a> Scanlines<'a> {
    /// Runs and voxels of the next scanline; empty past the slice (or where the index of
    /// a slice that was not validated does not fit its arrays, from there on).
    #[cfg_attr(target_arch = "x86_64", inline(always))]
    #[cfg_attr(not(target_arch = "x86_64"), inline)]
    pub(crate) fn next_row(&mut self) -> (&'a [u8], &'a [Voxel]) {
        let row = match self.scans {
            [a, b, ..] => (|| {
                let n_runs = b.run.checked_sub(a.run)? as usize;
                let n_vox = b.voxel.checked_sub(a.voxel)? as usize;
                let (runs, more_runs) = self.runs.split_at_checked(n_runs)?;
                let (voxels, more_voxels) = self.voxels.split_at_checked(n_vox)?;
                Some((runs, voxels, more_runs, more_voxels))
            })(),
            _ => None,
        };
        match row {
            Some((runs, voxels, more_runs, more_voxels)) => {
                self.scans = self.scans.get(1..).unwrap_or_default();
                (self.runs, self.voxels) = (more_runs, more_voxels);
                (runs, voxels)
            }
            None => {
                self.scans = &[];
                (&[], &[])
            }
        }
    }
}

/// Where an index entry's offset `x` into an axis's runs or voxels lies in a slice's
/// arrays that start at `base`; `None` before them. Subtracted with a check rather than
/// wrapped (and left to `get`): the Cortex-M3 frame takes 34.17 M instructions against
/// 34.53 M, x86-64 0.15 % more.
#[inline(always)]
fn offset(x: u32, base: u32) -> Option<usize> {
    x.checked_sub(base).map(|d| d as usize)
}

/// One slice of an encoded axis: `nj` scanlines of `ni` voxels. Offsets in `scans` are
/// relative to the axis arrays; `base` is subtracted to index this slice's arrays, which
/// lets a streaming source hold only one slice in memory.
#[derive(Clone, Copy, Debug)]
pub struct RleSlice<'a> {
    /// Voxels per scanline.
    pub ni: usize,
    /// Scanlines.
    pub nj: usize,
    /// Offsets of the slice's first run and voxel within the axis copy.
    pub base: ScanIndex,
    /// The slice's run lengths.
    pub runs: &'a [u8],
    /// The slice's non-transparent voxels.
    pub voxels: &'a [Voxel],
    /// `nj + 1` scanline offsets (absolute, see `base`).
    pub scans: &'a [ScanIndex],
    /// The slice's table of flat voxels ([`RleAxis::fill_flat_rows`]): `nj` rows of
    /// [`flat_row_words`]`(ni)` words, or empty.
    pub flat: &'a [u64],
}

impl<'a> RleSlice<'a> {
    /// Checks a slice that did not come from a validated [`RleAxis`] (for example one read
    /// from a stream).
    pub fn validate(&self) -> Result<(), Error> {
        if self.scans.len() != self.nj + 1 {
            return Err(Error::MalformedRle {
                reason: "slice index length is not nj + 1",
            });
        }
        let b = self.base;
        let rel = |s: ScanIndex| -> Option<ScanIndex> {
            Some(ScanIndex {
                run: s.run.checked_sub(b.run)?,
                voxel: s.voxel.checked_sub(b.voxel)?,
            })
        };
        let bad = Error::MalformedRle {
            reason: "slice index lies outside the slice",
        };
        let (Some(&first), Some(&last)) = (self.scans.first(), self.scans.last()) else {
            return Err(bad);
        };
        let (first, last) = (rel(first).ok_or(bad)?, rel(last).ok_or(bad)?);
        if first != ScanIndex::default()
            || last.run as usize != self.runs.len()
            || last.voxel as usize != self.voxels.len()
        {
            return Err(bad);
        }
        for w in self.scans.windows(2) {
            check_scanline(
                self.ni,
                self.runs,
                rel(w[0]).ok_or(bad)?,
                rel(w[1]).ok_or(bad)?,
            )?;
        }
        Ok(())
    }

    /// Runs and voxels of scanline `j` (`j < nj`; empty where `j` or the index of a slice
    /// that was not validated lies outside the slice's arrays). Inlined into the x86-64
    /// compositors: as a call its four-word result came back through the stack, and the
    /// compositor's 32-byte copy of it waited on the four 8-byte stores (a store that
    /// cannot be forwarded; 6 % of the head's compositing samples in `perf`).
    #[cfg_attr(target_arch = "x86_64", inline(always))]
    #[cfg_attr(not(target_arch = "x86_64"), inline)]
    pub fn scanline(&self, j: usize) -> (&'a [u8], &'a [Voxel]) {
        self.scanline_checked(j).unwrap_or((&[], &[]))
    }

    /// [`RleSlice::scanline`], `None` where the index does not point into the slice's
    /// arrays: never for `j < nj` of a validated slice, but a slice built by hand is
    /// read as empty rows there instead of panicking.
    #[inline(always)]
    fn scanline_checked(&self, j: usize) -> Option<(&'a [u8], &'a [Voxel])> {
        let [a, b] = [*self.scans.get(j)?, *self.scans.get(j.checked_add(1)?)?];
        let runs = self
            .runs
            .get(offset(a.run, self.base.run)?..offset(b.run, self.base.run)?)?;
        let voxels = self
            .voxels
            .get(offset(a.voxel, self.base.voxel)?..offset(b.voxel, self.base.voxel)?)?;
        Some((runs, voxels))
    }

    /// The scanlines from `j` on, in order, each found from the one before
    /// ([`Scanlines`]); only empty ones for a `j` outside the slice.
    #[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
    pub(crate) fn scanlines_from(&self, j: i64) -> Scanlines<'a> {
        let at = usize::try_from(j).ok().filter(|&j| j < self.nj);
        let start = at.and_then(|j| {
            let first = *self.scans.get(j)?;
            let runs = self.runs.get(offset(first.run, self.base.run)?..)?;
            let voxels = self.voxels.get(offset(first.voxel, self.base.voxel)?..)?;
            Some((self.scans.get(j..)?, runs, voxels))
        });
        let (scans, runs, voxels) = start.unwrap_or((&[], &[], &[]));
        Scanlines {
            scans,
            runs,
            voxels,
        }
    }

    /// Row `j`'s words of the slice's table of flat voxels, as row buffers keep theirs;
    /// empty without a table and for rows outside the slice.
    #[inline(always)]
    pub(crate) fn flat_row(&self, j: i64) -> &'a [Rgba] {
        let w = flat_row_words(self.ni);
        let words = usize::try_from(j)
            .ok()
            .filter(|&j| j < self.nj)
            .and_then(|j| self.flat.get(j * w..(j + 1) * w))
            .unwrap_or_default();
        // A `u64` is an `Rgba` of the same size and a stricter alignment: never an error.
        bytemuck::try_cast_slice(words).unwrap_or_default()
    }

    /// Runs and voxels of scanline `j`, empty for rows outside the slice (the
    /// compositor's rows above and below it). Inlined on x86-64: it is called once per
    /// row, and as a call it cost the head's frames 0.6 % more instructions.
    #[cfg_attr(target_arch = "x86_64", inline(always))]
    #[cfg_attr(not(target_arch = "x86_64"), inline)]
    pub(crate) fn row(&self, j: i64) -> (&'a [u8], &'a [Voxel]) {
        if j >= 0 && (j as usize) < self.nj {
            self.scanline(j as usize)
        } else {
            (&[], &[])
        }
    }

    /// The first and the last scanline in `lo..=hi` that hold a non-transparent voxel,
    /// `None` if none does (or the range is empty or lies outside the slice). Found from
    /// the scanline index alone: a scanline is empty when its voxel offset equals the
    /// next one's. The compositor trims a slice's empty scanlines at either end with it,
    /// a few instructions each instead of a walk through their runs.
    #[cfg_attr(target_arch = "x86_64", inline(always))]
    #[cfg_attr(not(target_arch = "x86_64"), inline)]
    pub fn visible_rows(&self, lo: usize, hi: usize) -> Option<(usize, usize)> {
        let hi = hi.min(self.nj.checked_sub(1)?);
        let offsets = self.scans.get(lo..hi.checked_add(2)?)?;
        let busy = |w: &[ScanIndex]| w[0].voxel != w[1].voxel;
        let first = offsets.windows(2).position(busy)?;
        let last = offsets.windows(2).rposition(busy)?;
        Some((lo + first, lo + last))
    }

    /// Calls `f(i, voxel)` for each non-transparent voxel of scanline `j`.
    pub fn for_each_visible(&self, j: usize, mut f: impl FnMut(usize, &Voxel)) {
        self.for_each_run(j, |i, run| {
            for (n, v) in run.iter().enumerate() {
                f(i + n, v);
            }
        });
    }

    /// Calls `f(i, voxels)` for each non-empty run of non-transparent voxels of scanline
    /// `j`: the run starts at position `i`.
    #[inline]
    pub fn for_each_run(&self, j: usize, mut f: impl FnMut(usize, &[Voxel])) {
        let (runs, mut voxels) = self.scanline(j);
        let mut i = 0;
        for pair in runs.chunks_exact(2) {
            i += pair[0] as usize;
            let n = pair[1] as usize;
            // Within the scanline's voxels when the slice was validated.
            let Some((run, rest)) = voxels.split_at_checked(n) else {
                return;
            };
            if n > 0 {
                f(i, run);
            }
            voxels = rest;
            i += n;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn encoder_refuses_wrong_slices_and_missing_ones() {
        let grid = Grid::new([3, 2, 2], [1.0; 3]).unwrap();
        let (mut runs, mut voxels, mut scans) =
            ([0u8; 64], [Voxel::default(); 12], [ScanIndex::default(); 5]);
        let mut enc = Encoder::new(&grid, Axis::Z, 0, &mut runs, &mut voxels, &mut scans).unwrap();
        let slice = [Voxel::default(); 6];
        assert!(enc.push_slice(&slice[..5]).is_err());
        enc.push_slice(&slice).unwrap();
        assert!(matches!(enc.finish(), Err(Error::BadParameter { .. })));
        let mut enc = Encoder::new(&grid, Axis::Z, 0, &mut runs, &mut voxels, &mut scans).unwrap();
        enc.push_slice(&slice).unwrap();
        enc.push_slice(&slice).unwrap();
        assert!(enc.push_slice(&slice).is_err());
        let enc = enc.finish().unwrap();
        assert_eq!(enc.parts().0, &[3, 0, 3, 0, 3, 0, 3, 0]);
        // Too small arrays report the size needed.
        let mut few = [0u8; 4];
        let mut enc = Encoder::new(&grid, Axis::Z, 0, &mut few, &mut voxels, &mut scans).unwrap();
        enc.push_slice(&slice).unwrap();
        enc.push_slice(&slice).unwrap();
        assert!(matches!(
            enc.finish(),
            Err(Error::BufferTooSmall { needed: 8, .. })
        ));
    }

    fn pseudo_random_volume(grid: &Grid, seed: u32) -> [Voxel; 600 * 3] {
        let mut s = seed;
        core::array::from_fn(|idx| {
            s = s.wrapping_mul(1664525).wrapping_add(1013904223);
            let on = (s >> 28) < 6 || (idx / 300) % 2 == 0 && idx % 7 != 0;
            let _ = grid;
            Voxel {
                opacity: if on { (s >> 8) as u8 | 1 } else { 0 },
                scalar: (s >> 16) as u8,
                normal: (s % 8193) as u16,
            }
        })
    }

    #[test]
    fn encode_decode_round_trip_on_every_axis() {
        // 300×2×3: long scanlines force runs > 255 to split along x.
        let grid = Grid::new([300, 2, 3], [1.0; 3]).unwrap();
        for seed in [1u32, 7, 99] {
            let dense = pseudo_random_volume(&grid, seed);
            for axis in Axis::ALL {
                let sz = measure(&dense, &grid, axis, 0).unwrap();
                let mut runs = [0u8; 4000];
                let mut vox = [Voxel::default(); 1800];
                let mut scans = [ScanIndex::default(); 1000];
                let rle = encode(&dense, &grid, axis, 0, &mut runs, &mut vox, &mut scans).unwrap();
                assert_eq!(rle.parts().0.len(), sz.runs);
                let mut back = [Voxel::default(); 1800];
                rle.decode(&mut back).unwrap();
                for (a, b) in dense.iter().zip(back.iter()) {
                    let expect = if a.opacity > 0 { *a } else { Voxel::default() };
                    assert_eq!(expect, *b);
                }
            }
        }
    }

    #[test]
    fn the_flat_voxel_table_holds_each_visible_flat_voxel_and_nothing_else() {
        use crate::normal::ZERO_GRADIENT;
        let grid = Grid::new([300, 2, 3], [1.0; 3]).unwrap();
        let mut dense = pseudo_random_volume(&grid, 5);
        for (i, v) in dense.iter_mut().enumerate() {
            if i % 5 < 2 {
                v.normal = ZERO_GRADIENT;
            }
        }
        for axis in Axis::ALL {
            let mut runs = [0u8; 4000];
            let mut vox = [Voxel::default(); 1800];
            let mut scans = [ScanIndex::default(); 1000];
            let rle = encode(&dense, &grid, axis, 0, &mut runs, &mut vox, &mut scans).unwrap();
            let [ni, nj, nk] = rle.permuted_dims();
            let w = flat_row_words(ni);
            let mut table = [0u64; 3 * 300 * 8];
            let table = &mut table[..rle.flat_rows_len()];
            assert_eq!(table.len(), nk * nj * w);
            // Stale bits are cleared.
            table.fill(u64::MAX);
            rle.fill_flat_rows(table).unwrap();
            let table = &*table;
            let tabled = rle.with_flat_rows(table).unwrap();
            let p = rle.permutation();
            for k in 0..nk {
                for j in 0..nj {
                    for x in 0..w * 64 {
                        let mut at = [0; 3];
                        (at[p[0]], at[p[1]], at[p[2]]) = (x.wrapping_sub(1), j, k);
                        let v =
                            (x >= 1 && x <= ni).then(|| dense[at[0] + 300 * (at[1] + 2 * at[2])]);
                        let want = v.is_some_and(|v| v.opacity > 0 && v.normal == ZERO_GRADIENT);
                        let got = table[(k * nj + j) * w + x / 64] >> (x % 64) & 1 != 0;
                        assert_eq!(got, want, "{axis:?} slice {k} row {j} bit {x}");
                    }
                    // The slice lends row j's words as the row buffers keep theirs.
                    let s = tabled.slice(k).unwrap();
                    let row: &[u64] = bytemuck::cast_slice(s.flat_row(j as i64));
                    assert_eq!(row, &table[(k * nj + j) * w..(k * nj + j + 1) * w]);
                }
            }
            let too_short = &mut [0u64; 4][..];
            assert!(rle.fill_flat_rows(too_short).is_err());
            assert!(rle.with_flat_rows(too_short).is_err());
            assert!(rle.slice(0).unwrap().flat_row(0).is_empty());
            assert!(tabled.slice(0).unwrap().flat_row(nj as i64).is_empty());
            assert!(tabled.slice(0).unwrap().flat_row(-1).is_empty());
        }
    }

    #[test]
    fn scanline_runs_come_in_pairs_split_and_closed() {
        let runs = |spans: &[(usize, usize)], width| {
            let (mut out, mut n) = ([0u8; 16], 0);
            scanline_runs(spans.iter().copied(), width, |b| {
                out[n] = b;
                n += 1;
            });
            (out, n)
        };
        let check = |spans: &[(usize, usize)], width, want: &[u8]| {
            let (out, n) = runs(spans, width);
            assert_eq!(&out[..n], want, "{spans:?} in {width}");
        };
        check(&[], 0, &[0, 0]);
        check(&[], 300, &[255, 0, 45, 0]);
        check(&[(0, 3)], 3, &[0, 3]);
        check(&[(1, 1), (3, 1)], 5, &[1, 1, 1, 1, 1, 0]);
        check(&[(0, 300)], 300, &[0, 255, 0, 45]);
        check(&[(256, 2)], 258, &[255, 0, 1, 2]);
    }

    #[test]
    fn a_scanline_at_once_is_encoded_as_voxel_by_voxel() {
        let mut s = 12345u32;
        for len in [0usize, 1, 2, 7, 255, 256, 300, 520] {
            for density in [0u32, 3, 8, 13, 16] {
                let mut row = [Voxel::default(); 520];
                for v in &mut row[..len] {
                    s = s.wrapping_mul(1664525).wrapping_add(1013904223);
                    // Long visible and transparent stretches as well as short ones.
                    let on = (s >> 28) < density || (density == 13 && len > 300);
                    v.opacity = if on {
                        (s >> 8) as u8 | 1
                    } else {
                        (s >> 9) as u8 & 1
                    };
                    v.scalar = (s >> 16) as u8;
                }
                let row = &row[..len];
                let (mut runs_a, mut runs_b) = ([0u8; 1100], [0u8; 1100]);
                let (mut vox_a, mut vox_b) = ([Voxel::default(); 520], [Voxel::default(); 520]);
                let writer = |runs, voxels| RunWriter::new(Some(runs), Some(voxels));
                let mut a = writer(&mut runs_a[..], &mut vox_a[..]);
                a.scanline(row, 1);
                let (na, va) = (a.n_runs, a.n_vox);
                let mut b = writer(&mut runs_b[..], &mut vox_b[..]);
                for v in row {
                    b.push(v, is_visible(v, 1));
                }
                b.end_scanline();
                let (nb, vb) = (b.n_runs, b.n_vox);
                assert_eq!((na, va), (nb, vb), "length {len}, density {density}");
                assert_eq!(runs_a[..na], runs_b[..nb]);
                assert_eq!(vox_a[..va], vox_b[..vb]);
            }
        }
    }

    #[test]
    fn long_runs_split_into_u8_pieces() {
        let grid = Grid::new([600, 1, 1], [1.0; 3]).unwrap();
        let dense = [Voxel {
            opacity: 200,
            scalar: 1,
            normal: 0,
        }; 600];
        let mut runs = [0u8; 16];
        let mut vox = [Voxel::default(); 600];
        let mut scans = [ScanIndex::default(); 2];
        let rle = encode(&dense, &grid, Axis::Z, 10, &mut runs, &mut vox, &mut scans).unwrap();
        assert_eq!(rle.parts().0, &[0, 255, 0, 255, 0, 90]);
    }

    #[test]
    fn threshold_decides_transparency() {
        let grid = Grid::new([4, 1, 1], [1.0; 3]).unwrap();
        let dense = [5u8, 6, 5, 200].map(|a| Voxel {
            opacity: a,
            scalar: 0,
            normal: 0,
        });
        let mut runs = [0u8; 8];
        let mut vox = [Voxel::default(); 4];
        let mut scans = [ScanIndex::default(); 2];
        let rle = encode(&dense, &grid, Axis::Z, 5, &mut runs, &mut vox, &mut scans).unwrap();
        assert_eq!(rle.parts().0, &[1, 1, 1, 1]);
        assert_eq!(rle.parts().1.len(), 2);
    }

    #[test]
    fn visible_rows_are_the_first_and_last_scanlines_with_voxels() {
        // 2×6×1, one slice of six rows: rows 1 and 3 hold a voxel, the others are empty.
        let grid = Grid::new([2, 6, 1], [1.0; 3])
            .unwrap()
            .with_layout(Layout::CYCLE);
        let mut dense = [Voxel::default(); 12];
        dense[2 + 1].opacity = 9;
        dense[6].opacity = 9;
        let (mut runs, mut vox, mut scans) =
            ([0u8; 32], [Voxel::default(); 12], [ScanIndex::default(); 7]);
        let rle = encode(&dense, &grid, Axis::Z, 0, &mut runs, &mut vox, &mut scans).unwrap();
        let slice = rle.slice(0).unwrap();
        let busy = |j: usize| !slice.scanline(j).1.is_empty();
        for lo in 0..8 {
            for hi in 0..8 {
                let mut rows = (lo..=hi.min(5)).filter(|&j| busy(j));
                let first = rows.next();
                let expect = first.map(|a| (a, rows.next_back().unwrap_or(a)));
                assert_eq!(slice.visible_rows(lo, hi), expect, "rows {lo}..={hi}");
            }
        }
        assert_eq!(slice.visible_rows(0, usize::MAX), Some((1, 3)));
    }

    #[test]
    fn scanlines_of_an_unvalidated_slice_outside_its_arrays_read_as_empty() {
        // A slice built by hand, never validated: row 0 is sound, row 1 points past the
        // runs, rows 2 and 3 reach below the slice's base; rows past `nj` do not exist.
        let runs = [1u8, 1, 2, 0];
        let voxels = [Voxel::default(); 1];
        let at = |run: u32, voxel: u32| ScanIndex {
            run: 10 + run,
            voxel: 10 + voxel,
        };
        let scans = [at(0, 0), at(2, 1), at(9, 1), ScanIndex::default(), at(2, 0)];
        let slice = RleSlice {
            ni: 2,
            nj: 4,
            base: at(0, 0),
            runs: &runs,
            voxels: &voxels,
            scans: &scans,
            flat: &[],
        };
        assert!(slice.validate().is_err());
        assert_eq!(slice.scanline(0), (&runs[..2], &voxels[..]));
        for j in [1, 2, 3, 4, 5, usize::MAX] {
            assert_eq!(slice.scanline(j), (&[][..], &[][..]), "row {j}");
        }
        assert_eq!(slice.row(-1), (&[][..], &[][..]));
        // Walked in order, the same rows: the sound one, then nothing.
        let mut rows = slice.scanlines_from(0);
        assert_eq!(rows.next_row(), (&runs[..2], &voxels[..]));
        for j in 1..6 {
            assert_eq!(rows.next_row(), (&[][..], &[][..]), "walked row {j}");
        }
    }

    #[test]
    fn layouts_keep_the_principal_axis_last_and_pick_the_longer_side() {
        for bits in 0..8 {
            let l = Layout::from_bits(bits).unwrap();
            assert_eq!(l.bits(), bits);
            for axis in Axis::ALL {
                let p = l.permutation(axis);
                assert_eq!(p[2], axis as usize, "layout {bits}");
                assert_eq!(p[0] + p[1] + p[2], 3, "layout {bits}: {p:?}");
                assert_ne!(p[0], p[1]);
                let swapped = bits >> axis as u8 & 1 != 0;
                let c = axis.cycle();
                assert_eq!(p, if swapped { [c[1], c[0], c[2]] } else { c });
                assert_eq!(
                    l.permuted_dims(axis, [10, 20, 30]),
                    p.map(|a| [10, 20, 30][a])
                );
            }
        }
        assert_eq!(Layout::from_bits(8), None);
        for dims in [[301, 370, 316], [181, 217, 181], [5, 5, 5], [1, 9, 4]] {
            let l = Layout::fewest_rows(dims);
            for axis in Axis::ALL {
                let [ni, nj, _] = l.permuted_dims(axis, dims);
                assert!(ni >= nj, "{dims:?} {axis:?}: {ni} × {nj}");
            }
        }
        // Ties keep the cycle; the hires brain's z copy runs along y.
        assert_eq!(Layout::fewest_rows([5, 5, 5]), Layout::CYCLE);
        assert_eq!(Layout::fewest_rows([301, 370, 316]).bits(), 0b100);
    }

    #[test]
    fn scanlines_walked_in_order_are_those_looked_up() {
        // A slice of rows of every kind (empty, split runs, voxels at both ends), walked
        // from each row and from outside it.
        extern crate std;
        use std::vec;
        use std::vec::Vec;
        let grid = Grid::new([300, 6, 2], [1.0; 3]).unwrap();
        let dense: Vec<Voxel> = (0..grid.voxel_count())
            .map(|n| Voxel {
                opacity: [0, 9, 200][(n / 7 + n / 300) % 3] * u8::from(n / 300 % 6 != 2),
                scalar: n as u8,
                normal: n as u16,
            })
            .collect();
        let sz = measure(&dense, &grid, Axis::Z, 0).unwrap();
        let (mut runs, mut vox, mut scans) = (
            vec![0u8; sz.runs],
            vec![Voxel::default(); sz.voxels],
            vec![ScanIndex::default(); sz.scans],
        );
        let rle = encode(&dense, &grid, Axis::Z, 0, &mut runs, &mut vox, &mut scans).unwrap();
        for k in 0..2 {
            let slice = rle.slice(k).unwrap();
            assert!(slice.scanline(2).1.is_empty() && !slice.scanline(3).1.is_empty());
            for from in 0..9 {
                let mut rows = slice.scanlines_from(from);
                for j in from..from + 9 {
                    assert_eq!(
                        rows.next_row(),
                        slice.row(j),
                        "slice {k} from {from}: row {j}"
                    );
                }
            }
            // From a row above the slice, nothing (the compositor starts inside it).
            let mut rows = slice.scanlines_from(-1);
            assert!((0..9).all(|_| rows.next_row() == (&[][..], &[][..])));
        }
    }

    #[test]
    fn malformed_streams_are_rejected() {
        let grid = Grid::new([4, 1, 1], [1.0; 3]).unwrap();
        let v = [Voxel::default(); 2];
        let ok = [
            ScanIndex { run: 0, voxel: 0 },
            ScanIndex { run: 4, voxel: 2 },
        ];
        assert!(RleAxis::new(&grid, Axis::Z, &[1, 1, 1, 1], &v, &ok).is_ok());
        // Wrong sum.
        assert!(RleAxis::new(&grid, Axis::Z, &[1, 1, 1, 2], &v, &ok).is_err());
        // Odd run count.
        let odd = [
            ScanIndex { run: 0, voxel: 0 },
            ScanIndex { run: 3, voxel: 2 },
        ];
        assert!(RleAxis::new(&grid, Axis::Z, &[2, 1, 1], &v, &odd).is_err());
        // Voxel count mismatch.
        assert!(RleAxis::new(&grid, Axis::Z, &[1, 1, 2, 0], &v, &ok).is_err());
        // Index past the arrays.
        let far = [
            ScanIndex { run: 0, voxel: 0 },
            ScanIndex { run: 9, voxel: 2 },
        ];
        assert!(RleAxis::new(&grid, Axis::Z, &[1, 1, 1, 1], &v, &far).is_err());
        // Wrong index length.
        assert!(RleAxis::new(&grid, Axis::Z, &[1, 1, 1, 1], &v, &ok[..1]).is_err());
    }
}
