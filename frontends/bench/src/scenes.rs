//! The benchmark scenes: volumes, their transfer functions and lighting, and the
//! translation of one appearance into shearwarp's, VolPack's and the reference caster's
//! terms.

use crate::{den, synth};
use shearwarp_core::classify::OpacityTf;
use shearwarp_core::composite::Mode;
use shearwarp_core::shade::{Light, Lighting};
use shearwarp_file::scene::{self, Classification, Look};
use shearwarp_file::volume::{self, RawVolume, Voxels};
use shearwarp_tests::reference::{RefShading, RefTf, RefVolume};
use std::error::Error;
use std::path::{Path, PathBuf};

/// Where Debian's `libvolpack1-dev` installs VolPack's example MR head.
pub const BRAINSMALL_DEFAULT: &str = "/usr/share/doc/libvolpack1-dev/examples/brainsmall.den";

/// Where a scene's voxels come from.
#[derive(Clone, Debug)]
pub enum Source {
    /// A VolPack `.den` file (spacing taken as 1).
    Den(PathBuf),
    /// A volume of the shared data set, by sidecar path.
    Shared(PathBuf),
    /// [`synth::nested_spheres`] of this side.
    Spheres(usize),
}

/// Everything about how a volume looks, shared by all three renderers.
#[derive(Clone, Debug)]
pub struct Appearance {
    /// Opacity per unit of the smallest spacing over raw value.
    pub opacity: Vec<(f64, f64)>,
    /// Colour over raw value (also the colour index for u8 data).
    pub color: Vec<(f64, [u8; 3])>,
    /// Ambient, diffuse, specular coefficients and specular exponent.
    pub ka: f64,
    pub kd: f64,
    pub ks: f64,
    pub shininess: f64,
    /// Direction toward the light, camera space.
    pub light: [f64; 3],
    /// Voxels at or below this opacity are stored as transparent.
    pub min_opacity: f64,
    /// Early-ray-termination opacity.
    pub ert: f64,
}

/// The warm grey colour ramp of the `shearwarp` CLI over u8 data.
pub const COLOR: [(f64, [u8; 3]); 3] = [
    (0.0, [0x80, 0x50, 0x40]),
    (127.5, [0xe0, 0xb0, 0x90]),
    (255.0, [0xff, 0xff, 0xf0]),
];

impl Appearance {
    /// An opacity ramp from 0 at `lo` to `top` at `hi` (constant above), the CLI's colour
    /// ramp and default lighting (ka 0.2, kd 0.7, ks 0.3, shininess 20, light toward
    /// (0.5, 0.5, 1)), minimum opacity 0.02 and early ray termination at 0.95.
    pub fn ramp(lo: f64, hi: f64, top: f64) -> Self {
        let l = Lighting::default();
        let mut opacity = vec![(0.0, 0.0), (lo, 0.0), (hi, top)];
        if hi < 255.0 {
            opacity.push((255.0, top));
        }
        Appearance {
            opacity,
            color: COLOR.to_vec(),
            ka: l.ka,
            kd: l.kd,
            ks: l.ks,
            shininess: l.shininess,
            light: l.lights[0].direction,
            min_opacity: 0.02,
            ert: 0.95,
        }
    }

    /// shearwarp's classification.
    pub fn classification(&self) -> Classification {
        Classification {
            opacity: self.opacity.clone(),
            gradient: None,
            min_opacity: self.min_opacity,
            cut: scene::Cut::NONE,
        }
    }

    /// shearwarp's per-frame look.
    pub fn look(&self, range: (u16, u16)) -> Result<Look, Box<dyn Error>> {
        let mut lighting = Lighting {
            ka: self.ka,
            kd: self.kd,
            ks: self.ks,
            shininess: self.shininess,
            ..Lighting::default()
        };
        lighting.lights.truncate(1);
        let light = lighting.lights.first_mut().ok_or("no default light")?;
        *light = Light {
            direction: self.light,
            color: [1.0; 3],
        };
        Ok(Look {
            mode: Mode::Composite,
            color: scene::color_table(&self.color, range)?,
            lighting: Some(lighting),
            ert_threshold: self.ert,
            depth_cue: None,
            shadows: false,
        })
    }

    /// The opacity table as shearwarp quantises it (u8 per raw value), as floats for
    /// VolPack. VolPack stores `trunc(opacity·255)`, so byte `k` is passed as
    /// `(k + 0.5)/255` (and 255 as 1.0): VolPack then stores exactly shearwarp's bytes.
    pub fn opacity_table(&self) -> Result<[f32; 256], Box<dyn Error>> {
        let pts: Vec<(f64, [f64; 1])> = self.opacity.iter().map(|&(v, a)| (v, [a])).collect();
        let mut t = [0u8; 256];
        OpacityTf::new(&pts)?.build_table(&mut t);
        Ok(t.map(|a| {
            if a == 255 {
                1.0
            } else {
                ((f64::from(a) + 0.5) / 255.0) as f32
            }
        }))
    }

    /// VolPack's minimum voxel opacity equivalent to shearwarp's: shearwarp drops voxels
    /// whose u8 opacity is at most `floor(min_opacity·255)`, VolPack those whose (table)
    /// opacity is at most the threshold; with bytes passed as `(k + 0.5)/255`, a
    /// threshold of `(floor(min_opacity·255) + 1)/255`, half a step from both the last
    /// dropped and the first kept byte, drops the same voxels.
    pub fn volpack_min_opacity(&self) -> f64 {
        ((self.min_opacity * 255.0).floor() + 1.0) / 255.0
    }

    /// Colour breakpoints as VolPack materials: each breakpoint's colour (0..1) and, per
    /// raw value, the piecewise-linear weight of each breakpoint (two neighbours sum to 1).
    pub fn materials(&self) -> (Vec<[f32; 3]>, Vec<f32>) {
        let m = self.color.len();
        let colors = self
            .color
            .iter()
            .map(|(_, c)| c.map(|x| f32::from(x) / 255.0))
            .collect();
        let mut w = vec![0.0f32; 256 * m];
        for v in 0..256 {
            let x = v as f64;
            let row = &mut w[v * m..(v + 1) * m];
            if x <= self.color[0].0 {
                row[0] = 1.0;
            } else if x >= self.color[m - 1].0 {
                row[m - 1] = 1.0;
            } else {
                let s = self.color.windows(2).position(|p| x <= p[1].0).unwrap_or(0);
                let (x0, x1) = (self.color[s].0, self.color[s + 1].0);
                let t = (x - x0) / (x1 - x0);
                row[s] = (1.0 - t) as f32;
                row[s + 1] = t as f32;
            }
        }
        (colors, w)
    }

    /// The reference caster's transfer functions.
    pub fn ref_tf(&self) -> RefTf {
        RefTf {
            opacity: self.opacity.clone(),
            color: self
                .color
                .iter()
                .map(|&(v, c)| (v, c.map(|x| f64::from(x) / 255.0)))
                .collect(),
        }
    }

    /// The reference caster's shading.
    pub fn ref_shading(&self) -> RefShading {
        RefShading {
            ka: self.ka,
            kd: self.kd,
            ks: self.ks,
            shininess: self.shininess,
            lights: vec![self.light],
            light_colors: vec![[1.0; 3]],
        }
    }
}

/// One benchmark scene.
#[derive(Clone, Debug)]
pub struct Scene {
    /// Short name used in tables.
    pub name: String,
    pub source: Source,
    pub look: Appearance,
    /// The view compared against the reference: (rotate_x, rotate_y), degrees.
    pub psnr_view: (f64, f64),
}

/// An 8-bit volume ready for all renderers.
pub struct Loaded {
    pub raw: RawVolume,
}

impl Loaded {
    /// The voxels (every benchmark volume is u8).
    pub fn data(&self) -> &[u8] {
        match &self.raw.voxels {
            Voxels::U8(d) => d,
            Voxels::U16(_) => unreachable!("benchmark volumes are loaded as u8"),
        }
    }

    /// The reference caster's volume (f32 copy).
    pub fn ref_volume(&self) -> RefVolume {
        RefVolume::from_u8(self.raw.dims, self.raw.spacing, self.data())
    }
}

impl Scene {
    /// Loads (or generates) the voxels.
    pub fn load(&self) -> Result<Loaded, Box<dyn Error>> {
        let raw = match &self.source {
            Source::Den(p) => {
                let d = den::read(p).map_err(|e| format!("{}: {e}", p.display()))?;
                RawVolume {
                    name: self.name.clone(),
                    dims: d.dims,
                    spacing: [1.0; 3],
                    voxels: Voxels::U8(d.data),
                }
            }
            Source::Shared(p) => {
                let raw = volume::load_volume_with(p, volume::Prefer::U8)
                    .map_err(|e| format!("{}: {e}", p.display()))?;
                if !matches!(raw.voxels, Voxels::U8(_)) {
                    return Err(format!("{}: the benchmark needs u8 voxels", p.display()).into());
                }
                raw
            }
            Source::Spheres(n) => RawVolume {
                name: self.name.clone(),
                dims: [*n; 3],
                spacing: [1.0; 3],
                voxels: Voxels::U8(synth::nested_spheres(*n)),
            },
        };
        Ok(Loaded { raw })
    }
}

/// The sides of the nested-spheres scaling series the benchmark times by default.
pub const SCALING_SIDES: &str = "64,128,256,512";

/// The nested-spheres scene of side `n`.
pub fn spheres(n: usize) -> Scene {
    Scene {
        name: format!("spheres{n}"),
        source: Source::Spheres(n),
        look: Appearance::ramp(60.0, 255.0, 0.8),
        psnr_view: (25.0, 35.0),
    }
}

/// The volume `name` of the shared data set (its sidecar `name.json` in `data_dir`),
/// looking as `look`.
fn shared(data_dir: &Path, name: &str, look: Appearance) -> Scene {
    Scene {
        name: name.into(),
        source: Source::Shared(data_dir.join(format!("{name}.json"))),
        look,
        psnr_view: (25.0, 35.0),
    }
}

/// The four comparison scenes.
pub fn main_scenes(data_dir: &Path, den: &Path) -> Vec<Scene> {
    vec![
        Scene {
            name: "brainsmall".into(),
            source: Source::Den(den.to_path_buf()),
            look: Appearance::ramp(20.0, 70.0, 0.9),
            psnr_view: (25.0, 35.0),
        },
        shared(
            data_dir,
            "mr_head_colin27",
            Appearance::ramp(30.0, 90.0, 0.9),
        ),
        shared(
            data_dir,
            "mr_brain_colin27_hires",
            Appearance::ramp(100.0, 200.0, 0.8),
        ),
        spheres(256),
    ]
}

/// The volumes a profile-guided build (`frontends/bench/pgo.sh`) is trained on: none
/// of them is timed, so the profile is what any volume makes the renderer do, not what
/// the timed ones do. A thick-slab proton-density MR series (anisotropic, 20 slices),
/// and nested spheres of sides the scaling series does not use (one small enough for
/// the supersampled frames).
pub fn training_scenes(data_dir: &Path) -> Vec<Scene> {
    vec![
        shared(
            data_dir,
            "mr_pd_brain_series",
            Appearance::ramp(30.0, 90.0, 0.9),
        ),
        spheres(96),
        spheres(192),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn no_training_scene_is_timed() {
        let (data, den) = (Path::new("data"), Path::new("brainsmall.den"));
        let timed = main_scenes(data, den);
        let sides: Vec<usize> = SCALING_SIDES
            .split(',')
            .map(|s| s.parse().unwrap())
            .collect();
        let training = training_scenes(data);
        assert!(!training.is_empty());
        for t in &training {
            assert!(
                timed.iter().all(|s| s.name != t.name),
                "{} is timed",
                t.name
            );
            match &t.source {
                Source::Spheres(n) => assert!(!sides.contains(n), "spheres{n} is timed"),
                Source::Shared(p) => {
                    let same = |s: &Scene| matches!(&s.source, Source::Shared(q) if q == p);
                    assert!(!timed.iter().any(same), "{} is timed", p.display());
                }
                Source::Den(_) => panic!("{}: the only .den scene is timed", t.name),
            }
        }
    }

    #[test]
    fn material_weights_interpolate_the_colour_ramp() {
        let a = Appearance::ramp(10.0, 20.0, 0.5);
        let (colors, w) = a.materials();
        let m = colors.len();
        assert_eq!(m, 3);
        for v in 0..256 {
            let row = &w[v * m..(v + 1) * m];
            let sum: f32 = row.iter().sum();
            assert!((sum - 1.0).abs() < 1e-6, "value {v}: {row:?}");
            // The weighted colour equals the piecewise-linear colour ramp.
            for ch in 0..3 {
                let got: f32 = (0..m).map(|i| row[i] * colors[i][ch]).sum();
                let x = v as f64;
                let (c0, c1, t) = if x <= 127.5 {
                    (COLOR[0].1, COLOR[1].1, x / 127.5)
                } else {
                    (COLOR[1].1, COLOR[2].1, (x - 127.5) / 127.5)
                };
                let want =
                    (f64::from(c0[ch]) + t * (f64::from(c1[ch]) - f64::from(c0[ch]))) / 255.0;
                assert!((f64::from(got) - want).abs() < 1e-5, "value {v} ch {ch}");
            }
        }
    }

    #[test]
    fn opacity_table_and_threshold_agree_with_shearwarp() {
        let a = Appearance::ramp(10.0, 20.0, 0.5);
        let t = a.opacity_table().unwrap();
        // VolPack's quantisation, trunc(opacity·255) in double precision, gives back
        // shearwarp's bytes: 0 below the ramp, ~128 at its top.
        let byte = |x: f32| (f64::from(x) * 255.0) as u8;
        assert_eq!(byte(t[10]), 0);
        assert!((127..=128).contains(&byte(t[20])));
        assert_eq!(t[255], t[20]);
        let b = Appearance::ramp(1.0, 255.0, 1.0).opacity_table().unwrap();
        assert_eq!(byte(b[255]), 255);
        assert_eq!(b[255], 1.0);
        // 0.02·255 = 5.1: bytes 0..=5 are transparent in both renderers.
        let th = a.volpack_min_opacity();
        let t5 = Appearance::ramp(1.0, 255.0, 5.0 / 255.0)
            .opacity_table()
            .unwrap();
        let t6 = Appearance::ramp(1.0, 255.0, 6.0 / 255.0)
            .opacity_table()
            .unwrap();
        assert_eq!((byte(t5[255]), byte(t6[255])), (5, 6));
        assert!(f64::from(t5[255]) < th && f64::from(t6[255]) > th);
    }
}
