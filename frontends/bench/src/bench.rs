//! Running one scene: preprocessing and frame timings for shearwarp (1 and 2 threads, and
//! one-thread frames side by side on every thread) and VolPack, and PSNR of each against
//! the reference ray caster.

use crate::scenes::{Loaded, Scene};
use crate::volpack::{self, VolPack};
use shearwarp_core::composite::FlatVoxels;
use shearwarp_core::source::SliceSource;
use shearwarp_core::view::Camera;
use shearwarp_file::isa::Isa;
use shearwarp_file::renderer::{FrameTimes, Renderer};
use shearwarp_file::scene::{self, Encoded, FlatVoxelsArg, Look};
use shearwarp_tests::metrics;
use shearwarp_tests::reference::{self, RefMode, RefView};
use std::error::Error;
use std::path::PathBuf;
use std::sync::Barrier;
use std::time::{Duration, Instant};

/// How to run a scene.
#[derive(Clone, Debug)]
pub struct Options {
    /// Frames per image size, `360/frames` degrees apart about the vertical axis.
    pub frames: usize,
    /// Passes over the frames; each view's time is its best pass.
    pub rounds: usize,
    /// Square image sides.
    pub sizes: Vec<usize>,
    /// Preprocessing repetitions (the median is reported).
    pub prep_runs: usize,
    /// Also time shearwarp with this many threads (none: skip).
    pub threads: Option<usize>,
    /// Compare against the reference ray caster.
    pub psnr: bool,
    /// Where reference images are cached.
    pub cache_dir: PathBuf,
    /// Where to write review images (shearwarp | VolPack | reference), if anywhere.
    pub images_dir: Option<PathBuf>,
    /// Skip VolPack even when it is built in.
    pub no_volpack: bool,
    /// The instruction-set build of shearwarp's compositing loop.
    pub isa: Isa,
    /// Also time the baseline build on one thread (when `isa` is above it).
    pub baseline: bool,
    /// Also render with this many intermediate pixels per voxel ([`Supersampled`]), at
    /// the image sizes at least twice the volume's largest side.
    pub supersample: Option<usize>,
    /// Compare the supersampled runs' images and the plain ones at the same sizes
    /// against the reference even where `psnr` is off (the scaling series).
    pub supersample_psnr: bool,
    /// How shearwarp's samples take flat voxels into their colour: fixed, or `Auto`,
    /// as each volume's share of them says ([`FlatVoxelsArg::resolve`]).
    pub flat_voxels: FlatVoxelsArg,
}

/// Median of a set of timings, ms.
#[derive(Clone, Copy, Debug, Default)]
pub struct Stats {
    pub median: f64,
}

impl Stats {
    pub fn of(samples: &[f64]) -> Stats {
        Stats {
            median: shearwarp_file::stats::median(samples),
        }
    }
}

/// Where shearwarp's frames went ([`shearwarp_file::renderer::FrameTimes`]), ms: for each
/// field, the median over the views of the phases of each view's best frame.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Phases {
    pub setup: f64,
    pub composite: f64,
    /// The compositing threads' busy times, summed.
    pub busy_sum: f64,
    /// The longest of them.
    pub busy_max: f64,
    pub warp: f64,
}

impl Phases {
    fn of(t: &FrameTimes) -> Phases {
        let ms = |d: Duration| d.as_secs_f64() * 1e3;
        Phases {
            setup: ms(t.setup),
            composite: ms(t.composite),
            busy_sum: t.busy.iter().copied().map(ms).sum(),
            busy_max: t.busy.iter().copied().map(ms).fold(0.0, f64::max),
            warp: ms(t.warp),
        }
    }

    /// Field by field, the median of `views`.
    pub fn median(views: &[Phases]) -> Phases {
        let m = |f: fn(&Phases) -> f64| Stats::of(&views.iter().map(f).collect::<Vec<_>>()).median;
        Phases {
            setup: m(|p| p.setup),
            composite: m(|p| p.composite),
            busy_sum: m(|p| p.busy_sum),
            busy_max: m(|p| p.busy_max),
            warp: m(|p| p.warp),
        }
    }
}

/// Renders `cam` with `r` into `img` and returns the time it took, ms.
fn render_ms<S: SliceSource + Clone + Send>(
    r: &mut Renderer,
    src: &mut S,
    cam: &Camera,
    look: &Look,
    img: &mut Vec<[u8; 4]>,
) -> Result<f64, shearwarp_core::Error> {
    let t = Instant::now();
    r.render_into(src, cam, look, img)
        .map(|()| t.elapsed().as_secs_f64() * 1e3)
}

/// Renders `cam` with every renderer of `side` at once, each on a thread of its own (the
/// calling thread the first) into its own image, and returns the slowest one's time, ms.
/// The renderers share nothing they write: this is how fast a frame renders while the
/// other cores render frames of their own, what the host allows threads of this work
/// before they share anything.
fn side_by_side<S: SliceSource + Clone + Send + Sync>(
    side: &mut [(Renderer, Vec<[u8; 4]>)],
    src: &S,
    cam: &Camera,
    look: &Look,
) -> Result<f64, shearwarp_core::Error> {
    let start = Barrier::new(side.len());
    let render = |(r, img): &mut (Renderer, Vec<[u8; 4]>)| {
        let mut src = src.clone();
        start.wait();
        render_ms(r, &mut src, cam, look, img)
    };
    let Some((first, others)) = side.split_first_mut() else {
        return Ok(0.0);
    };
    std::thread::scope(|s| {
        let handles: Vec<_> = others.iter_mut().map(|o| s.spawn(|| render(o))).collect();
        let mut slowest = render(first)?;
        for h in handles {
            let ms = h.join().map_err(|_| shearwarp_core::Error::Source {
                reason: "a side-by-side render panicked",
            })??;
            slowest = slowest.max(ms);
        }
        Ok(slowest)
    })
}

/// Medians over the views of each view's best time of `rounds` turns of `frames`
/// frames, each turn rendered by `one` and then by `many` back to back, one frame
/// right after the other (`render(r, view)` renders one and returns its time, ms).
///
/// The main loop lets the renderers take turns frame by frame, so that load from other
/// processes falls on all of them alike; there a threaded renderer's workers have gone
/// to sleep before each of its frames, and waking one costs a frame tens of
/// microseconds on a virtual machine. Back to back, with nothing between frames, the
/// workers are still awake: the difference is the wake's cost. (Rayon's workers fall
/// asleep within tens of microseconds, so a frontend that encodes or presents each
/// frame wakes them as the main loop does.) Each turn starts with one untimed frame
/// (the turn's last view), which both renderers get.
fn back_to_back<R, E>(
    one: &mut R,
    many: &mut R,
    frames: usize,
    rounds: usize,
    render: &mut impl FnMut(&mut R, usize) -> Result<f64, E>,
) -> Result<(Stats, Stats), E> {
    let (mut t1, mut tn) = (vec![f64::MAX; frames], vec![f64::MAX; frames]);
    for _ in 0..rounds.max(1) {
        for (r, t) in [(&mut *one, &mut t1), (&mut *many, &mut tn)] {
            render(r, frames.saturating_sub(1))?;
            for (f, best) in t.iter_mut().enumerate() {
                *best = best.min(render(r, f)?);
            }
        }
    }
    Ok((Stats::of(&t1), Stats::of(&tn)))
}

/// Results at one image size.
#[derive(Clone, Debug, Default)]
pub struct SizeResult {
    pub size: usize,
    pub sw: Stats,
    /// The phases of `sw`'s frames.
    pub sw_phases: Phases,
    pub sw_threads: Option<Stats>,
    /// The phases of `sw_threads`' frames.
    pub threads_phases: Option<Phases>,
    /// One-thread frames rendered side by side, one per thread ([`side_by_side`]).
    pub side_by_side: Option<Stats>,
    /// The one-thread and the threaded renderer each rendering the turn's frames back
    /// to back, nothing between them ([`back_to_back`]).
    pub back_to_back: Option<(Stats, Stats)>,
    /// The baseline (SSE2) build on one thread, when the main runs use a wider one.
    pub sw_base: Option<Stats>,
    /// The threaded, side-by-side and baseline-build images equal the single-threaded ones.
    pub threads_identical: Option<bool>,
    pub vp: Option<Stats>,
    pub psnr_sw: Option<f64>,
    pub psnr_vp: Option<f64>,
    /// The same views composited at a finer intermediate resolution, when measured.
    pub supersampled: Option<Supersampled>,
}

/// shearwarp on one thread compositing `factor`² intermediate pixels per voxel of a
/// slice (`Renderer::set_supersample`), which the plain frame's intermediate image,
/// at the volume's resolution, only upsamples in the warp.
#[derive(Clone, Copy, Debug, Default)]
pub struct Supersampled {
    pub factor: usize,
    /// Median over the views of each view's best of the rounds, as the plain frames'.
    pub sw: Stats,
    pub psnr: Option<f64>,
}

/// Results of one scene.
#[derive(Clone, Debug, Default)]
pub struct SceneResult {
    pub name: String,
    pub dims: [usize; 3],
    pub sw_prep: f64,
    pub vp_prep: Option<f64>,
    /// Bytes of shearwarp's three RLE copies and VolPack's.
    pub sw_bytes: usize,
    /// Non-transparent voxels shearwarp stores per axis copy.
    pub sw_visible: usize,
    /// Of those, the voxels with a zero gradient (flat voxels).
    pub sw_flat: usize,
    /// How shearwarp's frames took the flat voxels.
    pub flat_voxels: FlatVoxels,
    pub vp_bytes: Option<usize>,
    pub sizes: Vec<SizeResult>,
    pub threads: Option<usize>,
}

/// Rotation of frame `f`: about the vertical axis, `360/frames` degrees apart.
fn frame_view(f: usize, frames: usize) -> (f64, f64) {
    (0.0, 360.0 * f as f64 / frames as f64)
}

fn camera((rx, ry): (f64, f64), size: usize) -> Camera {
    Camera {
        rotate_x: rx,
        rotate_y: ry,
        width: size,
        height: size,
    }
}

fn rgb_of(px: &[[u8; 4]]) -> Vec<[u8; 3]> {
    px.iter().map(|p| [p[0], p[1], p[2]]).collect()
}

fn rgb_chunks(b: &[u8]) -> Vec<[u8; 3]> {
    b.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
}

/// 64-bit FNV-1a, to key cached reference images.
fn fnv(bytes: &[u8], mut h: u64) -> u64 {
    for &b in bytes {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x100_0000_01b3);
    }
    h
}

/// The reference image of `scene`'s PSNR view at `size`, from the cache when possible.
fn reference_image(
    scene: &Scene,
    vol: &Loaded,
    size: usize,
    opts: &Options,
) -> Result<Vec<[u8; 3]>, Box<dyn Error>> {
    let (rx, ry) = scene.psnr_view;
    let key = format!(
        "v1 {} {:?} {:?} {:?} {rx} {ry} {size}",
        env!("BENCH_REFERENCE_HASH"),
        vol.raw.dims,
        vol.raw.spacing,
        scene.look
    );
    let h = fnv(vol.data(), fnv(key.as_bytes(), 0xcbf2_9ce4_8422_2325));
    let path = opts
        .cache_dir
        .join(format!("ref-{}-{size}-{h:016x}.rgb", scene.name));
    if let Ok(b) = std::fs::read(&path) {
        if b.len() == size * size * 3 {
            return Ok(rgb_chunks(&b));
        }
    }
    let t = Instant::now();
    let img = reference::render_reference(
        &vol.ref_volume(),
        &scene.look.ref_tf(),
        Some(&scene.look.ref_shading()),
        RefMode::Composite,
        &RefView {
            rotate_x: rx,
            rotate_y: ry,
            width: size,
            height: size,
            depth_cue: None,
            shadows: false,
            fov: None,
            crop: None,
            clip: Vec::new(),
            clip_inverse: false,
            clip_face: 0.0,
        },
    );
    let img = metrics::to_rgb8(&img);
    eprintln!(
        "  reference {size}x{size} rendered in {:.1} s",
        t.elapsed().as_secs_f64()
    );
    std::fs::create_dir_all(&opts.cache_dir)?;
    std::fs::write(&path, img.iter().flatten().copied().collect::<Vec<u8>>())?;
    Ok(img)
}

/// Writes `images` side by side (each `size`²) as one PNG.
fn save_strip(path: &std::path::Path, size: usize, images: &[&[[u8; 3]]]) -> std::io::Result<()> {
    let w = size * images.len();
    let mut out = vec![[0u8; 3]; w * size];
    for (n, img) in images.iter().enumerate() {
        for y in 0..size {
            out[y * w + n * size..y * w + (n + 1) * size]
                .copy_from_slice(&img[y * size..(y + 1) * size]);
        }
    }
    metrics::save_png(path, w, size, &out)
}

/// Times shearwarp's preprocessing `runs` times; returns the last encoding, the way its
/// frames take flat voxels (`flat`, or the volume's own when `None`) and the median
/// time. Choosing the way and, with flat voxels excluded from samples' colours, the
/// tables of flat voxels the compositor then reads are part of it
/// ([`Encoded::build_flat_rows`]).
fn sw_preprocess(
    vol: &Loaded,
    scene: &Scene,
    runs: usize,
    flat: FlatVoxelsArg,
) -> Result<(Encoded, FlatVoxels, f64), Box<dyn Error>> {
    let class = scene.look.classification();
    let encode = || -> Result<(Encoded, FlatVoxels), Box<dyn Error>> {
        let mut enc = scene::encode_threads(&vol.raw, &class, 1)?;
        let way = flat.resolve(&enc);
        if way == FlatVoxels::Excluded {
            enc.build_flat_rows()?;
        }
        Ok((enc, way))
    };
    let mut times = Vec::new();
    // Earlier runs are dropped at the end of each iteration, so at most one is alive.
    for _ in 1..runs.max(1) {
        let t = Instant::now();
        let _enc = encode()?;
        times.push(t.elapsed().as_secs_f64() * 1e3);
    }
    let t = Instant::now();
    let (enc, way) = encode()?;
    times.push(t.elapsed().as_secs_f64() * 1e3);
    Ok((enc, way, Stats::of(&times).median))
}

/// Times VolPack's preprocessing `runs` times; returns the last scene and the median.
fn vp_preprocess(
    vol: &Loaded,
    scene: &Scene,
    runs: usize,
) -> Result<(VolPack, f64), Box<dyn Error>> {
    let setup = volpack::Setup::new(vol, &scene.look)?;
    let mut times = Vec::new();
    for _ in 1..runs.max(1) {
        let (_vp, ms) = VolPack::new(&setup, vol.data())?;
        times.push(ms);
    }
    let (vp, ms) = VolPack::new(&setup, vol.data())?;
    times.push(ms);
    Ok((vp, Stats::of(&times).median))
}

/// Runs one scene.
pub fn run_scene(scene: &Scene, opts: &Options) -> Result<SceneResult, Box<dyn Error>> {
    let t = Instant::now();
    let vol = scene.load()?;
    let [nx, ny, nz] = vol.raw.dims;
    eprintln!(
        "== {} ({nx}x{ny}x{nz}), loaded in {:.0} ms",
        scene.name,
        t.elapsed().as_secs_f64() * 1e3
    );
    let (enc, flat_voxels, sw_prep) = sw_preprocess(&vol, scene, opts.prep_runs, opts.flat_voxels)?;
    let (visible, flat) = (enc.visible_voxels(), enc.flat_voxels());
    eprintln!(
        "  flat voxels {}: {:.2} % of the {visible} visible ones",
        flat_voxels.name(),
        100.0 * flat as f64 / visible.max(1) as f64
    );
    let look = scene.look.look(enc.range)?;
    let mut vp = None;
    let mut vp_prep = None;
    if volpack::AVAILABLE && !opts.no_volpack {
        let (v, ms) = vp_preprocess(&vol, scene, opts.prep_runs)?;
        vp_prep = Some(ms);
        vp = Some(v);
    }
    let mut res = SceneResult {
        name: scene.name.clone(),
        dims: vol.raw.dims,
        sw_prep,
        vp_prep,
        sw_bytes: enc.bytes(),
        sw_visible: visible,
        sw_flat: flat,
        flat_voxels,
        vp_bytes: vp.as_ref().map(VolPack::classified_bytes),
        sizes: Vec::new(),
        threads: opts.threads,
    };
    let mut src = enc.volume()?;
    for &size in &opts.sizes {
        let renderer = |threads: usize, isa: Isa| {
            let mut r = Renderer::with_threads(&enc.grid, threads);
            r.set_isa(isa);
            r.set_flat_voxels(flat_voxels);
            r
        };
        let mut r1 = renderer(1, opts.isa);
        let mut rn = opts.threads.map(|n| renderer(n, opts.isa));
        let mut rb =
            (opts.baseline && r1.isa() > Isa::Baseline).then(|| renderer(1, Isa::Baseline));
        let mut imgb = Vec::new();
        let mut vp_img = vec![0u8; size * size * 3];
        let (mut img1, mut imgn) = (Vec::new(), Vec::new());
        // Per view, the best time over the rounds.
        let n = opts.frames;
        let (mut t1, mut tn, mut tv) = (vec![f64::MAX; n], vec![f64::MAX; n], vec![f64::MAX; n]);
        let mut tb = vec![f64::MAX; n];
        let mut side: Vec<_> = (0..opts.threads.unwrap_or(0))
            .map(|_| (renderer(1, opts.isa), Vec::new()))
            .collect();
        let mut ts = vec![f64::MAX; n];
        let (mut p1, mut pn) = (vec![Phases::default(); n], vec![Phases::default(); n]);
        let mut identical = true;
        // Frame 0 once untimed (allocations, page faults), then the timed frames, `rounds`
        // times over. The renderers take turns frame by frame so that load from other
        // processes on the machine falls on all of them alike.
        let warmup = std::iter::once((usize::MAX, 0));
        let timed = (0..opts.rounds.max(1)).flat_map(|_| (0..n).map(|f| (f, f)));
        for (slot, f) in warmup.chain(timed) {
            let view = frame_view(f, n);
            let cam = camera(view, size);
            // Every renderer writes into buffers kept across frames, as VolPack does.
            let mut render_ms =
                |r: &mut Renderer, img: &mut Vec<[u8; 4]>| render_ms(r, &mut src, &cam, &look, img);
            let ms1 = render_ms(&mut r1, &mut img1)?;
            // The threaded and the baseline-build renderer, when present; each image
            // must equal the first renderer's.
            let mut checked = |r: Option<&mut Renderer>, img: &mut Vec<[u8; 4]>| {
                let Some(r) = r else { return Ok(f64::MAX) };
                let ms = render_ms(r, img)?;
                identical &= *img == img1;
                Ok::<f64, shearwarp_core::Error>(ms)
            };
            let msn = checked(rn.as_mut(), &mut imgn)?;
            let msb = checked(rb.as_mut(), &mut imgb)?;
            let mss = if side.is_empty() {
                f64::MAX
            } else {
                let ms = side_by_side(&mut side, &src, &cam, &look)?;
                identical &= side.iter().all(|(_, img)| *img == img1);
                ms
            };
            let mut msv = f64::MAX;
            if let Some(v) = vp.as_mut() {
                msv = v.render(view.0, view.1, size, size, &mut vp_img)?;
            }
            if slot < n {
                if ms1 < t1[slot] {
                    p1[slot] = Phases::of(r1.times());
                }
                if let Some(r) = rn.as_ref().filter(|_| msn < tn[slot]) {
                    pn[slot] = Phases::of(r.times());
                }
                t1[slot] = t1[slot].min(ms1);
                tn[slot] = tn[slot].min(msn);
                tb[slot] = tb[slot].min(msb);
                ts[slot] = ts[slot].min(mss);
                tv[slot] = tv[slot].min(msv);
            }
        }
        let back_to_back = match rn.as_mut() {
            Some(rn) => {
                let (mut img, n) = (Vec::new(), opts.frames);
                let mut render = |r: &mut Renderer, f: usize| {
                    let cam = camera(frame_view(f, n), size);
                    render_ms(r, &mut src, &cam, &look, &mut img)
                };
                Some(back_to_back(&mut r1, rn, n, opts.rounds, &mut render)?)
            }
            None => None,
        };
        let mut sr = SizeResult {
            size,
            back_to_back,
            sw: Stats::of(&t1),
            sw_phases: Phases::median(&p1),
            sw_threads: rn.as_ref().map(|_| Stats::of(&tn)),
            threads_phases: rn.as_ref().map(|_| Phases::median(&pn)),
            side_by_side: (!side.is_empty()).then(|| Stats::of(&ts)),
            sw_base: rb.as_ref().map(|_| Stats::of(&tb)),
            threads_identical: (rn.is_some() || rb.is_some()).then_some(identical),
            vp: vp.as_ref().map(|_| Stats::of(&tv)),
            psnr_sw: None,
            psnr_vp: None,
            supersampled: None,
        };
        let max_side = vol.raw.dims.into_iter().max().unwrap_or(0);
        let mut rs = match opts.supersample {
            Some(f) if f > 1 && size >= 2 * max_side => {
                let mut r = renderer(1, opts.isa);
                r.set_supersample(f)?;
                Some((f, r))
            }
            _ => None,
        };
        if let Some((factor, r)) = rs.as_mut() {
            // Frame 0 once untimed, then `rounds` passes, each view's best time kept, as
            // for the plain frames.
            let mut img = Vec::new();
            let mut t = vec![f64::INFINITY; n];
            let timed = (0..opts.rounds.max(1)).flat_map(|_| (0..n).map(|f| (f, f)));
            for (slot, f) in std::iter::once((usize::MAX, 0)).chain(timed) {
                let cam = camera(frame_view(f, n), size);
                let start = Instant::now();
                r.render_into(&mut src, &cam, &look, &mut img)?;
                if let Some(best) = t.get_mut(slot) {
                    *best = best.min(start.elapsed().as_secs_f64() * 1e3);
                }
            }
            sr.supersampled = Some(Supersampled {
                factor: *factor,
                sw: Stats::of(&t),
                psnr: None,
            });
        }
        let psnr = opts.psnr || (rs.is_some() && opts.supersample_psnr);
        if psnr || opts.images_dir.is_some() {
            let cam = camera(scene.psnr_view, size);
            let sw_img = rgb_of(&r1.render(&mut src, &cam, &look)?);
            let vp_rgb = match vp.as_mut() {
                Some(v) => {
                    v.render(
                        scene.psnr_view.0,
                        scene.psnr_view.1,
                        size,
                        size,
                        &mut vp_img,
                    )?;
                    Some(rgb_chunks(&vp_img))
                }
                None => None,
            };
            let ref_img = if psnr {
                Some(reference_image(scene, &vol, size, opts)?)
            } else {
                None
            };
            let ss_img = match rs.as_mut() {
                Some((_, r)) => Some(rgb_of(&r.render(&mut src, &cam, &look)?)),
                None => None,
            };
            if let Some(r) = &ref_img {
                sr.psnr_sw = Some(metrics::psnr_rgb8(&sw_img, r));
                sr.psnr_vp = vp_rgb.as_ref().map(|v| metrics::psnr_rgb8(v, r));
                if let (Some(ss), Some(img)) = (sr.supersampled.as_mut(), &ss_img) {
                    ss.psnr = Some(metrics::psnr_rgb8(img, r));
                    eprintln!(
                        "  {size}x{size} PSNR at {:?} supersampled {}x: {:.3} dB",
                        scene.psnr_view,
                        ss.factor,
                        ss.psnr.unwrap_or(0.0)
                    );
                }
                // The table rounds to 0.1 dB; changes to quality are read here.
                eprintln!(
                    "  {size}x{size} PSNR at {:?}: shearwarp {:.3} dB{}",
                    scene.psnr_view,
                    sr.psnr_sw.unwrap_or(0.0),
                    sr.psnr_vp
                        .map(|p| format!(", VolPack {p:.3} dB"))
                        .unwrap_or_default(),
                );
            }
            if let Some(dir) = &opts.images_dir {
                std::fs::create_dir_all(dir)?;
                let blank = vec![[0u8; 3]; size * size];
                let strip: Vec<&[[u8; 3]]> = vec![
                    &sw_img,
                    vp_rgb.as_deref().unwrap_or(&blank),
                    ref_img.as_deref().unwrap_or(&blank),
                ];
                save_strip(
                    &dir.join(format!("{}-{size}.png", scene.name)),
                    size,
                    &strip,
                )?;
                if let Some(ss) = &ss_img {
                    // Supersampled | plain | reference.
                    let strip: Vec<&[[u8; 3]]> =
                        vec![ss, &sw_img, ref_img.as_deref().unwrap_or(&blank)];
                    save_strip(
                        &dir.join(format!("{}-{size}-supersampled.png", scene.name)),
                        size,
                        &strip,
                    )?;
                }
            }
        }
        eprintln!(
            "  {size}x{size}: shearwarp {:.2} ms{}{}{}",
            sr.sw.median,
            sr.sw_threads
                .map(|s| format!(", {} threads {:.2} ms", opts.threads.unwrap_or(1), s.median))
                .unwrap_or_default(),
            sr.sw_base
                .map(|s| format!(", baseline build {:.2} ms", s.median))
                .unwrap_or_default(),
            sr.vp
                .map(|s| format!(", VolPack {:.2} ms", s.median))
                .unwrap_or_default()
        );
        res.sizes.push(sr);
    }
    Ok(res)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stats_median() {
        assert_eq!(Stats::of(&[3.0, 1.0, 2.0]).median, 2.0);
        assert_eq!(Stats::of(&[4.0, 1.0, 2.0, 3.0]).median, 2.5);
        assert_eq!(Stats::of(&[]).median, 0.0);
    }

    #[test]
    fn back_to_back_renders_each_turn_whole_and_keeps_each_views_best() {
        // Renderers 1 and 2; the log of (renderer, view) calls; times by call order.
        let (mut one, mut many) = (1u8, 2u8);
        let mut log = Vec::new();
        let mut render = |r: &mut u8, f: usize| {
            log.push((*r, f));
            // Renderer 2 takes half as long; the second round is faster on view 1.
            let round = log.iter().filter(|&&(q, g)| q == *r && g == f).count();
            let ms = if round == 2 && f == 1 {
                0.5
            } else {
                4.0 + f as f64
            };
            Ok::<f64, ()>(ms / f64::from(*r))
        };
        let (a, b) = back_to_back(&mut one, &mut many, 3, 2, &mut render).unwrap();
        // Per round: renderer 1's untimed last view then views 0..3, then renderer 2's.
        let turn = |r| [(r, 2), (r, 0), (r, 1), (r, 2)];
        let want: Vec<_> = [turn(1), turn(2), turn(1), turn(2)].concat();
        assert_eq!(log, want);
        // Renderer 1's bests: views 0, 1, 2 at 4, 0.5, 6; renderer 2's half those.
        assert_eq!((a.median, b.median), (4.0, 2.0));
    }

    #[test]
    fn frames_turn_about_the_vertical_axis() {
        assert_eq!(frame_view(0, 36), (0.0, 0.0));
        assert_eq!(frame_view(9, 36), (0.0, 90.0));
        assert_eq!(frame_view(35, 36), (0.0, 350.0));
    }
}
