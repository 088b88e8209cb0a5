//! The speed/accuracy frontier: one log-log panel per workload, error (µm) against throughput, one
//! labelled point per configuration. Errors of exactly 0 (the reference itself, or a model that
//! reproduces it bit for bit) cannot sit on a log axis: they are drawn on a floor line labelled "0 (exact)".
//!
//! ```
//! use diffcassi::plot::{frontier_plot, FrontierPoint, png_dimensions, FRONTIER_PANEL_SIZE};
//! let p = |label: &str, t: f64, e: f64| FrontierPoint { label: label.into(), throughput: t, error_um: e };
//! let path = std::env::temp_dir().join(format!("diffcassi_frontier_doc_{}.png", std::process::id()));
//! frontier_plot(&path, "frontier", "M rays/s", &[("rays".into(), vec![p("analytic", 2.0, 0.0), p("mesh", 0.3, 0.9)])]).unwrap();
//! assert_eq!(png_dimensions(&path).unwrap(), (FRONTIER_PANEL_SIZE.0, FRONTIER_PANEL_SIZE.1 + 60));
//! # std::fs::remove_file(&path).ok();
//! ```
use std::path::Path;

use plotters::prelude::*;

use super::{draw_centered, fmt_sig, font, render, PlotError, LABEL_SIZE, TICK_SIZE, TITLE_SIZE};

/// Size of one panel (pixels); panels are stacked vertically under a 60 px title.
pub const FRONTIER_PANEL_SIZE: (u32, u32) = (1200, 640);

/// One configuration on the frontier.
#[derive(Clone, Debug)]
pub struct FrontierPoint {
    pub label: String,
    /// Throughput in the panel's unit (e.g. M rays/s); must be finite and > 0.
    pub throughput: f64,
    /// Error (µm); finite and ≥ 0 (0 is drawn on the floor).
    pub error_um: f64,
}

const COLORS: [RGBColor; 6] = [RGBColor(31, 119, 180), RGBColor(214, 39, 40), RGBColor(44, 160, 44), RGBColor(148, 103, 189), RGBColor(255, 127, 14), RGBColor(140, 86, 75)];

/// Draw one panel per `(workload name, points)` into `path` (PNG).
pub fn frontier_plot(path: impl AsRef<Path>, title: &str, x_label: &str, panels: &[(String, Vec<FrontierPoint>)]) -> Result<(), PlotError> {
    if panels.is_empty() || panels.iter().any(|p| p.1.is_empty()) {
        return Err(PlotError::Empty { what: "frontier plot: panels".into() });
    }
    for (name, pts) in panels {
        for (i, p) in pts.iter().enumerate() {
            if !(p.throughput.is_finite() && p.throughput > 0.0) {
                return Err(PlotError::NonFinite { what: format!("frontier plot: {name} throughput"), index: i, value: p.throughput });
            }
            if !(p.error_um.is_finite() && p.error_um >= 0.0) {
                return Err(PlotError::NonFinite { what: format!("frontier plot: {name} error_um"), index: i, value: p.error_um });
            }
        }
    }
    let (w, ph) = FRONTIER_PANEL_SIZE;
    let size = (w, ph * panels.len() as u32 + 60);
    render(path.as_ref(), size, |root| {
        draw_centered(root, title, &font(TITLE_SIZE), w as i32 / 2, 14)?;
        for (k, (name, pts)) in panels.iter().enumerate() {
            let area = root.clone().shrink((0, 60 + k as u32 * ph), (w, ph));
            let nonzero: Vec<f64> = pts.iter().map(|p| p.error_um).filter(|e| *e > 0.0).collect();
            let emax = nonzero.iter().cloned().fold(1e-3, f64::max);
            let emin = nonzero.iter().cloned().fold(emax, f64::min);
            let floor = (emin / 100.0).min(1e-12);
            let (tmin, tmax) = pts.iter().fold((f64::INFINITY, 0.0f64), |(a, b), p| (a.min(p.throughput), b.max(p.throughput)));
            let mut chart = ChartBuilder::on(&area)
                .caption(format!("{name}: max error vs throughput (log-log)"), font(LABEL_SIZE + 2.0))
                .margin(14)
                .margin_right(40)
                .x_label_area_size(50)
                .y_label_area_size(95)
                .build_cartesian_2d((tmin / 2.0..tmax * 2.0).log_scale(), (floor / 3.0..emax * 5.0).log_scale())?;
            chart
                .configure_mesh()
                .x_desc(x_label)
                .y_desc("max error vs analytic f64 (µm)")
                .x_label_formatter(&|v| fmt_sig(*v, 3))
                .y_label_formatter(&|v| format!("{v:.0e}"))
                .axis_desc_style(font(LABEL_SIZE))
                .label_style(font(TICK_SIZE))
                .bold_line_style(BLACK.mix(0.10))
                .light_line_style(TRANSPARENT)
                .draw()?;
            chart.draw_series(DashedLineSeries::new([(tmin / 2.0, floor), (tmax * 2.0, floor)], 6, 4, RGBColor(120, 120, 120).stroke_width(1)))?;
            chart.draw_series(std::iter::once(Text::new("0 (exact)", (tmin / 1.9, floor * 1.6), font(TICK_SIZE))))?;
            let at = |p: &FrontierPoint| (p.throughput, if p.error_um > 0.0 { p.error_um } else { floor });
            // One decade of the error axis is about (panel height / decades) px: stack the labels of
            // points that nearly coincide one text line apart.
            let line = 10f64.powf(16.0 * (emax * 5.0 / (floor / 3.0)).log10() / (ph as f64 - 130.0));
            for (i, p) in pts.iter().enumerate() {
                let (t, e) = at(p);
                let c = COLORS[i % COLORS.len()];
                chart.draw_series(std::iter::once(Circle::new((t, e), 6, c.filled())))?;
                let near = pts[..i].iter().filter(|q| {
                    let (tq, eq) = at(q);
                    (tq / t).max(t / tq) < 1.6 && (eq / e).max(e / eq) < line * 2.0
                });
                let k = near.count() as i32;
                chart.draw_series(std::iter::once(Text::new(p.label.clone(), (t * 1.04, e * line.powi(1 - 2 * k) ), font(12.0).color(&c))))?;
            }
        }
        Ok(())
    })
}
