//! `shearwarp`: render volumes to PNG and benchmark the renderer.

use clap::{Args, Parser, Subcommand, ValueEnum};
use shearwarp_core::composite::Mode;
use shearwarp_core::depth::DepthCue;
use shearwarp_core::shade::{Light, Lighting};
use shearwarp_core::view::Camera;
use shearwarp_core::{postclass, swv};
use shearwarp_file::scene::{self, Classification, Encoded, Look, Renderer};
use shearwarp_file::tfspec;
use shearwarp_file::volume::{self, RawVolume};
use std::error::Error;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

#[derive(Parser)]
#[command(name = "shearwarp", version, about = "Shear-warp volume renderer")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Render one view of a volume to a PNG.
    Render {
        /// Volume: a DICOM directory or file, .nii/.nii.gz, .nrrd/.nhdr, .mhd/.mha, a raw
        /// file (`.raw`, `.raw.gz`) or its JSON sidecar, or a `.swv`.
        volume: PathBuf,
        /// Output PNG.
        #[arg(short, long)]
        output: PathBuf,
        #[command(flatten)]
        opts: RenderOpts,
    },
    /// Classify and run-length encode a volume into a streamable `.swv` file.
    Encode {
        /// Volume: a DICOM directory or file, .nii/.nii.gz, .nrrd/.nhdr, .mhd/.mha, a raw
        /// file (`.raw`, `.raw.gz`) or its JSON sidecar.
        volume: PathBuf,
        /// Output `.swv` file.
        #[arg(short, long)]
        output: PathBuf,
        #[command(flatten)]
        opts: RenderOpts,
    },
    /// Compare two images (PNG or PPM): prints max channel error and PSNR; fails if the
    /// max channel error exceeds the tolerance.
    Compare {
        /// First image.
        a: PathBuf,
        /// Second image.
        b: PathBuf,
        /// Largest accepted per-channel difference (0 = bit-identical RGB).
        #[arg(long, default_value_t = 0)]
        tolerance: u8,
    },
    /// Describe a volume: dims, spacing, value range, a text histogram and suggested
    /// transfer-function presets.
    Info {
        /// Volume: a DICOM directory or file, .nii/.nii.gz, .nrrd/.nhdr, .mhd/.mha, or a
        /// raw file with its JSON sidecar.
        volume: PathBuf,
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
        /// Prefer the 16-bit file when a sidecar lists one.
        #[arg(long)]
        u16: bool,
    },
    /// Print the fixed memory the core needs for a maximum volume and image width.
    Memory {
        /// Volume dimensions NXxNYxNZ.
        dims: String,
        /// Image width in pixels.
        width: usize,
    },
    /// Render N frames turning 360/N degrees about Y and report timings.
    Bench {
        /// Volume: a DICOM directory or file, .nii/.nii.gz, .nrrd/.nhdr, .mhd/.mha, a raw
        /// file (`.raw`, `.raw.gz`) or its JSON sidecar.
        volume: PathBuf,
        /// Number of frames.
        #[arg(long, default_value_t = 36)]
        frames: usize,
        #[command(flatten)]
        opts: RenderOpts,
    },
}

#[derive(Clone, Copy, ValueEnum, PartialEq, Eq)]
enum ProjectionArg {
    Parallel,
    Perspective,
}

impl RenderOpts {
    /// The field of view for a perspective renderer, `None` for parallel projection.
    fn perspective(&self) -> Result<Option<f64>, String> {
        match self.projection {
            ProjectionArg::Parallel => Ok(None),
            ProjectionArg::Perspective if self.mode.dense() => {
                Err("--projection perspective works with --mode composite or mip".into())
            }
            ProjectionArg::Perspective => Ok(Some(self.fov)),
        }
    }
}

#[derive(Clone, Copy, ValueEnum, PartialEq, Eq)]
enum ModeArg {
    /// Classified RLE volume, "over" compositing.
    Composite,
    /// Maximum intensity projection.
    Mip,
    /// Unclassified volume, scalars interpolated then classified.
    Post,
    /// Unclassified volume, pre-integrated slabs between slices.
    Preint,
    /// Isosurface at --iso.
    Iso,
}

impl ModeArg {
    fn dense(self) -> bool {
        matches!(self, ModeArg::Post | ModeArg::Preint | ModeArg::Iso)
    }
}

#[derive(Args)]
struct RenderOpts {
    /// Image size WxH.
    #[arg(long, default_value = "256x256")]
    size: String,
    /// Rotation about X in degrees (applied after the Y rotation).
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    rotate_x: f64,
    /// Rotation about Y in degrees.
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    rotate_y: f64,
    /// Opacity transfer function "v:a,v:a,..." over raw voxel values (a per smallest
    /// voxel spacing). Default: a ramp over the data range.
    #[arg(long)]
    opacity: Option<String>,
    /// Colour transfer function "v:#rrggbb,...". Default: a warm grey ramp.
    #[arg(long)]
    color: Option<String>,
    /// Opacity factor over gradient magnitude "m:f,..." (raw units per smallest spacing).
    #[arg(long)]
    gradient_opacity: Option<String>,
    /// Turn on Phong/Blinn shading.
    #[arg(long)]
    shading: bool,
    /// Light direction x,y,z in camera space (x right, y up, z toward viewer), with an
    /// optional colour: "x,y,z:#rrggbb"; repeat for up to 4 lights.
    #[arg(long, allow_hyphen_values = true)]
    light: Vec<String>,
    /// Ambient coefficient.
    #[arg(long, default_value_t = 0.2)]
    ka: f64,
    /// Diffuse coefficient.
    #[arg(long, default_value_t = 0.7)]
    kd: f64,
    /// Specular coefficient.
    #[arg(long, default_value_t = 0.3)]
    ks: f64,
    /// Specular exponent.
    #[arg(long, default_value_t = 20.0)]
    shininess: f64,
    /// Rendering mode.
    #[arg(long, value_enum, default_value_t = ModeArg::Composite)]
    mode: ModeArg,
    /// Same as --mode preint: pre-integrated classification between adjacent slices.
    #[arg(long)]
    preintegrated: bool,
    /// Isovalue for --mode iso, in raw voxel units.
    #[arg(long)]
    iso: Option<f64>,
    /// Voxels with opacity at or below this are skipped as transparent.
    #[arg(long, default_value_t = 0.02)]
    min_opacity: f64,
    /// Early ray termination opacity (1 disables it).
    #[arg(long, default_value_t = 0.95)]
    ert: f64,
    /// Depth cueing FRONT:DENSITY: colour × FRONT·e^(−DENSITY·d), d = 0 at the volume's
    /// nearest corner and 1 at its farthest.
    #[arg(long)]
    depth_cue: Option<String>,
    /// Shadows cast toward the first light (needs --shading; the light must be within
    /// the view's principal-axis cone, on the viewer's side).
    #[arg(long)]
    shadows: bool,
    /// Intermediate pixels per voxel (1..=4): resample slices finer than the voxel grid,
    /// for images larger than the volume's projection.
    #[arg(long, default_value_t = 1)]
    supersample: usize,
    /// Projection: parallel (the default) or perspective (camera on +Z at the distance
    /// where the volume's bounding sphere fills --fov).
    #[arg(long, value_enum, default_value_t = ProjectionArg::Parallel)]
    projection: ProjectionArg,
    /// Field of view in degrees across the shorter image side, for --projection
    /// perspective (1..=150).
    #[arg(long, default_value_t = 30.0)]
    fov: f64,
    /// Render level L of the level-of-detail pyramid (each level halves the resolution;
    /// the image keeps the full volume's framing and brightness).
    #[arg(long, default_value_t = 0)]
    lod: usize,
    /// Compositing threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// Prefer the 16-bit file when the sidecar lists one.
    #[arg(long)]
    u16: bool,
}

struct Prepared {
    threads: usize,
    name: String,
    dims: [usize; 3],
    encoded: Encoded,
    look: Look,
    camera: Camera,
}

fn default_opacity(range: (u16, u16), mode: ModeArg) -> Vec<(f64, f64)> {
    let (lo, hi) = (range.0 as f64, range.1 as f64);
    let span = (hi - lo).max(1.0);
    match mode {
        // Everything above the minimum takes part in the maximum.
        ModeArg::Mip => vec![(lo, 0.0), (lo + 1.0, 1.0)],
        _ => vec![
            (lo, 0.0),
            (lo + 0.15 * span, 0.0),
            (lo + 0.4 * span, 0.1),
            (hi, 0.8),
        ],
    }
}

fn default_color(range: (u16, u16)) -> Vec<(f64, [u8; 3])> {
    let (lo, hi) = (range.0 as f64, range.1 as f64);
    vec![
        (lo, [0x80, 0x50, 0x40]),
        (lo + 0.5 * (hi - lo).max(1.0), [0xe0, 0xb0, 0x90]),
        (hi.max(lo + 1.0), [0xff, 0xff, 0xf0]),
    ]
}

fn prepare(path: &std::path::Path, o: &RenderOpts) -> Result<Prepared, Box<dyn Error>> {
    let (width, height) = tfspec::parse_size(&o.size)?;
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let (encoded, file_look) = if scene::is_swv(path) {
        if o.opacity.is_some() || o.gradient_opacity.is_some() || o.u16 {
            return Err(format!(
                "{}: opacity is baked into a .swv file; re-encode it with `shearwarp encode` \
                 to change --opacity/--gradient-opacity/--u16",
                path.display()
            )
            .into());
        }
        let (enc, look) = scene::read_swv(path)?;
        (enc, Some(look))
    } else {
        let raw = load_raw(path, o)?;
        if o.lod > 0 {
            if o.lod > 8 {
                return Err("--lod must be 0..=8".into());
            }
            let full = shearwarp_core::classify::Grid::new(raw.dims, raw.spacing)?;
            let (level, _) = scene::lod(&raw, o.lod)?;
            (encode_raw(&level, o)?.as_level(&full), None)
        } else {
            (encode_raw(&raw, o)?, None)
        }
    };
    let color = match (&o.color, &file_look) {
        (Some(s), _) => scene::color_table(&tfspec::parse_color(s)?, encoded.range)?,
        (None, Some(l)) => l.color,
        (None, None) => scene::color_table(&default_color(encoded.range), encoded.range)?,
    };
    let lighting = if o.shading || file_look.is_none() {
        o.shading.then(|| cli_lighting(o)).transpose()?
    } else {
        file_look.and_then(|l| l.lighting)
    };
    let look = Look {
        mode: match o.mode {
            ModeArg::Mip => Mode::Mip,
            _ => Mode::Composite,
        },
        color,
        lighting,
        ert_threshold: o.ert,
        depth_cue: o.depth_cue.as_deref().map(parse_depth_cue).transpose()?,
        shadows: o.shadows,
    };
    let camera = Camera {
        rotate_x: o.rotate_x,
        rotate_y: o.rotate_y,
        width,
        height,
    };
    let threads = o
        .threads
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    if threads == 0 || threads > 256 {
        return Err("--threads must be 1..=256".into());
    }
    Ok(Prepared {
        threads,
        name,
        dims: encoded.grid.dims,
        encoded,
        look,
        camera,
    })
}

struct Dense {
    vol: scene::DenseVolume,
    renderer: scene::PostRenderer,
    mode: postclass::PostMode,
    opacity: Vec<(f64, f64)>,
    look: Look,
    camera: Camera,
}

fn prepare_dense(path: &std::path::Path, o: &RenderOpts) -> Result<Dense, Box<dyn Error>> {
    if scene::is_swv(path) {
        return Err(format!(
            "{}: --mode post/preint/iso need the unclassified volume, not a .swv",
            path.display()
        )
        .into());
    }
    let (width, height) = tfspec::parse_size(&o.size)?;
    let raw = load_raw(path, o)?;
    let vol = scene::DenseVolume::new(&raw)?;
    let mode = match o.mode {
        ModeArg::Post => postclass::PostMode::PostClassified,
        ModeArg::Preint => postclass::PostMode::PreIntegrated,
        _ => {
            let iso = o
                .iso
                .ok_or("--mode iso needs --iso VALUE (raw voxel units)")?;
            if !iso.is_finite() {
                return Err("--iso must be a finite number".into());
            }
            postclass::PostMode::Isosurface(vol.quantize(iso))
        }
    };
    let opacity = match &o.opacity {
        Some(s) => tfspec::parse_opacity(s)?,
        None => default_opacity(vol.range, o.mode),
    };
    let color_pts = match &o.color {
        Some(s) => tfspec::parse_color(s)?,
        None => default_color(vol.range),
    };
    let look = Look {
        mode: Mode::Composite,
        color: scene::color_table(&color_pts, vol.range)?,
        lighting: o.shading.then(|| cli_lighting(o)).transpose()?,
        ert_threshold: o.ert,
        depth_cue: None,
        shadows: false,
    };
    if o.depth_cue.is_some() || o.shadows {
        return Err("--depth-cue and --shadows work with --mode composite only".into());
    }
    let camera = Camera {
        rotate_x: o.rotate_x,
        rotate_y: o.rotate_y,
        width,
        height,
    };
    let renderer = scene::PostRenderer::new(&vol);
    Ok(Dense {
        vol,
        renderer,
        mode,
        opacity,
        look,
        camera,
    })
}

fn load_raw(path: &std::path::Path, o: &RenderOpts) -> Result<RawVolume, Box<dyn Error>> {
    let prefer = if o.u16 {
        volume::Prefer::U16
    } else {
        volume::Prefer::U8
    };
    Ok(volume::load_volume_with(path, prefer)?)
}

fn encode_raw(raw: &RawVolume, o: &RenderOpts) -> Result<Encoded, Box<dyn Error>> {
    let range = match &raw.voxels {
        volume::Voxels::U8(_) => (0, 255),
        volume::Voxels::U16(d) => (
            d.iter().copied().min().unwrap_or(0),
            d.iter().copied().max().unwrap_or(0),
        ),
    };
    let opacity = match &o.opacity {
        Some(s) => tfspec::parse_opacity(s)?,
        None => default_opacity(range, o.mode),
    };
    let gradient = o
        .gradient_opacity
        .as_deref()
        .map(tfspec::parse_opacity)
        .transpose()?;
    let class = Classification {
        opacity,
        gradient,
        min_opacity: o.min_opacity,
    };
    Ok(scene::encode(raw, &class)?)
}

fn parse_depth_cue(s: &str) -> Result<DepthCue, Box<dyn Error>> {
    let bad = || format!("--depth-cue '{s}': expected FRONT:DENSITY, e.g. 1:1.5");
    let (f, d) = s.split_once(':').ok_or_else(bad)?;
    let cue = DepthCue {
        front: f.trim().parse().map_err(|_| bad())?,
        density: d.trim().parse().map_err(|_| bad())?,
    };
    cue.validate()
        .map_err(|e| format!("--depth-cue '{s}': {e}"))?;
    Ok(cue)
}

fn cli_lighting(o: &RenderOpts) -> Result<Lighting, Box<dyn Error>> {
    let mut l = Lighting {
        ka: o.ka,
        kd: o.kd,
        ks: o.ks,
        shininess: o.shininess,
        ..Lighting::default()
    };
    if !o.light.is_empty() {
        l.lights.clear();
        for s in &o.light {
            let (dir, color) = match s.split_once(':') {
                Some((d, c)) => {
                    let rgb = tfspec::parse_color(&format!("0:{}", c.trim()))
                        .map_err(|_| format!("--light '{s}': colour must be #rrggbb or #rgb"))?;
                    (d, rgb[0].1.map(|x| x as f64 / 255.0))
                }
                None => (s.as_str(), [1.0; 3]),
            };
            let d = tfspec::parse_vec3(dir)?;
            l.lights
                .push(Light {
                    direction: d,
                    color,
                })
                .map_err(|_| "at most 4 lights (--light) are supported")?;
        }
    }
    Ok(l)
}

fn run(mut cli: Cli) -> Result<(), Box<dyn Error>> {
    if let Command::Render { opts, .. }
    | Command::Bench { opts, .. }
    | Command::Encode { opts, .. } = &mut cli.command
    {
        if opts.preintegrated {
            if opts.mode != ModeArg::Composite && opts.mode != ModeArg::Preint {
                return Err("--preintegrated conflicts with --mode".into());
            }
            opts.mode = ModeArg::Preint;
        }
    }
    match cli.command {
        Command::Render {
            volume,
            output,
            opts,
        } if opts.mode.dense() => {
            opts.perspective()?;
            let mut d = prepare_dense(&volume, &opts)?;
            let frame = d
                .renderer
                .render(&d.vol, d.mode, &d.opacity, &d.look, &d.camera)?;
            scene::save_png(&output, d.camera.width, d.camera.height, &frame)
                .map_err(|e| format!("cannot write {}: {e}", output.display()))?;
            eprintln!("{} -> {}", volume.display(), output.display());
        }
        Command::Bench {
            volume,
            frames,
            opts,
        } if opts.mode.dense() => {
            if frames == 0 {
                return Err("--frames must be at least 1".into());
            }
            let t0 = Instant::now();
            let mut d = prepare_dense(&volume, &opts)?;
            let preprocess = t0.elapsed().as_secs_f64() * 1e3;
            // Every frame changes the transfer function (the ramp shifts by 4% of the
            // range back and forth), so each time includes reclassification.
            let span = (d.vol.range.1 as f64 - d.vol.range.0 as f64).max(1.0);
            let mut times = Vec::with_capacity(frames);
            for i in 0..frames {
                let mut cam = d.camera;
                cam.rotate_y += 360.0 * i as f64 / frames as f64;
                let shift = if i % 2 == 0 { 0.0 } else { 0.04 * span };
                let op: Vec<(f64, f64)> = d.opacity.iter().map(|&(v, a)| (v + shift, a)).collect();
                let t = Instant::now();
                let frame = d.renderer.render(&d.vol, d.mode, &op, &d.look, &cam)?;
                times.push(t.elapsed().as_secs_f64() * 1e3);
                std::hint::black_box(frame);
            }
            times.sort_by(f64::total_cmp);
            println!(
                "volume={} mode={:?} image={}x{} (every frame after a transfer-function change)",
                volume.display(),
                d.mode,
                d.camera.width,
                d.camera.height
            );
            println!(
                "frames={} median_ms={:.2} min_ms={:.2} preprocess_ms={:.1}",
                frames,
                times[frames / 2],
                times[0],
                preprocess
            );
        }
        Command::Render {
            volume,
            output,
            opts,
        } => {
            let p = prepare(&volume, &opts)?;
            let mut src = p.encoded.volume()?;
            let mut r = Renderer::with_threads(&p.encoded.grid, p.threads);
            r.set_supersample(opts.supersample)?;
            r.set_perspective(opts.perspective()?);
            let frame = r.render(&mut src, &p.camera, &p.look)?;
            scene::save_png(&output, p.camera.width, p.camera.height, &frame)
                .map_err(|e| format!("cannot write {}: {e}", output.display()))?;
            eprintln!(
                "{}: {}x{}x{} -> {} ({}x{})",
                p.name,
                p.dims[0],
                p.dims[1],
                p.dims[2],
                output.display(),
                p.camera.width,
                p.camera.height
            );
        }
        Command::Info { volume, json, u16 } => {
            let prefer = if u16 {
                volume::Prefer::U16
            } else {
                volume::Prefer::U8
            };
            let (raw, meta) = volume::load_volume_meta(&volume, prefer)?;
            let info = shearwarp_file::info::compute(&raw, &meta);
            let shown = volume.display().to_string();
            if json {
                println!(
                    "{}",
                    serde_json::to_string_pretty(&shearwarp_file::info::to_json(&info, &shown))?
                );
            } else {
                print!("{}", shearwarp_file::info::to_text(&info, &shown));
            }
        }
        Command::Memory { dims, width } => {
            let d: Vec<usize> = dims
                .split(['x', 'X'])
                .map(|t| t.trim().parse::<usize>())
                .collect::<Result<_, _>>()
                .map_err(|_| format!("dims '{dims}': expected NXxNYxNZ"))?;
            let [nx, ny, nz] = d[..] else {
                return Err(format!("dims '{dims}': expected three numbers").into());
            };
            shearwarp_core::classify::Grid::new([nx, ny, nz], [1.0; 3])?;
            if width == 0 || width > shearwarp_core::view::MAX_IMAGE {
                return Err(format!("width {width}: must be 1..=16384").into());
            }
            let ws = shearwarp_core::render::workspace_bytes([nx, ny, nz], width);
            let st = swv::stream_buffer_bytes([nx, ny, nz]);
            println!(
                "dims={nx}x{ny}x{nz} width={width} workspace_bytes={ws} stream_bytes={st} total_bytes={}",
                ws + st
            );
        }
        Command::Compare { a, b, tolerance } => {
            let load = |p: &PathBuf| -> Result<image::RgbImage, Box<dyn Error>> {
                Ok(image::open(p)
                    .map_err(|e| format!("{}: {e}", p.display()))?
                    .to_rgb8())
            };
            let (ia, ib) = (load(&a)?, load(&b)?);
            if ia.dimensions() != ib.dimensions() {
                return Err(format!(
                    "sizes differ: {:?} vs {:?}",
                    ia.dimensions(),
                    ib.dimensions()
                )
                .into());
            }
            let mut max = 0u8;
            let mut se = 0f64;
            for (x, y) in ia.as_raw().iter().zip(ib.as_raw()) {
                let d = x.abs_diff(*y);
                max = max.max(d);
                se += (d as f64).powi(2);
            }
            let mse = se / ia.as_raw().len() as f64;
            let psnr = if mse == 0.0 {
                f64::INFINITY
            } else {
                10.0 * (255.0f64 * 255.0 / mse).log10()
            };
            println!("max_channel_error={max} psnr_db={psnr:.2}");
            if max > tolerance {
                return Err(format!("images differ: max channel error {max} > {tolerance}").into());
            }
        }
        Command::Encode {
            volume,
            output,
            opts,
        } => {
            let p = prepare(&volume, &opts)?;
            let look = swv::Look {
                color: p.look.color,
                lighting: p.look.lighting.clone(),
            };
            scene::write_swv(&p.encoded, &look, &output)?;
            let bytes = std::fs::metadata(&output).map(|m| m.len()).unwrap_or(0);
            eprintln!(
                "{}: {}x{}x{} -> {} ({} bytes, {} stored voxels per axis copy)",
                p.name,
                p.dims[0],
                p.dims[1],
                p.dims[2],
                output.display(),
                bytes,
                p.encoded.visible_voxels()
            );
        }
        Command::Bench {
            volume,
            frames,
            opts,
        } => {
            if frames == 0 {
                return Err("--frames must be at least 1".into());
            }
            let t0 = Instant::now();
            let p = prepare(&volume, &opts)?;
            let preprocess = t0.elapsed().as_secs_f64() * 1e3;
            let mut src = p.encoded.volume()?;
            let mut r = Renderer::with_threads(&p.encoded.grid, p.threads);
            r.set_supersample(opts.supersample)?;
            r.set_perspective(opts.perspective()?);
            let mut times = Vec::with_capacity(frames);
            for i in 0..frames {
                let mut cam = p.camera;
                cam.rotate_y += 360.0 * i as f64 / frames as f64;
                let t = Instant::now();
                let frame = r.render(&mut src, &cam, &p.look)?;
                times.push(t.elapsed().as_secs_f64() * 1e3);
                std::hint::black_box(frame);
            }
            times.sort_by(f64::total_cmp);
            println!(
                "volume={} dims={}x{}x{} image={}x{} threads={} visible_voxels={} rle_bytes={}",
                p.name,
                p.dims[0],
                p.dims[1],
                p.dims[2],
                p.camera.width,
                p.camera.height,
                p.threads,
                p.encoded.visible_voxels(),
                p.encoded.bytes()
            );
            println!(
                "frames={} median_ms={:.2} min_ms={:.2} preprocess_ms={:.1}",
                frames,
                times[frames / 2],
                times[0],
                preprocess
            );
        }
    }
    Ok(())
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            // Bad input files (unreadable, malformed, unsupported) exit with 2.
            if e.downcast_ref::<volume::LoadError>().is_some() {
                ExitCode::from(2)
            } else {
                ExitCode::FAILURE
            }
        }
    }
}
