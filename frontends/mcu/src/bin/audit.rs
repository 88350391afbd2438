//! A firmware that is built and never run: it calls every entry point of the core with
//! arguments the compiler cannot see (each passes through `black_box`), so that every
//! code path of the core is linked, and links with the same panic handler as the
//! renderer firmware: a function defined nowhere. It links only if no code path of the
//! core can panic, whatever the input.
//!
//! The renderer firmware (`src/main.rs`) covers what a device runs: the `.swv` stream,
//! compositing and the warp. This adds classification, gradients and normals, run-length
//! encoding, crop boxes, clipping planes, the `.swv` writer, post-classified, pre-integrated and
//! isosurface rendering, the level-of-detail pyramid, perspective and supersampled
//! frames.
#![no_std]
#![no_main]

use core::hint::black_box;
use cortex_m_rt::entry;
use shearwarp_core::classify::{
    self, ColorTable, ColorTf, GradientTf, Grid, OpacityTf, Scalars, Voxel,
};
use shearwarp_core::clip::Clip;
use shearwarp_core::composite::Intermediate;
use shearwarp_core::composite::{Mode, Rgba};
use shearwarp_core::crop::Crop;
use shearwarp_core::depth::DepthCue;
use shearwarp_core::io::IoError;
use shearwarp_core::postclass::{self, PostMode, PostSettings, PostWorkspace};
use shearwarp_core::render::{self, Frame, Settings, ShadowWorkspace, Workspace};
use shearwarp_core::rle::{self, Axis, RleAxis, ScanIndex};
use shearwarp_core::shade::{Lighting, ShadeTable};
use shearwarp_core::source::RleVolume;
use shearwarp_core::swv::{self, Look, Write};
use shearwarp_core::view::Camera;
use shearwarp_core::warp::{self, PixelSink};
use shearwarp_core::{lod, normal, Error};

#[path = "../no_panic.rs"]
mod no_panic;

/// Every buffer's capacity (the lengths the core sees are hidden from the compiler).
const N: usize = 4096;

/// A slice of `buf` of a length the compiler cannot know.
fn some<T>(buf: &mut [T]) -> &mut [T] {
    let n = black_box(buf.len());
    match buf.get_mut(..n) {
        Some(b) => b,
        None => &mut [],
    }
}

/// Rows go nowhere (but the compiler cannot tell).
struct Sink;

impl PixelSink for Sink {
    fn put_row(&mut self, y: usize, row: &[[u8; 4]]) -> Result<(), Error> {
        black_box((y, row));
        Ok(())
    }
}

/// Bytes go nowhere.
struct Bytes;

impl Write for Bytes {
    fn write_all(&mut self, buf: &[u8]) -> Result<(), IoError> {
        black_box(buf);
        Ok(())
    }
}

fn camera() -> Camera {
    black_box(Camera {
        rotate_x: 0.0,
        rotate_y: 0.0,
        width: 0,
        height: 0,
    })
}

fn lighting() -> Lighting {
    black_box(Lighting::default())
}

fn run() -> Result<(), Error> {
    let grid = Grid::new(black_box([0; 3]), black_box([1.0; 3]))?;
    let mut scalars8 = [0u8; N];
    let mut scalars16 = [0u16; N];
    let scalars = if black_box(true) {
        Scalars::U8(some(&mut scalars8))
    } else {
        Scalars::U16(some(&mut scalars16))
    };
    let range = scalars.range();

    // Transfer functions.
    let mut points1 = [(0.0, [0.0]); 8];
    let mut points3 = [(0.0, [0.0; 3]); 8];
    let opacity = OpacityTf::new(some(&mut points1))?;
    let mut table = [0u8; 256];
    opacity.build_table(some(&mut table));
    let quantized = opacity.build_quantized(range);
    let color: ColorTable = ColorTf::new(some(&mut points3))?.build_table(range);
    let gradient = GradientTf::new(some(&mut points1))?.build_table();
    let gradient = black_box(true).then_some(&gradient);
    black_box(classify::opacity_correction(black_box(1.0)));
    black_box(classify::color_lanes(&color));

    // Classification and normals.
    let mut dense = [Voxel::default(); N];
    let threshold = black_box(Some(0));
    let slices = black_box(0..0);
    classify::classify_slices(
        &grid,
        scalars,
        &table,
        gradient,
        threshold,
        slices,
        some(&mut dense),
    )?;
    // A crop box over the classified records, and on a coarser level.
    let crop = Crop::new(
        black_box([0, 0, 0]),
        black_box([1, 1, 1]),
        black_box(grid.dims),
    )?;
    crop.apply(&grid, black_box(0..0), some(&mut dense))?;
    black_box(crop.at_level(grid.dims, black_box([1, 1, 1]), black_box(2)));
    black_box(crop.contains(black_box([0, 0, 0])));
    // Clipping planes over the same records.
    let clip = Clip::NONE.with_plane(&grid, black_box([1.0, 0.5, 0.0]), black_box(0.5))?;
    let clip = clip.with_shaded_face(black_box(2.0))?;
    let clip = if black_box(true) {
        clip.inverted()
    } else {
        clip
    };
    clip.apply(&grid, black_box(0..0), some(&mut dense))?;
    black_box(normal::decode(normal::encode(
        black_box(1),
        black_box(2),
        black_box(3),
    )));

    // Run-length encoding, all three axes.
    let dense = some(&mut dense);
    let th = black_box(0);
    let (mut rx, mut ry, mut rz) = ([0u8; N], [0u8; N], [0u8; N]);
    let (mut vx, mut vy, mut vz) = (
        [Voxel::default(); N],
        [Voxel::default(); N],
        [Voxel::default(); N],
    );
    let mut sx = [ScanIndex::default(); N];
    let mut sy = [ScanIndex::default(); N];
    let mut sz = [ScanIndex::default(); N];
    let x = rle::encode(
        dense,
        &grid,
        Axis::X,
        th,
        some(&mut rx),
        some(&mut vx),
        some(&mut sx),
    )?;
    let y = rle::encode(
        dense,
        &grid,
        Axis::Y,
        th,
        some(&mut ry),
        some(&mut vy),
        some(&mut sy),
    )?;
    let z = rle::encode(
        dense,
        &grid,
        Axis::Z,
        th,
        some(&mut rz),
        some(&mut vz),
        some(&mut sz),
    )?;
    let z = RleAxis::new(&grid, Axis::Z, z.parts().0, z.parts().1, z.parts().2)?;
    black_box(rle::measure(dense, &grid, Axis::Y, th)?);
    let mut decoded = [Voxel::default(); N];
    y.decode(some(&mut decoded))?;
    // The streaming encoder, a slice at a time.
    let (mut re, mut ve, mut se) = ([0u8; N], [Voxel::default(); N], [ScanIndex::default(); N]);
    let mut enc = rle::Encoder::new(
        &grid,
        Axis::Z,
        th,
        some(&mut re),
        some(&mut ve),
        some(&mut se),
    )?;
    enc.push_slice(some(&mut decoded))?;
    black_box(enc.finish()?);
    let mut vol = RleVolume::new(grid, [x, y, z])?;

    // The .swv writer.
    let look = Look {
        color,
        lighting: black_box(true).then(lighting),
    };
    swv::write(&mut Bytes, &vol, range, th, &look)?;

    // Pre-classified rendering: parallel (shadows, depth cue, MIP), supersampled,
    // perspective.
    let light = lighting();
    let settings = Settings {
        mode: if black_box(true) {
            Mode::Composite
        } else {
            Mode::Mip
        },
        color: &color,
        lighting: black_box(true).then_some(&light),
        ert_threshold: black_box(0.95),
        depth_cue: black_box(Some(DepthCue {
            front: 1.0,
            density: 1.0,
        })),
        shadows: black_box(true),
        flat_voxels: Default::default(),
        clip: black_box(clip),
    };
    let mut pixels = [[0u16; 4]; N];
    let mut links = [0; N];
    let mut rows: [Rgba; N] = [[0; 4]; N];
    let mut out_row = [[0u8; 4]; N];
    let mut shade = ShadeTable::UNSHADED;
    let mut shade0 = ShadeTable::UNSHADED;
    let mut alpha = [0u16; N];
    let mut alpha_rows = [0u16; N];
    let mut ws = Workspace {
        pixels: some(&mut pixels),
        links: some(&mut links),
        rows: some(&mut rows),
        out_row: some(&mut out_row),
        shade: &mut shade,
        shadow: black_box(true).then_some(ShadowWorkspace {
            alpha: some(&mut alpha),
            rows: some(&mut alpha_rows),
            shade0: &mut shade0,
        }),
    };
    render::render(&mut vol, &camera(), &settings, &mut ws, &mut Sink)?;
    let s = black_box(2);
    let frame = Frame::supersampled(&grid, &camera(), &settings, ws.shade, None, s)?;
    render::render_frame(&mut vol, &frame, &mut ws, &mut Sink)?;
    let frame = Frame::perspective(&grid, &camera(), black_box(60.0), &settings, ws.shade)?;
    render::render_frame(&mut vol, &frame, &mut ws, &mut Sink)?;

    // A band at a time, as the threaded frontends composite, then the warp's parts.
    let frame = Frame::new(&grid, &camera(), &settings, ws.shade, None)?;
    let tables = frame.tables(ws.shade, None);
    let [iw, ih] = frame.view.intermediate;
    let (row0, rows_held) = black_box((0, ih));
    let mut img = Intermediate::band(iw, ih, row0, rows_held, some(ws.pixels), some(ws.links))?;
    render::composite_band(&mut vol, &frame, &tables, &mut img, some(ws.rows), None)?;
    let mut extents = [[0u32; 2]; N];
    warp::extents(img.pixels(), iw, some(&mut extents))?;
    let span = black_box(0..0);
    let ext = black_box(true).then_some(&extents[..]);
    warp::warp_rows(
        img.pixels(),
        ext,
        &frame.view,
        span.clone(),
        some(ws.out_row),
        &mut Sink,
    )?;
    let mut q15 = [[0u16; 4]; N];
    let put = |y: usize, r: &[[u16; 4]]| -> Result<(), Error> {
        black_box((y, r));
        Ok(())
    };
    warp::warp_rows_q15(img.pixels(), ext, &frame.view, span, some(&mut q15), put)?;

    // Post-classified, pre-integrated and isosurface rendering.
    let mut bricks = [(0u8, 0u8); N];
    postclass::build_bricks(&grid, dense, some(&mut bricks))?;
    let mut preint: [Rgba; N] = [[0; 4]; N];
    postclass::build_preintegration(&quantized, &color, black_box(1.0), some(&mut preint))?;
    let mut visible = [false; N];
    let post = PostSettings {
        mode: match black_box(0) {
            0 => PostMode::PostClassified,
            1 => PostMode::PreIntegrated,
            _ => PostMode::Isosurface(black_box(9.5)),
        },
        opacity: &quantized,
        color: &color,
        lighting: black_box(true).then_some(&light),
        ert_threshold: black_box(0.95),
        crop: black_box(Some(crop)),
        clip: black_box(clip),
    };
    let mut pws = PostWorkspace {
        pixels: some(&mut pixels),
        links: some(&mut links),
        visible: some(&mut visible),
        preint: some(&mut preint),
        shade: &mut shade,
        out_row: some(&mut out_row),
    };
    postclass::render(
        &grid,
        dense,
        some(&mut bricks),
        &camera(),
        &post,
        &mut pws,
        &mut Sink,
    )?;

    // The level-of-detail pyramid, both sample types.
    let [mut mean, mut min, mut max] = [[0u8; N]; 3];
    let g = lod::downsample(
        some(&mut scalars8),
        &grid,
        some(&mut mean),
        some(&mut min),
        some(&mut max),
    )?;
    let [mut mean, mut min, mut max] = [[0u16; N]; 3];
    lod::downsample(
        some(&mut scalars16),
        &g,
        some(&mut mean),
        some(&mut min),
        some(&mut max),
    )?;
    Ok(())
}

#[entry]
fn main() -> ! {
    let _ = black_box(run());
    loop {
        cortex_m::asm::wfi();
    }
}
