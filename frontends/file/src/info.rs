//! `shearwarp info`: what a volume holds (dims, spacing, value range, histogram) and
//! which transfer functions suit it.

use crate::formats::VolumeMeta;
use crate::volume::{RawVolume, Voxels};
use serde_json::json;
use std::fmt::Write;

/// Number of histogram bins printed.
pub const BINS: usize = 16;

/// Statistics of a loaded volume.
#[derive(Clone, Debug)]
pub struct Info {
    pub name: String,
    pub dims: [usize; 3],
    pub spacing: [f64; 3],
    pub voxel_type: &'static str,
    pub meta: VolumeMeta,
    /// Stored value range.
    pub min: u16,
    pub max: u16,
    pub mean: f64,
    /// Stored values at the 1st, 50th and 99th percentile.
    pub p1: u16,
    pub p50: u16,
    pub p99: u16,
    /// `(lower, upper, count)` per bin over `min..=max` (stored values).
    pub histogram: Vec<(u16, u16, u64)>,
    /// Suggested named presets: `(name, description, CLI options)`.
    pub presets: Vec<(String, String, String)>,
}

fn percentile(counts: &[u64], total: u64, q: f64) -> u16 {
    let target = ((total as f64) * q).ceil().max(1.0) as u64;
    let mut acc = 0;
    for (v, c) in counts.iter().enumerate() {
        acc += c;
        if acc >= target {
            return v as u16;
        }
    }
    (counts.len() - 1) as u16
}

/// Computes [`Info`] for a volume.
pub fn compute(vol: &RawVolume, meta: &VolumeMeta) -> Info {
    let mut counts = vec![0u64; 65536];
    let mut sum = 0f64;
    match &vol.voxels {
        Voxels::U8(d) => d.iter().for_each(|&v| counts[v as usize] += 1),
        Voxels::U16(d) => d.iter().for_each(|&v| counts[v as usize] += 1),
    }
    for (v, c) in counts.iter().enumerate() {
        sum += v as f64 * *c as f64;
    }
    let total = vol.voxel_count() as u64;
    let min = counts.iter().position(|&c| c > 0).unwrap_or(0) as u16;
    let max = counts.iter().rposition(|&c| c > 0).unwrap_or(0) as u16;
    let span = (max - min) as usize + 1;
    let bins = BINS.min(span);
    let mut histogram = Vec::with_capacity(bins);
    for b in 0..bins {
        let lo = min as usize + span * b / bins;
        let hi = min as usize + span * (b + 1) / bins - 1;
        histogram.push((lo as u16, hi as u16, counts[lo..=hi].iter().sum()));
    }
    let p1 = percentile(&counts, total, 0.01);
    let p50 = percentile(&counts, total, 0.5);
    let p99 = percentile(&counts, total, 0.99);
    let mut info = Info {
        name: vol.name.clone(),
        dims: vol.dims,
        spacing: vol.spacing,
        voxel_type: vol.voxel_type().as_str(),
        meta: meta.clone(),
        min,
        max,
        mean: if total > 0 { sum / total as f64 } else { 0.0 },
        p1,
        p50,
        p99,
        histogram,
        presets: Vec::new(),
    };
    info.presets = presets(vol, meta);
    info
}

/// Whether the values are (or look like) CT in Hounsfield units
/// ([`crate::presets::hu_mapping`]).
pub fn looks_like_ct(info: &Info) -> bool {
    crate::presets::hu_mapping(&info.meta, (info.min, info.max)).is_some()
}

/// The named presets that suit the volume, as `shearwarp render` options.
fn presets(vol: &RawVolume, meta: &VolumeMeta) -> Vec<(String, String, String)> {
    let scale = crate::presets::value_scale(vol, meta);
    crate::presets::suggest(&scale)
        .into_iter()
        .map(|p| {
            (
                p.name.to_string(),
                p.description.to_string(),
                format!("--preset {}", p.name),
            )
        })
        .collect()
}

fn value_rule(m: &VolumeMeta) -> String {
    if m.slope == 1.0 && m.intercept == 0.0 {
        "stored = file value".into()
    } else {
        let sign = if m.intercept < 0.0 { '−' } else { '+' };
        let scale = if m.slope == 1.0 {
            String::new()
        } else {
            format!(" × {:.6}", m.slope)
        };
        format!("file value = stored{scale} {sign} {}", m.intercept.abs())
    }
}

/// The human-readable report.
pub fn to_text(info: &Info, path: &str) -> String {
    let mut s = String::new();
    let m = &info.meta;
    let [nx, ny, nz] = info.dims;
    let [sx, sy, sz] = info.spacing;
    let _ = writeln!(s, "file:        {path}");
    let _ = writeln!(
        s,
        "format:      {} ({} → {}; {})",
        m.format,
        m.source_type,
        info.voxel_type,
        value_rule(m)
    );
    let _ = writeln!(s, "name:        {}", info.name);
    let _ = writeln!(
        s,
        "dims:        {nx} × {ny} × {nz} ({} voxels)",
        nx * ny * nz
    );
    let _ = writeln!(
        s,
        "spacing:     {sx:.6} × {sy:.6} × {sz:.6} mm (extent {:.1} × {:.1} × {:.1} mm)",
        sx * nx as f64,
        sy * ny as f64,
        sz * nz as f64
    );
    if let Some(md) = &m.modality {
        let _ = writeln!(s, "modality:    {md}");
    }
    let unit = m
        .units
        .as_deref()
        .map(|u| format!(" {u}"))
        .unwrap_or_default();
    let _ = writeln!(
        s,
        "orientation: {}",
        if m.orientation.is_empty() {
            "as stored"
        } else {
            &m.orientation
        }
    );
    let _ = writeln!(
        s,
        "values:      stored {}..{} (file values {}..{}{unit}), mean {:.1}, p1 {}, median {}, p99 {}",
        info.min,
        info.max,
        m.physical(info.min as f64),
        m.physical(info.max as f64),
        info.mean,
        info.p1,
        info.p50,
        info.p99
    );
    let _ = writeln!(s, "histogram (stored values, bar length ∝ log count):");
    let maxc = info.histogram.iter().map(|h| h.2).max().unwrap_or(1).max(1);
    let w = info.max.to_string().len();
    for &(lo, hi, c) in &info.histogram {
        let bar = ((c as f64 + 1.0).ln() / (maxc as f64 + 1.0).ln() * 40.0).round() as usize;
        let _ = writeln!(
            s,
            "  {lo:>w$}..{hi:>w$} {:<40} {c}",
            "#".repeat(if c > 0 { bar.max(1) } else { 0 })
        );
    }
    let _ = writeln!(s, "suggested presets (options for `shearwarp render`):");
    for (n, d, o) in &info.presets {
        let _ = writeln!(s, "  {n:<11} {o:<20} # {d}");
    }
    s
}

/// The report as JSON.
pub fn to_json(info: &Info, path: &str) -> serde_json::Value {
    let m = &info.meta;
    json!({
        "file": path,
        "format": m.format,
        "source_type": m.source_type,
        "voxel_type": info.voxel_type,
        "value_slope": m.slope,
        "value_intercept": m.intercept,
        "name": info.name,
        "dims_xyz": info.dims,
        "spacing_mm_xyz": info.spacing,
        "modality": m.modality,
        "units": m.units,
        "orientation": m.orientation,
        "stored_range": [info.min, info.max],
        "value_range": [m.physical(info.min as f64), m.physical(info.max as f64)],
        "mean": info.mean,
        "percentiles": {"p1": info.p1, "p50": info.p50, "p99": info.p99},
        "histogram": info.histogram.iter().map(|h| json!({"lo": h.0, "hi": h.1, "count": h.2})).collect::<Vec<_>>(),
        "presets": info.presets.iter().map(|p| json!({"name": p.0, "description": p.1, "options": p.2})).collect::<Vec<_>>(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ct_and_mr_presets() {
        let vol = RawVolume {
            name: "ct".into(),
            dims: [4, 1, 1],
            spacing: [1.0; 3],
            voxels: Voxels::U16(vec![0, 1000, 1224, 3000]),
        };
        let mut meta = VolumeMeta::identity("dicom", "i16");
        meta.intercept = -1024.0;
        meta.modality = Some("CT".into());
        meta.units = Some("HU".into());
        let i = compute(&vol, &meta);
        assert_eq!((i.min, i.max), (0, 3000));
        assert!(looks_like_ct(&i));
        let names: Vec<&str> = i.presets.iter().map(|p| p.0.as_str()).collect();
        assert_eq!(names, ["ct-bone", "ct-skin", "ct-angio", "mip"]);
        assert_eq!(i.presets[0].2, "--preset ct-bone");
        let text = to_text(&i, "x");
        assert!(text.contains("file values -1024..1976 HU"), "{text}");
        let h: u64 = i.histogram.iter().map(|h| h.2).sum();
        assert_eq!(h, 4);

        let meta = VolumeMeta::identity("raw+json", "u8");
        let vol = RawVolume {
            voxels: Voxels::U8(vec![0, 10, 20, 255]),
            ..vol
        };
        let i = compute(&vol, &meta);
        assert_eq!(i.presets[0].0, "mr-default");
        assert!(!looks_like_ct(&i));
        let names: Vec<&str> = i.presets.iter().map(|p| p.0.as_str()).collect();
        assert_eq!(names, ["mr-default", "mr-brain", "mip"]);
        assert_eq!(i.histogram.len(), BINS);
        assert!(to_json(&i, "x")["dims_xyz"].is_array());
    }
}
