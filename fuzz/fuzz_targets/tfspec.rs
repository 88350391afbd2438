//! Command-line transfer-function, vector and size parsers (`shearwarp_file::tfspec`).
//!
//! Every parser sees the same string (invalid UTF-8 is replaced, as the shell would hand
//! it over lossily). Whatever they accept must be valid for the core: strictly increasing
//! finite breakpoints, alphas in 0..1, sizes in range, non-zero finite vectors. Errors
//! must format without panicking.
#![no_main]

use libfuzzer_sys::fuzz_target;
use shearwarp_core::classify::{ColorTf, OpacityTf};
use shearwarp_file::scene;
use shearwarp_file::tfspec::{self, MAX_SIZE};

fn increasing(xs: impl Iterator<Item = f64>) -> bool {
    let mut prev = f64::NEG_INFINITY;
    for x in xs {
        if !(x.is_finite() && x > prev) {
            return false;
        }
        prev = x;
    }
    true
}

fuzz_target!(|data: &[u8]| {
    let s = String::from_utf8_lossy(data);
    let s = s.as_ref();

    match tfspec::parse_opacity(s) {
        Ok(pts) => {
            assert!(!pts.is_empty());
            assert!(increasing(pts.iter().map(|p| p.0)), "{pts:?}");
            assert!(pts.iter().all(|p| (0.0..=1.0).contains(&p.1)), "{pts:?}");
            let core: Vec<(f64, [f64; 1])> = pts.iter().map(|&(v, a)| (v, [a])).collect();
            let tf = OpacityTf::new(&core).expect("accepted opacity must be valid for the core");
            let mut table = [0u8; 256];
            tf.build_table(&mut table);
            let _ = tf.build_quantized((0, 255));
        }
        Err(e) => {
            let _ = e.to_string();
        }
    }

    match tfspec::parse_color(s) {
        Ok(pts) => {
            assert!(!pts.is_empty());
            assert!(increasing(pts.iter().map(|p| p.0)), "{pts:?}");
            scene::color_table(&pts, (0, 4095)).expect("accepted colour must be valid");
            let core: Vec<(f64, [f64; 3])> = pts
                .iter()
                .map(|&(v, c)| (v, c.map(|x| x as f64 / 255.0)))
                .collect();
            let _ = ColorTf::new(&core)
                .expect("valid for the core")
                .build_table((7, 7));
        }
        Err(e) => {
            let _ = e.to_string();
        }
    }

    match tfspec::parse_vec3(s) {
        Ok(v) => {
            assert!(v.iter().all(|c| c.is_finite()), "{v:?}");
            assert!(v.iter().any(|c| *c != 0.0), "{v:?}");
            let len2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
            assert!(len2.is_finite() && len2 > 0.0, "{v:?}");
        }
        Err(e) => {
            let _ = e.to_string();
        }
    }

    match tfspec::parse_size(s) {
        Ok((w, h)) => {
            assert!(
                (1..=MAX_SIZE).contains(&w) && (1..=MAX_SIZE).contains(&h),
                "{w}x{h}"
            );
        }
        Err(e) => {
            let _ = e.to_string();
        }
    }
});
