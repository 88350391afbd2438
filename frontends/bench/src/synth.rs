//! The synthetic benchmark volume: nested spheres, the same shape at every resolution.

/// Components as (inner radius, outer radius, value), radii as fractions of half the
/// side; an inner radius of 0 makes a solid ball.
const LAYERS: [(f64, f64, f64); 3] = [(0.0, 0.25, 240.0), (0.45, 0.60, 160.0), (0.75, 0.90, 70.0)];

/// Width in voxels over which an edge ramps from 0 to the full value, so that gradients
/// and normals are well defined.
const RAMP: f64 = 1.5;

/// An n³ u8 volume (x fastest): a solid core (240) inside a shell (160) inside a thinner,
/// fainter outer shell (70), centred, on a zero background.
pub fn nested_spheres(n: usize) -> Vec<u8> {
    let c = (n as f64 - 1.0) / 2.0;
    let half = n as f64 / 2.0;
    let cover = |d: f64, inner: f64, outer: f64| -> f64 {
        let out = ((outer * half - d) / RAMP + 0.5).clamp(0.0, 1.0);
        if inner == 0.0 {
            out
        } else {
            out.min(((d - inner * half) / RAMP + 0.5).clamp(0.0, 1.0))
        }
    };
    let mut v = Vec::with_capacity(n * n * n);
    for k in 0..n {
        let dz = k as f64 - c;
        for j in 0..n {
            let dy = j as f64 - c;
            for i in 0..n {
                let dx = i as f64 - c;
                let d = (dx * dx + dy * dy + dz * dz).sqrt();
                let val = LAYERS
                    .iter()
                    .map(|&(ri, ro, val)| val * cover(d, ri, ro))
                    .fold(0.0, f64::max);
                v.push(val.round() as u8);
            }
        }
    }
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layers_at_known_radii() {
        let n = 64;
        let v = nested_spheres(n);
        assert_eq!(v.len(), n * n * n);
        let at = |i: usize, j: usize, k: usize| v[i + n * (j + n * k)];
        // Centre voxel (31.5 is the exact centre; 32 is half a voxel off).
        assert_eq!(at(32, 32, 32), 240);
        // Middle shell at radius ~0.525·32 = 16.8 voxels.
        assert_eq!(at(32 + 17, 32, 32), 160);
        // Outer shell at radius ~0.825·32 = 26.4 voxels.
        assert_eq!(at(32, 32 + 26, 32), 70);
        // Between the core and the middle shell, and in the corners: empty.
        assert_eq!(at(32 + 11, 32, 32), 0);
        assert_eq!(at(0, 0, 0), 0);
        // Symmetric under mirroring each axis.
        for (i, j, k) in [(5, 20, 40), (17, 33, 2), (50, 9, 31)] {
            assert_eq!(at(i, j, k), at(n - 1 - i, j, k));
            assert_eq!(at(i, j, k), at(i, n - 1 - j, k));
            assert_eq!(at(i, j, k), at(i, j, n - 1 - k));
        }
    }
}
