//! Checksum repair for `.swv` bytes, so that a test or a fuzz input that changes a
//! file's structure reaches the structural checks behind the CRCs. Included by the
//! core's integration tests (`common/mod.rs`) and by the fuzz crate (`fuzz/src/lib.rs`),
//! which cannot depend on each other, so that both repair files the same way.

use shearwarp_core::io::Crc32;
use shearwarp_core::rle::{Axis, Layout};
use shearwarp_core::swv::{ENTRY_LEN, HEADER_LEN, TABLES_START};

fn u32_at(b: &[u8], o: usize) -> Option<u32> {
    Some(u32::from_le_bytes(b.get(o..o + 4)?.try_into().ok()?))
}

fn put_u32(b: &mut [u8], o: usize, v: u32) {
    if let Some(d) = b.get_mut(o..o + 4) {
        d.copy_from_slice(&v.to_le_bytes());
    }
}

/// Offset of the slice-table entry `e` (x-axis entries first, then y, then z).
pub fn entry_at(e: usize) -> usize {
    TABLES_START + ENTRY_LEN * e
}

/// Recomputes every checksum the bytes allow (slice records whose entry points inside
/// the file, the tables, the header), so that only the structural change is tested.
pub fn fix_checksums(b: &mut [u8]) {
    if b.len() < HEADER_LEN {
        return;
    }
    let dims: [usize; 3] = [12, 16, 20].map(|o| u32_at(b, o).unwrap_or(0) as usize);
    if dims.iter().all(|&d| (1..=4096).contains(&d)) {
        let n = dims[0] + dims[1] + dims[2];
        let tables_end = TABLES_START + ENTRY_LEN * n;
        if tables_end <= b.len() {
            // The file's layout: version 1 files (and unknown bits) as the cycle.
            let layout = match b.get(8..10) {
                Some([1, 0]) => Layout::CYCLE,
                _ => b
                    .get(53)
                    .and_then(|&l| Layout::from_bits(l))
                    .unwrap_or(Layout::CYCLE),
            };
            let nj_of = |e: usize| {
                let axis = if e < dims[0] {
                    Axis::X
                } else if e < dims[0] + dims[1] {
                    Axis::Y
                } else {
                    Axis::Z
                };
                layout.permuted_dims(axis, dims)[1]
            };
            for e in 0..n {
                let o = entry_at(e);
                let (Some(lo), Some(hi), Some(runs), Some(vox)) = (
                    u32_at(b, o),
                    u32_at(b, o + 4),
                    u32_at(b, o + 8),
                    u32_at(b, o + 12),
                ) else {
                    continue;
                };
                let off = lo as u64 | (hi as u64) << 32;
                let len = 8 * (nj_of(e) as u64 + 1) + runs as u64 + 4 * vox as u64;
                if off
                    .checked_add(len)
                    .is_some_and(|end| end <= b.len() as u64)
                {
                    let c = Crc32::of(&b[off as usize..(off + len) as usize]);
                    put_u32(b, o + 16, c);
                }
            }
            let t = Crc32::of(&b[HEADER_LEN..tables_end]);
            put_u32(b, 56, t);
        }
    }
    let h = Crc32::of(&b[..60]);
    put_u32(b, 60, h);
}
