//! Grouped bar charts with error bars: one group per category (e.g. a system), one bar per series (e.g. a
//! reconstruction operator) of height `mean` with a ± `std` whisker — the study's PSNR figure.
//!
//! ```
//! use diffcassi::plot::{grouped_bars, png_dimensions, BarSeries, BAR_PLOT_SIZE};
//! # fn main() -> Result<(), diffcassi::plot::PlotError> {
//! let path = std::env::temp_dir().join(format!("diffcassi_bars_doc_{}.png", std::process::id()));
//! let groups = vec!["AP".to_string(), "SP".to_string()];
//! let series = vec![
//!     BarSeries { label: "exact".into(), mean: vec![30.0, 29.5], std: vec![1.0, 1.2] },
//!     BarSeries { label: "shift".into(), mean: vec![29.0, 20.0], std: vec![1.0, 2.0] },
//! ];
//! grouped_bars(&path, "PSNR", "PSNR (dB)", &groups, &series)?;
//! assert_eq!(png_dimensions(&path)?, BAR_PLOT_SIZE);
//! # std::fs::remove_file(&path).ok();
//! # Ok(())
//! # }
//! ```
use std::path::Path;

use plotters::prelude::*;

use super::colors::palette;
use super::{check_finite, font, render, PlotError, LABEL_SIZE, TICK_SIZE, TITLE_SIZE};

/// Image size of [`grouped_bars`] in pixels.
pub const BAR_PLOT_SIZE: (u32, u32) = (1000, 650);

/// One series of bars: a value (and its spread) per group.
#[derive(Clone, Debug)]
pub struct BarSeries {
    pub label: String,
    pub mean: Vec<f64>,
    /// Whisker half-length (e.g. the standard deviation); 0 draws none.
    pub std: Vec<f64>,
}

/// Draw the grouped bar chart to the PNG `path`. The y axis starts at 0 (or below the smallest bar if negative).
pub fn grouped_bars(path: impl AsRef<Path>, title: &str, y_label: &str, groups: &[String], series: &[BarSeries]) -> Result<(), PlotError> {
    if groups.is_empty() || series.is_empty() {
        return Err(PlotError::Empty { what: "bar plot: groups or series".into() });
    }
    for s in series {
        if s.mean.len() != groups.len() || s.std.len() != groups.len() {
            return Err(PlotError::InvalidArgument(format!("bar plot: series '{}' has {} means and {} stds for {} groups", s.label, s.mean.len(), s.std.len(), groups.len())));
        }
        check_finite(|| format!("bar plot: series '{}' mean", s.label), &s.mean)?;
        check_finite(|| format!("bar plot: series '{}' std", s.label), &s.std)?;
    }
    let hi = series.iter().flat_map(|s| s.mean.iter().zip(&s.std).map(|(m, d)| m + d.abs())).fold(f64::MIN, f64::max);
    let lo = series.iter().flat_map(|s| s.mean.iter().zip(&s.std).map(|(m, d)| m - d.abs())).fold(0.0, f64::min);
    let span = (hi - lo).max(1e-9);
    let (y_lo, y_hi) = (if lo < 0.0 { lo - 0.05 * span } else { 0.0 }, hi + 0.12 * span);
    let n = series.len() as f64;
    let width = 0.8 / n;
    render(path.as_ref(), BAR_PLOT_SIZE, |root| {
        let mut chart = ChartBuilder::on(root)
            .caption(title, font(TITLE_SIZE))
            .margin(15)
            .margin_right(30)
            .x_label_area_size(45)
            .y_label_area_size(80)
            .build_cartesian_2d(-0.5f64..groups.len() as f64 - 0.5, y_lo..y_hi)?;
        let g = groups.to_vec();
        chart
            .configure_mesh()
            .x_labels(groups.len() * 2 + 1)
            .x_label_formatter(&move |x: &f64| {
                let r = x.round();
                if (x - r).abs() < 1e-6 && r >= 0.0 && (r as usize) < g.len() { g[r as usize].clone() } else { String::new() }
            })
            .disable_x_mesh()
            .y_desc(y_label)
            .axis_desc_style(font(LABEL_SIZE))
            .label_style(font(TICK_SIZE))
            .bold_line_style(BLACK.mix(0.10))
            .light_line_style(TRANSPARENT)
            .draw()?;
        for (i, s) in series.iter().enumerate() {
            let color = palette(i);
            let x_of = |k: usize| k as f64 - 0.4 + width * (i as f64 + 0.5);
            chart
                .draw_series(s.mean.iter().enumerate().map(|(k, &m)| Rectangle::new([(x_of(k) - 0.45 * width, 0.0f64.max(y_lo)), (x_of(k) + 0.45 * width, m)], color.filled())))?
                .label(s.label.as_str())
                .legend(move |(lx, ly)| Rectangle::new([(lx, ly - 6), (lx + 18, ly + 6)], color.filled()));
            // Whiskers: a vertical line m ± d with short caps.
            for (k, (&m, &d)) in s.mean.iter().zip(&s.std).enumerate().filter(|(_, (_, d))| **d > 0.0) {
                let (x, cap) = (x_of(k), 0.15 * width);
                for line in [vec![(x, m - d), (x, m + d)], vec![(x - cap, m - d), (x + cap, m - d)], vec![(x - cap, m + d), (x + cap, m + d)]] {
                    chart.draw_series(std::iter::once(PathElement::new(line, BLACK.stroke_width(1))))?;
                }
            }
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .margin(12)
            .label_font(font(LABEL_SIZE))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK.mix(0.4))
            .draw()?;
        Ok(())
    })
}
