//! Image comparison for the headless checks: reads PNG and X window dumps (`xwd`
//! output, so a screenshot of the real window can be checked without ImageMagick) and
//! measures per-channel differences.

use std::fmt;
use std::path::Path;

/// An 8-bit RGB image.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Rgb {
    pub width: usize,
    pub height: usize,
    /// `width × height` pixels, row-major.
    pub pixels: Vec<[u8; 3]>,
}

/// Loads a PNG (anything the `image` crate's PNG decoder reads) or an XWD file.
pub fn load(path: &Path) -> Result<Rgb, String> {
    let bytes = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
    if bytes.starts_with(b"\x89PNG") {
        let img = image::load_from_memory_with_format(&bytes, image::ImageFormat::Png)
            .map_err(|e| format!("{}: {e}", path.display()))?
            .to_rgb8();
        Ok(Rgb {
            width: img.width() as usize,
            height: img.height() as usize,
            pixels: img.pixels().map(|p| p.0).collect(),
        })
    } else {
        parse_xwd(&bytes).map_err(|e| format!("{}: {e}", path.display()))
    }
}

/// Writes `img` as an RGB PNG.
pub fn save_png(img: &Rgb, path: &Path) -> Result<(), String> {
    let bytes: Vec<u8> = img.pixels.iter().flatten().copied().collect();
    image::save_buffer(
        path,
        &bytes,
        img.width as u32,
        img.height as u32,
        image::ExtendedColorType::Rgb8,
    )
    .map_err(|e| format!("cannot write {}: {e}", path.display()))
}

fn be32(b: &[u8], i: usize) -> Result<u32, String> {
    b.get(4 * i..4 * i + 4)
        .map(|s| u32::from_be_bytes([s[0], s[1], s[2], s[3]]))
        .ok_or_else(|| "truncated XWD header".to_string())
}

/// Parses an X11 window dump (XWD version 7, ZPixmap, TrueColor or DirectColor, 24 or
/// 32 bits per pixel) into RGB.
pub fn parse_xwd(b: &[u8]) -> Result<Rgb, String> {
    let header_size = be32(b, 0)? as usize;
    if be32(b, 1)? != 7 || header_size < 100 || header_size > b.len() {
        return Err("not an XWD (version 7) file".into());
    }
    let format = be32(b, 2)?;
    let (width, height) = (be32(b, 4)? as usize, be32(b, 5)? as usize);
    let byte_order = be32(b, 7)?;
    let bpp = be32(b, 11)? as usize;
    let bytes_per_line = be32(b, 12)? as usize;
    let visual_class = be32(b, 13)?;
    let masks = [be32(b, 14)?, be32(b, 15)?, be32(b, 16)?];
    let ncolors = be32(b, 19)? as usize;
    if format != 2 {
        return Err(format!(
            "XWD pixmap format {format} (only ZPixmap, 2, is read)"
        ));
    }
    if !(visual_class == 4 || visual_class == 5) || !(bpp == 24 || bpp == 32) {
        return Err(format!(
            "XWD visual class {visual_class} at {bpp} bits per pixel (only TrueColor or \
             DirectColor at 24/32 bits are read)"
        ));
    }
    if masks.contains(&0) {
        return Err("XWD colour mask is zero".into());
    }
    let data = header_size + 12 * ncolors;
    let bytes_pp = bpp / 8;
    if width == 0 || height == 0 || bytes_per_line < width * bytes_pp {
        return Err("XWD size fields are inconsistent".into());
    }
    let end = height
        .checked_mul(bytes_per_line)
        .and_then(|n| n.checked_add(data))
        .ok_or("XWD size overflows")?;
    if b.len() < end {
        return Err(format!(
            "XWD pixel data truncated ({} of {end} bytes)",
            b.len()
        ));
    }
    let channel = |p: u32, mask: u32| -> u8 {
        let shift = mask.trailing_zeros();
        let max = mask >> shift;
        (((p & mask) >> shift) as u64 * 255 / max as u64) as u8
    };
    let mut pixels = Vec::with_capacity(width * height);
    for y in 0..height {
        let row = &b[data + y * bytes_per_line..];
        for x in 0..width {
            let s = &row[x * bytes_pp..x * bytes_pp + bytes_pp];
            let mut v = 0u32;
            for i in 0..bytes_pp {
                // byte_order 0 = LSBFirst.
                let byte = if byte_order == 0 {
                    s[bytes_pp - 1 - i]
                } else {
                    s[i]
                };
                v = (v << 8) | byte as u32;
            }
            pixels.push(masks.map(|m| channel(v, m)));
        }
    }
    Ok(Rgb {
        width,
        height,
        pixels,
    })
}

/// Differences between two images of the same size.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Diff {
    /// Largest per-channel absolute difference.
    pub max: u8,
    /// Mean per-channel absolute difference.
    pub mean: f64,
    /// Pixels with any channel differing by more than the tolerance asked for.
    pub over: usize,
    /// Pixels compared.
    pub pixels: usize,
}

impl fmt::Display for Diff {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "max |Δ| {} · mean |Δ| {:.4} · {} of {} pixels over tolerance",
            self.max, self.mean, self.over, self.pixels
        )
    }
}

/// Compares `a` and `b`; `tolerance` decides what [`Diff::over`] counts.
pub fn diff(a: &Rgb, b: &Rgb, tolerance: u8) -> Result<Diff, String> {
    if (a.width, a.height) != (b.width, b.height) {
        return Err(format!(
            "sizes differ: {}x{} vs {}x{}",
            a.width, a.height, b.width, b.height
        ));
    }
    let mut max = 0u8;
    let mut sum = 0u64;
    let mut over = 0;
    for (p, q) in a.pixels.iter().zip(&b.pixels) {
        let d = [0, 1, 2].map(|c| p[c].abs_diff(q[c]));
        let m = d.into_iter().max().unwrap_or(0);
        max = max.max(m);
        sum += d.iter().map(|&x| x as u64).sum::<u64>();
        if m > tolerance {
            over += 1;
        }
    }
    Ok(Diff {
        max,
        mean: sum as f64 / (3 * a.pixels.len().max(1)) as f64,
        over,
        pixels: a.pixels.len(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn xwd(w: u32, h: u32, pixels: &[u32], lsb_first: bool) -> Vec<u8> {
        let bpl = 4 * w + 4; // padded rows
        let mut hdr = vec![
            0u32,
            7,
            2,
            24,
            w,
            h,
            0,
            !lsb_first as u32,
            32,
            0,
            32,
            32,
            bpl,
            4,
            0xff0000,
            0xff00,
            0xff,
            8,
            256,
            1,
            w,
            h,
            0,
            0,
            0,
        ];
        let name = b"shot\0\0\0\0";
        hdr[0] = 100 + name.len() as u32;
        let mut b: Vec<u8> = hdr.iter().flat_map(|v| v.to_be_bytes()).collect();
        b.extend_from_slice(name);
        b.extend_from_slice(&[0; 12]); // one colormap entry
        for y in 0..h {
            for x in 0..w {
                let p = pixels[(y * w + x) as usize];
                b.extend(if lsb_first {
                    p.to_le_bytes()
                } else {
                    p.to_be_bytes()
                });
            }
            b.extend([0xee; 4]);
        }
        b
    }

    #[test]
    fn reads_xwd_in_both_byte_orders() {
        let px = [
            0x00ff8000, 0x00010203, 0x00ffffff, 0x00000000, 0x00102030, 0x00abcdef,
        ];
        for lsb in [true, false] {
            let img = parse_xwd(&xwd(3, 2, &px, lsb)).unwrap();
            assert_eq!((img.width, img.height), (3, 2));
            assert_eq!(img.pixels[0], [0xff, 0x80, 0x00]);
            assert_eq!(img.pixels[1], [1, 2, 3]);
            assert_eq!(img.pixels[5], [0xab, 0xcd, 0xef]);
        }
        let mut bad = xwd(3, 2, &px, true);
        bad.truncate(bad.len() - 5);
        assert!(parse_xwd(&bad).unwrap_err().contains("truncated"));
        assert!(parse_xwd(b"not an image at all, clearly").is_err());
    }

    #[test]
    fn diff_counts() {
        let a = Rgb {
            width: 2,
            height: 1,
            pixels: vec![[10, 20, 30], [0, 0, 0]],
        };
        let mut b = a.clone();
        b.pixels[1] = [0, 3, 0];
        let d = diff(&a, &b, 2).unwrap();
        assert_eq!((d.max, d.over, d.pixels), (3, 1, 2));
        assert!((d.mean - 0.5).abs() < 1e-12);
        assert_eq!(diff(&a, &a, 0).unwrap().max, 0);
        let c = Rgb {
            width: 1,
            height: 2,
            pixels: a.pixels.clone(),
        };
        assert!(diff(&a, &c, 0).is_err());
    }
}
