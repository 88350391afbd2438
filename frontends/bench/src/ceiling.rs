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
    /// An integer loop in registers (no memory traffic), bound by one chain's latency.
    pub compute: f64,
    /// Vector multiply-adds in registers, bound by the vector units' throughput as the
    /// compositor's kernels are (AVX2 where the CPU has it).
    pub vector: f64,
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

/// Sixty-four independent lanes (eight AVX2 registers' worth) of multiply-adds, `n`
/// steps: throughput-bound, where [`compute`] is latency-bound. A core that slows down
/// when its neighbour also runs wide vector code (shared power budget, shared pipelines)
/// shows it here and not in [`compute`]. The AVX2 build runs where the CPU has it, as the
/// compositor's x86-64-v3 build does.
fn vector(n: u64) -> u32 {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2, checked just above.
        return unsafe { vector_avx2(n) };
    }
    lanes(n)
}

/// [`lanes`] in AVX2 registers, one chain a register (the compiler keeps [`lanes`] in
/// scalar registers).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn vector_avx2(n: u64) -> u32 {
    use std::arch::x86_64::*;
    let m = _mm256_set1_epi32(MUL as i32);
    let mut acc = [_mm256_setzero_si256(); 8];
    for (c, a) in acc.iter_mut().enumerate() {
        *a = _mm256_set1_epi32(c as i32 + 1);
    }
    for i in 0..n {
        let k = _mm256_set1_epi32((i as u32 | 1) as i32);
        for a in &mut acc {
            *a = _mm256_add_epi32(_mm256_mullo_epi32(*a, m), k);
        }
    }
    let mut x = _mm256_setzero_si256();
    for a in acc {
        x = _mm256_xor_si256(x, a);
    }
    let lane = [
        _mm256_extract_epi32::<0>(x),
        _mm256_extract_epi32::<1>(x),
        _mm256_extract_epi32::<2>(x),
        _mm256_extract_epi32::<3>(x),
        _mm256_extract_epi32::<4>(x),
        _mm256_extract_epi32::<5>(x),
        _mm256_extract_epi32::<6>(x),
        _mm256_extract_epi32::<7>(x),
    ];
    lane.iter().fold(0, |s, &v| s.rotate_left(1) ^ v as u32)
}

const MUL: u32 = 0x9e37_79b9;

/// The portable form of [`vector`]: eight chains of eight lanes, chain `c` starting at
/// `c + 1`, each step `x·MUL + (i | 1)`; the chains XORed lane by lane, then the lanes
/// folded.
fn lanes(n: u64) -> u32 {
    let mut acc = [[0u32; 8]; 8];
    for (c, chain) in acc.iter_mut().enumerate() {
        *chain = [c as u32 + 1; 8];
    }
    for i in 0..n {
        let k = i as u32 | 1;
        for chain in &mut acc {
            for x in chain.iter_mut() {
                *x = x.wrapping_mul(MUL).wrapping_add(k);
            }
        }
    }
    let mut x = [0u32; 8];
    for chain in acc {
        for (x, v) in x.iter_mut().zip(chain) {
            *x ^= v;
        }
    }
    x.iter().fold(0, |s, &v| s.rotate_left(1) ^ v)
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
        vector: scaling(threads, 7, &|_| u64::from(vector(black_box(20_000_000)))),
        stream: scaling(threads, 7, &|t| stream(&bufs[t]) ^ stream(&bufs[t])),
    }
}

impl Ceiling {
    /// One sentence for the report.
    pub fn describe(&self) -> String {
        format!(
            "this machine's own ceiling for {} threads, measured in the same run (the same \
             work on each thread, nothing shared; best of 7): {:.2}x on an integer loop in \
             registers, {:.2}x on vector multiply-adds in registers, {:.2}x reading a private \
             64 MiB buffer per thread",
            self.threads, self.compute, self.vector, self.stream
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_kernels_depend_on_their_input() {
        assert_ne!(compute(1000), compute(1001));
        assert_ne!(vector(1000), vector(1001));
        assert_eq!(vector(1000), lanes(1000));
        assert_ne!(stream(&[1; 64]), stream(&[2; 64]));
    }

    #[test]
    fn one_thread_scales_by_one_within_noise() {
        // The same work timed against itself: the ratio is 1 up to timing noise.
        let s = scaling(1, 3, &|_| compute(black_box(200_000)));
        assert!((0.5..2.0).contains(&s), "{s}");
    }
}
