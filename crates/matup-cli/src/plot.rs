//! `time_vs_error.png`: wall time against render error, one point per method and setting
//! (averaged over materials), the Pareto front drawn through the points no other beats on both.

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::anyhow;
use image::codecs::png::{CompressionType, FilterType, PngEncoder};
use image::{ExtendedColorType, ImageEncoder};
use matup_apps::experiment::Row;
use matup_draw::text::FONT; // shipped, so that a machine without fonts can plot
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::FontStyle;

/// (label, mean seconds, mean FLIP) per method and setting over the finished rows.
pub fn method_means(rows: &[Row]) -> Vec<(String, f64, f64)> {
    let mut sums: BTreeMap<String, (f64, f64, usize)> = BTreeMap::new();
    for r in rows.iter().filter(|r| r.error.is_none()) {
        // The run id without its material, and short: "per-map lanczos3", "matup onnx:…".
        let label =
            r.id.split_once('/')
                .map_or(r.id.as_str(), |p| p.1)
                .replace("upsampler=", "");
        let s = sums.entry(label).or_default();
        s.0 += r.seconds;
        s.1 += r.metric("render_flip");
        s.2 += 1;
    }
    sums.into_iter()
        .map(|(k, (t, f, n))| (k, t / n as f64, f / n as f64))
        .collect()
}

/// Indices of the points on the Pareto front (no other point is both faster and better).
pub fn pareto_front(points: &[(String, f64, f64)]) -> Vec<usize> {
    let mut order: Vec<usize> = (0..points.len()).collect();
    order.sort_by(|&a, &b| points[a].1.total_cmp(&points[b].1));
    let mut best = f64::INFINITY;
    order
        .into_iter()
        .filter(|&i| {
            let keep = points[i].2 < best;
            best = best.min(points[i].2);
            keep
        })
        .collect()
}

pub fn plot_time_vs_error(rows: &[Row], path: &Path) -> anyhow::Result<()> {
    let points = method_means(rows);
    if points.is_empty() {
        return Ok(());
    }
    write_png(path, (1100, 700), |root| draw(&points, root))
}

type Drawn = Result<(), Box<dyn std::error::Error>>;

/// A `size` plot drawn by `draw`, written to `path` as a PNG compressed as far as it goes
/// (every training run keeps its curves in the repository): beside the target first and
/// renamed over it, like every output.
fn write_png(
    path: &Path,
    (width, height): (u32, u32),
    draw: impl FnOnce(DrawingArea<BitMapBackend<'_>, Shift>) -> Drawn,
) -> anyhow::Result<()> {
    let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, FONT);
    let mut pixels = vec![0u8; width as usize * height as usize * 3];
    let root = BitMapBackend::with_buffer(&mut pixels, (width, height)).into_drawing_area();
    draw(root).map_err(|e| anyhow!("{}: cannot draw the plot: {e}", path.display()))?;
    let tmp = path.with_extension("partial.png");
    let file = std::io::BufWriter::new(std::fs::File::create(&tmp)?);
    PngEncoder::new_with_quality(file, CompressionType::Best, FilterType::Adaptive)
        .write_image(&pixels, width, height, ExtendedColorType::Rgb8)
        .map_err(|e| anyhow!("{}: cannot write the plot: {e}", path.display()))?;
    std::fs::rename(&tmp, path)?;
    Ok(())
}

fn draw(points: &[(String, f64, f64)], root: DrawingArea<BitMapBackend<'_>, Shift>) -> Drawn {
    root.fill(&WHITE)?;
    let (t_min, t_max) = points.iter().fold((f64::INFINITY, 0.0f64), |(lo, hi), p| {
        (lo.min(p.1), hi.max(p.1))
    });
    let (e_min, e_max) = points.iter().fold((f64::INFINITY, 0.0f64), |(lo, hi), p| {
        (lo.min(p.2), hi.max(p.2))
    });
    // Room on the right for the labels, which start at their point.
    let t_range = (t_min.max(1e-3) / 2.0)..(t_max.max(1e-3) * 8.0);
    let pad = (e_max - e_min).max(1e-4) * 0.15;
    let mut chart = ChartBuilder::on(&root)
        .caption(
            "run time against render error (mean over materials)",
            ("sans-serif", 24),
        )
        .margin(20)
        .x_label_area_size(50)
        .y_label_area_size(70)
        .build_cartesian_2d(t_range.log_scale(), (e_min - pad)..(e_max + pad))?;
    chart
        .configure_mesh()
        .x_desc("wall time (s, log scale)")
        .y_desc("render FLIP (lower is better)")
        .label_style(("sans-serif", 15))
        .draw()?;
    let front = pareto_front(points);
    chart.draw_series(LineSeries::new(
        front.iter().map(|&i| (points[i].1, points[i].2)),
        RED.stroke_width(2),
    ))?;
    for (i, (label, t, e)) in points.iter().enumerate() {
        let on_front = front.contains(&i);
        let colour = if on_front { RED } else { BLUE };
        chart.draw_series(std::iter::once(Circle::new((*t, *e), 5, colour.filled())))?;
        chart.draw_series(std::iter::once(Text::new(
            label.clone(),
            (*t, *e),
            ("sans-serif", 13).into_font().color(&BLACK),
        )))?;
    }
    root.present()?;
    Ok(())
}

/// `curves.png` of a `matup learn` run: the training loss (mean of every 100 steps) and each
/// validation's render PSNR gain over the start (per material and the mean), against the step;
/// `validated` says what the validation scored.
pub fn plot_learning_curves(run: &Path, validated: &str) -> anyhow::Result<()> {
    let read = |name: &str| -> anyhow::Result<Vec<Vec<String>>> {
        let text = std::fs::read_to_string(run.join(name))?;
        Ok(text
            .lines()
            .skip(1)
            .map(|l| l.split(',').map(str::to_string).collect())
            .collect())
    };
    let train = read("train.csv")?;
    let val = read("val.csv").unwrap_or_default();
    let number = |s: &str| s.parse::<f64>().unwrap_or(f64::NAN);
    let loss: Vec<(f64, f64)> = train
        .chunks(100)
        // A last, partial chunk would be a mean of a few steps: noise.
        .filter(|c| c.len() == 100 || train.len() < 100)
        .map(|c| {
            let mean = c.iter().map(|r| number(&r[2])).sum::<f64>() / c.len() as f64;
            (number(&c[c.len() - 1][0]), mean)
        })
        .collect();
    // Per material (and "mean"): (step, PSNR − PSNR at the first validation).
    let mut gains: BTreeMap<String, Vec<(f64, f64)>> = BTreeMap::new();
    let mut first: BTreeMap<String, f64> = BTreeMap::new();
    for r in &val {
        let psnr = number(&r[2]);
        let start = *first.entry(r[1].clone()).or_insert(psnr);
        gains
            .entry(r[1].clone())
            .or_default()
            .push((number(&r[0]), psnr - start));
    }
    if loss.is_empty() {
        return Ok(());
    }
    write_png(&run.join("curves.png"), (1400, 600), |root| {
        draw_curves(&loss, &gains, validated, root)
    })
}

type Curve = Vec<(f64, f64)>;

fn draw_curves(
    loss: &Curve,
    gains: &BTreeMap<String, Curve>,
    validated: &str,
    root: DrawingArea<BitMapBackend<'_>, Shift>,
) -> Drawn {
    root.fill(&WHITE)?;
    let (left, right) = root.split_horizontally(560);
    let last_step = loss.last().map_or(1.0, |p| p.0).max(1.0);
    let (lo, hi) = loss.iter().fold((f64::INFINITY, 0f64), |(lo, hi), p| {
        (lo.min(p.1), hi.max(p.1))
    });
    let mut chart = ChartBuilder::on(&left)
        .caption(
            "training render loss (mean of 100 steps)",
            ("sans-serif", 20),
        )
        .margin(20)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(0.0..last_step, (lo * 0.9)..(hi * 1.1))?;
    chart.configure_mesh().x_desc("step").draw()?;
    chart.draw_series(LineSeries::new(loss.iter().copied(), &BLUE))?;

    let all = gains.values().flatten();
    let (g_lo, g_hi) = all.fold((0f64, 0f64), |(lo, hi), p| (lo.min(p.1), hi.max(p.1)));
    let pad = (g_hi - g_lo).max(0.05) * 0.1;
    let mut chart = ChartBuilder::on(&right)
        .caption(
            format!("validation: render PSNR gain over the start (dB), {validated}"),
            ("sans-serif", 20),
        )
        .margin(20)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(0.0..last_step, (g_lo - pad)..(g_hi + pad))?;
    chart.configure_mesh().x_desc("step").draw()?;
    for (i, (name, curve)) in gains.iter().enumerate() {
        let mean = name == "mean";
        let colour = if mean {
            BLACK.to_rgba()
        } else {
            Palette99::pick(i).to_rgba()
        };
        let style = colour.stroke_width(if mean { 3 } else { 1 });
        let label = name.trim_start_matches("ambientcg_").to_string();
        chart
            .draw_series(LineSeries::new(curve.iter().copied(), style))?
            .label(label)
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], style));
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .position(SeriesLabelPosition::UpperLeft)
        .draw()?;
    root.present()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_front_keeps_points_no_other_beats_on_both() {
        let p = |t: f64, e: f64| (String::new(), t, e);
        let points = vec![
            p(1.0, 0.5),
            p(2.0, 0.6),
            p(3.0, 0.3),
            p(0.5, 0.9),
            p(10.0, 0.31),
        ];
        let mut front = pareto_front(&points);
        front.sort();
        assert_eq!(front, vec![0, 2, 3]);
    }
}
