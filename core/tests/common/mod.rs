//! Helpers shared by the integration tests: a small encoded volume, its `.swv` bytes,
//! checksum repair for hand-corrupted files, and a one-frame render of a stream.
#![allow(dead_code)]

use shearwarp_core::classify::{self, ColorTable, Grid, OpacityTf, Scalars, Voxel};
use shearwarp_core::io::{Crc32, IoError, SliceReader};
use shearwarp_core::render::{render, StaticWorkspace};
use shearwarp_core::rle::{self, Axis, RleAxis, ScanIndex};
use shearwarp_core::shade::Lighting;
use shearwarp_core::source::RleVolume;
use shearwarp_core::swv::{self, StreamSource, ENTRY_LEN, HEADER_LEN, TABLES_START};
use shearwarp_core::view::{self, Camera};
use shearwarp_core::warp::FrameBuffer;
use shearwarp_core::Error;

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
                RleAxis::new(self.grid.dims, axis, r, v, s).unwrap()
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

fn u32_at(b: &[u8], o: usize) -> Option<u32> {
    Some(u32::from_le_bytes(b.get(o..o + 4)?.try_into().ok()?))
}

fn put_u32(b: &mut [u8], o: usize, v: u32) {
    if let Some(d) = b.get_mut(o..o + 4) {
        d.copy_from_slice(&v.to_le_bytes());
    }
}

/// Offset of the slice-table entry `e` (x-axis entries first, then y, then z).
pub fn entry_at(e: usize) -> usize {
    TABLES_START + ENTRY_LEN * e
}

/// Recomputes every checksum the bytes allow (slice records whose entry points inside
/// the file, the tables, the header), so that only the structural change is tested.
/// The same repair the `swv_render` fuzz target applies.
pub fn fix_checksums(b: &mut [u8]) {
    if b.len() < HEADER_LEN {
        return;
    }
    let dims: [usize; 3] = [12, 16, 20].map(|o| u32_at(b, o).unwrap_or(0) as usize);
    if dims.iter().all(|&d| (1..=4096).contains(&d)) {
        let n = dims[0] + dims[1] + dims[2];
        let tables_end = TABLES_START + ENTRY_LEN * n;
        if tables_end <= b.len() {
            let nj_of = |e: usize| {
                if e < dims[0] {
                    dims[2]
                } else if e < dims[0] + dims[1] {
                    dims[0]
                } else {
                    dims[1]
                }
            };
            for e in 0..n {
                let o = entry_at(e);
                let (Some(lo), Some(hi), Some(runs), Some(vox)) = (
                    u32_at(b, o),
                    u32_at(b, o + 4),
                    u32_at(b, o + 8),
                    u32_at(b, o + 12),
                ) else {
                    continue;
                };
                let off = lo as u64 | (hi as u64) << 32;
                let len = 8 * (nj_of(e) as u64 + 1) + runs as u64 + 4 * vox as u64;
                if off
                    .checked_add(len)
                    .is_some_and(|end| end <= b.len() as u64)
                {
                    let c = Crc32::of(&b[off as usize..(off + len) as usize]);
                    put_u32(b, o + 16, c);
                }
            }
            let t = Crc32::of(&b[HEADER_LEN..tables_end]);
            put_u32(b, 56, t);
        }
    }
    let h = Crc32::of(&b[..60]);
    put_u32(b, 60, h);
}

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
