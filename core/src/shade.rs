//! Shading lookup table (Lacroute 1995, §2.2.3 and VolPack's shading tables).
//!
//! Every voxel carries an encoded normal; per frame we evaluate the lighting model once
//! per normal code instead of once per voxel. For each code the table holds a diffuse
//! factor `D` (ambient plus Σ diffuse·|n·L|) and a specular term `S` (Σ ks·|n·H|^shininess),
//! both RGB in Q15, and a voxel of transfer-function colour `C` is shaded as
//! `min(1, C·D + S)`. Lighting is two-sided (|n·L|), because the sign of a gradient says
//! which side is denser, not which side faces the viewer.

use crate::error::Error;
use crate::fixed::{self, ONE};
use crate::normal;
use heapless::Vec;

/// Most directional lights a frame may use.
pub const MAX_LIGHTS: usize = 4;

/// A directional light in camera space (x right, y up, z toward the viewer).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Light {
    /// Direction toward the light (need not be normalised).
    pub direction: [f64; 3],
    /// RGB intensity, each in `[0, 1]`.
    pub color: [f64; 3],
}

/// Phong/Blinn material and lights.
#[derive(Clone, Debug, PartialEq)]
pub struct Lighting {
    /// Ambient coefficient.
    pub ka: f64,
    /// Diffuse coefficient.
    pub kd: f64,
    /// Specular coefficient.
    pub ks: f64,
    /// Specular exponent.
    pub shininess: f64,
    /// Up to [`MAX_LIGHTS`] directional lights.
    pub lights: Vec<Light, MAX_LIGHTS>,
}

impl Default for Lighting {
    fn default() -> Self {
        let mut lights = Vec::new();
        // Capacity is MAX_LIGHTS >= 1, so this push cannot fail.
        let _ = lights.push(Light {
            direction: [0.5, 0.5, 1.0],
            color: [1.0; 3],
        });
        Lighting {
            ka: 0.2,
            kd: 0.7,
            ks: 0.3,
            shininess: 20.0,
            lights,
        }
    }
}

impl Lighting {
    /// Checks coefficients and light directions.
    pub fn validate(&self) -> Result<(), Error> {
        let ok = |x: f64| x.is_finite() && (0.0..=16.0).contains(&x);
        if !(ok(self.ka) && ok(self.kd) && ok(self.ks)) {
            return Err(Error::BadParameter {
                reason: "ka, kd and ks must be finite and in 0..16",
            });
        }
        if !(self.shininess.is_finite() && (0.0..=10000.0).contains(&self.shininess)) {
            return Err(Error::BadParameter {
                reason: "shininess must be finite and in 0..10000",
            });
        }
        for l in &self.lights {
            let n = norm(l.direction);
            if !(n.is_finite() && n > 1e-12) {
                return Err(Error::BadParameter {
                    reason: "a light direction is zero or not finite",
                });
            }
            if l.color
                .iter()
                .any(|c| !(c.is_finite() && (0.0..=1.0).contains(c)))
            {
                return Err(Error::BadParameter {
                    reason: "a light colour is outside 0..1",
                });
            }
        }
        Ok(())
    }
}

fn norm(v: [f64; 3]) -> f64 {
    libm::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Diffuse and specular factors per normal code, Q15 RGB. The diffuse factor can exceed
/// one (bright lights), so it is stored as `u32`-ranged `u16` with a cap of 2.0 (Q15
/// 65535); the product with a colour is clamped at composite time.
#[derive(Clone, Debug)]
pub struct ShadeTable {
    /// `D` per code.
    pub diffuse: [[u16; 3]; normal::CODES],
    /// `S` per code.
    pub specular: [[u16; 3]; normal::CODES],
}

impl ShadeTable {
    /// A table that leaves colours unchanged (`D = 1`, `S = 0`): shading off.
    pub const UNSHADED: ShadeTable = ShadeTable {
        diffuse: [[ONE as u16; 3]; normal::CODES],
        specular: [[0; 3]; normal::CODES],
    };

    /// Fills the table for `lighting` with object-to-camera rotation `rot` (row-major,
    /// applied to object-space normals measured in physical units).
    pub fn fill(&mut self, lighting: &Lighting, rot: &[[f64; 3]; 3]) -> Result<(), Error> {
        lighting.validate()?;
        let q = |x: f64| -> u16 { (x.clamp(0.0, 65535.0 / ONE as f64) * ONE as f64 + 0.5) as u16 };
        let mut lights: Vec<([f64; 3], [f64; 3], [f64; 3]), MAX_LIGHTS> = Vec::new();
        for l in &lighting.lights {
            let n = norm(l.direction);
            let d = l.direction.map(|c| c / n);
            let h = [d[0], d[1], d[2] + 1.0];
            let hn = norm(h);
            // Light exactly behind the object: the half vector is undefined; any
            // perpendicular direction gives |n·h| symmetric results, so use +x.
            let h = if hn < 1e-12 {
                [1.0, 0.0, 0.0]
            } else {
                h.map(|c| c / hn)
            };
            let _ = lights.push((d, h, l.color));
        }
        for code in 0..normal::CODES {
            let mut dsum = [lighting.ka; 3];
            let mut ssum = [0.0; 3];
            match normal::decode(code as u16) {
                Some(g) => {
                    // Normal = −gradient, rotated into camera space.
                    let n = [-dot(rot[0], g), -dot(rot[1], g), -dot(rot[2], g)];
                    for (d, h, c) in &lights {
                        let diff = lighting.kd * libm::fabs(dot(n, *d));
                        let spec = if lighting.ks > 0.0 {
                            lighting.ks * libm::pow(libm::fabs(dot(n, *h)), lighting.shininess)
                        } else {
                            0.0
                        };
                        for ch in 0..3 {
                            dsum[ch] += diff * c[ch];
                            ssum[ch] += spec * c[ch];
                        }
                    }
                }
                None => {
                    for (_, _, c) in &lights {
                        for ch in 0..3 {
                            dsum[ch] += lighting.kd * c[ch];
                        }
                    }
                }
            }
            self.diffuse[code] = dsum.map(q);
            self.specular[code] = ssum.map(|s| fixed::from_f64(s) as u16);
        }
        Ok(())
    }

    /// Shades a Q15 colour with the entry for `code`: `min(1, c·D + S)` per channel.
    #[inline(always)]
    pub fn shade(&self, code: u16, c: [u16; 3]) -> [u32; 3] {
        let i = (code as usize).min(normal::CODES - 1);
        let d = self.diffuse[i];
        let s = self.specular[i];
        let mut out = [0u32; 3];
        for ch in 0..3 {
            out[ch] = (fixed::mul(c[ch] as u32, d[ch] as u32) + s[ch] as u32).min(ONE);
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const ID: [[f64; 3]; 3] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

    #[test]
    fn head_on_light_gives_full_diffuse_and_specular_on_a_facing_normal() {
        let mut lights = Vec::new();
        lights
            .push(Light {
                direction: [0.0, 0.0, 1.0],
                color: [1.0; 3],
            })
            .unwrap();
        let l = Lighting {
            ka: 0.1,
            kd: 0.6,
            ks: 0.3,
            shininess: 10.0,
            lights,
        };
        let mut t = ShadeTable::UNSHADED.clone();
        t.fill(&l, &ID).unwrap();
        // Gradient toward −z means a normal toward +z (the viewer).
        let code = normal::encode(0, 0, -1000);
        let n = normal::decode(code).unwrap();
        let c = [ONE as u16; 3];
        let out = t.shade(code, c);
        let expect = 0.1 + 0.6 * n[2].abs() + 0.3 * n[2].abs().powf(10.0);
        assert!((out[0] as f64 / ONE as f64 - expect.min(1.0)).abs() < 1e-3);
        // Edge-on normal: only ambient.
        let side = normal::encode(1000, 0, 0);
        let o = t.shade(side, [ONE as u16 / 2; 3]);
        let ns = normal::decode(side).unwrap();
        let e = 0.5 * (0.1 + 0.6 * ns[2].abs()) + 0.3 * ns[2].abs().powf(10.0);
        assert!((o[1] as f64 / ONE as f64 - e).abs() < 2e-3, "{o:?} {e}");
        // Zero gradient: ambient + diffuse, no specular.
        let z = t.shade(normal::ZERO_GRADIENT, [ONE as u16; 3]);
        assert!((z[2] as f64 / ONE as f64 - 0.7).abs() < 1e-3);
    }

    #[test]
    fn bad_lighting_is_rejected() {
        let mut l = Lighting::default();
        l.lights[0].direction = [0.0; 3];
        let mut t = ShadeTable::UNSHADED.clone();
        assert!(t.fill(&l, &ID).is_err());
        let l = Lighting {
            ka: f64::NAN,
            ..Lighting::default()
        };
        assert!(t.fill(&l, &ID).is_err());
    }

    #[test]
    fn unshaded_table_is_identity() {
        let t = ShadeTable::UNSHADED;
        for c in [0u16, 1, 12345, ONE as u16] {
            assert_eq!(t.shade(17, [c; 3]), [c as u32; 3]);
        }
    }
}
