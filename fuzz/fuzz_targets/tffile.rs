//! Transfer-function files (`shearwarp_file::tffile`, `--tf FILE` and the viewer's `T`
//! key): the JSON schema's parser, its writer, and the resolution to stored values.
//!
//! Whatever the parser accepts must write back to the same spec, and must resolve,
//! against an 8-bit range, a 16-bit one and a CT volume's HU mapping, to transfer
//! functions the core either builds or refuses with an error (a mapping can squeeze
//! distinct points together); errors must format without panicking.
#![no_main]

use libfuzzer_sys::fuzz_target;
use shearwarp_core::classify::{GradientTf, OpacityTf};
use shearwarp_file::scene;
use shearwarp_file::tffile::{TfSpec, ValueScale};
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let path = Path::new("fuzz.tf.json");
    let Ok(v) = serde_json::from_slice::<serde_json::Value>(data) else {
        return;
    };
    let spec = match TfSpec::from_json(&v, path) {
        Ok(s) => s,
        Err(e) => {
            let _ = e.to_string();
            return;
        }
    };
    let again = TfSpec::from_json(&spec.to_json(), path).expect("a written spec reads back");
    assert_eq!(again, spec, "the written spec differs");
    let scales = [
        ValueScale {
            range: (0, 255),
            hu: None,
        },
        ValueScale {
            range: (17, 4095),
            hu: None,
        },
        ValueScale {
            range: (0, 4095),
            hu: Some((1.0, -1024.0)),
        },
    ];
    for scale in &scales {
        let r = match spec.resolve(scale, path) {
            Ok(r) => r,
            Err(e) => {
                let _ = e.to_string();
                continue;
            }
        };
        let op: Vec<(f64, [f64; 1])> = r.opacity.iter().map(|&(v, a)| (v, [a])).collect();
        match OpacityTf::new(&op) {
            Ok(tf) => {
                let mut table = vec![0u8; usize::from(scale.range.1) + 1];
                tf.build_table(&mut table);
                let _ = tf.build_quantized(scale.range);
            }
            Err(e) => {
                let _ = e.to_string();
            }
        }
        if let Some(c) = &r.color {
            if let Err(e) = scene::color_table(c, scale.range) {
                let _ = e.to_string();
            }
        }
        if let Some(g) = &r.gradient_opacity {
            let pts: Vec<(f64, [f64; 1])> = g.iter().map(|&(m, f)| (m, [f])).collect();
            match GradientTf::new(&pts) {
                Ok(tf) => {
                    let _ = tf.build_table();
                }
                Err(e) => {
                    let _ = e.to_string();
                }
            }
        }
    }
});
