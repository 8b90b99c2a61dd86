//! `hood plot`: a training run's curves as one SVG (validation objective, validation %
//! penetrating, per-vertex training loss), read from the run folder's `validation.jsonl` and
//! `log.jsonl`.

use clap::Args;
use hood::io::json::{self, Value};
use hood::{Error, Result};
use plotters::prelude::*;
use std::path::{Path, PathBuf};

#[derive(Args)]
pub struct PlotArgs {
    /// Run folder of `hood train` (holds `log.jsonl` and `validation.jsonl`).
    pub dir: PathBuf,
    /// Output SVG (default: `training.svg` in the run folder).
    #[arg(short, long)]
    pub out: Option<PathBuf>,
    /// Iterations per point of the training loss (the median of each window).
    #[arg(long, default_value_t = 250)]
    pub window: u64,
}

/// One panel: a title, points (iteration, value), and whether the value axis is logarithmic.
pub struct Panel {
    /// The panel's title.
    pub title: &'static str,
    /// (iteration, value) in iteration order; non-finite values (and, on a log axis,
    /// non-positive ones) already left out.
    pub points: Vec<(f64, f64)>,
    /// A logarithmic value axis.
    pub log: bool,
}

/// The objects of a JSON-lines file (lines that do not parse are skipped and counted).
fn read_lines(path: &Path) -> Result<(Vec<Value>, usize)> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    let mut bad = 0;
    let rows = text
        .lines()
        .filter(|l| !l.trim().is_empty())
        .filter_map(|l| json::parse_lenient(l).map_err(|_| bad += 1).ok())
        .collect();
    Ok((rows, bad))
}

fn field(v: &Value, key: &str) -> f64 {
    v.get(key).and_then(json::number).unwrap_or(f64::NAN)
}

/// The three panels from the lines of `validation.jsonl` and `log.jsonl`: the training loss is
/// the median, per window of `window` iterations, of the per-vertex objective of the regular
/// steps (no start-up step, none skipped).
pub fn panels(validation: &[Value], log: &[Value], window: u64) -> Vec<Panel> {
    let it = |v: &Value| v.get("iteration").and_then(Value::as_u64);
    let series = |key: &str, log_axis: bool| -> Vec<(f64, f64)> {
        validation
            .iter()
            .filter_map(|v| Some((it(v)? as f64, field(v, key))))
            .filter(|&(_, y)| y.is_finite() && (!log_axis || y > 0.0))
            .collect()
    };
    let window = window.max(1);
    let mut windows: std::collections::BTreeMap<u64, Vec<f64>> = Default::default();
    for r in log {
        let (Some(i), Some(steps)) = (it(r), r.get("steps").and_then(Value::as_array)) else { continue };
        let vertices = field(r, "vertices").max(1.0);
        for s in steps {
            let flag = |k: &str| s.get(k).and_then(Value::as_bool).unwrap_or(false);
            let per_vertex = field(s, "total") / vertices;
            if !flag("startup") && !flag("skipped") && per_vertex.is_finite() && per_vertex > 0.0 {
                windows.entry(i / window).or_default().push(per_vertex);
            }
        }
    }
    let loss = windows
        .into_iter()
        .map(|(k, mut v)| {
            v.sort_by(f64::total_cmp);
            ((k * window) as f64, v[v.len() / 2])
        })
        .collect();
    vec![
        Panel { title: "validation objective (J, log)", points: series("mean_total", true), log: true },
        Panel { title: "validation % penetrating", points: series("mean_penetrating_percent", false), log: false },
        Panel { title: "training loss per vertex, regular steps (J, median per window, log)", points: loss, log: true },
    ]
}

/// Draws `panels` one above the other into an SVG file at `out`.
///
/// # Errors
/// [`Error::Io`] naming `out` when the drawing or the file fails.
pub fn draw(panels: &[Panel], out: &Path) -> Result<()> {
    let fail = |e: &dyn std::fmt::Display| Error::Io { path: out.display().to_string(), message: e.to_string() };
    let root = SVGBackend::new(out, (900, 260 * panels.len() as u32)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| fail(&e))?;
    let xmax = panels.iter().flat_map(|p| p.points.iter().map(|q| q.0)).fold(1.0, f64::max);
    for (area, panel) in root.split_evenly((panels.len(), 1)).iter().zip(panels) {
        let ys: Vec<f64> = panel.points.iter().map(|&(_, y)| if panel.log { y.log10() } else { y }).collect();
        let (lo, hi) = ys.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &y| (a.min(y), b.max(y)));
        let (lo, hi) = if lo.is_finite() { (lo, if hi > lo { hi } else { lo + 1.0 }) } else { (0.0, 1.0) };
        let pad = 0.05 * (hi - lo);
        let mut chart = ChartBuilder::on(area)
            .caption(panel.title, ("sans-serif", 14))
            .margin(10)
            .x_label_area_size(30)
            .y_label_area_size(70)
            .build_cartesian_2d(0.0..xmax, lo - pad..hi + pad)
            .map_err(|e| fail(&e))?;
        let log = panel.log;
        chart
            .configure_mesh()
            .x_desc("iteration")
            .x_label_formatter(&|x| format!("{x:.0}"))
            .y_label_formatter(&|y| significant(if log { 10f64.powf(*y) } else { *y }))
            .draw()
            .map_err(|e| fail(&e))?;
        let points = panel.points.iter().zip(&ys).map(|(&(x, _), &y)| (x, y));
        chart.draw_series(LineSeries::new(points, RGBColor(42, 111, 191).stroke_width(2))).map_err(|e| fail(&e))?;
    }
    root.present().map_err(|e| fail(&e))
}

/// `v` to 3 significant digits: plain from 0.001 to 9,999, else in exponent form.
fn significant(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let e = v.abs().log10().floor() as i32;
    if (-3..4).contains(&e) {
        format!("{v:.*}", (2 - e).max(0) as usize)
    } else {
        format!("{v:.2e}")
    }
}

/// Runs `hood plot`.
pub fn plot(a: PlotArgs) -> Result<()> {
    let (validation, bad_v) = read_lines(&a.dir.join("validation.jsonl"))?;
    let (log, bad_l) = read_lines(&a.dir.join("log.jsonl"))?;
    if bad_v + bad_l > 0 {
        eprintln!("skipped {} lines that are not JSON", bad_v + bad_l);
    }
    let out = a.out.clone().unwrap_or_else(|| a.dir.join("training.svg"));
    draw(&panels(&validation, &log, a.window), &out)?;
    say!("wrote {}", out.display());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lines(text: &str) -> Vec<Value> {
        text.lines().map(|l| json::parse_lenient(l).unwrap()).collect()
    }

    #[test]
    fn panels_take_medians_per_window_and_leave_out_non_finite_values() {
        let validation = lines(concat!(
            "{\"iteration\":500,\"finite\":true,\"mean_total\":2.0,\"mean_penetrating_percent\":1.5,\"rollouts\":[]}\n",
            "{\"iteration\":1000,\"finite\":false,\"mean_total\":null,\"mean_penetrating_percent\":NaN,\"rollouts\":[]}\n",
        ));
        let step =
            |total: &str, startup: bool| format!("{{\"total\":{total},\"startup\":{startup},\"skipped\":false}}");
        let log = lines(&format!(
            "{{\"iteration\":1,\"vertices\":10,\"steps\":[{},{},{}]}}\n{{\"iteration\":2,\"vertices\":10,\"steps\":[{}]}}\n{{\"iteration\":300,\"vertices\":2,\"steps\":[{}]}}",
            step("100", true),
            step("10", false),
            step("30", false),
            step("20", false),
            step("null", false),
        ));
        let p = panels(&validation, &log, 250);
        assert_eq!(p[0].points, [(500.0, 2.0)]);
        assert_eq!(p[1].points, [(500.0, 1.5)]);
        // Window 0: per-vertex 1, 3, 2 (the start-up step left out): median 2; window 1: none finite.
        assert_eq!(p[2].points, [(0.0, 2.0)]);
    }

    #[test]
    fn labels_have_three_significant_digits() {
        assert_eq!(significant(0.0034567), "0.00346");
        assert_eq!(significant(158.489), "158");
        assert_eq!(significant(1.35), "1.35");
        assert_eq!(significant(2.5e-5), "2.50e-5");
        assert_eq!(significant(0.0), "0");
    }

    #[test]
    fn draw_writes_an_svg_with_every_title() {
        let dir = std::env::temp_dir().join(format!("hood-plot-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let out = dir.join("t.svg");
        let p = vec![
            Panel { title: "one", points: vec![(0.0, 1e-3), (100.0, 1e-4)], log: true },
            Panel { title: "two", points: vec![], log: false },
        ];
        draw(&p, &out).unwrap();
        let svg = std::fs::read_to_string(&out).unwrap();
        assert!(svg.starts_with("<svg") && svg.contains("one") && svg.contains("two"), "{svg}");
        assert!(svg.contains("<polyline"), "the line is drawn");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
