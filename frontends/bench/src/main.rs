//! `shearwarp-bench`: shearwarp against VolPack (Lacroute's C shear-warp) on the same
//! scenes, views, transfer functions and light, with PSNR of both against the reference
//! ray caster, a scaling series and a plot. See BENCHMARKS.md at the repository root.

mod bench;
mod ceiling;
mod den;
mod font;
mod plot;
mod report;
mod scenes;
mod synth;
mod volpack;

use bench::{Options, SceneResult};
use clap::Parser;
use shearwarp_file::isa::Isa;
use shearwarp_file::scene::FlatVoxelsArg;
use std::error::Error;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "shearwarp-bench",
    about = "Benchmark shearwarp against VolPack, with PSNR against the reference ray caster"
)]
struct Cli {
    /// Timed frames per scene and image size, 360/N degrees apart about the vertical axis.
    #[arg(long, default_value_t = 36)]
    frames: usize,
    /// Passes over the frames; each view's time is the best of its passes (which filters
    /// out preemption by other processes), and the median over the views is reported.
    #[arg(long, default_value_t = 3)]
    rounds: usize,
    /// Square image sides, comma separated.
    #[arg(long, default_value = "256,512", value_delimiter = ',')]
    sizes: Vec<usize>,
    /// Only these scenes (brainsmall, mr_head_colin27, mr_brain_colin27_hires, spheres256).
    #[arg(long, value_delimiter = ',')]
    scenes: Option<Vec<String>>,
    /// Sides of the nested-spheres scaling series, comma separated.
    #[arg(long, default_value = scenes::SCALING_SIDES, value_delimiter = ',')]
    scaling: Vec<usize>,
    /// Skip the scaling series.
    #[arg(long)]
    no_scaling: bool,
    /// Thread count of the threaded shearwarp runs (0 skips them).
    #[arg(long, default_value_t = 2)]
    threads: usize,
    /// Preprocessing repetitions (median reported).
    #[arg(long, default_value_t = 3)]
    prep_runs: usize,
    /// Skip the reference renders and PSNR.
    #[arg(long)]
    no_psnr: bool,
    /// Run the shearwarp side only.
    #[arg(long)]
    no_volpack: bool,
    /// The shared data directory (default: ../shared/data beside the repository, or
    /// $SHEARWARP_DATA).
    #[arg(long)]
    data: Option<PathBuf>,
    /// VolPack's brainsmall.den.
    #[arg(long, default_value = scenes::BRAINSMALL_DEFAULT)]
    den: PathBuf,
    /// Update the generated block of this markdown file (e.g. BENCHMARKS.md).
    #[arg(long)]
    markdown: Option<PathBuf>,
    /// Write the scaling plot PNG here (e.g. docs/bench-scaling.png).
    #[arg(long)]
    plot: Option<PathBuf>,
    /// Write review images (shearwarp | VolPack | reference) to this directory.
    #[arg(long)]
    images: Option<PathBuf>,
    /// Compare against the reference at this view "rotate_x,rotate_y" (degrees) instead
    /// of each scene's default (25, 35).
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true, num_args = 1)]
    view: Option<Vec<f64>>,
    /// Before measuring, wait up to this many seconds for the 1-minute load average to
    /// drop below 0.5 (other processes on the machine distort timings, threaded ones most).
    #[arg(long, default_value_t = 0)]
    wait_idle: u64,
    /// Cache of reference images (default: target/bench-cache in the repository).
    #[arg(long)]
    cache: Option<PathBuf>,
    /// Instruction-set build of shearwarp's compositing loop: baseline, x86-64-v3 or
    /// x86-64-v4 (default: the highest this CPU runs; a level it lacks runs the highest
    /// one below).
    #[arg(long)]
    isa: Option<Isa>,
    /// Do not also time the baseline build when a wider one is in use.
    #[arg(long)]
    no_baseline: bool,
    /// Intermediate pixels per voxel side of the supersampled runs (2..=4; 1 skips
    /// them), at the image sizes at least twice the volume's largest side.
    #[arg(long, default_value_t = 2)]
    supersample: usize,
    /// How shearwarp's samples take voxels with a zero gradient into their colour:
    /// blended like the others, or excluded where voxels with a direction are present
    /// (`shearwarp_core::composite::FlatVoxels`); auto, the default as in the CLI,
    /// excludes them in volumes where at least one in 16 visible voxels is flat.
    #[arg(long, value_enum, default_value_t = FlatVoxelsArg::Auto)]
    flat_voxels: FlatVoxelsArg,
    /// Render the training scenes (volumes the benchmark does not time) with shearwarp
    /// alone, every way the benchmark renders, and exit: the training run of a
    /// profile-guided build (`frontends/bench/pgo.sh`).
    #[arg(long)]
    train: bool,
}

/// What a profile-guided build of this binary was trained on, set at compile time by
/// `frontends/bench/pgo.sh`; `None` for a plain `cargo build`.
const PGO: Option<&str> = option_env!("SHEARWARP_BENCH_PGO");

fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn data_dir(cli: &Cli) -> PathBuf {
    if let Some(d) = &cli.data {
        return d.clone();
    }
    if let Some(d) = std::env::var_os("SHEARWARP_DATA") {
        return PathBuf::from(d);
    }
    repo_root().join("../shared/data")
}

fn run_output(cmd: &str, args: &[&str]) -> Option<String> {
    let out = std::process::Command::new(cmd).args(args).output().ok()?;
    out.status
        .success()
        .then(|| String::from_utf8_lossy(&out.stdout).trim().to_string())
}

/// This process's nice value (field 19 of /proc/self/stat), if it can be read.
fn niceness() -> Option<i32> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the parenthesised command name, which may contain spaces.
    let rest = &stat[stat.rfind(')')? + 1..];
    rest.split_whitespace().nth(16)?.parse().ok()
}

fn load1() -> Option<f64> {
    std::fs::read_to_string("/proc/loadavg")
        .ok()?
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

/// Waits up to `secs` for the 1-minute load average to fall below 0.5; returns whether
/// it did.
fn wait_idle(secs: u64) -> bool {
    let start = std::time::Instant::now();
    loop {
        match load1() {
            Some(l) if l < 0.5 => return true,
            None => return false,
            Some(l) => {
                if start.elapsed().as_secs() >= secs {
                    eprintln!("load average still {l:.2} after {secs} s; measuring anyway");
                    return false;
                }
                eprintln!("waiting for the machine to go idle (load average {l:.2})");
                std::thread::sleep(std::time::Duration::from_secs(10));
            }
        }
    }
}

fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .ok()
        .and_then(|s| {
            let v: Vec<&str> = s.split_whitespace().take(3).collect();
            (v.len() == 3).then(|| v.join(" "))
        })
        .unwrap_or_else(|| "unknown".into())
}

/// The machine's CPU time so far from `/proc/stat` (Linux): `(stolen, total)` in clock
/// ticks over all CPUs, where stolen is what the hypervisor gave to other guests while
/// this one had work to run.
fn cpu_ticks() -> Option<(u64, u64)> {
    let stat = std::fs::read_to_string("/proc/stat").ok()?;
    let line = stat.lines().find(|l| l.starts_with("cpu "))?;
    let v: Vec<u64> = line
        .split_whitespace()
        .skip(1)
        .map(|x| x.parse().ok())
        .collect::<Option<_>>()?;
    // user nice system idle iowait irq softirq steal [guest guest_nice], the guest
    // times being counted in user and nice already.
    let stolen = *v.get(7)?;
    Some((stolen, v.iter().take(8).sum()))
}

/// The share of the CPU time between two [`cpu_ticks`] readings that the hypervisor
/// stole, as a sentence.
fn stolen(before: Option<(u64, u64)>, after: Option<(u64, u64)>) -> String {
    match (before, after) {
        (Some((s0, t0)), Some((s1, t1))) if t1 > t0 => format!(
            "the hypervisor stole {:.1} % of the CPU time during the run (steal time in /proc/stat)",
            100.0 * s1.saturating_sub(s0) as f64 / (t1 - t0) as f64
        ),
        _ => "steal time unknown (no /proc/stat)".into(),
    }
}

/// The machine, as markdown bullet points.
fn machine() -> String {
    let mut out = String::new();
    if let Some(l) = run_output("lscpu", &[]) {
        let want = [
            "Architecture",
            "Model name",
            "CPU(s)",
            "Thread(s) per core",
            "Core(s) per socket",
            "L1d cache",
            "L2 cache",
            "L3 cache",
            "Hypervisor vendor",
        ];
        let fields: Vec<String> = l
            .lines()
            .filter_map(|line| {
                let (k, v) = line.split_once(':')?;
                want.contains(&k.trim())
                    .then(|| format!("{}: {}", k.trim(), v.trim()))
            })
            .collect();
        let _ = writeln!(out, "- CPU (`lscpu`): {}", fields.join("; "));
    }
    let kib = std::fs::read_to_string("/proc/meminfo").ok().and_then(|s| {
        s.lines()
            .next()?
            .split_whitespace()
            .nth(1)?
            .parse::<f64>()
            .ok()
    });
    if let Some(k) = kib {
        let _ = writeln!(out, "- Memory: {:.1} GiB", k / 1048576.0);
    }
    if let Some(k) = run_output("uname", &["-sr"]) {
        let _ = writeln!(out, "- OS: {k}");
    }
    let _ = writeln!(out, "- Rust: {}", env!("BENCH_RUSTC_VERSION"));
    let _ = writeln!(out, "- C compiler (driver): {}", env!("BENCH_CC_VERSION"));
    if volpack::AVAILABLE {
        let v = run_output("dpkg-query", &["-W", "-f", "${Version}", "libvolpack1-dev"])
            .unwrap_or_else(|| "unknown version".into());
        let _ = writeln!(
            out,
            "- VolPack: Debian libvolpack1-dev {v} (static library)"
        );
    } else {
        let _ = writeln!(out, "- VolPack: not built in");
    }
    out
}

fn mb(b: usize) -> String {
    format!("{:.1}", b as f64 / 1048576.0)
}

fn memory_table(results: &[SceneResult]) -> String {
    let mut out = String::from(
        "| scene | voxels | non-transparent (per copy) | flat, of those | flat voxels | shearwarp RLE MB | VolPack RLE MB |\n\
         |---|---:|---:|---:|---|---:|---:|\n",
    );
    for r in results {
        let n: usize = r.dims.iter().product();
        let _ = writeln!(
            out,
            "| {} | {n} | {} ({:.1}%) | {:.2}% | {} | {} | {} |",
            r.name,
            r.sw_visible,
            100.0 * r.sw_visible as f64 / n.max(1) as f64,
            100.0 * r.sw_flat as f64 / r.sw_visible.max(1) as f64,
            r.flat_voxels.name(),
            mb(r.sw_bytes),
            r.vp_bytes.map(mb).unwrap_or_else(|| "–".into())
        );
    }
    out
}

fn plot_series(scaling: &[SceneResult], threads: usize) -> Vec<plot::Series> {
    let mut sizes: Vec<usize> = scaling
        .iter()
        .flat_map(|r| r.sizes.iter().map(|s| s.size))
        .collect();
    sizes.sort_unstable();
    sizes.dedup();
    let mut out = Vec::new();
    let markers = [
        plot::Marker::Circle,
        plot::Marker::Square,
        plot::Marker::Triangle,
    ];
    for (i, &size) in sizes.iter().enumerate() {
        let marker = markers[i % markers.len()];
        let light = i == 0;
        let pts = |f: &dyn Fn(&bench::SizeResult) -> Option<f64>| -> Vec<(f64, f64)> {
            scaling
                .iter()
                .filter_map(|r| {
                    let s = r.sizes.iter().find(|s| s.size == size)?;
                    Some((r.dims[0] as f64, f(s)?))
                })
                .collect()
        };
        let shade = |c: (u8, u8, u8)| {
            if light {
                (c.0 / 2 + 120, c.1 / 2 + 120, c.2 / 2 + 120)
            } else {
                c
            }
        };
        out.push(plot::Series {
            label: format!("shearwarp 1 thread, {size}×{size}"),
            color: shade((20, 70, 200)),
            marker,
            points: pts(&|s| Some(s.sw.median)),
        });
        out.push(plot::Series {
            label: format!("shearwarp 1 thread, SSE2 build, {size}×{size}"),
            color: shade((110, 60, 160)),
            marker,
            points: pts(&|s| s.sw_base.map(|t| t.median)),
        });
        if threads > 1 {
            out.push(plot::Series {
                label: format!("shearwarp {threads} threads, {size}×{size}"),
                color: shade((20, 150, 60)),
                marker,
                points: pts(&|s| s.sw_threads.map(|t| t.median)),
            });
        }
        out.push(plot::Series {
            label: format!("VolPack, {size}×{size}"),
            color: shade((210, 40, 30)),
            marker,
            points: pts(&|s| s.vp.map(|t| t.median)),
        });
    }
    out.retain(|s| !s.points.is_empty());
    out
}

fn run(cli: Cli) -> Result<(), Box<dyn Error>> {
    if cli.frames == 0 || cli.sizes.is_empty() || cli.sizes.iter().any(|&s| s == 0 || s > 8192) {
        return Err("--frames must be positive and --sizes in 1..=8192".into());
    }
    if !(1..=4).contains(&cli.supersample) {
        return Err("--supersample must be in 1..=4".into());
    }
    if !volpack::AVAILABLE {
        eprintln!("{}", volpack::MISSING);
    }
    if cli.wait_idle > 0 {
        wait_idle(cli.wait_idle);
    }
    let load_before = load_average();
    let ticks_before = cpu_ticks();
    let started = run_output("date", &["-u", "+%Y-%m-%d %H:%M UTC"]).unwrap_or_default();
    let cache = cli
        .cache
        .clone()
        .unwrap_or_else(|| repo_root().join("target/bench-cache"));
    let threads = (cli.threads > 1).then_some(cli.threads);
    let opts = Options {
        frames: cli.frames,
        rounds: cli.rounds,
        sizes: cli.sizes.clone(),
        prep_runs: cli.prep_runs,
        threads,
        psnr: !cli.no_psnr,
        cache_dir: cache,
        images_dir: cli.images.clone(),
        no_volpack: cli.no_volpack,
        isa: cli.isa.unwrap_or_else(Isa::detect),
        baseline: !cli.no_baseline,
        supersample: (cli.supersample > 1).then_some(cli.supersample),
        supersample_psnr: !cli.no_psnr,
        flat_voxels: cli.flat_voxels,
    };
    if cli.train {
        let opts = Options {
            no_volpack: true,
            psnr: false,
            supersample_psnr: false,
            images_dir: None,
            ..opts
        };
        for scene in scenes::training_scenes(&data_dir(&cli)) {
            let r = bench::run_scene(&scene, &opts)?;
            println!("trained on {} ({} image sizes)", r.name, r.sizes.len());
        }
        return Ok(());
    }
    let mut list = scenes::main_scenes(&data_dir(&cli), &cli.den);
    if let Some(only) = &cli.scenes {
        for name in only {
            if !list.iter().any(|s| &s.name == name) {
                return Err(format!("unknown scene {name}").into());
            }
        }
        list.retain(|s| only.contains(&s.name));
    }
    if let Some(v) = &cli.view {
        let [rx, ry] = v[..] else {
            return Err("--view takes rotate_x,rotate_y".into());
        };
        for s in &mut list {
            s.psnr_view = (rx, ry);
        }
    }
    let ceiling = threads.map(ceiling::measure);
    let mut main_results = Vec::new();
    for scene in &list {
        main_results.push(bench::run_scene(scene, &opts)?);
    }
    let mut scaling = Vec::new();
    if !cli.no_scaling {
        let sopts = Options {
            psnr: false,
            images_dir: None,
            ..opts.clone()
        };
        for &n in &cli.scaling {
            let s = scenes::spheres(n);
            match main_results.iter().find(|r| r.name == s.name) {
                Some(r) => scaling.push(r.clone()),
                None => scaling.push(bench::run_scene(&s, &sopts)?),
            }
        }
    }
    let load_after = load_average();
    let stolen = stolen(ticks_before, cpu_ticks());

    println!(
        "\nScenes (ms/frame: median over {} views of the best of {} rounds; ratios < 1 mean \
         shearwarp is faster):",
        cli.frames, cli.rounds
    );
    print!("{}", report::text_table(&main_results));
    if !scaling.is_empty() {
        println!("\nScaling (nested spheres):");
        print!("{}", report::text_table(&scaling));
    }
    for r in main_results.iter().chain(&scaling) {
        for s in &r.sizes {
            if s.threads_identical == Some(false) {
                println!(
                    "WARNING: {} at {}: threaded, side-by-side or baseline-build image differs from \
                     single-threaded",
                    r.name, s.size
                );
            }
        }
    }
    let phases = report::phase_text_table(&main_results);
    if !phases.is_empty() {
        println!("\nWhere the frames went (ms; medians over the views):");
        print!("{phases}");
    }
    // Every scene once: the scaling series repeats spheres256 from the main scenes.
    let mut all = main_results.clone();
    all.extend(
        scaling
            .iter()
            .filter(|r| !main_results.iter().any(|m| m.name == r.name))
            .cloned(),
    );
    let supersampled = report::supersample_text_table(&all);
    if !supersampled.is_empty() {
        println!("\nSupersampled within slices (1 thread):");
        print!("{supersampled}");
    }
    if let Some(c) = &ceiling {
        println!("Threaded columns: read against {}.", c.describe());
    }
    println!("load average before {load_before}, after {load_after}; {stolen}");

    if let Some(p) = &cli.plot {
        plot::scaling_plot(
            p,
            "nested spheres, shaded: median ms/frame",
            &plot_series(&scaling, cli.threads),
        )?;
        eprintln!("wrote {}", p.display());
    }
    if let Some(md) = &cli.markdown {
        let args: Vec<String> = std::env::args().skip(1).collect();
        let mut block = String::new();
        let _ = writeln!(
            block,
            "Measured {started}; load average before {load_before}, after {load_after}; \
             {stolen}.\n"
        );
        let nice = match niceness() {
            Some(n) if n != 0 => format!("nice -n {n} "),
            _ => String::new(),
        };
        // How this binary was built: the command that reruns it, what to say of the
        // build, and the block of BENCHMARKS.md it writes.
        let (command, build, markers) = match PGO {
            Some(trained) => (
                "frontends/bench/pgo.sh",
                format!(
                    "shearwarp was built with a profile (`frontends/bench/pgo.sh`: an \
                     instrumented build of this binary rendered {trained}, none of which is \
                     timed here, and the profile steered the release build's inlining and \
                     code layout). VolPack is Debian's build, as in the plain build's table."
                ),
                &report::PGO,
            ),
            None => (
                "cargo run --release -p shearwarp-bench --",
                "shearwarp was built by `cargo build --release` (the workspace's release \
                 profile: thin LTO, one codegen unit)."
                    .to_string(),
                &report::PLAIN,
            ),
        };
        let _ = writeln!(
            block,
            "Command (from the repository root):\n\n```sh\n{nice}{command} {}\n```\n",
            args.join(" ")
        );
        let _ = writeln!(block, "{build}\n");
        let _ = writeln!(block, "Machine:\n\n{}", machine());
        let _ = writeln!(
            block,
            "shearwarp's compositing loop ran its {} build (chosen at run time from the \
             CPU's features; every build gives the same image, checked frame by frame \
             here); the `SSE2` columns time the baseline x86-64 build of the same code, \
             which is what Debian compiles VolPack for.\n",
            opts.isa.name()
        );
        let _ = writeln!(
            block,
            "### Scenes\n\nms/frame: median over {} views of each view's best of {} rounds; \
             `sw` = shearwarp (1 thread unless noted), `VP` = VolPack (1 thread); prep = \
             classification + normals + run-length encoding (median of {} runs); ratios \
             below 1 mean shearwarp is faster. PSNR against the reference ray caster at \
             view (rotate_x, rotate_y) = (25°, 35°).\n",
            cli.frames, cli.rounds, cli.prep_runs
        );
        block.push_str(&report::markdown_table(&main_results));
        if let Some(c) = &ceiling {
            let _ = writeln!(
                block,
                "\nRead the threaded columns against {}.",
                c.describe()
            );
        }
        let phases = report::phase_markdown_table(&main_results);
        if !phases.is_empty() {
            let _ = writeln!(
                block,
                "\n### Where the frames went\n\nms, medians over the views of each view's \
                 best frame, as the renderer times its phases (`Renderer::times`): the \
                 serial setup (factorization, shading and opacity tables), the compositing \
                 phase (wall clock) and the warp. `busy ÷ 1T compositing` is the threads' \
                 summed busy time over one thread's compositing: the extra CPU time threads \
                 spend, on more instructions or on slower ones. `waiting` is the compositing \
                 phase less the longest thread's busy time. The two columns after it \
                 render one-thread frames on every thread at once, each with its own \
                 renderer and nothing written in common: the time of the slowest, and how \
                 many frames a second that gives against one thread alone, the most \
                 threads can gain on this host for this work before they share anything. \
                 The last three render the turn back to back, nothing between frames: \
                 each round the one-thread renderer's {0} frames one after the other, \
                 then the threaded renderer's, each view's best of the rounds. In the \
                 main table the renderers take turns frame by frame, so the threaded \
                 renderer's worker has gone to sleep before each of its frames and the \
                 frame pays for waking it; back to back it is still awake.\n",
                cli.frames
            );
            block.push_str(&phases);
        }
        let supersampled = report::supersample_markdown_table(&all);
        if !supersampled.is_empty() {
            let _ = writeln!(
                block,
                "\n### Supersampled within slices\n\nWhere the image is at least twice \
                 the volume's largest side, shearwarp also composites {0}×{0} intermediate \
                 pixels per voxel of a slice (`--supersample {0}`: each slice resampled \
                 bilinearly at the finer grid), so the warp no longer upsamples a \
                 volume-resolution intermediate image, as the plain frame and VolPack do. One \
                 thread; ms/frame is the median over the same {1} views of each view's \
                 best of {2} rounds, as for the plain frame; PSNR at the same view against \
                 the same reference.\n",
                cli.supersample, cli.frames, cli.rounds
            );
            block.push_str(&supersampled);
        }
        if !scaling.is_empty() {
            let _ = writeln!(block, "\n### Scaling (nested spheres, n³)\n");
            block.push_str(&report::markdown_table(&scaling));
            if let Some(p) = &cli.plot {
                let rel = p.strip_prefix(repo_root()).unwrap_or(p);
                let _ = writeln!(
                    block,
                    "\n![median ms/frame against volume side, log-log]({})",
                    rel.display()
                );
            }
        }
        let _ = writeln!(block, "\n### Encoded size\n");
        block.push_str(&memory_table(&all));
        let existing = std::fs::read_to_string(md).unwrap_or_default();
        std::fs::write(md, report::splice(&existing, &block, markers))?;
        eprintln!("updated {}", md.display());
    }
    Ok(())
}

fn main() -> ExitCode {
    match run(Cli::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("shearwarp-bench: {e}");
            ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use shearwarp_core::composite::FlatVoxels;

    #[test]
    fn the_size_table_gives_each_scenes_flat_share_and_way() {
        let r = SceneResult {
            name: "s".into(),
            dims: [10, 10, 10],
            sw_visible: 400,
            sw_flat: 100,
            flat_voxels: FlatVoxels::Excluded,
            sw_bytes: 1 << 20,
            ..Default::default()
        };
        let t = memory_table(&[r]);
        assert!(
            t.contains("| s | 1000 | 400 (40.0%) | 25.00% | excluded | 1.0 | – |"),
            "{t}"
        );
    }
}
