//! Image comparison helpers for golden and reference tests.

use std::path::Path;

fn psnr_from_mse(mse: f64, peak: f64) -> f64 {
    if mse == 0.0 {
        f64::INFINITY
    } else {
        10.0 * (peak * peak / mse).log10()
    }
}

/// PSNR in dB over all channels, peak 255; infinite for identical images.
pub fn psnr_rgb8(a: &[[u8; 3]], b: &[[u8; 3]]) -> f64 {
    assert_eq!(a.len(), b.len(), "image sizes differ");
    let sum: f64 = a
        .iter()
        .zip(b)
        .flat_map(|(p, q)| (0..3).map(move |c| (f64::from(p[c]) - f64::from(q[c])).powi(2)))
        .sum();
    psnr_from_mse(sum / (3 * a.len().max(1)) as f64, 255.0)
}

/// PSNR in dB over all channels, peak 1.0; infinite for identical images.
pub fn psnr_f64(a: &[[f64; 3]], b: &[[f64; 3]]) -> f64 {
    assert_eq!(a.len(), b.len(), "image sizes differ");
    let sum: f64 = a
        .iter()
        .zip(b)
        .flat_map(|(p, q)| (0..3).map(move |c| (p[c] - q[c]).powi(2)))
        .sum();
    psnr_from_mse(sum / (3 * a.len().max(1)) as f64, 1.0)
}

/// Largest absolute difference of any channel of any pixel.
pub fn max_channel_error(a: &[[u8; 3]], b: &[[u8; 3]]) -> u8 {
    assert_eq!(a.len(), b.len(), "image sizes differ");
    a.iter()
        .zip(b)
        .flat_map(|(p, q)| (0..3).map(move |c| p[c].abs_diff(q[c])))
        .max()
        .unwrap_or(0)
}

/// Quantises 0..1 floats to bytes (NaN maps to 0).
pub fn to_rgb8(img: &[[f64; 3]]) -> Vec<[u8; 3]> {
    let q = |v: f64| {
        if v.is_nan() {
            0
        } else {
            (v.clamp(0.0, 1.0) * 255.0).round() as u8
        }
    };
    img.iter().map(|p| p.map(q)).collect()
}

/// Writes an 8-bit RGB PNG (format chosen from the path's extension).
pub fn save_png(path: &Path, w: usize, h: usize, px: &[[u8; 3]]) -> std::io::Result<()> {
    if px.len() != w * h {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            format!("{} pixels for a {w}x{h} image", px.len()),
        ));
    }
    let to_u32 = |v: usize| {
        u32::try_from(v).map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidInput, e))
    };
    let bytes: Vec<u8> = px.iter().flatten().copied().collect();
    image::save_buffer(
        path,
        &bytes,
        to_u32(w)?,
        to_u32(h)?,
        image::ExtendedColorType::Rgb8,
    )
    .map_err(std::io::Error::other)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identical_images_are_infinite() {
        let a = vec![[1u8, 2, 3]; 10];
        assert_eq!(psnr_rgb8(&a, &a), f64::INFINITY);
        let f = vec![[0.1, 0.2, 0.3]; 10];
        assert_eq!(psnr_f64(&f, &f), f64::INFINITY);
        assert_eq!(max_channel_error(&a, &a), 0);
    }

    #[test]
    fn known_difference_matches_formula() {
        let n = 100;
        let a = vec![[0u8; 3]; n];
        let mut b = a.clone();
        b[7][1] = 10;
        // MSE = 100 / (3n).
        let expect = 10.0 * (255.0f64 * 255.0 * 3.0 * n as f64 / 100.0).log10();
        assert!((psnr_rgb8(&a, &b) - expect).abs() < 1e-9);
        assert_eq!(max_channel_error(&a, &b), 10);
        b[3][2] = 255;
        assert_eq!(max_channel_error(&b, &a), 255);

        let fa = vec![[0.5f64; 3]; 4];
        let fb = vec![[0.6f64; 3]; 4];
        // MSE = 0.01 → 20 dB.
        assert!((psnr_f64(&fa, &fb) - 20.0).abs() < 1e-9);
    }

    #[test]
    fn quantisation_rounds_and_clamps() {
        let img = [
            [0.0, 1.0, 0.5],
            [-0.2, 1.7, f64::NAN],
            [0.6 / 255.0, 1.49 / 255.0, 0.999],
        ];
        assert_eq!(to_rgb8(&img), vec![[0, 255, 128], [0, 255, 0], [1, 1, 255]]);
    }

    #[test]
    fn png_round_trip() {
        let dir = std::env::temp_dir().join(format!("shearwarp-metrics-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("rt.png");
        let (w, h) = (3, 2);
        let px = vec![
            [255, 0, 0],
            [0, 255, 0],
            [0, 0, 255],
            [1, 2, 3],
            [4, 5, 6],
            [7, 8, 9],
        ];
        save_png(&path, w, h, &px).unwrap();
        let img = image::open(&path).unwrap().to_rgb8();
        assert_eq!((img.width(), img.height()), (3, 2));
        assert_eq!(img.get_pixel(0, 1).0, [1, 2, 3]);
        assert_eq!(img.get_pixel(2, 0).0, [0, 0, 255]);
        assert!(save_png(&path, 4, 4, &px).is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
