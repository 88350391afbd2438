//! Named transfer-function presets (`--preset NAME`, suggested by `shearwarp info`).
//!
//! CT presets are written in Hounsfield units and mapped to stored values through the
//! volume's value mapping ([`hu_mapping`]); a CT preset on a volume without one is
//! refused (exit code 2) rather than guessed. MR presets and `mip` are written over the
//! normalised data range ([`data_range`], the same range the viewer's presets use), so
//! they fit any data.

use crate::formats::VolumeMeta;
use crate::tffile::{TfSpec, Units, ValueScale};
use crate::volume::{RawVolume, Voxels};

/// One named preset.
#[derive(Clone, Copy, Debug)]
pub struct Preset {
    pub name: &'static str,
    pub description: &'static str,
    pub units: Units,
    pub mip: bool,
    pub shading: bool,
    pub opacity: &'static [(f64, f64)],
    pub color: &'static [(f64, [u8; 3])],
}

/// Warm grey colours of the file frontend's default, over the normalised range (the
/// viewer's presets use them too).
pub const WARM: &[(f64, [u8; 3])] = &[
    (0.0, [0x80, 0x50, 0x40]),
    (0.5, [0xe0, 0xb0, 0x90]),
    (1.0, [0xff, 0xff, 0xf0]),
];

/// Every preset, CT first.
pub const PRESETS: [Preset; 6] = [
    Preset {
        name: "ct-bone",
        description: "bone (HU 150..1500)",
        units: Units::Hu,
        mip: false,
        shading: true,
        opacity: &[(150.0, 0.0), (300.0, 0.3), (1500.0, 0.9)],
        color: &[
            (150.0, [0xa0, 0x60, 0x40]),
            (400.0, [0xf0, 0xe0, 0xc0]),
            (1500.0, [0xff, 0xff, 0xff]),
        ],
    },
    Preset {
        name: "ct-skin",
        description: "skin and soft tissue (HU −600..100)",
        units: Units::Hu,
        mip: false,
        shading: true,
        opacity: &[(-600.0, 0.0), (-400.0, 0.05), (-100.0, 0.15), (100.0, 0.3)],
        color: &[
            (-600.0, [0x80, 0x40, 0x30]),
            (-300.0, [0xc0, 0x80, 0x68]),
            (0.0, [0xf0, 0xc8, 0xa8]),
            (400.0, [0xff, 0xf8, 0xf0]),
        ],
    },
    Preset {
        name: "ct-angio",
        description: "contrast-filled vessels and bone (HU 100..600)",
        units: Units::Hu,
        mip: false,
        shading: true,
        opacity: &[(100.0, 0.0), (200.0, 0.2), (600.0, 0.6)],
        color: &[
            (100.0, [0x80, 0x10, 0x10]),
            (250.0, [0xe0, 0x40, 0x30]),
            (600.0, [0xff, 0xf0, 0xe0]),
        ],
    },
    Preset {
        name: "mr-default",
        description: "ramp over the upper 85 % of the data range (the CLI default)",
        units: Units::Normalized,
        mip: false,
        shading: true,
        opacity: &[(0.0, 0.0), (0.15, 0.0), (0.4, 0.1), (1.0, 0.8)],
        color: WARM,
    },
    Preset {
        name: "mr-brain",
        description: "semi-transparent tent over the middle intensities",
        units: Units::Normalized,
        mip: false,
        shading: true,
        opacity: &[(0.3, 0.0), (0.48, 0.25), (0.6, 0.12), (0.7, 0.04)],
        color: &[
            (0.0, [0x30, 0x10, 0x10]),
            (0.3, [0xb0, 0x60, 0x58]),
            (0.55, [0xf0, 0xc0, 0xb0]),
            (1.0, [0xff, 0xff, 0xff]),
        ],
    },
    Preset {
        name: "mip",
        description: "maximum intensity projection above 5 % of the range",
        units: Units::Normalized,
        mip: true,
        shading: false,
        opacity: &[(0.05, 0.0), (0.15, 1.0)],
        color: WARM,
    },
];

/// Preset names, for the command line.
pub const NAMES: [&str; 6] = [
    PRESETS[0].name,
    PRESETS[1].name,
    PRESETS[2].name,
    PRESETS[3].name,
    PRESETS[4].name,
    PRESETS[5].name,
];

/// The preset called `name`.
pub fn find(name: &str) -> Option<&'static Preset> {
    PRESETS.iter().find(|p| p.name == name)
}

impl Preset {
    /// The preset as a transfer-function file would hold it.
    pub fn spec(&self) -> TfSpec {
        TfSpec {
            units: self.units,
            mip: self.mip,
            shading: Some(self.shading),
            opacity: self.opacity.to_vec(),
            color: Some(self.color.to_vec()),
            gradient_opacity: None,
        }
    }
}

/// Fraction of voxels allowed above the top of a 16-bit normalised range.
pub const U16_TOP_FRACTION: f64 = 1e-4;

/// The stored value range normalised units span: `(0, 255)` for 8-bit data; for 16-bit
/// data the minimum and the value below which all but [`U16_TOP_FRACTION`] of the
/// voxels lie (the maximum if that would be the minimum), so a few extreme voxels
/// (dental enamel, metal) do not squash every ramp into the bottom of the range.
pub fn data_range(raw: &RawVolume) -> (u16, u16) {
    match &raw.voxels {
        Voxels::U8(_) => (0, 255),
        Voxels::U16(d) => u16_range(d),
    }
}

fn u16_range(d: &[u16]) -> (u16, u16) {
    let Some(&lo) = d.iter().min() else {
        return (0, 0);
    };
    let hi = d.iter().copied().max().unwrap_or(lo);
    let mut hist = vec![0u64; 65536];
    for &v in d {
        hist[v as usize] += 1;
    }
    let allowed = (d.len() as f64 * U16_TOP_FRACTION).floor() as u64;
    let mut above = 0u64;
    let mut top = hi;
    for v in (lo as usize..=hi as usize).rev() {
        if above + hist[v] > allowed {
            top = v as u16;
            break;
        }
        above += hist[v];
    }
    if top <= lo {
        (lo, hi)
    } else {
        (lo, top)
    }
}

/// `(slope, intercept)` with HU = stored · slope + intercept, if the values are known
/// to be Hounsfield units: the file says so (units `HU`, e.g. a sidecar `mapping`, or
/// DICOM/MetaImage modality CT), or the file values over the stored range `(min, max)`
/// look like CT (minimum ≤ −900, air; maximum ≥ 1000, bone), e.g. NIfTI with
/// `scl_inter = −1024`.
pub fn hu_mapping(meta: &VolumeMeta, stored: (u16, u16)) -> Option<(f64, f64)> {
    let says = meta.units.as_deref() == Some("HU") || meta.modality.as_deref() == Some("CT");
    let looks =
        meta.physical(stored.0 as f64) <= -900.0 && meta.physical(stored.1 as f64) >= 1000.0;
    (meta.slope > 0.0 && (says || looks)).then_some((meta.slope, meta.intercept))
}

/// Stored minimum and maximum.
pub fn stored_range(raw: &RawVolume) -> (u16, u16) {
    match &raw.voxels {
        Voxels::U8(d) => (
            d.iter().copied().min().unwrap_or(0) as u16,
            d.iter().copied().max().unwrap_or(0) as u16,
        ),
        Voxels::U16(d) => (
            d.iter().copied().min().unwrap_or(0),
            d.iter().copied().max().unwrap_or(0),
        ),
    }
}

/// What transfer functions of `raw` are resolved against.
pub fn value_scale(raw: &RawVolume, meta: &VolumeMeta) -> ValueScale {
    ValueScale {
        range: data_range(raw),
        hu: hu_mapping(meta, stored_range(raw)),
    }
}

/// Presets that suit a volume: the CT ones when its values are HU, else the MR ones;
/// `mip` always.
pub fn suggest(scale: &ValueScale) -> Vec<&'static Preset> {
    PRESETS
        .iter()
        .filter(|p| p.mip || (p.units == Units::Hu) == scale.hu.is_some())
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    fn ct_meta() -> VolumeMeta {
        let mut m = VolumeMeta::identity("dicom", "i16");
        m.intercept = -1024.0;
        m.modality = Some("CT".into());
        m.units = Some("HU".into());
        m
    }

    #[test]
    fn names_match_and_every_preset_resolves_increasing() {
        for (n, p) in NAMES.iter().zip(&PRESETS) {
            assert_eq!(*n, p.name);
            assert!(find(n).is_some());
            let scale = ValueScale {
                range: (0, 4000),
                hu: Some((1.0, -1024.0)),
            };
            let r = p.spec().resolve(&scale, Path::new("v")).unwrap();
            assert!(r.opacity.windows(2).all(|w| w[0].0 < w[1].0), "{n}");
            let c = r.color.unwrap();
            assert!(c.windows(2).all(|w| w[0].0 < w[1].0), "{n}");
        }
        assert!(find("ct-lung").is_none());
    }

    #[test]
    fn ct_presets_map_hounsfield_units_to_stored_values() {
        let scale = ValueScale {
            range: (0, 3000),
            hu: Some((1.0, -1024.0)),
        };
        let r = find("ct-bone")
            .unwrap()
            .spec()
            .resolve(&scale, Path::new("v"))
            .unwrap();
        assert_eq!(r.opacity[0], (1174.0, 0.0));
        // The shared CT head's u8 copy: u8 = floor((HU + 1024) / 12).
        let scale = ValueScale {
            range: (0, 255),
            hu: Some((12.0, -1018.5)),
        };
        let r = find("ct-bone")
            .unwrap()
            .spec()
            .resolve(&scale, Path::new("v"))
            .unwrap();
        assert!((r.opacity[0].0 - (150.0 + 1018.5) / 12.0).abs() < 1e-9);
        // No HU mapping: refused, naming the volume.
        let scale = ValueScale {
            range: (0, 255),
            hu: None,
        };
        let e = find("ct-skin")
            .unwrap()
            .spec()
            .resolve(&scale, Path::new("head.nii"))
            .unwrap_err();
        assert!(e.to_string().starts_with("head.nii: "), "{e}");
        assert!(e.to_string().contains("Hounsfield"), "{e}");
        // MR presets are relative to the range.
        let r = find("mr-default")
            .unwrap()
            .spec()
            .resolve(&scale, Path::new("v"))
            .unwrap();
        assert_eq!(r.opacity[1], (0.15 * 255.0, 0.0));
    }

    #[test]
    fn hu_detection_and_suggestions() {
        let ct = ct_meta();
        assert_eq!(hu_mapping(&ct, (0, 3000)), Some((1.0, -1024.0)));
        let mut nifti = VolumeMeta::identity("nifti", "i16");
        nifti.intercept = -1024.0;
        assert!(hu_mapping(&nifti, (0, 3000)).is_some());
        assert!(hu_mapping(&nifti, (1000, 1500)).is_none());
        let mr = VolumeMeta::identity("raw+json", "u8");
        assert!(hu_mapping(&mr, (0, 255)).is_none());
        let names = |hu| {
            suggest(&ValueScale { range: (0, 1), hu })
                .iter()
                .map(|p| p.name)
                .collect::<Vec<_>>()
        };
        assert_eq!(
            names(Some((1.0, 0.0))),
            ["ct-bone", "ct-skin", "ct-angio", "mip"]
        );
        assert_eq!(names(None), ["mr-default", "mr-brain", "mip"]);
    }

    #[test]
    fn u16_range_ignores_the_top_ten_thousandth() {
        let mut d: Vec<u16> = (0..20000).map(|i| (i % 1000) as u16).collect();
        d[5] = 60000;
        d[6] = 50000;
        assert_eq!(u16_range(&d), (0, 999));
        assert_eq!(u16_range(&[7, 7]), (7, 7));
    }
}
