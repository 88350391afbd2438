//! The render thread: owns both levels of the volume, re-encodes them when the
//! classification changes, and renders the newest request.
//!
//! Progressive refinement (after Ryan 1992): the window asks for a **preview** (level 1
//! of the core's level-of-detail pyramid, [`shearwarp_core::lod`]) on every input and
//! for the **full** level once input stops. The level keeps the full volume's opacity
//! unit and framing, so it lands in the same place equally bright with the same
//! transfer function. Requests carry a generation number; the window bumps the shared
//! `latest` counter on every input, and a full-level frame in progress checks it before
//! each slice (the core's `composite_band_until`), so new input interrupts refinement at
//! the next slice. Previews are never interrupted (they take a few milliseconds).
//!
//! After a window/level change only the axis copy the view needs is re-encoded
//! ([`crate::classifier::LevelRle`]): synchronously for the preview level (a few
//! milliseconds), on a helper thread for the full level, so previews go on while it
//! works.

use crate::classifier::{Classifier, Encoding, LevelRle};
use crate::preset::{self, PRESETS};
use crate::render::{self, Compositor, ImageMap};
use crate::state::{self, ViewState};
use shearwarp_core::classify::Grid;
use shearwarp_core::clip::Clip;
use shearwarp_core::composite::Mode;
use shearwarp_core::rle::Axis;
use shearwarp_core::shade::Lighting;
use shearwarp_core::view::{Camera, Factorization};
use shearwarp_core::Error;
use shearwarp_file::scene::{self, Classification, Look};
use shearwarp_file::volume::RawVolume;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError, Sender, TryRecvError};
use std::sync::{Arc, OnceLock};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// Which level a frame is rendered from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Quality {
    /// Level 1 of the pyramid (half resolution).
    Preview,
    /// The volume as loaded.
    Full,
}

impl Quality {
    /// Short name for the title bar.
    pub fn name(self) -> &'static str {
        match self {
            Quality::Preview => "preview 1/2",
            Quality::Full => "full",
        }
    }
}

/// A request for a frame.
#[derive(Clone, Copy, Debug)]
pub struct Job {
    pub generation: u64,
    pub quality: Quality,
    pub view: ViewState,
}

/// How a request ended.
pub enum Outcome {
    Frame {
        /// RGBA8, premultiplied over black, window-sized.
        pixels: Vec<[u8; 4]>,
        /// Compositing + warp.
        render_ms: f64,
        /// Classification + encoding this frame had to wait for (0 if cached).
        encode_ms: f64,
        /// Whether shadows were rendered.
        shadows: bool,
        /// Why something asked for was left out (shadows the core cannot do here).
        note: Option<String>,
    },
    /// New input arrived first.
    Cancelled,
    Failed(String),
}

/// A finished request.
pub struct Done {
    pub job: Job,
    pub outcome: Outcome,
}

/// Fixed rendering parameters.
#[derive(Clone, Debug)]
pub struct Settings {
    /// Window size.
    pub size: [usize; 2],
    /// Compositing threads.
    pub threads: usize,
    /// Voxels at or below this opacity are skipped (full level).
    pub min_opacity: f64,
    /// Early ray termination.
    pub ert: f64,
    /// Lighting when shading is on.
    pub lighting: Lighting,
    /// Field of view (degrees) of perspective frames.
    pub fov: f64,
}

/// The volume and its derived data.
pub struct Scene {
    pub full: Arc<RawVolume>,
    /// Level 1 of the level-of-detail pyramid.
    pub preview: RawVolume,
    /// Raw range the presets are expressed over (of the full volume).
    pub range: (u16, u16),
    pub settings: Settings,
}

impl Scene {
    /// Prepares `raw` (builds level 1 of its level-of-detail pyramid).
    pub fn new(raw: RawVolume, settings: Settings) -> Result<Scene, Error> {
        let (preview, _) = scene::lod(&raw, 1)?;
        let range = preset::data_range(&raw);
        Ok(Scene {
            full: Arc::new(raw),
            preview,
            range,
            settings,
        })
    }

    /// The full volume's grid.
    pub fn grid(&self) -> Result<Grid, Error> {
        Grid::new(self.full.dims, self.full.spacing)
    }

    /// The classification of `view` for a level of the volume (the full volume's grid,
    /// or the preview's, which keeps its voxels centred in the full volume's box). A
    /// crop box is baked into it; clipping planes are not ([`draw`] cuts the slices by
    /// them as they are composited), so that moving a plane re-encodes nothing.
    pub fn classification(&self, view: &ViewState, grid: &Grid) -> Result<Classification, Error> {
        let (full, dims) = (self.full.dims, grid.dims);
        let crop = view.cut.crop(full).and_then(|c| {
            // The preview is level 1: each of its voxels stands for two.
            let factor = if dims == full { 1 } else { 2 };
            c.at_level(full, dims, factor)
        });
        Ok(Classification {
            opacity: preset::opacity_points(&PRESETS[view.preset], view.wl, self.range),
            gradient: None,
            min_opacity: self.settings.min_opacity,
            cut: scene::Cut {
                crop,
                clip: Clip::NONE,
            },
        })
    }

    /// The look of `view` for a level encoded over `range`; `shadows` asks for shadows
    /// if the view has them on (they need shading and composite mode).
    pub fn look(
        &self,
        view: &ViewState,
        encoded_range: (u16, u16),
        shadows: bool,
    ) -> Result<Look, Error> {
        let colors = preset::color_points(&PRESETS[view.preset], self.range);
        let mip = view.is_mip();
        Ok(Look {
            mode: if mip { Mode::Mip } else { Mode::Composite },
            color: scene::color_table(&colors, encoded_range)?,
            lighting: (view.shading && !mip).then(|| self.settings.lighting.clone()),
            ert_threshold: self.settings.ert,
            depth_cue: (view.depth_cue && !mip && !view.perspective).then_some(state::DEPTH_CUE),
            shadows: shadows && view.shadows && view.shading && !mip && !view.perspective,
        })
    }

    /// The camera of `view`.
    pub fn camera(&self, view: &ViewState) -> Camera {
        Camera {
            rotate_x: view.rotate_x,
            rotate_y: view.rotate_y,
            width: self.settings.size[0],
            height: self.settings.size[1],
        }
    }
}

/// An encoding and the milliseconds it took.
type EncodeResult = Result<Encoding, Error>;

/// The full level's one-time classification, made by the first encoding thread.
type SharedClassifier = Arc<OnceLock<Result<Classifier, Error>>>;

struct Pending {
    handle: JoinHandle<EncodeResult>,
}

/// The render thread's state.
struct Engine {
    scene: Scene,
    comp: Compositor,
    latest: Arc<AtomicU64>,
    full_classifier: SharedClassifier,
    /// Full-level copies; `None` until the classifier has run (its range is needed).
    full: Option<LevelRle>,
    /// Milliseconds of the last full-level encoding, reported with the next full frame.
    full_encode_ms: f64,
    low_classifier: Classifier,
    low: LevelRle,
    pending: Option<Pending>,
}

enum Step {
    Done(Outcome),
    /// The full level is being re-encoded; ask again shortly.
    NotReady,
}

/// Starts the render thread. Send [`Job`]s; receive [`Done`]s. Dropping the sender
/// ends the thread.
pub fn spawn(
    scene: Scene,
    latest: Arc<AtomicU64>,
) -> (Sender<Job>, Receiver<Done>, JoinHandle<()>) {
    let (job_tx, job_rx) = mpsc::channel::<Job>();
    let (done_tx, done_rx) = mpsc::channel::<Done>();
    let handle = std::thread::spawn(move || {
        let grid = shearwarp_core::classify::Grid::new(scene.full.dims, scene.full.spacing);
        let low = Classifier::new(Arc::new(scene.preview.clone()));
        let (comp, low_classifier, full_grid) = match (grid, low) {
            (Ok(g), Ok(low)) => (Compositor::new(&g, scene.settings.threads), low, g),
            (Err(e), _) | (_, Err(e)) => {
                if let Ok(job) = job_rx.recv() {
                    let _ = done_tx.send(Done {
                        job,
                        outcome: Outcome::Failed(e.to_string()),
                    });
                }
                return;
            }
        };
        let low = LevelRle::new(
            low_classifier.grid().as_level_of(&full_grid),
            low_classifier.range(),
        );
        let mut engine = Engine {
            scene,
            comp,
            latest,
            full_classifier: Arc::new(OnceLock::new()),
            full: None,
            full_encode_ms: 0.0,
            low_classifier,
            low,
            pending: None,
        };
        engine.run(&job_rx, &done_tx);
    });
    (job_tx, done_rx, handle)
}

impl Engine {
    fn run(&mut self, rx: &Receiver<Job>, tx: &Sender<Done>) {
        let mut current: Option<Job> = None;
        loop {
            if current.is_none() {
                match rx.recv() {
                    Ok(j) => current = Some(j),
                    Err(_) => return,
                }
            }
            // The newest request wins.
            loop {
                match rx.try_recv() {
                    Ok(j) => current = Some(j),
                    Err(TryRecvError::Empty) => break,
                    Err(TryRecvError::Disconnected) => return,
                }
            }
            let Some(job) = current.take() else { continue };
            match self.step(&job) {
                Step::Done(outcome) => {
                    if tx.send(Done { job, outcome }).is_err() {
                        return;
                    }
                }
                Step::NotReady => match rx.recv_timeout(Duration::from_millis(4)) {
                    Ok(j) => current = Some(j),
                    Err(RecvTimeoutError::Timeout) => current = Some(job),
                    Err(RecvTimeoutError::Disconnected) => return,
                },
            }
        }
    }

    fn step(&mut self, job: &Job) -> Step {
        match job.quality {
            Quality::Preview => Step::Done(
                self.preview(job)
                    .unwrap_or_else(|e| Outcome::Failed(format!("preview: {e}"))),
            ),
            Quality::Full => match self.full_frame(job) {
                Ok(Some(o)) => Step::Done(o),
                Ok(None) => Step::NotReady,
                Err(e) if render::is_cancelled(&e) => Step::Done(Outcome::Cancelled),
                Err(e) => Step::Done(Outcome::Failed(format!("full quality: {e}"))),
            },
        }
    }

    fn preview(&mut self, job: &Job) -> Result<Outcome, Error> {
        let class = self.scene.classification(&job.view, &self.low.grid)?;
        let camera = self.scene.camera(&job.view);
        let axis = Factorization::new(&self.low.grid, &camera)?.axis;
        let encode_ms = self.low.ensure(&self.low_classifier, &class, axis)?;
        let t = Instant::now();
        let map = ImageMap {
            zoom: job.view.zoom,
            pan: job.view.pan,
            ..ImageMap::identity(&self.low.grid)
        };
        let src = self.low.volume()?;
        self.comp.set_flat_voxels(self.low.flat_voxels());
        let (pixels, shadows, note) = draw(
            &mut self.comp,
            &self.scene,
            &job.view,
            &src,
            self.low.range,
            &map,
            &|| true,
        )?;
        Ok(Outcome::Frame {
            pixels,
            render_ms: t.elapsed().as_secs_f64() * 1e3,
            encode_ms,
            shadows,
            note,
        })
    }

    /// `Ok(None)` while the full level is being (re-)encoded. Only the copy of the
    /// view's principal axis has to be current; it is built on its own thread so that
    /// previews go on meanwhile.
    fn full_frame(&mut self, job: &Job) -> Result<Option<Outcome>, Error> {
        if self.latest.load(Ordering::Relaxed) != job.generation {
            return Err(Error::Source {
                reason: render::CANCELLED,
            });
        }
        let grid = self.scene.grid()?;
        let class = self.scene.classification(&job.view, &grid)?;
        let camera = self.scene.camera(&job.view);
        let axis = Factorization::new(&grid, &camera)?.axis;
        let missing = |full: &Option<LevelRle>| match full {
            Some(l) => l.missing(&class, axis),
            None => Axis::ALL.to_vec(),
        };
        let mut waited_ms = 0.0;
        if !missing(&self.full).is_empty() {
            if let Some(p) = self.pending.take() {
                if !p.handle.is_finished() {
                    self.pending = Some(p);
                    return Ok(None);
                }
                let enc = p.handle.join().map_err(|_| Error::Source {
                    reason: "the encoding thread panicked",
                })??;
                self.full_encode_ms = enc.ms;
                if self.full.is_none() {
                    let c = self.full_classifier.get().and_then(|r| r.as_ref().ok());
                    let range = c.map(|c| c.range()).ok_or(Error::Source {
                        reason: "the full-level classifier is missing",
                    })?;
                    self.full = Some(LevelRle::new(grid, range));
                }
                if let Some(l) = self.full.as_mut() {
                    l.install(enc);
                }
            }
            let todo = missing(&self.full);
            if !todo.is_empty() {
                let raw = Arc::clone(&self.scene.full);
                let cell = Arc::clone(&self.full_classifier);
                let dense = self.full.as_ref().and_then(|l| l.dense_for(&class));
                let c = class.clone();
                self.pending = Some(Pending {
                    handle: std::thread::spawn(move || {
                        let t = Instant::now();
                        let classifier = cell
                            .get_or_init(|| Classifier::new(raw))
                            .as_ref()
                            .map_err(|e| *e)?;
                        let mut enc = classifier.encode_axes(&c, dense, &todo)?;
                        enc.ms = t.elapsed().as_secs_f64() * 1e3;
                        Ok(enc)
                    }),
                });
                return Ok(None);
            }
            waited_ms = self.full_encode_ms;
        }
        let Some(full) = &self.full else {
            unreachable!("encoded above")
        };
        let t = Instant::now();
        let map = ImageMap {
            zoom: job.view.zoom,
            pan: job.view.pan,
            ..ImageMap::identity(&full.grid)
        };
        let src = full.volume()?;
        self.comp.set_flat_voxels(full.flat_voxels());
        let (latest, generation) = (&*self.latest, job.generation);
        let (pixels, shadows, note) = draw(
            &mut self.comp,
            &self.scene,
            &job.view,
            &src,
            full.range,
            &map,
            &|| latest.load(Ordering::Relaxed) == generation,
        )?;
        Ok(Some(Outcome::Frame {
            pixels,
            render_ms: t.elapsed().as_secs_f64() * 1e3,
            encode_ms: waited_ms,
            shadows,
            note,
        }))
    }
}

/// Pixels, whether shadows were rendered, and why not if they were asked for.
type Drawn = (Vec<[u8; 4]>, bool, Option<String>);

/// Renders one level; if the core declines shadows for this view (the light must lie
/// in the view's principal-axis cone), renders without them and says why.
fn draw<S: shearwarp_core::source::SliceSource + Clone + Send>(
    comp: &mut Compositor,
    scene: &Scene,
    view: &ViewState,
    src: &S,
    range: (u16, u16),
    map: &ImageMap,
    keep_going: &(dyn Fn() -> bool + Sync),
) -> Result<Drawn, Error> {
    let camera = scene.camera(view);
    let look = scene.look(view, range, true)?;
    comp.set_perspective(view.perspective.then_some(scene.settings.fov));
    comp.set_clip(view.cut.clip(&scene.grid()?, &src.grid())?);
    let cancelled = || Error::Source {
        reason: render::CANCELLED,
    };
    match comp.render_until(src, &camera, &look, map, keep_going) {
        Ok(px) => Ok((px.ok_or_else(cancelled)?, look.shadows, None)),
        Err(Error::BadParameter { reason }) if look.shadows && reason.starts_with("shadows") => {
            let plain = scene.look(view, range, false)?;
            let px = comp
                .render_until(src, &camera, &plain, map, keep_going)?
                .ok_or_else(cancelled)?;
            Ok((
                px,
                false,
                Some(format!("no shadows for this view: {reason}")),
            ))
        }
        Err(e) => Err(e),
    }
}
