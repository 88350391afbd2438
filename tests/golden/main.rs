//! Golden tests: every case in `shearwarp_tests::cases::CASES` is rendered by the
//! shear-warp renderer and checked two ways:
//!
//! 1. against the float reference ray caster, by PSNR with the case's stated threshold
//!    (shear-warp pre-classifies and resamples per slice, so it is close to, not equal
//!    to, the post-classified trilinear reference);
//! 2. against the committed golden PNG of our own output, exactly (max channel error 0):
//!    the renderer is integer arithmetic, so any change is a real change. Goldens are
//!    written only by `cargo run -p shearwarp-tests --bin bless`, never by this test.

use shearwarp_file::isa::Isa;
use shearwarp_tests::cases::{self, CASES};
use shearwarp_tests::metrics;

fn load_png(path: &std::path::Path) -> Option<(usize, usize, Vec<[u8; 3]>)> {
    let img = image::open(path).ok()?.to_rgb8();
    let (w, h) = img.dimensions();
    let px = img.pixels().map(|p| p.0).collect();
    Some((w as usize, h as usize, px))
}

#[test]
fn golden_cases_match_reference_and_committed_images() {
    let actual_dir = std::path::PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("golden-actual");
    std::fs::create_dir_all(&actual_dir).unwrap();
    let mut failures = Vec::new();
    println!("{:<26} {:>9} {:>9}  golden", "case", "PSNR dB", "min dB");
    for case in CASES {
        let raw = cases::load(case.vol);
        let ours = cases::render_ours(case, &raw);
        let reference = cases::render_ref(case, &raw);
        let psnr = metrics::psnr_rgb8(&ours, &reference);
        let golden = load_png(&cases::golden_dir().join(format!("{}.png", case.name)));
        let golden_status = match &golden {
            None => "missing".to_string(),
            Some((w, h, px)) if (*w, *h) != (case.size, case.size) => {
                format!("size {w}x{h}")
            }
            Some((_, _, px)) => {
                let e = metrics::max_channel_error(&ours, px);
                if e == 0 {
                    "exact".to_string()
                } else {
                    format!("max channel error {e}")
                }
            }
        };
        println!(
            "{:<26} {:>9.2} {:>9.1}  {}",
            case.name, psnr, case.min_psnr, golden_status
        );
        if psnr < case.min_psnr {
            failures.push(format!(
                "{}: PSNR {psnr:.2} dB < {} dB",
                case.name, case.min_psnr
            ));
        }
        if golden_status != "exact" {
            failures.push(format!("{}: golden {golden_status}", case.name));
        }
        if psnr < case.min_psnr || golden_status != "exact" {
            let p = actual_dir.join(format!("{}.png", case.name));
            metrics::save_png(&p, case.size, case.size, &ours).unwrap();
            let r = actual_dir.join(format!("{}.reference.png", case.name));
            metrics::save_png(&r, case.size, case.size, &reference).unwrap();
        }
    }
    assert!(
        failures.is_empty(),
        "golden failures (actual images in {}; accept intended changes with \
         `cargo run -p shearwarp-tests --bin bless` and say why in the commit):\n{}",
        actual_dir.display(),
        failures.join("\n")
    );
}

#[test]
fn threaded_rendering_is_bit_identical_to_single_threaded() {
    for case in CASES.iter().filter(|c| {
        c.name.starts_with("head64")
            || c.name.starts_with("ml_p")
            || ["spheres_45_45", "spheres_iso_120"].contains(&c.name)
    }) {
        let raw = cases::load(case.vol);
        let one = cases::render_ours_threads(case, &raw, 1);
        for threads in [2, 3, 5] {
            let many = cases::render_ours_threads(case, &raw, threads);
            assert!(one == many, "{}: {threads} threads differ", case.name);
        }
    }
}

/// A crop box cuts the picture the reference's box cuts ([`cut_like_the_reference`]); a
/// box around the whole volume changes no pixel of either path.
#[test]
fn crop_boxes_cut_the_volume_like_the_reference() {
    let mut seen = 0;
    for case in CASES.iter().filter(|c| c.crop.is_some()) {
        let raw = cases::load(case.vol);
        let d = raw.dims;
        let whole = cases::Case {
            crop: None,
            ..*case
        };
        let every = cases::Case {
            crop: Some(([0; 3], [d[0] - 1, d[1] - 1, d[2] - 1])),
            ..*case
        };
        cut_like_the_reference(case, &whole, &every, &raw, 8.0);
        seen += 1;
    }
    assert!(seen >= 2);
}

/// Clipping planes cut the picture the reference's planes cut
/// ([`cut_like_the_reference`]), the reference's with a hard cut and ours with opacity
/// faded over the voxel each plane crosses; planes beyond the volume change no pixel,
/// and nor do inverted planes whose hole lies beyond it.
#[test]
fn clipping_planes_cut_the_volume_like_the_reference() {
    const BEYOND: &[([f64; 3], f64)] = &[([1.0, 0.5, 0.8], 1e3), ([0.0, -1.0, 0.0], 1e3)];
    const HOLE_BEYOND: &[([f64; 3], f64)] = &[([1.0, 0.5, 0.8], -1e3), ([0.0, 1.0, 0.0], 0.0)];
    let mut seen = 0;
    for case in CASES.iter().filter(|c| !c.clip.is_empty()) {
        let raw = cases::load(case.vol);
        let whole = cases::Case { clip: &[], ..*case };
        let beyond = cases::Case {
            clip: if case.clip_inverse {
                HOLE_BEYOND
            } else {
                BEYOND
            },
            ..*case
        };
        // A corner taken out changes the least of the picture (7.8 dB; 3.8 at level 1).
        let margin = if case.clip_inverse { 6.0 } else { 8.0 };
        cut_like_the_reference(case, &whole, &beyond, &raw, margin);
        seen += 1;
    }
    assert!(seen >= 3);
}

/// Clipping planes applied as the slices are composited (to a volume classified whole,
/// so that a plane can move from frame to frame) cut as those baked into the
/// classification do: the image is near the baked one and as near the reference, with
/// shadows, depth cueing, supersampling and perspective too, and two threads give the
/// same image as one.
#[test]
fn clipping_planes_applied_while_compositing_cut_as_classified_ones_do() {
    let cued = shearwarp_core::depth::DepthCue {
        front: 0.9,
        density: 1.2,
    };
    let named = |n: &str| *CASES.iter().find(|c| c.name == n).expect("case");
    let oblique = named("head64_clip_oblique");
    let variants = [
        oblique,
        named("head64_clip_corner"),
        named("head64_clip_oblique_mip"),
        named("head64_clip_slab_persp45"),
        cases::Case {
            name: "head64_clip_face_shadows",
            shadows: true,
            ..named("head64_shadows_face")
        },
        cases::Case {
            name: "head64_clip_oblique_cued",
            depth_cue: Some(cued),
            ..oblique
        },
        cases::Case {
            name: "head64_clip_oblique_ss2",
            supersample: 2,
            ..oblique
        },
    ];
    let review = std::env::var_os("SHEARWARP_REVIEW").map(std::path::PathBuf::from);
    for mut case in variants {
        if case.clip.is_empty() {
            case.clip = oblique.clip;
        }
        let raw = cases::load(case.vol);
        let live = cases::render_ours_clipped_live(&case, &raw, 1).expect("classic case");
        let baked = cases::render_ours(&case, &raw);
        let reference = cases::render_ref(&case, &raw);
        let whole = cases::render_ref(&cases::Case { clip: &[], ..case }, &raw);
        let near_baked = metrics::psnr_rgb8(&live, &baked);
        let (live_ref, baked_ref) = (
            metrics::psnr_rgb8(&live, &reference),
            metrics::psnr_rgb8(&baked, &reference),
        );
        let live_whole = metrics::psnr_rgb8(&live, &whole);
        println!(
            "{}: {near_baked:.2} dB against the baked cut; against the reference \
             {live_ref:.2} dB (baked {baked_ref:.2}, the uncut reference {live_whole:.2})",
            case.name
        );
        if let Some(dir) = &review {
            let n = case.size;
            let mut both = Vec::with_capacity(3 * n * n);
            for y in 0..n {
                for img in [&live, &baked, &reference] {
                    both.extend_from_slice(&img[y * n..(y + 1) * n]);
                }
            }
            let path = dir.join(format!("{}.live.png", case.name));
            metrics::save_png(&path, 3 * n, n, &both).expect("review image");
        }
        assert!(near_baked > 35.0, "{}: {near_baked:.2} dB", case.name);
        assert!(live_ref > baked_ref - 1.0, "{}", case.name);
        assert!(live_ref > live_whole + 6.0, "{}", case.name);
        let two = cases::render_ours_clipped_live(&case, &raw, 2).expect("classic case");
        assert!(two == live, "{}: two threads changed the image", case.name);
    }
}

/// The cut's face shaded by the planes' normals ([`shearwarp_core::clip::Clip::with_shaded_face`])
/// is the reference's face shaded so: each face case is nearer the reference that
/// shades its face than the same cut with the face left to the gradients is, by 5 dB
/// (7.7–11.0 measured), and nearer it than to the reference that does not shade it. Cut as the
/// slices are composited, the image is the baked one's to within rounding (and the
/// same on two threads), in parallel, supersampled and perspective frames: above 55 dB
/// (64.6–70.5 measured; shading only every other row's face gave 33.9–36.1).
#[test]
fn the_cut_face_is_lit_by_the_planes_normal_like_the_reference() {
    let named = |n: &str| *CASES.iter().find(|c| c.name == n).expect("case");
    let review = std::env::var_os("SHEARWARP_REVIEW").map(std::path::PathBuf::from);
    let mut seen = 0;
    for case in CASES.iter().filter(|c| c.clip_face > 0.0) {
        let raw = cases::load(case.vol);
        let plain = cases::Case {
            clip_face: 0.0,
            ..*case
        };
        let ours = cases::render_ours(case, &raw);
        let unlit = cases::render_ours(&plain, &raw);
        let reference = cases::render_ref(case, &raw);
        let plain_ref = cases::render_ref(&plain, &raw);
        let (near, unlit_near, plain_near) = (
            metrics::psnr_rgb8(&ours, &reference),
            metrics::psnr_rgb8(&unlit, &reference),
            metrics::psnr_rgb8(&ours, &plain_ref),
        );
        println!(
            "{}: {near:.2} dB against the reference with its face lit, {unlit_near:.2} dB \
             without our face lit, {plain_near:.2} dB against the reference without",
            case.name
        );
        if let Some(dir) = &review {
            let n = case.size;
            let mut all = Vec::with_capacity(4 * n * n);
            for y in 0..n {
                for img in [&ours, &unlit, &reference, &plain_ref] {
                    all.extend_from_slice(&img[y * n..(y + 1) * n]);
                }
            }
            let path = dir.join(format!("{}.face.png", case.name));
            metrics::save_png(&path, 4 * n, n, &all).expect("review image");
        }
        let margin = 5.0;
        assert!(near > unlit_near + margin, "{}", case.name);
        assert!(near > plain_near + margin, "{}", case.name);
        seen += 1;
    }
    assert!(seen >= 3);
    let oblique = named("head64_clip_oblique_face");
    for case in [
        oblique,
        named("head64_clip_corner_face"),
        cases::Case {
            name: "head64_clip_slab_persp45_face",
            clip_face: 2.0,
            ..named("head64_clip_slab_persp45")
        },
        cases::Case {
            name: "head64_clip_oblique_face_ss2",
            supersample: 2,
            ..oblique
        },
    ] {
        let raw = cases::load(case.vol);
        let live = cases::render_ours_clipped_live(&case, &raw, 1).expect("classic case");
        let baked = cases::render_ours(&case, &raw);
        let near_baked = metrics::psnr_rgb8(&live, &baked);
        println!(
            "{} cut live: {near_baked:.2} dB against the baked cut",
            case.name
        );
        assert!(near_baked > 55.0, "{}: {near_baked:.2} dB", case.name);
        let two = cases::render_ours_clipped_live(&case, &raw, 2).expect("classic case");
        assert!(two == live, "{}: two threads changed the image", case.name);
    }
}

/// `case` cuts the volume as the reference does: it is nearer the reference with the
/// cut than without by `margin` dB (so the cut is seen, not lost in the tolerance), and
/// `keeps_all` (a cut that leaves every voxel) renders exactly as `uncut` does. On a
/// level of detail a classified cut keeps its place: the level-1 frame is likewise
/// nearer the cut reference than the level's uncut frame is, by `margin` − 3 dB.
fn cut_like_the_reference(
    case: &cases::Case,
    uncut: &cases::Case,
    keeps_all: &cases::Case,
    raw: &shearwarp_file::volume::RawVolume,
    margin: f64,
) {
    let ours = cases::render_ours(case, raw);
    let reference = cases::render_ref(case, raw);
    let cut_ref = metrics::psnr_rgb8(&ours, &reference);
    let whole_ref = metrics::psnr_rgb8(&ours, &cases::render_ref(uncut, raw));
    println!(
        "{}: {cut_ref:.2} dB against the cut reference, {whole_ref:.2} dB against the \
         whole one",
        case.name
    );
    assert!(
        cut_ref > whole_ref + margin,
        "{}: {cut_ref:.2} dB cut against {whole_ref:.2} dB whole",
        case.name
    );
    assert!(
        cases::render_ours(keeps_all, raw) == cases::render_ours(uncut, raw),
        "{}: a cut that keeps every voxel changed the image",
        case.name
    );
    if case.post.is_none() {
        let level = cases::render_level(case, raw, 1);
        let level_whole = cases::render_level(uncut, raw, 1);
        let near = metrics::psnr_rgb8(&level, &reference);
        let far = metrics::psnr_rgb8(&level_whole, &reference);
        println!("{} at level 1: {near:.2} dB, uncut {far:.2} dB", case.name);
        assert!(
            near > far + margin - 3.0,
            "{}: level 1 {near:.2} against {far:.2} dB",
            case.name
        );
    }
}

#[test]
fn every_instruction_set_build_is_bit_identical_to_the_baseline() {
    let levels: Vec<Isa> = Isa::ALL
        .into_iter()
        .filter(|i| *i != Isa::Baseline && i.available())
        .collect();
    // On a CPU without the wider builds there is nothing to compare; say so.
    if levels.is_empty() {
        eprintln!("only the baseline build runs on this CPU");
        return;
    }
    let mut compared = 0;
    for case in CASES {
        let raw = cases::load(case.vol);
        let Some(base) = cases::render_ours_isa(case, &raw, Isa::Baseline) else {
            continue;
        };
        for &isa in &levels {
            let other = cases::render_ours_isa(case, &raw, isa).expect("classic case");
            assert!(
                base == other,
                "{}: {} differs from baseline",
                case.name,
                isa.name()
            );
            compared += 1;
        }
    }
    assert!(compared > 0);
}

/// Opacity correction: a uniform translucent cube must not change brightness as it
/// turns (the path per slice grows by up to √2 at 45°), and must match the reference.
#[test]
fn opacity_correction_keeps_a_translucent_cube_equally_bright() {
    use shearwarp_core::composite::Mode;
    use shearwarp_file::renderer::Renderer;
    use shearwarp_file::scene::{self, Classification, Look};
    use shearwarp_file::volume::{RawVolume, Voxels};
    use shearwarp_tests::reference::{self, RefMode, RefTf, RefView, RefVolume};
    // Optically thin (τ ≤ 0.1 along the longest diagonal), so the physical brightness is
    // itself nearly rotation-invariant and any drift would come from the correction.
    let n = 20;
    let raw = RawVolume {
        name: "cube".into(),
        dims: [n; 3],
        spacing: [1.0; 3],
        voxels: Voxels::U8(vec![200; n * n * n]),
    };
    // Exactly representable in the 8-bit stored opacity, so only correction is tested.
    let alpha = 1.0 / 255.0;
    let class = Classification {
        opacity: vec![(0.0, alpha)],
        gradient: None,
        min_opacity: 0.0,
        cut: scene::Cut::NONE,
    };
    let enc = scene::encode(&raw, &class).unwrap();
    let look = Look {
        mode: Mode::Composite,
        color: scene::color_table(&[(0.0, [255, 255, 255])], enc.range).unwrap(),
        lighting: None,
        ert_threshold: 1.0,
        depth_cue: None,
        shadows: false,
    };
    let vol = RefVolume::from_u8([n; 3], [1.0; 3], &vec![200; n * n * n]);
    let tf = RefTf {
        opacity: vec![(0.0, alpha)],
        color: vec![(0.0, [1.0; 3])],
    };
    let size = 160;
    let mut r = Renderer::new(&enc.grid);
    let mut means = Vec::new();
    for (rx, ry) in [
        (0.0, 0.0),
        (0.0, 15.0),
        (0.0, 30.0),
        (0.0, 45.0),
        (30.0, 30.0),
        (45.0, 45.0),
    ] {
        let cam = shearwarp_core::view::Camera {
            rotate_x: rx,
            rotate_y: ry,
            width: size,
            height: size,
        };
        let mut src = enc.volume().unwrap();
        let img = r.render(&mut src, &cam, &look).unwrap();
        let ours: f64 = img.iter().map(|p| p[0] as f64 / 255.0).sum::<f64>() / img.len() as f64;
        let view = RefView {
            rotate_x: rx,
            rotate_y: ry,
            width: size,
            height: size,
            depth_cue: None,
            shadows: false,
            fov: None,
            crop: None,
            clip: Vec::new(),
            clip_inverse: false,
            clip_face: 0.0,
        };
        let rimg = reference::render_reference(&vol, &tf, None, RefMode::Composite, &view);
        let theirs: f64 = rimg.iter().map(|p| p[0]).sum::<f64>() / rimg.len() as f64;
        println!("rx {rx:>4} ry {ry:>4}: mean ours {ours:.5} reference {theirs:.5}");
        assert!(
            (ours / theirs - 1.0).abs() < 0.01,
            "view {rx}/{ry}: ours {ours} vs reference {theirs}"
        );
        means.push(integrated_opacity(&enc, &cam));
    }
    let lo = means.iter().cloned().fold(f64::INFINITY, f64::min);
    let hi = means.iter().cloned().fold(0.0, f64::max);
    println!(
        "integrated opacity spread across rotations: {:.3}%",
        (hi / lo - 1.0) * 100.0
    );
    assert!(
        hi / lo < 1.01,
        "brightness varies by {:.2}% across rotations",
        (hi / lo - 1.0) * 100.0
    );
}

/// Opacity integrated over the image plane, from the Q15 intermediate image (before the
/// 8-bit output rounds it): Σ α over intermediate pixels × image area per pixel.
fn integrated_opacity(
    enc: &shearwarp_file::scene::Encoded,
    cam: &shearwarp_core::view::Camera,
) -> f64 {
    use shearwarp_core::composite::{Intermediate, Mode};
    use shearwarp_core::render::{composite_band, Frame, Settings};
    use shearwarp_core::shade::ShadeTable;
    let color = [[32768u16; 3]; 256];
    let settings = Settings {
        mode: Mode::Composite,
        color: &color,
        lighting: None,
        ert_threshold: 1.0,
        depth_cue: None,
        shadows: false,
        flat_voxels: Default::default(),
        clip: shearwarp_core::clip::Clip::NONE,
    };
    let mut shade = ShadeTable::UNSHADED;
    let frame = Frame::new(&enc.grid, cam, &settings, &mut shade, None).unwrap();
    let tables = frame.tables(&shade, None);
    let [w, h] = frame.view.intermediate;
    let mut px = vec![[0u16; 4]; w * h];
    let mut links = vec![0; w * h];
    let side = *enc.grid.dims.iter().max().unwrap();
    let mut rows = vec![[0u16; 4]; shearwarp_core::composite::row_buffer_len(side)];
    let mut img = Intermediate::new(w, h, &mut px, &mut links).unwrap();
    let mut src = enc.volume().unwrap();
    composite_band(&mut src, &frame, &tables, &mut img, &mut rows, None).unwrap();
    let m = frame.view.image_to_intermediate;
    let area = 1.0 / (m[0][0] * m[1][1] - m[0][1] * m[1][0]).abs();
    img.pixels()
        .iter()
        .map(|p| p[3] as f64 / 32768.0)
        .sum::<f64>()
        * area
}

/// Levels of detail: each level of the pyramid draws the same view equally bright (its
/// grid keeps the full volume's opacity unit, so opacity correction lengthens the fewer,
/// longer steps), and the images get closer to the full-resolution one level by level.
#[test]
fn levels_of_detail_keep_brightness_and_converge() {
    let base = CASES.iter().find(|c| c.name == "head64_34").unwrap();
    for (fov, vol) in [
        (None, "mr_head_colin27.json"),
        (Some(60.0), "mr_head_colin27.json"),
    ] {
        let case = cases::Case {
            vol: cases::Vol::Fixture(vol),
            size: 256,
            fov,
            ..*base
        };
        let raw = cases::load(case.vol);
        let mean = |img: &[[u8; 3]]| {
            img.iter()
                .map(|p| p.iter().map(|&c| c as f64).sum::<f64>())
                .sum::<f64>()
                / (3 * img.len()) as f64
        };
        let full = cases::render_level(&case, &raw, 0);
        let m0 = mean(&full);
        let mut last_psnr = f64::INFINITY;
        // Level 3 (23×28×23 voxels) loses the thin scalp to averaging with air (−8 %):
        // measured in the bench, not held to the brightness bound here.
        for level in 1..=2 {
            let img = cases::render_level(&case, &raw, level);
            let m = mean(&img);
            let psnr = metrics::psnr_rgb8(&img, &full);
            println!(
                "{vol} fov {fov:?} level {level}: mean {m:.2} vs {m0:.2} ({:+.2} %), PSNR {psnr:.2} dB",
                100.0 * (m / m0 - 1.0)
            );
            assert!(
                (m / m0 - 1.0).abs() < 0.03,
                "level {level}: mean {m} vs {m0}"
            );
            assert!(
                psnr < last_psnr + 0.5 && psnr > 20.0,
                "level {level}: {psnr} dB"
            );
            last_psnr = psnr;
        }
    }
}
