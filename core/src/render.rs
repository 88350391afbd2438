//! One frame, end to end: factor the view, build the per-frame tables, composite every
//! slice front to back, warp.
//!
//! The caller owns every buffer, either as slices ([`Workspace`]) or as one
//! const-generic block ([`StaticWorkspace`]) whose size is fixed at compile time for a
//! maximum volume and image.

use crate::classify::ColorTable;
use crate::composite::{self, Intermediate, Mode, Rgba, SliceTables};
use crate::error::{need, Error};
use crate::fixed;
use crate::shade::{Lighting, ShadeTable};
use crate::source::SliceSource;
use crate::view::{self, Camera, Factorization};
use crate::warp::{self, PixelSink};

/// How to render a frame.
#[derive(Clone, Debug)]
pub struct Settings<'a> {
    /// Compositing mode.
    pub mode: Mode,
    /// Colour per quantised scalar.
    pub color: &'a ColorTable,
    /// Lighting, or `None` for unshaded colours.
    pub lighting: Option<&'a Lighting>,
    /// Early-ray-termination opacity in `(0, 1]`; 1 disables termination.
    pub ert_threshold: f64,
}

/// Caller-owned buffers for [`render`].
pub struct Workspace<'a> {
    /// Intermediate image pixels: at least [`view::max_intermediate_pixels`].
    pub pixels: &'a mut [Rgba],
    /// Opaque-pixel links, as many as `pixels`.
    pub links: &'a mut [u16],
    /// Voxel row buffers: [`composite::row_buffer_len`] of the largest volume side.
    pub rows: &'a mut [Rgba],
    /// One output row: the image width.
    pub out_row: &'a mut [[u8; 4]],
    /// Shading table, rebuilt each frame when lighting is on.
    pub shade: &'a mut ShadeTable,
}

/// Buffers sized at compile time: `PIX` intermediate pixels, `ROW` row-buffer entries,
/// `W` image width.
///
/// Bytes: `10·PIX + 8·ROW + 4·W + 98 316` (the shade table). Use
/// [`view::max_intermediate_pixels`] and [`composite::row_buffer_len`] to choose `PIX`
/// and `ROW` for a maximum volume.
pub struct StaticWorkspace<const PIX: usize, const ROW: usize, const W: usize> {
    pixels: [Rgba; PIX],
    links: [u16; PIX],
    rows: [Rgba; ROW],
    out_row: [[u8; 4]; W],
    shade: ShadeTable,
}

impl<const PIX: usize, const ROW: usize, const W: usize> StaticWorkspace<PIX, ROW, W> {
    /// Size in bytes.
    pub const BYTES: usize = core::mem::size_of::<Self>();

    /// A zeroed workspace (usable in a `static`).
    pub const fn new() -> Self {
        StaticWorkspace {
            pixels: [[0; 4]; PIX],
            links: [0; PIX],
            rows: [[0; 4]; ROW],
            out_row: [[0; 4]; W],
            shade: ShadeTable::UNSHADED,
        }
    }

    /// Borrows the buffers.
    pub fn workspace(&mut self) -> Workspace<'_> {
        Workspace {
            pixels: &mut self.pixels,
            links: &mut self.links,
            rows: &mut self.rows,
            out_row: &mut self.out_row,
            shade: &mut self.shade,
        }
    }
}

impl<const PIX: usize, const ROW: usize, const W: usize> Default for StaticWorkspace<PIX, ROW, W> {
    fn default() -> Self {
        Self::new()
    }
}

/// Renders one frame of `source` into `sink`.
pub fn render<S: SliceSource, P: PixelSink>(
    source: &mut S,
    camera: &Camera,
    settings: &Settings<'_>,
    ws: &mut Workspace<'_>,
    sink: &mut P,
) -> Result<(), Error> {
    let grid = source.grid();
    let view = Factorization::new(&grid, camera)?;
    if !(settings.ert_threshold > 0.0 && settings.ert_threshold <= 1.0) {
        return Err(Error::BadParameter {
            reason: "early-ray-termination threshold must be in (0, 1]",
        });
    }
    let [iw, ih] = view.intermediate;
    need("out row", camera.width, ws.out_row.len())?;
    need("row buffer", composite::row_buffer_len(view.dims[0]), ws.rows.len())?;
    match settings.lighting {
        Some(l) => ws.shade.fill(l, &view.rotation)?,
        None => *ws.shade = ShadeTable::UNSHADED,
    }
    let opacity = crate::classify::opacity_correction(view.step_ratio);
    // ERT at 1.0 can never trigger strictly below ONE; keep it reachable only at ONE+1.
    let ert = if settings.ert_threshold >= 1.0 {
        fixed::ONE + 1
    } else {
        fixed::from_f64(settings.ert_threshold)
    };
    let tables = SliceTables {
        opacity: &opacity,
        color: settings.color,
        shade: ws.shade,
        mode: settings.mode,
        ert,
    };
    let rows = &mut *ws.rows;
    rows.fill([0; 4]);
    let mut img = Intermediate::new(iw, ih, ws.pixels, ws.links)?;
    for idx in 0..view.dims[2] {
        let k = view.slice_at(idx);
        source.with_slice(view.axis, k, |slice| {
            composite::composite_slice(&mut img, slice, k, &view, &tables, rows, (0, ih))
        })??;
    }
    warp::warp(&img, &view, ws.out_row, sink)
}

/// Bytes of a [`StaticWorkspace`] able to render any view of a `dims` volume at width
/// `width`.
pub const fn workspace_bytes(dims: [usize; 3], width: usize) -> usize {
    let pix = view::max_intermediate_pixels(dims);
    let mut m = dims[0];
    if dims[1] > m {
        m = dims[1];
    }
    if dims[2] > m {
        m = dims[2];
    }
    pix * (8 + 2)
        + composite::row_buffer_len(m) * 8
        + width * 4
        + core::mem::size_of::<ShadeTable>()
}
