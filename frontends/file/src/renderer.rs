//! Rendering an encoded volume with threads: the workspace the core composites into,
//! the intermediate image's scanlines cut into bands and shared out among threads
//! (Lacroute 1995, ch. 6), and the warp's output strips split the same way.

use crate::isa::{self, Isa};
use crate::scene::Look;
use crate::steal::{Piece, Retire, Sharing};
use shearwarp_core::classify::Grid;
use shearwarp_core::clip::Clip;
use shearwarp_core::composite::{self, FlatVoxels, Intermediate, Rgba};
use shearwarp_core::opaque;
use shearwarp_core::render::{Frame, Settings};
use shearwarp_core::shade::ShadeTable;
use shearwarp_core::shadow;
use shearwarp_core::source::SliceSource;
use shearwarp_core::view::{self, Camera, Factorization};
use shearwarp_core::warp;
use shearwarp_core::Error;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// A thread's starting band: first scanline, scanlines, pixels, opaque-pixel bitmap,
/// extents.
type Start<'a> = (
    usize,
    usize,
    &'a mut [Rgba],
    &'a mut [opaque::Word],
    &'a mut [[u32; 2]],
);

/// What a compositing thread has to itself: its row buffer, its handle on the source
/// and its busy time ([`FrameTimes::busy`]). (A thread on a pool worker also takes that
/// worker's shading table, `Renderer::own_shade`.)
type Own<'a, S> = (&'a mut Vec<Rgba>, S, &'a mut Duration);

/// Waits, without sleeping and for at most [`SPIN_LIMIT`], until `running` is zero.
///
/// The threads of a frame finish within a fraction of a millisecond of each other (a
/// thread that runs out of work takes half of another's band), but a thread that blocks
/// waits to be woken, and a pool thread that went to sleep after the compositing is slow
/// to take the warp's first job. Measured inside the renderer (brainsmall, two threads,
/// 36 frames at 256², medians): the warp's worker started 0.05–0.19 ms after the
/// compositing was joined when the threads slept, 0.004 ms when they spin, out of a
/// frame of about 1 ms. The limit bounds the waste when another process holds the
/// other core.
///
/// The count is read after every pause and the clock after every 64: reading the count
/// only after each batch of 64 pauses took up to a microsecond to notice the end here.
fn spin_until_done(running: &AtomicUsize) {
    let start = Instant::now();
    loop {
        for _ in 0..64 {
            if running.load(Ordering::Acquire) == 0 {
                return;
            }
            std::hint::spin_loop();
        }
        if start.elapsed() >= SPIN_LIMIT {
            return;
        }
    }
}

/// How long [`spin_until_done`] spins before leaving the wait to the pool.
const SPIN_LIMIT: Duration = Duration::from_millis(2);

/// How long the calling thread spins on after another thread finished the last item,
/// before it waits for the pool's scope to end.
///
/// The calling thread is not one of the pool's threads, so rayon ends the scope for it
/// on a lock and condition variable: when it gets there before the last worker's job
/// has returned into the pool and posted its completion, it goes to sleep and has to be
/// woken, which on this host's virtual CPUs (halted when idle) takes 15–30 µs. The
/// worker needs well under a microsecond from its last count to that post. Measured
/// inside the renderer (brainsmall, two threads, 256², 180 frames): from the calling
/// thread's end of its own item to the scope's end took 0.9 µs at the median but 8.4 µs
/// at the 80th percentile and 20.6 at the 90th for the compositing, 17.7 and 26.0 µs
/// for the warp; a mean of 13 µs a frame. With this wait the 90th percentiles were
/// 1.5 and 1.3 µs, and whole two-thread frames, alternating with and without it in one
/// process (with the count read between single pauses), took 12–16 µs less at the
/// median in four runs (0.424–0.430 ms against 0.437–0.442 on a calm host).
const LATCH_GRACE: Duration = Duration::from_micros(1);

/// Calls `work` once per item of `each`, the first on the calling thread and the others
/// on `pool`'s workers, and returns the first error (`panicked` names a poisoned lock).
fn on_threads<T: Send>(
    pool: &rayon::ThreadPool,
    each: impl IntoIterator<Item = T>,
    work: impl Fn(T) -> Result<(), Error> + Sync,
    panicked: &'static str,
) -> Result<(), Error> {
    let failed: Mutex<Option<Error>> = Mutex::new(None);
    let keep = |r: Result<(), Error>| {
        if let (Err(e), Ok(mut f)) = (r, failed.lock()) {
            f.get_or_insert(e);
        }
    };
    // Items not finished yet. Every thread, the calling one too, spins after its own
    // item until all are done, so that none of them is asleep when the next phase (the
    // warp after the compositing) posts its jobs.
    let running = AtomicUsize::new(0);
    pool.in_place_scope(|scope| {
        let mut each = each.into_iter();
        let first = each.next();
        running.fetch_add(first.is_some() as usize, Ordering::Relaxed);
        let (work, keep, running) = (&work, &keep, &running);
        // Whether this item was the last to finish.
        let finish = move |item| {
            keep(work(item));
            let last = running.fetch_sub(1, Ordering::Release) == 1;
            spin_until_done(running);
            last
        };
        for item in each {
            running.fetch_add(1, Ordering::Relaxed);
            scope.spawn(move |_| {
                finish(item);
            });
        }
        // The calling thread works too (one thread fewer to wake, and its caches are
        // warm).
        if let Some(item) = first {
            if !finish(item) {
                let grace = Instant::now();
                while grace.elapsed() < LATCH_GRACE {
                    std::hint::spin_loop();
                }
            }
        }
    });
    match failed.into_inner() {
        Ok(None) => Ok(()),
        Ok(Some(e)) => Err(e),
        Err(_) => Err(Error::Source { reason: panicked }),
    }
}

/// Where the last frame's time went, wall clock, as [`Renderer::times`] reports it.
///
/// With one thread `composite` and the one `busy` entry are the same span. With more,
/// the gap between them says what the threads lost beside the work itself: summed
/// `busy` over one thread's `composite` is the extra time threads spend on the same
/// work (more instructions, or slower ones), and `composite` minus the longest `busy`
/// is waiting (a thread starting late, or asking for part of another's band).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FrameTimes {
    /// Serial work before the compositing: waking the other threads, the view's
    /// factorization, the shading and opacity tables, the buffers' sizes.
    pub setup: Duration,
    /// The compositing phase, from the bands being handed out to the last one finished
    /// (each thread's scan of its bands' extents included).
    pub composite: Duration,
    /// Each compositing thread's busy time, the calling thread first: the time it spent
    /// compositing its bands and scanning their extents, not its waits for a band to
    /// take over.
    pub busy: Vec<Duration>,
    /// The warp into the output image ([`Renderer::render_into`] only; zero after
    /// [`Renderer::composite`] alone).
    pub warp: Duration,
}

/// Heap-allocated workspace sized for one volume, reused across frames, rendering with
/// a configurable number of threads.
///
/// With more than one thread the intermediate image is cut into one band of scanlines
/// per thread, and each thread composites every slice into its band; a thread that
/// finishes takes over the lower half of the band with the most work left, from the
/// slice its thread has reached (the `steal` module: the load stays balanced when the
/// object fills only part of the image, with few bands). The output is bit-identical
/// to the single-threaded path because every intermediate pixel is computed by the same
/// code from the same inputs.
pub struct Renderer {
    pixels: Vec<Rgba>,
    links: Vec<opaque::Word>,
    /// Each intermediate scanline's columns that hold anything ([`warp::extents`]),
    /// found by the thread that composited the scanline's band, right after it, while
    /// the band is in its cache: the warp skips the background by them. Measured as a
    /// serial pass before the warp, the scan took 0.03 ms a frame on brainsmall to
    /// 0.3 ms on the hires brain (256², one thread), a tenth to a half of the warp.
    extents: Vec<[u32; 2]>,
    /// The intermediate image size `extents` hold, `None` when the last frame was
    /// abandoned (its bands were not all finished, and were not scanned).
    extents_of: Option<[usize; 2]>,
    rows: Vec<Vec<Rgba>>,
    shade: Box<ShadeTable>,
    threads: usize,
    shadow_alpha: Vec<u16>,
    shadow_rows: Vec<u16>,
    shade0: Box<ShadeTable>,
    /// The shading table of each pool worker, by its index in the pool, which the worker
    /// fills itself (the same entries as `shade`) and composites with. The calling
    /// thread fills `shade` every frame; had the other threads read it, the fill would
    /// first take every line they held back from their cores: on brainsmall (two
    /// threads, medians of 200 frames) it took 17.7–21.0 µs against 9.5 on one thread,
    /// all of it serial, and the worker then fetched the entries it used from the other
    /// core one miss at a time. Filling its own copy costs the worker the fill's 9.5 µs
    /// in parallel. Setup plus compositing, against the shared table (frames alternating
    /// in pairs in one process, medians of 180 each, two threads): 0.94–1.00× on
    /// brainsmall in eight of ten runs (0.74 and 0.79 in the other two), 0.98–1.01× on
    /// the head in four.
    ///
    /// The job that wakes the workers at the start of a frame, one run on each worker,
    /// fills these tables too, for the frame's lights and rotation, so that a worker
    /// already awake (frames back to back, with nothing between them) fills its table
    /// during the calling thread's setup and starts its band at once; a worker that was
    /// asleep fills it when it wakes. A band fills its worker's table again if it was
    /// not filled for the frame (a no-op when it was).
    ///
    /// The tables go by worker, not by band, because the pool hands a frame's bands to
    /// whichever worker is free: with more than one worker, a table filled by the job of
    /// one and read by the band of another would sit in the wrong core's cache, the
    /// cost the copies are there to avoid.
    own_shade: Arc<[Mutex<ShadeTable>]>,
    supersample: usize,
    flat_voxels: FlatVoxels,
    fov: Option<f64>,
    /// Clipping planes applied as slices are composited ([`Renderer::set_clip`]).
    clip: Clip,
    /// The other `threads - 1` workers, started once. Starting a thread took about 40 µs
    /// here, twice a frame; waking a parked worker took 2 µs right after its last job
    /// and 40–60 µs after a millisecond asleep.
    pool: Option<rayon::ThreadPool>,
    /// The instruction-set build of the compositing loop ([`Isa::detect`] by default).
    isa: Isa,
    /// The last frame's phases.
    times: FrameTimes,
}

impl Renderer {
    /// Fewest scanlines a band is split into in threaded rendering.
    pub const BAND_ROWS: usize = 8;

    /// Allocates for any view of `grid` (buffers grow if a frame needs more), one thread.
    pub fn new(grid: &Grid) -> Self {
        Self::with_threads(grid, 1)
    }

    /// As [`Renderer::new`], compositing with `threads` threads (at least 1).
    pub fn with_threads(grid: &Grid, threads: usize) -> Self {
        let pool = (threads > 1)
            .then(|| {
                rayon::ThreadPoolBuilder::new()
                    .num_threads(threads - 1)
                    .thread_name(|i| format!("shearwarp-{}", i + 1))
                    .build()
                    .ok()
            })
            .flatten();
        // Without a pool (it could not be started) the calling thread works alone.
        let threads = if pool.is_some() { threads } else { 1 };
        let pix = view::max_intermediate_pixels(grid.dims);
        let m = grid.dims.iter().copied().max().unwrap_or(1);
        Renderer {
            pixels: vec![[0; 4]; pix],
            links: vec![0; pix],
            extents: Vec::new(),
            extents_of: None,
            rows: (0..threads)
                .map(|_| vec![[0; 4]; composite::row_buffer_len(m)])
                .collect(),
            shade: Box::new(ShadeTable::UNSHADED),
            threads,
            shadow_alpha: Vec::new(),
            shadow_rows: vec![0; shadow::row_buffer_len(m)],
            shade0: Box::new(ShadeTable::UNSHADED),
            own_shade: (1..threads)
                .map(|_| Mutex::new(ShadeTable::UNSHADED))
                .collect(),
            supersample: 1,
            flat_voxels: FlatVoxels::Blended,
            fov: None,
            clip: Clip::NONE,
            pool,
            isa: Isa::detect(),
            times: FrameTimes::default(),
        }
    }

    /// Composites with the `isa` build of the core's loop (a level this CPU lacks runs
    /// the highest one below it); every level gives the same image.
    pub fn set_isa(&mut self, isa: Isa) {
        self.isa = isa;
    }

    /// The instruction-set level compositing runs at.
    pub fn isa(&self) -> Isa {
        self.isa.effective()
    }

    /// Composites at `s` intermediate pixels per voxel (1..=4; see
    /// [`shearwarp_core::view::Factorization::with_supersampling`]).
    pub fn set_supersample(&mut self, s: usize) -> Result<(), Error> {
        if !(1..=4).contains(&s) {
            return Err(Error::BadParameter {
                reason: "supersampling factor must be 1..=4",
            });
        }
        self.supersample = s;
        Ok(())
    }

    /// How voxels with a zero gradient enter a sample's colour
    /// ([`shearwarp_core::composite::FlatVoxels`]; blended by default).
    pub fn set_flat_voxels(&mut self, f: FlatVoxels) {
        self.flat_voxels = f;
    }

    /// Renders perspective views with a `fov` (degrees) field of view, or parallel
    /// projection with `None` (see [`shearwarp_core::view::Factorization::perspective`]).
    pub fn set_perspective(&mut self, fov: Option<f64>) {
        self.fov = fov;
    }

    /// Cuts every frame by clipping planes `clip`, made for the grid of the volumes
    /// rendered, as their slices are composited ([`Settings::clip`]): planes that move
    /// from frame to frame cost no encoding. [`Clip::NONE`] (the default) cuts nothing.
    pub fn set_clip(&mut self, clip: Clip) {
        self.clip = clip;
    }

    /// Number of compositing threads.
    pub fn threads(&self) -> usize {
        self.threads
    }

    /// Where the last frame's time went. Measuring costs a few clock reads a frame.
    pub fn times(&self) -> &FrameTimes {
        &self.times
    }

    /// Renders one frame of `source`; returns RGBA8 pixels, row-major.
    pub fn render<S: SliceSource + Clone + Send>(
        &mut self,
        source: &mut S,
        camera: &Camera,
        look: &Look,
    ) -> Result<Vec<[u8; 4]>, Error> {
        let mut out = Vec::new();
        self.render_into(source, camera, look, &mut out)?;
        Ok(out)
    }

    /// As [`Renderer::render`], into `out` (resized to the image; its allocation is
    /// reused, as a caller rendering frame after frame wants: a fresh megabyte-sized
    /// buffer per frame costs page faults on every frame).
    pub fn render_into<S: SliceSource + Clone + Send>(
        &mut self,
        source: &mut S,
        camera: &Camera,
        look: &Look,
        out: &mut Vec<[u8; 4]>,
    ) -> Result<(), Error> {
        let frame = self.composite(source, camera, look)?;
        let start = Instant::now();
        self.warp_into(&frame.view, out)?;
        self.times.warp = start.elapsed();
        Ok(())
    }

    /// Composites every slice of `source` into the held intermediate image and returns
    /// the frame (its `view` says how to warp it). Each thread starts with an equal band
    /// of scanlines and takes over half of another's band (at least
    /// [`Renderer::BAND_ROWS`] scanlines) when it finishes; with shadows the whole image
    /// is one band on the calling thread.
    pub fn composite<S: SliceSource + Clone + Send>(
        &mut self,
        source: &mut S,
        camera: &Camera,
        look: &Look,
    ) -> Result<Frame, Error> {
        let frame = self.composite_until(source, camera, look, &|| true)?;
        frame.ok_or(Error::Source {
            reason: "compositing stopped without being asked to",
        })
    }

    /// As [`Renderer::composite`], asking `keep_going` before every slice of every band
    /// ([`shearwarp_core::render::composite_band_until`]); `None` when it said no and the frame was
    /// abandoned.
    pub fn composite_until<S: SliceSource + Clone + Send>(
        &mut self,
        source: &mut S,
        camera: &Camera,
        look: &Look,
        keep_going: &(dyn Fn() -> bool + Sync),
    ) -> Result<Option<Frame>, Error> {
        let start = Instant::now();
        self.times.warp = Duration::ZERO;
        // A parked worker takes 0.06–0.17 ms to start a job here, which the calling
        // thread would spend compositing alone. Waking every worker now, with a job run
        // once on each (a broadcast), lets that overlap the frame's serial setup
        // (factorization, shading table). Measured
        // inside the renderer (means of 200 two-thread frames, two alternating runs at
        // 256²), the worker then started 0.04 ms after the bands were posted instead of
        // 0.06–0.12 ms, and the compositing phase took 0.87–0.92 ms instead of
        // 0.95–0.98 ms on brainsmall, 3.86–4.11 ms instead of 4.45–4.61 ms on the head.
        // With lights the job also fills that worker's shading table (`own_shade`): an
        // awake worker then fills it during the setup instead of at the start of its
        // band (brainsmall at 256², frames back to back: 1.78–1.80× → 1.80–1.84× over
        // one thread in six alternating pairs of runs).
        if let Some(pool) = self.pool.as_ref().filter(|_| !look.shadows) {
            let fill = look.lighting.clone().map(|l| {
                let rotation = view::rotation(camera.rotate_x, camera.rotate_y);
                (Arc::clone(&self.own_shade), l, rotation, self.isa)
            });
            pool.spawn_broadcast(move |worker| {
                let Some((tables, l, rotation, isa)) = &fill else {
                    return;
                };
                // A failed fill (invalid lights) is the band's to report: it fills
                // again, and returns the error.
                if let Some(Ok(mut t)) = tables.get(worker.index()).map(|t| t.lock()) {
                    let _ = isa::fill_shade(*isa, &mut t, l, rotation);
                }
            });
        }
        let settings = Settings {
            mode: look.mode,
            color: &look.color,
            lighting: look.lighting.as_ref(),
            ert_threshold: look.ert_threshold,
            depth_cue: look.depth_cue,
            shadows: look.shadows,
            flat_voxels: self.flat_voxels,
            clip: self.clip,
        };
        let grid = source.grid();
        let shade0 = look.shadows.then_some(&mut *self.shade0);
        let view = match self.fov {
            Some(fov) => Factorization::perspective(&grid, camera, fov)?,
            None => Factorization::new(&grid, camera)?.with_supersampling(self.supersample)?,
        };
        // The shading table filled by this CPU's widest build; the frame's setup finds
        // it filled for its lights. With shadows the setup fills it for the other
        // lights, and the first light's table apart.
        if let (Some(l), false) = (&look.lighting, look.shadows) {
            isa::fill_shade(self.isa, &mut self.shade, l, &view.rotation)?;
        }
        let frame = Frame::with_view(&grid, view, &settings, &mut self.shade, shade0)?;
        let shade0 = look.shadows.then_some(&*self.shade0);
        let tables = frame.tables(&self.shade, shade0);
        let [iw, ih] = frame.view.intermediate;
        let n = iw * ih;
        if self.pixels.len() < n {
            self.pixels.resize(n, [0; 4]);
            self.links.resize(n, 0);
        }
        if self.extents.len() < ih {
            self.extents.resize(ih, [0, 0]);
        }
        self.extents_of = None;
        let need_row = composite::rows_needed(&frame.view);
        for r in &mut self.rows {
            if r.len() < need_row {
                r.resize(need_row, [0; 4]);
            }
        }
        let posted = Instant::now();
        self.times.setup = posted - start;
        let pool = match &self.pool {
            Some(p) if frame.shadow.is_none() && self.rows.len() > 1 => p,
            _ => {
                // One thread, or shadows (the shadow buffer is swept with the slices): the
                // whole image is one band, composited on the calling thread.
                let shadow = match &frame.shadow {
                    Some(sf) => {
                        let sn = sf.size[0] * sf.size[1];
                        if self.shadow_alpha.len() < sn {
                            self.shadow_alpha.resize(sn, 0);
                        }
                        Some((&mut self.shadow_alpha[..], &mut self.shadow_rows[..]))
                    }
                    None => None,
                };
                let mut img =
                    Intermediate::new(iw, ih, &mut self.pixels[..n], &mut self.links[..n])?;
                let rows = &mut self.rows[0];
                let nk = frame.view.dims[2];
                let reached = isa::composite_band_until(
                    self.isa,
                    source,
                    &frame,
                    &tables,
                    &mut img,
                    rows,
                    shadow,
                    0..nk,
                    &mut || keep_going(),
                )?;
                let done = reached == nk;
                if done {
                    warp::extents(img.pixels(), iw, &mut self.extents[..ih])?;
                    self.extents_of = Some([iw, ih]);
                }
                self.times.composite = posted.elapsed();
                self.times.busy.clear();
                self.times.busy.push(self.times.composite);
                return Ok(done.then_some(frame));
            }
        };
        const PANICKED: &str = "a compositing thread panicked";
        // Equal bands to start with, one per thread; they are split as threads finish.
        let threads = self.rows.len();
        let stride = opaque::words(iw);
        let mut starts = Vec::with_capacity(threads);
        let (mut px, mut op, mut ex) = (
            &mut self.pixels[..n],
            &mut self.links[..stride * ih],
            &mut self.extents[..ih],
        );
        for t in 0..threads {
            let (row0, rows) = (ih * t / threads, ih * (t + 1) / threads - ih * t / threads);
            let (p, rest) = std::mem::take(&mut px).split_at_mut(rows * iw);
            px = rest;
            let (o, rest) = std::mem::take(&mut op).split_at_mut(rows * stride);
            op = rest;
            let (e, rest) = std::mem::take(&mut ex).split_at_mut(rows);
            ex = rest;
            starts.push((row0, rows, p, o, e));
        }
        let nk = frame.view.dims[2];
        let sharing = Sharing::new(
            nk,
            Renderer::BAND_ROWS,
            starts.iter().map(|s| s.1).collect(),
        );
        let stopped = AtomicBool::new(false);
        let isa = self.isa;
        // Lights of the threads' own shading tables; without them every thread reads the
        // unshaded table `tables` holds.
        let lights = look.lighting.as_ref();
        let own_shade = &*self.own_shade;
        let rotation = frame.view.rotation;
        // One worker per row buffer, each with its own handle on the source, its busy
        // time, its shading table and its starting band.
        let work =
            |(t, (rows, mut src, busy), start): (usize, Own<'_, S>, _)| -> Result<(), Error> {
                let began = Instant::now();
                let (mut held, own);
                // The table of the worker this band runs on (none on the calling thread,
                // which is not one of the pool's).
                let shade = pool.current_thread_index().and_then(|i| own_shade.get(i));
                let tables = match (shade, lights) {
                    (Some(sh), Some(l)) => {
                        held = sh.lock().map_err(|_| Error::Source { reason: PANICKED })?;
                        isa::fill_shade(isa, &mut held, l, &rotation)?;
                        own = frame.tables(&held, None);
                        &own
                    }
                    _ => &tables,
                };
                *busy = began.elapsed();
                let (row0, here, p, l, e): Start<'_> = start;
                let _retire = Retire {
                    sharing: &sharing,
                    t,
                };
                let img = Intermediate::band(iw, ih, row0, here, p, l)?;
                let mut piece = Some(Piece {
                    img,
                    extents: e,
                    next: 0,
                });
                while let Some(mut p) = piece {
                    while p.next < nk {
                        let mut abandon = false;
                        let mut at = p.next;
                        let go = &mut || {
                            if sharing.wanted(t, at) {
                                return false;
                            }
                            at += 1;
                            abandon = !keep_going();
                            !abandon
                        };
                        let began = Instant::now();
                        let reached = isa::composite_band_until(
                            isa,
                            &mut src,
                            &frame,
                            tables,
                            &mut p.img,
                            rows,
                            None,
                            p.next..nk,
                            go,
                        );
                        *busy += began.elapsed();
                        p.next = reached?;
                        if abandon {
                            // The frame holds no extents: none to scan.
                            stopped.store(true, Ordering::Relaxed);
                            return Ok(());
                        }
                        if p.next < nk {
                            sharing.serve(t, &mut p)?;
                        }
                    }
                    let began = Instant::now();
                    warp::extents(p.img.pixels(), iw, p.extents)?;
                    *busy += began.elapsed();
                    sharing.retire(t);
                    piece = sharing.steal(t)?;
                }
                Ok(())
            };
        self.times.busy.resize(threads, Duration::ZERO);
        let own = self.rows.iter_mut().zip(self.times.busy.iter_mut());
        let each = (0..threads)
            .zip(own.map(|(rows, busy)| (rows, source.clone(), busy)))
            .zip(starts)
            .map(|((t, r), s)| (t, r, s));
        on_threads(pool, each, work, PANICKED)?;
        self.times.composite = posted.elapsed();
        let done = !stopped.load(Ordering::Relaxed);
        self.extents_of = done.then_some([iw, ih]);
        Ok(done.then_some(frame))
    }

    /// Warps the intermediate image left by [`Renderer::composite`] through `view` (that
    /// frame's view, or one whose image-to-intermediate map was changed, e.g. for zoom),
    /// output rows split across the threads; returns `view.image` RGBA8 pixels.
    pub fn warp(&self, view: &Factorization) -> Result<Vec<[u8; 4]>, Error> {
        let mut out = Vec::new();
        self.warp_into(view, &mut out)?;
        Ok(out)
    }

    /// As [`Renderer::warp`], into `frame` (resized to the image; every pixel is written).
    pub fn warp_into(&self, view: &Factorization, frame: &mut Vec<[u8; 4]>) -> Result<(), Error> {
        let [iw, ih] = view.intermediate;
        let pixels = self.held_pixels(iw, ih)?;
        let [w, h] = view.image;
        frame.resize(w * h, [0; 4]);
        if w == 0 || h == 0 {
            return Ok(());
        }
        let ext = self.extents(pixels, iw, ih)?;
        let ext = Some(&ext[..]);
        // Strips of TILE_ROWS rows, each warped in place: the strip is the warp's row
        // buffer ([`warp::InPlace`]).
        const STRIP: usize = warp::TILE_ROWS;
        let strip = |i: usize, chunk: &mut [[u8; 4]]| {
            let rows = i * STRIP..i * STRIP + chunk.len() / w;
            isa::warp_rows(self.isa, pixels, ext, view, rows, chunk, &mut warp::InPlace)
        };
        let Some(pool) = self.pool.as_ref().filter(|_| self.rows.len() > 1) else {
            let mut strips = frame.chunks_mut(STRIP * w).enumerate();
            return strips.try_for_each(|(i, chunk)| strip(i, chunk));
        };
        // Every row is computed on its own, so the result does not depend on the split.
        // Strips are claimed as threads finish: the object rarely covers the top and
        // bottom halves of the image alike. The calling thread claims them from one end
        // of the image and the others from the other end: the calling thread composited
        // the intermediate image's top band, which the output's top rows read when the
        // map runs down the intermediate image (`image_to_intermediate[1][1] >= 0`), its
        // bottom rows otherwise, so each thread mostly reads pixels its own cache holds.
        // That holds where the scanline changes down the output image; in views whose
        // scanlines run across it (half of a turn about the vertical axis), every strip
        // reads every band whichever end it is taken from (brainsmall at 256²: the
        // two-thread warp gains 1.35× there, 1.52× in the other views; a split by
        // columns, measured instead, was slower, see docs/bench-history.md). Two threads, frames
        // alternating in pairs in one process (medians of 180 warps), against claiming
        // from the top only: 0.85–0.91× the time in six of eight comparisons on
        // brainsmall and the head at 256² and 512², 0.99 and 1.01 in the other two; with
        // the ends the other way round, 0.93–1.02×.
        const PANICKED: &str = "a warp thread panicked";
        let strips = Mutex::new(frame.chunks_mut(STRIP * w).enumerate());
        let top_first = view.image_to_intermediate[1][1] >= 0.0;
        let work = |t: usize| -> Result<(), Error> {
            let forward = (t == 0) == top_first;
            loop {
                let next = {
                    let mut left = strips
                        .lock()
                        .map_err(|_| Error::Source { reason: PANICKED })?;
                    if forward {
                        left.next()
                    } else {
                        left.next_back()
                    }
                };
                let Some((i, chunk)) = next else {
                    return Ok(());
                };
                strip(i, chunk)?;
            }
        };
        on_threads(pool, 0..self.rows.len(), work, PANICKED)
    }
}

impl Renderer {
    /// As [`Renderer::render`], with 16 bits per channel: the intermediate image is Q15,
    /// so the warp's bilinear sums are kept at that precision ([`Renderer::warp16`]).
    pub fn render16<S: SliceSource + Clone + Send>(
        &mut self,
        source: &mut S,
        camera: &Camera,
        look: &Look,
    ) -> Result<Vec<[u16; 4]>, Error> {
        let frame = self.composite(source, camera, look)?;
        self.warp16(&frame.view)
    }

    /// The warp of [`Renderer::warp`] at 16 bits per channel: the core's
    /// `warp::warp_rows_q15` (the same positions and weights as the 8-bit warp, before
    /// rounding) scaled to 0..65535. Rounding it to 8 bits (`(v · 255 + 32767) / 65535`)
    /// gives the 8-bit frame within 1.
    pub fn warp16(&self, view: &Factorization) -> Result<Vec<[u16; 4]>, Error> {
        let [iw, ih] = view.intermediate;
        let px = self.held_pixels(iw, ih)?;
        let [w, h] = view.image;
        let q15 = shearwarp_core::fixed::ONE as u64;
        let mut out = vec![[0u16; 4]; w * h];
        let mut row = vec![[0u16; 4]; warp::TILE_ROWS * w];
        let ext = self.extents(px, iw, ih)?;
        warp::warp_rows_q15(px, Some(&ext), view, 0..h, &mut row, |y, r| {
            for (o, p) in out[y * w..(y + 1) * w].iter_mut().zip(r) {
                *o = p.map(|q| ((q as u64 * 65535 + q15 / 2) / q15) as u16);
            }
            Ok(())
        })?;
        Ok(out)
    }

    /// The held intermediate image's first `iw×ih` pixels, as the warps read them.
    fn held_pixels(&self, iw: usize, ih: usize) -> Result<&[Rgba], Error> {
        self.pixels.get(..iw * ih).ok_or(Error::BufferTooSmall {
            what: "intermediate pixels",
            needed: iw * ih,
            got: self.pixels.len(),
        })
    }

    /// The columns of each scanline of the `iw×ih` intermediate image `px` that hold
    /// anything ([`warp::extents`]), for the warp to skip the background by: those the
    /// compositing threads found, or a scan now if they are not of this image.
    fn extents<'a>(
        &'a self,
        px: &[Rgba],
        iw: usize,
        ih: usize,
    ) -> Result<std::borrow::Cow<'a, [[u32; 2]]>, Error> {
        if self.extents_of == Some([iw, ih]) {
            return Ok(std::borrow::Cow::Borrowed(&self.extents[..ih]));
        }
        let mut ext = vec![[0u32; 2]; ih];
        warp::extents(px, iw, &mut ext)?;
        Ok(std::borrow::Cow::Owned(ext))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{color_table, encode, Classification, Encoded};
    use crate::volume::{RawVolume, Voxels};
    use shearwarp_core::composite::Mode;
    use shearwarp_core::shade::Lighting;

    /// An off-centre ball, 37×30×26, encoded, and an unlit look.
    fn ball() -> (Encoded, Look) {
        let dims = [37usize, 30, 26];
        let mut v = Vec::new();
        for z in 0..dims[2] {
            for y in 0..dims[1] {
                for x in 0..dims[0] {
                    let d = ((x as f64 - 22.0).powi(2)
                        + (y as f64 - 12.0).powi(2)
                        + (z as f64 - 11.0).powi(2))
                    .sqrt();
                    v.push((240.0 - 22.0 * d).clamp(0.0, 255.0) as u8);
                }
            }
        }
        let raw = RawVolume {
            name: "ball".into(),
            dims,
            spacing: [1.0, 1.0, 1.0],
            voxels: Voxels::U8(v),
        };
        let class = Classification {
            opacity: vec![(0.0, 0.0), (60.0, 0.0), (200.0, 0.8)],
            gradient: None,
            min_opacity: 0.02,
            cut: crate::scene::Cut::NONE,
        };
        let enc = encode(&raw, &class).unwrap();
        let look = Look {
            mode: Mode::Composite,
            color: color_table(&[(0.0, [255, 255, 255])], (0, 255)).unwrap(),
            lighting: None,
            ert_threshold: 0.95,
            depth_cue: None,
            shadows: false,
        };
        (enc, look)
    }

    /// Threads after the first shade from tables they fill themselves: frame after
    /// frame, as the view turns and the lights change (or go, or come back with the
    /// view unchanged), two and three threads give one thread's image. Fails if a
    /// thread's table is left filled for an earlier frame's lights or rotation.
    #[test]
    fn threads_shade_like_one_thread_as_views_and_lights_change() {
        let (enc, unlit) = ball();
        let white = Lighting::default();
        let mut coloured = white.clone();
        coloured.lights[0] = shearwarp_core::shade::Light {
            direction: [-0.7, 0.2, 0.6],
            color: [1.0, 0.5, 0.2],
        };
        coloured.ks = 0.6;
        let lit = |l: &Lighting| Look {
            lighting: Some(l.clone()),
            ..unlit.clone()
        };
        let frames = [
            (10.0, 20.0, lit(&white)),
            (10.0, 50.0, lit(&white)),
            (10.0, 50.0, lit(&coloured)),
            (10.0, 50.0, unlit.clone()),
            (10.0, 50.0, lit(&coloured)),
            (-35.0, 120.0, lit(&coloured)),
            (-35.0, 120.0, lit(&white)),
        ];
        let cam = |rx: f64, ry: f64| Camera {
            rotate_x: rx,
            rotate_y: ry,
            width: 70,
            height: 60,
        };
        let mut one = Renderer::with_threads(&enc.grid, 1);
        let want: Vec<Vec<[u8; 4]>> = frames
            .iter()
            .map(|(rx, ry, look)| {
                let mut src = enc.volume().unwrap();
                one.render(&mut src, &cam(*rx, *ry), look).unwrap()
            })
            .collect();
        // The lights change the image: a table left as it was would show.
        assert!(want[1] != want[2] && want[2] != want[3] && want[5] != want[6]);
        for threads in [2, 3, 4] {
            let mut r = Renderer::with_threads(&enc.grid, threads);
            for (i, (rx, ry, look)) in frames.iter().enumerate() {
                let mut src = enc.volume().unwrap();
                let got = r.render(&mut src, &cam(*rx, *ry), look).unwrap();
                assert!(got == want[i], "frame {i}, {threads} threads");
            }
        }
    }

    /// The extents the compositing threads leave are a scan of the finished image, for
    /// every band split; an abandoned frame leaves none, and the warp scans instead.
    #[test]
    fn held_extents_equal_a_scan_of_the_composited_image() {
        let (enc, look) = ball();
        for threads in [1, 2, 3] {
            let mut r = Renderer::with_threads(&enc.grid, threads);
            for (rx, ry) in [(10.0, 20.0), (-40.0, 75.0), (80.0, -5.0)] {
                let cam = Camera {
                    rotate_x: rx,
                    rotate_y: ry,
                    width: 70,
                    height: 60,
                };
                let frame = r
                    .composite(&mut enc.volume().unwrap(), &cam, &look)
                    .unwrap();
                let [iw, ih] = frame.view.intermediate;
                let mut scan = vec![[0u32; 2]; ih];
                warp::extents(&r.pixels[..iw * ih], iw, &mut scan).unwrap();
                assert_eq!(r.extents_of, Some([iw, ih]), "threads {threads}");
                assert!(
                    r.extents[..ih] == scan[..],
                    "threads {threads}, view {rx} {ry}"
                );
                assert!(scan.iter().any(|e| e[1] > e[0]), "the ball is in view");
            }
            // Stopped after a few slices: no extents are held.
            let calls = AtomicUsize::new(0);
            let go = || calls.fetch_add(1, Ordering::Relaxed) < 5;
            let cam = Camera {
                rotate_x: 0.0,
                rotate_y: 30.0,
                width: 70,
                height: 60,
            };
            let mut src = enc.volume().unwrap();
            assert!(r
                .composite_until(&mut src, &cam, &look, &go)
                .unwrap()
                .is_none());
            assert_eq!(r.extents_of, None, "threads {threads}");
        }
    }

    /// The phase times cover what they say: one busy entry per thread, each inside the
    /// compositing phase; the warp counted by `render_into` only.
    #[test]
    fn frame_times_have_a_busy_span_per_thread_inside_the_compositing() {
        let (enc, look) = ball();
        let cam = Camera {
            rotate_x: 10.0,
            rotate_y: 20.0,
            width: 70,
            height: 60,
        };
        let mut out = Vec::new();
        for threads in [1, 2, 3] {
            let mut r = Renderer::with_threads(&enc.grid, threads);
            let mut src = enc.volume().unwrap();
            r.render_into(&mut src, &cam, &look, &mut out).unwrap();
            let t = r.times().clone();
            assert_eq!(t.busy.len(), threads);
            let inside = |b: &Duration| Duration::ZERO < *b && *b <= t.composite;
            assert!(t.busy.iter().all(inside), "{t:?}");
            assert!(t.warp > Duration::ZERO, "{t:?}");
            r.composite(&mut src, &cam, &look).unwrap();
            assert_eq!(r.times().warp, Duration::ZERO);
            assert_eq!(r.times().busy.len(), threads);
        }
    }
}
