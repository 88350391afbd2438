//! Tables for the terminal and for BENCHMARKS.md.

use crate::bench::SceneResult;
use std::fmt::Write as _;

/// Start and end markers of a generated block in BENCHMARKS.md.
pub struct Markers {
    pub begin: &'static str,
    pub end: &'static str,
}

/// The block of the plain `cargo build --release` binary.
pub const PLAIN: Markers = Markers {
    begin: "<!-- shearwarp-bench:begin (generated; edit outside the markers) -->",
    end: "<!-- shearwarp-bench:end -->",
};

/// The block of the profile-guided binary (`frontends/bench/pgo.sh`): a run of either
/// build leaves the other's block as it is.
pub const PGO: Markers = Markers {
    begin: "<!-- shearwarp-bench-pgo:begin (generated; edit outside the markers) -->",
    end: "<!-- shearwarp-bench-pgo:end -->",
};

fn opt(v: Option<f64>, prec: usize) -> String {
    match v {
        Some(x) if x.is_finite() => format!("{x:.prec$}"),
        Some(_) => "inf".into(),
        None => "–".into(),
    }
}

fn ratio(a: f64, b: Option<f64>) -> Option<f64> {
    b.filter(|&b| b > 0.0).map(|b| a / b)
}

/// Column headers of the main table.
fn headers(threads: Option<usize>) -> Vec<String> {
    let t = threads.unwrap_or(2);
    vec![
        "scene".into(),
        "image".into(),
        "prep sw ms".into(),
        "prep VP ms".into(),
        "prep sw/VP".into(),
        "sw ms/frame".into(),
        format!("sw {t}T ms/frame"),
        format!("{t}T speed-up"),
        "VP ms/frame".into(),
        "sw/VP".into(),
        "sw SSE2 ms/frame".into(),
        "SSE2/VP".into(),
        "PSNR sw dB".into(),
        "PSNR VP dB".into(),
    ]
}

fn rows(results: &[SceneResult]) -> Vec<Vec<String>> {
    let mut out = Vec::new();
    for r in results {
        for s in &r.sizes {
            let [nx, ny, nz] = r.dims;
            let t = s.sw_threads.map(|t| t.median);
            out.push(vec![
                format!("{} ({nx}×{ny}×{nz})", r.name),
                format!("{0}×{0}", s.size),
                format!("{:.1}", r.sw_prep),
                opt(r.vp_prep, 1),
                opt(ratio(r.sw_prep, r.vp_prep), 2),
                format!("{:.2}", s.sw.median),
                opt(t, 2),
                opt(t.and_then(|t| ratio(s.sw.median, Some(t))), 2),
                opt(s.vp.map(|v| v.median), 2),
                opt(ratio(s.sw.median, s.vp.map(|v| v.median)), 2),
                opt(s.sw_base.map(|b| b.median), 2),
                opt(
                    s.sw_base
                        .and_then(|b| ratio(b.median, s.vp.map(|v| v.median))),
                    2,
                ),
                opt(s.psnr_sw, 1),
                opt(s.psnr_vp, 1),
            ]);
        }
    }
    out
}

/// Column headers of the phase table.
fn phase_headers(threads: Option<usize>) -> Vec<String> {
    let t = threads.unwrap_or(2);
    vec![
        "scene".into(),
        "image".into(),
        "1T setup ms".into(),
        "1T compositing ms".into(),
        "1T warp ms".into(),
        format!("{t}T setup ms"),
        format!("{t}T compositing ms"),
        format!("{t}T warp ms"),
        format!("{t}T threads busy, summed ms"),
        "busy ÷ 1T compositing".into(),
        format!("{t}T waiting ms"),
        format!("{t} 1T frames side by side ms"),
        "their throughput ×".into(),
        "1T back to back ms".into(),
        format!("{t}T back to back ms"),
        format!("{t}T back to back speed-up"),
    ]
}

/// One row per scene and size that ran threaded.
fn phase_rows(results: &[SceneResult]) -> Vec<Vec<String>> {
    let mut out = Vec::new();
    for r in results {
        let threads = r.threads.unwrap_or(2);
        for s in &r.sizes {
            let Some(t) = s.threads_phases else { continue };
            let o = s.sw_phases;
            let [nx, ny, nz] = r.dims;
            out.push(vec![
                format!("{} ({nx}×{ny}×{nz})", r.name),
                format!("{0}×{0}", s.size),
                format!("{:.3}", o.setup),
                format!("{:.2}", o.composite),
                format!("{:.3}", o.warp),
                format!("{:.3}", t.setup),
                format!("{:.2}", t.composite),
                format!("{:.3}", t.warp),
                format!("{:.2}", t.busy_sum),
                opt(ratio(t.busy_sum, Some(o.composite)), 2),
                format!("{:.3}", (t.composite - t.busy_max).max(0.0)),
                opt(s.side_by_side.map(|x| x.median), 2),
                opt(
                    s.side_by_side
                        .and_then(|x| ratio(threads as f64 * s.sw.median, Some(x.median))),
                    2,
                ),
                opt(s.back_to_back.map(|(o, _)| o.median), 2),
                opt(s.back_to_back.map(|(_, n)| n.median), 2),
                opt(
                    s.back_to_back
                        .and_then(|(o, n)| ratio(o.median, Some(n.median))),
                    2,
                ),
            ]);
        }
    }
    out
}

/// Column headers of the supersampling table.
fn supersample_headers() -> Vec<String> {
    [
        "scene",
        "image",
        "factor",
        "sw ms/frame",
        "supersampled ms/frame",
        "cost ×",
        "PSNR sw dB",
        "PSNR supersampled dB",
        "gain dB",
        "PSNR VP dB",
    ]
    .map(String::from)
    .to_vec()
}

/// One row per scene and size that ran supersampled.
fn supersample_rows(results: &[SceneResult]) -> Vec<Vec<String>> {
    let mut out = Vec::new();
    for r in results {
        for s in &r.sizes {
            let Some(ss) = s.supersampled else { continue };
            let [nx, ny, nz] = r.dims;
            out.push(vec![
                format!("{} ({nx}×{ny}×{nz})", r.name),
                format!("{0}×{0}", s.size),
                format!("{}×{}", ss.factor, ss.factor),
                format!("{:.2}", s.sw.median),
                format!("{:.2}", ss.sw.median),
                opt(ratio(ss.sw.median, Some(s.sw.median)), 1),
                opt(s.psnr_sw, 2),
                opt(ss.psnr, 2),
                opt(ss.psnr.zip(s.psnr_sw).map(|(a, b)| a - b), 2),
                opt(s.psnr_vp, 2),
            ]);
        }
    }
    out
}

/// Plain-text supersampling table (empty when nothing ran supersampled).
pub fn supersample_text_table(results: &[SceneResult]) -> String {
    unless_empty(&supersample_headers(), &supersample_rows(results), text)
}

/// Markdown supersampling table (empty when nothing ran supersampled).
pub fn supersample_markdown_table(results: &[SceneResult]) -> String {
    unless_empty(&supersample_headers(), &supersample_rows(results), markdown)
}

/// The table in `format`, or nothing when it has no rows.
fn unless_empty(
    h: &[String],
    rows: &[Vec<String>],
    format: fn(&[String], &[Vec<String>]) -> String,
) -> String {
    if rows.is_empty() {
        return String::new();
    }
    format(h, rows)
}

/// Plain-text table for the terminal.
pub fn text_table(results: &[SceneResult]) -> String {
    let threads = results.iter().find_map(|r| r.threads);
    text(&headers(threads), &rows(results))
}

/// Plain-text phase table for the terminal (empty when nothing ran threaded).
pub fn phase_text_table(results: &[SceneResult]) -> String {
    phase_table(results, text)
}

/// Markdown phase table (empty when nothing ran threaded).
pub fn phase_markdown_table(results: &[SceneResult]) -> String {
    phase_table(results, markdown)
}

/// The phase table in `format` (empty when nothing ran threaded).
fn phase_table(results: &[SceneResult], format: fn(&[String], &[Vec<String>]) -> String) -> String {
    let threads = results.iter().find_map(|r| r.threads);
    unless_empty(&phase_headers(threads), &phase_rows(results), format)
}

/// Columns padded to their widest cell; the first two left-aligned.
fn text(h: &[String], rows: &[Vec<String>]) -> String {
    let mut widths: Vec<usize> = h.iter().map(|c| c.chars().count()).collect();
    for r in rows {
        for (w, c) in widths.iter_mut().zip(r) {
            *w = (*w).max(c.chars().count());
        }
    }
    let line = |cells: &[String]| -> String {
        let mut s = String::new();
        for (i, (c, w)) in cells.iter().zip(&widths).enumerate() {
            let pad = w - c.chars().count();
            if i < 2 {
                let _ = write!(s, "{c}{}  ", " ".repeat(pad));
            } else {
                let _ = write!(s, "{}{c}  ", " ".repeat(pad));
            }
        }
        s.trim_end().to_string()
    };
    let mut out = line(h);
    out.push('\n');
    for r in rows {
        out.push_str(&line(r));
        out.push('\n');
    }
    out
}

/// Markdown table.
pub fn markdown_table(results: &[SceneResult]) -> String {
    let threads = results.iter().find_map(|r| r.threads);
    markdown(&headers(threads), &rows(results))
}

/// A markdown table; the first two columns left-aligned, the others right.
fn markdown(h: &[String], rows: &[Vec<String>]) -> String {
    let mut out = format!("| {} |\n", h.join(" | "));
    let align: Vec<&str> = (0..h.len())
        .map(|i| if i < 2 { "---" } else { "---:" })
        .collect();
    let _ = writeln!(out, "|{}|", align.join("|"));
    for r in rows {
        let _ = writeln!(out, "| {} |", r.join(" | "));
    }
    out
}

/// Replaces the generated block of `existing` marked by `m` (or appends one) with
/// `block`.
pub fn splice(existing: &str, block: &str, m: &Markers) -> String {
    let Markers { begin, end } = m;
    let generated = format!("{begin}\n{block}{end}\n");
    match (existing.find(begin), existing.find(end)) {
        (Some(b), Some(e)) if e > b => {
            let after = &existing[e + end.len()..];
            let after = after.strip_prefix('\n').unwrap_or(after);
            format!("{}{generated}{after}", &existing[..b])
        }
        _ => {
            let mut s = existing.to_string();
            if !s.is_empty() && !s.ends_with("\n\n") {
                s.push_str(if s.ends_with('\n') { "\n" } else { "\n\n" });
            }
            s.push_str(&generated);
            s
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bench::{Phases, SizeResult, Stats, Supersampled};

    fn sample() -> Vec<SceneResult> {
        vec![SceneResult {
            name: "s".into(),
            dims: [2, 3, 4],
            sw_prep: 10.0,
            vp_prep: Some(40.0),
            sw_bytes: 1,
            sw_visible: 1,
            sw_flat: 0,
            flat_voxels: shearwarp_core::composite::FlatVoxels::Blended,
            vp_bytes: Some(2),
            threads: Some(2),
            sizes: vec![SizeResult {
                size: 256,
                sw: Stats { median: 1.0 },
                sw_phases: Phases {
                    setup: 0.05,
                    composite: 0.8,
                    busy_sum: 0.8,
                    busy_max: 0.8,
                    warp: 0.1,
                },
                sw_threads: Some(Stats { median: 0.5 }),
                threads_phases: Some(Phases {
                    setup: 0.05,
                    composite: 0.5,
                    busy_sum: 0.88,
                    busy_max: 0.46,
                    warp: 0.06,
                }),
                side_by_side: Some(Stats { median: 1.25 }),
                back_to_back: Some((Stats { median: 0.9 }, Stats { median: 0.48 })),
                sw_base: Some(Stats { median: 2.0 }),
                threads_identical: Some(true),
                vp: Some(Stats { median: 4.0 }),
                psnr_sw: Some(40.0),
                psnr_vp: None,
                supersampled: Some(Supersampled {
                    factor: 2,
                    sw: Stats { median: 4.5 },
                    psnr: Some(40.25),
                }),
            }],
        }]
    }

    #[test]
    fn tables_show_ratios() {
        let t = text_table(&sample());
        assert!(t.contains("0.25"), "{t}");
        assert!(t.contains("2.00"), "{t}");
        let m = markdown_table(&sample());
        assert_eq!(m.lines().count(), 3);
        assert!(m.contains("| s (2×3×4) | 256×256 | 10.0 | 40.0 | 0.25 | 1.00 | 0.50 | 2.00 | 4.00 | 0.25 | 2.00 | 0.50 | 40.0 | – |"), "{m}");
    }

    #[test]
    fn the_phase_table_shows_extra_cpu_time_and_waiting() {
        let m = phase_markdown_table(&sample());
        assert!(
            m.contains("| s (2×3×4) | 256×256 | 0.050 | 0.80 | 0.100 | 0.050 | 0.50 | 0.060 | 0.88 | 1.10 | 0.040 | 1.25 | 1.60 | 0.90 | 0.48 | 1.88 |"),
            "{m}"
        );
        let mut one = sample();
        one[0].sizes[0].threads_phases = None;
        assert_eq!(phase_text_table(&one), "");
    }

    #[test]
    fn the_supersampling_table_shows_cost_and_gain() {
        let m = supersample_markdown_table(&sample());
        assert!(
            m.contains(
                "| s (2×3×4) | 256×256 | 2×2 | 1.00 | 4.50 | 4.5 | 40.00 | 40.25 | 0.25 | – |"
            ),
            "{m}"
        );
        let mut plain = sample();
        plain[0].sizes[0].supersampled = None;
        assert_eq!(supersample_text_table(&plain), "");
    }

    #[test]
    fn splice_replaces_or_appends() {
        let Markers { begin, end } = PLAIN;
        let a = splice("# T\n\ntext\n", "one\n", &PLAIN);
        assert_eq!(a, format!("# T\n\ntext\n\n{begin}\none\n{end}\n"));
        let b = splice(&a, "two\n", &PLAIN);
        assert_eq!(b, format!("# T\n\ntext\n\n{begin}\ntwo\n{end}\n"));
        let c = splice(&format!("{b}tail\n"), "three\n", &PLAIN);
        assert_eq!(c, format!("# T\n\ntext\n\n{begin}\nthree\n{end}\ntail\n"));
        assert_eq!(splice("", "x\n", &PLAIN), format!("{begin}\nx\n{end}\n"));
    }

    #[test]
    fn each_build_replaces_only_its_own_block() {
        let both = splice(&splice("# T\n", "plain\n", &PLAIN), "pgo\n", &PGO);
        let again = splice(&both, "pgo 2\n", &PGO);
        assert!(again.contains(&format!("{}\nplain\n{}", PLAIN.begin, PLAIN.end)));
        assert!(again.contains(&format!("{}\npgo 2\n{}", PGO.begin, PGO.end)));
        assert!(!again.contains("pgo\n"));
        let plain = splice(&again, "plain 2\n", &PLAIN);
        assert!(plain.contains("plain 2\n") && !plain.contains("plain\n"));
        assert!(plain.contains("pgo 2\n"));
    }
}
