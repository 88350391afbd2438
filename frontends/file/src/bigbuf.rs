//! Large preprocessing buffers backed by huge pages where the kernel offers them.
//!
//! Encoding a 256³ volume through a dense classified copy (the viewer's route) writes
//! that 64 MiB copy, a 16 MiB transpose slab and three axis copies, all freshly
//! allocated; the file frontend's route still writes the three copies. With 4 KiB
//! pages that is tens of thousands of page faults, and `perf` put the kernel's fault
//! and page-clearing paths at about a fifth of the encoding. Linux backs a region with
//! 2 MiB pages on request (`MADV_HUGEPAGE`; its usual setting, `madvise`, does so only
//! when asked), which turns those faults into a few dozen: the nested-spheres 256³
//! encoding went from 194–202 ms to 137–141 ms on one thread here (alternating runs).
//! Elsewhere the buffers are plain vectors.

/// A vector of `n` copies of `value`, its memory advised for huge pages before it is
/// first written.
pub fn filled<T: Clone>(n: usize, value: T) -> Vec<T> {
    let mut v = Vec::with_capacity(n);
    advise_huge(&mut v);
    v.resize(n, value);
    v
}

/// `n` zero bytes, allocated zeroed (pages are not touched until written) and advised
/// for huge pages: for worst-case buffers written from the front and then trimmed.
pub fn zeroed_bytes(n: usize) -> Vec<u8> {
    let mut v = vec![0u8; n];
    advise_huge(&mut v);
    v
}

/// Asks for huge pages over the whole 2 MiB-aligned part of `v`'s capacity.
#[cfg(target_os = "linux")]
fn advise_huge<T>(v: &mut Vec<T>) {
    const HUGE: usize = 2 << 20;
    let bytes = v.capacity().saturating_mul(std::mem::size_of::<T>());
    let start = v.as_mut_ptr() as usize;
    let lo = start.next_multiple_of(HUGE);
    let hi = start.saturating_add(bytes) / HUGE * HUGE;
    if lo < hi {
        // SAFETY: [lo, hi) lies inside the allocation `v` owns, and MADV_HUGEPAGE only
        // changes which page size the kernel backs it with, never its contents or
        // validity. The call can fail (e.g. huge pages disabled); it is a hint, so the
        // result is ignored.
        unsafe {
            libc::madvise(lo as *mut libc::c_void, hi - lo, libc::MADV_HUGEPAGE);
        }
    }
}

#[cfg(not(target_os = "linux"))]
fn advise_huge<T>(_: &mut Vec<T>) {}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn buffers_hold_what_they_were_made_with() {
        for n in [0, 1, 1000, 3 << 20] {
            let v = filled(n, 7u32);
            assert_eq!(v.len(), n);
            assert!(v.iter().all(|&x| x == 7));
            let z = zeroed_bytes(n);
            assert_eq!(z.len(), n);
            assert!(z.iter().all(|&x| x == 0));
        }
    }
}
