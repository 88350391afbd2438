//! How well this machine lets threads scale at all: the speed-up of work that shares
//! nothing between threads, measured in the same run as the renderers.
//!
//! A two-thread speed-up target means little without it. On a virtual machine the two
//! vCPUs may share a physical core's pipelines, the host's memory bandwidth and its
//! power budget with other guests, so even independent loops do not run twice as fast
//! on two threads. The renderer's two-thread speed-up is read against these figures.

use std::hint::black_box;
use std::time::Instant;

/// Speed-ups of `threads` threads over one, each thread doing the same work as the one.
#[derive(Clone, Copy, Debug)]
pub struct Ceiling {
    pub threads: usize,
    /// An integer loop in registers (no memory traffic).
    pub compute: f64,
    /// Each thread reading its own buffer, larger than the last-level cache, one load
    /// per cache line.
    pub stream: f64,
}

/// A dependent chain of multiplies and shifts, `n` steps.
fn compute(n: u64) -> u64 {
    let (mut x, mut y) = (0x9e37_79b9_7f4a_7c15u64, 7u64);
    for i in 0..n {
        x = x.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(i);
        y = (y ^ (x >> 17)).rotate_left(5).wrapping_add(x);
    }
    x ^ y
}

/// One load per 64-byte line of `buf`, summed.
fn stream(buf: &[u64]) -> u64 {
    buf.iter().step_by(8).fold(0u64, |s, &v| s.wrapping_add(v))
}

/// Wall time of `work(t)` on threads `t = 0..n` at once (thread 0 the calling one), ms.
fn timed(n: usize, work: &(dyn Fn(usize) -> u64 + Sync)) -> f64 {
    let start = Instant::now();
    std::thread::scope(|s| {
        let others: Vec<_> = (1..n).map(|t| s.spawn(move || work(t))).collect();
        black_box(work(0));
        for h in others {
            black_box(h.join().ok());
        }
    });
    start.elapsed().as_secs_f64() * 1e3
}

/// `threads`·t(1)/t(threads) for `work`, each time the best of `rounds` (one and
/// `threads` threads alternating, so drift in the machine's speed falls on both).
fn scaling(threads: usize, rounds: usize, work: &(dyn Fn(usize) -> u64 + Sync)) -> f64 {
    let (mut one, mut many) = (f64::MAX, f64::MAX);
    for _ in 0..rounds {
        one = one.min(timed(1, work));
        many = many.min(timed(threads, work));
    }
    threads as f64 * one / many
}

/// Measures both speed-ups (about a second in all).
pub fn measure(threads: usize) -> Ceiling {
    let threads = threads.max(1);
    // 64 MiB a thread: twice the 32 MiB L3 of the machines this was written on.
    let words = 8 << 20;
    let bufs: Vec<Vec<u64>> = (0..threads)
        .map(|t| (0..words as u64).map(|i| i ^ t as u64).collect())
        .collect();
    Ceiling {
        threads,
        compute: scaling(threads, 7, &|_| compute(black_box(20_000_000))),
        stream: scaling(threads, 7, &|t| stream(&bufs[t]) ^ stream(&bufs[t])),
    }
}

impl Ceiling {
    /// One sentence for the report.
    pub fn describe(&self) -> String {
        format!(
            "this machine's own ceiling for {} threads, measured in the same run (the same \
             work on each thread, nothing shared; best of 7): {:.2}x on an integer loop in \
             registers, {:.2}x reading a private 64 MiB buffer per thread",
            self.threads, self.compute, self.stream
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_kernels_depend_on_their_input() {
        assert_ne!(compute(1000), compute(1001));
        assert_ne!(stream(&[1; 64]), stream(&[2; 64]));
    }

    #[test]
    fn one_thread_scales_by_one_within_noise() {
        // The same work timed against itself: the ratio is 1 up to timing noise.
        let s = scaling(1, 3, &|_| compute(black_box(200_000)));
        assert!((0.5..2.0).contains(&s), "{s}");
    }
}
