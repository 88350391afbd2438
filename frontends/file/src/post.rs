//! Unclassified volumes held in memory for post-classified, pre-integrated and
//! isosurface rendering ([`shearwarp_core::postclass`]).

use crate::scene::{opacity_points, Cut, Look};
use crate::volume::{RawVolume, Voxels};
use shearwarp_core::classify::{self, Grid, OpacityTf, Scalars, Voxel};
use shearwarp_core::composite::{Intermediate, Rgba};
use shearwarp_core::opaque;
use shearwarp_core::postclass;
use shearwarp_core::shade::ShadeTable;
use shearwarp_core::view::{self, Camera};
use shearwarp_core::warp::{self, FrameBuffer};
use shearwarp_core::Error;
use std::sync::Mutex;

/// An unclassified volume for post-classified, pre-integrated and isosurface rendering:
/// quantised scalars and normals, plus min-max bricks. A transfer-function change needs
/// no re-encode.
pub struct DenseVolume {
    /// Geometry.
    pub grid: Grid,
    /// Raw value range of the quantised scalars.
    pub range: (u16, u16),
    voxels: Vec<Voxel>,
    bricks: Vec<(u8, u8)>,
}

impl DenseVolume {
    /// Quantises and computes normals and bricks.
    pub fn new(raw: &RawVolume) -> Result<Self, Error> {
        let grid = Grid::new(raw.dims, raw.spacing)?;
        let scalars = match &raw.voxels {
            Voxels::U8(d) => Scalars::U8(d),
            Voxels::U16(d) => Scalars::U16(d),
        };
        let table = vec![255u8; scalars.value_count()];
        let mut voxels = vec![Voxel::default(); grid.voxel_count()];
        classify::classify(&grid, scalars, &table, None, &mut voxels)?;
        let mut bricks = vec![(0u8, 0u8); postclass::brick_count(grid.dims)];
        postclass::build_bricks(&grid, &voxels, &mut bricks)?;
        Ok(DenseVolume {
            grid,
            range: scalars.range(),
            voxels,
            bricks,
        })
    }

    /// Converts a raw value to the quantised scale the renderer works in.
    pub fn quantize(&self, raw: f64) -> f64 {
        let (lo, hi) = (self.range.0 as f64, self.range.1 as f64);
        if hi > lo {
            ((raw - lo) * 255.0 / (hi - lo)).clamp(0.0, 255.0)
        } else {
            0.0
        }
    }
}

/// Workspace and tables for rendering a [`DenseVolume`], on one thread or several.
///
/// With several threads the intermediate image is cut into bands of [`BAND_ROWS`]
/// scanlines, which the threads take in turn as they finish one
/// ([`postclass::composite_band`]: every scanline depends on itself alone, so the image
/// is the same for any count); then strips of output rows are warped the same way.
/// Unlike the classified path's two long bands with work stealing
/// ([`crate::renderer::Renderer`]), the bands are short and taken from a queue: a band's
/// cost is its area less its empty bricks and opaque pixels, uneven across the image but
/// fine-grained enough that thirty-odd bands a frame balance two threads (1.90–2.03×
/// faster than one on the head and the hires brain, BENCHMARKS.md).
pub struct PostRenderer {
    pixels: Vec<Rgba>,
    links: Vec<opaque::Word>,
    visible: Vec<bool>,
    preint: Vec<Rgba>,
    shade: Box<ShadeTable>,
    out_row: Vec<[u8; 4]>,
    threads: usize,
}

/// Scanlines of a band that a thread composites at a time.
pub const BAND_ROWS: usize = 8;

impl PostRenderer {
    /// Allocates for `vol`, to render on the calling thread.
    pub fn new(vol: &DenseVolume) -> Self {
        Self::with_threads(vol, 1)
    }

    /// Allocates for `vol`, to render on `threads` threads (the calling one and
    /// `threads − 1` scoped ones a frame; at least one).
    pub fn with_threads(vol: &DenseVolume, threads: usize) -> Self {
        let pix = view::max_intermediate_pixels(vol.grid.dims);
        PostRenderer {
            pixels: vec![[0; 4]; pix],
            links: vec![0; pix],
            visible: vec![false; postclass::brick_count(vol.grid.dims)],
            preint: vec![[0; 4]; 65536],
            shade: Box::new(ShadeTable::UNSHADED),
            out_row: Vec::new(),
            threads: threads.max(1),
        }
    }

    /// Threads a frame renders on.
    pub fn threads(&self) -> usize {
        self.threads
    }

    /// Renders one frame; `opacity` is the opacity transfer function over raw values,
    /// and `cut` what is cut away of the volume.
    pub fn render(
        &mut self,
        vol: &DenseVolume,
        mode: postclass::PostMode,
        opacity: &[(f64, f64)],
        look: &Look,
        camera: &Camera,
        cut: Cut,
    ) -> Result<Vec<[u8; 4]>, Error> {
        let pts = opacity_points(opacity);
        let op = OpacityTf::new(&pts)?.build_quantized(vol.range);
        let mut frame = vec![[0u8; 4]; camera.width * camera.height];
        let settings = postclass::PostSettings {
            mode,
            opacity: &op,
            color: &look.color,
            lighting: look.lighting.as_ref(),
            ert_threshold: look.ert_threshold,
            crop: cut.crop,
            clip: cut.clip,
        };
        if self.threads == 1 {
            if self.out_row.len() < camera.width {
                self.out_row.resize(camera.width, [0; 4]);
            }
            let mut ws = postclass::PostWorkspace {
                pixels: &mut self.pixels,
                links: &mut self.links,
                visible: &mut self.visible,
                preint: &mut self.preint,
                shade: &mut self.shade,
                out_row: &mut self.out_row,
            };
            let mut sink = FrameBuffer {
                width: camera.width,
                pixels: &mut frame,
            };
            postclass::render(
                &vol.grid,
                &vol.voxels,
                &vol.bricks,
                camera,
                &settings,
                &mut ws,
                &mut sink,
            )?;
            return Ok(frame);
        }
        let tables = postclass::PostTables {
            visible: &mut self.visible,
            preint: &mut self.preint,
            shade: &mut self.shade,
        };
        let post = postclass::prepare(&vol.grid, &vol.bricks, camera, &settings, tables)?;
        let [iw, ih] = post.view.intermediate;
        let stride = opaque::words(iw);
        let (n, words) = (iw * ih, stride * ih);
        // Sized for any view of this volume in `with_threads`; checked before slicing.
        for (what, needed, got) in [
            ("intermediate pixels", n, self.pixels.len()),
            ("intermediate links", words, self.links.len()),
        ] {
            if got < needed {
                return Err(Error::BufferTooSmall { what, needed, got });
            }
        }
        let bands = self.pixels[..n]
            .chunks_mut(BAND_ROWS * iw.max(1))
            .zip(self.links[..words].chunks_mut(BAND_ROWS * stride.max(1)))
            .enumerate()
            .map(|(b, (p, l))| (b * BAND_ROWS, p, l));
        let bands = Mutex::new(bands);
        let composite = || -> Result<(), Error> {
            loop {
                let next = bands.lock().map_err(|_| POISONED)?.next();
                let Some((row0, p, l)) = next else {
                    return Ok(());
                };
                let rows = BAND_ROWS.min(ih - row0);
                let mut img = Intermediate::band(iw, ih, row0, rows, p, l)?;
                postclass::composite_band(&post, &vol.voxels, &mut img)?;
            }
        };
        on_scoped_threads(self.threads, composite)?;
        // Strips of output rows, each warped in place (its own row buffer).
        let w = camera.width;
        if w == 0 {
            return Ok(frame);
        }
        let pixels = &self.pixels[..n];
        let strips = Mutex::new(frame.chunks_mut(warp::TILE_ROWS * w).enumerate());
        let warp = || -> Result<(), Error> {
            loop {
                let next = strips.lock().map_err(|_| POISONED)?.next();
                let Some((i, strip)) = next else {
                    return Ok(());
                };
                let rows = i * warp::TILE_ROWS..i * warp::TILE_ROWS + strip.len() / w;
                warp::warp_rows(pixels, None, &post.view, rows, strip, &mut warp::InPlace)?;
            }
        };
        on_scoped_threads(self.threads, warp)?;
        Ok(frame)
    }
}

/// The error of a band or strip queue whose lock a panicking thread poisoned.
const POISONED: Error = Error::Source {
    reason: "a post-classification thread panicked",
};

/// Runs `work` on the calling thread and on `threads − 1` scoped threads; returns the
/// first error.
fn on_scoped_threads(
    threads: usize,
    work: impl Fn() -> Result<(), Error> + Sync,
) -> Result<(), Error> {
    std::thread::scope(|s| {
        let others: Vec<_> = (1..threads).map(|_| s.spawn(&work)).collect();
        let mine = work();
        others
            .into_iter()
            .map(|h| h.join().unwrap_or(Err(POISONED)))
            .fold(mine, |acc, r| acc.and(r))
    })
}
