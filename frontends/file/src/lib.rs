//! File frontend for `shearwarp`: loading volumes with JSON sidecars, parsing transfer
//! functions from the command line, encoding, rendering to PNG.

pub mod scene;
pub mod tfspec;
pub mod volume;
