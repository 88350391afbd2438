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
//!
//! # Example
//!
//! A 16³ ball classified, encoded and rendered to a 32×32 RGBA image, every buffer a
//! fixed-size array (on a microcontroller they would be `static`s; the firmware in
//! `frontends/mcu` streams a `.swv` file instead of encoding on the device).
//!
//! ```
//! use shearwarp_core::classify::{self, ColorTf, Grid, OpacityTf, Scalars, Voxel};
//! use shearwarp_core::clip::Clip;
//! use shearwarp_core::composite::{self, Mode};
//! use shearwarp_core::render::{render, Settings, StaticWorkspace};
//! use shearwarp_core::rle::{self, Axis, ScanIndex};
//! use shearwarp_core::source::RleVolume;
//! use shearwarp_core::view::{self, Camera};
//! use shearwarp_core::warp::FrameBuffer;
//!
//! const N: usize = 16;
//! const DIMS: [usize; 3] = [N; 3];
//! const VOXELS: usize = N * N * N;
//!
//! // Scalars that fall off with the distance from the centre, x fastest.
//! let mut scalars = [0u8; VOXELS];
//! for (i, s) in scalars.iter_mut().enumerate() {
//!     let d = [i % N, i / N % N, i / (N * N)].map(|c| c as f64 - 7.5);
//!     let r = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
//!     *s = (255.0 - 30.0 * r).max(0.0) as u8;
//! }
//! let grid = Grid::new(DIMS, [1.0; 3])?;
//!
//! // Transfer functions as lookup tables: opacity rises from value 100, colour runs
//! // from dark red to white.
//! let mut opacity = [0u8; 256];
//! OpacityTf::new(&[(100.0, [0.0]), (255.0, [0.8])])?.build_table(&mut opacity);
//! let color = ColorTf::new(&[(0.0, [0.5, 0.1, 0.1]), (255.0, [1.0; 3])])?.build_table((0, 255));
//! let mut voxels = [Voxel::default(); VOXELS];
//! classify::classify(&grid, Scalars::U8(&scalars), &opacity, None, &mut voxels)?;
//!
//! // One run-length-encoded copy per principal axis; voxels of opacity 0 are dropped.
//! // (`rle::measure` gives the exact sizes; these are enough for any 16³ volume.)
//! let mut runs = [[0u8; 2 * VOXELS]; 3];
//! let mut kept = [[Voxel::default(); VOXELS]; 3];
//! let mut scans = [[ScanIndex::default(); N * N + 1]; 3];
//! let [rx, ry, rz] = &mut runs;
//! let [vx, vy, vz] = &mut kept;
//! let [sx, sy, sz] = &mut scans;
//! let x = rle::encode(&voxels, &grid, Axis::X, 0, rx, vx, sx)?;
//! let y = rle::encode(&voxels, &grid, Axis::Y, 0, ry, vy, sy)?;
//! let z = rle::encode(&voxels, &grid, Axis::Z, 0, rz, vz, sz)?;
//! let mut volume = RleVolume::new(grid, [x, y, z])?;
//!
//! // Buffers sized for this volume and image, then one frame.
//! const PIX: usize = view::max_intermediate_pixels(DIMS);
//! const ROW: usize = composite::row_buffer_len(N);
//! let mut work = StaticWorkspace::<PIX, ROW, 32>::new();
//! let mut image = [[0u8; 4]; 32 * 32];
//! let settings = Settings {
//!     mode: Mode::Composite,
//!     color: &color,
//!     lighting: None,
//!     ert_threshold: 0.95,
//!     depth_cue: None,
//!     shadows: false,
//!     flat_voxels: Default::default(),
//!     clip: Clip::NONE,
//! };
//! let camera = Camera { rotate_x: 20.0, rotate_y: 30.0, width: 32, height: 32 };
//! let mut sink = FrameBuffer { width: 32, pixels: &mut image };
//! render(&mut volume, &camera, &settings, &mut work.workspace(), &mut sink)?;
//!
//! // The ball covers the centre; the corners are background.
//! assert!(image[16 * 32 + 16][3] > 200);
//! assert_eq!(image[0], [0; 4]);
//!
//! // A clipping plane through the centre cuts away the half of the ball at x > 7.5,
//! // as the slices are composited (moving it costs no encoding).
//! let coverage = |img: &[[u8; 4]]| img.iter().map(|p| p[3] as u32).sum::<u32>();
//! let whole = coverage(&image);
//! let clip = Clip::NONE.with_plane(&grid, [1.0, 0.0, 0.0], 0.0)?;
//! let mut sink = FrameBuffer { width: 32, pixels: &mut image };
//! let cut = Settings { clip, ..settings };
//! render(&mut volume, &camera, &cut, &mut work.workspace(), &mut sink)?;
//! assert!(coverage(&image) < whole * 3 / 4);
//! # Ok::<(), shearwarp_core::Error>(())
//! ```
#![no_std]
#![forbid(unsafe_code)]
#![warn(missing_docs)]
#![cfg_attr(
    not(test),
    deny(clippy::unwrap_used, clippy::expect_used, clippy::panic)
)]

pub mod classify;
pub mod clip;
pub mod composite;
pub mod crop;
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
