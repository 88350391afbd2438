//! `shearwarp`: render volumes to PNG and benchmark the renderer.

use clap::{Args, Parser, Subcommand, ValueEnum};
use shearwarp_core::clip::Clip;
use shearwarp_core::composite::{FlatVoxels, Mode};
use shearwarp_core::crop::Crop;
use shearwarp_core::depth::DepthCue;
use shearwarp_core::shade::{Light, Lighting};
use shearwarp_core::view::Camera;
use shearwarp_core::{postclass, swv};
use shearwarp_file::anim;
use shearwarp_file::isa::Isa;
use shearwarp_file::presets;
use shearwarp_file::renderer::{FrameTimes, Renderer};
use shearwarp_file::scene::{self, Classification, Encoded, FlatVoxelsArg, Look};
use shearwarp_file::stats::median;
use shearwarp_file::tffile::{Resolved, TfFileError, TfSpec};
use shearwarp_file::tfspec;
use shearwarp_file::volume::{self, RawVolume, Voxels};
use shearwarp_file::{png, post, swvfile};
use std::error::Error;
use std::fmt;
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, Instant};

#[derive(Parser)]
#[command(name = "shearwarp", version, about = "Shear-warp volume renderer")]
struct Cli {
    #[command(subcommand)]
    command: Command,
    /// Print nothing but errors (and the --json object when asked for).
    #[arg(long, short, global = true)]
    quiet: bool,
    /// render, bench, info: print one JSON object on stdout instead of text.
    #[arg(long, global = true)]
    json: bool,
    /// Refuse volumes with more voxels than this (from their header, before reading the
    /// data); at most 2^30, the core's limit.
    #[arg(long, global = true, value_name = "N")]
    max_voxels: Option<u64>,
}

#[derive(Subcommand)]
enum Command {
    /// Render one view of a volume to a PNG.
    Render {
        /// Volume: a DICOM directory or file, .nii/.nii.gz, .nrrd/.nhdr, .mhd/.mha, a raw
        /// file (`.raw`, `.raw.gz`) or its JSON sidecar, or a `.swv`.
        volume: PathBuf,
        /// Output PNG; with --turntable a .gif, a .png (animated PNG) or a name with
        /// `%d`/`%03d` (numbered PNGs).
        #[arg(short, long)]
        output: PathBuf,
        /// Write 16 bits per channel (from the renderer's Q15 intermediate image).
        #[arg(long)]
        png16: bool,
        /// Render N frames turning 360/N degrees about the volume's Y axis (vertical on
        /// screen when --rotate-x is 0) from the start view, into an animation or
        /// numbered PNGs (see --output).
        #[arg(long, value_name = "N")]
        turntable: Option<usize>,
        /// Turntable frame duration in milliseconds.
        #[arg(long, default_value_t = 40)]
        frame_ms: u16,
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
    fn perspective(&self) -> Result<Option<f64>, Box<dyn Error>> {
        match self.projection {
            ProjectionArg::Parallel => Ok(None),
            ProjectionArg::Perspective if self.mode.dense() => Err(usage(
                "--projection perspective works with --mode composite or mip",
            )),
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
    /// Voxels with a zero gradient (plateaus, shaded as unoriented): blended into a
    /// sample's colour like the others, or excluded from it where voxels with a
    /// direction are present, as a ray caster normalising gradients per sample shades
    /// them (parallel projection; costs time only where there are such voxels). Auto
    /// excludes them when at least one in 16 of the visible voxels is flat (synthetic
    /// and segmented volumes), and blends them otherwise (scanned data).
    #[arg(long, value_enum, default_value_t = FlatVoxelsArg::Auto)]
    flat_voxels: FlatVoxelsArg,
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
    /// Instruction-set build of the compositing loop: baseline, x86-64-v3 or x86-64-v4
    /// (default: the highest this CPU runs; every level gives the same image).
    #[arg(long)]
    isa: Option<Isa>,
    /// Prefer the 16-bit file when the sidecar lists one.
    #[arg(long)]
    u16: bool,
    /// Named transfer function: ct-bone, ct-skin, ct-angio (Hounsfield units; the volume
    /// needs an HU mapping), mr-default, mr-brain, mip (relative to the data range).
    /// --opacity/--color/--gradient-opacity override its parts.
    #[arg(long, value_name = "NAME", value_parser = clap::builder::PossibleValuesParser::new(presets::NAMES), conflicts_with = "tf")]
    preset: Option<String>,
    /// Transfer-function JSON file (the schema of `shearwarp_file::tffile`, as the
    /// viewer's `T` key saves it). --opacity/--color/--gradient-opacity override parts.
    #[arg(long, value_name = "FILE")]
    tf: Option<PathBuf>,
    /// Window C:W (centre, width) mapped onto the 8-bit pipeline: values C−W/2..C+W/2
    /// become 0..255, values outside are clamped. In HU when the volume has an HU
    /// mapping, else in stored values.
    #[arg(long, value_name = "C:W", allow_hyphen_values = true)]
    window: Option<String>,
    /// Crop box X0:X1,Y0:Y1,Z0:Z1: the voxels kept, inclusive indices of the volume as
    /// stored (x fastest); a bound left out is the volume's edge (`:90,,` keeps x
    /// 0..=90). Classified modes bake it into the encoding; post/preint/iso apply it
    /// per frame.
    #[arg(long, value_name = "X0:X1,Y0:Y1,Z0:Z1")]
    crop: Option<String>,
    /// Clipping plane NX,NY,NZ[:OFFSET], repeatable up to 6 times: cuts away the part
    /// of the volume its normal (in the volume's x, y, z as stored, physical units)
    /// points into. OFFSET moves the plane from the volume's centre along the normal,
    /// as a fraction of the volume's half-extent that way: 0 (the default) halves the
    /// volume, 1 keeps all of it, -1 none. Classified modes bake the planes into the
    /// encoding (a .swv, already encoded, is cut as it is composited); post/preint/iso
    /// apply them per frame.
    #[arg(long, value_name = "NX,NY,NZ[:OFFSET]", allow_hyphen_values = true)]
    clip: Vec<String>,
    /// Inverse clipping: cut away the region behind every --clip plane (which they
    /// otherwise keep) and keep the rest, to take a wedge or a corner out of the volume.
    #[arg(long)]
    clip_invert: bool,
    /// Cut a classified volume by the --clip planes as its slices are composited, as a
    /// .swv is cut and as the desktop preview cuts (planes that move cost no encoding),
    /// instead of baking them into the encoding (which drops what they cut, so frames
    /// cost less). The images differ by rounding on the planes' one-voxel ramps.
    #[arg(long, requires = "clip")]
    clip_live: bool,
    /// Shade the cut's face as a surface: the voxels within VOXELS (0 to 16) of the
    /// --clip planes, on the side kept, are lit by the nearest plane's normal instead
    /// of their own gradient, which inside tissue is noise or nothing. 1 to 2 voxels
    /// reads as a solid cut face.
    #[arg(long, value_name = "VOXELS", requires = "clip")]
    clip_face: Option<f64>,
}

/// A bad command-line value or option combination (exit code 2).
#[derive(Debug)]
struct Usage(String);

impl fmt::Display for Usage {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl Error for Usage {}

fn usage(s: impl Into<String>) -> Box<dyn Error> {
    Box::new(Usage(s.into()))
}

/// What the user asked to see: progress on a terminal, text, JSON.
#[derive(Clone, Copy)]
struct Out {
    quiet: bool,
    json: bool,
    /// Progress bars: stderr is a terminal and neither --quiet nor --json.
    progress: bool,
}

impl Out {
    /// A spinner with `msg` (hidden unless progress is on).
    fn spinner(&self, msg: String) -> indicatif::ProgressBar {
        if !self.progress {
            return indicatif::ProgressBar::hidden();
        }
        let pb = indicatif::ProgressBar::new_spinner().with_message(msg);
        pb.enable_steady_tick(Duration::from_millis(100));
        pb
    }

    /// A bar of `n` steps with `msg` (hidden unless progress is on).
    fn bar(&self, n: usize, msg: &str) -> indicatif::ProgressBar {
        if !self.progress {
            return indicatif::ProgressBar::hidden();
        }
        let style = indicatif::ProgressStyle::with_template(
            "{msg} [{bar:30}] {pos}/{len} {elapsed_precise} (eta {eta})",
        )
        .map(|s| s.progress_chars("=> "))
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar());
        indicatif::ProgressBar::new(n as u64)
            .with_style(style)
            .with_message(msg.to_string())
    }

    /// A human-readable status line on stderr (not with --quiet or --json).
    fn note(&self, msg: impl fmt::Display) {
        if !self.quiet && !self.json {
            eprintln!("{msg}");
        }
    }

    /// Text results on stdout (not with --quiet).
    fn text(&self, msg: impl fmt::Display) {
        if !self.quiet {
            println!("{msg}");
        }
    }
}

/// The transfer function and mode a render uses, in the (possibly windowed) volume's
/// stored values.
struct Tf {
    mode: ModeArg,
    shading: bool,
    opacity: Vec<(f64, f64)>,
    color: Vec<(f64, [u8; 3])>,
    gradient: Option<Vec<(f64, f64)>>,
    iso: Option<f64>,
}

struct Prepared {
    threads: usize,
    name: String,
    dims: [usize; 3],
    encoded: Encoded,
    look: Look,
    camera: Camera,
    /// How the frames take flat voxels (`--flat-voxels`, resolved for the volume).
    flat_voxels: FlatVoxels,
    /// Clipping planes applied as the slices are composited: a `.swv`'s `--clip`
    /// (a raw volume's are baked into its encoding instead, which drops what they cut).
    clip: Clip,
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

fn camera_of(o: &RenderOpts) -> Result<Camera, Box<dyn Error>> {
    let (width, height) = tfspec::parse_size(&o.size)?;
    Ok(Camera {
        rotate_x: o.rotate_x,
        rotate_y: o.rotate_y,
        width,
        height,
    })
}

fn prepare(path: &Path, o: &RenderOpts, out: Out) -> Result<Prepared, Box<dyn Error>> {
    let camera = camera_of(o)?;
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let mut live_clip = Clip::NONE;
    let (mut encoded, look) = if swvfile::is_swv(path) {
        if o.opacity.is_some()
            || o.gradient_opacity.is_some()
            || o.u16
            || o.preset.is_some()
            || o.tf.is_some()
            || o.window.is_some()
            || o.crop.is_some()
            || o.lod > 0
        {
            return Err(usage(format!(
                "{}: opacity is baked into a .swv file; re-encode it with `shearwarp encode` \
                 to change --opacity/--gradient-opacity/--preset/--tf/--window/--u16/--crop \
                 (or to render a --lod level)",
                path.display()
            )));
        }
        let (enc, file_look) = swvfile::read_swv(path)?;
        // Planes given for a .swv cut it as it is composited (any planes it was encoded
        // with stay, so the two cuts add up).
        let (dims, spacing) = (enc.grid.dims, enc.grid.spacing);
        live_clip = clip_for(o, &clip_planes(o, dims, spacing)?, dims, spacing)?;
        let color = match &o.color {
            Some(s) => scene::color_table(&tfspec::parse_color(s)?, enc.range)?,
            None => file_look.color,
        };
        let lighting = if o.shading {
            Some(cli_lighting(o)?)
        } else {
            file_look.lighting
        };
        let look = look_of(o, o.mode, color, lighting, true)?;
        (enc, look)
    } else {
        let (raw, tf) = load_with_tf(path, o, out)?;
        let sp = out.spinner(format!("classifying and encoding {name}"));
        let crop = crop_of(o, raw.dims)?;
        let planes = clip_planes(o, raw.dims, raw.spacing)?;
        // Planes baked into the encoding, for a grid of the volume's or a level's; live
        // ones are made for the grid encoded, below.
        let baked = |dims, spacing| match o.clip_live {
            true => Ok::<_, Box<dyn Error>>(Clip::NONE),
            false => clip_for(o, &planes, dims, spacing),
        };
        let mut class = Classification {
            opacity: tf.opacity.clone(),
            gradient: tf.gradient.clone(),
            min_opacity: o.min_opacity,
            cut: scene::Cut {
                crop,
                clip: baked(raw.dims, raw.spacing)?,
            },
        };
        let enc = if o.lod > 0 {
            if o.lod > 8 {
                return Err(usage("--lod must be 0..=8"));
            }
            let full = shearwarp_core::classify::Grid::new(raw.dims, raw.spacing)?;
            let (level, _) = scene::lod(&raw, o.lod)?;
            if let (Some(c), Some(s)) = (crop, &o.crop) {
                // The box in the level's voxels: those centred in its cells.
                let at = c.at_level(raw.dims, level.dims, 1 << o.lod);
                class.cut.crop = Some(at.ok_or_else(|| {
                    usage(format!("--crop '{s}': holds no voxel of --lod {}", o.lod))
                })?);
            }
            // The planes keep their place about the centre, which the level shares.
            class.cut.clip = baked(level.dims, level.spacing)?;
            scene::encode(&level, &class)?.as_level(&full)
        } else {
            scene::encode(&raw, &class)?
        };
        if o.clip_live {
            let g = &enc.grid;
            live_clip = clip_for(o, &planes, g.dims, g.spacing)?;
        }
        sp.finish_and_clear();
        let color = scene::color_table(&tf.color, enc.range)?;
        let lighting = tf.shading.then(|| cli_lighting(o)).transpose()?;
        let look = look_of(o, tf.mode, color, lighting, true)?;
        (enc, look)
    };
    let flat_voxels = o.flat_voxels.resolve(&encoded);
    // Only parallel projections in composite mode read the tables of flat voxels: MIP
    // shades nothing, and perspective rows take no rule for flat voxels. Building them
    // for those took spheres256 about 10 ms of preprocessing for nothing.
    let reads_flat_rows = look.mode == Mode::Composite && o.perspective()?.is_none();
    if flat_voxels == FlatVoxels::Excluded && reads_flat_rows {
        encoded.build_flat_rows()?;
    }
    let threads = thread_count(o)?;
    Ok(Prepared {
        threads,
        name,
        dims: encoded.grid.dims,
        encoded,
        look,
        camera,
        flat_voxels,
        clip: live_clip,
    })
}

fn look_of(
    o: &RenderOpts,
    mode: ModeArg,
    color: shearwarp_core::classify::ColorTable,
    lighting: Option<Lighting>,
    classified: bool,
) -> Result<Look, Box<dyn Error>> {
    if !classified && (o.depth_cue.is_some() || o.shadows) {
        return Err(usage(
            "--depth-cue and --shadows work with --mode composite only",
        ));
    }
    Ok(Look {
        mode: match mode {
            ModeArg::Mip => Mode::Mip,
            _ => Mode::Composite,
        },
        color,
        lighting,
        ert_threshold: o.ert,
        depth_cue: o.depth_cue.as_deref().map(parse_depth_cue).transpose()?,
        shadows: o.shadows,
    })
}

/// Loads a volume and works out its transfer function: --preset or --tf (resolved
/// against the volume's value mapping), overridden by --opacity/--color/
/// --gradient-opacity, then --window (which turns the volume into 8 bits and moves
/// every point with it), then the defaults for what is still missing.
fn load_with_tf(path: &Path, o: &RenderOpts, out: Out) -> Result<(RawVolume, Tf), Box<dyn Error>> {
    let prefer = if o.u16 {
        volume::Prefer::U16
    } else {
        volume::Prefer::U8
    };
    let sp = out.spinner(format!("loading {}", path.display()));
    let (raw, meta) = volume::load_volume_meta(path, prefer)?;
    sp.finish_and_clear();
    let scale = presets::value_scale(&raw, &meta);
    let base: Option<Resolved> = match (&o.preset, &o.tf) {
        (Some(n), _) => {
            let p = presets::find(n).ok_or_else(|| usage(format!("unknown preset '{n}'")))?;
            Some(p.spec().resolve(&scale, path)?)
        }
        (None, Some(f)) => Some(TfSpec::load(f)?.resolve(&scale, path)?),
        (None, None) => None,
    };
    let mut mode = o.mode;
    if base.as_ref().is_some_and(|b| b.mip) {
        match mode {
            ModeArg::Composite | ModeArg::Mip => mode = ModeArg::Mip,
            _ => {
                return Err(usage(
                    "the transfer function asks for MIP, which --mode post/preint/iso cannot do",
                ))
            }
        }
    }
    let shading = o.shading || base.as_ref().is_some_and(|b| b.shading == Some(true));
    let mut opacity = match &o.opacity {
        Some(s) => Some(tfspec::parse_opacity(s)?),
        None => base.as_ref().map(|b| b.opacity.clone()),
    };
    let mut color = match &o.color {
        Some(s) => Some(tfspec::parse_color(s)?),
        None => base.as_ref().and_then(|b| b.color.clone()),
    };
    let mut gradient = match &o.gradient_opacity {
        Some(s) => Some(tfspec::parse_opacity(s)?),
        None => base.as_ref().and_then(|b| b.gradient_opacity.clone()),
    };
    let mut iso = o.iso;
    let raw = match &o.window {
        None => raw,
        Some(w) => {
            let (lo, hi) = window_bounds(w, &scale)?;
            let to8 = |v: f64| (v - lo) * 255.0 / (hi - lo);
            for p in opacity.iter_mut().flatten() {
                p.0 = to8(p.0);
            }
            for p in color.iter_mut().flatten() {
                p.0 = to8(p.0);
            }
            for p in gradient.iter_mut().flatten() {
                p.0 *= 255.0 / (hi - lo);
            }
            iso = iso.map(to8);
            window_volume(raw, lo, hi)
        }
    };
    let range = match &raw.voxels {
        Voxels::U8(_) => (0, 255),
        Voxels::U16(_) => presets::stored_range(&raw),
    };
    let tf = Tf {
        mode,
        shading,
        opacity: opacity.unwrap_or_else(|| default_opacity(range, mode)),
        color: color.unwrap_or_else(|| default_color(range)),
        gradient,
        iso,
    };
    Ok((raw, tf))
}

/// Stored-value bounds `(C − W/2, C + W/2)` of `--window C:W` (C and W in HU when the
/// volume has an HU mapping).
fn window_bounds(
    spec: &str,
    scale: &shearwarp_file::tffile::ValueScale,
) -> Result<(f64, f64), Box<dyn Error>> {
    let bad = || {
        usage(format!(
            "--window '{spec}': expected CENTRE:WIDTH, e.g. 40:400 (width > 0)"
        ))
    };
    let (c, w) = spec.split_once(':').ok_or_else(bad)?;
    let c: f64 = c.trim().parse().map_err(|_| bad())?;
    let w: f64 = w.trim().parse().map_err(|_| bad())?;
    if !(c.is_finite() && w.is_finite() && w > 0.0) {
        return Err(bad());
    }
    let (lo, hi) = (c - w / 2.0, c + w / 2.0);
    let (lo, hi) = match scale.hu {
        Some((slope, intercept)) => ((lo - intercept) / slope, (hi - intercept) / slope),
        None => (lo, hi),
    };
    if !(lo.is_finite() && hi.is_finite() && hi - lo > 0.0 && (hi - lo).is_finite()) {
        return Err(usage(format!("--window '{spec}': out of range")));
    }
    Ok((lo, hi))
}

/// The 8-bit volume of the window `lo..hi` (stored values): `round((v − lo) · 255 / (hi −
/// lo))`, clamped to 0..255.
fn window_volume(raw: RawVolume, lo: f64, hi: f64) -> RawVolume {
    let map = |v: f64| ((v - lo) * 255.0 / (hi - lo)).round().clamp(0.0, 255.0) as u8;
    let voxels = match &raw.voxels {
        Voxels::U8(d) => d.iter().map(|&v| map(v as f64)).collect(),
        Voxels::U16(d) => d.iter().map(|&v| map(v as f64)).collect(),
    };
    RawVolume {
        voxels: Voxels::U8(voxels),
        ..raw
    }
}

/// `--threads`, or all cores.
fn thread_count(o: &RenderOpts) -> Result<usize, Box<dyn Error>> {
    let threads = o
        .threads
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    if threads == 0 || threads > 256 {
        return Err(usage("--threads must be 1..=256"));
    }
    Ok(threads)
}

struct Dense {
    vol: post::DenseVolume,
    renderer: post::PostRenderer,
    mode: postclass::PostMode,
    opacity: Vec<(f64, f64)>,
    look: Look,
    camera: Camera,
    cut: scene::Cut,
}

fn prepare_dense(path: &Path, o: &RenderOpts, out: Out) -> Result<Dense, Box<dyn Error>> {
    if swvfile::is_swv(path) {
        return Err(usage(format!(
            "{}: --mode post/preint/iso need the unclassified volume, not a .swv",
            path.display()
        )));
    }
    if o.lod > 0 {
        return Err(usage(
            "--lod renders the classified volume; --mode post/preint/iso take the full one",
        ));
    }
    let camera = camera_of(o)?;
    let threads = thread_count(o)?;
    let (raw, tf) = load_with_tf(path, o, out)?;
    let cut = scene::Cut {
        crop: crop_of(o, raw.dims)?,
        clip: clip_for(
            o,
            &clip_planes(o, raw.dims, raw.spacing)?,
            raw.dims,
            raw.spacing,
        )?,
    };
    let sp = out.spinner("quantising and computing normals".into());
    let vol = post::DenseVolume::new(&raw)?;
    sp.finish_and_clear();
    let mode = match tf.mode {
        ModeArg::Post => postclass::PostMode::PostClassified,
        ModeArg::Preint => postclass::PostMode::PreIntegrated,
        _ => {
            let iso = tf
                .iso
                .ok_or_else(|| usage("--mode iso needs --iso VALUE (raw voxel units)"))?;
            if !iso.is_finite() {
                return Err(usage("--iso must be a finite number"));
            }
            postclass::PostMode::Isosurface(vol.quantize(iso))
        }
    };
    let color = scene::color_table(&tf.color, vol.range)?;
    let lighting = tf.shading.then(|| cli_lighting(o)).transpose()?;
    let look = look_of(o, ModeArg::Composite, color, lighting, false)?;
    let renderer = post::PostRenderer::with_threads(&vol, threads);
    Ok(Dense {
        vol,
        renderer,
        mode,
        opacity: tf.opacity,
        look,
        camera,
        cut,
    })
}

/// The box of `--crop`, if given, for a volume of `dims` ([`parse_crop`]).
fn crop_of(o: &RenderOpts, dims: [usize; 3]) -> Result<Option<Crop>, Box<dyn Error>> {
    o.crop.as_deref().map(|s| parse_crop(s, dims)).transpose()
}

/// `--crop X0:X1,Y0:Y1,Z0:Z1` for a volume of `dims`: three ranges of inclusive voxel
/// indices, either bound of each optional (`10:`, `:90`, `:` or nothing: up to the
/// volume's edge).
fn parse_crop(s: &str, dims: [usize; 3]) -> Result<Crop, Box<dyn Error>> {
    let bad = |why: String| usage(format!("--crop '{s}': {why}"));
    let parts: Vec<&str> = s.split(',').collect();
    let [x, y, z] = parts[..] else {
        return Err(bad("expected three ranges X0:X1,Y0:Y1,Z0:Z1".into()));
    };
    let mut lo = [0; 3];
    let mut hi = [0; 3];
    for (a, part) in [x, y, z].into_iter().enumerate() {
        let (l, h) = match part.trim() {
            "" => ("", ""),
            p => p
                .split_once(':')
                .ok_or_else(|| bad(format!("range '{p}' is not LO:HI")))?,
        };
        let bound = |t: &str, edge: usize| -> Result<usize, Box<dyn Error>> {
            match t.trim() {
                "" => Ok(edge),
                t => t
                    .parse()
                    .map_err(|_| bad(format!("'{t}' is not a voxel index"))),
            }
        };
        let axis = ["x", "y", "z"][a];
        lo[a] = bound(l, 0)?;
        hi[a] = bound(h, dims[a] - 1)?;
        if let Some(&far) = [lo[a], hi[a]].iter().find(|&&b| b >= dims[a]) {
            return Err(bad(format!(
                "{axis} bound {far} is outside the volume (0..={})",
                dims[a] - 1
            )));
        }
        if lo[a] > hi[a] {
            return Err(bad(format!("{axis} range {}:{} is empty", lo[a], hi[a])));
        }
    }
    Ok(Crop::new(lo, hi, dims)?)
}

/// A clipping plane as [`Clip::with_plane`] takes it: normal, and signed distance from
/// the volume's centre in physical units.
type PlaneSpec = ([f64; 3], f64);

/// The planes of `--clip`, for a volume of `dims` voxels spaced `spacing` apart: each
/// as its normal and its signed distance from the volume's centre (physical units), as
/// [`Clip::with_plane`] takes them ([`parse_clip`]).
fn clip_planes(
    o: &RenderOpts,
    dims: [usize; 3],
    spacing: [f64; 3],
) -> Result<Vec<PlaneSpec>, Box<dyn Error>> {
    if o.clip.len() > shearwarp_core::clip::MAX_PLANES {
        return Err(usage(format!(
            "--clip: at most {} planes",
            shearwarp_core::clip::MAX_PLANES
        )));
    }
    let grid = shearwarp_core::classify::Grid::new(dims, spacing)?;
    o.clip
        .iter()
        .map(|s| {
            let (n, offset) = parse_clip(s)?;
            Ok((n, Clip::offset_distance(&grid, n, offset)))
        })
        .collect()
}

/// The clip of `planes` ([`clip_planes`]) for a grid of `dims` and `spacing`: the
/// volume's own, or a level of it (which has the same centre); inverted with
/// `--clip-invert`.
fn clip_for(
    o: &RenderOpts,
    planes: &[PlaneSpec],
    dims: [usize; 3],
    spacing: [f64; 3],
) -> Result<Clip, Box<dyn Error>> {
    if planes.is_empty() {
        if o.clip_invert {
            return Err(usage("--clip-invert needs at least one --clip plane"));
        }
        return Ok(Clip::NONE);
    }
    let grid = shearwarp_core::classify::Grid::new(dims, spacing)?;
    let mut clip = Clip::NONE;
    for &(n, d) in planes {
        clip = clip.with_plane(&grid, n, d)?;
    }
    let face = o.clip_face.unwrap_or(0.0);
    if !(0.0..=shearwarp_core::clip::MAX_FACE).contains(&face) {
        return Err(usage(format!(
            "--clip-face {face}: the face's thickness is 0 to 16 voxels"
        )));
    }
    let clip = clip.with_shaded_face(face)?;
    Ok(if o.clip_invert { clip.inverted() } else { clip })
}

/// One `--clip NX,NY,NZ[:OFFSET]`: the normal, and the offset (−1..=1, default 0).
fn parse_clip(s: &str) -> Result<([f64; 3], f64), Box<dyn Error>> {
    let bad = |why: String| usage(format!("--clip '{s}': {why}"));
    let (normal, offset) = match s.split_once(':') {
        Some((n, f)) => (n, Some(f)),
        None => (s, None),
    };
    let num = |t: &str| -> Result<f64, Box<dyn Error>> {
        t.trim()
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .ok_or_else(|| bad(format!("'{}' is not a number", t.trim())))
    };
    let parts: Vec<&str> = normal.split(',').collect();
    let [x, y, z] = parts[..] else {
        return Err(bad(
            "expected a normal NX,NY,NZ and an optional :OFFSET".into()
        ));
    };
    let n = [num(x)?, num(y)?, num(z)?];
    if n.iter().all(|&v| v == 0.0) {
        return Err(bad("the normal is zero".into()));
    }
    let offset = offset.map(num).transpose()?.unwrap_or(0.0);
    if !(-1.0..=1.0).contains(&offset) {
        return Err(bad(format!("offset {offset} is outside -1..=1")));
    }
    Ok((n, offset))
}

fn parse_depth_cue(s: &str) -> Result<DepthCue, Box<dyn Error>> {
    let bad = || {
        usage(format!(
            "--depth-cue '{s}': expected FRONT:DENSITY, e.g. 1:1.5"
        ))
    };
    let (f, d) = s.split_once(':').ok_or_else(bad)?;
    let cue = DepthCue {
        front: f.trim().parse().map_err(|_| bad())?,
        density: d.trim().parse().map_err(|_| bad())?,
    };
    cue.validate()
        .map_err(|e| usage(format!("--depth-cue '{s}': {e}")))?;
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
                    let rgb = tfspec::parse_color(&format!("0:{}", c.trim())).map_err(|_| {
                        usage(format!("--light '{s}': colour must be #rrggbb or #rgb"))
                    })?;
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
                .map_err(|_| usage("at most 4 lights (--light) are supported"))?;
        }
    }
    Ok(l)
}

/// How `render` writes its result.
struct Output<'a> {
    path: &'a Path,
    png16: bool,
    turntable: Option<usize>,
    frame_ms: u16,
}

fn rgb8(frame: &[[u8; 4]]) -> Vec<u8> {
    frame.iter().flat_map(|p| [p[0], p[1], p[2]]).collect()
}

/// Renders and writes one image or a turntable; returns (frames, total render ms).
fn render_out(
    o: &Output<'_>,
    camera: Camera,
    out: Out,
    mut frame8: impl FnMut(&Camera) -> Result<Vec<[u8; 4]>, Box<dyn Error>>,
    mut frame16: impl FnMut(&Camera) -> Result<Vec<[u16; 4]>, Box<dyn Error>>,
) -> Result<(usize, f64), Box<dyn Error>> {
    let (w, h) = (camera.width, camera.height);
    let write_err = |e: &dyn fmt::Display| format!("cannot write {}: {e}", o.path.display());
    let Some(n) = o.turntable else {
        let t = Instant::now();
        if o.png16 {
            let f = frame16(&camera)?;
            let ms = t.elapsed().as_secs_f64() * 1e3;
            png::save_png16(o.path, w, h, &f).map_err(|e| write_err(&e))?;
            return Ok((1, ms));
        }
        let f = frame8(&camera)?;
        let ms = t.elapsed().as_secs_f64() * 1e3;
        png::save_png(o.path, w, h, &f).map_err(|e| write_err(&e))?;
        return Ok((1, ms));
    };
    if n == 0 || n > 3600 {
        return Err(usage("--turntable must be 1..=3600 frames"));
    }
    let target = anim::target(o.path).ok_or_else(|| {
        usage(format!(
            "{}: --turntable writes .gif, .png (animated PNG) or numbered PNGs (a name with %d)",
            o.path.display()
        ))
    })?;
    if o.png16 && matches!(target, anim::Target::Gif(_)) {
        return Err(usage(format!(
            "{}: a GIF holds 8-bit colour only; use .png (APNG) or numbered PNGs with --png16",
            o.path.display()
        )));
    }
    let mut writer = anim::Writer::create(&target, w, h, n, o.frame_ms, o.png16)?;
    let bar = out.bar(n, "turntable");
    let mut ms = 0.0;
    for i in 0..n {
        let mut cam = camera;
        cam.rotate_y += 360.0 * i as f64 / n as f64;
        let t = Instant::now();
        let px = if o.png16 {
            let f = frame16(&cam)?;
            anim::Pixels::Rgb16(f.iter().flat_map(|p| [p[0], p[1], p[2]]).collect())
        } else {
            anim::Pixels::Rgb8(rgb8(&frame8(&cam)?))
        };
        ms += t.elapsed().as_secs_f64() * 1e3;
        writer.push(px)?;
        bar.inc(1);
    }
    writer.finish()?;
    bar.finish_and_clear();
    Ok((n, ms))
}

fn run(mut cli: Cli) -> Result<(), Box<dyn Error>> {
    if let Command::Render { opts, .. }
    | Command::Bench { opts, .. }
    | Command::Encode { opts, .. } = &mut cli.command
    {
        if opts.preintegrated {
            if opts.mode != ModeArg::Composite && opts.mode != ModeArg::Preint {
                return Err(usage("--preintegrated conflicts with --mode"));
            }
            opts.mode = ModeArg::Preint;
        }
    }
    let out = Out {
        quiet: cli.quiet,
        json: cli.json,
        progress: !cli.quiet && !cli.json && std::io::stderr().is_terminal(),
    };
    if cli.json
        && matches!(
            cli.command,
            Command::Compare { .. } | Command::Memory { .. } | Command::Encode { .. }
        )
    {
        return Err(usage("--json is for render, bench and info"));
    }
    match cli.command {
        Command::Render {
            volume,
            output,
            png16,
            turntable,
            frame_ms,
            opts,
        } => {
            let o = Output {
                path: &output,
                png16,
                turntable,
                frame_ms,
            };
            let (dims, camera, frames, ms) = if opts.mode.dense() {
                if png16 {
                    return Err(usage("--png16 works with --mode composite or mip"));
                }
                opts.perspective()?;
                let mut d = prepare_dense(&volume, &opts, out)?;
                let camera = d.camera;
                let dims = d.vol.grid.dims;
                let (frames, ms) = render_out(
                    &o,
                    camera,
                    out,
                    |cam| {
                        Ok(d.renderer
                            .render(&d.vol, d.mode, &d.opacity, &d.look, cam, d.cut)?)
                    },
                    |_| Err(usage("--png16 works with --mode composite or mip")),
                )?;
                (dims, camera, frames, ms)
            } else {
                let p = prepare(&volume, &opts, out)?;
                let src = p.encoded.volume()?;
                let mut r = Renderer::with_threads(&p.encoded.grid, p.threads);
                r.set_isa(opts.isa.unwrap_or_else(Isa::detect));
                r.set_supersample(opts.supersample)?;
                r.set_flat_voxels(p.flat_voxels);
                r.set_perspective(opts.perspective()?);
                r.set_clip(p.clip);
                let r = std::cell::RefCell::new(r);
                let (frames, ms) = render_out(
                    &o,
                    p.camera,
                    out,
                    |cam| Ok(r.borrow_mut().render(&mut src.clone(), cam, &p.look)?),
                    |cam| Ok(r.borrow_mut().render16(&mut src.clone(), cam, &p.look)?),
                )?;
                (p.dims, p.camera, frames, ms)
            };
            if out.json {
                println!(
                    "{}",
                    serde_json::json!({
                        "volume": volume.display().to_string(),
                        "output": output.display().to_string(),
                        "dims_xyz": dims,
                        "image": [camera.width, camera.height],
                        "frames": frames,
                        "bit_depth": if png16 { 16 } else { 8 },
                        "render_ms": ms,
                    })
                );
            } else {
                out.note(format_args!(
                    "{}: {}x{}x{} -> {} ({}x{}{})",
                    volume.display(),
                    dims[0],
                    dims[1],
                    dims[2],
                    output.display(),
                    camera.width,
                    camera.height,
                    if frames > 1 {
                        format!(", {frames} frames")
                    } else {
                        String::new()
                    }
                ));
            }
        }
        Command::Bench {
            volume,
            frames,
            opts,
        } if opts.mode.dense() => {
            if frames == 0 {
                return Err(usage("--frames must be at least 1"));
            }
            opts.perspective()?;
            let t0 = Instant::now();
            let mut d = prepare_dense(&volume, &opts, out)?;
            let preprocess = t0.elapsed().as_secs_f64() * 1e3;
            // Every frame changes the transfer function (the ramp shifts by 4% of the
            // range back and forth), so each time includes reclassification.
            let span = (d.vol.range.1 as f64 - d.vol.range.0 as f64).max(1.0);
            let times = time_turntable(frames, d.camera, out, |i, cam| {
                let shift = if i % 2 == 0 { 0.0 } else { 0.04 * span };
                let op: Vec<(f64, f64)> = d.opacity.iter().map(|&(v, a)| (v + shift, a)).collect();
                let t = Instant::now();
                let frame = d
                    .renderer
                    .render(&d.vol, d.mode, &op, &d.look, cam, d.cut)?;
                let ms = t.elapsed().as_secs_f64() * 1e3;
                std::hint::black_box(frame);
                Ok(ms)
            })?;
            if out.json {
                println!(
                    "{}",
                    serde_json::json!({
                        "volume": volume.display().to_string(),
                        "mode": format!("{:?}", d.mode),
                        "threads": d.renderer.threads(),
                        "dims_xyz": d.vol.grid.dims,
                        "image": [d.camera.width, d.camera.height],
                        "frames": frames,
                        "median_ms": median(&times),
                        "min_ms": times[0],
                        "preprocess_ms": preprocess,
                    })
                );
            } else {
                out.text(format_args!(
                    "volume={} mode={:?} image={}x{} threads={} (every frame after a transfer-function change)",
                    volume.display(),
                    d.mode,
                    d.camera.width,
                    d.camera.height,
                    d.renderer.threads()
                ));
                out.text(format_args!(
                    "frames={} median_ms={:.2} min_ms={:.2} preprocess_ms={:.1}",
                    frames,
                    median(&times),
                    times[0],
                    preprocess
                ));
            }
        }
        Command::Info { volume, u16 } => {
            let prefer = if u16 {
                volume::Prefer::U16
            } else {
                volume::Prefer::U8
            };
            let sp = out.spinner(format!("loading {}", volume.display()));
            let (raw, meta) = volume::load_volume_meta(&volume, prefer)?;
            let info = shearwarp_file::info::compute(&raw, &meta);
            sp.finish_and_clear();
            let shown = volume.display().to_string();
            if out.json {
                println!(
                    "{}",
                    serde_json::to_string_pretty(&shearwarp_file::info::to_json(&info, &shown))?
                );
            } else if !out.quiet {
                print!("{}", shearwarp_file::info::to_text(&info, &shown));
            }
        }
        Command::Memory { dims, width } => {
            let d: Vec<usize> = dims
                .split(['x', 'X'])
                .map(|t| t.trim().parse::<usize>())
                .collect::<Result<_, _>>()
                .map_err(|_| usage(format!("dims '{dims}': expected NXxNYxNZ")))?;
            let [nx, ny, nz] = d[..] else {
                return Err(usage(format!("dims '{dims}': expected three numbers")));
            };
            shearwarp_core::classify::Grid::new([nx, ny, nz], [1.0; 3])?;
            if width == 0 || width > shearwarp_core::view::MAX_IMAGE {
                return Err(usage(format!("width {width}: must be 1..=16384")));
            }
            let ws = shearwarp_core::render::workspace_bytes([nx, ny, nz], width);
            let st = swv::stream_buffer_bytes([nx, ny, nz]);
            out.text(format_args!(
                "dims={nx}x{ny}x{nz} width={width} workspace_bytes={ws} stream_bytes={st} total_bytes={}",
                ws + st
            ));
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
            out.text(format_args!("max_channel_error={max} psnr_db={psnr:.2}"));
            if max > tolerance {
                return Err(format!("images differ: max channel error {max} > {tolerance}").into());
            }
        }
        Command::Encode {
            volume,
            output,
            opts,
        } => {
            let p = prepare(&volume, &opts, out)?;
            if !p.clip.is_empty() {
                return Err(usage(
                    "encode bakes --clip planes into a raw volume's encoding; planes that cut \
                     as the slices are composited (--clip-live, or --clip on a .swv) belong \
                     to render and bench",
                ));
            }
            let look = swv::Look {
                color: p.look.color,
                lighting: p.look.lighting.clone(),
            };
            swvfile::write_swv(&p.encoded, &look, &output)?;
            let bytes = std::fs::metadata(&output).map(|m| m.len()).unwrap_or(0);
            out.note(format_args!(
                "{}: {}x{}x{} -> {} ({} bytes, {} stored voxels per axis copy)",
                p.name,
                p.dims[0],
                p.dims[1],
                p.dims[2],
                output.display(),
                bytes,
                p.encoded.visible_voxels()
            ));
        }
        Command::Bench {
            volume,
            frames,
            opts,
        } => {
            if frames == 0 {
                return Err(usage("--frames must be at least 1"));
            }
            let t0 = Instant::now();
            let p = prepare(&volume, &opts, out)?;
            let preprocess = t0.elapsed().as_secs_f64() * 1e3;
            let mut src = p.encoded.volume()?;
            let mut r = Renderer::with_threads(&p.encoded.grid, p.threads);
            r.set_isa(opts.isa.unwrap_or_else(Isa::detect));
            r.set_supersample(opts.supersample)?;
            r.set_flat_voxels(p.flat_voxels);
            r.set_perspective(opts.perspective()?);
            r.set_clip(p.clip);
            // One output buffer for every frame, as a viewer keeps its window's and as
            // `shearwarp-bench` times it, so that the allocator is not part of the figure.
            let mut frame = Vec::new();
            let mut phases = Vec::with_capacity(frames);
            let times = time_turntable(frames, p.camera, out, |_, cam| {
                let t = Instant::now();
                r.render_into(&mut src, cam, &p.look, &mut frame)?;
                let ms = t.elapsed().as_secs_f64() * 1e3;
                std::hint::black_box(&frame);
                phases.push(r.times().clone());
                Ok(ms)
            })?;
            let phase = PhaseMedians::of(&phases);
            if out.json {
                println!(
                    "{}",
                    serde_json::json!({
                        "volume": p.name,
                        "dims_xyz": p.dims,
                        "image": [p.camera.width, p.camera.height],
                        "threads": p.threads,
                        "isa": r.isa().name(),
                        "visible_voxels": p.encoded.visible_voxels(),
                        "flat_voxels": p.flat_voxels.name(),
                        "rle_bytes": p.encoded.bytes(),
                        "frames": frames,
                        "median_ms": median(&times),
                        "min_ms": times[0],
                        "preprocess_ms": preprocess,
                        "phase_medians_ms": {
                            "setup": phase.setup,
                            "composite": phase.composite,
                            "busy": phase.busy,
                            "warp": phase.warp,
                        },
                    })
                );
            } else {
                out.text(format_args!(
                    "volume={} dims={}x{}x{} image={}x{} threads={} isa={} visible_voxels={} flat_voxels={} rle_bytes={}",
                    p.name,
                    p.dims[0],
                    p.dims[1],
                    p.dims[2],
                    p.camera.width,
                    p.camera.height,
                    p.threads,
                    r.isa().name(),
                    p.encoded.visible_voxels(),
                    p.flat_voxels.name(),
                    p.encoded.bytes()
                ));
                out.text(format_args!(
                    "frames={} median_ms={:.2} min_ms={:.2} preprocess_ms={:.1}",
                    frames,
                    median(&times),
                    times[0],
                    preprocess
                ));
                let busy: Vec<String> = phase.busy.iter().map(|b| format!("{b:.2}")).collect();
                out.text(format_args!(
                    "phase medians: setup_ms={:.3} composite_ms={:.2} busy_ms={} warp_ms={:.3}",
                    phase.setup,
                    phase.composite,
                    busy.join(","),
                    phase.warp
                ));
            }
        }
    }
    Ok(())
}

/// Medians over frames of each phase of [`Renderer::times`], ms (`busy` per thread).
struct PhaseMedians {
    setup: f64,
    composite: f64,
    busy: Vec<f64>,
    warp: f64,
}

impl PhaseMedians {
    fn of(frames: &[FrameTimes]) -> Self {
        let median_of = |f: &dyn Fn(&FrameTimes) -> Option<Duration>| {
            let v: Vec<f64> = frames
                .iter()
                .filter_map(f)
                .map(|d| d.as_secs_f64() * 1e3)
                .collect();
            median(&v)
        };
        let threads = frames.iter().map(|t| t.busy.len()).max().unwrap_or(0);
        PhaseMedians {
            setup: median_of(&|t| Some(t.setup)),
            composite: median_of(&|t| Some(t.composite)),
            busy: (0..threads)
                .map(|i| median_of(&|t| t.busy.get(i).copied()))
                .collect(),
            warp: median_of(&|t| Some(t.warp)),
        }
    }
}

/// `bench`'s timing loop: `frames` views turned 360/frames degrees apart about Y, each
/// timed by `frame` (given its index and camera, returning milliseconds), with a progress
/// bar; returns the times sorted.
fn time_turntable(
    frames: usize,
    camera: Camera,
    out: Out,
    mut frame: impl FnMut(usize, &Camera) -> Result<f64, Box<dyn Error>>,
) -> Result<Vec<f64>, Box<dyn Error>> {
    let mut times = Vec::with_capacity(frames);
    let bar = out.bar(frames, "bench");
    for i in 0..frames {
        let mut cam = camera;
        cam.rotate_y += 360.0 * i as f64 / frames as f64;
        times.push(frame(i, &cam)?);
        bar.inc(1);
    }
    bar.finish_and_clear();
    times.sort_by(f64::total_cmp);
    Ok(times)
}

/// Bad input (unreadable or malformed files, unsupported content, bad option values,
/// including those only the core's checks catch, such as `--supersample 9`): exit code
/// 2, like clap's usage errors. Failures to write, and the core's own faults (a buffer
/// it was given too small, a thread that panicked), exit with 1.
fn is_bad_input(e: &(dyn Error + 'static)) -> bool {
    use shearwarp_core::Error as Core;
    let core_input = |c: &Core| {
        matches!(
            c,
            Core::BadDimensions { .. }
                | Core::BadSpacing
                | Core::BadTransferFunction { .. }
                | Core::MalformedRle { .. }
                | Core::BadParameter { .. }
                | Core::Format { .. }
        )
    };
    e.is::<volume::LoadError>()
        || e.is::<TfFileError>()
        || e.is::<tfspec::TfError>()
        || e.is::<Usage>()
        || e.downcast_ref::<swvfile::SwvError>()
            .is_some_and(swvfile::SwvError::is_bad_input)
        || e.downcast_ref::<Core>().is_some_and(core_input)
}

fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) if !e.use_stderr() => e.exit(), // --help, --version
        Err(e) => {
            // Usage errors on one line too: drop the usage and help hints.
            let text = e.to_string();
            let msg: Vec<&str> = text
                .lines()
                .map(str::trim)
                .filter(|l| !l.is_empty() && !l.starts_with("Usage:") && !l.starts_with("For more"))
                .collect();
            let msg = msg.join(" ");
            eprintln!("error: {}", msg.trim_start_matches("error: "));
            return ExitCode::from(2);
        }
    };
    let limit = cli.max_voxels.unwrap_or(volume::MAX_VOXELS);
    match volume::with_voxel_limit(limit, || run(cli)) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            // One line, whatever the error's text holds.
            let msg = e.to_string().replace('\n', " ");
            eprintln!("error: {msg}");
            if is_bad_input(&*e) {
                ExitCode::from(2)
            } else {
                ExitCode::FAILURE
            }
        }
    }
}
