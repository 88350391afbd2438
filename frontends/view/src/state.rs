//! What the user controls, and how inputs change it. The window and the script player
//! both turn their events into [`Input`]s, so a replayed script drives exactly the code
//! a person does.

use crate::preset::{WindowLevel, PRESETS};
use shearwarp_core::classify::Grid;
use shearwarp_core::clip::Clip;
use shearwarp_core::crop::Crop;
use shearwarp_core::depth::DepthCue;

/// The fog of the depth-cue toggle: full brightness at the nearest corner of the volume,
/// `e^(−1.5)` ≈ 22 % at the farthest.
pub const DEPTH_CUE: DepthCue = DepthCue {
    front: 1.0,
    density: 1.5,
};

/// Degrees of rotation per pixel of left-drag.
pub const DEG_PER_PIXEL: f64 = 0.5;
/// Degrees per arrow-key press.
pub const DEG_PER_KEY: f64 = 5.0;
/// Zoom factor per wheel notch.
pub const ZOOM_PER_NOTCH: f64 = 1.1;
/// Zoom factor per `+`/`-` key press.
pub const ZOOM_PER_KEY: f64 = 1.25;
/// Zoom limits.
pub const ZOOM_RANGE: (f64, f64) = (0.2, 20.0);
/// Window/level drag: level change per pixel of upward drag (normalised units).
pub const LEVEL_PER_PIXEL: f64 = 0.002;
/// Window/level drag: the window is multiplied by `exp(dx · WINDOW_PER_PIXEL)`.
pub const WINDOW_PER_PIXEL: f64 = 0.005;
/// Level change per key press (normalised units).
pub const LEVEL_PER_KEY: f64 = 0.01;
/// Window factor per key press.
pub const WINDOW_PER_KEY: f64 = 1.15;

/// Steps of the F and B keys: a twentieth of the cut's range per press.
pub const CUT_STEPS: i32 = 20;

/// How the volume is cut open (the C key): the whole of it; the lower part of its voxel
/// indices along one axis, a crop box ([`shearwarp_core::crop`]); or the part facing the
/// viewer taken away by a clipping plane ([`shearwarp_core::clip`]). Each shows the
/// inside on the cut face; F and B move the cut, in steps of 1/[`CUT_STEPS`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum Cut {
    #[default]
    Whole,
    /// Voxels `0..round(keep · n)` along `axis` x, y or z (0, 1, 2), `keep` in steps
    /// (1..=[`CUT_STEPS`]; half, `(n − 1)/2` the last voxel kept, to start with).
    Axis { axis: usize, keep: i32 },
    /// The plane with this normal (physical x, y, z; the direction toward the viewer
    /// when the key was pressed), `offset` steps (−[`CUT_STEPS`]..=[`CUT_STEPS`]) of the
    /// way from the centre to the farthest corner along it
    /// ([`Clip::offset_distance`]): through the centre to start with. The plane stays
    /// put as the view turns, so the cut face can be looked at from the side.
    Facing { normal: [f64; 3], offset: i32 },
    /// The corner of the volume toward the viewer when the key was pressed taken out:
    /// the region behind three axis planes, inverted ([`Clip::inverted`]), `signs` the
    /// side of the centre the corner lies on along x, y, z, and each plane `offset`
    /// steps (0..=[`CUT_STEPS`]) of the way past the centre.
    Corner { signs: [i8; 3], offset: i32 },
}

impl Cut {
    /// The next cut in the C key's cycle: whole, half in x, in y, in z, the half facing
    /// a viewer at rotations `rotate_x`, `rotate_y`, the corner facing that viewer.
    pub fn next(self, rotate_x: f64, rotate_y: f64) -> Cut {
        let half = CUT_STEPS / 2;
        match self {
            Cut::Whole => Cut::Axis {
                axis: 0,
                keep: half,
            },
            Cut::Axis { axis, .. } if axis < 2 => Cut::Axis {
                axis: axis + 1,
                keep: half,
            },
            // The camera looks down −z: toward it is the third row of the rotation.
            Cut::Axis { .. } => Cut::Facing {
                normal: shearwarp_core::view::rotation(rotate_x, rotate_y)[2],
                offset: 0,
            },
            Cut::Facing { normal, .. } => Cut::Corner {
                signs: normal.map(|v| if v < 0.0 { -1 } else { 1 }),
                offset: 0,
            },
            Cut::Corner { .. } => Cut::Whole,
        }
    }

    /// This cut moved `steps` (F: −1, cutting more away; B: +1), within its range.
    pub fn moved(self, steps: i32) -> Cut {
        match self {
            Cut::Whole => Cut::Whole,
            Cut::Axis { axis, keep } => Cut::Axis {
                axis,
                keep: (keep + steps).clamp(1, CUT_STEPS),
            },
            Cut::Facing { normal, offset } => Cut::Facing {
                normal,
                offset: (offset + steps).clamp(-CUT_STEPS, CUT_STEPS),
            },
            // A larger corner cuts more away.
            Cut::Corner { signs, offset } => Cut::Corner {
                signs,
                offset: (offset - steps).clamp(0, CUT_STEPS),
            },
        }
    }

    /// The planes' normals, their offset as `shearwarp render --clip` takes it, and
    /// whether they are inverted; `None` without planes. A corner's planes are the
    /// axes' normals pointing away from it.
    fn planes(self) -> Option<(Vec<[f64; 3]>, f64, bool)> {
        match self {
            Cut::Facing { normal, offset } => Some((vec![normal], Cut::offset(offset), false)),
            Cut::Corner { signs, offset } => {
                let normals = (0..3)
                    .map(|a| {
                        let mut n = [0.0; 3];
                        n[a] = -f64::from(signs[a]);
                        n
                    })
                    .collect();
                Some((normals, Cut::offset(offset), true))
            }
            _ => None,
        }
    }

    /// The plane's offset as `shearwarp render --clip` takes it (steps of a twentieth
    /// print exactly as the division gives them).
    fn offset(offset: i32) -> f64 {
        offset as f64 / CUT_STEPS as f64
    }

    /// The clipping plane on a level's grid `grid` of the volume whose grid is `full`
    /// (the plane is placed on the full volume; a level shares its centre), or none.
    pub fn clip(self, full: &Grid, grid: &Grid) -> Result<Clip, shearwarp_core::Error> {
        let Some((normals, offset, inverse)) = self.planes() else {
            return Ok(Clip::NONE);
        };
        let mut clip = Clip::NONE;
        for n in normals {
            clip = clip.with_plane(grid, n, Clip::offset_distance(full, n, offset))?;
        }
        Ok(if inverse { clip.inverted() } else { clip })
    }

    /// The box of a volume of `dims`, or `None` for the whole.
    pub fn crop(self, dims: [usize; 3]) -> Option<Crop> {
        let Cut::Axis { axis, keep } = self else {
            return None;
        };
        let a = axis.min(2);
        let mut hi = Crop::whole(dims).hi();
        // round(keep/STEPS · n) voxels, at least one: (2·keep·n + STEPS) / (2·STEPS).
        let kept =
            (2 * keep.max(1) as usize * dims[a] + CUT_STEPS as usize) / (2 * CUT_STEPS as usize);
        hi[a] = kept.clamp(1, dims[a]) - 1;
        Crop::new([0; 3], hi, dims).ok()
    }

    /// The same cut as `shearwarp render` takes it (`--crop …` or `--clip …`), for a
    /// volume of `dims`. The normal prints as its shortest round-trip decimals, so the
    /// command's plane is this one to the bit.
    pub fn spec(self, dims: [usize; 3]) -> Option<String> {
        if let Some((normals, o, inverse)) = self.planes() {
            let mut args: Vec<String> = normals
                .iter()
                .map(|[x, y, z]| format!("--clip={x},{y},{z}:{o}"))
                .collect();
            if inverse {
                args.push("--clip-invert".into());
            }
            // The preview cuts as it composites, so that a plane moves without encoding.
            args.push("--clip-live".into());
            return Some(args.join(" "));
        }
        let c = self.crop(dims)?;
        let r = |a: usize| format!("{}:{}", c.lo()[a], c.hi()[a]);
        Some(format!("--crop {},{},{}", r(0), r(1), r(2)))
    }

    /// How the title bar names the cut, or `None` for the whole volume.
    pub fn describe(self) -> Option<String> {
        match self {
            Cut::Whole => None,
            Cut::Axis { axis, keep } => Some(format!(
                "{} ≤ {} %",
                ["x", "y", "z"][axis.min(2)],
                100 * keep / CUT_STEPS
            )),
            Cut::Facing { offset, .. } => Some(format!("plane at {:+.2}", Cut::offset(offset))),
            Cut::Corner { offset, .. } => Some(format!("corner out, {:+.2}", Cut::offset(offset))),
        }
    }
}

/// Everything that decides a frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ViewState {
    /// Rotation about X, degrees (applied after Y).
    pub rotate_x: f64,
    /// Rotation about Y, degrees.
    pub rotate_y: f64,
    /// Zoom (1 = whole volume fits).
    pub zoom: f64,
    /// Pan in window pixels.
    pub pan: [f64; 2],
    /// Index into [`PRESETS`].
    pub preset: usize,
    /// Window/level of the preset's opacity ramp.
    pub wl: WindowLevel,
    /// Phong/Blinn shading.
    pub shading: bool,
    /// Maximum intensity projection forced on (presets can also be MIP).
    pub mip: bool,
    /// Depth cueing ([`DEPTH_CUE`]; composite mode only).
    pub depth_cue: bool,
    /// Shadows toward the first light (composite mode with shading only).
    pub shadows: bool,
    /// Perspective projection (the field of view is a setting); depth cueing and
    /// shadows are parallel-only and left out while it is on.
    pub perspective: bool,
    /// How the volume is cut open (the C key).
    pub cut: Cut,
}

impl ViewState {
    /// The start view.
    pub fn new(rotate_x: f64, rotate_y: f64, preset: usize, shading: bool) -> Self {
        let preset = preset % PRESETS.len();
        ViewState {
            rotate_x,
            rotate_y,
            zoom: 1.0,
            pan: [0.0; 2],
            preset,
            wl: PRESETS[preset].wl,
            shading,
            mip: false,
            depth_cue: false,
            shadows: false,
            perspective: false,
            cut: Cut::Whole,
        }
    }

    /// True if the frame is a maximum intensity projection.
    pub fn is_mip(&self) -> bool {
        self.mip || PRESETS[self.preset].mip
    }

    /// True if only the placement differs: the classification (and so the encoded
    /// volumes) of `self` and `other` are the same.
    pub fn same_classification(&self, other: &ViewState) -> bool {
        self.preset == other.preset && self.wl == other.wl && self.cut == other.cut
    }
}

/// Mouse buttons that drag.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Button {
    /// Rotate.
    Left,
    /// Window/level.
    Right,
    /// Pan.
    Middle,
}

/// Keyboard commands.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ViewKey {
    RotateLeft,
    RotateRight,
    RotateUp,
    RotateDown,
    ZoomIn,
    ZoomOut,
    ResetView,
    NextPreset,
    PrevPreset,
    Preset(usize),
    WindowNarrower,
    WindowWider,
    LevelDown,
    LevelUp,
    ResetWindowLevel,
    Shading,
    Mip,
    Shadows,
    DepthCue,
    Perspective,
    Cut,
    CutMore,
    CutLess,
    Screenshot,
    SaveTf,
    Print,
    Help,
    Quit,
}

/// Key names for scripts, with what they do (the key list printed at start).
pub const KEYS: &[(&str, &str, ViewKey)] = &[
    (
        "left",
        "Left arrow: rotate 5° (about Y)",
        ViewKey::RotateLeft,
    ),
    ("right", "Right arrow: rotate 5°", ViewKey::RotateRight),
    ("up", "Up arrow: tilt 5° (about X)", ViewKey::RotateUp),
    ("down", "Down arrow: tilt 5°", ViewKey::RotateDown),
    ("+", "+ / = / PageUp: zoom in", ViewKey::ZoomIn),
    ("-", "- / PageDown: zoom out", ViewKey::ZoomOut),
    ("r", "R: reset rotation, zoom and pan", ViewKey::ResetView),
    (
        "tab",
        "Tab: next preset (Shift+Tab: previous)",
        ViewKey::NextPreset,
    ),
    ("shift+tab", "", ViewKey::PrevPreset),
    (
        "1",
        "1..5: preset MR default, MR brain, CT bone, CT skin, MIP",
        ViewKey::Preset(0),
    ),
    ("2", "", ViewKey::Preset(1)),
    ("3", "", ViewKey::Preset(2)),
    ("4", "", ViewKey::Preset(3)),
    ("5", "", ViewKey::Preset(4)),
    (
        "[",
        "[ / ]: narrower / wider opacity window",
        ViewKey::WindowNarrower,
    ),
    ("]", "", ViewKey::WindowWider),
    (",", ", / .: lower / raise the level", ViewKey::LevelDown),
    (".", "", ViewKey::LevelUp),
    (
        "0",
        "0: the preset's window/level",
        ViewKey::ResetWindowLevel,
    ),
    ("l", "L: shading on/off", ViewKey::Shading),
    ("m", "M: maximum intensity projection on/off", ViewKey::Mip),
    (
        "w",
        "W: shadows toward the light on/off (needs shading)",
        ViewKey::Shadows,
    ),
    ("d", "D: depth cueing (fog) on/off", ViewKey::DepthCue),
    (
        "o",
        "O: perspective projection on/off (parallel-only: depth cueing, shadows)",
        ViewKey::Perspective,
    ),
    (
        "c",
        "C: cut the volume open: whole, lower half in x, in y, in z, the half facing you, the corner facing you",
        ViewKey::Cut,
    ),
    (
        "f",
        "F / B: move the cut forward (cut more away) / back",
        ViewKey::CutMore,
    ),
    ("b", "", ViewKey::CutLess),
    ("s", "S: screenshot to PNG", ViewKey::Screenshot),
    (
        "t",
        "T: save the transfer function as JSON (for `shearwarp render --tf`)",
        ViewKey::SaveTf,
    ),
    (
        "p",
        "P: print the view and the equivalent `shearwarp render` command",
        ViewKey::Print,
    ),
    ("h", "H / F1: this list", ViewKey::Help),
    ("q", "Q / Esc: quit", ViewKey::Quit),
];

impl ViewKey {
    /// The key of a script name (see [`KEYS`]), ASCII case-insensitive.
    pub fn from_name(name: &str) -> Option<ViewKey> {
        let lower = name.to_ascii_lowercase();
        let alias = match lower.as_str() {
            "esc" | "escape" => "q",
            "=" | "plus" | "pageup" => "+",
            "minus" | "pagedown" => "-",
            "f1" => "h",
            other => other,
        };
        KEYS.iter().find(|k| k.0 == alias).map(|k| k.2)
    }
}

/// One input event.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Input {
    /// Mouse moved by `(dx, dy)` pixels with `button` held.
    Drag { button: Button, dx: f64, dy: f64 },
    /// Wheel turned `notches` (positive zooms in) with the pointer at `at`.
    Wheel { notches: f64, at: Option<[f64; 2]> },
    /// A key press.
    Key(ViewKey),
}

/// What an input asks of the application besides a new view.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Request {
    /// Nothing besides (the view may have changed).
    None,
    Screenshot,
    SaveTf,
    Print,
    Help,
    Quit,
}

/// Applies `input` to `view` for a window of `size` pixels, starting from `home` on
/// reset.
pub fn apply(view: &mut ViewState, home: &ViewState, input: Input, size: [usize; 2]) -> Request {
    let centre = [size[0] as f64 * 0.5, size[1] as f64 * 0.5];
    match input {
        Input::Drag { button, dx, dy } => match button {
            Button::Left => {
                view.rotate_y = wrap_deg(view.rotate_y + DEG_PER_PIXEL * dx);
                view.rotate_x = wrap_deg(view.rotate_x + DEG_PER_PIXEL * dy);
            }
            Button::Middle => {
                view.pan[0] += dx;
                view.pan[1] += dy;
            }
            Button::Right => {
                view.wl = view
                    .wl
                    .adjust(-LEVEL_PER_PIXEL * dy, (WINDOW_PER_PIXEL * dx).exp());
            }
        },
        Input::Wheel { notches, at } => {
            zoom_about(view, ZOOM_PER_NOTCH.powf(notches), at, centre);
        }
        Input::Key(k) => match k {
            ViewKey::RotateLeft => view.rotate_y = wrap_deg(view.rotate_y - DEG_PER_KEY),
            ViewKey::RotateRight => view.rotate_y = wrap_deg(view.rotate_y + DEG_PER_KEY),
            ViewKey::RotateUp => view.rotate_x = wrap_deg(view.rotate_x - DEG_PER_KEY),
            ViewKey::RotateDown => view.rotate_x = wrap_deg(view.rotate_x + DEG_PER_KEY),
            ViewKey::ZoomIn => zoom_about(view, ZOOM_PER_KEY, None, centre),
            ViewKey::ZoomOut => zoom_about(view, 1.0 / ZOOM_PER_KEY, None, centre),
            ViewKey::ResetView => {
                view.rotate_x = home.rotate_x;
                view.rotate_y = home.rotate_y;
                view.zoom = home.zoom;
                view.pan = home.pan;
            }
            ViewKey::NextPreset => set_preset(view, (view.preset + 1) % PRESETS.len()),
            ViewKey::PrevPreset => {
                set_preset(view, (view.preset + PRESETS.len() - 1) % PRESETS.len())
            }
            ViewKey::Preset(i) => set_preset(view, i.min(PRESETS.len() - 1)),
            ViewKey::WindowNarrower => view.wl = view.wl.adjust(0.0, 1.0 / WINDOW_PER_KEY),
            ViewKey::WindowWider => view.wl = view.wl.adjust(0.0, WINDOW_PER_KEY),
            ViewKey::LevelDown => view.wl = view.wl.adjust(-LEVEL_PER_KEY, 1.0),
            ViewKey::LevelUp => view.wl = view.wl.adjust(LEVEL_PER_KEY, 1.0),
            ViewKey::ResetWindowLevel => view.wl = PRESETS[view.preset].wl,
            ViewKey::Shading => view.shading = !view.shading,
            ViewKey::Mip => view.mip = !view.mip,
            ViewKey::Shadows => view.shadows = !view.shadows,
            ViewKey::DepthCue => view.depth_cue = !view.depth_cue,
            ViewKey::Perspective => view.perspective = !view.perspective,
            ViewKey::Cut => view.cut = view.cut.next(view.rotate_x, view.rotate_y),
            ViewKey::CutMore => view.cut = view.cut.moved(-1),
            ViewKey::CutLess => view.cut = view.cut.moved(1),
            ViewKey::Screenshot => return Request::Screenshot,
            ViewKey::SaveTf => return Request::SaveTf,
            ViewKey::Print => return Request::Print,
            ViewKey::Help => return Request::Help,
            ViewKey::Quit => return Request::Quit,
        },
    }
    Request::None
}

fn set_preset(view: &mut ViewState, i: usize) {
    view.preset = i;
    view.wl = PRESETS[i].wl;
}

/// Multiplies the zoom by `factor` (clamped) keeping the virtual-image point under
/// window position `at` (default: the centre) fixed.
fn zoom_about(view: &mut ViewState, factor: f64, at: Option<[f64; 2]>, centre: [f64; 2]) {
    let new = (view.zoom * factor).clamp(ZOOM_RANGE.0, ZOOM_RANGE.1);
    if !new.is_finite() || new == view.zoom {
        return;
    }
    let at = at.unwrap_or(centre);
    // Window w shows virtual C + (w − C − pan)/zoom; keep that fixed at w = at.
    for a in 0..2 {
        view.pan[a] = at[a] - centre[a] - (at[a] - centre[a] - view.pan[a]) * new / view.zoom;
    }
    view.zoom = new;
}

/// Angle in (−180, 180].
pub fn wrap_deg(a: f64) -> f64 {
    let r = a.rem_euclid(360.0);
    if r > 180.0 {
        r - 360.0
    } else {
        r
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn drags_and_keys() {
        let home = ViewState::new(-70.0, -35.0, 0, true);
        let mut v = home;
        let size = [400, 300];
        apply(
            &mut v,
            &home,
            Input::Drag {
                button: Button::Left,
                dx: 20.0,
                dy: -10.0,
            },
            size,
        );
        assert_eq!((v.rotate_x, v.rotate_y), (-75.0, -25.0));
        apply(&mut v, &home, Input::Key(ViewKey::NextPreset), size);
        assert_eq!(v.preset, 1);
        assert_eq!(v.wl, PRESETS[1].wl);
        let before = v.wl;
        apply(
            &mut v,
            &home,
            Input::Drag {
                button: Button::Right,
                dx: 0.0,
                dy: -50.0,
            },
            size,
        );
        assert!((v.wl.level - (before.level + 0.1)).abs() < 1e-12);
        assert_eq!(v.wl.window, before.window);
        apply(&mut v, &home, Input::Key(ViewKey::PrevPreset), size);
        apply(&mut v, &home, Input::Key(ViewKey::PrevPreset), size);
        assert_eq!(v.preset, PRESETS.len() - 1);
        assert!(v.is_mip());
        apply(&mut v, &home, Input::Key(ViewKey::DepthCue), size);
        assert!(v.depth_cue);
        assert_eq!(
            apply(&mut v, &home, Input::Key(ViewKey::Shadows), size),
            Request::None
        );
        assert!(v.shadows);
        apply(&mut v, &home, Input::Key(ViewKey::Perspective), size);
        assert!(v.perspective);
        assert_eq!(ViewKey::from_name("O"), Some(ViewKey::Perspective));
        apply(&mut v, &home, Input::Key(ViewKey::ResetView), size);
        assert_eq!((v.rotate_x, v.rotate_y, v.zoom), (-70.0, -35.0, 1.0));
        assert_eq!(wrap_deg(190.0), -170.0);
        assert_eq!(wrap_deg(-180.0), 180.0);
    }

    #[test]
    fn wheel_zoom_keeps_the_point_under_the_pointer() {
        let home = ViewState::new(0.0, 0.0, 0, false);
        let mut v = home;
        let size = [400, 300];
        let at = [300.0, 100.0];
        let virt = |v: &ViewState| {
            [0, 1]
                .map(|a| size[a] as f64 * 0.5 + (at[a] - size[a] as f64 * 0.5 - v.pan[a]) / v.zoom)
        };
        let before = virt(&v);
        apply(
            &mut v,
            &home,
            Input::Wheel {
                notches: 3.0,
                at: Some(at),
            },
            size,
        );
        assert!((v.zoom - 1.1f64.powi(3)).abs() < 1e-12);
        let after = virt(&v);
        assert!((before[0] - after[0]).abs() < 1e-9 && (before[1] - after[1]).abs() < 1e-9);
        for _ in 0..100 {
            apply(&mut v, &home, Input::Key(ViewKey::ZoomOut), size);
        }
        assert_eq!(v.zoom, ZOOM_RANGE.0);
    }

    #[test]
    fn the_c_key_cycles_the_cuts_and_their_boxes() {
        let home = ViewState::new(-90.0, 0.0, 0, true);
        let mut v = home;
        let dims = [64, 65, 1];
        let mut seen = Vec::new();
        for _ in 0..6 {
            seen.push(v.cut.spec(dims));
            let mut w = v;
            apply(&mut w, &home, Input::Key(ViewKey::Cut), [100, 100]);
            assert!(!w.same_classification(&v), "a new cut is a new encoding");
            v = w;
        }
        assert_eq!(v.cut, Cut::Whole);
        let want = [
            None,
            Some("--crop 0:31,0:64,0:0"),
            Some("--crop 0:63,0:32,0:0"),
            Some("--crop 0:63,0:64,0:0"),
            // Seen from rotate-x −90 (looking along +y), the viewer is toward −y.
            Some("--clip=-0,-1,0:0 --clip-live"),
            // The corner toward it: x and z at or above the centre, y below.
            Some("--clip=-1,0,0:0 --clip=0,1,0:0 --clip=0,0,-1:0 --clip-invert --clip-live"),
        ];
        assert_eq!(seen, want.map(|s| s.map(String::from)));
        // The plane through the centre facing −y keeps the voxels of larger y.
        let grid = Grid::new(dims, [1.0; 3]).unwrap();
        let normal = [0.0, -1.0, 0.0];
        let facing = Cut::Facing { normal, offset: 0 };
        let clip = facing.clip(&grid, &grid).unwrap();
        assert_eq!(clip.coverage([0, 31, 0], 0), 0);
        assert_eq!(clip.coverage([0, 33, 0], 0), 1 << 16);
        let half = Cut::Axis { axis: 1, keep: 10 };
        assert_eq!(half.clip(&grid, &grid).unwrap(), Clip::NONE);
    }

    #[test]
    fn f_and_b_move_the_cut_within_its_range() {
        let dims = [64, 65, 10];
        let home = ViewState::new(-90.0, 0.0, 0, true);
        let mut v = home;
        let press = |v: &mut ViewState, k: ViewKey, n: usize| {
            for _ in 0..n {
                let before = *v;
                apply(v, &home, Input::Key(k), [100, 100]);
                if v.cut != before.cut {
                    assert!(!v.same_classification(&before), "a moved cut re-encodes");
                }
            }
        };
        press(&mut v, ViewKey::CutMore, 1);
        assert_eq!(v.cut, Cut::Whole, "the whole volume has no cut to move");
        press(&mut v, ViewKey::Cut, 3);
        press(&mut v, ViewKey::CutMore, 3);
        // z: 7/20 of 10 slices, rounded: 4 (the last kept is 3).
        assert_eq!(v.cut.spec(dims).unwrap(), "--crop 0:63,0:64,0:3");
        assert_eq!(v.cut.describe().unwrap(), "z ≤ 35 %");
        press(&mut v, ViewKey::CutMore, 30);
        assert_eq!(v.cut.spec(dims).unwrap(), "--crop 0:63,0:64,0:0");
        press(&mut v, ViewKey::CutLess, 40);
        assert_eq!(v.cut.spec(dims).unwrap(), "--crop 0:63,0:64,0:9");
        press(&mut v, ViewKey::Cut, 1);
        press(&mut v, ViewKey::CutMore, 3);
        assert_eq!(
            v.cut.spec(dims).unwrap(),
            "--clip=-0,-1,0:-0.15 --clip-live"
        );
        assert_eq!(v.cut.describe().unwrap(), "plane at -0.15");
        // Placed on the full volume: 0.15 of its half-extent (32.5 cells along y) toward
        // larger y, whatever the grid it is applied to.
        let full = Grid::new(dims, [1.0; 3]).unwrap();
        let clip = v.cut.clip(&full, &full).unwrap();
        let want = Clip::NONE
            .with_plane(&full, [0.0, -1.0, 0.0], -0.15 * 32.5)
            .unwrap();
        assert_eq!(clip, want);
        press(&mut v, ViewKey::CutLess, 50);
        assert_eq!(v.cut.spec(dims).unwrap(), "--clip=-0,-1,0:1 --clip-live");
        // The corner grows as F cuts more, from the centre.
        press(&mut v, ViewKey::Cut, 1);
        press(&mut v, ViewKey::CutLess, 1);
        press(&mut v, ViewKey::CutMore, 2);
        let corner =
            "--clip=-1,0,0:0.1 --clip=0,1,0:0.1 --clip=0,0,-1:0.1 --clip-invert --clip-live";
        assert_eq!(v.cut.spec(dims).unwrap(), corner);
        assert_eq!(v.cut.describe().unwrap(), "corner out, +0.10");
        // Its clip takes out the voxels at x ≥ 31.5 − 3.2, y ≤ 32 + 3.25, z ≥ 4.5 − 0.5.
        let clip = v.cut.clip(&full, &full).unwrap();
        assert!(clip.is_inverse());
        assert_eq!(clip.coverage([40, 20, 8], 0), 0);
        assert_eq!(clip.coverage([20, 20, 8], 0), 1 << 16);
        assert_eq!(clip.coverage([40, 40, 8], 0), 1 << 16);
        assert_eq!(clip.coverage([40, 20, 2], 0), 1 << 16);
    }

    #[test]
    fn key_names() {
        assert_eq!(ViewKey::from_name("Tab"), Some(ViewKey::NextPreset));
        assert_eq!(ViewKey::from_name("ESC"), Some(ViewKey::Quit));
        assert_eq!(ViewKey::from_name("3"), Some(ViewKey::Preset(2)));
        assert_eq!(ViewKey::from_name("="), Some(ViewKey::ZoomIn));
        assert_eq!(ViewKey::from_name("x"), None);
    }
}
