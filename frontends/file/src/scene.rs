//! Owned buffers around the core: classify and run-length encode a loaded volume, and
//! render frames of it into an RGBA frame buffer.

use crate::volume::{RawVolume, Voxels};
use shearwarp_core::classify::{
    self, ColorTable, ColorTf, GradientTf, Grid, OpacityTf, Scalars, Voxel,
};
use shearwarp_core::composite::{self, Intermediate, Mode, Rgba};
use shearwarp_core::depth::DepthCue;
use shearwarp_core::opaque;
use shearwarp_core::render::{Frame, Settings};
use shearwarp_core::rle::{self, Axis, RleAxis, ScanIndex};
use shearwarp_core::shade::{Lighting, ShadeTable};
use shearwarp_core::shadow;
use shearwarp_core::source::{RleVolume, SliceSource};
use shearwarp_core::view::{self, Camera, Factorization};
use shearwarp_core::warp::FrameBuffer;
use shearwarp_core::Error;
use shearwarp_core::{io, postclass, swv, warp};

use crate::bigbuf;
use crate::isa::{self, Isa};
use crate::reslice;
use crate::steal::{Piece, Retire, Sharing};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// Everything about appearance that is decided when the volume is encoded.
#[derive(Clone, Debug)]
pub struct Classification {
    /// Opacity transfer function `(raw value, opacity per smallest spacing)`.
    pub opacity: Vec<(f64, f64)>,
    /// Optional opacity factor over gradient magnitude.
    pub gradient: Option<Vec<(f64, f64)>>,
    /// Voxels with opacity at or below this (0..1) are stored as transparent.
    pub min_opacity: f64,
}

/// The classified volume, run-length encoded along all three axes.
pub struct Encoded {
    /// Geometry.
    pub grid: Grid,
    /// Raw value range that the 8-bit scalars were quantised over.
    pub range: (u16, u16),
    /// Opacity threshold used for transparency.
    pub threshold: u8,
    runs: [Vec<u8>; 3],
    voxels: [Vec<Voxel>; 3],
    scans: [Vec<ScanIndex>; 3],
}

fn opacity_points(p: &[(f64, f64)]) -> Vec<(f64, [f64; 1])> {
    p.iter().map(|&(v, a)| (v, [a])).collect()
}

/// Classifies and encodes `raw`.
pub fn encode(raw: &RawVolume, class: &Classification) -> Result<Encoded, Error> {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    encode_threads(raw, class, cores)
}

/// As [`encode`], on up to `threads` threads (1: all on the calling thread, as the
/// single-thread benchmark measures it). No dense classified copy of the volume is made:
/// the z copy is classified and encoded a few slices at a time, its slices split between
/// the threads, and the x and y copies are re-sliced from it ([`reslice`]). Against
/// classifying into a dense copy and transposing it for x and y (which the viewer still
/// does, see [`encode_axis`]): one thread, medians of five, alternating runs, nested
/// spheres 256³ 156–191 → 115–138 ms, the MR heads within the spread; peak memory
/// encoding the hires brain 363 → 246 MB.
pub fn encode_threads(
    raw: &RawVolume,
    class: &Classification,
    threads: usize,
) -> Result<Encoded, Error> {
    let grid = Grid::new(raw.dims, raw.spacing)?;
    let scalars = match &raw.voxels {
        Voxels::U8(d) => Scalars::U8(d),
        Voxels::U16(d) => Scalars::U16(d),
    };
    let pts = opacity_points(&class.opacity);
    let tf = OpacityTf::new(&pts)?;
    let mut table = vec![0u8; scalars.value_count()];
    tf.build_table(&mut table);
    let gpts = class.gradient.as_deref().map(opacity_points);
    let gtable = match &gpts {
        Some(g) => Some(GradientTf::new(g)?.build_table()),
        None => None,
    };
    if !(0.0..1.0).contains(&class.min_opacity) {
        return Err(Error::BadParameter {
            reason: "minimum opacity must be in [0, 1)",
        });
    }
    let threshold = (class.min_opacity * 255.0).floor() as u8;
    let classifier = reslice::Classifier {
        grid: &grid,
        scalars,
        opacity_table: &table,
        gradient_table: gtable.as_ref(),
        threshold,
    };
    let [x, y, z] = reslice::encode_all(&classifier, threads)?;
    let runs = [x.0, y.0, z.0];
    let voxels = [x.1, y.1, z.1];
    let scans = [x.2, y.2, z.2];
    Ok(Encoded {
        grid,
        range: scalars.range(),
        threshold,
        runs,
        voxels,
        scans,
    })
}

/// The run-length copy of `dense` along `axis` as owned arrays (the route of a caller
/// that keeps a dense classified copy anyway, as the viewer does to re-classify
/// quickly), for a volume with `visible` voxels above `threshold`
/// ([`rle::is_visible`]): runs are allocated for the worst case (`ni + 2` per scanline,
/// zero pages until written) and trimmed, so no counting pass is needed.
pub fn encode_axis(
    dense: &[Voxel],
    grid: &Grid,
    axis: Axis,
    threshold: u8,
    visible: usize,
) -> Result<AxisArrays, Error> {
    let [ni, nj, nk] = axis.permuted_dims(grid.dims);
    let mut runs = bigbuf::zeroed_bytes(nj * nk * (ni + 2));
    let mut voxels = bigbuf::filled(visible, Voxel::default());
    let mut scans = bigbuf::filled(nj * nk + 1, ScanIndex::default());
    let used = encode_slabs(
        dense,
        grid,
        axis,
        threshold,
        &mut runs,
        &mut voxels,
        &mut scans,
    )?;
    runs.truncate(used);
    runs.shrink_to_fit();
    Ok((runs, voxels, scans))
}

/// x slices transposed together by [`encode_slabs`]: each volume row then gives 256
/// contiguous bytes (four cache lines) per slab. Measured on a 256³ volume: 16 slices
/// 93 ms, 32 slices 73 ms, 64 slices 67 ms for the x copy (the strided walk: 122 ms).
const X_SLAB: usize = 64;

/// Voxels in a 64-byte cache line: the padding between transposed slices.
const LINE: usize = 16;

/// `rle::encode` of `dense` along `axis`, returning the number of runs used. The x and y
/// copies read the volume across its storage order; instead of walking it with a stride
/// (which misses the cache on nearly every voxel), slices are transposed into a buffer a
/// few at a time, reading the volume in order, and fed to the core's [`rle::Encoder`].
/// The result is the same as `rle::encode` (tested).
pub fn encode_slabs(
    dense: &[Voxel],
    grid: &Grid,
    axis: Axis,
    threshold: u8,
    runs: &mut [u8],
    voxels: &mut [Voxel],
    scans: &mut [ScanIndex],
) -> Result<usize, Error> {
    let [nx, ny, nz] = grid.dims;
    let [ni, nj, nk] = axis.permuted_dims(grid.dims);
    if dense.len() < grid.voxel_count() {
        return Err(Error::BufferTooSmall {
            what: "dense voxels",
            needed: grid.voxel_count(),
            got: dense.len(),
        });
    }
    let mut enc = rle::Encoder::new(grid, axis, threshold, runs, voxels, scans)?;
    let plane = ni * nj;
    if axis == Axis::Z {
        for k in 0..nk {
            enc.push_slice(&dense[k * plane..(k + 1) * plane])?;
        }
    } else {
        // An x slice uses one voxel of each volume row, so [`X_SLAB`] of them are
        // gathered together, a cache line further apart than their size (so the lines a
        // tile writes do not share a cache set). A y slice is gathered from whole rows
        // of the volume, one slice at a time, which stays in the cache while it is
        // written.
        let (group, pitch) = match axis {
            Axis::X => (X_SLAB, plane + LINE),
            _ => (1, plane),
        };
        let mut slab = bigbuf::filled(group * pitch, Voxel::default());
        for k0 in (0..nk).step_by(group) {
            let g = group.min(nk - k0);
            if axis == Axis::X {
                // Slice x = k0 + s holds (i, j) = (y, z): per z, the rows y of the
                // volume become columns of the slices.
                for z in 0..nz {
                    let src = Strided {
                        offset: z * ny * nx + k0,
                        stride: nx,
                    };
                    let dst = Strided {
                        offset: z * ny,
                        stride: pitch,
                    };
                    transpose(dense, src, &mut slab, dst, [ny, g]);
                }
            } else {
                // Slice y = k0 holds (i, j) = (z, x): the rows z of the volume become
                // its columns.
                let src = Strided {
                    offset: k0 * nx,
                    stride: nx * ny,
                };
                let dst = Strided {
                    offset: 0,
                    stride: nz,
                };
                transpose(dense, src, &mut slab, dst, [nz, nx]);
            }
            for s in 0..g {
                enc.push_slice(&slab[s * pitch..s * pitch + plane])?;
            }
        }
    }
    Ok(enc.finish()?.parts().0.len())
}

/// A matrix inside a flat array: element `(r, c)` at `offset + r·stride + c`.
#[derive(Clone, Copy)]
struct Strided {
    offset: usize,
    stride: usize,
}

/// Writes the `rows × cols` matrix `src` transposed into `dst` (`dst(c, r) = src(r,
/// c)`), in 16×16 tiles so that both sides touch whole cache lines.
fn transpose(src: &[Voxel], s: Strided, dst: &mut [Voxel], d: Strided, [rows, cols]: [usize; 2]) {
    const T: usize = 16;
    let mut tile = [[Voxel::default(); T]; T];
    for r0 in (0..rows).step_by(T) {
        let tr = T.min(rows - r0);
        for c0 in (0..cols).step_by(T) {
            let tc = T.min(cols - c0);
            // Whole tile rows in, whole tile columns out: both sides move contiguous
            // runs of voxels, and the shuffle happens in the local tile.
            for (r, line) in tile.iter_mut().enumerate().take(tr) {
                let at = s.offset + (r0 + r) * s.stride + c0;
                let from = &src[at..at + tc];
                match <&[Voxel; T]>::try_from(from) {
                    // A fixed-size copy: a few vector moves instead of a memmove call.
                    Ok(full) => *line = *full,
                    Err(_) => line[..tc].copy_from_slice(from),
                }
            }
            for c in 0..tc {
                let at = d.offset + (c0 + c) * d.stride + r0;
                for (o, line) in dst[at..at + tr].iter_mut().zip(&tile) {
                    *o = line[c];
                }
            }
        }
    }
}

/// Runs, voxels and scanline index of one axis copy.
pub type AxisArrays = (Vec<u8>, Vec<Voxel>, Vec<ScanIndex>);

/// Level `level` of `raw`'s level-of-detail pyramid (0: `raw` itself), built with the
/// core's centred 2×2×2 means ([`shearwarp_core::lod`]); returns the volume and its grid,
/// which keeps `raw`'s opacity unit and framing (set it on the encoded level with
/// [`Encoded::as_level`]).
pub fn lod(raw: &RawVolume, level: usize) -> Result<(RawVolume, Grid), Error> {
    let mut grid = Grid::new(raw.dims, raw.spacing)?;
    // The level being halved: `raw` itself at first (borrowed, not copied).
    let mut built: Option<RawVolume> = None;
    for _ in 0..level {
        let current = built.as_ref().unwrap_or(raw);
        let (voxels, next) = match &current.voxels {
            Voxels::U8(d) => halve(d, &grid).map(|(m, g)| (Voxels::U8(m), g))?,
            Voxels::U16(d) => halve(d, &grid).map(|(m, g)| (Voxels::U16(m), g))?,
        };
        grid = next;
        built = Some(RawVolume {
            name: raw.name.clone(),
            dims: grid.dims,
            spacing: grid.spacing,
            voxels,
        });
    }
    Ok((built.unwrap_or_else(|| raw.clone()), grid))
}

/// The means of the level above `d` (a `grid` volume) and that level's grid.
fn halve<T: shearwarp_core::lod::Sample + Default + Clone>(
    d: &[T],
    grid: &Grid,
) -> Result<(Vec<T>, Grid), Error> {
    let n = shearwarp_core::lod::level_dims(grid.dims);
    let count = n[0] * n[1] * n[2];
    let (mut mean, mut lo, mut hi) = (
        vec![T::default(); count],
        vec![T::default(); count],
        vec![T::default(); count],
    );
    let level = shearwarp_core::lod::downsample(d, grid, &mut mean, &mut lo, &mut hi)?;
    Ok((mean, level))
}

impl Encoded {
    /// Marks this encoding as a level of detail of `full` (see [`Grid::as_level_of`]).
    pub fn as_level(mut self, full: &Grid) -> Self {
        self.grid = self.grid.as_level_of(full);
        self
    }

    /// Borrows the encoded copies as a renderable source.
    pub fn volume(&self) -> Result<RleVolume<'_>, Error> {
        let axis = |a: Axis| {
            let i = a as usize;
            RleAxis::new(
                self.grid.dims,
                a,
                &self.runs[i],
                &self.voxels[i],
                &self.scans[i],
            )
        };
        RleVolume::new(self.grid, [axis(Axis::X)?, axis(Axis::Y)?, axis(Axis::Z)?])
    }

    /// Non-transparent voxels stored (per axis copy).
    pub fn visible_voxels(&self) -> usize {
        self.voxels[2].len()
    }

    /// Total bytes of the three copies.
    pub fn bytes(&self) -> usize {
        (0..3)
            .map(|a| self.runs[a].len() + 4 * self.voxels[a].len() + 8 * self.scans[a].len())
            .sum()
    }
}

/// Builds the colour table for data quantised over `range`.
pub fn color_table(points: &[(f64, [u8; 3])], range: (u16, u16)) -> Result<ColorTable, Error> {
    let pts: Vec<(f64, [f64; 3])> = points
        .iter()
        .map(|&(v, c)| (v, c.map(|x| x as f64 / 255.0)))
        .collect();
    Ok(ColorTf::new(&pts)?.build_table(range))
}

/// Per-frame appearance.
#[derive(Clone, Debug)]
pub struct Look {
    /// Compositing mode.
    pub mode: Mode,
    /// Colour table.
    pub color: ColorTable,
    /// Lighting, or `None` for unshaded.
    pub lighting: Option<Lighting>,
    /// Early-ray-termination threshold.
    pub ert_threshold: f64,
    /// Depth cueing (fog), or `None`.
    pub depth_cue: Option<DepthCue>,
    /// Shadows toward the first light (rendered on one thread: the shadow buffer is
    /// swept with the slices).
    pub shadows: bool,
}

/// A thread's starting band: first scanline, scanlines, pixels, opaque-pixel bitmap,
/// extents.
type Start<'a> = (
    usize,
    usize,
    &'a mut [Rgba],
    &'a mut [opaque::Word],
    &'a mut [[u32; 2]],
);

/// What a compositing thread has to itself: its row buffer, its handle on the source,
/// its busy time ([`FrameTimes::busy`]) and, after the first thread, its shading table
/// (`Renderer::own_shade`).
type Own<'a, S> = (
    &'a mut Vec<Rgba>,
    S,
    &'a mut Duration,
    Option<&'a mut ShadeTable>,
);

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
    /// The shading table of each compositing thread after the first, which fills it
    /// itself at the start of its first band (the same entries as `shade`). The calling
    /// thread fills `shade` every frame; had the other threads read it, the fill would
    /// first take every line they held back from their cores: on brainsmall (two
    /// threads, medians of 200 frames) it took 17.7–21.0 µs against 9.5 on one thread,
    /// all of it serial, and the worker then fetched the entries it used from the other
    /// core one miss at a time. Filling its own copy costs the worker the fill's 9.5 µs
    /// in parallel. Setup plus compositing, against the shared table (frames alternating
    /// in pairs in one process, medians of 180 each, two threads): 0.94–1.00× on
    /// brainsmall in eight of ten runs (0.74 and 0.79 in the other two), 0.98–1.01× on
    /// the head in four.
    own_shade: Vec<Box<ShadeTable>>,
    supersample: usize,
    fov: Option<f64>,
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
                .map(|_| Box::new(ShadeTable::UNSHADED))
                .collect(),
            supersample: 1,
            fov: None,
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

    /// Renders perspective views with a `fov` (degrees) field of view, or parallel
    /// projection with `None` (see [`shearwarp_core::view::Factorization::perspective`]).
    pub fn set_perspective(&mut self, fov: Option<f64>) {
        self.fov = fov;
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
        // thread would spend compositing alone. Waking it now, with an empty job, lets
        // that overlap the frame's serial setup (factorization, shading table). Measured
        // inside the renderer (means of 200 two-thread frames, two alternating runs at
        // 256²), the worker then started 0.04 ms after the bands were posted instead of
        // 0.06–0.12 ms, and the compositing phase took 0.87–0.92 ms instead of
        // 0.95–0.98 ms on brainsmall, 3.86–4.11 ms instead of 4.45–4.61 ms on the head.
        if let Some(pool) = &self.pool {
            if !look.shadows {
                pool.spawn(|| {});
            }
        }
        let settings = Settings {
            mode: look.mode,
            color: &look.color,
            lighting: look.lighting.as_ref(),
            ert_threshold: look.ert_threshold,
            depth_cue: look.depth_cue,
            shadows: look.shadows,
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
        let rotation = frame.view.rotation;
        // One worker per row buffer, each with its own handle on the source, its busy
        // time, its shading table and its starting band.
        let work =
            |(t, (rows, mut src, busy, shade), start): (usize, Own<'_, S>, _)| -> Result<(), Error> {
                let began = Instant::now();
                let own;
                let tables = match (shade, lights) {
                    (Some(sh), Some(l)) => {
                        isa::fill_shade(isa, sh, l, &rotation)?;
                        own = frame.tables(sh, None);
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
        let shades = std::iter::once(None).chain(self.own_shade.iter_mut().map(|s| Some(&mut **s)));
        let own = self
            .rows
            .iter_mut()
            .zip(self.times.busy.iter_mut())
            .zip(shades);
        let each = (0..threads)
            .zip(own.map(|((rows, busy), shade)| (rows, source.clone(), busy, shade)))
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
        let pixels = self.pixels.get(..iw * ih).ok_or(Error::BufferTooSmall {
            what: "intermediate pixels",
            needed: iw * ih,
            got: self.pixels.len(),
        })?;
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
        // columns, measured instead, was slower, see BENCHMARKS.md). Two threads, frames
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
        let px = self.pixels.get(..iw * ih).ok_or(Error::BufferTooSmall {
            what: "intermediate pixels",
            needed: iw * ih,
            got: self.pixels.len(),
        })?;
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

/// Writes RGBA16 pixels (premultiplied over black) as a 16-bit RGB PNG.
pub fn save_png16(
    path: &std::path::Path,
    width: usize,
    height: usize,
    rgba: &[[u16; 4]],
) -> Result<(), image::ImageError> {
    let rgb: Vec<u16> = rgba.iter().flat_map(|p| [p[0], p[1], p[2]]).collect();
    let img =
        image::ImageBuffer::<image::Rgb<u16>, Vec<u16>>::from_raw(width as u32, height as u32, rgb)
            .ok_or_else(|| {
                image::ImageError::Parameter(image::error::ParameterError::from_kind(
                    image::error::ParameterErrorKind::DimensionMismatch,
                ))
            })?;
    img.save_with_format(path, image::ImageFormat::Png)
}

/// Writes RGBA8 pixels (premultiplied over black) as an RGB PNG.
pub fn save_png(
    path: &std::path::Path,
    width: usize,
    height: usize,
    rgba: &[[u8; 4]],
) -> Result<(), image::ImageError> {
    let rgb: Vec<u8> = rgba.iter().flat_map(|p| [p[0], p[1], p[2]]).collect();
    image::save_buffer(
        path,
        &rgb,
        width as u32,
        height as u32,
        image::ExtendedColorType::Rgb8,
    )
}

/// `std::fs::File` (buffered) as the core's byte source.
pub struct FileReader(std::io::BufReader<std::fs::File>);

impl FileReader {
    /// Opens `path` for reading.
    pub fn open(path: &std::path::Path) -> std::io::Result<Self> {
        Ok(FileReader(std::io::BufReader::new(std::fs::File::open(
            path,
        )?)))
    }
}

impl io::Read for FileReader {
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, io::IoError> {
        std::io::Read::read(&mut self.0, buf).map_err(|_| io::IoError::Device)
    }
}

impl io::Seek for FileReader {
    fn seek(&mut self, pos: u64) -> Result<(), io::IoError> {
        let len = self
            .0
            .get_ref()
            .metadata()
            .map_err(|_| io::IoError::Device)?
            .len();
        if pos > len {
            return Err(io::IoError::BadSeek);
        }
        std::io::Seek::seek(&mut self.0, std::io::SeekFrom::Start(pos))
            .map(|_| ())
            .map_err(|_| io::IoError::Device)
    }
}

struct FileWriter(std::io::BufWriter<std::fs::File>);

impl swv::Write for FileWriter {
    fn write_all(&mut self, buf: &[u8]) -> Result<(), io::IoError> {
        std::io::Write::write_all(&mut self.0, buf).map_err(|_| io::IoError::Device)
    }
}

/// Failure to read or write a `.swv` file.
#[derive(Debug)]
pub enum SwvError {
    /// The file could not be opened or created.
    Io(std::path::PathBuf, std::io::Error),
    /// The core rejected the contents.
    Core(std::path::PathBuf, Error),
}

impl std::fmt::Display for SwvError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            SwvError::Io(p, e) => write!(f, "{}: {e}", p.display()),
            SwvError::Core(p, e) => write!(f, "{}: {e}", p.display()),
        }
    }
}

impl std::error::Error for SwvError {}

/// Writes `enc` with its default look as a `.swv` file.
pub fn write_swv(enc: &Encoded, look: &swv::Look, path: &std::path::Path) -> Result<(), SwvError> {
    let err = |e| SwvError::Core(path.to_path_buf(), e);
    let file = std::fs::File::create(path).map_err(|e| SwvError::Io(path.to_path_buf(), e))?;
    let mut w = FileWriter(std::io::BufWriter::new(file));
    let vol = enc.volume().map_err(err)?;
    swv::write(&mut w, &vol, enc.range, enc.threshold, look).map_err(err)?;
    std::io::Write::flush(&mut w.0).map_err(|e| SwvError::Io(path.to_path_buf(), e))
}

/// True if `path` starts with the `.swv` signature.
pub fn is_swv(path: &std::path::Path) -> bool {
    let mut magic = [0u8; 8];
    std::fs::File::open(path)
        .and_then(|mut f| std::io::Read::read_exact(&mut f, &mut magic))
        .is_ok()
        && magic == swv::MAGIC
}

/// Reads a whole `.swv` file into memory (every slice checked), with its default look.
pub fn read_swv(path: &std::path::Path) -> Result<(Encoded, swv::Look), SwvError> {
    let err = |e| SwvError::Core(path.to_path_buf(), e);
    let mut r = FileReader::open(path).map_err(|e| SwvError::Io(path.to_path_buf(), e))?;
    let file_len = std::fs::metadata(path)
        .map_err(|e| SwvError::Io(path.to_path_buf(), e))?
        .len();
    let header = swv::read_header(&mut r).map_err(err)?;
    let grid = header.grid;
    let mut runs: [Vec<u8>; 3] = Default::default();
    let mut voxels: [Vec<Voxel>; 3] = Default::default();
    let mut scans: [Vec<ScanIndex>; 3] = Default::default();
    for axis in Axis::ALL {
        let a = axis as usize;
        let [_, nj, nk] = axis.permuted_dims(grid.dims);
        scans[a].push(ScanIndex::default());
        for k in 0..nk {
            let e = swv::read_entry(&mut r, &header, axis, k).map_err(err)?;
            // Bound allocations by what one slice can hold, and by the file's length,
            // before trusting the counts.
            let [ni, _, _] = axis.permuted_dims(grid.dims);
            let record = 8 * (nj as u64 + 1) + e.runs as u64 + 4 * e.voxels as u64;
            if e.runs as usize > nj * (ni + 2)
                || e.voxels as usize > ni * nj
                || e.offset.saturating_add(record) > file_len
            {
                return Err(err(Error::Format {
                    reason: "slice counts exceed what the slice or the file can hold",
                }));
            }
            let mut s = vec![ScanIndex::default(); nj + 1];
            let mut rb = vec![0u8; e.runs as usize];
            let mut vb = vec![Voxel::default(); e.voxels as usize];
            let slice = swv::read_slice(&mut r, &header, axis, &e, 256, &mut s, &mut rb, &mut vb)
                .map_err(err)?;
            let (r0, v0) = (runs[a].len() as u32, voxels[a].len() as u32);
            for sc in &slice.scans[1..] {
                scans[a].push(ScanIndex {
                    run: r0 + sc.run,
                    voxel: v0 + sc.voxel,
                });
            }
            runs[a].extend_from_slice(slice.runs);
            voxels[a].extend_from_slice(slice.voxels);
        }
    }
    let enc = Encoded {
        grid,
        range: header.range,
        threshold: header.threshold,
        runs,
        voxels,
        scans,
    };
    enc.volume().map_err(err)?;
    Ok((enc, header.look))
}

/// An unclassified volume for post-classified, pre-integrated and isosurface rendering:
/// quantised scalars and normals, plus min-max bricks. A transfer-function change needs
/// no re-encode.
pub struct DenseVolume {
    /// Geometry.
    pub grid: Grid,
    /// Raw value range of the quantised scalars.
    pub range: (u16, u16),
    voxels: Vec<Voxel>,
    bricks: Vec<(u8, u8)>,
}

impl DenseVolume {
    /// Quantises and computes normals and bricks.
    pub fn new(raw: &RawVolume) -> Result<Self, Error> {
        let grid = Grid::new(raw.dims, raw.spacing)?;
        let scalars = match &raw.voxels {
            Voxels::U8(d) => Scalars::U8(d),
            Voxels::U16(d) => Scalars::U16(d),
        };
        let table = vec![255u8; scalars.value_count()];
        let mut voxels = vec![Voxel::default(); grid.voxel_count()];
        classify::classify(&grid, scalars, &table, None, &mut voxels)?;
        let mut bricks = vec![(0u8, 0u8); postclass::brick_count(grid.dims)];
        postclass::build_bricks(&grid, &voxels, &mut bricks)?;
        Ok(DenseVolume {
            grid,
            range: scalars.range(),
            voxels,
            bricks,
        })
    }

    /// Converts a raw value to the quantised scale the renderer works in.
    pub fn quantize(&self, raw: f64) -> f64 {
        let (lo, hi) = (self.range.0 as f64, self.range.1 as f64);
        if hi > lo {
            ((raw - lo) * 255.0 / (hi - lo)).clamp(0.0, 255.0)
        } else {
            0.0
        }
    }
}

/// Workspace and tables for rendering a [`DenseVolume`].
pub struct PostRenderer {
    pixels: Vec<Rgba>,
    links: Vec<opaque::Word>,
    visible: Vec<bool>,
    preint: Vec<Rgba>,
    shade: Box<ShadeTable>,
    out_row: Vec<[u8; 4]>,
}

impl PostRenderer {
    /// Allocates for `vol`.
    pub fn new(vol: &DenseVolume) -> Self {
        let pix = view::max_intermediate_pixels(vol.grid.dims);
        PostRenderer {
            pixels: vec![[0; 4]; pix],
            links: vec![0; pix],
            visible: vec![false; postclass::brick_count(vol.grid.dims)],
            preint: vec![[0; 4]; 65536],
            shade: Box::new(ShadeTable::UNSHADED),
            out_row: Vec::new(),
        }
    }

    /// Renders one frame; `opacity` is the opacity transfer function over raw values.
    pub fn render(
        &mut self,
        vol: &DenseVolume,
        mode: postclass::PostMode,
        opacity: &[(f64, f64)],
        look: &Look,
        camera: &Camera,
    ) -> Result<Vec<[u8; 4]>, Error> {
        let pts = opacity_points(opacity);
        let op = OpacityTf::new(&pts)?.build_quantized(vol.range);
        if self.out_row.len() < camera.width {
            self.out_row.resize(camera.width, [0; 4]);
        }
        let mut frame = vec![[0u8; 4]; camera.width * camera.height];
        let settings = postclass::PostSettings {
            mode,
            opacity: &op,
            color: &look.color,
            lighting: look.lighting.as_ref(),
            ert_threshold: look.ert_threshold,
        };
        let mut ws = postclass::PostWorkspace {
            pixels: &mut self.pixels,
            links: &mut self.links,
            visible: &mut self.visible,
            preint: &mut self.preint,
            shade: &mut self.shade,
            out_row: &mut self.out_row,
        };
        let mut sink = FrameBuffer {
            width: camera.width,
            pixels: &mut frame,
        };
        postclass::render(
            &vol.grid,
            &vol.voxels,
            &vol.bricks,
            camera,
            &settings,
            &mut ws,
            &mut sink,
        )?;
        Ok(frame)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
        for threads in [2, 3] {
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

    #[test]
    fn slab_encoding_equals_the_core_walk() {
        // Sizes that are not multiples of the slab, and a pattern with runs of every
        // length (split visible and transparent runs included: 300 voxels along x).
        let grid = Grid::new([300, 7, 37], [1.0, 2.0, 0.5]).unwrap();
        let n = grid.voxel_count();
        let dense: Vec<Voxel> = (0..n)
            .map(|i| {
                let h = (i as u32).wrapping_mul(2_654_435_761) >> 24;
                let opacity = match (i / 300) % 3 {
                    0 => 200,
                    1 => 0,
                    _ => (h % 8) as u8 * 30,
                };
                Voxel {
                    opacity,
                    scalar: h as u8,
                    normal: (i % 8192) as u16,
                }
            })
            .collect();
        for axis in Axis::ALL {
            let sz = rle::measure(&dense, &grid, axis, 40).unwrap();
            let mut a = (
                vec![0u8; sz.runs],
                vec![Voxel::default(); sz.voxels],
                vec![ScanIndex::default(); sz.scans],
            );
            let mut b = a.clone();
            rle::encode(&dense, &grid, axis, 40, &mut a.0, &mut a.1, &mut a.2).unwrap();
            let used = encode_slabs(&dense, &grid, axis, 40, &mut b.0, &mut b.1, &mut b.2);
            assert_eq!(used.unwrap(), sz.runs, "{axis:?}");
            assert!(a == b, "{axis:?}");
        }
    }
}
