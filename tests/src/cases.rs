//! The golden cases: each volume, transfer function and view that the golden test renders
//! with both the shear-warp renderer and the reference ray caster.

use crate::metrics;
use crate::reference::{self, RefMode, RefShading, RefTf, RefView, RefVolume};
use crate::synth;
use shearwarp_core::clip::Clip;
use shearwarp_core::composite::Mode;
use shearwarp_core::crop::Crop;
use shearwarp_core::depth::DepthCue;
use shearwarp_core::postclass::PostMode;
use shearwarp_core::shade::{Light, Lighting};
use shearwarp_core::view::Camera;
use shearwarp_file::isa::Isa;
use shearwarp_file::renderer::Renderer;
use shearwarp_file::scene::{self, Classification, Look};
use shearwarp_file::volume::{self, RawVolume, Voxels};
use std::path::PathBuf;

/// Where a case's volume comes from.
#[derive(Clone, Copy, Debug)]
pub enum Vol {
    /// Generated spheres, n³, spacing 1.
    Spheres(usize),
    /// Generated Marschner–Lobb signal, n³, spacing 1.
    MarschnerLobb(usize),
    /// Generated box with anisotropic spacing (1.0, 2.0, 0.5).
    AnisoBox,
    /// A sidecar file under `fixtures/`.
    Fixture(&'static str),
}

/// One golden case.
#[derive(Clone, Copy, Debug)]
pub struct Case {
    /// File stem of the golden image.
    pub name: &'static str,
    /// Volume.
    pub vol: Vol,
    /// Opacity transfer function.
    pub opacity: &'static [(f64, f64)],
    /// Colour transfer function.
    pub color: &'static [(f64, [u8; 3])],
    /// Shade with the default lighting.
    pub shading: bool,
    /// Compositing or MIP.
    pub mode: Mode,
    /// Rotation about X, degrees.
    pub rx: f64,
    /// Rotation about Y, degrees.
    pub ry: f64,
    /// Image size.
    pub size: usize,
    /// Lowest acceptable PSNR against the reference, dB.
    pub min_psnr: f64,
    /// Depth cueing.
    pub depth_cue: Option<DepthCue>,
    /// Shadows from the first light.
    pub shadows: bool,
    /// Two coloured lights (warm key, blue fill) instead of the default white light.
    pub two_lights: bool,
    /// Render the unclassified volume in this mode instead of the classified RLE path.
    pub post: Option<PostMode>,
    /// Intermediate pixels per voxel.
    pub supersample: usize,
    /// Perspective field of view in degrees (`None`: parallel projection).
    pub fov: Option<f64>,
    /// Crop box `(lo, hi)`, inclusive voxel indices of the volume.
    pub crop: Option<([usize; 3], [usize; 3])>,
    /// Clipping planes `(normal, distance)` as [`RefView::clip`] takes them.
    pub clip: &'static [([f64; 3], f64)],
    /// Inverse clipping ([`Clip::inverted`]).
    pub clip_inverse: bool,
    /// Thickness of the layer shaded as the cut's face ([`Clip::with_shaded_face`]).
    pub clip_face: f64,
}

/// The lighting a case uses.
pub fn lighting(case: &Case) -> Lighting {
    let mut l = Lighting::default();
    if case.two_lights {
        l.lights.clear();
        let _ = l.lights.push(Light {
            direction: [0.5, 0.5, 1.0],
            color: [1.0, 0.8, 0.6],
        });
        let _ = l.lights.push(Light {
            direction: [-0.8, -0.3, 0.5],
            color: [0.3, 0.45, 1.0],
        });
    }
    l
}

const SPHERE_OPACITY: &[(f64, f64)] = &[(0.0, 0.0), (60.0, 0.0), (100.0, 0.5), (255.0, 0.9)];
const SPHERE_COLOR: &[(f64, [u8; 3])] = &[
    (0.0, [0, 0, 0]),
    (80.0, [255, 80, 40]),
    (160.0, [60, 200, 90]),
    (240.0, [80, 120, 255]),
];
const ML_OPACITY: &[(f64, f64)] = &[(0.0, 0.0), (110.0, 0.0), (128.0, 0.25), (146.0, 0.0)];
const ML_COLOR: &[(f64, [u8; 3])] = &[(0.0, [255, 255, 255]), (255.0, [255, 255, 255])];
const HEAD_OPACITY: &[(f64, f64)] = &[(0.0, 0.0), (40.0, 0.0), (90.0, 0.15), (255.0, 0.9)];
const HEAD_COLOR: &[(f64, [u8; 3])] = &[
    (0.0, [128, 80, 64]),
    (128.0, [224, 176, 144]),
    (255.0, [255, 255, 240]),
];
/// A narrow peak around the skin/scalp boundary: hard for pre-classification.
const HEAD_PEAK: &[(f64, f64)] = &[(0.0, 0.0), (66.0, 0.0), (76.0, 0.9), (86.0, 0.0)];
const BOX_OPACITY: &[(f64, f64)] = &[(0.0, 0.0), (100.0, 0.0), (200.0, 0.3)];
const GREY: &[(f64, [u8; 3])] = &[(0.0, [0, 0, 0]), (255.0, [255, 255, 255])];
const MIP_OPACITY: &[(f64, f64)] = &[(0.0, 0.0), (1.0, 1.0)];

macro_rules! case {
    ($name:expr, $vol:expr, $op:expr, $col:expr, $sh:expr, $mode:expr, $rx:expr, $ry:expr, $psnr:expr) => {
        Case {
            name: $name,
            vol: $vol,
            opacity: $op,
            color: $col,
            shading: $sh,
            mode: $mode,
            rx: $rx,
            ry: $ry,
            size: 128,
            min_psnr: $psnr,
            depth_cue: None,
            shadows: false,
            two_lights: false,
            post: None,
            supersample: 1,
            fov: None,
            crop: None,
            clip: &[],
            clip_inverse: false,
            clip_face: 0.0,
        }
    };
}

/// The Colin27 head at 64³, cut open by a crop box; its variants in [`CASES`] change
/// the projection or the path.
const HEAD_CUT: Case = Case {
    crop: Some(([0, 0, 0], [31, 63, 55])),
    ..case!(
        "head64_crop_cut",
        Vol::Fixture("mr_head_colin27_64.json"),
        HEAD_OPACITY,
        HEAD_COLOR,
        true,
        Mode::Composite,
        -30.0,
        -60.0,
        25.0
    )
};

/// The Colin27 head at 64³ cut by an oblique plane through its centre, the cut face
/// turned toward the viewer; its variants in [`CASES`] change the path or the planes.
const HEAD_CLIP: Case = Case {
    clip: &[([1.0, 0.5, 0.8], 0.0)],
    ..case!(
        "head64_clip_oblique",
        Vol::Fixture("mr_head_colin27_64.json"),
        HEAD_OPACITY,
        HEAD_COLOR,
        true,
        Mode::Composite,
        -30.0,
        -35.0,
        25.0
    )
};

/// Three planes whose inverse takes out the head's corner toward the viewer of
/// [`HEAD_CLIP`], reaching 8 mm past the centre along each axis.
const CORNER: &[([f64; 3], f64)] = &[
    ([-1.0, 0.0, 0.0], 8.0),
    ([0.0, 1.0, 0.0], 8.0),
    ([0.0, 0.0, -1.0], 8.0),
];

/// Thresholds: shear-warp classifies voxels before interpolating, the reference after,
/// so surfaces that are sharp in the data (the hard-edged box, the unshaded sphere rims)
/// land up to half a voxel apart and thin iso-bands (Marschner–Lobb) alias; those cases
/// get 28 and 25 dB, smooth real data 25–30 dB, everything else 30 dB.
///
/// All golden cases. Views cover each principal axis (0/0 → z, 0/90 → x, 90/0 → y) and
/// oblique 45° cases.
pub const CASES: &[Case] = &[
    case!(
        "spheres_z",
        Vol::Spheres(64),
        SPHERE_OPACITY,
        SPHERE_COLOR,
        true,
        Mode::Composite,
        0.0,
        0.0,
        30.0
    ),
    case!(
        "spheres_x",
        Vol::Spheres(64),
        SPHERE_OPACITY,
        SPHERE_COLOR,
        true,
        Mode::Composite,
        0.0,
        90.0,
        30.0
    ),
    case!(
        "spheres_y",
        Vol::Spheres(64),
        SPHERE_OPACITY,
        SPHERE_COLOR,
        true,
        Mode::Composite,
        90.0,
        0.0,
        30.0
    ),
    case!(
        "spheres_45_45",
        Vol::Spheres(64),
        SPHERE_OPACITY,
        SPHERE_COLOR,
        true,
        Mode::Composite,
        45.0,
        45.0,
        30.0
    ),
    case!(
        "spheres_unshaded_30_m60",
        Vol::Spheres(64),
        SPHERE_OPACITY,
        SPHERE_COLOR,
        false,
        Mode::Composite,
        30.0,
        -60.0,
        28.0
    ),
    case!(
        "ml_z",
        Vol::MarschnerLobb(41),
        ML_OPACITY,
        ML_COLOR,
        false,
        Mode::Composite,
        0.0,
        0.0,
        25.0
    ),
    case!(
        "ml_20_45",
        Vol::MarschnerLobb(41),
        ML_OPACITY,
        ML_COLOR,
        true,
        Mode::Composite,
        20.0,
        45.0,
        25.0
    ),
    case!(
        "box_aniso_30_30",
        Vol::AnisoBox,
        BOX_OPACITY,
        GREY,
        true,
        Mode::Composite,
        30.0,
        30.0,
        28.0
    ),
    case!(
        "head64_face",
        Vol::Fixture("mr_head_colin27_64.json"),
        HEAD_OPACITY,
        HEAD_COLOR,
        true,
        Mode::Composite,
        -90.0,
        0.0,
        25.0
    ),
    case!(
        "head64_34",
        Vol::Fixture("mr_head_colin27_64.json"),
        HEAD_OPACITY,
        HEAD_COLOR,
        true,
        Mode::Composite,
        -45.0,
        -65.0,
        25.0
    ),
    case!(
        "head64_side",
        Vol::Fixture("mr_head_colin27_64.json"),
        HEAD_OPACITY,
        HEAD_COLOR,
        true,
        Mode::Composite,
        0.0,
        90.0,
        25.0
    ),
    case!(
        "head64_mip",
        Vol::Fixture("mr_head_colin27_64.json"),
        MIP_OPACITY,
        GREY,
        false,
        Mode::Mip,
        -90.0,
        0.0,
        30.0
    ),
    case!(
        "brain64_45",
        Vol::Fixture("mr_brain_colin27_hires_64.json"),
        HEAD_OPACITY,
        HEAD_COLOR,
        true,
        Mode::Composite,
        -45.0,
        45.0,
        25.0
    ),
    case!(
        "pd64_mip_30",
        Vol::Fixture("mr_pd_brain_series_64.json"),
        MIP_OPACITY,
        GREY,
        false,
        Mode::Mip,
        30.0,
        20.0,
        30.0
    ),
    Case {
        depth_cue: Some(DepthCue {
            front: 1.0,
            density: 2.0,
        }),
        ..case!(
            "spheres_depthcue_30_45",
            Vol::Spheres(64),
            SPHERE_OPACITY,
            SPHERE_COLOR,
            true,
            Mode::Composite,
            30.0,
            45.0,
            30.0
        )
    },
    Case {
        depth_cue: Some(DepthCue {
            front: 0.9,
            density: 1.2,
        }),
        ..case!(
            "head64_depthcue_34",
            Vol::Fixture("mr_head_colin27_64.json"),
            HEAD_OPACITY,
            HEAD_COLOR,
            true,
            Mode::Composite,
            -70.0,
            -35.0,
            25.0
        )
    },
    Case {
        shadows: true,
        ..case!(
            "spheres_shadows_20_30",
            Vol::Spheres(64),
            SPHERE_OPACITY,
            SPHERE_COLOR,
            true,
            Mode::Composite,
            20.0,
            30.0,
            28.0
        )
    },
    Case {
        shadows: true,
        ..case!(
            "head64_shadows_face",
            Vol::Fixture("mr_head_colin27_64.json"),
            HEAD_OPACITY,
            HEAD_COLOR,
            true,
            Mode::Composite,
            -90.0,
            0.0,
            25.0
        )
    },
    Case {
        two_lights: true,
        ..case!(
            "spheres_two_lights_25_m35",
            Vol::Spheres(64),
            SPHERE_OPACITY,
            SPHERE_COLOR,
            true,
            Mode::Composite,
            25.0,
            -35.0,
            30.0
        )
    },
    Case {
        two_lights: true,
        ..case!(
            "head64_two_lights_34",
            Vol::Fixture("mr_head_colin27_64.json"),
            HEAD_OPACITY,
            HEAD_COLOR,
            true,
            Mode::Composite,
            -70.0,
            -35.0,
            25.0
        )
    },
    // The head cut open by a crop box (its left half and top eighth kept away), the cut
    // faces turned toward the viewer: classified (the box baked into the encoding), in
    // perspective, and post-classified (the box applied per sample).
    HEAD_CUT,
    Case {
        name: "head64_crop_cut_persp60",
        fov: Some(60.0),
        ..HEAD_CUT
    },
    Case {
        name: "head64_crop_cut_post",
        post: Some(PostMode::PostClassified),
        ..HEAD_CUT
    },
    // The head cut by an oblique plane: classified (the plane's coverage baked into the
    // voxels' opacity), post-classified and as an isosurface (per sample), and a slab
    // 12 mm thick between two parallel planes, in perspective.
    HEAD_CLIP,
    Case {
        name: "head64_clip_oblique_post",
        post: Some(PostMode::PostClassified),
        ..HEAD_CLIP
    },
    Case {
        name: "head64_clip_oblique_iso",
        post: Some(PostMode::Isosurface(60.0)),
        ..HEAD_CLIP
    },
    // A corner taken out of the head (inverse clipping: the region behind three planes
    // is the hole), classified and post-classified.
    Case {
        name: "head64_clip_corner",
        clip: CORNER,
        clip_inverse: true,
        ..HEAD_CLIP
    },
    Case {
        name: "head64_clip_corner_post",
        clip: CORNER,
        clip_inverse: true,
        post: Some(PostMode::PostClassified),
        ..HEAD_CLIP
    },
    // The cut's face shaded as a surface, by the planes' normals over a layer two
    // voxels deep: the oblique cut classified and post-classified, and the corner.
    Case {
        name: "head64_clip_oblique_face",
        clip_face: 2.0,
        ..HEAD_CLIP
    },
    Case {
        name: "head64_clip_oblique_face_post",
        clip_face: 2.0,
        post: Some(PostMode::PostClassified),
        ..HEAD_CLIP
    },
    Case {
        name: "head64_clip_corner_face",
        clip: CORNER,
        clip_inverse: true,
        clip_face: 2.0,
        ..HEAD_CLIP
    },
    // A maximum intensity projection of the cut head: the brightest voxel along each
    // ray of what is left.
    Case {
        name: "head64_clip_oblique_mip",
        opacity: MIP_OPACITY,
        color: GREY,
        shading: false,
        mode: Mode::Mip,
        ..HEAD_CLIP
    },
    Case {
        name: "head64_clip_slab_persp45",
        clip: &[([1.0, 0.5, 0.8], 6.0), ([-1.0, -0.5, -0.8], 6.0)],
        fov: Some(45.0),
        ..HEAD_CLIP
    },
    Case {
        post: Some(PostMode::PostClassified),
        ..case!(
            "ml_post_20_45",
            Vol::MarschnerLobb(41),
            ML_OPACITY,
            ML_COLOR,
            true,
            Mode::Composite,
            20.0,
            45.0,
            25.0
        )
    },
    Case {
        post: Some(PostMode::PreIntegrated),
        ..case!(
            "ml_preint_20_45",
            Vol::MarschnerLobb(41),
            ML_OPACITY,
            ML_COLOR,
            true,
            Mode::Composite,
            20.0,
            45.0,
            25.0
        )
    },
    case!(
        "head64_peak_34",
        Vol::Fixture("mr_head_colin27_64.json"),
        HEAD_PEAK,
        HEAD_COLOR,
        true,
        Mode::Composite,
        -70.0,
        -35.0,
        20.0
    ),
    Case {
        post: Some(PostMode::PreIntegrated),
        ..case!(
            "head64_peak_preint_34",
            Vol::Fixture("mr_head_colin27_64.json"),
            HEAD_PEAK,
            HEAD_COLOR,
            true,
            Mode::Composite,
            -70.0,
            -35.0,
            25.0
        )
    },
    Case {
        post: Some(PostMode::Isosurface(120.0)),
        ..case!(
            "spheres_iso_120",
            Vol::Spheres(64),
            SPHERE_OPACITY,
            SPHERE_COLOR,
            true,
            Mode::Composite,
            30.0,
            45.0,
            25.0
        )
    },
    Case {
        post: Some(PostMode::Isosurface(70.0)),
        ..case!(
            "head64_iso_70_34",
            Vol::Fixture("mr_head_colin27_64.json"),
            HEAD_OPACITY,
            HEAD_COLOR,
            true,
            Mode::Composite,
            -70.0,
            -35.0,
            22.0
        )
    },
    Case {
        post: Some(PostMode::PreIntegrated),
        ..case!(
            "ml_preint_z",
            Vol::MarschnerLobb(41),
            ML_OPACITY,
            ML_COLOR,
            false,
            Mode::Composite,
            0.0,
            0.0,
            25.0
        )
    },
    Case {
        size: 512,
        supersample: 1,
        ..case!(
            "head64_512_34",
            Vol::Fixture("mr_head_colin27_64.json"),
            HEAD_OPACITY,
            HEAD_COLOR,
            true,
            Mode::Composite,
            -70.0,
            -35.0,
            25.0
        )
    },
    Case {
        size: 512,
        supersample: 2,
        ..case!(
            "head64_512_34_ss2",
            Vol::Fixture("mr_head_colin27_64.json"),
            HEAD_OPACITY,
            HEAD_COLOR,
            true,
            Mode::Composite,
            -70.0,
            -35.0,
            25.0
        )
    },
    Case {
        size: 512,
        supersample: 1,
        ..case!(
            "spheres_512_30_45",
            Vol::Spheres(64),
            SPHERE_OPACITY,
            SPHERE_COLOR,
            true,
            Mode::Composite,
            30.0,
            45.0,
            25.0
        )
    },
    Case {
        size: 512,
        supersample: 2,
        ..case!(
            "spheres_512_30_45_ss2",
            Vol::Spheres(64),
            SPHERE_OPACITY,
            SPHERE_COLOR,
            true,
            Mode::Composite,
            30.0,
            45.0,
            25.0
        )
    },
    Case {
        fov: Some(30.0),
        ..case!(
            "spheres_persp30_30_45",
            Vol::Spheres(64),
            SPHERE_OPACITY,
            SPHERE_COLOR,
            true,
            Mode::Composite,
            30.0,
            45.0,
            30.0
        )
    },
    Case {
        fov: Some(60.0),
        ..case!(
            "spheres_persp60_z",
            Vol::Spheres(64),
            SPHERE_OPACITY,
            SPHERE_COLOR,
            true,
            Mode::Composite,
            0.0,
            0.0,
            30.0
        )
    },
    Case {
        fov: Some(90.0),
        ..case!(
            "spheres_persp90_20_m60",
            Vol::Spheres(64),
            SPHERE_OPACITY,
            SPHERE_COLOR,
            true,
            Mode::Composite,
            20.0,
            -60.0,
            30.0
        )
    },
    Case {
        fov: Some(60.0),
        ..case!(
            "head64_persp60_34",
            Vol::Fixture("mr_head_colin27_64.json"),
            HEAD_OPACITY,
            HEAD_COLOR,
            true,
            Mode::Composite,
            -70.0,
            -35.0,
            25.0
        )
    },
    Case {
        fov: Some(90.0),
        ..case!(
            "head64_persp90_face",
            Vol::Fixture("mr_head_colin27_64.json"),
            HEAD_OPACITY,
            HEAD_COLOR,
            true,
            Mode::Composite,
            -90.0,
            0.0,
            25.0
        )
    },
    Case {
        fov: Some(90.0),
        ..case!(
            "box_aniso_persp90_30_30",
            Vol::AnisoBox,
            BOX_OPACITY,
            GREY,
            false,
            Mode::Composite,
            30.0,
            30.0,
            24.0
        )
    },
    Case {
        fov: Some(45.0),
        ..case!(
            "pd64_mip_persp45_30",
            Vol::Fixture("mr_pd_brain_series_64.json"),
            MIP_OPACITY,
            GREY,
            false,
            Mode::Mip,
            -60.0,
            30.0,
            30.0
        )
    },
];

/// The workspace's `fixtures/` directory.
pub fn fixtures_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../fixtures")
}

/// Directory of committed golden images.
pub fn golden_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("golden/expected")
}

/// Loads or generates a case's volume.
pub fn load(vol: Vol) -> RawVolume {
    let gen = |name: &str, dims: [usize; 3], spacing: [f64; 3], data: Vec<u8>| RawVolume {
        name: name.to_string(),
        dims,
        spacing,
        voxels: Voxels::U8(data),
    };
    match vol {
        Vol::Spheres(n) => gen("spheres", [n; 3], [1.0; 3], synth::spheres(n)),
        Vol::MarschnerLobb(n) => gen("marschner_lobb", [n; 3], [1.0; 3], synth::marschner_lobb(n)),
        Vol::AnisoBox => gen(
            "box",
            [40, 24, 64],
            [1.0, 2.0, 0.5],
            synth::ramp_box(40, 24, 64),
        ),
        Vol::Fixture(f) => volume::load_volume(&fixtures_dir().join(f))
            .unwrap_or_else(|e| panic!("fixture {f}: {e}")),
    }
}

/// Renders a case with the shear-warp renderer (RGB8, row-major).
pub fn render_ours(case: &Case, raw: &RawVolume) -> Vec<[u8; 3]> {
    render_ours_threads(case, raw, 1)
}

/// As [`render_ours`], compositing with `threads` threads.
pub fn render_ours_threads(case: &Case, raw: &RawVolume, threads: usize) -> Vec<[u8; 3]> {
    if let Some(mode) = case.post {
        let vol = shearwarp_file::post::DenseVolume::new(raw).expect("dense volume");
        let look = Look {
            mode: Mode::Composite,
            color: scene::color_table(case.color, vol.range).expect("colour"),
            lighting: case.shading.then(|| lighting(case)),
            ert_threshold: 0.95,
            depth_cue: None,
            shadows: false,
        };
        let cam = camera(case);
        let mut r = shearwarp_file::post::PostRenderer::with_threads(&vol, threads);
        let cut = cut(case, raw.dims, raw.spacing);
        let frame = r
            .render(&vol, mode, case.opacity, &look, &cam, cut)
            .expect("render");
        return frame.iter().map(|p| [p[0], p[1], p[2]]).collect();
    }
    let enc = scene::encode(raw, &classification(case, raw.dims, raw.spacing)).expect("encode");
    render_encoded(case, &enc, threads, Isa::detect())
}

/// Renders a classic (RLE) case with `threads` threads, its clipping planes applied as
/// the slices are composited ([`Renderer::set_clip`]) to the volume classified without
/// them; `None` for a post-classified case (its planes are always applied so).
pub fn render_ours_clipped_live(
    case: &Case,
    raw: &RawVolume,
    threads: usize,
) -> Option<Vec<[u8; 3]>> {
    if case.post.is_some() {
        return None;
    }
    let mut class = classification(case, raw.dims, raw.spacing);
    let planes = std::mem::replace(&mut class.cut.clip, Clip::NONE);
    let enc = scene::encode(raw, &class).expect("encode");
    Some(render_encoded_clipped(
        case,
        &enc,
        threads,
        Isa::detect(),
        planes,
    ))
}

/// Renders a classic (RLE) case on one thread with the `isa` build of the compositing
/// loop; `None` for a post-classified case (it has no such builds).
pub fn render_ours_isa(case: &Case, raw: &RawVolume, isa: Isa) -> Option<Vec<[u8; 3]>> {
    if case.post.is_some() {
        return None;
    }
    let enc = scene::encode(raw, &classification(case, raw.dims, raw.spacing)).expect("encode");
    Some(render_encoded(case, &enc, 1, isa))
}

/// The camera of a case.
fn camera(case: &Case) -> Camera {
    Camera {
        rotate_x: case.rx,
        rotate_y: case.ry,
        width: case.size,
        height: case.size,
    }
}

/// The classification of a case's transfer function, crop box and clipping planes, for
/// a volume of `dims` voxels spaced `spacing` apart.
fn classification(case: &Case, dims: [usize; 3], spacing: [f64; 3]) -> Classification {
    Classification {
        opacity: case.opacity.to_vec(),
        gradient: None,
        min_opacity: 0.0,
        cut: cut(case, dims, spacing),
    }
}

/// A case's crop box and clipping planes for a volume of `dims` voxels spaced `spacing`
/// apart.
fn cut(case: &Case, dims: [usize; 3], spacing: [f64; 3]) -> scene::Cut {
    scene::Cut {
        crop: case
            .crop
            .map(|(lo, hi)| Crop::new(lo, hi, dims).expect("crop")),
        clip: clip(case, dims, spacing),
    }
}

/// A case's clipping planes for a grid of `dims` and `spacing` (the volume, or a level
/// of it: the planes are placed about the centre both share).
fn clip(case: &Case, dims: [usize; 3], spacing: [f64; 3]) -> Clip {
    let grid = shearwarp_core::classify::Grid::new(dims, spacing).expect("grid");
    let clip = case.clip.iter().fold(Clip::NONE, |c, &(n, d)| {
        c.with_plane(&grid, n, d).expect("clipping plane")
    });
    let clip = clip.with_shaded_face(case.clip_face).expect("face");
    if case.clip_inverse {
        clip.inverted()
    } else {
        clip
    }
}

/// Renders a classic (RLE) case from an encoded volume with `threads` threads.
fn render_encoded(case: &Case, enc: &scene::Encoded, threads: usize, isa: Isa) -> Vec<[u8; 3]> {
    render_encoded_clipped(case, enc, threads, isa, Clip::NONE)
}

/// [`render_encoded`], cutting the slices by `clip` as they are composited.
fn render_encoded_clipped(
    case: &Case,
    enc: &scene::Encoded,
    threads: usize,
    isa: Isa,
    clip: Clip,
) -> Vec<[u8; 3]> {
    let look = Look {
        mode: case.mode,
        color: scene::color_table(case.color, enc.range).expect("colour"),
        lighting: case.shading.then(|| lighting(case)),
        ert_threshold: 0.95,
        depth_cue: case.depth_cue,
        shadows: case.shadows,
    };
    let cam = camera(case);
    let mut r = Renderer::with_threads(&enc.grid, threads);
    r.set_isa(isa);
    r.set_supersample(case.supersample).expect("supersample");
    r.set_perspective(case.fov);
    r.set_clip(clip);
    let mut src = enc.volume().expect("volume");
    let frame = r.render(&mut src, &cam, &look).expect("render");
    frame.iter().map(|p| [p[0], p[1], p[2]]).collect()
}

/// Renders a classic (RLE) case from level `level` of the volume's level-of-detail
/// pyramid (0: the volume itself).
pub fn render_level(case: &Case, raw: &RawVolume, level: usize) -> Vec<[u8; 3]> {
    let (lod, _) = scene::lod(raw, level).expect("level");
    let full = shearwarp_core::classify::Grid::new(raw.dims, raw.spacing).expect("grid");
    let mut class = classification(case, raw.dims, raw.spacing);
    class.cut.crop = class.cut.crop.map(|c| {
        c.at_level(raw.dims, lod.dims, 1 << level)
            .expect("crop at the level")
    });
    class.cut.clip = clip(case, lod.dims, lod.spacing);
    let enc = scene::encode(&lod, &class).expect("encode").as_level(&full);
    render_encoded(case, &enc, 1, Isa::detect())
}

/// Renders a case with the reference ray caster.
pub fn render_ref(case: &Case, raw: &RawVolume) -> Vec<[u8; 3]> {
    let vol = match &raw.voxels {
        Voxels::U8(d) => RefVolume::from_u8(raw.dims, raw.spacing, d),
        Voxels::U16(d) => RefVolume::from_u16(raw.dims, raw.spacing, d),
    };
    let l = lighting(case);
    let shading = RefShading {
        ka: l.ka,
        kd: l.kd,
        ks: l.ks,
        shininess: l.shininess,
        lights: l.lights.iter().map(|x| x.direction).collect(),
        light_colors: l.lights.iter().map(|x| x.color).collect(),
    };
    let tf = RefTf {
        opacity: case.opacity.to_vec(),
        color: case
            .color
            .iter()
            .map(|&(v, c)| (v, c.map(|x| x as f64 / 255.0)))
            .collect(),
    };
    let mode = match (case.post, case.mode) {
        (Some(PostMode::Isosurface(v)), _) => RefMode::Iso(v),
        (_, Mode::Composite) => RefMode::Composite,
        (_, Mode::Mip) => RefMode::Mip,
    };
    let view = RefView {
        rotate_x: case.rx,
        rotate_y: case.ry,
        width: case.size,
        height: case.size,
        depth_cue: case.depth_cue.map(|d| (d.front, d.density)),
        shadows: case.shadows,
        fov: case.fov,
        crop: case.crop,
        clip: case.clip.to_vec(),
        clip_inverse: case.clip_inverse,
        clip_face: case.clip_face,
    };
    let img = reference::render_reference(&vol, &tf, case.shading.then_some(&shading), mode, &view);
    metrics::to_rgb8(&img)
}
