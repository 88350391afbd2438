//! `shearwarp-view`: interactive desktop preview (minifb window) with progressive
//! refinement, presets, window/level, screenshots, and a scripted headless mode.

use clap::Parser;
use minifb::{Key, KeyRepeat, MouseButton, MouseMode, Window, WindowOptions};
use shearwarp_core::shade::Lighting;
use shearwarp_file::tfspec;
use shearwarp_file::volume::{self, Voxels};
use shearwarp_view::engine::{self, Done, Job, Outcome, Quality, Scene, Settings};
use shearwarp_view::preset::{self, PRESETS};
use shearwarp_view::script::{self, Player, Tick};
use shearwarp_view::state::{self, Button, Input, Request, ViewKey, ViewState, KEYS};
use std::collections::VecDeque;
use std::error::Error;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, Sender};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Input frames per second (the window's event polling rate).
const INPUT_FPS: u32 = 60;

#[derive(Parser)]
#[command(
    name = "shearwarp-view",
    version,
    about = "Interactive shear-warp volume preview with progressive refinement"
)]
struct Cli {
    /// Volume: a raw file (`.raw` or `.raw.gz`) or its JSON sidecar.
    volume: PathBuf,
    /// Window size WxH.
    #[arg(long, default_value = "512x512")]
    size: String,
    /// Start rotation about X in degrees (applied after Y); -90 shows the face of the
    /// shared LPS data sets.
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    rotate_x: f64,
    /// Start rotation about Y in degrees.
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    rotate_y: f64,
    /// Start preset, 1..=5 (MR default, MR brain, CT bone, CT skin, MIP).
    #[arg(long, default_value_t = 1)]
    preset: usize,
    /// Start with shading off.
    #[arg(long)]
    no_shading: bool,
    /// Compositing threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// Prefer the 16-bit file when the sidecar lists one.
    #[arg(long)]
    u16: bool,
    /// Voxels with opacity at or below this are skipped as transparent.
    #[arg(long, default_value_t = 0.02)]
    min_opacity: f64,
    /// Early ray termination opacity (1 disables it).
    #[arg(long, default_value_t = 0.95)]
    ert: f64,
    /// Start in perspective projection (the O key toggles it).
    #[arg(long)]
    perspective: bool,
    /// Field of view of perspective frames, degrees (1..=150).
    #[arg(long, default_value_t = 30.0)]
    fov: f64,
    /// Milliseconds without input before refining to full quality.
    #[arg(long, default_value_t = 150)]
    refine_after_ms: u64,
    /// Replay the inputs of this script (format: see the README), then settle.
    #[arg(long)]
    script: Option<PathBuf>,
    /// Write the final full-quality frame to this PNG and exit.
    #[arg(long)]
    dump: Option<PathBuf>,
    /// After --dump, keep the window open this many milliseconds (for screenshots).
    #[arg(long, default_value_t = 0)]
    hold_ms: u64,
    /// Run without a window (needs --script or --dump): same inputs, same frames.
    #[arg(long)]
    no_window: bool,
    /// Screenshots go to PREFIX-NNN.png, saved transfer functions to PREFIX-tf-NNN.json.
    #[arg(long, default_value = "shearwarp-view")]
    shot_prefix: String,
}

fn main() -> ExitCode {
    match run(Cli::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}

/// The frame on screen.
struct Shown {
    pixels: Vec<[u8; 4]>,
    job: Job,
    render_ms: f64,
    encode_ms: f64,
    /// Shadows were rendered.
    shadows: bool,
    /// Why the core left shadows out, if it did.
    note: Option<String>,
}

/// Timings for the summary.
#[derive(Default)]
struct Stats {
    preview_ms: Vec<f64>,
    preview_encode_ms: Vec<f64>,
    full_ms: Vec<f64>,
    full_encode_ms: Vec<f64>,
    cancelled: usize,
    /// When preview frames reached the screen.
    preview_shown: Vec<Instant>,
}

fn median_p90_max(v: &[f64]) -> String {
    if v.is_empty() {
        return "none".into();
    }
    if v.len() <= 4 {
        let all: Vec<String> = v.iter().map(|x| format!("{x:.1}")).collect();
        return format!("{} ms", all.join(", "));
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let p90 = s[((s.len() as f64 * 0.9).ceil() as usize).clamp(1, s.len()) - 1];
    format!(
        "median {:.1} ms, p90 {:.1} ms, max {:.1} ms",
        s[s.len() / 2],
        p90,
        s[s.len() - 1]
    )
}

impl Stats {
    /// Frames shown per second during bursts of preview frames (gaps over 250 ms
    /// split bursts): the frame rate while the user drags.
    fn drag_fps(&self) -> Option<(usize, f64, f64)> {
        let mut frames = 0;
        let mut secs = 0.0;
        let mut start = 0;
        let t = &self.preview_shown;
        for i in 1..=t.len() {
            let end = i == t.len() || t[i].duration_since(t[i - 1]) > Duration::from_millis(250);
            if end {
                if i - start >= 2 {
                    frames += i - start - 1;
                    secs += t[i - 1].duration_since(t[start]).as_secs_f64();
                }
                start = i;
            }
        }
        (secs > 0.0).then(|| (frames, secs, frames as f64 / secs))
    }

    fn print(&self) {
        println!(
            "summary: preview frames {} (render {}); preview re-encodes {} ({})",
            self.preview_ms.len(),
            median_p90_max(&self.preview_ms),
            self.preview_encode_ms.len(),
            median_p90_max(&self.preview_encode_ms)
        );
        println!(
            "summary: full frames {} (render {}); interrupted {}; full re-encodes {} ({})",
            self.full_ms.len(),
            median_p90_max(&self.full_ms),
            self.cancelled,
            self.full_encode_ms.len(),
            median_p90_max(&self.full_encode_ms)
        );
        match self.drag_fps() {
            Some((n, s, fps)) => {
                println!("summary: while dragging {n} frames in {s:.2} s = {fps:.1} fps shown")
            }
            None => println!("summary: no dragging"),
        }
    }
}

/// The application: view state, the render thread, and what is on screen.
struct App {
    volume: PathBuf,
    name: String,
    u16: bool,
    range: (u16, u16),
    /// The full volume's voxels (the C key's crop boxes are of these).
    dims: [usize; 3],
    size: [usize; 2],
    min_opacity: f64,
    ert: f64,
    /// Field of view of perspective frames, degrees.
    fov: f64,
    lighting: Lighting,
    threads: usize,
    refine_after: Duration,
    view: ViewState,
    home: ViewState,
    generation: u64,
    latest: Arc<AtomicU64>,
    jobs: Sender<Job>,
    done: Receiver<Done>,
    last_input: Instant,
    full_requested: bool,
    shown: Option<Shown>,
    fresh: bool,
    shown_at: VecDeque<Instant>,
    stats: Stats,
    shots: usize,
    tfs: usize,
    shot_prefix: String,
    /// The last note printed (printed again only when it changes).
    last_note: Option<String>,
}

/// What the loop should do after a tick.
#[derive(PartialEq, Eq)]
enum Flow {
    Go,
    Quit,
}

impl App {
    fn request(&mut self, quality: Quality) {
        let job = Job {
            generation: self.generation,
            quality,
            view: self.view,
        };
        // A closed channel means the render thread is gone; the loop notices when no
        // frame arrives, and the error is reported there.
        let _ = self.jobs.send(job);
    }

    /// Applies inputs; sends a preview request if the view changed, a full-quality one
    /// once input has stopped.
    fn tick(&mut self, inputs: &[Input], now: Instant) -> Result<Flow, Box<dyn Error>> {
        let before = self.view;
        for &input in inputs {
            match state::apply(&mut self.view, &self.home, input, self.size) {
                Request::None if input == Input::Key(ViewKey::Shadows) => {
                    let v = &self.view;
                    if v.shadows && (!v.shading || v.is_mip()) {
                        println!(
                            "shadows need shading and compositing (press L, or M for MIP off)"
                        );
                    }
                }
                Request::None => {}
                Request::Quit => return Ok(Flow::Quit),
                Request::Help => print_keys(),
                Request::Print => self.print_view(),
                Request::Screenshot => self.screenshot()?,
                Request::SaveTf => self.save_tf(),
            }
        }
        if self.view != before {
            self.generation += 1;
            self.latest.store(self.generation, Ordering::Relaxed);
            self.last_input = now;
            self.full_requested = false;
            self.request(Quality::Preview);
        } else if !self.full_requested && now.duration_since(self.last_input) >= self.refine_after {
            self.full_requested = true;
            self.request(Quality::Full);
        }
        while let Ok(d) = self.done.try_recv() {
            self.receive(d, now);
        }
        Ok(Flow::Go)
    }

    fn receive(&mut self, d: Done, now: Instant) {
        match d.outcome {
            Outcome::Frame {
                pixels,
                render_ms,
                encode_ms,
                shadows,
                note,
            } => {
                match d.job.quality {
                    Quality::Preview => {
                        self.stats.preview_ms.push(render_ms);
                        if encode_ms > 0.0 {
                            self.stats.preview_encode_ms.push(encode_ms);
                        }
                    }
                    Quality::Full => {
                        self.stats.full_ms.push(render_ms);
                        if encode_ms > 0.0 {
                            self.stats.full_encode_ms.push(encode_ms);
                        }
                    }
                }
                // Never replace a newer frame, nor a full frame by a preview of the
                // same view.
                if let Some(s) = &self.shown {
                    let older = d.job.generation < s.job.generation;
                    let worse = d.job.generation == s.job.generation
                        && s.job.quality == Quality::Full
                        && d.job.quality == Quality::Preview;
                    if older || worse {
                        return;
                    }
                }
                if d.job.quality == Quality::Preview {
                    self.stats.preview_shown.push(now);
                }
                self.shown_at.push_back(now);
                if note.is_some() && note != self.last_note {
                    println!("{}", note.as_deref().unwrap_or_default());
                }
                self.last_note.clone_from(&note);
                self.shown = Some(Shown {
                    pixels,
                    job: d.job,
                    render_ms,
                    encode_ms,
                    shadows,
                    note,
                });
                self.fresh = true;
            }
            Outcome::Cancelled => self.stats.cancelled += 1,
            Outcome::Failed(e) => {
                eprintln!("render failed: {e}");
                if d.job.quality == Quality::Full && d.job.generation == self.generation {
                    // Do not retry the same failing request every frame.
                    self.full_requested = true;
                }
            }
        }
    }

    /// True once the full-quality frame of the current view is on screen.
    fn settled(&self) -> bool {
        self.shown
            .as_ref()
            .is_some_and(|s| s.job.generation == self.generation && s.job.quality == Quality::Full)
    }

    fn title(&mut self, now: Instant) -> String {
        while self
            .shown_at
            .front()
            .is_some_and(|&t| now.duration_since(t) > Duration::from_secs(1))
        {
            self.shown_at.pop_front();
        }
        // ASCII only: X11 window managers may read the title as Latin-1.
        let v = &self.view;
        let p = &PRESETS[v.preset];
        let (lo, hi) = v.wl.raw_bounds(self.range);
        let mut t = match &self.shown {
            Some(s) => {
                let mut q = format!("{} {:.1} ms", s.job.quality.name(), s.render_ms);
                if s.encode_ms > 0.0 {
                    q += &format!(" (+{:.0} ms encode)", s.encode_ms);
                }
                q
            }
            None => "loading".to_string(),
        };
        // Frames shown in the last second, while previews are coming.
        if self
            .shown
            .as_ref()
            .is_some_and(|s| s.job.quality == Quality::Preview)
            && now.duration_since(self.last_input) < Duration::from_secs(1)
        {
            t += &format!(" | {} fps", self.shown_at.len());
        }
        let mip = v.is_mip();
        t += &format!(
            " | {}{} W {:.0} L {:.0}",
            p.name,
            if v.mip && !p.mip { " (MIP)" } else { "" },
            hi - lo,
            0.5 * (lo + hi)
        );
        if v.shading && !mip {
            t += " | shading";
        }
        if v.perspective {
            t += &format!(" | perspective {}°", self.fov);
        }
        if v.depth_cue && !mip {
            t += if v.perspective {
                " | no fog in perspective"
            } else {
                " | fog"
            };
        }
        if v.shadows && v.shading && !mip && v.perspective {
            t += " | no shadows in perspective";
        } else if v.shadows && v.shading && !mip {
            t += match &self.shown {
                Some(s) if s.note.is_some() => " | no shadows for this view",
                _ => " | shadows",
            };
        }
        if let Some(cut) = v.cut.describe() {
            t += &format!(" | cut: {cut}");
        }
        if v.zoom != 1.0 || v.pan != [0.0; 2] {
            t += &format!(" | zoom {:.2}", v.zoom);
        }
        t += &format!(" | {} - shearwarp-view", self.name);
        t
    }

    /// Arguments of `shearwarp render` (without `-o`) for the current view, shell-quoted.
    fn cli_args(&self, view: &ViewState, shadows: bool) -> String {
        let p = &PRESETS[view.preset];
        let opacity = preset::opacity_points(p, view.wl, self.range);
        let color = preset::color_points(p, self.range);
        let mut a = vec![
            quote(&self.volume.to_string_lossy()),
            format!("--size {}x{}", self.size[0], self.size[1]),
            format!("--rotate-x={}", view.rotate_x),
            format!("--rotate-y={}", view.rotate_y),
            format!("--opacity {}", quote(&preset::opacity_spec(&opacity))),
            format!("--color {}", quote(&preset::color_spec(&color))),
            format!("--min-opacity {}", self.min_opacity),
            format!("--ert {}", self.ert),
            format!("--threads {}", self.threads),
        ];
        if view.is_mip() {
            a.push("--mode mip".into());
        } else if view.shading {
            let l = &self.lighting;
            a.push(format!(
                "--shading --ka {} --kd {} --ks {} --shininess {}",
                l.ka, l.kd, l.ks, l.shininess
            ));
            for light in l.lights.iter() {
                let d = light.direction;
                a.push(format!("--light={},{},{}", d[0], d[1], d[2]));
            }
        }
        if shadows {
            a.push("--shadows".into());
        }
        if view.perspective {
            a.push(format!("--projection perspective --fov {}", self.fov));
        }
        if view.depth_cue && !view.is_mip() && !view.perspective {
            let c = state::DEPTH_CUE;
            a.push(format!("--depth-cue {}:{}", c.front, c.density));
        }
        if let Some(spec) = view.cut.spec(self.dims) {
            a.push(spec);
        }
        if self.u16 {
            a.push("--u16".into());
        }
        a.join(" ")
    }

    fn print_cli(&self, view: &ViewState, shadows: bool) {
        if view.zoom != 1.0 || view.pan != [0.0; 2] {
            println!(
                "note: the file frontend has no zoom/pan; the command renders the whole volume"
            );
        }
        println!("cli-args: {}", self.cli_args(view, shadows));
    }

    fn print_view(&self) {
        let v = &self.view;
        let (lo, hi) = v.wl.raw_bounds(self.range);
        println!(
            "view: rotate-x {} rotate-y {} zoom {:.3} pan {:.1},{:.1} preset '{}' window {:.1} \
             level {:.1} (raw) shading {} mip {} depth cue {}",
            v.rotate_x,
            v.rotate_y,
            v.zoom,
            v.pan[0],
            v.pan[1],
            PRESETS[v.preset].name,
            hi - lo,
            0.5 * (lo + hi),
            v.shading,
            v.is_mip(),
            v.depth_cue
        );
        let shadows = match &self.shown {
            Some(s) if s.job.view == *v => s.shadows,
            _ => v.shadows && v.shading && !v.is_mip() && !v.perspective,
        };
        self.print_cli(v, shadows);
    }

    /// Writes the frame on screen to `path` (through a temporary file in the same
    /// directory, so a watcher never sees a half-written PNG).
    fn save(&self, path: &Path) -> Result<(), Box<dyn Error>> {
        let s = self.shown.as_ref().ok_or("no frame to save yet")?;
        let name = path
            .file_name()
            .ok_or_else(|| format!("{}: not a file name", path.display()))?;
        let tmp = path.with_file_name(format!(".{}.partial.png", name.to_string_lossy()));
        shearwarp_file::png::save_png(&tmp, self.size[0], self.size[1], &s.pixels)
            .map_err(|e| format!("cannot write {}: {e}", tmp.display()))?;
        std::fs::rename(&tmp, path)
            .map_err(|e| format!("cannot rename {} to {}: {e}", tmp.display(), path.display()))?;
        println!(
            "wrote {} ({}, {}x{})",
            path.display(),
            s.job.quality.name(),
            self.size[0],
            self.size[1]
        );
        self.print_cli(&s.job.view, s.shadows);
        Ok(())
    }

    fn screenshot(&mut self) -> Result<(), Box<dyn Error>> {
        self.shots += 1;
        let path = PathBuf::from(format!("{}-{:03}.png", self.shot_prefix, self.shots));
        if let Err(e) = self.save(&path) {
            // A failed screenshot is reported, not fatal.
            eprintln!("screenshot: {e}");
        }
        Ok(())
    }
}

impl App {
    /// Writes the transfer function on screen (the preset's ramp under the current
    /// window/level, its colours, MIP and shading) to `PREFIX-tf-NNN.json` in raw units,
    /// for `shearwarp render --tf`. A failure is reported, not fatal.
    fn save_tf(&mut self) {
        self.tfs += 1;
        let path = PathBuf::from(format!("{}-tf-{:03}.json", self.shot_prefix, self.tfs));
        let v = &self.view;
        let spec = preset::tf_spec(&PRESETS[v.preset], v.wl, self.range, v.is_mip(), v.shading);
        match spec.save(&path) {
            Ok(()) => {
                println!("wrote {}", path.display());
                let shadows = v.shadows && v.shading && !v.is_mip() && !v.perspective;
                self.print_cli(v, shadows);
            }
            Err(e) => eprintln!(
                "save transfer function: cannot write {}: {e}",
                path.display()
            ),
        }
    }
}

/// Single-quotes `s` for a POSIX shell when it needs it.
fn quote(s: &str) -> String {
    if !s.is_empty()
        && s.chars()
            .all(|c| c.is_ascii_alphanumeric() || "-_./:,=+#".contains(c))
    {
        s.to_string()
    } else {
        format!("'{}'", s.replace('\'', r"'\''"))
    }
}

fn print_keys() {
    println!("shearwarp-view controls:");
    println!("  left-drag: rotate (horizontal: about Y, vertical: about X)");
    println!(
        "  right-drag: window/level of the opacity ramp (horizontal: window, vertical: level)"
    );
    println!("  middle-drag or Shift+left-drag: pan; wheel: zoom about the pointer");
    for (_, help, _) in KEYS.iter().filter(|k| !k.1.is_empty()) {
        println!("  {help}");
    }
}

/// Reads the window's mouse and keyboard into inputs.
struct WindowInput {
    last: Option<(f32, f32)>,
}

impl WindowInput {
    fn poll(&mut self, w: &Window) -> Vec<Input> {
        let mut out = Vec::new();
        let pos = w.get_mouse_pos(MouseMode::Pass);
        let shift = w.is_key_down(Key::LeftShift) || w.is_key_down(Key::RightShift);
        let left = w.get_mouse_down(MouseButton::Left);
        let right = w.get_mouse_down(MouseButton::Right);
        let middle = w.get_mouse_down(MouseButton::Middle);
        if let (Some(p), Some(l)) = (pos, self.last) {
            let (dx, dy) = ((p.0 - l.0) as f64, (p.1 - l.1) as f64);
            if dx != 0.0 || dy != 0.0 {
                let button = if middle || (left && shift) {
                    Some(Button::Middle)
                } else if left {
                    Some(Button::Left)
                } else if right {
                    Some(Button::Right)
                } else {
                    None
                };
                if let Some(button) = button {
                    out.push(Input::Drag { button, dx, dy });
                }
            }
        }
        self.last = pos;
        if let Some((_, sy)) = w.get_scroll_wheel() {
            if sy != 0.0 {
                out.push(Input::Wheel {
                    notches: (sy as f64).clamp(-10.0, 10.0),
                    at: pos.map(|p| [p.0 as f64, p.1 as f64]),
                });
            }
        }
        for k in w.get_keys_pressed(KeyRepeat::Yes) {
            if let Some(vk) = map_key(k, shift) {
                out.push(Input::Key(vk));
            }
        }
        out
    }
}

fn map_key(k: Key, shift: bool) -> Option<ViewKey> {
    Some(match k {
        Key::Left => ViewKey::RotateLeft,
        Key::Right => ViewKey::RotateRight,
        Key::Up => ViewKey::RotateUp,
        Key::Down => ViewKey::RotateDown,
        Key::Equal | Key::NumPadPlus | Key::PageUp => ViewKey::ZoomIn,
        Key::Minus | Key::NumPadMinus | Key::PageDown => ViewKey::ZoomOut,
        Key::R => ViewKey::ResetView,
        Key::Tab if shift => ViewKey::PrevPreset,
        Key::Tab => ViewKey::NextPreset,
        Key::Key1 | Key::NumPad1 => ViewKey::Preset(0),
        Key::Key2 | Key::NumPad2 => ViewKey::Preset(1),
        Key::Key3 | Key::NumPad3 => ViewKey::Preset(2),
        Key::Key4 | Key::NumPad4 => ViewKey::Preset(3),
        Key::Key5 | Key::NumPad5 => ViewKey::Preset(4),
        Key::LeftBracket => ViewKey::WindowNarrower,
        Key::RightBracket => ViewKey::WindowWider,
        Key::Comma => ViewKey::LevelDown,
        Key::Period => ViewKey::LevelUp,
        Key::Key0 | Key::NumPad0 => ViewKey::ResetWindowLevel,
        Key::L => ViewKey::Shading,
        Key::M => ViewKey::Mip,
        Key::W => ViewKey::Shadows,
        Key::D => ViewKey::DepthCue,
        Key::O => ViewKey::Perspective,
        Key::C => ViewKey::Cut,
        Key::F => ViewKey::CutMore,
        Key::B => ViewKey::CutLess,
        Key::S => ViewKey::Screenshot,
        Key::T => ViewKey::SaveTf,
        Key::P => ViewKey::Print,
        Key::H | Key::F1 => ViewKey::Help,
        Key::Q | Key::Escape => ViewKey::Quit,
        _ => return None,
    })
}

fn to_argb(px: &[[u8; 4]], out: &mut Vec<u32>) {
    out.clear();
    out.extend(
        px.iter()
            .map(|p| ((p[0] as u32) << 16) | ((p[1] as u32) << 8) | p[2] as u32),
    );
}

/// Where inputs come from.
enum Source {
    Window(WindowInput),
    Script(Player),
    /// `--dump` without a script: no inputs.
    Nothing,
}

fn run(cli: Cli) -> Result<(), Box<dyn Error>> {
    let (width, height) = tfspec::parse_size(&cli.size)?;
    if !(1..=PRESETS.len()).contains(&cli.preset) {
        return Err(format!("--preset must be 1..={}", PRESETS.len()).into());
    }
    if cli.no_window && cli.script.is_none() && cli.dump.is_none() {
        return Err("--no-window needs --script or --dump".into());
    }
    if !(0.0..1.0).contains(&cli.min_opacity) {
        return Err("--min-opacity must be in [0, 1)".into());
    }
    if !(cli.ert > 0.0 && cli.ert <= 1.0) {
        return Err("--ert must be in (0, 1]".into());
    }
    if !(1.0..=150.0).contains(&cli.fov) {
        return Err("--fov must be in 1..=150 degrees".into());
    }
    let threads = cli
        .threads
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    if threads == 0 || threads > 256 {
        return Err("--threads must be 1..=256".into());
    }
    let player = match &cli.script {
        Some(p) => {
            let text = std::fs::read_to_string(p)
                .map_err(|e| format!("cannot read {}: {e}", p.display()))?;
            Some(Player::new(script::parse(&text)?))
        }
        None => None,
    };

    let t0 = Instant::now();
    let prefer = if cli.u16 {
        volume::Prefer::U16
    } else {
        volume::Prefer::U8
    };
    let raw = volume::load_volume_with(&cli.volume, prefer)?;
    let u16_data = matches!(raw.voxels, Voxels::U16(_));
    let name = raw.name.clone();
    let dims = raw.dims;
    let lighting = Lighting::default();
    let scene = Scene::new(
        raw,
        Settings {
            size: [width, height],
            threads,
            min_opacity: cli.min_opacity,
            ert: cli.ert,
            lighting: lighting.clone(),
            fov: cli.fov,
        },
    )?;
    let range = scene.range;
    let half_dims = scene.preview.dims;
    println!(
        "{name}: {}x{}x{} {}, range {}..{}; preview level {}x{}x{}; loaded in {:.0} ms; {} threads",
        dims[0],
        dims[1],
        dims[2],
        if u16_data { "u16" } else { "u8" },
        range.0,
        range.1,
        half_dims[0],
        half_dims[1],
        half_dims[2],
        t0.elapsed().as_secs_f64() * 1e3,
        threads
    );
    print_keys();

    let latest = Arc::new(AtomicU64::new(0));
    let (jobs, done, render_thread) = engine::spawn(scene, Arc::clone(&latest));
    let home = ViewState {
        perspective: cli.perspective,
        ..ViewState::new(cli.rotate_x, cli.rotate_y, cli.preset - 1, !cli.no_shading)
    };
    let now = Instant::now();
    let mut app = App {
        volume: cli.volume.clone(),
        name,
        u16: cli.u16 && u16_data,
        range,
        dims,
        size: [width, height],
        min_opacity: cli.min_opacity,
        ert: cli.ert,
        fov: cli.fov,
        lighting,
        threads,
        refine_after: Duration::from_millis(cli.refine_after_ms),
        view: home,
        home,
        generation: 0,
        latest,
        jobs,
        done,
        last_input: now,
        full_requested: false,
        shown: None,
        fresh: false,
        shown_at: VecDeque::new(),
        stats: Stats::default(),
        shots: 0,
        tfs: 0,
        shot_prefix: cli.shot_prefix.clone(),
        last_note: None,
    };
    // A quick first picture, then refinement.
    app.request(Quality::Preview);

    let mut window = if cli.no_window {
        None
    } else {
        let mut w = Window::new("shearwarp-view", width, height, WindowOptions::default())
            .map_err(|e| {
                format!(
                    "cannot open a window ({e}); without a display use xvfb-run, or \
                     --no-window with --script/--dump"
                )
            })?;
        w.set_target_fps(INPUT_FPS as usize);
        Some(w)
    };
    let mut source = match (player, &window) {
        (Some(p), _) => Source::Script(p),
        (None, Some(_)) if cli.dump.is_none() => Source::Window(WindowInput { last: None }),
        _ => Source::Nothing,
    };

    let frame_period = Duration::from_secs_f64(1.0 / INPUT_FPS as f64);
    let mut next_tick = Instant::now();
    let mut buffer: Vec<u32> = Vec::with_capacity(width * height);
    let mut last_title = String::new();
    // Ticks until the next redraw of an unchanged frame.
    let mut redraw_in: u32 = 0;
    let mut hold_until: Option<Instant> = None;
    let settle_deadline = Duration::from_secs(120);
    let mut settle_started: Option<Instant> = None;
    loop {
        let now = Instant::now();
        if let Some(w) = &window {
            if !w.is_open() {
                break;
            }
        }
        if let Some(h) = hold_until {
            if now >= h {
                break;
            }
        }
        let inputs = match &mut source {
            Source::Window(wi) => window.as_ref().map(|w| wi.poll(w)).unwrap_or_default(),
            Source::Script(p) => match p.tick(now, app.settled()) {
                Tick::Inputs(v) => v,
                Tick::Wait => Vec::new(),
                Tick::Done => {
                    source = Source::Nothing;
                    Vec::new()
                }
            },
            Source::Nothing => Vec::new(),
        };
        if app.tick(&inputs, now)? == Flow::Quit {
            break;
        }
        // Scripted or dump runs end once the final view is refined.
        if matches!(source, Source::Nothing) && hold_until.is_none() {
            let started = *settle_started.get_or_insert(now);
            if app.settled() {
                if let Some(path) = &cli.dump {
                    app.save(path)?;
                }
                if cli.hold_ms > 0 && window.is_some() {
                    hold_until = Some(now + Duration::from_millis(cli.hold_ms));
                } else {
                    hold_until = Some(now);
                }
            } else if now.duration_since(started) > settle_deadline {
                return Err("the final frame did not arrive within 120 s".into());
            }
        }
        if let Some(w) = &mut window {
            let title = app.title(now);
            if title != last_title {
                w.set_title(&title);
                last_title = title;
            }
            // Redraw on a new frame, and now and then to survive expose events.
            if app.fresh || redraw_in == 0 {
                redraw_in = 15;
                match &app.shown {
                    Some(s) => {
                        to_argb(&s.pixels, &mut buffer);
                        w.update_with_buffer(&buffer, width, height)?;
                    }
                    None => w.update(),
                }
                app.fresh = false;
            } else {
                w.update();
            }
        } else {
            app.fresh = false;
            next_tick += frame_period;
            let now = Instant::now();
            if next_tick > now {
                std::thread::sleep(next_tick - now);
            } else {
                next_tick = now;
            }
        }
        redraw_in = redraw_in.saturating_sub(1);
        if render_thread.is_finished() {
            return Err("the render thread stopped".into());
        }
    }
    app.stats.print();
    Ok(())
}
