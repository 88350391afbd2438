//! Rendering for the viewer: the file frontend's threaded renderer (interruptible before
//! every slice through the core's `composite_band_until`), and zoom/pan folded into the
//! final warp.
//!
//! **Zoom and pan.** The core's camera always frames the whole volume (the shorter
//! image side spans its diagonal). The viewer keeps that camera at the window's size and
//! changes only the last step: the 2D warp maps each *window* pixel through
//! `window → virtual image → intermediate image`, where the virtual image is the one the
//! core would produce and `virtual = C + (window − C − pan) / zoom` (`C` the window
//! centre). That is exactly rendering a `zoom`× larger virtual image and cropping the
//! window out of it at offset `pan`, but the warp touches only the window's pixels, so
//! zooming in costs nothing extra; compositing does not depend on the image size at all.
//! At zoom 1 and no pan the map is the core's own, bit for bit, so the frame equals the
//! file frontend's.
//!
//! The same composition places a coarser level of detail: the core's pyramid levels are
//! centred like the full volume and keep its framing ([`Grid::as_level_of`]), so the
//! map is the same for every level.

use shearwarp_core::classify::Grid;
use shearwarp_core::source::SliceSource;
use shearwarp_core::view::{self, Camera, Factorization};
use shearwarp_core::Error;
use shearwarp_file::renderer::Renderer;
use shearwarp_file::scene::Look;

/// The reason a full-quality frame gives when new input interrupted it.
pub const CANCELLED: &str = "cancelled";

/// True if `e` is the error of an interrupted frame.
pub fn is_cancelled(e: &Error) -> bool {
    matches!(e, Error::Source { reason } if *reason == CANCELLED)
}

/// Where the rendered level goes in the window.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImageMap {
    /// Magnification relative to the core's framing (1 = whole volume fits).
    pub zoom: f64,
    /// Shift of the image in window pixels (right, down).
    pub pan: [f64; 2],
    /// Diagonal (mm) the full-resolution grid is framed on: the framing every level is
    /// matched to.
    pub reference_diagonal: f64,
    /// Offset (mm) from the full-resolution grid's centred coordinates to this level's;
    /// zero for the core's centred levels of detail.
    pub offset_mm: [f64; 3],
}

impl ImageMap {
    /// The identity for the full level: the core's own framing.
    pub fn identity(grid: &Grid) -> Self {
        ImageMap {
            zoom: 1.0,
            pan: [0.0; 2],
            reference_diagonal: grid.frame_diagonal(),
            offset_mm: [0.0; 3],
        }
    }

    /// Affine map `p_level = a·w + b` from window pixel coordinates to the coordinates
    /// of the image the core's factorization of `grid` under `camera` produces.
    pub fn window_to_level(&self, grid: &Grid, camera: &Camera) -> (f64, [f64; 2]) {
        let side = camera.width.min(camera.height) as f64;
        let k_ref = side / self.reference_diagonal;
        let k_level = side / grid.frame_diagonal();
        let a = k_level / (self.zoom * k_ref);
        let c = [camera.width as f64 * 0.5, camera.height as f64 * 0.5];
        let r = view::rotation(camera.rotate_x, camera.rotate_y);
        let d = self.offset_mm;
        let rd = [
            r[0][0] * d[0] + r[0][1] * d[1] + r[0][2] * d[2],
            r[1][0] * d[0] + r[1][1] * d[1] + r[1][2] * d[2],
        ];
        let b = [
            c[0] - a * (c[0] + self.pan[0]) + k_level * rd[0],
            c[1] - a * (c[1] + self.pan[1]) - k_level * rd[1],
        ];
        (a, b)
    }

    /// `view` with its image-to-intermediate map composed with [`Self::window_to_level`].
    pub fn apply(&self, grid: &Grid, camera: &Camera, view: &Factorization) -> Factorization {
        let (a, b) = self.window_to_level(grid, camera);
        let mut out = *view;
        for (o, m) in out
            .image_to_intermediate
            .iter_mut()
            .zip(view.image_to_intermediate)
        {
            *o = [m[0] * a, m[1] * a, m[0] * b[0] + m[1] * b[1] + m[2]];
        }
        out
    }
}

/// Reusable buffers for rendering any level of one volume with `threads` threads: the
/// file frontend's [`Renderer`] (band-parallel compositing, bit-identical whatever the
/// thread count; shadowed frames on one thread), with the window's zoom and pan folded
/// into its final warp.
pub struct Compositor {
    renderer: Renderer,
}

impl Compositor {
    /// Allocates for any view of `grid` (and of any smaller grid), `threads` ≥ 1.
    pub fn new(grid: &Grid, threads: usize) -> Self {
        Compositor {
            renderer: Renderer::with_threads(grid, threads),
        }
    }

    /// Compositing threads.
    pub fn threads(&self) -> usize {
        self.renderer.threads()
    }

    /// Takes flat voxels into samples' colours the way `f` says (the level's,
    /// [`crate::classifier::LevelRle::flat_voxels`]).
    pub fn set_flat_voxels(&mut self, f: shearwarp_core::composite::FlatVoxels) {
        self.renderer.set_flat_voxels(f);
    }

    /// Cuts frames by clipping planes `clip` as their slices are composited (made for
    /// the grid of the level rendered).
    pub fn set_clip(&mut self, clip: shearwarp_core::clip::Clip) {
        self.renderer.set_clip(clip);
    }

    /// Renders perspective views with a `fov` (degrees) field of view, or parallel
    /// projection with `None` (the file frontend's `--projection perspective --fov`).
    pub fn set_perspective(&mut self, fov: Option<f64>) {
        self.renderer.set_perspective(fov);
    }

    /// Renders `source` under `camera` and `look`, placed in the window by `map`;
    /// returns `camera.width × camera.height` RGBA8 pixels (premultiplied over black).
    pub fn render<S: SliceSource + Clone + Send>(
        &mut self,
        source: &S,
        camera: &Camera,
        look: &Look,
        map: &ImageMap,
    ) -> Result<Vec<[u8; 4]>, Error> {
        self.render_until(source, camera, look, map, &|| true)?
            .ok_or(Error::Source { reason: CANCELLED })
    }

    /// As [`Compositor::render`], asking `keep_going` before every slice; `None` if it
    /// said no and the frame was abandoned.
    pub fn render_until<S: SliceSource + Clone + Send>(
        &mut self,
        source: &S,
        camera: &Camera,
        look: &Look,
        map: &ImageMap,
        keep_going: &(dyn Fn() -> bool + Sync),
    ) -> Result<Option<Vec<[u8; 4]>>, Error> {
        let grid = source.grid();
        let Some(frame) =
            self.renderer
                .composite_until(&mut source.clone(), camera, look, keep_going)?
        else {
            return Ok(None);
        };
        self.renderer
            .warp(&map.apply(&grid, camera, &frame.view))
            .map(Some)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use shearwarp_core::composite::Mode;
    use shearwarp_core::shade::Lighting;
    use shearwarp_file::renderer::Renderer;
    use shearwarp_file::scene::{self, Classification};
    use shearwarp_file::volume::{RawVolume, Voxels};
    use std::sync::atomic::{AtomicU64, Ordering};

    /// An off-centre ball in an odd-sized, anisotropic volume.
    fn ball() -> RawVolume {
        let dims = [41usize, 36, 29];
        let c = [26.0, 15.0, 13.0];
        let mut v = Vec::new();
        for z in 0..dims[2] {
            for y in 0..dims[1] {
                for x in 0..dims[0] {
                    let d = ((x as f64 - c[0]).powi(2)
                        + (y as f64 - c[1]).powi(2)
                        + (1.5 * (z as f64 - c[2])).powi(2))
                    .sqrt();
                    v.push((230.0 - 25.0 * d).clamp(0.0, 255.0) as u8);
                }
            }
        }
        RawVolume {
            name: "ball".into(),
            dims,
            spacing: [1.0, 1.0, 1.5],
            voxels: Voxels::U8(v),
        }
    }

    fn look(mode: Mode, shading: bool) -> Look {
        Look {
            mode,
            color: scene::color_table(
                &[(0.0, [255, 200, 150]), (255.0, [255, 255, 255])],
                (0, 255),
            )
            .unwrap(),
            lighting: shading.then(Lighting::default),
            ert_threshold: 0.95,
            depth_cue: None,
            shadows: false,
        }
    }

    fn class() -> Classification {
        Classification {
            opacity: vec![(0.0, 0.0), (60.0, 0.0), (120.0, 0.6), (255.0, 0.9)],
            gradient: None,
            min_opacity: 0.02,
            cut: scene::Cut::NONE,
        }
    }

    fn cam(rx: f64, ry: f64) -> Camera {
        Camera {
            rotate_x: rx,
            rotate_y: ry,
            width: 96,
            height: 80,
        }
    }

    /// Intensity-weighted centroid of the red channel.
    fn centroid(px: &[[u8; 4]], w: usize) -> [f64; 2] {
        let (mut sx, mut sy, mut s) = (0.0, 0.0, 0.0);
        for (i, p) in px.iter().enumerate() {
            let a = p[0] as f64;
            sx += a * (i % w) as f64;
            sy += a * (i / w) as f64;
            s += a;
        }
        [sx / s, sy / s]
    }

    #[test]
    fn identity_map_equals_the_file_frontend_bit_for_bit() {
        let raw = ball();
        let enc = scene::encode(&raw, &class()).unwrap();
        let vol = enc.volume().unwrap();
        for (threads, c, l) in [
            (1, cam(-70.0, -35.0), look(Mode::Composite, true)),
            (2, cam(20.0, 100.0), look(Mode::Composite, false)),
            (3, cam(95.0, 10.0), look(Mode::Mip, false)),
        ] {
            let mut comp = Compositor::new(&enc.grid, threads);
            let mine = comp
                .render(&vol, &c, &l, &ImageMap::identity(&enc.grid))
                .unwrap();
            let mut r = Renderer::with_threads(&enc.grid, threads);
            let theirs = r.render(&mut vol.clone(), &c, &l).unwrap();
            assert!(mine == theirs, "threads {threads}");
        }
    }

    #[test]
    fn perspective_frames_equal_the_file_frontend_and_zoom_about_the_centre() {
        let raw = ball();
        let enc = scene::encode(&raw, &class()).unwrap();
        let vol = enc.volume().unwrap();
        let id = ImageMap::identity(&enc.grid);
        for (threads, c, l, fov) in [
            (1, cam(-70.0, -35.0), look(Mode::Composite, true), 30.0),
            (2, cam(20.0, 100.0), look(Mode::Composite, false), 60.0),
            (3, cam(95.0, 10.0), look(Mode::Mip, false), 90.0),
        ] {
            let mut comp = Compositor::new(&enc.grid, threads);
            comp.set_perspective(Some(fov));
            let mine = comp.render(&vol, &c, &l, &id).unwrap();
            let mut r = Renderer::with_threads(&enc.grid, threads);
            r.set_perspective(Some(fov));
            let theirs = r.render(&mut vol.clone(), &c, &l).unwrap();
            assert!(mine == theirs, "threads {threads}, {fov}°");
            // The window's zoom and pan act on the projected image as in parallel.
            let zoomed = ImageMap {
                zoom: 1.5,
                pan: [4.0, -3.0],
                ..id
            };
            let (base, z) = (
                centroid(&mine, c.width),
                centroid(&comp.render(&vol, &c, &l, &zoomed).unwrap(), c.width),
            );
            let centre = [48.0, 40.0];
            for a in 0..2 {
                let want = centre[a] + 1.5 * (base[a] - centre[a]) + zoomed.pan[a];
                assert!(
                    (z[a] - want).abs() < 0.35,
                    "{fov}°, axis {a}: {z:?} vs {want}"
                );
            }
            // Back to parallel projection.
            comp.set_perspective(None);
            let parallel = comp.render(&vol, &c, &l, &id).unwrap();
            let theirs = Renderer::with_threads(&enc.grid, 1)
                .render(&mut vol.clone(), &c, &l)
                .unwrap();
            assert!(parallel == theirs, "threads {threads}, parallel again");
        }
    }

    #[test]
    fn shadows_and_depth_cue_equal_the_file_frontend() {
        let raw = ball();
        let enc = scene::encode(&raw, &class()).unwrap();
        let vol = enc.volume().unwrap();
        let mut l = look(Mode::Composite, true);
        // A light near the viewing direction: the core's shadows need it inside the
        // view's principal-axis cone.
        if let Some(light) = l.lighting.as_mut().and_then(|x| x.lights.first_mut()) {
            light.direction = [0.2, 0.3, 1.0];
        }
        l.depth_cue = Some(shearwarp_core::depth::DepthCue {
            front: 1.0,
            density: 1.5,
        });
        for shadows in [false, true] {
            l.shadows = shadows;
            for c in [cam(0.0, 0.0), cam(10.0, -20.0)] {
                let mut comp = Compositor::new(&enc.grid, 2);
                let mine = comp
                    .render(&vol, &c, &l, &ImageMap::identity(&enc.grid))
                    .unwrap();
                let mut r = Renderer::with_threads(&enc.grid, 2);
                let theirs = r.render(&mut vol.clone(), &c, &l).unwrap();
                assert!(mine == theirs, "shadows {shadows} {c:?}");
            }
        }
    }

    #[test]
    fn zoom_and_pan_scale_about_the_centre_and_shift() {
        let raw = ball();
        let enc = scene::encode(&raw, &class()).unwrap();
        let vol = enc.volume().unwrap();
        let c = cam(-30.0, 40.0);
        let l = look(Mode::Composite, false);
        let mut comp = Compositor::new(&enc.grid, 2);
        let id = ImageMap::identity(&enc.grid);
        let base = centroid(&comp.render(&vol, &c, &l, &id).unwrap(), c.width);
        let zoomed = ImageMap {
            zoom: 1.5,
            pan: [4.0, -3.0],
            ..id
        };
        let z = centroid(&comp.render(&vol, &c, &l, &zoomed).unwrap(), c.width);
        let centre = [48.0, 40.0];
        for a in 0..2 {
            let want = centre[a] + 1.5 * (base[a] - centre[a]) + zoomed.pan[a];
            assert!((z[a] - want).abs() < 0.35, "axis {a}: {z:?} vs {want}");
        }
    }

    #[test]
    fn half_level_lands_where_the_full_level_does() {
        let raw = ball();
        let (h, _) = scene::lod(&raw, 1).unwrap();
        let full = scene::encode(&raw, &class()).unwrap();
        let low = scene::encode(&h, &class()).unwrap().as_level(&full.grid);
        let l = look(Mode::Mip, false);
        let mut comp = Compositor::new(&full.grid, 2);
        for (c, fov) in [
            (cam(0.0, 0.0), None),
            (cam(-70.0, -35.0), None),
            (cam(33.0, 120.0), None),
            (cam(-70.0, -35.0), Some(60.0)),
            (cam(33.0, 120.0), Some(30.0)),
        ] {
            comp.set_perspective(fov);
            for (zoom, pan) in [(1.0, [0.0, 0.0]), (2.0, [-6.0, 5.0])] {
                let map = ImageMap {
                    zoom,
                    pan,
                    ..ImageMap::identity(&full.grid)
                };
                let a = comp.render(&full.volume().unwrap(), &c, &l, &map).unwrap();
                let b = comp.render(&low.volume().unwrap(), &c, &l, &map).unwrap();
                let (ca, cb) = (centroid(&a, c.width), centroid(&b, c.width));
                for k in 0..2 {
                    assert!(
                        (ca[k] - cb[k]).abs() < 0.3 * zoom,
                        "{c:?} {fov:?} {ca:?} {cb:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn frames_stop_when_the_generation_moves_on() {
        let raw = ball();
        let enc = scene::encode(&raw, &class()).unwrap();
        let latest = AtomicU64::new(7);
        let c = cam(10.0, 10.0);
        let l = look(Mode::Composite, false);
        let mut comp = Compositor::new(&enc.grid, 2);
        let id = ImageMap::identity(&enc.grid);
        let vol = enc.volume().unwrap();
        let live = || latest.load(Ordering::Relaxed) == 7;
        assert!(comp
            .render_until(&vol, &c, &l, &id, &live)
            .unwrap()
            .is_some());
        latest.store(8, Ordering::Relaxed);
        assert!(comp
            .render_until(&vol, &c, &l, &id, &live)
            .unwrap()
            .is_none());
        // Stopping half way through: the check runs before every slice.
        let calls = AtomicU64::new(0);
        let half = || calls.fetch_add(1, Ordering::Relaxed) < 10;
        let one = Compositor::new(&enc.grid, 1)
            .render_until(&vol, &c, &l, &id, &half)
            .unwrap();
        assert!(one.is_none());
        assert_eq!(calls.load(Ordering::Relaxed), 11);
    }
}
