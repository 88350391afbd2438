//! `shearwarp-view`: an interactive desktop preview for `shearwarp` volumes.
//!
//! The binary opens a `minifb` window; this library holds everything that can be tested
//! without one: transfer-function presets and window/level ([`preset`]), threaded
//! rendering, interruptible before every slice, with zoom/pan in the warp ([`render`]),
//! the render thread with progressive refinement from the core's level-of-detail pyramid
//! ([`engine`]), input handling ([`state`]), replayable scripts
//! ([`script`]) and image comparison for the headless checks ([`compare`]).

pub mod classifier;
pub mod compare;
pub mod engine;
pub mod preset;
pub mod render;
pub mod script;
pub mod state;
