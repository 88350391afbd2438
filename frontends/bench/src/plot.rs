//! The scaling plot: median ms/frame against volume side, log-log, drawn with plotters'
//! bitmap backend; labels use the built-in pixel font, so no font files are needed.

use crate::font;
use plotters::prelude::*;
use std::error::Error;
use std::path::Path;

/// Marker shape of a series.
#[derive(Clone, Copy, Debug)]
pub enum Marker {
    Circle,
    Square,
    Triangle,
}

/// One line of the plot.
#[derive(Clone, Debug)]
pub struct Series {
    pub label: String,
    pub color: (u8, u8, u8),
    pub marker: Marker,
    /// (volume side, ms/frame)
    pub points: Vec<(f64, f64)>,
}

const W: u32 = 960;
const H: u32 = 640;

fn text<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    s: &str,
    x: i32,
    y: i32,
    scale: i32,
    vertical: bool,
) {
    let mut px = Vec::new();
    font::render(s, x, y, scale, vertical, |x, y| px.push((x, y)));
    for p in px {
        let _ = area.draw_pixel(p, &BLACK);
    }
}

/// Decade-based ticks (1, 2, 5 × 10^k) within `[lo, hi]`.
fn ticks(lo: f64, hi: f64) -> Vec<f64> {
    let mut out = Vec::new();
    let mut decade = 10f64.powi(lo.log10().floor() as i32);
    while decade <= hi {
        for m in [1.0, 2.0, 5.0] {
            let v = m * decade;
            if v >= lo && v <= hi {
                out.push(v);
            }
        }
        decade *= 10.0;
    }
    out
}

fn tick_label(v: f64) -> String {
    if v >= 1.0 {
        format!("{v:.0}")
    } else {
        let s = format!("{v:.3}");
        s.trim_end_matches('0').to_string()
    }
}

/// Draws `series` to a PNG at `path`.
pub fn scaling_plot(path: &Path, title: &str, series: &[Series]) -> Result<(), Box<dyn Error>> {
    let xs: Vec<f64> = series
        .iter()
        .flat_map(|s| s.points.iter().map(|p| p.0))
        .collect();
    let ys: Vec<f64> = series
        .iter()
        .flat_map(|s| s.points.iter().map(|p| p.1))
        .filter(|&y| y > 0.0)
        .collect();
    if xs.is_empty() || ys.is_empty() {
        return Err("nothing to plot".into());
    }
    let fold = |v: &[f64], f: fn(f64, f64) -> f64, init: f64| v.iter().copied().fold(init, f);
    let (xmin, xmax) = (fold(&xs, f64::min, f64::MAX), fold(&xs, f64::max, 0.0));
    let (ymin, ymax) = (fold(&ys, f64::min, f64::MAX), fold(&ys, f64::max, 0.0));
    let (x0, x1) = (xmin / 1.25, xmax * 1.25);
    let (y0, y1) = (ymin / 2.0, ymax * 2.0);

    let mut buf = vec![0u8; (W * H * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (W, H)).into_drawing_area();
        root.fill(&WHITE)?;
        let mut chart = ChartBuilder::on(&root)
            .margin_top(50)
            .margin_right(30)
            .margin_left(100)
            .margin_bottom(80)
            .build_cartesian_2d((x0..x1).log_scale(), (y0..y1).log_scale())?;
        let grid = RGBColor(220, 220, 220);
        let (left, top) = chart.backend_coord(&(x0, y1));
        let (right, bottom) = chart.backend_coord(&(x1, y0));
        for &y in &ticks(y0, y1) {
            let (_, py) = chart.backend_coord(&(x0, y));
            root.draw(&PathElement::new(vec![(left, py), (right, py)], grid))?;
            let l = tick_label(y);
            text(&root, &l, left - 10 - font::width(&l, 2), py - 7, 2, false);
        }
        let mut xticks: Vec<f64> = xs.clone();
        xticks.sort_by(f64::total_cmp);
        xticks.dedup();
        for &x in &xticks {
            let (px, _) = chart.backend_coord(&(x, y0));
            root.draw(&PathElement::new(vec![(px, top), (px, bottom)], grid))?;
            let l = format!("{x:.0}");
            text(
                &root,
                &l,
                px - font::width(&l, 2) / 2,
                bottom + 10,
                2,
                false,
            );
        }
        root.draw(&Rectangle::new([(left, top), (right, bottom)], BLACK))?;
        let xl = "volume side n (n³ voxels)";
        text(
            &root,
            xl,
            (left + right - font::width(xl, 2)) / 2,
            bottom + 40,
            2,
            false,
        );
        let yl = "median ms/frame";
        text(
            &root,
            yl,
            20,
            (top + bottom + font::width(yl, 2)) / 2,
            2,
            true,
        );
        text(&root, title, left, 15, 2, false);

        for s in series {
            let c = RGBColor(s.color.0, s.color.1, s.color.2);
            chart.draw_series(LineSeries::new(s.points.iter().copied(), c.stroke_width(2)))?;
            for &p in &s.points {
                let st = c.filled();
                match s.marker {
                    Marker::Circle => chart.draw_series(std::iter::once(Circle::new(p, 5, st)))?,
                    Marker::Square => chart.draw_series(std::iter::once(
                        EmptyElement::at(p) + Rectangle::new([(-5, -5), (5, 5)], st),
                    ))?,
                    Marker::Triangle => {
                        chart.draw_series(std::iter::once(TriangleMarker::new(p, 7, st)))?
                    }
                };
            }
        }
        // Legend, top left inside the frame.
        for (i, s) in series.iter().enumerate() {
            let c = RGBColor(s.color.0, s.color.1, s.color.2);
            let y = top + 20 + 24 * i as i32;
            let x = left + 20;
            root.draw(&PathElement::new(
                vec![(x, y), (x + 40, y)],
                c.stroke_width(2),
            ))?;
            let st = c.filled();
            match s.marker {
                Marker::Circle => root.draw(&Circle::new((x + 20, y), 5, st))?,
                Marker::Square => {
                    root.draw(&Rectangle::new([(x + 15, y - 5), (x + 25, y + 5)], st))?
                }
                Marker::Triangle => root.draw(&TriangleMarker::new((x + 20, y), 7, st))?,
            }
            text(&root, &s.label, x + 52, y - 7, 2, false);
        }
        root.present()?;
    }
    let rgb: Vec<[u8; 3]> = buf.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir)?;
    }
    shearwarp_tests::metrics::save_png(path, W as usize, H as usize, &rgb)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticks_cover_decades() {
        assert_eq!(ticks(0.3, 30.0), vec![0.5, 1.0, 2.0, 5.0, 10.0, 20.0]);
        assert_eq!(tick_label(0.5), "0.5");
        assert_eq!(tick_label(20.0), "20");
    }

    #[test]
    fn plot_writes_a_png() {
        let dir = std::env::temp_dir().join(format!("sw-bench-plot-{}", std::process::id()));
        let path = dir.join("p.png");
        let s = Series {
            label: "a".into(),
            color: (200, 0, 0),
            marker: Marker::Square,
            points: vec![(64.0, 1.0), (128.0, 3.0), (256.0, 10.0)],
        };
        scaling_plot(&path, "t", &[s]).unwrap();
        assert!(std::fs::metadata(&path).unwrap().len() > 1000);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
