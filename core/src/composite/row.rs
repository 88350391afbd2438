//! Voxel rows as the compositor reads them: the spans of a run-length-encoded scanline,
//! the row buffer its voxels are shaded into, and which of them open pixels still read.
//!
//! Each voxel row is shaded once per slice into a buffer of premultiplied colours and
//! read by the two intermediate scanlines it straddles. Behind opaque pixels most of a
//! row is never read, so [`Needed`] tells a row, from the opaque-pixel bitmaps of those
//! two scanlines, which voxels to shade and whether to shade it at all.

use super::{
    flat, row_buffer_len, FlatRule, Intermediate, Kernels, Mode, Rgba, Shading, SliceTables,
};
use crate::classify::Voxel;
use crate::clip::RowCut;
use crate::opaque;

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
    /// One bit per entry of `buf`, set for flat voxels ([`flat`]), as 64-bit words; empty
    /// where no rule for flat voxels is applied (perspective rows).
    pub(crate) flat: &'b mut [Rgba],
    /// True if some bit of `flat` may be set.
    pub(crate) has_flat: bool,
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
        Row::cleared(buf, &mut [], (0, n))
    }

    /// A row over `buf` and flat bits `flat` whose entries `dirty` may be non-zero (and
    /// whose bits may be set unless `dirty` is empty), cleared.
    pub(super) fn cleared(
        buf: &'b mut [Rgba],
        flat: &'b mut [Rgba],
        dirty: (usize, usize),
    ) -> Self {
        let mut r = Row {
            buf,
            flat,
            has_flat: dirty.0 < dirty.1,
            dirty,
            runs: [(0, 0); Row::RUNS],
            written: Row::UNKNOWN,
        };
        r.clear();
        r
    }

    /// The two row buffers for slices `ni` wide (`rows` holds at least
    /// [`row_buffer_len`]`(ni)` entries: two rows of `ni + 2`, then their flat bits),
    /// cleared unless `clean` says they already are.
    pub(super) fn pair(rows: &'b mut [Rgba], ni: usize, clean: bool) -> (Row<'b>, Row<'b>) {
        let rows = rows.get_mut(..row_buffer_len(ni)).unwrap_or_default();
        let (r0, rest) = rows.split_at_mut_checked(ni + 2).unwrap_or_default();
        let (r1, rest) = rest.split_at_mut_checked(ni + 2).unwrap_or_default();
        let (f0, f1) = rest
            .split_at_mut_checked(flat::words(ni))
            .unwrap_or_default();
        let all = if clean { (0, 0) } else { (0, ni + 2) };
        (Row::cleared(r0, f0, all), Row::cleared(r1, f1, all))
    }

    /// Buffer indices `[lo, hi)` that may hold non-zero entries, `None` if none.
    #[inline]
    pub(super) fn extent(&self) -> Option<(usize, usize)> {
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
        // Runs are cleared in blocks of eight entries (64 bytes, four 16-byte stores),
        // past a run's end where the buffer allows: an entry is either zero or in a run
        // being cleared, so zeroing more is harmless. A run is mostly a few voxels (the
        // MR head: 5.7), one block; as `fill` it was a call to `memset`, whose branches
        // on the length cost more than the stores (alternating runs, one thread, 256²:
        // brainsmall 1.05 → 0.99 ms, the head 4.58 → 4.35, the hires brain 13.49 →
        // 12.91; blocks of 4 entries: 1.01, 4.39, 13.18; of 16: 1.02, 4.55, 13.08).
        const BLOCK: usize = 8;
        let (a, b) = self.dirty;
        let b = b.min(self.buf.len());
        if a < b {
            // Without runs kept (`RUNS` 0) the test folds away and the extent is cleared.
            match self.runs.get(..self.written).filter(|_| Row::RUNS != 0) {
                Some(runs) => {
                    for &(x, y) in runs {
                        let mut i = x;
                        while i < y {
                            match self
                                .buf
                                .get_mut(i..)
                                .and_then(|s| s.first_chunk_mut::<BLOCK>())
                            {
                                Some(c) => *c = [[0; 4]; BLOCK],
                                None => {
                                    if let Some(r) = self.buf.get_mut(i..y) {
                                        r.fill([0; 4]);
                                    }
                                    break;
                                }
                            }
                            i += BLOCK;
                        }
                    }
                }
                None => self.buf[a..b].fill([0; 4]),
            }
        }
        if self.has_flat {
            self.flat.fill([0; 4]);
            self.has_flat = false;
        }
        self.dirty = (0, 0);
        self.written = 0;
    }

    /// After `shading` shaded voxels `src` (`n` of them) into entries `x + 1..`: their
    /// flat bits, when the way excludes flat voxels from samples' colours. Ways that
    /// always do copy them from the row's words of the slice's table of flat voxels,
    /// `table` ([`crate::rle::RleAxis::with_flat_rows`]), when it has one.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn note_flat<S: Shading>(
        &mut self,
        x: usize,
        src: &[Voxel],
        n: usize,
        table: &[Rgba],
        t: &SliceTables<'_>,
        shading: &S,
        k: &impl Kernels,
    ) {
        match S::FLAT {
            FlatRule::Never => {}
            FlatRule::Always if !table.is_empty() => {
                if flat::copy(self.flat, x + 1, table, n) {
                    self.has_flat = true;
                }
            }
            FlatRule::Always => self.mark_flat(x, src, n, k),
            FlatRule::AsAsked => {
                if shading.excludes_flat(t) {
                    self.mark_flat_out_of_line(x, src, n, k);
                }
            }
        }
    }

    /// [`Row::mark_flat`] out of line, for a loop that asks the tables which rule they
    /// want ([`FlatRule::AsAsked`]).
    #[inline(never)]
    fn mark_flat_out_of_line(&mut self, x: usize, src: &[Voxel], n: usize, k: &impl Kernels) {
        self.mark_flat(x, src, n, k)
    }

    /// Sets the flat bits of voxels `src` (as many as were shaded, `n`) at entries
    /// `x + 1..`: a pass of its own over the shaded voxels (asked in the shading loops
    /// instead, the test cost the default way an instruction a voxel).
    #[inline(always)]
    fn mark_flat(&mut self, x: usize, src: &[Voxel], n: usize, k: &impl Kernels) {
        if !self.flat.is_empty() && flat::mark(self.flat, x + 1, src, n, |v, n| k.flat_bits(v, n)) {
            self.has_flat = true;
        }
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

    /// Cuts shaded voxels `from..to` of the row by the clipping planes along it
    /// ([`RowCut::apply`]) for a frame in `mode`: in composite mode each colour is
    /// scaled by its voxel's coverage, as the voxel's opacity is, premultiplied. A MIP
    /// entry is the voxel's scalar, which opacity does not weigh: a voxel the planes
    /// cover at all is kept whole, as a classified cut keeps every voxel left with some
    /// opacity (the images are the same). Out of line:
    /// rows the planes cross are few next to the voxels shaded, and the loops of frames
    /// without planes stay as they were.
    #[inline(never)]
    pub(crate) fn cut(&mut self, cut: &RowCut, (from, to): (usize, usize), mode: Mode) {
        match mode {
            Mode::Composite => cut.apply(self.buf, (from, to), |e, c| {
                *e = e.map(|x| ((x as u32 * c + (1 << 15)) >> 16) as u16)
            }),
            Mode::Mip => cut.apply(self.buf, (from, to), |_, _| {}),
        }
    }

    /// [`Row::cut`] over every voxel the row holds. The row's extent then shrinks to
    /// the voxels the planes keep, so that the scanlines reading it composite only
    /// those (behind a cut, half a row of zeroes composited for nothing).
    pub(crate) fn cut_all(&mut self, cut: &RowCut, mode: Mode) {
        if let Some((lo, hi)) = self.extent() {
            self.cut(cut, (lo.saturating_sub(1), hi.saturating_sub(1)), mode);
            if let Some((a, b)) = cut.kept() {
                let (lo, hi) = (lo.max(a + 1), hi.min(b + 1));
                self.dirty = if lo < hi { (lo, hi) } else { (0, 0) };
            }
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
        self.note_flat(x, src, y - x, &[], t, shading, k);
        self.wrote(x + 1, y + 1);
        self.dirty = match self.extent() {
            Some((lo, hi)) => (lo.min(x + 1), hi.max(y + 1)),
            None => (x + 1, y + 1),
        };
    }

    /// `shading` shades the voxels of row `j` (see [`Shading`]). With `needed`, only
    /// voxels some non-opaque pixel will read are shaded (the others stay zero, and only
    /// opaque pixels, which are never composited again, would read them). With `cut`,
    /// the clipping planes along the row: the voxels they drop are not shaded (the loop
    /// bounds Lacroute designs them as, §7.5), and the rest are cut ([`Row::cut_all`]).
    #[allow(clippy::too_many_arguments)]
    #[cfg_attr(target_arch = "x86_64", inline(always))]
    pub(crate) fn fill(
        &mut self,
        row: (&[u8], &[Voxel], &[Rgba]),
        t: &SliceTables<'_>,
        j: i64,
        needed: Option<&Needed<'_>>,
        cut: Option<&RowCut>,
        k: &impl Kernels,
        shading: &impl Shading,
    ) {
        self.clear();
        // The voxels the planes keep: one range, or, inverted, the two about the hole.
        // The second is a pass of its own over the row's runs, so that rows without
        // planes keep the loop they had (a loop over both ranges in it cost the
        // Colin27 head's unclipped frames 6 % more instructions).
        let [first, second] = cut.map_or([(0, usize::MAX), (0, 0)], RowCut::kept_ranges);
        let face = cut.filter(|c| c.shades_face() && t.mode != Mode::Mip);
        self.fill_range(row, t, j, needed, first, face, k, shading);
        if second.0 < second.1 {
            self.fill_range(row, t, j, needed, second, face, k, shading);
        }
        if let Some(c) = cut {
            self.cut_all(c, t.mode);
        }
    }

    /// After voxels `x..y` were shaded from `src` (voxel `x` first): those of them in
    /// the layer shaded as the cut's face, if `face` has one there, shaded again by the
    /// nearest plane's normal ([`crate::clip::Clip::with_shaded_face`]) before the row
    /// is cut. A test a piece inline, the shading out of line.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn face_piece(
        &mut self,
        face: Option<&RowCut>,
        src: &[Voxel],
        (x, y): (usize, usize),
        t: &SliceTables<'_>,
        j: i64,
        k: &impl Kernels,
        shading: &impl Shading,
    ) {
        if let Some(c) = face {
            let [f0, f1] = c.face_ranges();
            if (f0.0 < y && x < f0.1) || (f1.0 < y && x < f1.1) {
                self.shade_face_in(c, src, (x, y), t, j, k, shading);
            }
        }
    }

    /// Shades again, by the nearest plane's normal, the voxels `x..y` of the row that
    /// lie in the layer shaded as the cut's face, `src` holding them from `x`: only
    /// those already shaded (a voxel left zero is one no open pixel reads). The
    /// voxels are shaded in batches of consecutive ones, their records copied with the
    /// plane's normal: one voxel a call cost 280 instructions a voxel (the Colin27
    /// head, a two-voxel layer).
    #[allow(clippy::too_many_arguments)]
    #[inline(never)]
    pub(crate) fn shade_face_in(
        &mut self,
        cut: &RowCut,
        src: &[Voxel],
        (x, y): (usize, usize),
        t: &SliceTables<'_>,
        j: i64,
        k: &impl Kernels,
        shading: &impl Shading,
    ) {
        if t.mode == Mode::Mip {
            return;
        }
        const BATCH: usize = 16;
        let mut batch = [Voxel::default(); BATCH];
        for (a, b) in cut.face_ranges() {
            let (mut i, end) = (a.max(x), b.min(y).min(x + src.len()));
            while i < end {
                // The next run of shaded voxels, at most a batch of them.
                let shaded = |e: &Rgba| *e != [0; 4];
                if !self.buf.get(i + 1).is_some_and(shaded) {
                    i += 1;
                    continue;
                }
                let mut n = 0;
                while n < BATCH && i + n < end && self.buf.get(i + n + 1).is_some_and(shaded) {
                    n += 1;
                }
                let (Some(from), Some(dst)) = (
                    src.get(i - x..i - x + n),
                    self.buf.get_mut(i + 1..i + n + 1),
                ) else {
                    return;
                };
                for ((f, v), at) in batch.iter_mut().zip(from).zip(i..) {
                    *f = Voxel {
                        normal: cut.face_code(at),
                        ..*v
                    };
                }
                shading.shade_run(dst, &batch, i, t, j, k);
                // They have a direction now: no longer flat voxels.
                if self.has_flat {
                    (i + 1..i + n + 1).for_each(|e| flat::clear(self.flat, e));
                }
                i += n;
            }
        }
    }

    /// [`Row::fill`]'s pass over voxels `from..to` of the row, adding the voxels it
    /// shades to the row's extent.
    #[allow(clippy::too_many_arguments)]
    #[cfg_attr(target_arch = "x86_64", inline(always))]
    fn fill_range(
        &mut self,
        (runs, voxels, table): (&[u8], &[Voxel], &[Rgba]),
        t: &SliceTables<'_>,
        j: i64,
        needed: Option<&Needed<'_>>,
        (first, last): (usize, usize),
        face: Option<&RowCut>,
        k: &impl Kernels,
        shading: &impl Shading,
    ) {
        let mut v = 0usize;
        let mut lo = usize::MAX;
        let mut hi = 0;
        // The last window of needed voxels computed: its first voxel and its bits
        // ([`Needed::voxels`]).
        let mut word = (usize::MAX / 2, 0u64);
        for (a0, b) in Spans::new(runs) {
            let base = v;
            v += b - a0;
            // The span's voxels in the range: voxel `a` at `voxels[base + a - a0]`.
            let (a, b) = (a0.max(first), b.min(last));
            if a >= b {
                continue;
            }
            match needed {
                None => {
                    lo = lo.min(a + 1);
                    hi = b + 1;
                    // Both in bounds for a validated slice and a buffer of
                    // `row_buffer_len` entries; a run past them is not shaded.
                    // `shade_run` shades as many voxels as `dst` holds.
                    let (Some(dst), Some(src)) = (
                        self.buf.get_mut(a + 1..b + 1),
                        voxels.get(base + (a - a0)..),
                    ) else {
                        continue;
                    };
                    shading.shade_run(dst, src, a, t, j, k);
                    self.note_flat(a, src, b - a, table, t, shading, k);
                    self.face_piece(face, src, (a, b), t, j, k, shading);
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
                            let (Some(dst), Some(src)) = (
                                self.buf.get_mut(c + 1..d + 1),
                                voxels.get(base + (c - a0)..),
                            ) else {
                                continue;
                            };
                            shading.shade_run(dst, src, c, t, j, k);
                            self.note_flat(c, src, d - c, table, t, shading, k);
                            self.face_piece(face, src, (c, d), t, j, k, shading);
                            self.wrote(c + 1, d + 1);
                        }
                    }
                }
            }
        }
        if lo < hi {
            self.dirty = match self.extent() {
                Some((x, y)) => (x.min(lo), y.max(hi)),
                None => (lo, hi),
            };
        }
    }
}

impl Row<'_> {
    /// `shading` shades the voxels of row `j` (`runs`, `voxels`) that lie in `needed`,
    /// sorted disjoint voxel ranges; the others stay zero. Those in `face`'s layer
    /// shaded as the cut's face are shaded so ([`Row::face_piece`]).
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn fill_in(
        &mut self,
        runs: &[u8],
        voxels: &[Voxel],
        t: &SliceTables<'_>,
        j: i64,
        needed: &[(usize, usize)],
        face: Option<&RowCut>,
        k: &impl Kernels,
        shading: &impl Shading,
    ) {
        self.clear();
        let mut need = needed.iter().peekable();
        let mut v = 0usize;
        for (a, b) in Spans::new(runs) {
            let base = v;
            v += b - a;
            // The ranges that overlap the span; one that runs on past it is kept for the
            // next span.
            while let Some(&&(c, d)) = need.peek() {
                if d <= a {
                    need.next();
                    continue;
                }
                if c >= b {
                    break;
                }
                let (x, y) = (c.max(a), d.min(b));
                if let Some(src) = voxels.get(base + (x - a)..) {
                    self.shade(src, (x, y), t, j, k, shading);
                    self.face_piece(face, src, (x, y), t, j, k, shading);
                }
                if d > b {
                    break;
                }
                need.next();
            }
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
    /// [`crate::rle::RleSlice::scanline`]).
    #[cfg_attr(target_arch = "x86_64", inline(always))]
    pub(super) fn lines(img: &'a Intermediate<'_>, v0: i64, shift: i64) -> Self {
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
    pub(super) fn reach(&self, runs: &[u8], ni: usize) -> Reach {
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
    pub(super) fn hides(&self, runs: &[u8], ni: usize) -> bool {
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
pub(super) enum Reach {
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
pub(super) fn visible_extent(runs: &[u8], ni: usize) -> Option<(usize, usize)> {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::composite::{
        mark_random_stretches, random_scanline, rng, Lit, PlainTables, Portable,
    };

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
            eager.fill((&runs, &voxels, &[]), &t, 0, None, None, &Portable, &Lit);
            let mut lazy = Row::new(&mut lazy_buf, false);
            lazy.fill(
                (&runs, &voxels, &[]),
                &t,
                0,
                Some(&need),
                None,
                &Portable,
                &Lit,
            );
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

    /// Clearing zeroes every written run, one that ends too near the buffer's end for a
    /// whole block of zeroes included, and nothing of the other row of the pair; with
    /// more runs than a row keeps, the whole extent is cleared. Fails if the blocks are
    /// cut short at a run's end or run on past the row's buffer.
    #[test]
    fn clearing_zeroes_the_written_runs_and_stays_in_its_row() {
        const NI: usize = 37;
        let mark = [7u16, 1, 2, 3];
        for runs in [
            &[(1, 2), (4, 13), (NI - 3, NI + 2)][..],
            &[
                (0, 3),
                (5, 6),
                (8, 9),
                (11, 12),
                (14, 15),
                (17, 18),
                (20, 21),
                (23, 24),
                (26, NI + 2),
            ],
        ] {
            let mut rows = [[0u16; 4]; row_buffer_len(NI)];
            let (mut r0, r1) = Row::pair(&mut rows, NI, true);
            r1.buf.fill(mark);
            for &(x, y) in runs {
                r0.buf[x..y].fill(mark);
                r0.wrote(x, y);
            }
            r0.dirty = (runs[0].0, runs[runs.len() - 1].1);
            r0.clear();
            assert!(r0.buf.iter().all(|e| *e == [0; 4]), "{runs:?}");
            assert_eq!(r0.extent(), None);
            assert!(r1.buf.iter().all(|e| *e == mark), "{runs:?}");
        }
    }
}
