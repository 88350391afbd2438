//! Transfer-function presets and window/level of the opacity ramp.
//!
//! A preset is written in *normalised* units over the data's raw range ([`data_range`]):
//! `(0, 255)` for 8-bit data; for 16-bit data the minimum up to the 99.99th percentile,
//! so a few extreme voxels (dental enamel, metal) do not squash every ramp into the
//! bottom of the range. Its
//! opacity ramp is a shape over `s ∈ [0, 1]` that window/level places on the value axis:
//! `s = 0` sits at `level − window/2`, `s = 1` at `level + window/2`. Colours stay put
//! when the window moves.

// Warm grey colours: the file frontend's default, so both frontends' presets share them.
use shearwarp_file::presets::WARM;
use shearwarp_file::tffile::{TfSpec, Units};
use shearwarp_file::volume::RawVolume;

/// One transfer-function preset.
#[derive(Clone, Copy, Debug)]
pub struct Preset {
    /// Name shown in the title and the key list.
    pub name: &'static str,
    /// Maximum intensity projection instead of compositing.
    pub mip: bool,
    /// Initial window/level (normalised).
    pub wl: WindowLevel,
    /// Opacity shape `(s, opacity per smallest spacing)`, `s` strictly increasing in
    /// `[0, 1]`.
    pub ramp: &'static [(f64, f64)],
    /// Colour `(normalised value, rgb)`, strictly increasing.
    pub color: &'static [(f64, [u8; 3])],
}

/// The presets, in the order the number keys select them.
pub const PRESETS: [Preset; 5] = [
    // The file frontend's default ramp: 0 up to 15 % of the range, 0.1 at 40 %, 0.8 at
    // the top.
    Preset {
        name: "MR default",
        mip: false,
        wl: WindowLevel {
            level: 0.575,
            window: 0.85,
        },
        ramp: &[(0.0, 0.0), (0.25 / 0.85, 0.1), (1.0, 0.8)],
        color: WARM,
    },
    // A tent over the middle intensities (grey and white matter of T1 data), so a
    // skull-stripped brain shows its folds and a full head its soft tissue, semi
    // transparent.
    Preset {
        name: "MR brain",
        mip: false,
        wl: WindowLevel {
            level: 0.5,
            window: 0.4,
        },
        ramp: &[(0.0, 0.0), (0.45, 0.25), (0.75, 0.12), (1.0, 0.04)],
        color: &[
            (0.0, [0x30, 0x10, 0x10]),
            (0.3, [0xb0, 0x60, 0x58]),
            (0.55, [0xf0, 0xc0, 0xb0]),
            (1.0, [0xff, 0xff, 0xff]),
        ],
    },
    // A steep ramp in the upper part of the range: on the shared CT head (u8 = (HU +
    // 1024)/12) it starts near 300 HU.
    Preset {
        name: "CT bone",
        mip: false,
        wl: WindowLevel {
            level: 0.5,
            window: 0.14,
        },
        ramp: &[(0.0, 0.0), (1.0, 0.9)],
        color: &[
            (0.0, [0x60, 0x30, 0x20]),
            (0.4, [0xc8, 0x90, 0x70]),
            (0.5, [0xf0, 0xe0, 0xc0]),
            (1.0, [0xff, 0xff, 0xff]),
        ],
    },
    // A ramp in the lower part of the range: air below, skin and fat (about −500 to
    // −100 HU on the shared CT head) opaque.
    Preset {
        name: "CT skin",
        mip: false,
        wl: WindowLevel {
            level: 0.2,
            window: 0.08,
        },
        ramp: &[(0.0, 0.0), (1.0, 0.85)],
        color: &[
            (0.0, [0x40, 0x20, 0x18]),
            (0.16, [0xc0, 0x80, 0x68]),
            (0.3, [0xf0, 0xc8, 0xa8]),
            (1.0, [0xff, 0xf8, 0xf0]),
        ],
    },
    // MIP: the opacity ramp only decides what takes part (transparent voxels count as
    // zero); the output is the grey of the brightest sample.
    Preset {
        name: "MIP",
        mip: true,
        wl: WindowLevel {
            level: 0.1,
            window: 0.1,
        },
        ramp: &[(0.0, 0.0), (1.0, 1.0)],
        color: WARM,
    },
];

/// Window and level of the opacity ramp, in normalised units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WindowLevel {
    /// Centre of the ramp.
    pub level: f64,
    /// Width of the ramp.
    pub window: f64,
}

impl WindowLevel {
    /// Narrowest window.
    pub const MIN_WINDOW: f64 = 0.004;
    /// Widest window.
    pub const MAX_WINDOW: f64 = 2.0;
    /// Level limits: the ramp may be pushed half off either end of the range.
    pub const LEVEL_RANGE: (f64, f64) = (-0.5, 1.5);

    /// Moves the level by `d_level` and scales the window by `window_factor`, clamped
    /// to the limits above.
    pub fn adjust(self, d_level: f64, window_factor: f64) -> WindowLevel {
        let window = if window_factor.is_finite() && window_factor > 0.0 {
            self.window * window_factor
        } else {
            self.window
        };
        let level = if d_level.is_finite() {
            self.level + d_level
        } else {
            self.level
        };
        WindowLevel {
            level: level.clamp(Self::LEVEL_RANGE.0, Self::LEVEL_RANGE.1),
            window: window.clamp(Self::MIN_WINDOW, Self::MAX_WINDOW),
        }
    }

    /// Lowest and highest raw value of the ramp for data of raw `range`.
    pub fn raw_bounds(&self, range: (u16, u16)) -> (f64, f64) {
        let (lo, span) = lo_span(range);
        (
            lo + (self.level - 0.5 * self.window) * span,
            lo + (self.level + 0.5 * self.window) * span,
        )
    }
}

fn lo_span(range: (u16, u16)) -> (f64, f64) {
    let lo = range.0 as f64;
    (lo, (range.1 as f64 - lo).max(1.0))
}

pub use shearwarp_file::presets::U16_TOP_FRACTION;

/// The raw value range presets are expressed over: the file frontend's normalised range
/// ([`shearwarp_file::presets::data_range`]), shared so that the viewer's presets and the
/// CLI's `--preset`/normalised transfer functions mean the same values. `(0, 255)` for
/// 8-bit data; for 16-bit data the minimum and the value below which all but
/// [`U16_TOP_FRACTION`] of the voxels lie. On the shared CT head (u16 = HU + 1024,
/// maximum 4010) this gives 0..3010, close to the 8-bit copy's window of −1024..2036 HU,
/// so the same presets fit both files.
pub fn data_range(raw: &RawVolume) -> (u16, u16) {
    shearwarp_file::presets::data_range(raw)
}

#[cfg(test)]
fn u16_range(d: &[u16]) -> (u16, u16) {
    use shearwarp_file::volume::Voxels;
    data_range(&RawVolume {
        name: String::new(),
        dims: [d.len().max(1), 1, 1],
        spacing: [1.0; 3],
        voxels: Voxels::U16(d.to_vec()),
    })
}

/// Opacity breakpoints `(raw value, opacity)` of `preset` under `wl`, for data of raw
/// `range`. Strictly increasing for any window the limits allow.
pub fn opacity_points(preset: &Preset, wl: WindowLevel, range: (u16, u16)) -> Vec<(f64, f64)> {
    let (lo, span) = lo_span(range);
    let start = wl.level - 0.5 * wl.window;
    preset
        .ramp
        .iter()
        .map(|&(s, a)| (lo + (start + s * wl.window) * span, a))
        .collect()
}

/// Colour breakpoints `(raw value, rgb)` of `preset` for data of raw `range`.
pub fn color_points(preset: &Preset, range: (u16, u16)) -> Vec<(f64, [u8; 3])> {
    let (lo, span) = lo_span(range);
    preset
        .color
        .iter()
        .map(|&(t, c)| (lo + t * span, c))
        .collect()
}

/// Piecewise-linear evaluation, constant beyond the ends (as the core does).
pub fn eval(points: &[(f64, f64)], x: f64) -> f64 {
    let Some(first) = points.first() else {
        return 0.0;
    };
    if x <= first.0 {
        return first.1;
    }
    for w in points.windows(2) {
        let ((x0, y0), (x1, y1)) = (w[0], w[1]);
        if x <= x1 {
            return y0 + (x - x0) / (x1 - x0) * (y1 - y0);
        }
    }
    points[points.len() - 1].1
}

/// `"v:a,v:a,..."` as the file frontend's `--opacity` reads it (exact round trip).
pub fn opacity_spec(points: &[(f64, f64)]) -> String {
    points
        .iter()
        .map(|(v, a)| format!("{v}:{a}"))
        .collect::<Vec<_>>()
        .join(",")
}

/// `"v:#rrggbb,..."` as the file frontend's `--color` reads it.
pub fn color_spec(points: &[(f64, [u8; 3])]) -> String {
    points
        .iter()
        .map(|(v, c)| format!("{v}:#{:02x}{:02x}{:02x}", c[0], c[1], c[2]))
        .collect::<Vec<_>>()
        .join(",")
}

/// The transfer function of `preset` under `wl` for data of raw `range`, as a
/// transfer-function file in raw units (what the `T` key saves): the same opacity and
/// colour points as [`opacity_points`] and [`color_points`], the same mode, and shading
/// when it is on and the mode composites.
pub fn tf_spec(
    preset: &Preset,
    wl: WindowLevel,
    range: (u16, u16),
    mip: bool,
    shading: bool,
) -> TfSpec {
    TfSpec {
        units: Units::Raw,
        mip,
        shading: Some(shading && !mip),
        opacity: opacity_points(preset, wl, range),
        color: Some(color_points(preset, range)),
        gradient_opacity: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use shearwarp_file::tfspec;

    #[test]
    fn presets_are_valid_at_their_defaults_and_extremes() {
        for p in &PRESETS {
            assert!(p.ramp.first().unwrap().0 == 0.0 && p.ramp.last().unwrap().0 == 1.0);
            for range in [(0u16, 255u16), (0, 4010), (17, 1059), (5, 5)] {
                for wl in [
                    p.wl,
                    p.wl.adjust(-10.0, 1e-9),
                    p.wl.adjust(10.0, 1e9),
                    p.wl.adjust(0.0, 0.0),
                ] {
                    let o = opacity_points(p, wl, range);
                    assert!(o.windows(2).all(|w| w[0].0 < w[1].0), "{} {wl:?}", p.name);
                    assert!(o.iter().all(|q| (0.0..=1.0).contains(&q.1)));
                    // The printed form parses back to the same numbers.
                    assert_eq!(tfspec::parse_opacity(&opacity_spec(&o)).unwrap(), o);
                }
                let c = color_points(p, range);
                assert!(c.windows(2).all(|w| w[0].0 < w[1].0));
                assert_eq!(tfspec::parse_color(&color_spec(&c)).unwrap(), c);
            }
        }
    }

    #[test]
    fn mr_default_is_the_file_frontends_default_ramp() {
        // shearwarp render without --opacity: (lo,0), (lo+.15 span,0), (lo+.4 span,.1),
        // (hi,.8).
        let o = opacity_points(&PRESETS[0], PRESETS[0].wl, (0, 255));
        let want = [(0.0, 0.0), (38.25, 0.0), (102.0, 0.1), (255.0, 0.8)];
        assert_eq!(o.len(), 3);
        for (got, w) in o.iter().zip(&want[1..]) {
            assert!((got.0 - w.0).abs() < 1e-9 && got.1 == w.1, "{o:?}");
        }
    }

    #[test]
    fn window_level_math() {
        let wl = WindowLevel {
            level: 0.5,
            window: 0.2,
        };
        let (a, b) = wl.raw_bounds((0, 255));
        assert!((a - 102.0).abs() < 1e-9 && (b - 153.0).abs() < 1e-9);
        let (a, b) = wl.raw_bounds((1000, 3000));
        assert!((a - 1800.0).abs() < 1e-9 && (b - 2200.0).abs() < 1e-9);
        // Level moves the ramp, the window scales it about its centre.
        let w2 = wl.adjust(0.1, 2.0);
        assert!((w2.level - 0.6).abs() < 1e-12 && (w2.window - 0.4).abs() < 1e-12);
        let o = opacity_points(&PRESETS[2], w2, (0, 100));
        assert!((o[0].0 - 40.0).abs() < 1e-9 && (o[1].0 - 80.0).abs() < 1e-9);
        // Clamping.
        let lo = wl.adjust(-5.0, 1e-6);
        assert_eq!(lo.level, WindowLevel::LEVEL_RANGE.0);
        assert_eq!(lo.window, WindowLevel::MIN_WINDOW);
        let hi = wl.adjust(5.0, 1e6);
        assert_eq!(
            (hi.level, hi.window),
            (WindowLevel::LEVEL_RANGE.1, WindowLevel::MAX_WINDOW)
        );
        assert_eq!(wl.adjust(f64::NAN, f64::NAN), wl);
        // A constant volume still gets a strictly increasing ramp.
        let o = opacity_points(&PRESETS[0], PRESETS[0].wl, (7, 7));
        assert!(o.windows(2).all(|w| w[0].0 < w[1].0));
    }

    #[test]
    fn u16_range_ignores_the_top_ten_thousandth() {
        let mut d: Vec<u16> = (0..20_000).map(|i| 100 + (i % 1000) as u16).collect();
        d[5] = 60_000; // one outlier of 20 000: within the 2 allowed
        d[6] = 50_000;
        assert_eq!(u16_range(&d), (100, 1099));
        d[7] = 40_000; // three outliers: the third highest is the top
        assert_eq!(u16_range(&d), (100, 40_000));
        assert_eq!(u16_range(&[7, 7, 7]), (7, 7));
        assert_eq!(u16_range(&[]), (0, 0));
        let mut spike = vec![0u16; 100_000];
        spike[0] = 9;
        assert_eq!(u16_range(&spike), (0, 9));
    }
}
