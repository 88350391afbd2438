//! `shearwarp-view-compare A [B] [--tolerance N] [--max-over N] [--save-a OUT.png]`:
//! compares two images (PNG or XWD window dumps) of the same size per channel. Exits 0
//! when at most `--max-over` pixels (default 0) differ by more than `--tolerance`
//! (default 2) in any channel. `--save-a` writes A as a PNG (to keep a window dump);
//! with it, B may be left out to only convert.

use clap::Parser;
use shearwarp_view::compare;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "shearwarp-view-compare",
    about = "Compare two images (PNG or XWD)"
)]
struct Cli {
    /// First image (PNG or XWD).
    a: PathBuf,
    /// Second image (PNG or XWD); optional with --save-a.
    b: Option<PathBuf>,
    /// Largest per-channel difference that still counts as equal.
    #[arg(long, default_value_t = 2)]
    tolerance: u8,
    /// Pixels allowed over the tolerance.
    #[arg(long, default_value_t = 0)]
    max_over: usize,
    /// Also write image A to this PNG.
    #[arg(long)]
    save_a: Option<PathBuf>,
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let Some(b_path) = cli.b.clone() else {
        let Some(out) = &cli.save_a else {
            eprintln!("error: give a second image to compare with, or --save-a to convert");
            return ExitCode::FAILURE;
        };
        return match compare::load(&cli.a).and_then(|a| compare::save_png(&a, out)) {
            Ok(()) => {
                println!("wrote {}", out.display());
                ExitCode::SUCCESS
            }
            Err(e) => {
                eprintln!("error: {e}");
                ExitCode::FAILURE
            }
        };
    };
    let result = compare::load(&cli.a)
        .and_then(|a| {
            if let Some(p) = &cli.save_a {
                compare::save_png(&a, p)?;
            }
            Ok((a, compare::load(&b_path)?))
        })
        .and_then(|(a, b)| compare::diff(&a, &b, cli.tolerance));
    match result {
        Ok(d) => {
            let ok = d.over <= cli.max_over;
            println!(
                "{} vs {}: {d} (tolerance {}, allowed {}) -> {}",
                cli.a.display(),
                b_path.display(),
                cli.tolerance,
                cli.max_over,
                if ok { "PASS" } else { "FAIL" }
            );
            if ok {
                ExitCode::SUCCESS
            } else {
                ExitCode::FAILURE
            }
        }
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
