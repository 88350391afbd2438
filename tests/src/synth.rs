//! Generated u8 test volumes (x fastest: index = i + nx*(j + ny*k)).

/// Calls `f(i, j, k)` for every voxel in memory order.
fn generate(dims: [usize; 3], mut f: impl FnMut(usize, usize, usize) -> u8) -> Vec<u8> {
    let mut out = Vec::with_capacity(dims[0] * dims[1] * dims[2]);
    for k in 0..dims[2] {
        for j in 0..dims[1] {
            for i in 0..dims[0] {
                out.push(f(i, j, k));
            }
        }
    }
    out
}

/// Normalised coordinate of index `i` along an axis of `n` samples, 0..1.
fn unit(i: usize, n: usize) -> f64 {
    if n > 1 {
        i as f64 / (n - 1) as f64
    } else {
        0.5
    }
}

/// Spheres as (centre in 0..1 units, radius as a fraction of n, value).
const SPHERES: [([f64; 3], f64, f64); 4] = [
    ([0.28, 0.30, 0.30], 0.18, 240.0),
    ([0.70, 0.30, 0.68], 0.22, 160.0),
    ([0.30, 0.72, 0.70], 0.15, 80.0),
    ([0.70, 0.70, 0.30], 0.12, 200.0),
];

/// n³ volume with four solid spheres in different octants. Edges ramp
/// linearly over 1.5 voxels so gradients (and normals) are well defined.
pub fn spheres(n: usize) -> Vec<u8> {
    const RAMP: f64 = 1.5;
    let scale = n.saturating_sub(1) as f64;
    generate([n; 3], |i, j, k| {
        let p = [i as f64, j as f64, k as f64];
        let mut v: f64 = 0.0;
        for (c, r, val) in SPHERES {
            let d = (0..3)
                .map(|a| (p[a] - c[a] * scale).powi(2))
                .sum::<f64>()
                .sqrt();
            let cover = ((r * n as f64 - d) / RAMP + 0.5).clamp(0.0, 1.0);
            v = v.max(val * cover);
        }
        v.round() as u8
    })
}

/// Marschner–Lobb signal (f_M = 6, α = 0.25) at a point of [−1,1]³, in 0..1.
pub fn marschner_lobb_value(x: f64, y: f64, z: f64) -> f64 {
    use std::f64::consts::PI;
    const FM: f64 = 6.0;
    const ALPHA: f64 = 0.25;
    let r = (x * x + y * y).sqrt();
    let rho_r = (2.0 * PI * FM * (PI * r / 2.0).cos()).cos();
    (1.0 - (PI * z / 2.0).sin() + ALPHA * (1.0 + rho_r)) / (2.0 * (1.0 + ALPHA))
}

/// Marschner & Lobb (1994) test signal sampled at n³ points spanning [−1,1]³.
/// It is band-limited near Nyquist, so it exposes interpolation/resampling error.
pub fn marschner_lobb(n: usize) -> Vec<u8> {
    generate([n; 3], |i, j, k| {
        let c = |i| 2.0 * unit(i, n) - 1.0;
        (marschner_lobb_value(c(i), c(j), c(k)) * 255.0).round() as u8
    })
}

/// Solid box of value 200 inset by 20% on each side; meant for anisotropic
/// spacing, where a wrong spacing shows up as a wrong box aspect ratio.
pub fn ramp_box(nx: usize, ny: usize, nz: usize) -> Vec<u8> {
    let inside = |i: usize, n: usize| {
        let u = unit(i, n);
        (0.2 - 1e-9..=0.8 + 1e-9).contains(&u)
    };
    generate([nx, ny, nz], |i, j, k| {
        if inside(i, nx) && inside(j, ny) && inside(k, nz) {
            200
        } else {
            0
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(v: &[u8], d: [usize; 3], i: usize, j: usize, k: usize) -> u8 {
        v[i + d[0] * (j + d[1] * k)]
    }

    #[test]
    fn marschner_lobb_known_points() {
        assert!((marschner_lobb_value(0.0, 0.0, 0.0) - 0.6).abs() < 1e-12);
        assert!((marschner_lobb_value(0.0, 0.0, 1.0) - 0.2).abs() < 1e-12);
        assert!((marschner_lobb_value(0.0, 0.0, -1.0) - 1.0).abs() < 1e-12);
        // r = 1: cos(π/2) = 0, so ρ_r = 1 as at r = 0.
        assert!((marschner_lobb_value(1.0, 0.0, 0.0) - 0.6).abs() < 1e-12);
        let n = 41;
        let v = marschner_lobb(n);
        assert_eq!(v.len(), n * n * n);
        let d = [n; 3];
        assert_eq!(at(&v, d, 20, 20, 20), 153);
        assert_eq!(at(&v, d, 20, 20, 40), 51);
        assert_eq!(at(&v, d, 20, 20, 0), 255);
        // z = −0.5 at the centre axis: (1 + sin(π/4) + 0.5) / 2.5.
        let expect = ((1.5 + (std::f64::consts::PI / 4.0).sin()) / 2.5 * 255.0).round() as u8;
        assert_eq!(at(&v, d, 20, 20, 10), expect);
    }

    #[test]
    fn spheres_layout() {
        let n = 64;
        let v = spheres(n);
        assert_eq!(v.len(), n * n * n);
        let d = [n; 3];
        assert_eq!(at(&v, d, 0, 0, 0), 0);
        assert_eq!(at(&v, d, n - 1, n - 1, n - 1), 0);
        for (c, _, val) in SPHERES {
            let p = c.map(|x| (x * (n - 1) as f64).round() as usize);
            assert_eq!(f64::from(at(&v, d, p[0], p[1], p[2])), val);
        }
        // The edge ramp produces intermediate values, not just plateaus.
        assert!(v.iter().any(|&x| x > 0 && x < 80));
        // Spheres stay away from the volume border.
        for k in [0, n - 1] {
            for j in 0..n {
                for i in 0..n {
                    assert_eq!(at(&v, d, i, j, k), 0);
                }
            }
        }
    }

    #[test]
    fn ramp_box_extent() {
        let d = [21, 11, 6];
        let v = ramp_box(d[0], d[1], d[2]);
        assert_eq!(v.len(), 21 * 11 * 6);
        assert_eq!(at(&v, d, 10, 5, 2), 200);
        assert_eq!(at(&v, d, 0, 5, 2), 0);
        // Along x, u = i/20 in [0.2, 0.8] gives i = 4..=16.
        let row: Vec<u8> = (0..21).map(|i| at(&v, d, i, 5, 2)).collect();
        assert_eq!(row.iter().filter(|&&x| x == 200).count(), 13);
        assert_eq!(row[3], 0);
        assert_eq!(row[4], 200);
        assert_eq!(row[16], 200);
        assert_eq!(row[17], 0);
        assert!(v.iter().all(|&x| x == 0 || x == 200));
    }
}
