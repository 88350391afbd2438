//! Front-to-back compositing of sheared slices into the intermediate image
//! (Lacroute 1995, §4.1).
//!
//! For each slice the two voxel scanlines that straddle an intermediate scanline are
//! resampled bilinearly (the weights are the same for every pixel of the slice, because
//! the shear translates whole slices) and composited with the "over" operator.
//!
//! Work is skipped in two ways, both exact:
//! - the run-length-encoded voxel scanlines are walked in lockstep and only pixels whose
//!   footprint touches a non-transparent voxel are visited;
//! - pixels that reached the early-ray-termination opacity are skipped through a bitmap
//!   of opaque pixels ([`crate::opaque`]), which also tells each voxel row which of its
//!   voxels an open pixel will read, so only those are shaded.
//!
//! All arithmetic is Q15 integer. Voxel colours are shaded once per voxel row and slice
//! into a row buffer (premultiplied RGBA); each row is used by two intermediate scanlines.

use crate::classify::{ColorLanes, Voxel};
use crate::error::{need, Error};
use crate::fixed::{self, ONE};
use crate::opaque;
use crate::rle::RleSlice;
use crate::shade::{ShadeEntry, ShadeTable};
use crate::shadow::ShadowLookup;
use crate::view::{Factorization, SliceOffset};

/// Premultiplied RGBA, Q15 per channel.
pub type Rgba = [u16; 4];

/// Compositing mode.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// Front-to-back "over" compositing of shaded, classified samples.
    Composite,
    /// Maximum intensity projection of the resampled 8-bit scalar (grey output).
    /// Voxels classified transparent count as zero, so the opacity transfer function
    /// acts as a window.
    Mip,
}

/// Opacity-corrected Q15 opacity per stored 8-bit opacity. The entries are 32 bits wide
/// so that the vector shading kernels broadcast one straight from memory, but hold
/// 16-bit values: a table is made only from a `[u16; 256]`, so an opacity times any
/// Q15 factor fits 32 bits and every kernel reads the same value.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(transparent)]
pub struct OpacityTable([u32; 256]);

impl From<[u16; 256]> for OpacityTable {
    fn from(t: [u16; 256]) -> Self {
        OpacityTable(t.map(u32::from))
    }
}

impl OpacityTable {
    /// The corrected opacity of stored opacity `stored`.
    #[inline(always)]
    pub fn get(&self, stored: u8) -> u32 {
        self.0[stored as usize]
    }
}

/// Per-frame lookup tables the compositor reads.
#[derive(Clone, Copy)]
pub struct SliceTables<'a> {
    /// Opacity-corrected Q15 opacity per stored 8-bit opacity.
    pub opacity: &'a OpacityTable,
    /// Q15 RGB (and a padding lane) per quantised scalar.
    pub color: &'a ColorLanes,
    /// Shading per normal code ([`ShadeTable::UNSHADED`] for none).
    pub shade: &'a ShadeTable,
    /// Mode.
    pub mode: Mode,
    /// Early-ray-termination opacity, Q15; pixels at or above it are never touched again.
    pub ert: u32,
    /// Depth cueing, if on.
    pub depth: Option<&'a crate::depth::DepthFrame>,
    /// With shadows: the shading of the first light alone (then `shade` holds the
    /// ambient term and the other lights).
    pub shade0: Option<&'a ShadeTable>,
    /// Perspective views: the per-ray opacity-correction gains.
    pub ray_gain: Option<&'a crate::perspective::RayGain>,
}

/// The intermediate image, or a band of its scanlines: pixels plus the bitmap of opaque
/// pixels. Bands let several threads composite disjoint scanline ranges of one frame into
/// caller-owned memory (Lacroute 1995, ch. 6 partitions the intermediate image the same
/// way).
pub struct Intermediate<'a> {
    width: usize,
    height: usize,
    row0: usize,
    rows: usize,
    pub(crate) pixels: &'a mut [Rgba],
    /// Opaque-pixel bitmap, [`opaque::words`]`(width)` words per scanline.
    opaque: &'a mut [opaque::Word],
    stride: usize,
}

impl<'a> Intermediate<'a> {
    /// Borrows `pixels` (at least `width·height` entries) and `links` and clears them.
    /// `links` holds the opaque-pixel bitmap: at least [`opaque::words`]`(width)` entries
    /// per scanline. `width·height`, which the per-pixel links of earlier versions took,
    /// is always enough, so existing callers keep working.
    pub fn new(
        width: usize,
        height: usize,
        pixels: &'a mut [Rgba],
        links: &'a mut [opaque::Word],
    ) -> Result<Self, Error> {
        Self::band(width, height, 0, height, pixels, links)
    }

    /// Scanlines `row0..row0 + rows` of a `width×height` intermediate image, stored in
    /// `pixels` (at least `width·rows` entries) and `links` (at least
    /// [`opaque::words`]`(width)·rows`), both cleared here.
    pub fn band(
        width: usize,
        height: usize,
        row0: usize,
        rows: usize,
        pixels: &'a mut [Rgba],
        links: &'a mut [opaque::Word],
    ) -> Result<Self, Error> {
        if width >= u16::MAX as usize {
            return Err(Error::BadParameter {
                reason: "intermediate image wider than 65534 pixels",
            });
        }
        if row0 > height || rows > height - row0 {
            return Err(Error::BadParameter {
                reason: "band lies outside the intermediate image",
            });
        }
        let n = width * rows;
        let stride = opaque::words(width);
        need("intermediate pixels", n, pixels.len())?;
        need("intermediate links", stride * rows, links.len())?;
        let pixels = &mut pixels[..n];
        let opaque = &mut links[..stride * rows];
        pixels.fill([0; 4]);
        opaque.fill(0);
        Ok(Intermediate {
            width,
            height,
            row0,
            rows,
            pixels,
            opaque,
            stride,
        })
    }

    /// Keeps the first `rows` scanlines and returns the others, with their pixels and
    /// opaque bits as they are, as a band of their own. A thread that has run out of
    /// work takes over half of another's band this way between two slices, and
    /// composites the remaining slices into it ([`crate::render::composite_band_until`]
    /// from the position the other reached): the two bands then give the same pixels
    /// as the one would have.
    pub fn split_off(&mut self, rows: usize) -> Result<Intermediate<'a>, Error> {
        if rows > self.rows {
            return Err(Error::BadParameter {
                reason: "band split below its last scanline",
            });
        }
        let (p, tail_p) = core::mem::take(&mut self.pixels).split_at_mut(rows * self.width);
        let (o, tail_o) = core::mem::take(&mut self.opaque).split_at_mut(rows * self.stride);
        self.pixels = p;
        self.opaque = o;
        let tail = Intermediate {
            width: self.width,
            height: self.height,
            row0: self.row0 + rows,
            rows: self.rows - rows,
            pixels: tail_p,
            opaque: tail_o,
            stride: self.stride,
        };
        self.rows = rows;
        Ok(tail)
    }

    /// Scanlines held.
    pub fn rows(&self) -> usize {
        self.rows
    }

    /// Width in pixels.
    pub fn width(&self) -> usize {
        self.width
    }
    /// Height of the whole intermediate image.
    pub fn height(&self) -> usize {
        self.height
    }
    /// First scanline held.
    pub fn first_row(&self) -> usize {
        self.row0
    }
    /// Pixels of the held scanlines, row-major.
    pub fn pixels(&self) -> &[Rgba] {
        self.pixels
    }

    /// The opaque-pixel bitmap of held scanline `r` (relative to the band), or an empty
    /// slice (every pixel open) past the band.
    pub(crate) fn opaque_line(&self, r: usize) -> &[opaque::Word] {
        self.opaque
            .get(r * self.stride..(r + 1) * self.stride)
            .unwrap_or_default()
    }

    /// Pixels and opaque-pixel bitmap of held scanline `r` (relative to the band), or
    /// two empty slices past the band.
    #[cfg_attr(target_arch = "x86_64", inline(always))]
    pub(crate) fn scanline_mut(&mut self, r: usize) -> (&mut [Rgba], &mut [opaque::Word]) {
        let (w, s) = (self.width, self.stride);
        match (
            self.pixels.get_mut(r * w..(r + 1) * w),
            self.opaque.get_mut(r * s..(r + 1) * s),
        ) {
            (Some(p), Some(o)) => (p, o),
            _ => (&mut [], &mut []),
        }
    }

    /// Applies the per-pixel depth-cue factor to every held scanline.
    pub fn apply_depth_cue(&mut self, d: &crate::depth::DepthFrame) {
        if self.width == 0 {
            return;
        }
        for (r, row) in self.pixels.chunks_mut(self.width).enumerate() {
            d.apply_row(self.row0 + r, row);
        }
    }
}

/// Row-buffer entries the compositor needs for slices `ni` voxels wide (two rows with a
/// guard entry on each side) in parallel projection.
pub const fn row_buffer_len(ni: usize) -> usize {
    2 * (ni + 2)
}

/// Row-buffer entries [`composite_slice`] needs for `view` (perspective views need a
/// ring of intermediate-width rows, see [`crate::perspective::row_buffer_len`]).
pub fn rows_needed(view: &Factorization) -> usize {
    match view.perspective {
        Some(_) => crate::perspective::row_buffer_len(view),
        None => row_buffer_len(view.dims[0]),
    }
}

/// Non-transparent spans `[start, end)` of one scanline's runs; adjacent runs split at 255
/// come out as one span.
pub(crate) struct Spans<'a> {
    /// The pairs not read yet, starting at a transparent run.
    runs: &'a [u8],
    pos: usize,
}

impl<'a> Spans<'a> {
    pub(crate) fn new(runs: &'a [u8]) -> Self {
        Spans { runs, pos: 0 }
    }
}

impl Iterator for Spans<'_> {
    type Item = (usize, usize);
    #[cfg_attr(target_arch = "x86_64", inline(always))]
    #[cfg_attr(not(target_arch = "x86_64"), inline)]
    fn next(&mut self) -> Option<(usize, usize)> {
        // Runs alternate transparent, visible. The pairs are taken off the front of the
        // slice (a length test each) rather than indexed by a cursor (a range check each:
        // the MR head, callgrind: 2.1 % fewer instructions a frame).
        loop {
            let (&[clear, visible], rest) = self.runs.split_first_chunk::<2>()?;
            self.runs = rest;
            self.pos += clear as usize;
            if visible == 0 {
                continue;
            }
            let start = self.pos;
            self.pos += visible as usize;
            // Merge continuations (zero-length transparent runs).
            while let Some((&[0, more], rest)) = self.runs.split_first_chunk::<2>() {
                self.runs = rest;
                self.pos += more as usize;
            }
            return Some((start, self.pos));
        }
    }
}

/// A shaded voxel row: premultiplied colours at buffer index `i + 1` for voxel `i`, zero
/// elsewhere, plus the range that holds non-zero entries (to clear it cheaply).
pub(crate) struct Row<'b> {
    pub(crate) buf: &'b mut [Rgba],
    dirty: (usize, usize),
    /// The runs of entries written since the last clear, `written` of them, when there
    /// are at most [`Row::RUNS`]; more (or an unknown set) clear the whole extent.
    /// Behind opaque pixels a row's shaded voxels are a few short runs at the ends of a
    /// wide extent, so clearing the runs alone saves zeroing the rest: the MR head,
    /// 256², shades 5.7 voxels a run and 1.7 runs a row.
    runs: [(usize, usize); Row::RUNS],
    written: usize,
}

impl<'b> Row<'b> {
    /// A row over `buf` (at least `ni + 2` entries for slices `ni` wide), cleared unless
    /// `clean` says it already is.
    pub(crate) fn new(buf: &'b mut [Rgba], clean: bool) -> Self {
        let n = if clean { 0 } else { buf.len() };
        Row::cleared(buf, (0, n))
    }

    /// A row over `buf` whose entries `dirty` may be non-zero, cleared.
    fn cleared(buf: &'b mut [Rgba], dirty: (usize, usize)) -> Self {
        let mut r = Row {
            buf,
            dirty,
            runs: [(0, 0); Row::RUNS],
            written: Row::UNKNOWN,
        };
        r.clear();
        r
    }

    /// The two row buffers for slices `ni` wide (`rows` holds at least
    /// [`row_buffer_len`]`(ni)` entries), cleared unless `clean` says they already are.
    fn pair(rows: &'b mut [Rgba], ni: usize, clean: bool) -> (Row<'b>, Row<'b>) {
        let rows = rows.get_mut(..row_buffer_len(ni)).unwrap_or_default();
        let (r0, r1) = rows.split_at_mut_checked(ni + 2).unwrap_or_default();
        let all = if clean { (0, 0) } else { (0, ni + 2) };
        (Row::cleared(r0, all), Row::cleared(r1, all))
    }

    /// Buffer indices `[lo, hi)` that may hold non-zero entries, `None` if none.
    #[inline]
    fn extent(&self) -> Option<(usize, usize)> {
        (self.dirty.0 < self.dirty.1).then_some(self.dirty)
    }

    /// True if every entry outside [`Row::extent`] is zero (tests).
    #[cfg(test)]
    pub(crate) fn zero_outside_extent(&self) -> bool {
        let (lo, hi) = self.extent().unwrap_or((0, 0));
        self.buf[..lo]
            .iter()
            .chain(&self.buf[hi..])
            .all(|p| *p == [0; 4])
    }

    /// Zeroes the entries that may be non-zero. Out of line, as it was when its slicing
    /// could panic: inlined into its callers it cost the head's frames 0.4 % more
    /// instructions and the hires brain's 0.6 % (callgrind, x86-64-v3).
    #[inline(never)]
    pub(crate) fn clear(&mut self) {
        let (a, b) = self.dirty;
        let b = b.min(self.buf.len());
        if a < b {
            // Without runs kept (`RUNS` 0) the test folds away and the extent is cleared.
            match self.runs.get(..self.written).filter(|_| Row::RUNS != 0) {
                Some(runs) => {
                    for &(x, y) in runs {
                        if let Some(r) = self.buf.get_mut(x..y) {
                            r.fill([0; 4]);
                        }
                    }
                }
                None => self.buf[a..b].fill([0; 4]),
            }
        }
        self.dirty = (0, 0);
        self.written = 0;
    }

    /// Most runs [`Row::clear`] keeps. None on other targets: the Cortex-M3 frame took
    /// 1.5 % more instructions keeping them (it has no cache for the extent's zeroes to
    /// miss in).
    #[cfg(target_arch = "x86_64")]
    const RUNS: usize = 8;
    #[cfg(not(target_arch = "x86_64"))]
    const RUNS: usize = 0;
    /// `written` when the runs are not known.
    const UNKNOWN: usize = usize::MAX;

    /// Notes that entries `x..y` were written.
    #[inline(always)]
    fn wrote(&mut self, x: usize, y: usize) {
        // Nothing to note without runs kept: written as a test on `RUNS` rather than
        // left to the bound check below, the Cortex-M3 frame takes 0.4 % fewer
        // instructions.
        if Row::RUNS == 0 {
            return;
        }
        if let Some(r) = self.runs.get_mut(self.written) {
            *r = (x, y);
            self.written += 1;
        } else {
            self.written = Row::UNKNOWN;
        }
    }

    /// `shading` shades voxels `x..y` of row `j` from `src` (voxel `x` first) into a row
    /// that holds the row's other shaded voxels or nothing (the perspective compositor
    /// shades a row piece by piece, as its pixels ask).
    #[cfg_attr(target_arch = "x86_64", inline(always))]
    pub(crate) fn shade(
        &mut self,
        src: &[Voxel],
        (x, y): (usize, usize),
        t: &SliceTables<'_>,
        j: i64,
        k: &impl Kernels,
        shading: &impl Shading,
    ) {
        let Some(dst) = self.buf.get_mut(x + 1..y + 1) else {
            return;
        };
        shading.shade_run(dst, src, x, t, j, k);
        self.wrote(x + 1, y + 1);
        self.dirty = match self.extent() {
            Some((lo, hi)) => (lo.min(x + 1), hi.max(y + 1)),
            None => (x + 1, y + 1),
        };
    }

    /// `shading` shades the voxels of row `j` (see [`Shading`]). With `needed`, only
    /// voxels some non-opaque pixel will read are shaded (the others stay zero, and only
    /// opaque pixels, which are never composited again, would read them).
    #[allow(clippy::too_many_arguments)]
    #[cfg_attr(target_arch = "x86_64", inline(always))]
    pub(crate) fn fill(
        &mut self,
        runs: &[u8],
        voxels: &[Voxel],
        t: &SliceTables<'_>,
        j: i64,
        needed: Option<&Needed<'_>>,
        k: &impl Kernels,
        shading: &impl Shading,
    ) {
        self.clear();
        let mut v = 0usize;
        let mut lo = usize::MAX;
        let mut hi = 0;
        // The last window of needed voxels computed: its first voxel and its bits
        // ([`Needed::voxels`]).
        let mut word = (usize::MAX / 2, 0u64);
        for (a, b) in Spans::new(runs) {
            let base = v;
            v += b - a;
            match needed {
                None => {
                    lo = lo.min(a + 1);
                    hi = b + 1;
                    // Both in bounds for a validated slice and a buffer of
                    // `row_buffer_len` entries; a run past them is not shaded.
                    // `shade_run` shades as many voxels as `dst` holds.
                    let (Some(dst), Some(src)) =
                        (self.buf.get_mut(a + 1..b + 1), voxels.get(base..))
                    else {
                        continue;
                    };
                    shading.shade_run(dst, src, a, t, j, k);
                    self.wrote(a + 1, b + 1);
                }
                Some(n) => {
                    // Shade only the voxels that open pixels of the reading scanlines
                    // reach, 64 at a time from the opaque-pixel bitmaps; a span that
                    // starts inside the last window of 64 computed reads it from there.
                    let mut x = a;
                    while x < b {
                        // Voxels x.. are bits off.. of the window, if it holds them.
                        let mut off = x.wrapping_sub(word.0);
                        if off >= 64 {
                            word = (x, n.voxels(x));
                            off = 0;
                        }
                        let mut m = (word.1 >> off) & opaque::ones((b - x).min(64 - off));
                        let at = x;
                        x = word.0 + 64;
                        while m != 0 {
                            let z = m.trailing_zeros() as usize;
                            let len = (!(m >> z)).trailing_zeros() as usize;
                            let (c, d) = (at + z, at + z + len);
                            m &= !opaque::ones(z + len);
                            // The extent covers shaded voxels only: the others stay
                            // zero, and zero taps leave a pixel as it is.
                            lo = lo.min(c + 1);
                            hi = d + 1;
                            let (Some(dst), Some(src)) =
                                (self.buf.get_mut(c + 1..d + 1), voxels.get(base + (c - a)..))
                            else {
                                continue;
                            };
                            shading.shade_run(dst, src, c, t, j, k);
                            self.wrote(c + 1, d + 1);
                        }
                    }
                }
            }
        }
        if lo < hi {
            self.dirty = (lo, hi);
        }
    }
}

/// Which voxels of a row some open pixel reads: voxel `i` feeds pixels `i + shift` and
/// `i + shift + 1` of the (up to two) scanlines that use the row.
pub(crate) struct Needed<'a> {
    lines: [Option<&'a [opaque::Word]>; 2],
    width: usize,
    shift: i64,
}

impl<'a> Needed<'a> {
    /// The scanlines `v0` and `v0 + 1`, where they lie in the band `img` holds. Inlined
    /// on x86-64, where as a call its six-word result went through the stack (see
    /// [`RleSlice::scanline`]).
    #[cfg_attr(target_arch = "x86_64", inline(always))]
    fn lines(img: &'a Intermediate<'_>, v0: i64, shift: i64) -> Self {
        let stride = img.stride;
        // Scanline v0 relative to the band; a negative one wraps to past the band.
        let r = (v0 - img.row0 as i64) as u64;
        let rows = img.rows as u64;
        // Both in the band, the common case: one slice, split (the MR head, callgrind:
        // 4.6 % fewer instructions a frame than two lookups).
        let both = (r < rows.saturating_sub(1))
            .then(|| {
                let s = r as usize * stride;
                img.opaque.get(s..s + 2 * stride)
            })
            .flatten();
        let lines = match both.and_then(|two| two.split_at_checked(stride)) {
            Some((a, b)) => [Some(a), Some(b)],
            None => {
                let at = |r: u64| (r < rows).then(|| img.opaque_line(r as usize));
                [at(r), at(r.wrapping_add(1))]
            }
        };
        Needed {
            lines,
            width: img.width,
            shift,
        }
    }

    /// What open pixels read of the visible voxels of the `ni`-voxel scanline `runs`.
    fn reach(&self, runs: &[u8], ni: usize) -> Reach {
        let Some((first, last)) = visible_extent(runs, ni) else {
            return Reach::Nothing;
        };
        // Voxels first..last feed pixels first + shift ..= last + shift.
        let (a, b) = (first as i64 + self.shift, last as i64 + self.shift + 1);
        // Each test holds for a scanline outside the band, which reads nothing.
        let [l0, l1] = self.lines;
        let all =
            |l: Option<&[opaque::Word]>| l.is_none_or(|l| opaque::all_closed(l, self.width, a, b));
        let none =
            |l: Option<&[opaque::Word]>| l.is_none_or(|l| opaque::none_closed(l, self.width, a, b));
        if all(l0) && all(l1) {
            Reach::Nothing
        } else if none(l0) && none(l1) {
            Reach::Everything
        } else {
            Reach::Some
        }
    }

    /// True if no open pixel reads any visible voxel of the `ni`-voxel scanline `runs`.
    #[cfg(test)]
    fn hides(&self, runs: &[u8], ni: usize) -> bool {
        self.reach(runs, ni) == Reach::Nothing
    }

    /// Bit `t` set if voxel `x + t` is read by an open pixel: it is not when both of its
    /// pixels are closed in both scanlines.
    #[inline(always)]
    fn voxels(&self, x: usize) -> u64 {
        let p = x as i64 + self.shift;
        // A scanline outside the band reads nothing: all closed. Written out for the two
        // lines rather than as a loop over the present ones (the MR head, callgrind: 3.8 %
        // fewer instructions a frame).
        let (c, next) = match self.lines {
            [Some(l0), Some(l1)] => opaque::closed65_both(l0, l1, self.width, p),
            [Some(l), None] | [None, Some(l)] => opaque::closed65(l, self.width, p),
            [None, None] => (u64::MAX, true),
        };
        // Bit t of `right`: pixel p + t + 1.
        let right = (c >> 1) | (next as u64) << 63;
        !(c & right)
    }
}

/// What the open pixels of a voxel row's reading scanlines read of its visible voxels
/// ([`Needed::reach`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Reach {
    /// None of them: the row is neither streamed into the cache nor shaded.
    Nothing,
    /// All of them, as far as the pixels they feed go: no pixel there is opaque, so the
    /// row is shaded without asking which voxels are needed.
    Everything,
    /// Some of them.
    Some,
}

/// The voxels `[first, last)` from a scanline's first to its last visible voxel (`ni`
/// wide), from the runs at its two ends; `None` if it has none.
fn visible_extent(runs: &[u8], ni: usize) -> Option<(usize, usize)> {
    let mut first = 0;
    let mut seen = false;
    for pair in runs.chunks_exact(2) {
        first += pair[0] as usize;
        if pair[1] != 0 {
            seen = true;
            break;
        }
    }
    if !seen {
        return None;
    }
    // Trailing transparency: the transparent runs of the pairs at the end whose visible
    // run is empty (a long run is split into such pairs), then nothing more.
    let mut trailing = 0;
    for pair in runs.rchunks_exact(2) {
        if pair[1] != 0 {
            break;
        }
        trailing += pair[0] as usize;
    }
    let last = ni.saturating_sub(trailing);
    (first < last).then_some((first, last))
}

/// How a slice's voxels are shaded into a row buffer: chosen once per slice from the
/// mode, the shadows and the depth-cue factor, so that an instruction-set build compiles
/// the slice loop for each way apart, without the choice on every run. On Zen 2, with
/// the choice made per run, the x86-64-v3 compositor's code was 39 KB; with the common
/// case alone it was 30 KB, and the MR head's frame (256², one thread) took 4.58 ms
/// instead of 4.92.
pub(crate) trait Shading {
    /// Shades voxels `src` (the first at index `first` of row `j`) into `out`, as many
    /// as `out` holds (`src` may run on past them).
    fn shade_run(
        &self,
        out: &mut [Rgba],
        src: &[Voxel],
        first: usize,
        t: &SliceTables<'_>,
        j: i64,
        k: &impl Kernels,
    );
}

/// Composite mode, unshadowed, without depth cueing: the premultiplied shaded colour.
pub(crate) struct Lit;

impl Shading for Lit {
    #[inline(always)]
    fn shade_run(
        &self,
        out: &mut [Rgba],
        src: &[Voxel],
        _: usize,
        t: &SliceTables<'_>,
        _: i64,
        k: &impl Kernels,
    ) {
        for (o, vox) in out.iter_mut().zip(src) {
            let alpha = t.opacity.get(vox.opacity);
            let c = &t.color[vox.scalar as usize];
            *o = k.premultiply(c, t.shade.entry_ref(vox.normal), alpha);
        }
    }
}

/// Composite mode, unshadowed, with the slice's depth-cue factor (Q15, below one) on
/// the colour but not on the opacity.
pub(crate) struct Cued(pub u32);

impl Shading for Cued {
    #[inline(always)]
    fn shade_run(
        &self,
        out: &mut [Rgba],
        src: &[Voxel],
        _: usize,
        t: &SliceTables<'_>,
        _: i64,
        k: &impl Kernels,
    ) {
        for (o, vox) in out.iter_mut().zip(src) {
            let alpha = t.opacity.get(vox.opacity);
            let c = &t.color[vox.scalar as usize];
            let a = fixed::mul(alpha, self.0);
            let [r, g, b, _] = k.premultiply(c, t.shade.entry_ref(vox.normal), a);
            *o = [r, g, b, alpha as u16];
        }
    }
}

/// Composite mode with shadows: the first light's table `lit` weighted by the shadow
/// buffer's transmittance, the other lights' from the slice tables, and the depth-cue
/// factor `scale` (Q15).
pub(crate) struct Shadowed<'a, 'b> {
    pub shadow: &'a ShadowLookup<'b>,
    pub lit: &'a ShadeTable,
    pub scale: u32,
}

impl Shading for Shadowed<'_, '_> {
    #[inline(always)]
    fn shade_run(
        &self,
        out: &mut [Rgba],
        src: &[Voxel],
        first: usize,
        t: &SliceTables<'_>,
        j: i64,
        _: &impl Kernels,
    ) {
        for (idx, (o, vox)) in out.iter_mut().zip(src).enumerate() {
            let alpha = t.opacity.get(vox.opacity);
            let [r, g, b, _] = t.color[vox.scalar as usize];
            let base = [r, g, b];
            let rest = t.shade.shade_raw(vox.normal, base);
            let lit = self.lit.shade_raw(vox.normal, base);
            let tr = self.shadow.transmittance(first + idx, j);
            let am = fixed::mul(alpha, self.scale);
            let mut px = [0u16; 4];
            for c in 0..3 {
                let v = (rest[c] + fixed::mul(lit[c].min(2 * ONE), tr)).min(ONE);
                px[c] = fixed::mul(v, am) as u16;
            }
            px[3] = alpha as u16;
            *o = px;
        }
    }
}

/// Maximum intensity projection: the voxel's scalar in every channel.
pub(crate) struct Mip;

impl Shading for Mip {
    #[inline(always)]
    fn shade_run(
        &self,
        out: &mut [Rgba],
        src: &[Voxel],
        _: usize,
        _: &SliceTables<'_>,
        _: i64,
        _: &impl Kernels,
    ) {
        for (o, vox) in out.iter_mut().zip(src) {
            let g = fixed::from_u8(vox.scalar) as u16;
            *o = [g; 4];
        }
    }
}

/// The way a slice's voxels are shaded, from its mode, its shadows and its depth-cue
/// factor `scale` ([`Way::of`], the one place that chooses). As a [`Shading`] it asks
/// which way on every run: one copy of the slice loop for all of them, as bare-metal
/// targets keep it (for flash), and as the slices that are rarely hot (supersampled
/// ones) use it. The x86-64 builds compile the slice loop for each way instead.
pub(crate) enum Way<'a, 'b> {
    Lit,
    Cued(u32),
    Shadowed(Shadowed<'a, 'b>),
    Mip,
}

impl<'a, 'b> Way<'a, 'b> {
    /// The way for tables `t`, the shadow lookup of the slice if any and its depth-cue
    /// factor (Q15).
    pub(crate) fn of(
        t: &SliceTables<'a>,
        shadow: Option<&'a ShadowLookup<'b>>,
        scale: u32,
    ) -> Self {
        match (t.mode, shadow, t.shade0) {
            (Mode::Composite, Some(shadow), Some(lit)) => {
                Way::Shadowed(Shadowed { shadow, lit, scale })
            }
            (Mode::Composite, _, _) if scale < ONE => Way::Cued(scale),
            (Mode::Composite, _, _) => Way::Lit,
            (Mode::Mip, _, _) => Way::Mip,
        }
    }
}

impl Shading for Way<'_, '_> {
    #[inline(always)]
    fn shade_run(
        &self,
        out: &mut [Rgba],
        src: &[Voxel],
        first: usize,
        t: &SliceTables<'_>,
        j: i64,
        k: &impl Kernels,
    ) {
        match self {
            Way::Lit => Lit.shade_run(out, src, first, t, j, k),
            Way::Cued(scale) => Cued(*scale).shade_run(out, src, first, t, j, k),
            Way::Shadowed(s) => s.shade_run(out, src, first, t, j, k),
            Way::Mip => Mip.shade_run(out, src, first, t, j, k),
        }
    }
}

/// Merges two sorted span streams into sorted, disjoint pixel spans after translating by
/// `shift` and widening each by one pixel on the right (a voxel at `i` reaches pixels
/// `i + shift` and `i + shift + 1`).
pub(crate) struct MergedSpans<'a> {
    pub(crate) a: core::iter::Peekable<Spans<'a>>,
    pub(crate) b: core::iter::Peekable<Spans<'a>>,
}

impl Iterator for MergedSpans<'_> {
    type Item = (usize, usize);
    #[inline]
    fn next(&mut self) -> Option<(usize, usize)> {
        let pick = |a: &mut core::iter::Peekable<Spans<'_>>,
                    b: &mut core::iter::Peekable<Spans<'_>>|
         -> Option<(usize, usize)> {
            match (a.peek(), b.peek()) {
                (Some(x), Some(y)) => {
                    if x.0 <= y.0 {
                        a.next()
                    } else {
                        b.next()
                    }
                }
                (Some(_), None) => a.next(),
                (None, _) => b.next(),
            }
        };
        let (s, mut e) = pick(&mut self.a, &mut self.b)?;
        e += 1;
        loop {
            let nxt = match (self.a.peek(), self.b.peek()) {
                (Some(x), Some(y)) => x.0.min(y.0),
                (Some(x), None) => x.0,
                (None, Some(y)) => y.0,
                (None, None) => break,
            };
            if nxt > e {
                break;
            }
            let (_, e2) = pick(&mut self.a, &mut self.b)?;
            e = e.max(e2 + 1);
        }
        Some((s, e))
    }
}

/// The steps an instruction-set build of the compositor may replace (see
/// [`crate::render::composite_band_until_x86_v3`]): warming the cache for a row, shading
/// a voxel, compositing a run of pixels. Everything else is shared.
pub(crate) trait Kernels {
    /// Warms the cache for a voxel row the compositor reads two rows later.
    fn warm(&self, voxels: &[Voxel]);
    /// Shades colour `c` with `e` and premultiplies it by `alpha` (Q15):
    /// [`premultiply`] or a bit-identical vector version.
    fn premultiply(&self, c: &[u16; 4], e: &ShadeEntry, alpha: u32) -> Rgba;
    /// Resamples and composites a run of open pixels: [`over_run`] or a bit-identical
    /// vector version. Returns at least the highest opacity of the run's pixels
    /// afterwards: pixels below the early-ray-termination threshold are not looked at
    /// for the opaque mark when it is below it.
    fn over_run(&self, px: &mut [Rgba], top: &[Rgba], bot: &[Rgba], w: [u32; 4]) -> u16;
    /// Bit `i` set where pixel `px[i]` (at most 64 pixels) reached opacity `thr`
    /// (`thr >= 1`): [`closed_bits`] or a bit-identical vector version.
    fn closed_bits(&self, px: &[Rgba], thr: u32) -> u64;
    /// Composites a slice of a perspective view ([`crate::perspective::composite_slice`])
    /// with these kernels, in a function of its own compiled for the build's
    /// instruction set: inlined into the band compositor instead, it made frames slower.
    fn perspective(&self, job: SliceJob<'_, '_>) -> Result<(), Error>;
}

/// One slice to composite: slice `k` into the scanlines `img` holds, with `rows` as the
/// row buffer, all zero if `clean` ([`Kernels::perspective`], and the parallel scanline
/// loop).
pub(crate) struct SliceJob<'a, 'b> {
    pub img: &'a mut Intermediate<'b>,
    pub slice: &'a RleSlice<'a>,
    pub k: usize,
    pub view: &'a Factorization,
    pub tables: &'a SliceTables<'a>,
    pub rows: &'a mut [Rgba],
    pub clean: bool,
}

/// The portable kernels: [`touch`], [`premultiply`], [`closed_bits`] and [`over_run`],
/// which does not keep the run's highest opacity: as a reduction in its loop it stopped
/// the compiler from vectorising the loop for baseline x86-64 (spheres256: 34 → 43 ms a
/// frame), and on the Cortex-M3 it cost as much as it saved. So every run is looked at.
pub(crate) struct Portable;

impl Kernels for Portable {
    #[inline(always)]
    fn warm(&self, voxels: &[Voxel]) {
        touch(voxels)
    }
    #[inline(always)]
    fn premultiply(&self, c: &[u16; 4], e: &ShadeEntry, alpha: u32) -> Rgba {
        premultiply(c, e, alpha)
    }
    #[inline(always)]
    fn over_run(&self, px: &mut [Rgba], top: &[Rgba], bot: &[Rgba], w: [u32; 4]) -> u16 {
        over_run_unranked(px, top, bot, w)
    }
    #[inline(always)]
    fn closed_bits(&self, px: &[Rgba], thr: u32) -> u64 {
        closed_bits(px, thr)
    }
    #[inline(always)]
    fn perspective(&self, job: SliceJob<'_, '_>) -> Result<(), Error> {
        crate::perspective::composite_slice(job, self)
    }
}

/// Kernels given as closures: an instruction-set build writes them inside its
/// `target_feature` function, so they are compiled with its features (and may call the
/// vector intrinsics those features make safe). Only the x86-64 builds have such
/// functions.
#[cfg(target_arch = "x86_64")]
pub(crate) struct With<W, P, O, C, S>(pub W, pub P, pub O, pub C, pub S);

#[cfg(target_arch = "x86_64")]
impl<W, P, O, C, S> Kernels for With<W, P, O, C, S>
where
    W: Fn(&[Voxel]),
    P: Fn(&[u16; 4], &ShadeEntry, u32) -> Rgba,
    O: Fn(&mut [Rgba], &[Rgba], &[Rgba], [u32; 4]) -> u16,
    C: Fn(&[Rgba], u32) -> u64,
    S: Fn(SliceJob<'_, '_>) -> Result<(), Error>,
{
    #[inline(always)]
    fn warm(&self, voxels: &[Voxel]) {
        (self.0)(voxels)
    }
    #[inline(always)]
    fn premultiply(&self, c: &[u16; 4], e: &ShadeEntry, alpha: u32) -> Rgba {
        (self.1)(c, e, alpha)
    }
    #[inline(always)]
    fn over_run(&self, px: &mut [Rgba], top: &[Rgba], bot: &[Rgba], w: [u32; 4]) -> u16 {
        (self.2)(px, top, bot, w)
    }
    #[inline(always)]
    fn closed_bits(&self, px: &[Rgba], thr: u32) -> u64 {
        (self.3)(px, thr)
    }
    #[inline(always)]
    fn perspective(&self, job: SliceJob<'_, '_>) -> Result<(), Error> {
        (self.4)(job)
    }
}

/// A voxel's premultiplied colour, Q15: `min(1, c·D + S)·α` for red, green and blue from
/// its colour and shading entry, and `α` after them. The fourth lanes of `c` and `e`
/// are padding ([`ColorLanes`], [`ShadeEntry`]) and are not used.
#[inline(always)]
pub(crate) fn premultiply(c: &[u16; 4], e: &ShadeEntry, alpha: u32) -> Rgba {
    let mut out = [0, 0, 0, alpha as u16];
    for ch in 0..3 {
        let x = fixed::mul(c[ch] as u32, e.diffuse[ch] as u32) + e.specular[ch] as u32;
        out[ch] = fixed::mul(x.min(ONE), alpha) as u16;
    }
    out
}

/// [`premultiply`] in SSE4.1 vectors: the voxel's four lanes in one 128-bit register,
/// the padding lane computed along and then replaced by `α` (the compiler kept the
/// channels in scalar registers: 44 instructions a voxel in the x86-64-v4 build against
/// 27 here). A macro expanding to a closure, because the intrinsics are safe to call
/// only where SSE4.1 is enabled: it is written inside the x86-64-v3 and v4 compositors.
#[cfg(target_arch = "x86_64")]
macro_rules! premultiply_sse41 {
    () => {
        |c: &[u16; 4], e: &$crate::shade::ShadeEntry, alpha: u32| -> $crate::composite::Rgba {
            use core::arch::x86_64::*;
            let lanes = |x: &[u16; 4]| _mm_cvtepu16_epi32(_mm_cvtsi64_si128(bytemuck::cast(*x)));
            let half = _mm_set1_epi32(1 << 14);
            let d = _mm_mullo_epi32(lanes(c), lanes(&e.diffuse));
            let x = _mm_add_epi32(
                _mm_srli_epi32::<15>(_mm_add_epi32(d, half)),
                lanes(&e.specular),
            );
            let a = _mm_set1_epi32(alpha as i32);
            let x = _mm_min_epu32(x, _mm_set1_epi32($crate::fixed::ONE as i32));
            let x = _mm_mullo_epi32(x, a);
            let x = _mm_srli_epi32::<15>(_mm_add_epi32(x, half));
            // The padding lane becomes α, from the vector it was broadcast into.
            let x = _mm_blend_epi16::<0xC0>(x, a);
            let p = _mm_packus_epi32(x, x);
            bytemuck::cast(_mm_cvtsi128_si64(p))
        }
    };
}
#[cfg(target_arch = "x86_64")]
pub(crate) use premultiply_sse41;

/// [`over_run`] by `N` pixels at a time with `step`, which composites `N` pixels
/// (given by value) from `N + 1` entries of each row and returns them with their lanes
/// as a vector; runs shorter than `N` go to `short`. The run's highest opacity is kept
/// lane by lane in a vector (`most`, one maximum a step) and read out once at the end
/// (`opacity_of`): per step, pulling the two opacities out of the vector and comparing
/// them in scalar registers cost 7 of the AVX2 step's 35 instructions. The step at the
/// end overlaps the one before it rather than running past the run: it is computed
/// first, from the pixels as they were, and stored last, so the pixels both cover get
/// the same value twice.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) fn by_steps<const N: usize, M: Copy>(
    px: &mut [Rgba],
    top: &[Rgba],
    bot: &[Rgba],
    step: impl Fn([Rgba; N], &[Rgba], &[Rgba]) -> ([Rgba; N], M),
    most: impl Fn(M, M) -> M,
    opacity_of: impl FnOnce(M) -> u16,
    short: impl FnOnce(&mut [Rgba], &[Rgba], &[Rgba]) -> u16,
) -> u16 {
    let n = px.len();
    let Some(end) = n.checked_sub(N) else {
        return short(px, top, bot);
    };
    let (top, bot) = (&top[..n + 1], &bot[..n + 1]);
    let at = |px: &[Rgba], u: usize| -> [Rgba; N] { core::array::from_fn(|k| px[u + k]) };
    let (last, mut hi) = step(at(px, end), &top[end..], &bot[end..]);
    let mut u = 0;
    while u < end {
        let (out, m) = step(at(px, u), &top[u..], &bot[u..]);
        hi = most(hi, m);
        px[u..u + N].copy_from_slice(&out);
        u += N;
    }
    px[end..].copy_from_slice(&last);
    opacity_of(hi)
}

/// [`over_run`] in AVX2 or AVX-512 vectors, 2 or 4 pixels a step ([`by_steps`]): each
/// pixel's four channels are four 32-bit lanes of one 128-bit part of a register, so the
/// bilinear taps are plain loads of neighbouring buffer entries and the pixel's own
/// opacity is a shuffle. The compiler's version keeps one channel of eight pixels a
/// register and spends most of its instructions regrouping channels (callgrind,
/// spheres256, x86-64-v3: about 39 instructions a pixel). AVX-512 hands runs shorter
/// than four pixels to the AVX2 version, which hands single pixels to [`over_run`].
///
/// Bit-identical to [`over_run`] for any `u16` taps: every intermediate fits its 32-bit
/// lane (a tap sum is at most `ONE·65535`, a product with `1 − α` at most
/// `65535·ONE`), and the results, at most [`ONE`], narrow to `u16` unchanged. A macro
/// expanding to a closure, written inside the x86-64-v3 and v4 compositors (see
/// [`premultiply_sse41`]).
#[cfg(target_arch = "x86_64")]
macro_rules! over_run_simd {
    (avx2) => {
        |px: &mut [$crate::composite::Rgba],
         top: &[$crate::composite::Rgba],
         bot: &[$crate::composite::Rgba],
         w: [u32; 4]| {
            use core::arch::x86_64::*;
            type Rgba = $crate::composite::Rgba;
            let step = $crate::composite::over_run_simd!(
                step 2, w,
                _mm256_set1_epi32, _mm256_add_epi32, _mm256_sub_epi32, _mm256_mullo_epi32,
                _mm256_srli_epi32, _mm256_min_epu32, _mm256_shuffle_epi32,
                |q: [Rgba; 2]| _mm256_cvtepu16_epi32(bytemuck::cast(q)),
                |r| -> [Rgba; 2] {
                    // Pack each 128-bit half to u16 and bring the two pixels together.
                    let packed = _mm256_permute4x64_epi64::<0b1000>(_mm256_packus_epi32(r, r));
                    bytemuck::cast(_mm256_castsi256_si128(packed))
                }
            );
            // The opacities are lanes 3 and 7, each at most `ONE`.
            let opacity = |m: __m256i| {
                (_mm256_extract_epi32::<3>(m) as u32).max(_mm256_extract_epi32::<7>(m) as u32)
                    as u16
            };
            $crate::composite::by_steps::<2, __m256i>(
                px,
                top,
                bot,
                step,
                |a, b| _mm256_max_epu32(a, b),
                opacity,
                |p, t, b| {
                    $crate::composite::over_run(p, t, b, w);
                    $crate::composite::highest(p)
                },
            )
        }
    };
    (avx512) => {
        |px: &mut [$crate::composite::Rgba],
         top: &[$crate::composite::Rgba],
         bot: &[$crate::composite::Rgba],
         w: [u32; 4]| {
            use core::arch::x86_64::*;
            type Rgba = $crate::composite::Rgba;
            let step = $crate::composite::over_run_simd!(
                step 4, w,
                _mm512_set1_epi32, _mm512_add_epi32, _mm512_sub_epi32, _mm512_mullo_epi32,
                _mm512_srli_epi32, _mm512_min_epu32, _mm512_shuffle_epi32,
                |q: [Rgba; 4]| _mm512_cvtepu16_epi32(bytemuck::cast(q)),
                |r| -> [Rgba; 4] { bytemuck::cast(_mm512_cvtepi32_epi16(r)) }
            );
            let short = $crate::composite::over_run_simd!(avx2);
            // The opacities are lanes 3, 7, 11 and 15.
            $crate::composite::by_steps::<4, __m512i>(
                px,
                top,
                bot,
                step,
                |a, b| _mm512_max_epu32(a, b),
                |m| _mm512_mask_reduce_max_epu32(0x8888, m) as u16,
                |p, t, b| short(p, t, b, w),
            )
        }
    };
    // One step of N pixels.
    (step $n:literal, $w:expr, $set1:ident, $add:ident, $sub:ident, $mul:ident, $srli:ident,
     $min:ident, $shuffle:ident, $wide:expr, $narrow:expr) => {{
        const N: usize = $n;
        let one = $set1($crate::fixed::ONE as i32);
        let half = $set1(1 << 14);
        let wv = $w.map(|x: u32| $set1(x as u16 as i32));
        let wide = $wide;
        let narrow = $narrow;
        move |p: [Rgba; N], t: &[Rgba], b: &[Rgba]| {
            let (t, b) = (&t[..N + 1], &b[..N + 1]);
            let at = |r: &[Rgba], o: usize| {
                let q: [Rgba; N] = bytemuck::pod_read_unaligned(bytemuck::cast_slice(&r[o..o + N]));
                wide(q)
            };
            let sum = $add(
                $add($mul(wv[0], at(t, 0)), $mul(wv[1], at(t, 1))),
                $add($mul(wv[2], at(b, 0)), $mul(wv[3], at(b, 1))),
            );
            let s = $srli::<15>($add(sum, half));
            let cur = wide(p);
            // 1 − α of each pixel in all four of its lanes.
            let tr = $sub(one, $shuffle::<0xff>(cur));
            let over = $srli::<15>($add($mul(s, tr), half));
            let r = $min($add(cur, over), one);
            (narrow(r), r)
        }
    }};
}
#[cfg(target_arch = "x86_64")]
pub(crate) use over_run_simd;

/// Reads one byte per 64-byte line of `voxels`, a row the compositor reaches two rows
/// later: the compositor's default way to warm the cache (see [`composite_slice_in`]'s
/// `warm`). Lazy shading reads a few scattered voxels per row, which the hardware does
/// not prefetch; walking the row ahead streams the slice into the cache instead (about
/// 10 % of a frame on the MR head, which otherwise waits on those reads). The loads make
/// the core wait for memory when the row is not cached, which a prefetch instruction
/// does not (every x86-64 build uses one, see
/// [`crate::render::composite_band_until_x86_64`]). Bare-metal targets have no data
/// cache to fill, so there it does nothing.
#[cfg_attr(target_arch = "x86_64", inline(always))]
#[cfg_attr(not(target_arch = "x86_64"), inline)]
pub(crate) fn touch(voxels: &[Voxel]) {
    if cfg!(target_os = "none") {
        return;
    }
    let mut acc = 0u8;
    for v in voxels.iter().step_by(16) {
        acc ^= v.opacity;
    }
    core::hint::black_box(acc);
}

/// Composites slice `k` into the scanlines `img` holds. `rows` must hold
/// [`rows_needed`]`(view)` entries (any contents: they are cleared first).
pub fn composite_slice(
    img: &mut Intermediate<'_>,
    slice: &RleSlice<'_>,
    k: usize,
    view: &Factorization,
    tables: &SliceTables<'_>,
    rows: &mut [Rgba],
    shadow: Option<&ShadowLookup<'_>>,
) -> Result<(), Error> {
    composite_slice_in(img, slice, k, view, tables, rows, shadow, false, &Portable)
}

/// [`composite_slice`] with `clean` saying whether `rows` is all zero on entry (every
/// path leaves it all zero again on success, so a caller compositing slice after slice
/// clears it once instead of once per slice and band), and `warm` called on each voxel
/// row two rows before the loop reads it ([`touch`], or a prefetch).
// Inlined on x86-64 so that the instruction-set builds of
// [`crate::render::composite_band_until`] compile this loop for their own features (a
// function that is not inlined keeps the baseline build); bare-metal targets keep one
// copy, for flash.
#[allow(clippy::too_many_arguments)]
#[cfg_attr(target_arch = "x86_64", inline(always))]
pub(crate) fn composite_slice_in(
    img: &mut Intermediate<'_>,
    slice: &RleSlice<'_>,
    k: usize,
    view: &Factorization,
    tables: &SliceTables<'_>,
    rows: &mut [Rgba],
    shadow: Option<&ShadowLookup<'_>>,
    clean: bool,
    kern: &impl Kernels,
) -> Result<(), Error> {
    let [ni, nj, _] = view.dims;
    if slice.ni != ni || slice.nj != nj {
        return Err(Error::MalformedRle {
            reason: "slice dimensions do not match the view",
        });
    }
    let job = SliceJob {
        img,
        slice,
        k,
        view,
        tables,
        rows,
        clean,
    };
    if view.perspective.is_some() {
        if shadow.is_some() {
            return Err(Error::BadParameter {
                reason: "shadows are not available in perspective views",
            });
        }
        return kern.perspective(job);
    }
    need("row buffer", row_buffer_len(ni), job.rows.len())?;
    if view.supersample > 1 {
        let SliceJob { img, rows, .. } = job;
        return composite_slice_supersampled(
            img, slice, k, view, tables, rows, shadow, clean, kern,
        );
    }
    let scale = tables.depth.map_or(ONE, |d| d.slice_factor(k));
    let way = Way::of(tables, shadow, scale);
    #[cfg(target_arch = "x86_64")]
    match way {
        Way::Lit => composite_rows(job, kern, &Lit),
        Way::Cued(scale) => composite_rows(job, kern, &Cued(scale)),
        Way::Shadowed(s) => composite_rows(job, kern, &s),
        Way::Mip => composite_rows(job, kern, &Mip),
    }
    #[cfg(not(target_arch = "x86_64"))]
    composite_rows(job, kern, &way)
}

/// The scanline loop of [`composite_slice_in`] for one [`Shading`].
#[cfg_attr(target_arch = "x86_64", inline(always))]
fn composite_rows(
    job: SliceJob<'_, '_>,
    kern: &impl Kernels,
    shading: &impl Shading,
) -> Result<(), Error> {
    let SliceJob {
        img,
        slice,
        k,
        view,
        tables,
        rows,
        clean,
    } = job;
    let [ni, nj, _] = view.dims;
    let [ou, ov]: [SliceOffset; 2] = view.slice_offset(k);
    let (mut r0, mut r1) = Row::pair(rows, ni, clean);
    // Swapped by reference: a row carries its written runs, too large to swap by value
    // every scanline.
    let (mut top, mut bot) = (&mut r0, &mut r1);
    // Weights: f weighs the left column / top row.
    let w = fixed::bilinear_weights(ou.f, ov.f);
    let width = img.width;
    // Scanline v reads voxel rows jt = v − n_v − 1 and jt + 1.
    let band_lo = img.row0 as i64;
    let band_hi = (img.row0 + img.rows) as i64;
    let jt_lo = (band_lo - ov.n as i64 - 1).max(-1);
    let jt_hi = (band_hi - ov.n as i64 - 1).min(nj as i64 - 1);
    if jt_lo > jt_hi {
        return Ok(());
    }
    // Scanline jt reads rows jt and jt + 1: only those from the row before the first
    // non-empty one to the last non-empty one composite anything (a brain slice's empty
    // rows lie mostly at its two ends).
    let Some((j_first, j_last)) = slice.visible_rows(jt_lo.max(0) as usize, (jt_hi + 1) as usize)
    else {
        return Ok(());
    };
    let jt_lo = jt_lo.max(j_first as i64 - 1);
    let jt_hi = jt_hi.min(j_last as i64);
    let empty: (&[u8], &[Voxel]) = (&[], &[]);
    let row_of = |j: i64| slice.row(j);
    let first = row_of(jt_lo);
    // Row j is read by scanlines j + n_v (as the bottom row) and j + n_v + 1 (top).
    // In MIP no pixel becomes opaque, so every voxel is needed.
    let skip_opaque_voxels = tables.mode == Mode::Composite;
    {
        let need = Needed::lines(img, jt_lo + ov.n as i64, ou.n as i64);
        let need = skip_opaque_voxels.then_some(&need);
        top.fill(first.0, first.1, tables, jt_lo, need, kern, shading);
    }
    // What open pixels read of the rows two rows ahead, by row index mod 4. A row whose
    // every voxel only closed pixels read is neither streamed into the cache nor walked:
    // pixels only ever close, so a row hidden then is still hidden when its turn comes.
    // A row whose reach held no closed pixel then is shaded whole, without the
    // per-voxel test of which voxels open pixels read: voxels that only pixels closed
    // since then read are shaded for nothing, and no pixel reads them.
    // In MIP no pixel closes: every row is read whole. The first two rows' reach is
    // asked here, as the loop asks each later row's: since the slice starts at its first
    // non-empty row, they are rarely empty (the Cortex-M3 frame: 1.7 % fewer
    // instructions than taking them as read in part).
    let first_reach = if skip_opaque_voxels {
        Reach::Some
    } else {
        Reach::Everything
    };
    let mut reach = [first_reach; 4];
    // The scanlines of rows jt + 1 ..= jt + 3 by row index mod 4, each looked up once.
    let mut scans = [empty; 4];
    for j in jt_lo + 1..jt_lo + 3 {
        let row = row_of(j);
        scans[j.rem_euclid(4) as usize] = row;
        if skip_opaque_voxels {
            let r = Needed::lines(img, j + ov.n as i64, ou.n as i64).reach(row.0, ni);
            reach[j.rem_euclid(4) as usize] = r;
        }
    }
    for jt in jt_lo..=jt_hi {
        let next = scans[(jt + 1).rem_euclid(4) as usize];
        let ahead = row_of(jt + 3);
        scans[(jt + 3).rem_euclid(4) as usize] = ahead;
        let r = if skip_opaque_voxels {
            Needed::lines(img, jt + 3 + ov.n as i64, ou.n as i64).reach(ahead.0, ni)
        } else {
            Reach::Everything
        };
        reach[(jt + 3).rem_euclid(4) as usize] = r;
        if r != Reach::Nothing {
            kern.warm(ahead.1);
        }
        match reach[(jt + 1).rem_euclid(4) as usize] {
            Reach::Nothing => bot.clear(),
            Reach::Everything => {
                bot.fill(next.0, next.1, tables, jt + 1, None, kern, shading);
            }
            Reach::Some => {
                let need = Needed::lines(img, jt + 1 + ov.n as i64, ou.n as i64);
                bot.fill(next.0, next.1, tables, jt + 1, Some(&need), kern, shading);
            }
        }
        let v = jt + ov.n as i64 + 1;
        if v >= band_lo && v < band_hi {
            let (pixels, opaque) = img.scanline_mut(v as usize - img.row0);
            // Pixel u reads buffer entries u − n and u − n + 1: visit the pixels that
            // reach the non-zero extent of either row (zero taps leave a pixel as it is).
            let (lo, hi) = match (top.extent(), bot.extent()) {
                (Some(a), Some(b)) => (a.0.min(b.0), a.1.max(b.1)),
                (Some(a), None) | (None, Some(a)) => a,
                (None, None) => (0, 0),
            };
            if lo < hi {
                let n = ou.n as i64;
                let ua = (lo as i64 + n - 1).clamp(0, width as i64) as usize;
                let ub = (hi as i64 + n).clamp(0, width as i64) as usize;
                let taps = Taps {
                    top: top.buf,
                    bot: bot.buf,
                    n: ou.n,
                    w,
                };
                composite_span(pixels, opaque, &taps, ua..ub, tables, kern);
            }
        }
        core::mem::swap(&mut top, &mut bot);
    }
    top.clear();
    bot.clear();
    Ok(())
}

/// [`composite_slice`] for an intermediate image with `s = view.supersample` pixels per
/// voxel: pixel `u` samples the slice at `u/s − T`, so weights vary from pixel to pixel
/// (with period `s`), and each pair of voxel rows serves `s` scanlines.
#[allow(clippy::too_many_arguments)]
fn composite_slice_supersampled(
    img: &mut Intermediate<'_>,
    slice: &RleSlice<'_>,
    k: usize,
    view: &Factorization,
    tables: &SliceTables<'_>,
    rows: &mut [Rgba],
    shadow: Option<&ShadowLookup<'_>>,
    clean: bool,
    kern: &impl Kernels,
) -> Result<(), Error> {
    let [ni, nj, _] = view.dims;
    let ss = view.supersample as i64;
    let one = ONE as i64;
    // Pixel u samples at u·ONE/s (floored): stepped from pixel to pixel as a quotient
    // and a remainder, one division a run instead of one a pixel (a 64-bit division
    // takes tens of cycles).
    let (step, carry) = (one / ss, one % ss);
    let [ou, ov]: [SliceOffset; 2] = view.slice_offset(k);
    // Slice translation T in Q15.
    let tu = ou.n as i64 * one + ou.f as i64;
    let tv = ov.n as i64 * one + ov.f as i64;
    let (mut r0, mut r1) = Row::pair(rows, ni, clean);
    // Swapped by reference: a row carries its written runs, too large to swap by value
    // every scanline.
    let (mut top, mut bot) = (&mut r0, &mut r1);
    let scale = tables.depth.map_or(ONE, |d| d.slice_factor(k));
    let shading = Way::of(tables, shadow, scale);
    let width = img.width;
    let row_of = |j: i64| slice.row(j);
    // Scanlines reading rows jt and jt + 1 composite something only for jt from the row
    // before the first non-empty one to the last non-empty one.
    let Some((j_first, j_last)) = slice.visible_rows(0, nj) else {
        return Ok(());
    };
    // Rows held in `top` / `bot` (voxel row indices), i64::MIN when none.
    let mut held = i64::MIN;
    for v in img.row0..img.row0 + img.rows {
        let pv = v as i64 * one / ss - tv;
        let jt = pv.div_euclid(one);
        let frv = pv.rem_euclid(one) as u32;
        if jt < j_first as i64 - 1 || jt > j_last as i64 {
            continue;
        }
        if jt != held {
            if jt == held + 1 {
                core::mem::swap(&mut top, &mut bot);
            } else {
                let r = row_of(jt);
                top.fill(r.0, r.1, tables, jt, None, kern, &shading);
            }
            let r = row_of(jt + 1);
            bot.fill(r.0, r.1, tables, jt + 1, None, kern, &shading);
            held = jt;
        }
        let (top_runs, bot_runs) = (row_of(jt).0, row_of(jt + 1).0);
        let (pixels, opaque) = img.scanline_mut(v - img.row0);
        let spans = MergedSpans {
            a: Spans::new(top_runs).peekable(),
            b: Spans::new(bot_runs).peekable(),
        };
        for (a, b) in spans {
            // The merged span [a, b) already includes the voxel to the right of each run
            // (b = last + 2): pixels whose left voxel lies in [a − 1, b − 1).
            let lo = ((a as i64 - 1) * one + tu) * ss;
            let hi = ((b as i64 - 1) * one + tu) * ss;
            let ua = (lo.div_euclid(one) + 1).clamp(0, width as i64) as usize;
            let ub = (hi.div_euclid(one) + 1).clamp(0, width as i64) as usize;
            let mut runs = opaque::OpenRuns::new(ua, ub);
            while let Some((u, e)) = runs.next(opaque, width) {
                let (mut q, mut r) = ((u as i64 * one) / ss, (u as i64 * one) % ss);
                for (u, px) in pixels.iter_mut().enumerate().take(e).skip(u) {
                    let pu = q - tu;
                    q += step;
                    r += carry;
                    if r >= ss {
                        q += 1;
                        r -= ss;
                    }
                    let il = pu.div_euclid(one);
                    let fru = pu.rem_euclid(one) as u32;
                    if il < -1 || il >= ni as i64 {
                        continue;
                    }
                    let bl = (il + 1) as usize;
                    let w = fixed::bilinear_weights(ONE - fru, ONE - frv);
                    if composite_pixel(px, top.buf, bot.buf, bl, w, tables) {
                        opaque::mark(opaque, u);
                    }
                }
            }
        }
    }
    top.clear();
    bot.clear();
    Ok(())
}

/// Resamples and composites one pixel from voxel buffer index `bl` (left) and `bl + 1`;
/// true if the pixel became opaque (reached the early-ray-termination opacity).
#[inline(always)]
fn composite_pixel(
    p: &mut Rgba,
    top: &[Rgba],
    bot: &[Rgba],
    bl: usize,
    w: [u32; 4],
    t: &SliceTables<'_>,
) -> bool {
    // Entries past a buffer read as transparent (they are never asked for: the
    // compositors keep `bl + 1` inside the row buffers).
    let at = |r: &[Rgba], i: usize| r.get(i).copied().unwrap_or_default();
    let (tl, tr, bl_, br) = (at(top, bl), at(top, bl + 1), at(bot, bl), at(bot, bl + 1));
    let mut s = [0u32; 4];
    for c in 0..4 {
        s[c] = (w[0] * tl[c] as u32
            + w[1] * tr[c] as u32
            + w[2] * bl_[c] as u32
            + w[3] * br[c] as u32
            + (1 << 14))
            >> 15;
    }
    match t.mode {
        Mode::Composite => {
            if s[3] != 0 {
                let tr = ONE - p[3] as u32;
                for c in 0..4 {
                    p[c] = (p[c] as u32 + fixed::mul(s[c], tr)).min(ONE) as u16;
                }
                return p[3] as u32 >= t.ert;
            }
            false
        }
        Mode::Mip => {
            if s[0] > p[0] as u32 {
                *p = [s[0] as u16; 4];
            }
            false
        }
    }
}

/// Two shaded voxel rows placed on a scanline: pixel `u` reads buffer entries `u − n` and
/// `u − n + 1` of both rows with the slice's bilinear weights `w`.
struct Taps<'r> {
    top: &'r [Rgba],
    bot: &'r [Rgba],
    n: i32,
    w: [u32; 4],
}

/// The inner loop: pixels `us` of one scanline.
#[cfg_attr(target_arch = "x86_64", inline(always))]
#[cfg_attr(not(target_arch = "x86_64"), inline)]
fn composite_span(
    pixels: &mut [Rgba],
    opaque: &mut [opaque::Word],
    taps: &Taps<'_>,
    us: core::ops::Range<usize>,
    t: &SliceTables<'_>,
    kern: &impl Kernels,
) {
    if t.mode == Mode::Composite {
        return over_span(pixels, opaque, taps, us, t.ert, kern);
    }
    // MIP: no pixel ever becomes opaque.
    let first = us.start;
    for (u, p) in pixels.iter_mut().enumerate().take(us.end).skip(first) {
        // Buffer index of the left voxel: (u − n − 1) + 1.
        let bl = (u as i64 - taps.n as i64) as usize;
        composite_pixel(p, taps.top, taps.bot, bl, taps.w, t);
    }
}

/// [`composite_span`] for [`Mode::Composite`]: each run of pixels that are not opaque
/// is composited by [`over_run`], a loop without branches that the compiler vectorises,
/// and the pixels that reached the early-ray-termination opacity are marked opaque
/// afterwards. Bit-identical to [`composite_pixel`], which the tests check.
#[cfg_attr(target_arch = "x86_64", inline(always))]
#[cfg_attr(not(target_arch = "x86_64"), inline)]
fn over_span(
    pixels: &mut [Rgba],
    opaque: &mut [opaque::Word],
    taps: &Taps<'_>,
    us: core::ops::Range<usize>,
    ert: u32,
    kern: &impl Kernels,
) {
    let width = pixels.len();
    let end = us.end.min(width);
    // A pixel still at zero opacity was never composited, so it is not marked even when
    // the threshold is zero (as in the per-pixel kernel).
    let thr = ert.max(1);
    let mut runs = opaque::OpenRuns::new(us.start, end);
    while let Some((u, e)) = runs.next(opaque, width) {
        // Pixels u..e read buffer entries u − n ..= e − n of both rows.
        let bl = (u as i64 - taps.n as i64) as usize;
        // In bounds: the compositors place the span inside the scanline and the taps
        // inside the row buffers. The kernels read `px.len() + 1` entries of each row.
        let (Some(px), Some(top), Some(bot)) =
            (pixels.get_mut(u..e), taps.top.get(bl..), taps.bot.get(bl..))
        else {
            return;
        };
        let highest = kern.over_run(px, top, bot, taps.w);
        // Most runs have no pixel that reached the threshold, and the run's highest
        // opacity says so without a look at each pixel (spheres256, callgrind: 9.7 %
        // fewer instructions a frame).
        if highest as u32 >= thr {
            mark_closed(opaque, u, px, thr, kern);
        }
    }
}

/// Marks opaque the pixels of `px` (pixel `u` first) whose opacity reached `thr`.
///
/// With 64-bit words a mask of 64 pixels is built and ORed into the bitmap at once
/// (spheres256, x86-64-v3: 2 % fewer instructions per frame than a test and bit-set per
/// pixel). On 32-bit targets the 64-bit shifts cost more than they save (the Cortex-M3
/// firmware: 42 565 200 instructions per frame against 40 838 680), so they mark pixel
/// by pixel.
#[cfg(target_pointer_width = "64")]
#[inline(always)]
fn mark_closed(opaque: &mut [opaque::Word], u: usize, px: &[Rgba], thr: u32, k: &impl Kernels) {
    mark_closed_words(opaque, u, px, thr, k);
}

/// [`mark_closed`] on 32-bit targets.
#[cfg(not(target_pointer_width = "64"))]
#[inline(always)]
fn mark_closed(opaque: &mut [opaque::Word], u: usize, px: &[Rgba], thr: u32, _: &impl Kernels) {
    mark_closed_each(opaque, u, px, thr);
}

/// [`mark_closed`] 64 pixels at a time.
#[cfg_attr(not(any(test, target_pointer_width = "64")), allow(dead_code))]
#[inline(always)]
fn mark_closed_words<W: opaque::BitWord>(
    opaque: &mut [W],
    u: usize,
    px: &[Rgba],
    thr: u32,
    k: &impl Kernels,
) {
    for (c, chunk) in px.chunks(64).enumerate() {
        let m = k.closed_bits(chunk, thr);
        if m != 0 {
            opaque::mark_bits(opaque, u + 64 * c, m);
        }
    }
}

/// Bit `i` set where `px[i]` (at most 64 pixels) reached opacity `thr`.
#[inline(always)]
pub(crate) fn closed_bits(px: &[Rgba], thr: u32) -> u64 {
    let mut m = 0u64;
    for (i, p) in px.iter().take(64).enumerate() {
        m |= ((p[3] as u32 >= thr) as u64) << i;
    }
    m
}

/// [`closed_bits`] four pixels a step in AVX2: a pixel is one 64-bit lane, its opacity
/// the lane's top 16 bits, so a shift, a 64-bit compare and a sign-bit mask give four
/// bits. The compiler's version of the plain loop sets up vector code that short runs
/// hardly enter: on the MR head, 19 K runs a frame of 7.6 pixels on average are looked
/// at, and this kernel takes 1.5 % off the frame's instructions (callgrind). Runs
/// shorter than four pixels go pixel by pixel; the last step of a longer run overlaps
/// the one before it. A macro expanding to a closure, written inside the x86-64-v3 and
/// v4 compositors (see [`premultiply_sse41`]).
#[cfg(target_arch = "x86_64")]
macro_rules! closed_bits_avx2 {
    () => {
        |px: &[$crate::composite::Rgba], thr: u32| -> u64 {
            use core::arch::x86_64::*;
            type Rgba = $crate::composite::Rgba;
            let px = &px[..px.len().min(64)];
            let n = px.len();
            if n < 4 {
                return $crate::composite::closed_bits(px, thr);
            }
            // Opacity above thr − 1, as signed 64-bit lanes (both are below 2^16).
            let below = _mm256_set1_epi64x(thr as i64 - 1);
            let four = |q: &[Rgba]| -> u64 {
                let q: [Rgba; 4] = core::array::from_fn(|k| q[k]);
                let alpha = _mm256_srli_epi64::<48>(bytemuck::cast(q));
                let ge = _mm256_cmpgt_epi64(alpha, below);
                _mm256_movemask_pd(_mm256_castsi256_pd(ge)) as u64
            };
            let mut m = four(&px[n - 4..]) << (n - 4);
            let mut i = 0;
            while i + 4 < n {
                m |= four(&px[i..i + 4]) << i;
                i += 4;
            }
            m
        }
    };
}
#[cfg(target_arch = "x86_64")]
pub(crate) use closed_bits_avx2;

/// [`mark_closed`] pixel by pixel.
#[cfg_attr(all(not(test), target_pointer_width = "64"), allow(dead_code))]
#[inline(always)]
fn mark_closed_each<W: opaque::BitWord>(opaque: &mut [W], u: usize, px: &[Rgba], thr: u32) {
    for (i, p) in px.iter().enumerate() {
        if p[3] as u32 >= thr {
            opaque::mark(opaque, u + i);
        }
    }
}

/// Resamples `top`/`bot` (one entry longer than `px`) with weights `w` and composites
/// the result under `px`. A zero sample leaves a pixel unchanged (`p + 0·(1 − α) = p`),
/// so no pixel needs a test and the loop has no branches.
#[cfg_attr(target_arch = "x86_64", inline(always))]
#[cfg_attr(not(target_arch = "x86_64"), inline)]
pub(crate) fn over_run(px: &mut [Rgba], top: &[Rgba], bot: &[Rgba], w: [u32; 4]) {
    const H: u32 = 1 << 14;
    let w = w.map(|x| x as u16 as u32);
    for ((p, t), b) in px.iter_mut().zip(top.windows(2)).zip(bot.windows(2)) {
        let mut s = [0u32; 4];
        for c in 0..4 {
            let sum = w[0] * t[0][c] as u32
                + w[1] * t[1][c] as u32
                + w[2] * b[0][c] as u32
                + w[3] * b[1][c] as u32;
            // At most ONE: the weights sum to ONE and the channels are at most ONE.
            s[c] = ((sum + H) >> 15) as u16 as u32;
        }
        let tr = (ONE - p[3] as u32) as u16 as u32;
        for c in 0..4 {
            p[c] = (p[c] as u32 + ((s[c] * tr + H) >> 15)).min(ONE) as u16;
        }
    }
}

/// [`over_run`] as [`Kernels::over_run`] of the portable kernels: returns `u16::MAX`, so
/// every run is looked at for the opaque mark (see [`Portable`]).
#[inline(always)]
pub(crate) fn over_run_unranked(px: &mut [Rgba], top: &[Rgba], bot: &[Rgba], w: [u32; 4]) -> u16 {
    over_run(px, top, bot, w);
    u16::MAX
}

/// The highest opacity of `px`.
#[cfg(any(test, target_arch = "x86_64"))]
#[inline(always)]
pub(crate) fn highest(px: &[Rgba]) -> u16 {
    px.iter().fold(0, |h, p| h.max(p[3]))
}

/// Unshaded tables for tests: colour rising with the scalar, opacity with the stored
/// byte, no termination.
#[cfg(test)]
pub(crate) struct PlainTables {
    color: ColorLanes,
    shade: ShadeTable,
    opacity: OpacityTable,
}

#[cfg(test)]
impl PlainTables {
    pub(crate) fn new() -> Self {
        PlainTables {
            color: core::array::from_fn(|i| [i as u16 * 64, 7, 9, 0]),
            shade: ShadeTable::UNSHADED,
            opacity: OpacityTable::from(core::array::from_fn(|i| (i * 128) as u16)),
        }
    }

    pub(crate) fn get(&self) -> SliceTables<'_> {
        SliceTables {
            opacity: &self.opacity,
            color: &self.color,
            shade: &self.shade,
            mode: Mode::Composite,
            ert: ONE,
            depth: None,
            shade0: None,
            ray_gain: None,
        }
    }
}

/// Marks random stretches of the `w`-pixel scanline `line` opaque, for tests: stretches
/// up to `long` pixels when `density` is 0, up to `short` otherwise, each opaque with
/// odds growing with `density`. `next(m)` gives values in `0..=m`.
#[cfg(test)]
pub(crate) fn mark_random_stretches(
    line: &mut [opaque::Word],
    w: usize,
    (long, short): (usize, usize),
    density: usize,
    next: &mut impl FnMut(usize) -> usize,
) {
    let mut u = 0;
    while u < w {
        let len = 1 + next(if density == 0 { long } else { short });
        if next(3) < density.max(1) {
            (u..(u + len).min(w)).for_each(|p| opaque::mark(line, p));
        }
        u += len;
    }
}

/// A random scanline `ni` voxels wide, for tests: transparent and visible runs in turn,
/// mostly short and now and then long (split at 255 by empty continuations), with random
/// visible voxels. `next(m)` gives values in `0..=m`.
#[cfg(test)]
pub(crate) fn random_scanline<const R: usize, const N: usize>(
    ni: usize,
    next: &mut impl FnMut(u32) -> u32,
) -> (heapless::Vec<u8, R>, heapless::Vec<Voxel, N>) {
    let mut runs = heapless::Vec::new();
    let mut voxels = heapless::Vec::new();
    let (mut i, mut visible) = (0usize, false);
    while i < ni {
        let long = next(9) == 0;
        let len = (if long { next(300) } else { next(12) } as usize).min(ni - i);
        let mut left = len;
        loop {
            let piece = left.min(255);
            runs.push(piece as u8).unwrap();
            left -= piece;
            if left == 0 {
                break;
            }
            runs.push(0).unwrap();
        }
        if visible {
            for _ in 0..len {
                let v = Voxel {
                    opacity: 1 + next(254) as u8,
                    scalar: next(255) as u8,
                    normal: 0,
                };
                voxels.push(v).unwrap();
            }
        }
        i += len;
        visible = !visible;
    }
    if runs.len() % 2 == 1 {
        runs.push(0).unwrap();
    }
    (runs, voxels)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::normal;

    #[test]
    fn premultiply_gives_the_shaded_colour_and_the_opacity_after_it() {
        // With real tables (a lit table, colours and opacities within one) and anything
        // in the padding lane, the step must give what shading three channels and
        // appending the opacity gives.
        let mut shade = ShadeTable::UNSHADED;
        let mut lights = heapless::Vec::new();
        let _ = lights.push(crate::shade::Light {
            direction: [0.3, -0.5, 1.0],
            color: [1.0, 0.8, 0.6],
        });
        let l = crate::shade::Lighting {
            ka: 0.2,
            kd: 1.4,
            ks: 0.5,
            shininess: 12.0,
            lights,
        };
        let rot = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        assert!(shade.fill(&l, &rot).is_ok());
        let mut next = rng(0x51f1_5ee5_d00d_f00d);
        for _ in 0..20_000 {
            let c = [next(ONE), next(ONE), next(ONE)].map(|x| x as u16);
            let code = next(normal::CODES as u32 + 40) as u16;
            let alpha = next(ONE);
            let lanes = [c[0], c[1], c[2], next(u16::MAX as u32) as u16];
            let got = premultiply(&lanes, shade.entry_ref(code), alpha);
            let s = shade.shade(code, c);
            let want = [0, 1, 2].map(|i| fixed::mul(s[i], alpha) as u16);
            assert_eq!(
                got,
                [want[0], want[1], want[2], alpha as u16],
                "{c:?} {code} {alpha}"
            );
        }
    }

    #[test]
    fn spans_merge_split_runs() {
        let runs = [2u8, 3, 0, 4, 1, 0, 0, 2];
        let v: heapless::Vec<(usize, usize), 8> = Spans::new(&runs).collect();
        assert_eq!(&v[..], &[(2, 9), (10, 12)]);
        let runs = [0u8, 1, 3, 1, 2, 0];
        let v: heapless::Vec<(usize, usize), 8> = Spans::new(&runs).collect();
        assert_eq!(&v[..], &[(0, 1), (4, 5)]);
    }

    #[test]
    fn merged_spans_are_disjoint_and_dilated() {
        let a = [1u8, 2, 5, 1, 0, 0]; // [1,3) [8,9)
        let b = [3u8, 1, 3, 2]; // [3,4) [7,9)
        let m = MergedSpans {
            a: Spans::new(&a).peekable(),
            b: Spans::new(&b).peekable(),
        };
        let v: heapless::Vec<(usize, usize), 8> = m.collect();
        assert_eq!(&v[..], &[(1, 5), (7, 10)]);
    }

    /// Uniform values in `0..=m` from a xorshift stream.
    fn rng(seed: u64) -> impl FnMut(u32) -> u32 {
        let mut r = crate::xorshift(seed);
        move |m: u32| ((r() >> 20) % (m as u64 + 1)) as u32
    }

    #[test]
    fn visible_extent_spans_first_to_last_visible_voxel() {
        // ni = 20 unless noted.
        assert_eq!(visible_extent(&[20, 0], 20), None);
        assert_eq!(visible_extent(&[3, 4, 13, 0], 20), Some((3, 7)));
        assert_eq!(visible_extent(&[0, 2, 3, 15], 20), Some((0, 20)));
        assert_eq!(visible_extent(&[0, 0, 5, 1, 14, 0], 20), Some((5, 6)));
        // Long runs split at 255, transparent at both ends.
        let runs = [255, 0, 45, 2, 3, 1, 255, 0, 94, 0];
        assert_eq!(visible_extent(&runs, 655), Some((300, 306)));
        let runs = [1, 255, 0, 255, 0, 9];
        assert_eq!(visible_extent(&runs, 520), Some((1, 520)));
    }

    #[test]
    fn a_row_is_hidden_exactly_when_no_open_pixel_reads_a_visible_voxel() {
        // Row: voxels 10..14 and 90..93 visible (ni = 120), shift 7: voxel i feeds
        // pixels i + 7 and i + 8 of scanlines 4 and 5 (both in the band).
        let runs = [10u8, 4, 76, 3, 27, 0];
        let mut pixels = [[0u16; 4]; 2 * 140];
        let mut links = [0; 2 * 140];
        let mut img = Intermediate::band(140, 10, 4, 2, &mut pixels, &mut links).unwrap();
        let close = |img: &mut Intermediate<'_>, r: usize, us: core::ops::Range<usize>| {
            let (_, line) = img.scanline_mut(r);
            us.for_each(|u| opaque::mark(line, u));
        };
        close(&mut img, 0, 0..140);
        close(&mut img, 1, 0..100);
        // Pixel 100 of scanline 5 is open, read by voxel 92.
        assert!(!Needed::lines(&img, 4, 7).hides(&runs, 120));
        close(&mut img, 1, 100..101);
        // Pixels 101.. are open but read only transparent voxels.
        assert!(Needed::lines(&img, 4, 7).hides(&runs, 120));
        // Scanline 3 lies outside the band: only scanline 4 reads, and it is closed.
        assert!(Needed::lines(&img, 3, 7).hides(&runs, 120));
        assert!(Needed::lines(&img, 3, 7).hides(&[120, 0], 120));
    }

    #[test]
    fn a_rows_scanlines_are_those_of_the_band_it_lies_in() {
        // A band of scanlines 5..9 of a 12-scanline image, 70 pixels wide (two words a
        // scanline on 64-bit targets), scanline r with pixel r closed.
        let mut pixels = [[0u16; 4]; 4 * 70];
        let mut links = [0; 4 * 70];
        let mut img = Intermediate::band(70, 12, 5, 4, &mut pixels, &mut links).unwrap();
        for r in 0..4 {
            let (_, line) = img.scanline_mut(r);
            opaque::mark(line, r);
        }
        for v0 in -2i64..14 {
            let need = Needed::lines(&img, v0, 0);
            for (k, line) in need.lines.into_iter().enumerate() {
                let v = v0 + k as i64;
                match line {
                    Some(l) => {
                        assert!((5..9).contains(&v), "scanline {v}");
                        assert_eq!(l.len(), opaque::words(70));
                        for u in 0..70 {
                            let want = u as i64 == v - 5;
                            assert_eq!(opaque::is_opaque(l, u), want, "scanline {v}, {u}");
                        }
                    }
                    None => assert!(!(5..9).contains(&v), "scanline {v}"),
                }
            }
        }
    }

    #[test]
    fn a_row_is_read_whole_exactly_when_no_pixel_it_reaches_is_closed() {
        // As above: voxels 10..14 and 90..93 visible, shift 7, so they reach pixels
        // 17..=100 of scanlines 4 and 5.
        let runs = [10u8, 4, 76, 3, 27, 0];
        let mut pixels = [[0u16; 4]; 2 * 140];
        let mut links = [0; 2 * 140];
        let mut img = Intermediate::band(140, 10, 4, 2, &mut pixels, &mut links).unwrap();
        let close = |img: &mut Intermediate<'_>, r: usize, u: usize| {
            let (_, line) = img.scanline_mut(r);
            opaque::mark(line, u);
        };
        assert_eq!(
            Needed::lines(&img, 4, 7).reach(&runs, 120),
            Reach::Everything
        );
        // Closed pixels outside the reach, in either scanline.
        close(&mut img, 0, 16);
        close(&mut img, 1, 101);
        close(&mut img, 1, 139);
        assert_eq!(
            Needed::lines(&img, 4, 7).reach(&runs, 120),
            Reach::Everything
        );
        // Pixel 100 (voxel 92's right one) in scanline 5, then pixel 17 (voxel 10's left
        // one) in scanline 5 of a fresh band.
        close(&mut img, 1, 100);
        assert_eq!(Needed::lines(&img, 4, 7).reach(&runs, 120), Reach::Some);
        let mut img = Intermediate::band(140, 10, 4, 2, &mut pixels, &mut links).unwrap();
        close(&mut img, 1, 17);
        assert_eq!(Needed::lines(&img, 4, 7).reach(&runs, 120), Reach::Some);
        // Scanline 3 lies outside the band: scanline 4, all open, alone decides.
        assert_eq!(
            Needed::lines(&img, 3, 7).reach(&runs, 120),
            Reach::Everything
        );
        // A row without visible voxels reaches nothing.
        assert_eq!(
            Needed::lines(&img, 4, 7).reach(&[120, 0], 120),
            Reach::Nothing
        );
    }

    #[test]
    fn lazy_fill_shades_every_voxel_an_open_pixel_reads() {
        // Random scanlines (transparent and visible runs, splits at 255 included) shaded
        // eagerly and lazily against random opaque bitmaps of the two reading scanlines,
        // one or both of which may lie outside the band. Lazily, every voxel that an open
        // pixel reads must come out exactly as eagerly, and the others must stay zero.
        const NI: usize = 300;
        const W: usize = 340;
        let mut next = rng(0x2545_f491_4f6c_dd1d);
        let plain = PlainTables::new();
        let t = plain.get();
        for round in 0..300 {
            let (runs, voxels): (heapless::Vec<u8, 700>, heapless::Vec<Voxel, NI>) =
                random_scanline(NI, &mut next);
            // Two scanlines of opaque bits: dense, sparse, or long opaque stretches.
            let mut pixels = [[0u16; 4]; 2 * W];
            let mut links = [0; 2 * W];
            let mut img = Intermediate::band(W, 10, 4, 2, &mut pixels, &mut links).unwrap();
            let density = next(4) as usize;
            for r in 0..2 {
                let (_, line) = img.scanline_mut(r);
                let next = &mut |m: usize| next(m as u32) as usize;
                mark_random_stretches(line, W, (90, 6), density, next);
            }
            let shift = next(45) as i64 - 5;
            // v0 = 3: only the second line is in the band; 4: both; 5: only the first.
            let v0 = 3 + (round % 3) as i64;
            let need = Needed::lines(&img, v0, shift);
            let mut eager_buf = [[0u16; 4]; NI + 2];
            let mut lazy_buf = [[1u16; 4]; NI + 2];
            let mut eager = Row::new(&mut eager_buf, false);
            eager.fill(&runs, &voxels, &t, 0, None, &Portable, &Lit);
            let mut lazy = Row::new(&mut lazy_buf, false);
            lazy.fill(&runs, &voxels, &t, 0, Some(&need), &Portable, &Lit);
            let open = |v: i64, u: i64| -> bool {
                (4..6).contains(&v)
                    && (0..W as i64).contains(&u)
                    && !opaque::is_opaque(img.opaque_line((v - 4) as usize), u as usize)
            };
            for i in 0..NI as i64 {
                let read = [v0, v0 + 1]
                    .iter()
                    .any(|&v| open(v, i + shift) || open(v, i + shift + 1));
                let (e, l) = (eager.buf[i as usize + 1], lazy.buf[i as usize + 1]);
                if read {
                    assert_eq!(
                        l, e,
                        "round {round}: voxel {i} is read but shaded differently"
                    );
                } else {
                    assert_eq!(l, [0; 4], "round {round}: voxel {i} is not read");
                }
            }
            // The extent covers every non-zero entry.
            assert!(lazy.zero_outside_extent());
        }
    }

    #[test]
    fn both_ways_of_marking_closed_pixels_agree() {
        let mut rng = crate::xorshift(0xc105ed);
        for case in 0..400 {
            let width = 1 + (rng() % 300) as usize;
            let u = (rng() % width as u64) as usize;
            let n = (rng() % (width - u) as u64) as usize + 1;
            let px: heapless::Vec<Rgba, 300> = (0..n)
                .map(|_| [0, 0, 0, (rng() % (ONE as u64 + 1)) as u16])
                .collect();
            let thr = 1 + (rng() % ONE as u64) as u32;
            // Both word widths, whichever this target stores.
            let mut a = [0u16; 19];
            a.iter_mut().for_each(|w| *w = rng() as u16 & rng() as u16);
            let mut b = a;
            mark_closed_words(&mut a[..width.div_ceil(16)], u, &px, thr, &Portable);
            mark_closed_each(&mut b[..width.div_ceil(16)], u, &px, thr);
            assert_eq!(a, b, "case {case}");
            let mut a = [0u64; 5];
            a.iter_mut().for_each(|w| *w = rng() & rng());
            let mut b = a;
            mark_closed_words(&mut a[..width.div_ceil(64)], u, &px, thr, &Portable);
            mark_closed_each(&mut b[..width.div_ceil(64)], u, &px, thr);
            assert_eq!(a, b, "case {case}");
        }
    }

    #[test]
    fn over_span_matches_the_per_pixel_kernel() {
        // Random premultiplied rows (channels up to alpha, alpha up to ONE, edge values
        // and transparent stretches included) composited under random pixels that are
        // not yet opaque (alpha below the threshold, or zero) through both kernels.
        let mut rand = crate::xorshift(0x9e37_79b9_7f4a_7c15);
        let mut next = |m: u32| {
            let seed = rand();
            let r = (seed >> 20) as u32 % (m + 1);
            match seed & 7 {
                0 => m,
                1 => 0,
                _ => r,
            }
        };
        let color: ColorLanes = [[0; 4]; 256];
        let shade = ShadeTable::UNSHADED;
        let opacity = OpacityTable::from([0u16; 256]);
        for round in 0..400 {
            let ert = if round % 8 == 0 { 0 } else { next(ONE) };
            let px = |next: &mut dyn FnMut(u32) -> u32, max_alpha: u32| {
                let a = next(max_alpha);
                [next(a) as u16, next(a) as u16, next(a) as u16, a as u16]
            };
            let top: [Rgba; 34] = core::array::from_fn(|_| px(&mut next, ONE));
            let bot: [Rgba; 34] = core::array::from_fn(|_| px(&mut next, ONE));
            let open = ert.saturating_sub(1);
            let start: [Rgba; 40] = core::array::from_fn(|_| px(&mut next, open));
            let w = fixed::bilinear_weights(next(ONE), next(ONE));
            let t = SliceTables {
                opacity: &opacity,
                color: &color,
                shade: &shade,
                mode: Mode::Composite,
                ert,
                depth: None,
                shade0: None,
                ray_gain: None,
            };
            let (mut fast, mut slow) = (start, start);
            // Some pixels already opaque: both kernels must leave them alone.
            let mut lf = [0 as opaque::Word; opaque::words(40)];
            for u in 0..40 {
                if next(7) == 0 {
                    opaque::mark(&mut lf, u);
                }
            }
            let mut ls = lf;
            let taps = Taps {
                top: &top,
                bot: &bot,
                n: 3,
                w,
            };
            let (mut exact, mut le) = (fast, lf);
            over_span(&mut fast, &mut lf, &taps, 3..36, ert, &Portable);
            over_span(&mut exact, &mut le, &taps, 3..36, ert, &Exact);
            for (u, p) in slow.iter_mut().enumerate().take(36).skip(3) {
                if !opaque::is_opaque(&ls, u) && composite_pixel(p, &top, &bot, u - 3, w, &t) {
                    opaque::mark(&mut ls, u);
                }
            }
            assert_eq!(fast, slow);
            assert_eq!(lf, ls);
            assert_eq!(exact, slow);
            assert_eq!(le, ls);
        }
    }

    /// The portable kernels returning the run's exact highest opacity, as the vector
    /// builds' over kernels do (the portable one returns `u16::MAX`).
    struct Exact;

    impl Kernels for Exact {
        fn warm(&self, voxels: &[Voxel]) {
            touch(voxels)
        }
        fn premultiply(&self, c: &[u16; 4], e: &ShadeEntry, alpha: u32) -> Rgba {
            premultiply(c, e, alpha)
        }
        fn over_run(&self, px: &mut [Rgba], top: &[Rgba], bot: &[Rgba], w: [u32; 4]) -> u16 {
            over_run(px, top, bot, w);
            highest(px)
        }
        fn closed_bits(&self, px: &[Rgba], thr: u32) -> u64 {
            closed_bits(px, thr)
        }
        fn perspective(&self, job: SliceJob<'_, '_>) -> Result<(), Error> {
            crate::perspective::composite_slice(job, self)
        }
    }

    /// A run is marked only where a pixel reached the threshold, and a pixel that
    /// reaches it exactly is marked: the run's highest opacity decides whether its
    /// pixels are looked at, wherever the pixel lies in the run.
    #[test]
    fn a_pixel_that_reaches_the_threshold_exactly_is_marked() {
        check_exact_threshold(&Portable);
        check_exact_threshold(&Exact);
    }

    fn check_exact_threshold(kern: &impl Kernels) {
        let a = 20_000u16;
        for len in 1..=9 {
            for at in 0..len {
                // Weights all on the top-left tap: pixel u reads top[u - n] alone.
                let w = [ONE, 0, 0, 0];
                let mut top = [[0u16; 4]; 12];
                top[at] = [a / 2, a / 3, a / 4, a];
                let bot = [[7u16; 4]; 12];
                for (ert, marked) in [(a as u32, true), (a as u32 + 1, false)] {
                    let mut px = [[0u16; 4]; 10];
                    let mut op = [0 as opaque::Word; opaque::words(10)];
                    let taps = Taps {
                        top: &top,
                        bot: &bot,
                        n: 0,
                        w,
                    };
                    over_span(&mut px, &mut op, &taps, 0..len, ert, kern);
                    assert_eq!(px[at][3], a, "length {len}, pixel {at}");
                    for u in 0..len {
                        let want = marked && u == at;
                        assert_eq!(opaque::is_opaque(&op, u), want, "length {len}, pixel {u}");
                    }
                }
            }
        }
    }
}
