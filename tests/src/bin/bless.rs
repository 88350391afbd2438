//! Writes the golden images: `cargo run -p shearwarp-tests --bin bless [CASE...]`.
//!
//! This is the only way a golden changes. It also writes the reference ray caster's image
//! next to each one under `target/golden-review/` so the change can be looked at before
//! it is committed.

use shearwarp_tests::cases::{self, CASES};
use shearwarp_tests::metrics;

fn main() {
    let only: Vec<String> = std::env::args().skip(1).collect();
    let review =
        std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../target/golden-review");
    std::fs::create_dir_all(&review).expect("create review dir");
    std::fs::create_dir_all(cases::golden_dir()).expect("create golden dir");
    for case in CASES {
        if !only.is_empty() && !only.iter().any(|n| n == case.name) {
            continue;
        }
        let raw = cases::load(case.vol);
        let ours = cases::render_ours(case, &raw);
        let reference = cases::render_ref(case, &raw);
        let psnr = metrics::psnr_rgb8(&ours, &reference);
        let out = cases::golden_dir().join(format!("{}.png", case.name));
        metrics::save_png(&out, case.size, case.size, &ours).expect("write golden");
        // Side by side for review: shear-warp on the left, reference on the right.
        let n = case.size;
        let mut both = vec![[0u8; 3]; 2 * n * n];
        for y in 0..n {
            both[2 * n * y..2 * n * y + n].copy_from_slice(&ours[n * y..n * y + n]);
            both[2 * n * y + n..2 * n * (y + 1)].copy_from_slice(&reference[n * y..n * y + n]);
        }
        metrics::save_png(&review.join(format!("{}.png", case.name)), 2 * n, n, &both)
            .expect("write review image");
        println!(
            "{:<26} PSNR {:>6.2} dB  -> {}",
            case.name,
            psnr,
            out.display()
        );
    }
}
