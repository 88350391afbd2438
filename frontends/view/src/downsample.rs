//! The cheap level of detail: a copy of the volume at half resolution.
//!
//! Each voxel of the copy is the rounded mean of a 2×2×2 block (axes shorter than 2
//! voxels are kept as they are) and the spacing doubles, so the copy covers the same
//! physical extent. Along an axis of odd length the last block repeats the last voxel.
//! The copy has ~1/8 of the voxels, so it classifies, encodes and composites about
//! eight times faster; the renderer maps it to the same place on screen as the full
//! volume (see [`Half::offset_mm`]).

use shearwarp_file::volume::{RawVolume, Voxels};

/// A half-resolution copy and where it sits relative to the original.
pub struct Half {
    /// The copy.
    pub volume: RawVolume,
    /// Downsampling factor per axis (1 or 2).
    pub factor: [usize; 3],
    /// Object-space offset (mm) to add to a point given in the original volume's
    /// centred coordinates to get the same point in the copy's centred coordinates.
    /// Non-zero only along axes of odd length, where the copy's centre is half an
    /// original voxel off the original's.
    pub offset_mm: [f64; 3],
}

/// Builds the half-resolution copy of `raw`.
pub fn half(raw: &RawVolume) -> Half {
    let n = raw.dims;
    let factor = n.map(|d| if d >= 2 { 2 } else { 1 });
    let m = [0, 1, 2].map(|a| n[a].div_ceil(factor[a]));
    let voxels = match &raw.voxels {
        Voxels::U8(d) => Voxels::U8(mean_blocks(d, n, m, factor, |s| s as u8)),
        Voxels::U16(d) => Voxels::U16(mean_blocks(d, n, m, factor, |s| s as u16)),
    };
    // Copy voxel I stands for original index positions f·I + (f−1)/2; in centred
    // coordinates the copy puts it at (I − (m−1)/2)·f·s, the original at
    // (f·I + (f−1)/2 − (n−1)/2)·s: the difference is (n − m·f)/2 · s.
    let offset_mm =
        [0, 1, 2].map(|a| (n[a] as f64 - (m[a] * factor[a]) as f64) * 0.5 * raw.spacing[a]);
    Half {
        volume: RawVolume {
            name: format!("{} (half resolution)", raw.name),
            dims: m,
            spacing: [0, 1, 2].map(|a| raw.spacing[a] * factor[a] as f64),
            voxels,
        },
        factor,
        offset_mm,
    }
}

fn mean_blocks<T: Copy + Into<u32>>(
    src: &[T],
    n: [usize; 3],
    m: [usize; 3],
    f: [usize; 3],
    cast: impl Fn(u32) -> T,
) -> Vec<T> {
    let mut out = Vec::with_capacity(m[0] * m[1] * m[2]);
    let idx = |x: usize, y: usize, z: usize| (z * n[1] + y) * n[0] + x;
    for z in 0..m[2] {
        for y in 0..m[1] {
            for x in 0..m[0] {
                let mut sum = 0u32;
                let mut count = 0u32;
                for dz in 0..f[2] {
                    let zz = (z * f[2] + dz).min(n[2] - 1);
                    for dy in 0..f[1] {
                        let yy = (y * f[1] + dy).min(n[1] - 1);
                        for dx in 0..f[0] {
                            let xx = (x * f[0] + dx).min(n[0] - 1);
                            sum += src[idx(xx, yy, zz)].into();
                            count += 1;
                        }
                    }
                }
                out.push(cast((sum + count / 2) / count));
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn vol(dims: [usize; 3], voxels: Voxels) -> RawVolume {
        RawVolume {
            name: "t".into(),
            dims,
            spacing: [1.0, 2.0, 0.5],
            voxels,
        }
    }

    #[test]
    fn means_of_blocks_and_geometry() {
        // 3×2×1: x odd (last block repeats), y even, z of length 1 kept.
        let v = vol([3, 2, 1], Voxels::U8(vec![0, 10, 100, 2, 12, 200]));
        let h = half(&v);
        assert_eq!(h.volume.dims, [2, 1, 1]);
        assert_eq!(h.factor, [2, 2, 1]);
        assert_eq!(h.volume.spacing, [2.0, 4.0, 0.5]);
        // (0+10+2+12)/4 = 6; (100+100+200+200)/4 = 150.
        assert_eq!(h.volume.voxels, Voxels::U8(vec![6, 150]));
        assert_eq!(h.offset_mm, [-0.5, 0.0, 0.0]);

        let v = vol(
            [2, 2, 2],
            Voxels::U16(vec![1000, 1001, 1000, 1001, 0, 0, 0, 1]),
        );
        let h = half(&v);
        assert_eq!(h.volume.voxels, Voxels::U16(vec![500]));
        assert_eq!(h.offset_mm, [0.0; 3]);
    }

    #[test]
    fn offset_puts_voxel_centres_where_they_were() {
        // Centre of copy voxel I in original centred coordinates, shifted by the
        // offset, equals its position in the copy's own centred coordinates.
        for n in [5usize, 6, 181, 217] {
            let v = vol([n, 1, 1], Voxels::U8(vec![0; n]));
            let h = half(&v);
            let m = h.volume.dims[0];
            for i in [0, m / 2, m - 1] {
                let orig = (2.0 * i as f64 + 0.5 - (n as f64 - 1.0) / 2.0) * 1.0;
                let copy = (i as f64 - (m as f64 - 1.0) / 2.0) * 2.0;
                assert!((orig + h.offset_mm[0] - copy).abs() < 1e-12, "{n} {i}");
            }
        }
    }
}
