//! File frontend for `shearwarp`: loading volumes (raw data with JSON sidecars, DICOM
//! series, NIfTI-1, NRRD, MetaImage), parsing transfer functions from the command line,
//! encoding, rendering to PNG.

pub mod anim;
pub mod bigbuf;
pub mod formats;
pub mod info;
pub mod isa;
pub mod png;
pub mod post;
pub mod presets;
pub mod renderer;
pub mod reslice;
pub mod scene;
pub mod stats;
mod steal;
pub mod swvfile;
pub mod tffile;
pub mod tfspec;
pub mod volume;
