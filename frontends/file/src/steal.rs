//! Sharing one frame's compositing among threads by splitting bands between slices.
//!
//! Each thread starts with an equal band of the intermediate image's scanlines and
//! composites every slice into it, front to back. A thread that finishes takes over the
//! lower half of the band with the most work left: it asks, and the band's thread splits
//! its band ([`Intermediate::split_off`]) before its next slice and hands the lower half
//! over together with the slice position both halves go on from. Lacroute (1995, ch. 6)
//! assigns scanline bands to processors dynamically in the same spirit; splitting lazily
//! keeps the bands few.
//!
//! Few bands matter because each band shades again, in every slice, the voxel row that
//! its first scanline shares with the band above (a shaded row serves two scanlines).
//! With bands claimed from a queue, long ones first, a frame had 9–13 bands, and the
//! two threads' busy time summed to 5–10 % more than with two fixed halves (brainsmall,
//! the MR head, the hires brain and spheres256, 256² and 512²); fixed halves, in turn,
//! left one thread idle for up to a fifth of the frame. Here a frame has as many bands
//! as threads plus one per split, and a split late in the frame costs only the slices
//! left.

use shearwarp_core::composite::Intermediate;
use shearwarp_core::Error;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Mutex;

/// A band of scanlines and how far it has been composited.
pub(crate) struct Piece<'a> {
    /// The band's pixels and opaque-pixel bitmap.
    pub img: Intermediate<'a>,
    /// The band's scanline extents, found when it is finished.
    pub extents: &'a mut [[u32; 2]],
    /// Slice position reached: the band holds slices `0..next`.
    pub next: usize,
}

/// What the threads of one frame share: who holds how much, and the requests and
/// answers between them. Thread `t` is the `t`-th worker of the frame.
pub(crate) struct Sharing<'a> {
    /// Slices per frame.
    slices: usize,
    /// Fewest scanlines a band is split into.
    min_rows: usize,
    board: Mutex<Board<'a>>,
    /// Thread `t`'s flags are `flags[t]`.
    flags: Vec<Flags>,
}

/// Thread `t`'s flags, which it writes (`next`) and reads (`wanted`) before every slice.
///
/// Each thread's flags fill a 128-byte block of their own (two cache lines: x86 cores
/// fetch lines in adjacent pairs). Packed side by side, every thread's per-slice store
/// would take the one line they shared away from all the others, a transfer per thread
/// per slice that grows with the thread count. On this project's two-core host the
/// packed and padded layouts time alike, within the host's noise; the padding is for
/// more cores.
#[repr(align(128))]
#[derive(Default)]
struct Flags {
    /// Thread `t`'s slice position, updated before each slice it composites.
    next: AtomicUsize,
    /// A thread waits for part of thread `t`'s band.
    wanted: AtomicBool,
    /// Thread `t`'s request has an answer.
    answered: AtomicBool,
}

/// The part of [`Sharing`] that changes only under its lock.
struct Board<'a> {
    /// Scanlines of thread `t`'s band, 0 when it has none to share.
    rows: Vec<usize>,
    /// The thread waiting for part of thread `t`'s band.
    thief: Vec<Option<usize>>,
    /// The answer to thread `t`'s request: a band, or `None` when it was declined.
    answer: Vec<Option<Option<Piece<'a>>>>,
}

/// Spins before a waiting thread starts yielding its core: about as long as a slice of
/// a large volume takes to composite.
const SPINS: usize = 4096;

impl<'a> Sharing<'a> {
    /// A frame of `slices` slices whose threads start with bands of `rows[t]` scanlines;
    /// bands are not split below `min_rows` scanlines.
    pub fn new(slices: usize, min_rows: usize, rows: Vec<usize>) -> Self {
        let n = rows.len();
        Sharing {
            slices,
            min_rows: min_rows.max(1),
            board: Mutex::new(Board {
                rows,
                thief: vec![None; n],
                answer: (0..n).map(|_| None).collect(),
            }),
            flags: (0..n).map(|_| Flags::default()).collect(),
        }
    }

    /// Whether thread `t` should stop before slice position `next` and answer a request
    /// ([`Sharing::serve`]); records the position for thieves choosing a band.
    #[inline]
    pub fn wanted(&self, t: usize, next: usize) -> bool {
        self.flags[t].next.store(next, Ordering::Relaxed);
        self.flags[t].wanted.load(Ordering::Acquire)
    }

    fn board(&self) -> Result<std::sync::MutexGuard<'_, Board<'a>>, Error> {
        self.board.lock().map_err(|_| Error::Source {
            reason: "a compositing thread panicked",
        })
    }

    /// Answers the request for part of thread `t`'s band `piece`, which stopped before
    /// slice position `piece.next`: the lower half goes to the thief when both halves
    /// keep at least the minimum of scanlines, otherwise the request is declined and the
    /// band is no longer offered.
    pub fn serve(&self, t: usize, piece: &mut Piece<'a>) -> Result<(), Error> {
        let mut b = self.board()?;
        self.flags[t].wanted.store(false, Ordering::Relaxed);
        let Some(thief) = b.thief[t].take() else {
            return Ok(());
        };
        let rows = piece.img.rows();
        let answer = if rows >= 2 * self.min_rows && piece.next < self.slices {
            let keep = rows - rows / 2;
            let img = piece.img.split_off(keep)?;
            let (mine, theirs) = std::mem::take(&mut piece.extents).split_at_mut(keep);
            piece.extents = mine;
            b.rows[t] = keep;
            b.rows[thief] = rows - keep;
            self.flags[thief].next.store(piece.next, Ordering::Relaxed);
            Some(Piece {
                img,
                extents: theirs,
                next: piece.next,
            })
        } else {
            b.rows[t] = 0;
            None
        };
        b.answer[thief] = Some(answer);
        self.flags[thief].answered.store(true, Ordering::Release);
        Ok(())
    }

    /// Thread `t` holds no band any more: a request waiting on it is declined.
    pub fn retire(&self, t: usize) {
        // A poisoned lock means another thread panicked; the frame fails anyway, and
        // the answer still has to reach any thread waiting on this one.
        let mut b = self.board.lock().unwrap_or_else(|e| e.into_inner());
        b.rows[t] = 0;
        self.flags[t].wanted.store(false, Ordering::Relaxed);
        if let Some(thief) = b.thief[t].take() {
            b.answer[thief] = Some(None);
            self.flags[thief].answered.store(true, Ordering::Release);
        }
    }

    /// For thread `t`, which holds no band: the lower half of the band with the most
    /// work left (scanlines × slices), asked of its thread and waited for; `None` when
    /// no band is left to split.
    pub fn steal(&self, t: usize) -> Result<Option<Piece<'a>>, Error> {
        loop {
            {
                let mut b = self.board()?;
                let left = |v: usize| {
                    b.rows[v]
                        * (self.slices
                            - self.flags[v].next.load(Ordering::Relaxed).min(self.slices))
                };
                let victim = (0..b.rows.len())
                    .filter(|&v| v != t && b.thief[v].is_none() && b.rows[v] >= 2 * self.min_rows)
                    .max_by_key(|&v| left(v))
                    .filter(|&v| left(v) > 0);
                let Some(v) = victim else {
                    return Ok(None);
                };
                b.thief[v] = Some(t);
                b.answer[t] = None;
                self.flags[t].answered.store(false, Ordering::Relaxed);
                self.flags[v].wanted.store(true, Ordering::Release);
            }
            // The band's thread answers before its next slice, or when it finishes.
            let mut spins = 0;
            while !self.flags[t].answered.load(Ordering::Acquire) {
                spins += 1;
                if spins < SPINS {
                    std::hint::spin_loop();
                } else {
                    std::thread::yield_now();
                }
            }
            if let Some(Some(piece)) = self.board()?.answer[t].take() {
                return Ok(Some(piece));
            }
            // Declined: that band is no longer offered; look again.
        }
    }
}

/// Retires thread `t` from `sharing` when dropped, on every way out of its work
/// (errors and panics included), so that no thread waits on it for ever.
pub(crate) struct Retire<'s, 'a> {
    pub sharing: &'s Sharing<'a>,
    pub t: usize,
}

impl Drop for Retire<'_, '_> {
    fn drop(&mut self) {
        self.sharing.retire(self.t);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use shearwarp_core::composite::Rgba;
    use shearwarp_core::opaque;

    const W: usize = 5;

    /// A band of `rows` scanlines from `row0` of a `W`-wide, 64-high image, over
    /// buffers the caller keeps.
    fn piece<'a>(
        row0: usize,
        rows: usize,
        px: &'a mut [Rgba],
        links: &'a mut [opaque::Word],
        ext: &'a mut [[u32; 2]],
        next: usize,
    ) -> Piece<'a> {
        Piece {
            img: Intermediate::band(W, 64, row0, rows, px, links).unwrap(),
            extents: ext,
            next,
        }
    }

    /// A thread that asks gets the lower half of the other thread's band, from the slice
    /// position that thread stopped at, with the matching extents; the band's thread
    /// keeps the upper half. Fails if the halves overlap, leave a gap or start from the
    /// wrong slice.
    #[test]
    fn a_request_is_answered_with_the_lower_half_from_the_slice_reached() {
        let (mut px, mut links, mut ext) = (vec![[0; 4]; W * 40], vec![0; 40], vec![[0; 2]; 40]);
        // Mark every scanline's extent with its index, to see which ones each half got.
        for (i, e) in ext.iter_mut().enumerate() {
            *e = [i as u32; 2];
        }
        let sharing = Sharing::new(30, 8, vec![40, 0]);
        let mut mine = piece(10, 40, &mut px, &mut links, &mut ext, 0);
        std::thread::scope(|s| {
            let thief = s.spawn(|| sharing.steal(1).unwrap());
            // Composite "slices" until asked, as the renderer's loop does.
            let mut at = 0;
            while !sharing.wanted(0, at) {
                at = (at + 1).min(29);
                std::thread::yield_now();
            }
            mine.next = at;
            sharing.serve(0, &mut mine).unwrap();
            let theirs = thief.join().unwrap().expect("a band");
            assert_eq!((mine.img.first_row(), mine.img.rows()), (10, 20));
            assert_eq!((theirs.img.first_row(), theirs.img.rows()), (30, 20));
            assert_eq!(theirs.next, at);
            assert_eq!(mine.extents.len(), 20);
            assert_eq!(theirs.extents[0], [20; 2]);
            assert_eq!(theirs.img.pixels().len(), 20 * W);
        });
        assert!(!sharing.wanted(0, 5), "the request was answered");
    }

    /// A thread that retires declines the request waiting on it, and a band that has
    /// composited its last slice is not split and no longer offered: in both cases the
    /// thief gets `None` instead of waiting for ever.
    #[test]
    fn finished_bands_and_retired_threads_decline() {
        let (mut px, mut links, mut ext) = (vec![[0; 4]; W * 40], vec![0; 40], vec![[0; 2]; 40]);
        let sharing = Sharing::new(30, 8, vec![16, 0, 40]);
        let mut done = piece(
            0,
            16,
            &mut px[..W * 16],
            &mut links[..16],
            &mut ext[..16],
            30,
        );
        std::thread::scope(|s| {
            // Thread 2 (the most work) retires without compositing: the thief is
            // declined there, then asks thread 0, which has finished its slices.
            let thief = s.spawn(|| sharing.steal(1).unwrap());
            while !sharing.wanted(2, 0) {
                std::thread::yield_now();
            }
            sharing.retire(2);
            while !sharing.wanted(0, 29) {
                std::thread::yield_now();
            }
            sharing.serve(0, &mut done).unwrap();
            assert!(thief.join().unwrap().is_none());
        });
        assert_eq!(done.img.rows(), 16);
        // Nothing is left to ask for.
        assert!(sharing.steal(1).unwrap().is_none());
    }
}
