//! Unclassified volumes held in memory for post-classified, pre-integrated and
//! isosurface rendering ([`shearwarp_core::postclass`]).

use crate::scene::{opacity_points, Look};
use crate::volume::{RawVolume, Voxels};
use shearwarp_core::classify::{self, Grid, OpacityTf, Scalars, Voxel};
use shearwarp_core::composite::Rgba;
use shearwarp_core::opaque;
use shearwarp_core::postclass;
use shearwarp_core::shade::ShadeTable;
use shearwarp_core::view::{self, Camera};
use shearwarp_core::warp::FrameBuffer;
use shearwarp_core::Error;

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

/// Workspace and tables for rendering a [`DenseVolume`].
pub struct PostRenderer {
    pixels: Vec<Rgba>,
    links: Vec<opaque::Word>,
    visible: Vec<bool>,
    preint: Vec<Rgba>,
    shade: Box<ShadeTable>,
    out_row: Vec<[u8; 4]>,
}

impl PostRenderer {
    /// Allocates for `vol`.
    pub fn new(vol: &DenseVolume) -> Self {
        let pix = view::max_intermediate_pixels(vol.grid.dims);
        PostRenderer {
            pixels: vec![[0; 4]; pix],
            links: vec![0; pix],
            visible: vec![false; postclass::brick_count(vol.grid.dims)],
            preint: vec![[0; 4]; 65536],
            shade: Box::new(ShadeTable::UNSHADED),
            out_row: Vec::new(),
        }
    }

    /// Renders one frame; `opacity` is the opacity transfer function over raw values.
    pub fn render(
        &mut self,
        vol: &DenseVolume,
        mode: postclass::PostMode,
        opacity: &[(f64, f64)],
        look: &Look,
        camera: &Camera,
    ) -> Result<Vec<[u8; 4]>, Error> {
        let pts = opacity_points(opacity);
        let op = OpacityTf::new(&pts)?.build_quantized(vol.range);
        if self.out_row.len() < camera.width {
            self.out_row.resize(camera.width, [0; 4]);
        }
        let mut frame = vec![[0u8; 4]; camera.width * camera.height];
        let settings = postclass::PostSettings {
            mode,
            opacity: &op,
            color: &look.color,
            lighting: look.lighting.as_ref(),
            ert_threshold: look.ert_threshold,
        };
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
        Ok(frame)
    }
}
