//! Golden tests: every case in `shearwarp_tests::cases::CASES` is rendered by the
//! shear-warp renderer and checked two ways:
//!
//! 1. against the float reference ray caster, by PSNR with the case's stated threshold
//!    (shear-warp pre-classifies and resamples per slice, so it is close to, not equal
//!    to, the post-classified trilinear reference);
//! 2. against the committed golden PNG of our own output, exactly (max channel error 0):
//!    the renderer is integer arithmetic, so any change is a real change. Goldens are
//!    written only by `cargo run -p shearwarp-tests --bin bless`, never by this test.

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
    for case in CASES
        .iter()
        .filter(|c| c.name.starts_with("head64") || c.name == "spheres_45_45")
    {
        let raw = cases::load(case.vol);
        let one = cases::render_ours_threads(case, &raw, 1);
        for threads in [2, 3, 5] {
            let many = cases::render_ours_threads(case, &raw, threads);
            assert!(one == many, "{}: {threads} threads differ", case.name);
        }
    }
}
