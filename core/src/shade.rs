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

/// Entries of the specular power table (plus one).
const SPEC_STEPS: usize = 1024;

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

/// The shading of one normal code, Q15 RGB. The diffuse factor can exceed one (bright
/// lights), so it is stored with a cap of 2.0 (Q15 65535); the product with a colour is
/// clamped at composite time.
///
/// Each half is padded to four lanes (the fourth is zero and never used): an entry is
/// one aligned 16-byte load, and the x86 compositors shade a voxel's channels as one
/// four-lane vector ([`crate::classify::ColorLanes`] is padded the same way).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(C, align(16))]
pub struct ShadeEntry {
    /// `D`: ambient plus diffuse, RGB and padding.
    pub diffuse: [u16; 4],
    /// `S`: specular, RGB and padding.
    pub specular: [u16; 4],
}

/// Diffuse and specular factors per normal code. Both halves of a code sit side by side
/// (16 bytes, one aligned load), so shading a voxel reads one place of the 128 KiB table
/// instead of two: the table outgrows a first-level cache, and a lazily shaded voxel's
/// normal is close to random, so each read is usually a miss.
#[derive(Clone, Debug)]
pub struct ShadeTable {
    /// The entry per code.
    entries: [ShadeEntry; normal::CODES],
    /// The object-space lights, ambient term and material the entries were filled for
    /// (`None`: the unshaded table, or entries changed by hand): a fill for the same
    /// ones has nothing to do. A still view redrawn (a resized or zoomed window)
    /// reuses the table, and a frontend may fill it ahead with a faster build
    /// ([`ShadeTable::fill_x86_v3`]) before the core's frame setup asks for it.
    filled: Option<FillKey>,
    /// The specular power table of the last [`ShadeTable::fill`] and the (ks, shininess)
    /// it was made for: it depends on the material alone, so a turning view reuses it
    /// instead of evaluating 1025 `pow`s per frame (on brainsmall they were about a
    /// quarter of the table's fill in `perf`).
    spec: SpecTable,
}

/// `ks·x^shininess` for `x = i/1024`, Q15, and the bits of the `(ks, shininess)` it
/// holds (`None`: not made yet).
#[derive(Clone, Debug)]
struct SpecTable {
    key: Option<(u64, u64)>,
    power: [u32; SPEC_STEPS + 1],
}

impl SpecTable {
    const EMPTY: SpecTable = SpecTable {
        key: None,
        power: [0; SPEC_STEPS + 1],
    };

    /// The table for `ks` and `shininess`, remade only when they changed.
    fn update(&mut self, ks: f64, shininess: f64) -> &[u32; SPEC_STEPS + 1] {
        let key = (ks.to_bits(), shininess.to_bits());
        if self.key != Some(key) {
            self.power = [0; SPEC_STEPS + 1];
            if ks > 0.0 {
                for (i, out) in self.power.iter_mut().enumerate() {
                    let x = i as f64 / SPEC_STEPS as f64;
                    *out = q15(ks * libm::pow(x, shininess)).min(1 << 20);
                }
            }
            self.key = Some(key);
        }
        &self.power
    }
}

/// A non-negative float in Q15, rounded.
fn q15(x: f64) -> u32 {
    (x.max(0.0) * ONE as f64 + 0.5) as u32
}

impl ShadeTable {
    /// A table that leaves colours unchanged (`D = 1`, `S = 0`): shading off.
    pub const UNSHADED: ShadeTable = ShadeTable {
        entries: [ShadeEntry {
            diffuse: [ONE as u16, ONE as u16, ONE as u16, 0],
            specular: [0; 4],
        }; normal::CODES],
        spec: SpecTable::EMPTY,
        filled: None,
    };

    /// Every entry, by code.
    pub fn entries(&self) -> &[ShadeEntry; normal::CODES] {
        &self.entries
    }

    /// Every entry, to change by hand (the next [`ShadeTable::fill`] fills it anew).
    pub fn entries_mut(&mut self) -> &mut [ShadeEntry; normal::CODES] {
        self.filled = None;
        &mut self.entries
    }

    /// The entry for `code` (codes past the table read its last entry).
    #[inline(always)]
    pub fn entry(&self, code: u16) -> ShadeEntry {
        *self.entry_ref(code)
    }

    /// Fills the table for `lighting` with object-to-camera rotation `rot` (row-major,
    /// applied to object-space normals measured in physical units).
    ///
    /// Floats are used once per light (to move it into object space) and to tabulate the
    /// specular power; the 8193 entries are then integer arithmetic on the compile-time
    /// normal table [`normal::UNIT`]. On a Cortex-M3 without FPU this keeps the per-frame
    /// setup to a few million instructions instead of a soft-float `pow` per code.
    ///
    /// A table already filled for the same lights in object space, ambient term and
    /// material is left as it is.
    pub fn fill(&mut self, lighting: &Lighting, rot: &[[f64; 3]; 3]) -> Result<(), Error> {
        self.fill_inline(lighting, rot)
    }

    /// [`ShadeTable::fill`] compiled for x86-64-v3 (AVX2 and the rest of the list
    /// below): the same integer code, so the same entries, but the compiler computes
    /// the dot products of eight codes at a time (baseline x86-64 has no 32-bit vector
    /// multiply): 28 → 13 µs a fill here. A frontend calls it before the frame's setup,
    /// whose own fill then finds the table filled for its lights.
    ///
    /// # Safety
    ///
    /// The CPU must have every feature listed; check at run time first (the file
    /// frontend's `isa` module does). `target_feature` functions are safe to define
    /// but a caller must know the CPU has the features.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,bmi1,bmi2,fma,lzcnt,popcnt")]
    pub fn fill_x86_v3(&mut self, lighting: &Lighting, rot: &[[f64; 3]; 3]) -> Result<(), Error> {
        self.fill_inline(lighting, rot)
    }

    /// [`ShadeTable::fill`] compiled for x86-64-v4 (AVX-512 on top of
    /// [`ShadeTable::fill_x86_v3`]'s list): the same integer code, sixteen codes' dot
    /// products a step. On a Zen 4, which executes a 512-bit operation as two 256-bit
    /// halves, a fill took 8.3–8.5 µs at the median against 9.3–9.4 µs for the v3 build
    /// (2 000 fills each, in alternating blocks of ten, four runs): a microsecond off the
    /// frame's serial setup, where the calling thread fills its table, and off the start
    /// of every other compositing thread's first band, where it fills its own.
    ///
    /// # Safety
    ///
    /// As for [`ShadeTable::fill_x86_v3`], with the AVX-512 features listed too.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(
        enable = "avx2,bmi1,bmi2,fma,lzcnt,popcnt,avx512f,avx512bw,avx512vl,avx512dq,avx512cd"
    )]
    pub fn fill_x86_v4(&mut self, lighting: &Lighting, rot: &[[f64; 3]; 3]) -> Result<(), Error> {
        self.fill_inline(lighting, rot)
    }

    /// The body of the fills, inlined into each so that its loops compile for that
    /// fill's instruction set.
    #[inline(always)]
    fn fill_inline(&mut self, lighting: &Lighting, rot: &[[f64; 3]; 3]) -> Result<(), Error> {
        lighting.validate()?;
        let lights = lights_of(lighting, rot);
        let ka = q15(lighting.ka);
        let key = FillKey {
            lights,
            ka,
            material: (lighting.ks.to_bits(), lighting.shininess.to_bits()),
        };
        if self.filled.as_ref() == Some(&key) {
            return Ok(());
        }
        // ks·x^shininess for x = i/1024, Q15, interpolated linearly between entries.
        let spec = self.spec.update(lighting.ks, lighting.shininess);
        let lights = &key.lights;
        // White lights (the usual case) give three equal channels: compute one.
        let grey = lights
            .iter()
            .all(|l| l.kd.iter().all(|&k| k == l.kd[0]) && l.ks.iter().all(|&k| k == l.ks[0]));
        let e = &mut self.entries;
        match (grey, &lights[..]) {
            // One white light, the usual case: a slice of known length lets the
            // compiler drop the loop over lights (callgrind: 108 -> 76 instructions a
            // code).
            (true, [one]) => fill_entries::<1>(e, core::slice::from_ref(one), spec, ka),
            (true, all) => fill_entries::<1>(e, all, spec, ka),
            (false, all) => fill_entries::<3>(e, all, spec, ka),
        }
        self.filled = Some(key);
        Ok(())
    }

    /// The entry for `code`, by reference (codes past the table read its last entry).
    #[inline(always)]
    pub fn entry_ref(&self, code: u16) -> &ShadeEntry {
        &self.entries[(code as usize).min(normal::CODES - 1)]
    }

    /// `c·D + S` per channel for `code`, unclamped (up to about 3·ONE).
    #[inline(always)]
    pub fn shade_raw(&self, code: u16, c: [u16; 3]) -> [u32; 3] {
        let ShadeEntry {
            diffuse: d,
            specular: s,
        } = self.entry(code);
        [0, 1, 2].map(|ch| fixed::mul(c[ch] as u32, d[ch] as u32) + s[ch] as u32)
    }

    /// Shades a Q15 colour with the entry for `code`: `min(1, c·D + S)` per channel.
    #[inline(always)]
    pub fn shade(&self, code: u16, c: [u16; 3]) -> [u32; 3] {
        self.shade_raw(code, c).map(|x| x.min(ONE))
    }
}

/// What a table's entries depend on: the lights in object space, the ambient term (Q15)
/// and the specular material (the bits of ks and the shininess).
#[derive(Clone, Debug, PartialEq)]
struct FillKey {
    lights: Vec<L, MAX_LIGHTS>,
    ka: u32,
    material: (u64, u64),
}

/// A light and its half vector in object space, Q14, and its colour times kd and ks, Q15.
#[derive(Clone, Debug, PartialEq)]
struct L {
    d: [i16; 3],
    h: [i16; 3],
    kd: [u32; 3],
    ks: [u32; 3],
}

/// The lights of `lighting` in object space (the view rotation `rot` undone), Q14, with
/// their diffuse and specular colours in Q15.
fn lights_of(lighting: &Lighting, rot: &[[f64; 3]; 3]) -> Vec<L, MAX_LIGHTS> {
    const Q14: f64 = (1 << 14) as f64;
    let mut lights: Vec<L, MAX_LIGHTS> = Vec::new();
    for l in &lighting.lights {
        let n = norm(l.direction);
        let d = l.direction.map(|c| c / n);
        let h = [d[0], d[1], d[2] + 1.0];
        let hn = norm(h);
        // Light exactly behind the object: the half vector is undefined; any
        // perpendicular direction gives symmetric results, so use +x.
        let h = if hn < 1e-12 {
            [1.0, 0.0, 0.0]
        } else {
            h.map(|c| c / hn)
        };
        // n_cam · v = n_obj · (Rᵀ v).
        // A unit vector's components are within ±1, so ±16384 in Q14: i16, like the
        // normal table's.
        let to_obj = |v: [f64; 3]| -> [i16; 3] {
            core::array::from_fn(|a| {
                let c = rot[0][a] * v[0] + rot[1][a] * v[1] + rot[2][a] * v[2];
                libm::round(c * Q14).clamp(-Q14, Q14) as i16
            })
        };
        let _ = lights.push(L {
            d: to_obj(d),
            h: to_obj(h),
            kd: l.color.map(|c| q15(lighting.kd * c)),
            ks: l.color.map(q15),
        });
    }
    lights
}

/// Every entry of a shading table under `lights` ([`entry`] per code, `N` channels):
/// the direction codes from the normal table, then the zero-gradient code.
#[inline(always)]
fn fill_entries<const N: usize>(
    entries: &mut [ShadeEntry; normal::CODES],
    lights: &[L],
    spec: &[u32; SPEC_STEPS + 1],
    ka: u32,
) {
    let (units, zero) = entries.split_at_mut(normal::DIRECTIONS);
    // Code `DIRECTIONS − 1 − c` is the direction opposite code `c`, with exactly the
    // negated unit vector ([`normal::antipode`]), and an entry depends only on |n·l|
    // and |n·h| (lighting is two-sided): computing the first half and mirroring it
    // halves the fill (3 % of brainsmall's one-thread frame, and a serial step before
    // threads can start).
    let (front, back) = units.split_at_mut(normal::DIRECTIONS / 2);
    let units = &normal::UNIT[..normal::DIRECTIONS / 2];
    if BY_CHUNKS {
        fill_by_chunks::<N>(front, units, lights, spec, ka);
    } else {
        fill_by_codes::<N>(front, units, lights, spec, ka);
    }
    for (e, twin) in back.iter_mut().zip(front.iter().rev()) {
        *e = *twin;
    }
    for e in zero {
        *e = entry::<N>(None, lights, spec, ka);
    }
}

/// Whether [`fill_entries`] goes [`CHUNK`] codes a step ([`fill_by_chunks`]), where
/// that lets the compiler use vectors: x86-64, whose wider builds fill twice as fast
/// that way. Elsewhere it goes code by code ([`fill_by_codes`]): the Cortex-M3 firmware
/// took 1.7 % more instructions for the setup of a frame by chunks, and 3.2 KB more
/// flash.
const BY_CHUNKS: bool = cfg!(target_arch = "x86_64");

/// [`entry`] for each code with unit vector `units` into `out`, code by code.
#[inline(always)]
fn fill_by_codes<const N: usize>(
    out: &mut [ShadeEntry],
    units: &[[i16; 3]],
    lights: &[L],
    spec: &[u32; SPEC_STEPS + 1],
    ka: u32,
) {
    for (e, n) in out.iter_mut().zip(units) {
        *e = entry::<N>(Some(n), lights, spec, ka);
    }
}

/// [`entry`] for each code with unit vector `units` into `out`, [`CHUNK`] codes a
/// step ([`fill_chunk`]).
#[inline(always)]
fn fill_by_chunks<const N: usize>(
    out: &mut [ShadeEntry],
    units: &[[i16; 3]],
    lights: &[L],
    spec: &[u32; SPEC_STEPS + 1],
    ka: u32,
) {
    for (out, units) in out.chunks_mut(CHUNK).zip(units.chunks(CHUNK)) {
        fill_chunk::<N>(out, units, lights, spec, ka);
    }
}

/// Codes per step of [`fill_chunk`].
const CHUNK: usize = 64;

/// [`entry`] for up to [`CHUNK`] codes with unit vectors `units`, into `out`, one
/// step at a time over all of them: the dot products of every code with a light, then
/// the specular lookups, then the sums. The first step is a loop the compiler turns
/// into vector code where there are 32-bit vector multiplies, which it does not do for
/// a loop that also looks up the specular table: a fill of the x86-64-v3 build takes
/// 13 µs here against 27 µs as one loop per code (two-thirds of brainsmall's per-frame
/// setup). The baseline x86-64 build (27 µs) gains nothing from it, and the Cortex-M3
/// loses ([`BY_CHUNKS`]).
#[inline(always)]
fn fill_chunk<const N: usize>(
    out: &mut [ShadeEntry],
    units: &[[i16; 3]],
    lights: &[L],
    spec: &[u32; SPEC_STEPS + 1],
    ka: u32,
) {
    let mut d = [[ka; CHUNK]; N];
    let mut sp = [[0u32; CHUNK]; N];
    for l in lights {
        let (mut nd, mut nh) = ([0u32; CHUNK], [0u32; CHUNK]);
        for ((n, a), b) in units.iter().zip(&mut nd).zip(&mut nh) {
            *a = abs_dot(n, &l.d) << 1;
            *b = abs_dot(n, &l.h);
        }
        for (i, (&nd, &nh)) in nd.iter().zip(&nh).enumerate() {
            let s = specular_power(spec, nh);
            for c in 0..N {
                d[c][i] += light_term(l.kd[c], nd);
                sp[c][i] += light_term(l.ks[c], s);
            }
        }
    }
    for (i, e) in out.iter_mut().enumerate().take(CHUNK) {
        *e = pack::<N>(
            core::array::from_fn(|c| d[c.min(N - 1)][i]),
            core::array::from_fn(|c| sp[c.min(N - 1)][i]),
        );
    }
}

/// |n·v| in Q14 for unit vectors in Q14, clamped against rounding past 1.
#[inline(always)]
fn abs_dot(n: &[i16; 3], v: &[i16; 3]) -> u32 {
    let p = |a: usize| n[a] as i32 * v[a] as i32;
    let s = p(0) + p(1) + p(2);
    ((s.unsigned_abs() + (1 << 13)) >> 14).min(1 << 14)
}

/// `ks·x^shininess` for `x` = `nh` (Q14), interpolated linearly in the power table.
#[inline(always)]
fn specular_power(spec: &[u32; SPEC_STEPS + 1], nh: u32) -> u32 {
    let i = (nh >> 4) as usize;
    let f = nh & 15;
    let lo = spec[i.min(SPEC_STEPS)];
    let hi = spec[(i + 1).min(SPEC_STEPS)];
    (lo * (16 - f) + hi * f + 8) >> 4
}

/// A light's colour (Q15, up to 16) times a factor (Q15), capped at 32.
#[inline(always)]
fn light_term(k: u32, x: u32) -> u32 {
    // u64: kd and ks may reach 16 (validation), so the products can pass u32.
    ((k as u64 * x as u64 + (1 << 14)) >> 15).min(1 << 20) as u32
}

/// The entry from its diffuse and specular sums (`N` = 1: the first channel stands for
/// all three).
#[inline(always)]
fn pack<const N: usize>(d: [u32; 3], sp: [u32; 3]) -> ShadeEntry {
    let (d, sp) = if N == 1 {
        ([d[0]; 3], [sp[0]; 3])
    } else {
        (d, sp)
    };
    let cap = |x: u32| x.min(u16::MAX as u32) as u16;
    let sat = |x: u32| x.min(ONE) as u16;
    ShadeEntry {
        diffuse: [cap(d[0]), cap(d[1]), cap(d[2]), 0],
        specular: [sat(sp[0]), sat(sp[1]), sat(sp[2]), 0],
    }
}

/// The entry for unit normal `n` (`None`: the zero-gradient code, full diffuse light)
/// under `lights`, computing `N` channels (1: the lights are white and the channels
/// equal, so the first is copied; 3: all).
#[inline(always)]
fn entry<const N: usize>(
    n: Option<&[i16; 3]>,
    lights: &[L],
    spec: &[u32; SPEC_STEPS + 1],
    ka: u32,
) -> ShadeEntry {
    let mut d = [ka; 3];
    let mut sp = [0u32; 3];
    match n {
        Some(n) => {
            for l in lights {
                let nd = abs_dot(n, &l.d) << 1; // Q15
                let s = specular_power(spec, abs_dot(n, &l.h));
                for c in 0..N {
                    d[c] += light_term(l.kd[c], nd);
                    sp[c] += light_term(l.ks[c], s);
                }
            }
        }
        None => {
            for l in lights {
                for (dc, kd) in d.iter_mut().zip(l.kd).take(N) {
                    *dc += kd;
                }
            }
        }
    }
    pack::<N>(d, sp)
}

#[cfg(test)]
mod tests {
    use super::*;

    const ID: [[f64; 3]; 3] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

    #[test]
    fn the_one_channel_path_equals_the_three_channel_one_for_white_lights() {
        let spec: [u32; SPEC_STEPS + 1] = core::array::from_fn(|i| (i * i / 40) as u32);
        let light = |d: [i16; 3], kd: u32, ks: u32| L {
            d,
            h: [d[1], d[2], d[0]],
            kd: [kd; 3],
            ks: [ks; 3],
        };
        let lights = [
            light([16384, 0, 0], 22938, 32768),
            light([-9000, 9000, 9000], 400_000, 524_288),
        ];
        for code in 0..normal::CODES {
            let n = normal::UNIT.get(code);
            for k in 1..=2 {
                assert_eq!(
                    entry::<1>(n, &lights[..k], &spec, 6554),
                    entry::<3>(n, &lights[..k], &spec, 6554),
                    "code {code}, {k} lights"
                );
            }
        }
    }

    /// The mirrored fill equals every code's entry computed on its own, for one white
    /// light and for coloured lights; fails if an entry is mirrored from the wrong code
    /// or lighting stops being two-sided.
    #[test]
    fn every_entry_of_a_filled_table_is_its_codes_own() {
        extern crate std;
        use std::boxed::Box;
        let mut coloured = Lighting::default();
        coloured.lights[0].color = [1.0, 0.4, 0.2];
        coloured
            .lights
            .push(Light {
                direction: [-0.3, 0.8, 0.1],
                color: [0.1, 0.9, 0.5],
            })
            .unwrap();
        let rot = [[0.6, 0.0, 0.8], [0.0, 1.0, 0.0], [-0.8, 0.0, 0.6]];
        for lighting in [Lighting::default(), coloured] {
            let mut t = Box::new(ShadeTable::UNSHADED);
            t.fill(&lighting, &rot).unwrap();
            // The same lights and specular table the fill used, one code at a time.
            let lights = lights_of(&lighting, &rot);
            let spec = t.spec.power;
            let ka = q15(lighting.ka);
            for code in 0..normal::CODES {
                let own = entry::<3>(normal::UNIT.get(code), &lights, &spec, ka);
                assert_eq!(t.entries[code], own, "code {code}");
            }
        }
    }

    /// Both fill orders give every code's own entry, whichever the target uses: one,
    /// two and three lights, white and coloured, against [`entry`].
    #[test]
    fn filling_by_chunks_equals_filling_code_by_code() {
        let spec: [u32; SPEC_STEPS + 1] = core::array::from_fn(|i| (i * i / 40) as u32);
        let light = |d: [i16; 3], h: [i16; 3], kd: [u32; 3], ks: [u32; 3]| L { d, h, kd, ks };
        let lights = [
            light(
                [9459, 9459, 9459],
                [4000, 6000, 15000],
                [22938; 3],
                [32768; 3],
            ),
            light(
                [-9000, 9000, 9000],
                [0, 16384, 0],
                [400_000, 20, 7],
                [524_288, 0, 9],
            ),
            light([16384, 0, 0], [-11585, 0, 11585], [1, 2, 3], [30000, 1, 0]),
        ];
        let units = &normal::UNIT[..normal::DIRECTIONS / 2];
        let n = units.len();
        for k in 1..=3 {
            let zero = ShadeEntry {
                diffuse: [0; 4],
                specular: [0; 4],
            };
            let mut a = [zero; normal::DIRECTIONS / 2];
            let mut b = a;
            fill_by_chunks::<3>(&mut a, units, &lights[..k], &spec, 6554);
            fill_by_codes::<3>(&mut b, units, &lights[..k], &spec, 6554);
            assert!(a == b, "{k} lights, three channels");
            for (code, e) in a.iter().enumerate().take(n) {
                assert_eq!(
                    *e,
                    entry::<3>(Some(&units[code]), &lights[..k], &spec, 6554)
                );
            }
            fill_by_chunks::<1>(&mut a, units, &lights[..k], &spec, 6554);
            fill_by_codes::<1>(&mut b, units, &lights[..k], &spec, 6554);
            assert!(a == b, "{k} lights, one channel");
        }
    }

    #[test]
    fn the_one_light_loop_equals_the_general_one() {
        extern crate std;
        use std::boxed::Box;
        // A black second light adds nothing, but sends the fill through the loop over
        // any number of lights.
        let one = Lighting::default();
        let mut two = one.clone();
        two.lights
            .push(Light {
                direction: [-0.3, 0.8, 0.1],
                color: [0.0; 3],
            })
            .unwrap();
        let rot = [[0.6, 0.0, 0.8], [0.0, 1.0, 0.0], [-0.8, 0.0, 0.6]];
        let (mut a, mut b) = (
            Box::new(ShadeTable::UNSHADED),
            Box::new(ShadeTable::UNSHADED),
        );
        a.fill(&one, &rot).unwrap();
        b.fill(&two, &rot).unwrap();
        assert!(a.entries == b.entries);
    }

    /// A fill for the lights a table was filled for leaves it as it is, unless its
    /// entries were changed by hand since; a fill for a turned view fills it anew.
    #[test]
    fn a_table_is_filled_again_only_when_what_it_depends_on_changed() {
        extern crate std;
        use std::boxed::Box;
        let l = Lighting::default();
        let rot = [[0.6, 0.0, 0.8], [0.0, 1.0, 0.0], [-0.8, 0.0, 0.6]];
        let turned = [[0.8, 0.0, 0.6], [0.0, 1.0, 0.0], [-0.6, 0.0, 0.8]];
        let fresh = |rot: &[[f64; 3]; 3]| {
            let mut t = Box::new(ShadeTable::UNSHADED);
            t.fill(&l, rot).unwrap();
            t
        };
        let mut t = fresh(&rot);
        t.entries_mut()[100] = ShadeEntry {
            diffuse: [1, 2, 3, 0],
            specular: [4, 5, 6, 0],
        };
        t.fill(&l, &rot).unwrap();
        assert!(
            t.entries == fresh(&rot).entries,
            "a hand-changed entry was kept"
        );
        // The memo itself: filled for these lights, the table is not filled again.
        t.entries[100].specular[3] = 7;
        t.fill(&l, &rot).unwrap();
        assert_eq!(t.entries[100].specular[3], 7);
        t.fill(&l, &turned).unwrap();
        assert!(
            t.entries == fresh(&turned).entries,
            "not refilled for a turned view"
        );
        let dim = Lighting {
            ka: 0.1,
            ..l.clone()
        };
        t.fill(&dim, &turned).unwrap();
        assert_ne!(
            t.entries[normal::CODES - 1],
            fresh(&turned).entries[normal::CODES - 1]
        );
    }

    #[test]
    fn a_reused_table_equals_a_fresh_one_after_the_material_changes() {
        extern crate std;
        use std::boxed::Box;
        let mat = |ks: f64, shininess: f64| Lighting {
            ks,
            shininess,
            ..Lighting::default()
        };
        let rot = [[0.6, 0.0, 0.8], [0.0, 1.0, 0.0], [-0.8, 0.0, 0.6]];
        let mut reused = Box::new(ShadeTable::UNSHADED);
        for (ks, sh) in [
            (0.3, 20.0),
            (0.3, 7.5),
            (0.0, 7.5),
            (0.6, 20.0),
            (0.3, 20.0),
        ] {
            reused.fill(&mat(ks, sh), &rot).unwrap();
            let mut fresh = Box::new(ShadeTable::UNSHADED);
            fresh.fill(&mat(ks, sh), &rot).unwrap();
            assert!(reused.entries == fresh.entries, "ks {ks} shininess {sh}");
        }
    }

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
    fn coloured_lights_add_per_channel() {
        let mut lights = Vec::new();
        for (d, c) in [
            ([0.0, 0.0, 1.0], [1.0, 0.0, 0.0]),
            ([0.0, 0.0, 1.0], [0.0, 0.0, 0.5]),
        ] {
            lights
                .push(Light {
                    direction: d,
                    color: c,
                })
                .unwrap();
        }
        let l = Lighting {
            ka: 0.1,
            kd: 0.6,
            ks: 0.0,
            shininess: 1.0,
            lights,
        };
        let mut t = ShadeTable::UNSHADED.clone();
        t.fill(&l, &ID).unwrap();
        let code = normal::encode(0, 0, -1000);
        let nz = normal::decode(code).unwrap()[2].abs();
        let out = t
            .shade(code, [ONE as u16; 3])
            .map(|x| x as f64 / ONE as f64);
        let expect = [0.1 + 0.6 * nz, 0.1, 0.1 + 0.3 * nz];
        for c in 0..3 {
            assert!((out[c] - expect[c]).abs() < 2e-3, "{out:?} vs {expect:?}");
        }
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
