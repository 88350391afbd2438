//! Helpers shared by the integration tests: a small encoded volume, its `.swv` bytes,
//! checksum repair for hand-corrupted files, and a one-frame render of a stream.
#![allow(dead_code)]

use shearwarp_core::classify::{self, ColorTable, Grid, OpacityTf, Scalars, Voxel};
use shearwarp_core::io::{IoError, SliceReader};
use shearwarp_core::render::{render, StaticWorkspace};
use shearwarp_core::rle::{self, Axis, RleAxis, ScanIndex};
use shearwarp_core::shade::Lighting;
use shearwarp_core::source::RleVolume;
use shearwarp_core::swv::{self, StreamSource};
use shearwarp_core::view::{self, Camera};
use shearwarp_core::warp::FrameBuffer;
use shearwarp_core::Error;

// The checksum repair, shared with the fuzz targets (`fuzz/src/lib.rs` includes the
// same file).
mod swv_crc;

/// Dimensions of [`sphere`].
pub const DIMS: [usize; 3] = [9, 7, 5];
/// Buffers for volumes up to 16 per side.
pub const SIDE: usize = 16;
pub const CAP: (usize, usize, usize) = swv::worst_case_capacity([SIDE; 3]);
pub const PIX: usize = view::max_intermediate_pixels([SIDE; 3]);
pub const ROW: usize = shearwarp_core::composite::row_buffer_len(SIDE);
pub const IMG: usize = 16;
pub type Src<'a> = StreamSource<SliceReader<'a>, { CAP.0 }, { CAP.1 }, { CAP.2 }>;

pub struct VecWriter(pub Vec<u8>);

impl swv::Write for VecWriter {
    fn write_all(&mut self, buf: &[u8]) -> Result<(), IoError> {
        self.0.extend_from_slice(buf);
        Ok(())
    }
}

/// A classified ball in a `DIMS` box, encoded along the three axes.
pub struct Encoded {
    pub grid: Grid,
    pub axes: Vec<(Vec<u8>, Vec<Voxel>, Vec<ScanIndex>)>,
}

impl Encoded {
    pub fn volume(&self) -> RleVolume<'_> {
        let a: Vec<RleAxis<'_>> = Axis::ALL
            .iter()
            .map(|&axis| {
                let (r, v, s) = &self.axes[axis as usize];
                RleAxis::new(&self.grid, axis, r, v, s).unwrap()
            })
            .collect();
        RleVolume::new(self.grid, [a[0], a[1], a[2]]).unwrap()
    }
}

pub fn sphere() -> Encoded {
    let grid = Grid::new(DIMS, [1.0, 1.5, 2.0]).unwrap();
    let mut data = Vec::new();
    for z in 0..DIMS[2] as i32 {
        for y in 0..DIMS[1] as i32 {
            for x in 0..DIMS[0] as i32 {
                let d = (x - 4).pow(2) + (y - 3).pow(2) + 2 * (z - 2).pow(2);
                data.push((255 - 20 * d).clamp(0, 255) as u8);
            }
        }
    }
    let pts = [(60.0, [0.0]), (200.0, [0.9])];
    let mut table = [0u8; 256];
    OpacityTf::new(&pts).unwrap().build_table(&mut table);
    let mut dense = vec![Voxel::default(); grid.voxel_count()];
    classify::classify(&grid, Scalars::U8(&data), &table, None, &mut dense).unwrap();
    let axes = Axis::ALL
        .iter()
        .map(|&axis| {
            let sz = rle::measure(&dense, &grid, axis, 0).unwrap();
            let mut r = vec![0u8; sz.runs];
            let mut v = vec![Voxel::default(); sz.voxels];
            let mut s = vec![ScanIndex::default(); sz.scans];
            rle::encode(&dense, &grid, axis, 0, &mut r, &mut v, &mut s).unwrap();
            (r, v, s)
        })
        .collect();
    Encoded { grid, axes }
}

pub fn color() -> ColorTable {
    core::array::from_fn(|q| [(q as u16) << 7, 16384, 32768 - ((q as u16) << 7)])
}

/// The `.swv` bytes of [`sphere`], shaded.
pub fn swv_bytes() -> Vec<u8> {
    let enc = sphere();
    let look = swv::Look {
        color: color(),
        lighting: Some(Lighting::default()),
    };
    let mut w = VecWriter(Vec::new());
    swv::write(&mut w, &enc.volume(), (0, 255), 0, &look).unwrap();
    w.0
}

// Not every test file uses them (each includes this module).
#[allow(unused_imports)]
pub use swv_crc::{entry_at, fix_checksums};

/// Opens `bytes` and renders one frame per principal axis with the file's look; the
/// first error, if any. What the `swv_render` fuzz target does, minus the variations.
pub fn open_and_render(bytes: &[u8]) -> Result<Vec<[u8; 4]>, Error> {
    let mut src = Src::open(SliceReader::new(bytes))?;
    let look = src.header().look.clone();
    let mut ws = Box::new(StaticWorkspace::<PIX, ROW, IMG>::new());
    let mut px = vec![[0u8; 4]; IMG * IMG];
    // Principal x, y, z (for moderate spacings), then an oblique view.
    for (rx, ry) in [(5.0, 85.0), (85.0, 5.0), (5.0, 5.0), (25.0, -40.0)] {
        let settings = look.settings();
        let cam = Camera {
            rotate_x: rx,
            rotate_y: ry,
            width: IMG,
            height: IMG,
        };
        let mut sink = FrameBuffer {
            width: IMG,
            pixels: &mut px,
        };
        render(&mut src, &cam, &settings, &mut ws.workspace(), &mut sink)?;
    }
    Ok(px)
}
