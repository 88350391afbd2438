//! Turntable output: an animated GIF, an animated PNG (APNG), or numbered PNG files.

use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

/// Where the frames of a turntable go, decided by the output path.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Target {
    /// A path with `%d` (or `%0Nd`, zero-padded to N digits) in its file name: one PNG
    /// per frame, numbered from 0.
    Numbered { path: PathBuf, width: usize },
    /// `.gif`: an animated GIF (looping; 8-bit palette per frame).
    Gif(PathBuf),
    /// `.png`/`.apng` without `%d`: an animated PNG (looping).
    Apng(PathBuf),
}

/// Decides the target for `path`; `None` for an extension that cannot hold frames.
pub fn target(path: &Path) -> Option<Target> {
    let name = path.file_name()?.to_string_lossy().into_owned();
    if let Some(at) = name.find('%') {
        let rest = &name[at + 1..];
        let digits: String = rest.chars().take_while(|c| c.is_ascii_digit()).collect();
        if rest[digits.len()..].starts_with('d') {
            let width = if digits.is_empty() {
                0
            } else {
                digits.parse().ok().filter(|&w: &usize| w <= 9)?
            };
            return Some(Target::Numbered {
                path: path.to_path_buf(),
                width,
            });
        }
    }
    let lower = name.to_ascii_lowercase();
    if lower.ends_with(".gif") {
        Some(Target::Gif(path.to_path_buf()))
    } else if lower.ends_with(".png") || lower.ends_with(".apng") {
        Some(Target::Apng(path.to_path_buf()))
    } else {
        None
    }
}

/// The file of frame `i` for a numbered target (`%d`/`%0Nd` replaced).
pub fn numbered(path: &Path, width: usize, i: usize) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let Some(at) = name.find('%') else {
        return path.to_path_buf();
    };
    let end = name[at..].find('d').map_or(name.len(), |d| at + d + 1);
    path.with_file_name(format!("{}{i:0width$}{}", &name[..at], &name[end..]))
}

/// One frame: 8- or 16-bit RGB.
pub enum Pixels {
    Rgb8(Vec<u8>),
    Rgb16(Vec<u16>),
}

enum Sink {
    Numbered(PathBuf, usize),
    Gif(image::codecs::gif::GifEncoder<BufWriter<File>>),
    Apng(png::Writer<BufWriter<File>>),
}

/// Writes the frames of one animation.
pub struct Writer {
    sink: Sink,
    width: u32,
    height: u32,
    frame_ms: u16,
    next: usize,
    out: PathBuf,
}

type Result<T> = std::result::Result<T, String>;

impl Writer {
    /// Opens the target for `frames` frames of `width × height`, `frame_ms` apart;
    /// `sixteen` writes 16-bit PNGs (not possible in a GIF).
    pub fn create(
        target: &Target,
        width: usize,
        height: usize,
        frames: usize,
        frame_ms: u16,
        sixteen: bool,
    ) -> Result<Writer> {
        let create = |p: &Path| {
            File::create(p)
                .map(BufWriter::new)
                .map_err(|e| format!("cannot write {}: {e}", p.display()))
        };
        let (sink, out) = match target {
            Target::Numbered { path, width } => {
                (Sink::Numbered(path.clone(), *width), path.clone())
            }
            Target::Gif(p) => {
                if sixteen {
                    return Err(format!(
                        "{}: a GIF holds 8-bit colour only; use .png (APNG) or numbered PNGs \
                         with 16 bits",
                        p.display()
                    ));
                }
                let mut enc = image::codecs::gif::GifEncoder::new_with_speed(create(p)?, 10);
                enc.set_repeat(image::codecs::gif::Repeat::Infinite)
                    .map_err(|e| format!("{}: {e}", p.display()))?;
                (Sink::Gif(enc), p.clone())
            }
            Target::Apng(p) => {
                let mut enc = png::Encoder::new(create(p)?, width as u32, height as u32);
                enc.set_color(png::ColorType::Rgb);
                enc.set_depth(if sixteen {
                    png::BitDepth::Sixteen
                } else {
                    png::BitDepth::Eight
                });
                let pe = |e: png::EncodingError| format!("{}: {e}", p.display());
                enc.set_animated(frames as u32, 0).map_err(pe)?;
                enc.set_frame_delay(frame_ms, 1000).map_err(pe)?;
                (Sink::Apng(enc.write_header().map_err(pe)?), p.clone())
            }
        };
        Ok(Writer {
            sink,
            width: width as u32,
            height: height as u32,
            frame_ms,
            next: 0,
            out,
        })
    }

    /// Adds the next frame.
    pub fn push(&mut self, frame: Pixels) -> Result<()> {
        let i = self.next;
        self.next += 1;
        let err =
            |p: &Path, e: &dyn std::fmt::Display| format!("cannot write {}: {e}", p.display());
        match &mut self.sink {
            Sink::Numbered(path, width) => {
                let p = numbered(path, *width, i);
                match frame {
                    Pixels::Rgb8(rgb) => image::save_buffer(
                        &p,
                        &rgb,
                        self.width,
                        self.height,
                        image::ExtendedColorType::Rgb8,
                    )
                    .map_err(|e| err(&p, &e)),
                    Pixels::Rgb16(rgb) => {
                        let rgba: Vec<[u16; 4]> = rgb
                            .chunks_exact(3)
                            .map(|c| [c[0], c[1], c[2], 65535])
                            .collect();
                        crate::png::save_png16(&p, self.width as usize, self.height as usize, &rgba)
                            .map_err(|e| err(&p, &e))
                    }
                }
            }
            Sink::Gif(enc) => {
                let Pixels::Rgb8(rgb) = frame else {
                    return Err(format!("{}: GIF frames are 8-bit", self.out.display()));
                };
                let rgba: Vec<u8> = rgb
                    .chunks_exact(3)
                    .flat_map(|c| [c[0], c[1], c[2], 255])
                    .collect();
                let img = image::RgbaImage::from_raw(self.width, self.height, rgba)
                    .ok_or_else(|| format!("{}: frame size mismatch", self.out.display()))?;
                let delay = image::Delay::from_numer_denom_ms(self.frame_ms as u32, 1);
                enc.encode_frame(image::Frame::from_parts(img, 0, 0, delay))
                    .map_err(|e| err(&self.out, &e))
            }
            Sink::Apng(w) => {
                let bytes: Vec<u8> = match frame {
                    Pixels::Rgb8(rgb) => rgb,
                    Pixels::Rgb16(rgb) => rgb.iter().flat_map(|v| v.to_be_bytes()).collect(),
                };
                w.write_image_data(&bytes).map_err(|e| err(&self.out, &e))
            }
        }
    }

    /// Finishes the file (APNG and GIF trailers).
    pub fn finish(self) -> Result<()> {
        match self.sink {
            Sink::Numbered(..) => Ok(()),
            Sink::Gif(enc) => {
                drop(enc);
                Ok(())
            }
            Sink::Apng(w) => w
                .finish()
                .map_err(|e| format!("cannot write {}: {e}", self.out.display())),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn targets_and_numbering() {
        assert_eq!(
            target(Path::new("d/f%03d.png")),
            Some(Target::Numbered {
                path: "d/f%03d.png".into(),
                width: 3
            })
        );
        assert_eq!(
            numbered(Path::new("d/f%03d.png"), 3, 7),
            PathBuf::from("d/f007.png")
        );
        assert_eq!(
            numbered(Path::new("f%d-x.png"), 0, 12),
            PathBuf::from("f12-x.png")
        );
        assert_eq!(
            target(Path::new("a.GIF")),
            Some(Target::Gif("a.GIF".into()))
        );
        assert_eq!(
            target(Path::new("a.png")),
            Some(Target::Apng("a.png".into()))
        );
        assert_eq!(target(Path::new("a.jpg")), None);
        assert_eq!(target(Path::new("a%x.jpg")), None);
    }
}
