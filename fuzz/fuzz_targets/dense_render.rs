//! Unclassified volumes through the core's dense paths: classification with a gradient
//! opacity table, min-max bricks, post-classified, pre-integrated and isosurface frames
//! (`postclass::render`), and the same frames from the level of detail above
//! (`lod::downsample`).
//!
//! The input decides everything the caller of these functions controls: the volume's
//! sides (1 to 12) and spacing (any `f64` bits, some of the time), 8- or 16-bit voxels,
//! the Q15 opacity and colour tables (any `u16`, so also above one), the lighting (any
//! coefficients, which `Lighting::validate` must refuse or the frame must survive), the
//! view's angles (any `f64` bits, some of the time), the image size, the mode, the
//! isovalue, the early-termination threshold, a crop box and clipping planes. Errors are fine; panics, overflows
//! (the targets build with overflow checks) and a colour above its alpha are not, nor
//! bands of scanlines (`postclass::composite_band`, as the threads composite them) that
//! differ from the whole intermediate image.
#![no_main]

use libfuzzer_sys::fuzz_target;
use shearwarp_core::classify::{self, Grid, Scalars, Voxel};
use shearwarp_core::clip::Clip;
use shearwarp_core::composite::{Intermediate, Rgba};
use shearwarp_core::crop::Crop;
use shearwarp_core::postclass::{self, PostMode, PostSettings, PostTables, PostWorkspace};
use shearwarp_core::shade::{Light, Lighting, ShadeTable};
use shearwarp_core::view::{self, Camera};
use shearwarp_core::warp::FrameBuffer;
use shearwarp_core::{lod, opaque};

/// Largest side of a fuzzed volume, and of its image.
const SIDE: usize = 12;

/// Reads the input front to back; past its end every read gives zeros.
struct Bytes<'a>(&'a [u8]);

impl Bytes<'_> {
    fn u8(&mut self) -> u8 {
        let (&b, rest) = self.0.split_first().unwrap_or((&0, &[]));
        self.0 = rest;
        b
    }
    fn u16(&mut self) -> u16 {
        u16::from_le_bytes([self.u8(), self.u8()])
    }
    fn u64(&mut self) -> u64 {
        (0..8).fold(0, |v, i| v | (self.u8() as u64) << (8 * i))
    }
    /// A side length in `1..=SIDE`.
    fn side(&mut self) -> usize {
        1 + self.u8() as usize % SIDE
    }
    /// Mostly a tame value from `tame`, sometimes any `f64` at all.
    fn f64_or(&mut self, tame: impl FnOnce(u8) -> f64) -> f64 {
        let b = self.u8();
        if b >= 0xf0 {
            f64::from_bits(self.u64())
        } else {
            tame(b)
        }
    }
}

fn lighting(b: &mut Bytes<'_>) -> Option<Lighting> {
    let n = b.u8() % 4;
    if n == 0 {
        return None;
    }
    let mut l = Lighting {
        ka: b.f64_or(|x| x as f64 / 64.0),
        kd: b.f64_or(|x| x as f64 / 64.0),
        ks: b.f64_or(|x| x as f64 / 64.0),
        shininess: b.f64_or(|x| x as f64),
        ..Lighting::default()
    };
    l.lights.clear();
    for _ in 0..n {
        let mut axis = || b.f64_or(|x| x as f64 - 120.0);
        let direction = [axis(), axis(), axis()];
        let color = [0; 3].map(|_| b.u8() as f64 / 255.0);
        let _ = l.lights.push(Light { direction, color });
    }
    Some(l)
}

fuzz_target!(|data: &[u8]| {
    let mut b = Bytes(data);
    let dims = [b.side(), b.side(), b.side()];
    let spacing = [0; 3].map(|_| b.f64_or(|x| 0.25 + (x % 16) as f64 / 4.0));
    let Ok(grid) = Grid::new(dims, spacing) else {
        return;
    };
    let wide = b.u8() & 1 == 1;
    let gradient = b.u8() & 1 == 1;
    let mut opacity = [0u16; 256];
    let mut color = [[0u16; 3]; 256];
    for v in 0..256 {
        opacity[v] = b.u16();
        color[v] = [b.u16(), b.u16(), b.u16()];
    }
    let look = lighting(&mut b);
    let camera = Camera {
        rotate_x: b.f64_or(|x| x as f64 * 3.0),
        rotate_y: b.f64_or(|x| x as f64 * 3.0),
        width: b.side(),
        height: b.side(),
    };
    let mode = match b.u8() % 3 {
        0 => PostMode::PostClassified,
        1 => PostMode::PreIntegrated,
        _ => PostMode::Isosurface(b.f64_or(|x| x as f64 + 0.5)),
    };
    let ert_threshold = b.f64_or(|x| x as f64 / 255.0);
    // A crop box of any bounds, kept when this volume accepts it (the level below gets
    // the same box, which may then lie outside it).
    let (lo, hi) = ([b.u8(), b.u8(), b.u8()], [b.u8(), b.u8(), b.u8()]);
    let crop = Crop::new(lo.map(usize::from), hi.map(usize::from), dims).ok();
    // Up to three clipping planes of any normal and distance, each kept when this grid
    // accepts it (the level below gets the same planes, made for this grid).
    let mut clip = Clip::NONE;
    for _ in 0..b.u8() % 4 {
        let tame = |b: &mut Bytes<'_>| b.f64_or(|x| x as f64 / 16.0 - 8.0);
        let normal = [tame(&mut b), tame(&mut b), tame(&mut b)];
        clip = clip.with_plane(&grid, normal, tame(&mut b)).unwrap_or(clip);
    }
    if b.u8() & 1 == 1 {
        clip = clip.inverted();
    }
    // A layer along the cut lit as its face, of any thickness (refused outside 0..=16).
    clip = clip
        .with_shaded_face(b.f64_or(|x| x as f64 / 8.0))
        .unwrap_or(clip);
    // The voxels: what is left of the input, repeated.
    let rest = if b.0.is_empty() { &[0u8][..] } else { b.0 };
    let n = grid.voxel_count();
    let bytes = rest.iter().copied().cycle();
    let (d8, d16): (Vec<u8>, Vec<u16>) = if wide {
        let v: Vec<u8> = bytes.take(2 * n).collect();
        (
            Vec::new(),
            v.chunks(2)
                .map(|c| u16::from_le_bytes([c[0], c[1]]))
                .collect(),
        )
    } else {
        (bytes.take(n).collect(), Vec::new())
    };
    let scalars = if wide {
        Scalars::U16(&d16)
    } else {
        Scalars::U8(&d8)
    };
    let settings = PostSettings {
        mode,
        opacity: &opacity,
        color: &color,
        lighting: look.as_ref(),
        ert_threshold,
        crop,
        clip,
    };
    frame(&grid, scalars, gradient, &camera, &settings);
    // The level above, drawn with the same settings.
    let count = {
        let m = lod::level_dims(dims);
        m[0] * m[1] * m[2]
    };
    let level = if wide {
        let (mut mean, mut lo, mut hi) = (vec![0u16; count], vec![0u16; count], vec![0u16; count]);
        lod::downsample(&d16, &grid, &mut mean, &mut lo, &mut hi).map(|g| (g, Vec::new(), mean))
    } else {
        let (mut mean, mut lo, mut hi) = (vec![0u8; count], vec![0u8; count], vec![0u8; count]);
        lod::downsample(&d8, &grid, &mut mean, &mut lo, &mut hi).map(|g| (g, mean, Vec::new()))
    };
    if let Ok((g, m8, m16)) = level {
        let s = if wide {
            Scalars::U16(&m16)
        } else {
            Scalars::U8(&m8)
        };
        frame(&g, s, gradient, &camera, &settings);
    }
});

/// Classifies `scalars` as the file frontend's dense volumes do and renders one frame;
/// a frame that renders must keep every colour at or below its alpha.
fn frame(
    grid: &Grid,
    scalars: Scalars<'_>,
    gradient: bool,
    camera: &Camera,
    settings: &PostSettings<'_>,
) {
    let table = vec![255u8; scalars.value_count()];
    // A gradient opacity table of every other entry, to reach the magnitude path.
    let gradient_table: [u16; 256] = core::array::from_fn(|i| (i as u16 & 1) << 15);
    let mut voxels = vec![Voxel::default(); grid.voxel_count()];
    let gt = gradient.then_some(&gradient_table);
    if classify::classify(grid, scalars, &table, gt, &mut voxels).is_err() {
        return;
    }
    if let Some(c) = &settings.crop {
        // The classified path's crop, on the same records (a box of the level above
        // may not fit this volume).
        let _ = c.apply(grid, 0..grid.dims[2], &mut voxels);
    }
    let _ = settings.clip.apply(grid, 0..grid.dims[2], &mut voxels);
    let mut bricks = vec![(0u8, 0u8); postclass::brick_count(grid.dims)];
    if postclass::build_bricks(grid, &voxels, &mut bricks).is_err() {
        return;
    }
    let pix = view::max_intermediate_pixels(grid.dims);
    let mut pixels: Vec<Rgba> = vec![[0; 4]; pix];
    let mut links: Vec<opaque::Word> = vec![0; pix];
    let mut visible = vec![false; bricks.len()];
    let mut preint: Vec<Rgba> = vec![[0; 4]; 65536];
    let mut shade = Box::new(ShadeTable::UNSHADED);
    let mut out_row = vec![[0u8; 4]; camera.width];
    let mut image = vec![[0u8; 4]; camera.width * camera.height];
    let mut ws = PostWorkspace {
        pixels: &mut pixels,
        links: &mut links,
        visible: &mut visible,
        preint: &mut preint,
        shade: &mut shade,
        out_row: &mut out_row,
    };
    let mut sink = FrameBuffer {
        width: camera.width,
        pixels: &mut image,
    };
    let ok = postclass::render(grid, &voxels, &bricks, camera, settings, &mut ws, &mut sink);
    if ok.is_err() {
        return;
    }
    for p in &image {
        assert!(p[0] <= p[3] && p[1] <= p[3] && p[2] <= p[3], "{p:?}");
    }
    // The same frame composited in bands of 1, 2, 3, ... scanlines must give the
    // intermediate image the whole composite gives.
    let tables = PostTables {
        visible: &mut visible,
        preint: &mut preint,
        shade: &mut shade,
    };
    let frame = postclass::prepare(grid, &bricks, camera, settings, tables).expect("prepared");
    let [iw, ih] = frame.view.intermediate;
    let stride = opaque::words(iw);
    let mut whole: Vec<Rgba> = vec![[0; 4]; iw * ih];
    let mut whole_links: Vec<opaque::Word> = vec![0; stride * ih];
    let mut img = Intermediate::new(iw, ih, &mut whole, &mut whole_links).expect("whole");
    postclass::composite_band(&frame, &voxels, &mut img).expect("whole composite");
    let (mut row0, mut rows) = (0, 1);
    while row0 < ih {
        let take = rows.min(ih - row0);
        let mut p: Vec<Rgba> = vec![[0; 4]; iw * take];
        let mut l: Vec<opaque::Word> = vec![0; stride * take];
        let mut band = Intermediate::band(iw, ih, row0, take, &mut p, &mut l).expect("band");
        postclass::composite_band(&frame, &voxels, &mut band).expect("band composite");
        assert!(
            p[..] == whole[row0 * iw..(row0 + take) * iw],
            "band {row0}+{take} differs"
        );
        row0 += take;
        rows += 1;
    }
}
