//! The seam between storage and rendering: where slices come from.
//!
//! The compositor needs exactly one slice at a time, in front-to-back order along the
//! principal axis. A [`SliceSource`] hands it over; the in-memory [`RleVolume`] lends
//! slices of borrowed arrays, and a streaming source can read each slice into a fixed
//! buffer just before it is needed.

use crate::classify::Grid;
use crate::error::Error;
use crate::rle::{Axis, RleAxis, RleSlice};

/// Supplies run-length-encoded slices.
pub trait SliceSource {
    /// Geometry of the volume.
    fn grid(&self) -> Grid;

    /// Calls `f` with slice `k` of the copy for principal `axis`.
    fn with_slice<R>(
        &mut self,
        axis: Axis,
        k: usize,
        f: impl FnOnce(&RleSlice<'_>) -> R,
    ) -> Result<R, Error>;
}

/// All three axis copies of an encoded volume, borrowed.
#[derive(Clone, Copy, Debug)]
pub struct RleVolume<'a> {
    grid: Grid,
    axes: [RleAxis<'a>; 3],
}

impl<'a> RleVolume<'a> {
    /// Bundles three validated copies (x, y, z principal, in that order).
    pub fn new(grid: Grid, axes: [RleAxis<'a>; 3]) -> Result<Self, Error> {
        for (a, want) in axes.iter().zip(Axis::ALL) {
            if a.axis() != want || a.dims() != grid.dims {
                return Err(Error::MalformedRle {
                    reason: "axis copies do not match the grid or are out of order",
                });
            }
        }
        Ok(RleVolume { grid, axes })
    }

    /// The copy for `axis`.
    pub fn axis(&self, axis: Axis) -> &RleAxis<'a> {
        &self.axes[axis as usize]
    }
}

impl SliceSource for RleVolume<'_> {
    fn grid(&self) -> Grid {
        self.grid
    }

    // Inlined so that the instruction-set builds of the band compositor that call it
    // compile the compositing loop in `f` for their own features.
    #[cfg_attr(target_arch = "x86_64", inline(always))]
    fn with_slice<R>(
        &mut self,
        axis: Axis,
        k: usize,
        f: impl FnOnce(&RleSlice<'_>) -> R,
    ) -> Result<R, Error> {
        let s = self.axes[axis as usize].slice(k).ok_or(Error::Source {
            reason: "slice index past the end of the volume",
        })?;
        Ok(f(&s))
    }
}
