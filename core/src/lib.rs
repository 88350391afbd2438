//! `shearwarp-core`: a `no_std`, allocation-free, fixed-point shear-warp volume renderer.
//!
//! The pipeline follows Lacroute's shear-warp factorization (Lacroute 1995, ch. 3–4):
//!
//! 1. [`classify`] turns scalars into voxel records (opacity, quantised scalar, encoded
//!    normal) using transfer-function lookup tables, and [`normal`] encodes gradients.
//! 2. [`rle`] run-length encodes the classified volume once per principal axis so that
//!    transparent voxels cost nothing at render time.
//! 3. [`view`] factors the viewing transform into a shear (per-slice translation) and a
//!    2D affine warp.
//! 4. [`composite`] resamples each sheared slice and composites it front to back into a
//!    run-length-encoded intermediate image, skipping transparent voxel runs and opaque
//!    pixels in lockstep.
//! 5. [`warp`] resamples the intermediate image into the final image.
//!
//! Floats are used only for per-frame setup (the factorization and lookup tables); every
//! per-voxel and per-pixel loop is integer arithmetic in Q15 fixed point ([`fixed`]).
//! All memory is owned by the caller; every size is stated up front and a buffer that is
//! too small is an [`Error`], never a panic.
#![no_std]
#![forbid(unsafe_code)]
#![warn(missing_docs)]
#![cfg_attr(
    not(test),
    deny(clippy::unwrap_used, clippy::expect_used, clippy::panic)
)]

pub mod classify;
pub mod composite;
pub mod depth;
pub mod error;
pub mod fixed;
pub mod io;
pub mod lod;
pub mod normal;
pub mod opaque;
pub mod perspective;
pub mod postclass;
pub mod render;
pub mod rle;
pub mod shade;
pub mod shadow;
pub mod source;
pub mod swv;
pub mod view;
pub mod warp;

pub use error::Error;

/// A xorshift64 stream for the unit tests' random cases (the core has no `rand`).
#[cfg(test)]
pub(crate) fn xorshift(mut seed: u64) -> impl FnMut() -> u64 {
    move || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        seed
    }
}
