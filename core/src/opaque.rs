//! Which pixels of the intermediate image are opaque: one bit per pixel.
//!
//! Early ray termination needs, for every scanline, a fast way past the pixels that have
//! reached the termination opacity. Lacroute (1995, §4.1.2) stores per pixel the offset
//! to the next pixel that may still change and compresses those paths as they are
//! followed. A bitmap answers the same questions with word operations instead of a
//! chain of dependent loads: 64 pixels are tested at once, the next open pixel and the
//! end of an open run are trailing-zero counts, and the voxels a row must shade are the
//! open bits of the scanlines that read it, shifted by the slice offset and ORed (see
//! [`crate::composite`]). It also takes a sixteenth of the memory of 16-bit links.
//!
//! Storage is the caller's buffer of [`Word`]s (the one that held the links), `BITS`
//! pixels per word, each scanline starting on a word: bit `u % BITS` of word `u / BITS`
//! is set once pixel `u` is opaque. A zeroed buffer is an image with every pixel open.

/// The bitmap's storage word: 64 pixels on 64-bit targets, where a 65-pixel window is
/// two loads, and 16 on others, where 64-bit shifts are several instructions each (the
/// Cortex-M3 firmware was measured with 16-bit words).
#[cfg(target_pointer_width = "64")]
pub type Word = u64;
/// The bitmap's storage word (see the 64-bit definition).
#[cfg(not(target_pointer_width = "64"))]
pub type Word = u16;

/// Pixels per word.
const BITS: usize = Word::BITS as usize;

/// Words one scanline of `width` pixels takes.
#[inline]
pub const fn words(width: usize) -> usize {
    width.div_ceil(BITS)
}

/// Bits `0..n` set (`n` at most 64).
#[inline(always)]
pub(crate) const fn ones(n: usize) -> u64 {
    if n >= 64 {
        u64::MAX
    } else {
        (1u64 << n) - 1
    }
}

/// What the bitmap needs of its storage word. Both widths are implemented (and tested on
/// every host); [`Word`] picks one per target.
pub(crate) trait BitWord: Copy + Eq {
    /// Pixels per word.
    const BITS: usize;
    /// Every pixel opaque.
    const ALL: Self;
    /// The 64 bits of `line` from word `w` on and the word (or words) after them, both
    /// widened to `u64`; words past the end read as zero.
    fn words(line: &[Self], w: usize) -> (u64, u64);
    /// ORs `m << o` into `line` from word `w` on (bits past the end are dropped).
    fn or_bits(line: &mut [Self], w: usize, o: usize, m: u64);
    /// Bits `lo..=hi` (`lo <= hi < BITS`).
    fn range(lo: usize, hi: usize) -> Self;
    /// `self & mask == mask`.
    fn covers(self, mask: Self) -> bool;
    /// `self & mask == 0`.
    fn misses(self, mask: Self) -> bool;
    /// Bit `i`.
    fn bit(self, i: usize) -> bool;
    /// Sets bit `i`.
    fn set(&mut self, i: usize);
}

/// The parts of [`BitWord`] that are the same for every width.
macro_rules! word_bits {
    ($t:ty) => {
        const BITS: usize = <$t>::BITS as usize;
        const ALL: Self = <$t>::MAX;
        #[inline(always)]
        fn range(lo: usize, hi: usize) -> $t {
            (<$t>::MAX << lo) & (<$t>::MAX >> (<Self as BitWord>::BITS - 1 - hi))
        }
        #[inline(always)]
        fn covers(self, mask: $t) -> bool {
            self & mask == mask
        }
        #[inline(always)]
        fn misses(self, mask: $t) -> bool {
            self & mask == 0
        }
        #[inline(always)]
        fn bit(self, i: usize) -> bool {
            self >> i & 1 != 0
        }
        #[inline(always)]
        fn set(&mut self, i: usize) {
            *self |= 1 << i;
        }
    };
}

impl BitWord for u16 {
    #[inline(always)]
    fn words(line: &[u16], w: usize) -> (u64, u64) {
        // One bounds check for the five words in the common case, one per word at the
        // end.
        match line.get(w..w + 5) {
            Some(&[a, b, c, d, e]) => (
                a as u64 | (b as u64) << 16 | (c as u64) << 32 | (d as u64) << 48,
                e as u64,
            ),
            _ => {
                let word = |k: usize| line.get(w + k).map_or(0, |&x| x as u64);
                (
                    word(0) | word(1) << 16 | word(2) << 32 | word(3) << 48,
                    word(4),
                )
            }
        }
    }
    #[inline(always)]
    fn or_bits(line: &mut [u16], w: usize, o: usize, m: u64) {
        let v = (m as u128) << o;
        for k in 0..5 {
            if let Some(x) = line.get_mut(w + k) {
                *x |= (v >> (16 * k)) as u16;
            }
        }
    }
    word_bits!(u16);
}

impl BitWord for u64 {
    #[inline(always)]
    fn words(line: &[u64], w: usize) -> (u64, u64) {
        match line.get(w..w + 2) {
            Some(&[a, b]) => (a, b),
            _ => (line.get(w).copied().unwrap_or(0), 0),
        }
    }
    #[inline(always)]
    fn or_bits(line: &mut [u64], w: usize, o: usize, m: u64) {
        let v = (m as u128) << o;
        if let Some(x) = line.get_mut(w) {
            *x |= v as u64;
        }
        if let Some(x) = line.get_mut(w + 1) {
            *x |= (v >> 64) as u64;
        }
    }
    word_bits!(u64);
}

/// The opaque bits of pixels `start..start + 64` (`start >= 0`) of a scanline stored in
/// `line`, bit `t` for pixel `start + t`, and the bit of pixel `start + 64`; words past
/// the end read as zero.
#[inline(always)]
fn opaque_window<W: BitWord>(line: &[W], start: usize) -> (u64, bool) {
    window(W::words(line, start / W::BITS), start % W::BITS)
}

/// The 64 bits from bit `o` (`o < BITS`) of the 64 bits `lo` and the word(s) `top` after
/// them, and the bit after those ([`opaque_window`]).
#[inline(always)]
fn window((lo, top): (u64, u64), o: usize) -> (u64, bool) {
    let win = if o == 0 {
        lo
    } else {
        (lo >> o) | (top << (64 - o))
    };
    (win, top >> o & 1 != 0)
}

/// Pixels `start..=start + 64` of a `width`-pixel scanline that no sample may change:
/// bit `t` of the word for pixel `start + t` (`t < 64`), and the flag for pixel
/// `start + 64`. A pixel is closed if it is opaque or lies outside `0..width`.
#[inline(always)]
pub(crate) fn closed65<W: BitWord>(line: &[W], width: usize, start: i64) -> (u64, bool) {
    // Inside the scanline, the common case, the window is the bits as stored (the MR
    // head, callgrind: 3.1 % fewer instructions a frame than clamping every window).
    if start >= 0 && start + 65 <= width as i64 {
        return opaque_window(line, start as usize);
    }
    // Pixels start + t with t in lo..hi lie in the scanline.
    let lo = (-start).clamp(0, 65) as usize;
    let hi = (width as i64 - start).clamp(0, 65) as usize;
    if lo >= hi {
        return (u64::MAX, true);
    }
    let (win, next) = if start >= 0 {
        opaque_window(line, start as usize)
    } else {
        // Here lo is in 1..=64: the window from pixel 0 moves up by lo bits.
        let (w0, _) = opaque_window(line, 0);
        let win = if lo < 64 { w0 << lo } else { 0 };
        (win, w0 >> (64 - lo) & 1 != 0)
    };
    let valid = ones(hi) & !ones(lo);
    (win | !valid, next || !(lo <= 64 && hi > 64))
}

/// [`closed65`] of two scanlines ANDed: the pixels closed in both. Inside the
/// scanline the words of the two are ANDed before the window is shifted out of them, once
/// (the MR head, callgrind: 3.0 % fewer instructions a frame than two windows).
#[inline(always)]
pub(crate) fn closed65_both<W: BitWord>(
    l0: &[W],
    l1: &[W],
    width: usize,
    start: i64,
) -> (u64, bool) {
    if start >= 0 && start + 65 <= width as i64 {
        let (s, o) = (start as usize / W::BITS, start as usize % W::BITS);
        let ((lo0, top0), (lo1, top1)) = (W::words(l0, s), W::words(l1, s));
        return window((lo0 & lo1, top0 & top1), o);
    }
    let ((c0, n0), (c1, n1)) = (closed65(l0, width, start), closed65(l1, width, start));
    (c0 & c1, n0 & n1)
}

/// True if every pixel of `a..b` that lies in `0..width` is opaque (pixels outside the
/// scanline count as closed, pixels past the stored words as open). Whole words are
/// compared at once, so a hidden-row test costs a word per 16 pixels instead of a
/// 65-pixel window per 64 voxels.
#[inline(always)]
pub(crate) fn all_closed<W: BitWord>(line: &[W], width: usize, a: i64, b: i64) -> bool {
    test_words(line, width, a, b, W::covers)
}

/// True if no pixel of `a..b` that lies in `0..width` is opaque, a word at a time like
/// [`all_closed`] (a range past the stored words is not known to be open: false).
#[inline(always)]
pub(crate) fn none_closed<W: BitWord>(line: &[W], width: usize, a: i64, b: i64) -> bool {
    test_words(line, width, a, b, W::misses)
}

/// `test(word, mask)` for every word of the bitmap that pixels `a..b` (clamped to
/// `0..width`) touch, with the mask of those pixels in it; true for an empty range.
#[inline(always)]
fn test_words<W: BitWord>(
    line: &[W],
    width: usize,
    a: i64,
    b: i64,
    test: impl Fn(W, W) -> bool,
) -> bool {
    let a = a.clamp(0, width as i64) as usize;
    let b = b.clamp(0, width as i64) as usize;
    if a >= b {
        return true;
    }
    let (wa, wb) = (a / W::BITS, (b - 1) / W::BITS);
    let Some(words) = line.get(wa..=wb) else {
        return false;
    };
    let (ha, tb) = (a % W::BITS, (b - 1) % W::BITS);
    match words {
        [w] => test(*w, W::range(ha, tb)),
        [first, mid @ .., last] => {
            test(*first, W::range(ha, W::BITS - 1))
                && test(*last, W::range(0, tb))
                && mid.iter().all(|&w| test(w, W::ALL))
        }
        [] => true,
    }
}

/// Bit `t` set if pixel `start + t` lies in `0..width` and is open (not opaque), for `t`
/// in `0..64`.
#[inline(always)]
pub(crate) fn open_bits<W: BitWord>(line: &[W], width: usize, start: i64) -> u64 {
    !closed65(line, width, start).0
}

/// True if pixel `u` is opaque (pixels past the stored words count as open).
#[inline(always)]
pub(crate) fn is_opaque<W: BitWord>(line: &[W], u: usize) -> bool {
    line.get(u / W::BITS).is_some_and(|w| w.bit(u % W::BITS))
}

/// Marks pixels `start + t` opaque for the bits `t` set in `m` (bits past the stored
/// words are dropped).
#[inline(always)]
pub(crate) fn mark_bits<W: BitWord>(line: &mut [W], start: usize, m: u64) {
    W::or_bits(line, start / W::BITS, start % W::BITS, m);
}

/// Marks pixel `u` opaque.
#[inline(always)]
pub(crate) fn mark<W: BitWord>(line: &mut [W], u: usize) {
    if let Some(w) = line.get_mut(u / W::BITS) {
        w.set(u % W::BITS);
    }
}

/// The first open pixel in `u..end` of a `width`-pixel scanline, or `end` if none.
#[cfg_attr(target_arch = "x86_64", inline(always))]
#[cfg_attr(not(target_arch = "x86_64"), inline)]
pub(crate) fn next_open<W: BitWord>(line: &[W], width: usize, mut u: usize, end: usize) -> usize {
    while u < end {
        let w = open_bits(line, width, u as i64);
        if w != 0 {
            return (u + w.trailing_zeros() as usize).min(end);
        }
        u += 64;
    }
    end
}

/// The end of the run of open pixels that starts at the open pixel `u`, at most `end`.
#[cfg_attr(target_arch = "x86_64", inline(always))]
#[cfg_attr(not(target_arch = "x86_64"), inline)]
pub(crate) fn open_run_end<W: BitWord>(
    line: &[W],
    width: usize,
    mut u: usize,
    end: usize,
) -> usize {
    while u < end {
        let w = open_bits(line, width, u as i64);
        let run = (!w).trailing_zeros() as usize;
        if run < 64 {
            return (u + run).min(end);
        }
        u += 64;
    }
    end
}

/// The runs of open pixels in a range of a scanline, front to back, from one read of the
/// bitmap per 64 pixels rather than two per run. The caller may mark pixels of the run
/// it was given opaque (compositing does) before it asks for the next: that leaves the
/// bits of the pixels after the run as they were read. A run that reaches a window's end
/// is followed into the next window.
pub(crate) struct OpenRuns {
    /// The window's first pixel.
    at: usize,
    /// Open pixels of the window not handed out yet, bit `t` for pixel `at + t`.
    open: u64,
    /// Where the next window starts.
    next: usize,
    end: usize,
}

impl OpenRuns {
    /// The runs in `start..end`; the first window is read by the first [`OpenRuns::next`].
    #[inline(always)]
    pub(crate) fn new(start: usize, end: usize) -> Self {
        OpenRuns {
            at: start,
            open: 0,
            next: start,
            end,
        }
    }

    /// The next run `u..e` of open pixels of `line` (`width` pixels), `None` past the end.
    #[inline(always)]
    pub(crate) fn next<W: BitWord>(&mut self, line: &[W], width: usize) -> Option<(usize, usize)> {
        while self.open == 0 {
            if self.next >= self.end {
                return None;
            }
            self.at = self.next;
            self.next = self.at + 64;
            self.open = open_bits(line, width, self.at as i64) & ones(self.end - self.at);
        }
        let z = self.open.trailing_zeros() as usize;
        let len = (!(self.open >> z)).trailing_zeros() as usize;
        let u = self.at + z;
        if z + len < 64 {
            self.open &= !ones(z + len);
            Some((u, u + len))
        } else {
            self.open = 0;
            self.next = open_run_end(line, width, self.at + 64, self.end);
            Some((u, self.next))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A scanline of `width` pixels with the given pixels opaque, in words of `W`.
    fn line<W: BitWord + Default>(width: usize, opaque: &[usize]) -> heapless::Vec<W, 16> {
        let mut l = heapless::Vec::new();
        l.resize(width.div_ceil(W::BITS), W::default()).unwrap();
        for &u in opaque {
            mark(&mut l, u);
        }
        l
    }

    /// Runs a test body for both word widths, whichever this target stores.
    macro_rules! both_widths {
        ($name:ident, $body:ident) => {
            #[test]
            fn $name() {
                $body::<u16>();
                $body::<u64>();
            }
        };
    }

    both_widths!(open_bits_match_the_per_pixel_definition, open_bits_case);
    fn open_bits_case<W: BitWord + Default>() {
        let width = 150;
        let opq = [0, 1, 5, 15, 16, 17, 63, 64, 65, 100, 127, 128, 149];
        let l = line::<W>(width, &opq);
        for start in -80i64..200 {
            let w = open_bits(&l, width, start);
            for t in 0..64 {
                let u = start + t;
                let open = u >= 0 && (u as usize) < width && !opq.contains(&(u as usize));
                assert_eq!(w >> t & 1 != 0, open, "start {start} t {t}");
            }
        }
        for u in 0..width {
            assert_eq!(is_opaque(&l, u), opq.contains(&u));
        }
        for start in -80i64..200 {
            let (_, next) = closed65(&l, width, start);
            let u = start + 64;
            let open = u >= 0 && (u as usize) < width && !opq.contains(&(u as usize));
            assert_eq!(next, !open, "start {start}: pixel {u}");
        }
    }

    both_widths!(closed65_both_is_the_two_windows_anded, closed65_both_case);
    fn closed65_both_case<W: BitWord + Default>() {
        let width = 150;
        let mut rng = crate::xorshift(0x0b07);
        for _ in 0..40 {
            let mut pick = || -> heapless::Vec<usize, 150> {
                (0..width).filter(|_| !rng().is_multiple_of(3)).collect()
            };
            let (o0, o1) = (pick(), pick());
            let (l0, l1) = (line::<W>(width, &o0), line::<W>(width, &o1));
            for start in -80i64..200 {
                let ((c0, n0), (c1, n1)) =
                    (closed65(&l0, width, start), closed65(&l1, width, start));
                assert_eq!(
                    closed65_both(&l0, &l1, width, start),
                    (c0 & c1, n0 & n1),
                    "start {start}"
                );
            }
        }
    }

    both_widths!(
        open_runs_are_those_of_the_pixel_by_pixel_walk,
        open_runs_case
    );
    fn open_runs_case<W: BitWord + Default + core::fmt::Debug>() {
        let width = 150;
        let mut rng = crate::xorshift(0x0be7);
        for round in 0..200 {
            let dense = round % 4;
            let opq: heapless::Vec<usize, 150> = (0..width)
                .filter(|_| rng() % 8 < dense as u64 * 2)
                .collect();
            let (a, b) = ((rng() % 160) as usize, (rng() % 160) as usize);
            let (start, end) = (a.min(b), a.max(b).min(width));
            // Each run marks some of its own pixels opaque, as compositing does; the
            // walk must find the runs of the bitmap as it was before them.
            let marks = |u: usize| (u * 7 + round).is_multiple_of(3);
            let mut l = line::<W>(width, &opq);
            let mut got: heapless::Vec<(usize, usize), 150> = heapless::Vec::new();
            let mut runs = OpenRuns::new(start, end);
            while let Some((u, e)) = runs.next(&l, width) {
                got.push((u, e)).unwrap();
                (u..e).filter(|&x| marks(x)).for_each(|x| mark(&mut l, x));
            }
            let mut want: heapless::Vec<(usize, usize), 150> = heapless::Vec::new();
            let mut u = start;
            while u < end {
                if opq.contains(&u) {
                    u += 1;
                    continue;
                }
                let mut e = u;
                while e < end && !opq.contains(&e) {
                    e += 1;
                }
                want.push((u, e)).unwrap();
                u = e;
            }
            assert_eq!(got, want, "round {round}: {start}..{end}");
        }
    }

    both_widths!(
        none_closed_matches_the_per_pixel_definition,
        none_closed_case
    );
    fn none_closed_case<W: BitWord + Default>() {
        let width = 150;
        for opaque in [None, Some(0), Some(15), Some(16), Some(70), Some(149)] {
            let opq: heapless::Vec<usize, 1> = opaque.into_iter().collect();
            let l = line::<W>(width, &opq);
            for a in -20i64..170 {
                for b in a - 1..a + 90 {
                    let want = !(a.max(0)..b.min(width as i64)).any(|u| opaque == Some(u as usize));
                    assert_eq!(
                        none_closed(&l, width, a, b),
                        want,
                        "opaque {opaque:?} {a}..{b}"
                    );
                }
            }
        }
        // Pixels past the stored words are not known to be open.
        assert!(!none_closed(
            &[W::default()],
            W::BITS + 24,
            0,
            W::BITS as i64 + 4
        ));
        assert!(none_closed(
            &[W::default()],
            W::BITS + 24,
            0,
            W::BITS as i64
        ));
    }

    both_widths!(all_closed_matches_the_per_pixel_definition, all_closed_case);
    fn all_closed_case<W: BitWord + Default>() {
        let width = 150;
        let mut opq: heapless::Vec<usize, 150> = (0..width).collect();
        for hole in [None, Some(0), Some(15), Some(16), Some(70), Some(149)] {
            if let Some(h) = hole {
                opq = (0..width).filter(|&u| u != h).collect();
            }
            let l = line::<W>(width, &opq);
            for a in -20i64..170 {
                for b in a - 1..a + 90 {
                    let want = (a.max(0)..b.min(width as i64)).all(|u| opq.contains(&(u as usize)));
                    assert_eq!(all_closed(&l, width, a, b), want, "hole {hole:?} {a}..{b}");
                }
            }
        }
        // Pixels past the stored words are open.
        assert!(!all_closed(&[W::ALL], W::BITS + 24, 0, W::BITS as i64 + 4));
        assert!(all_closed(&[W::ALL], W::BITS + 24, 0, W::BITS as i64));
    }

    both_widths!(
        mark_bits_marks_exactly_the_pixels_of_its_mask,
        mark_bits_case
    );
    fn mark_bits_case<W: BitWord + Default + core::fmt::Debug>() {
        let width = 150;
        let mut rng = crate::xorshift(0x5eed);
        for start in 0..width + 20 {
            let m = rng();
            let mut a = line::<W>(width, &[]);
            let mut b = line::<W>(width, &[]);
            mark_bits(&mut a, start, m);
            for t in 0..64 {
                if m >> t & 1 != 0 {
                    mark(&mut b, start + t);
                }
            }
            assert_eq!(a, b, "start {start} mask {m:#x}");
        }
    }

    both_widths!(runs_and_skips_cover_exactly_the_open_pixels, runs_case);
    fn runs_case<W: BitWord + Default>() {
        let width = 200;
        let opq: heapless::Vec<usize, 200> = (0..width)
            .filter(|u| (u * 7 + u / 13) % 5 < 2 || (70..150).contains(u))
            .collect();
        let l = line::<W>(width, &opq);
        for (lo, hi) in [(0, 200), (3, 64), (64, 65), (69, 151), (150, 200), (10, 10)] {
            // Walk the open runs with next_open / open_run_end ...
            let mut seen = [false; 200];
            let mut last = lo;
            let mut u = next_open(&l, width, lo, hi);
            while u < hi {
                let e = open_run_end(&l, width, u, hi);
                assert!(u >= last && u < e && e <= hi, "{lo}..{hi}: run {u}..{e}");
                // ... which are maximal: the pixel after a run is opaque or past hi.
                assert!(e == hi || opq.contains(&e));
                seen[u..e].iter_mut().for_each(|s| *s = true);
                last = e;
                u = next_open(&l, width, e, hi);
            }
            // ... and cover exactly the open pixels.
            for (u, s) in seen.iter().enumerate() {
                let want = u >= lo && u < hi && !opq.contains(&u);
                assert_eq!(*s, want, "{lo}..{hi} pixel {u}");
            }
        }
    }
}
