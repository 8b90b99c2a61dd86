//! The report's figure: the relative objective gap against ms per step, as SVG.

use super::Row;
use std::fmt::Write as _;

/// Gap (mean, with a bar to the 95th percentile) against ms/step on a log axis.
pub(super) fn svg_plot(rows: &[Row]) -> String {
    let (w, h) = (760.0f64, 460.0f64);
    let (l, r, t, b) = (70.0, 230.0, 30.0, 50.0);
    let pts: Vec<(&Row, f64, f64, f64)> = rows
        .iter()
        .filter_map(|row| {
            let s = &row.summary;
            Some((row, s.median_step_ms.max(1e-3), s.gap_mean?, s.gap_p95.unwrap_or(s.gap_mean?)))
        })
        .collect();
    let lx = |v: f64| v.log10();
    let (mut x0, mut x1) = pts.iter().fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(lx(p.1)), b.max(lx(p.1))));
    if pts.is_empty() {
        (x0, x1) = (0.0, 1.0);
    }
    let (x0, x1) = (x0.floor(), x1.ceil().max(x0.floor() + 1.0));
    let y1 = pts.iter().map(|p| p.3).fold(1.1f64, f64::max).min(3.0);
    let px = |v: f64| l + (lx(v) - x0) / (x1 - x0) * (w - l - r);
    let py = |g: f64| t + (1.0 - g.clamp(0.0, y1) / y1) * (h - t - b);
    let mut s = String::new();
    let _ = writeln!(
        s,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" font-family="sans-serif" font-size="11">"#
    );
    let _ = writeln!(s, r#"<rect width="{w}" height="{h}" fill="white"/>"#);
    // Axes and grid.
    for e in (x0 as i32)..=(x1 as i32) {
        let x = px(10f64.powi(e));
        let _ = writeln!(s, r##"<line x1="{x:.1}" y1="{t}" x2="{x:.1}" y2="{}" stroke="#ddd"/>"##, h - b);
        let _ = writeln!(s, r#"<text x="{x:.1}" y="{}" text-anchor="middle">{}</text>"#, h - b + 16.0, 10f64.powi(e));
    }
    let mut g = 0.0;
    while g <= y1 + 1e-9 {
        let y = py(g);
        let _ = writeln!(s, r##"<line x1="{l}" y1="{y:.1}" x2="{}" y2="{y:.1}" stroke="#ddd"/>"##, w - r);
        let _ = writeln!(s, r#"<text x="{}" y="{:.1}" text-anchor="end">{g:.1}</text>"#, l - 6.0, y + 4.0);
        g += 0.2;
    }
    let _ = writeln!(
        s,
        r#"<rect x="{l}" y="{t}" width="{}" height="{}" fill="none" stroke="black"/>"#,
        w - l - r,
        h - t - b
    );
    let _ = writeln!(
        s,
        r#"<text x="{}" y="{}" text-anchor="middle">ms per step (log)</text>"#,
        l + (w - l - r) / 2.0,
        h - 12.0
    );
    let _ = writeln!(
        s,
        r#"<text x="16" y="{}" text-anchor="middle" transform="rotate(-90 16 {})">relative objective gap (mean, bar to p95)</text>"#,
        t + (h - t - b) / 2.0,
        t + (h - t - b) / 2.0
    );
    // Points: colour per workload; squares for the implicit solver, circles for models.
    const COLOURS: [&str; 5] = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e"];
    let mut workloads: Vec<&str> = Vec::new();
    for row in rows {
        if !workloads.contains(&row.workload.as_str()) {
            workloads.push(&row.workload);
        }
    }
    for (i, (row, ms, mean, p95)) in pts.iter().enumerate() {
        let c = COLOURS[workloads.iter().position(|w| *w == row.workload).unwrap_or(0) % COLOURS.len()];
        let (x, y, yp) = (px(*ms), py(*mean), py(*p95));
        let _ = writeln!(s, r#"<line x1="{x:.1}" y1="{y:.1}" x2="{x:.1}" y2="{yp:.1}" stroke="{c}"/>"#);
        if row.implicit {
            let _ = writeln!(s, r#"<rect x="{:.1}" y="{:.1}" width="7" height="7" fill="{c}"/>"#, x - 3.5, y - 3.5);
        } else {
            let _ = writeln!(s, r#"<circle cx="{x:.1}" cy="{y:.1}" r="4" fill="{c}"/>"#);
        }
        let _ = writeln!(s, r#"<text x="{:.1}" y="{:.1}" fill="{c}" font-size="9">{}</text>"#, x + 6.0, y - 4.0, i + 1);
    }
    // Legend: numbered variants.
    for (i, (row, ..)) in pts.iter().enumerate() {
        let c = COLOURS[workloads.iter().position(|w| *w == row.workload).unwrap_or(0) % COLOURS.len()];
        let _ = writeln!(
            s,
            r#"<text x="{}" y="{:.1}" fill="{c}" font-size="9">{}: {} {}</text>"#,
            w - r + 10.0,
            t + 10.0 + 11.0 * i as f64,
            i + 1,
            row.workload,
            row.variant
        );
    }
    s.push_str("</svg>\n");
    s
}
