//! Spot diagrams: one square panel per field, points coloured by wavelength.
//!
//! Each panel shows ray positions in µm relative to the panel's centroid (the unweighted mean of
//! all its points, all wavelengths together, like Zemax's "reference: centroid"), with equal x/y
//! scales. All panels share the same scale so spot sizes can be compared between fields. Under the
//! panel label, the RMS spot radius and the GEO radius (largest distance to the centroid) are
//! printed together with the absolute centroid position.
//!
//! Series colours come from the wavelength in the series label (see
//! [`parse_wavelength_nm`]: `"450 nm"`, `"0.45 µm"`...); labels
//! without a wavelength get distinct palette colours. Series with the same label in different
//! panels get the same colour and one legend entry.
//!
//! A panel without any point is drawn with a "no rays" note; the plot is an error only if there
//! are no panels or no points at all.
//!
//! # Example
//!
//! ```
//! use diffcassi::plot::{png_dimensions, spot_diagram, spot_diagram_size, SpotPanel, SpotSeries};
//!
//! # fn main() -> Result<(), diffcassi::plot::PlotError> {
//! let ring = |r: f64, cx: f64| -> (Vec<f64>, Vec<f64>) {
//!     (0..64).map(|i| {
//!         let t = i as f64 / 64.0 * std::f64::consts::TAU;
//!         (cx + r * t.cos(), r * t.sin())
//!     }).unzip()
//! };
//! let panels: Vec<SpotPanel> = [(0.0, "F1 (0, 0) mm"), (2500.0, "F2 (2.5, 0) mm")]
//!     .iter()
//!     .map(|&(cx, label)| SpotPanel {
//!         label: label.to_string(),
//!         series: [(450.0, 3.0), (650.0, 5.0)]
//!             .iter()
//!             .map(|&(nm, r)| {
//!                 let (x_um, y_um) = ring(r, cx);
//!                 SpotSeries { label: format!("{nm} nm"), x_um, y_um }
//!             })
//!             .collect(),
//!     })
//!     .collect();
//! let path = std::env::temp_dir().join(format!("diffcassi_spot_doc_{}.png", std::process::id()));
//! spot_diagram(&path, "Spot diagram", &panels)?;
//! assert_eq!(png_dimensions(&path)?, spot_diagram_size(&panels));
//! # std::fs::remove_file(&path).ok();
//! # Ok(())
//! # }
//! ```

use std::path::Path;

use plotters::prelude::*;
use plotters::style::text_anchor;

use super::colors::{palette, parse_wavelength_nm, wavelength_to_plot_rgb};
use super::{
    check_finite, check_range, check_same_len, draw_centered, fmt_fixed, fmt_sig, font, render,
    tick_formatter, Area, PlotError, LABEL_SIZE, TICK_SIZE, TITLE_SIZE,
};

/// One field of a spot diagram.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SpotPanel {
    /// Panel caption, e.g. `"F2 (2.5, 0) mm"`.
    pub label: String,
    /// One series per wavelength.
    pub series: Vec<SpotSeries>,
}

/// The ray positions of one wavelength in one panel.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SpotSeries {
    /// Legend label, e.g. `"450 nm"`; a wavelength in it selects the colour.
    pub label: String,
    /// Image-plane x positions (µm, any origin: the panel centroid is subtracted).
    pub x_um: Vec<f64>,
    /// Image-plane y positions (µm), same length as `x_um`.
    pub y_um: Vec<f64>,
}

const TITLE_H: u32 = 48;
const CAPTION_H: u32 = 66;
const MARGIN: u32 = 12;
const Y_LABEL_W: u32 = 78;
const X_LABEL_H: u32 = 48;
/// Side of the square plotting area of each panel, in pixels.
const PLOT_PX: u32 = 320;
const CELL_W: u32 = Y_LABEL_W + PLOT_PX + 2 * MARGIN;
const CELL_H: u32 = CAPTION_H + PLOT_PX + X_LABEL_H + 2 * MARGIN;
const LEGEND_ROW_H: u32 = 28;
const LEGEND_PAD: u32 = 12;

fn grid(n: usize) -> (u32, u32) {
    let n = n.max(1) as u32;
    let cols = if n <= 3 {
        n
    } else {
        (n as f64).sqrt().ceil() as u32
    };
    (cols, n.div_ceil(cols))
}

/// Distinct series labels in order of first appearance.
fn legend_labels(panels: &[SpotPanel]) -> Vec<&str> {
    let mut labels: Vec<&str> = Vec::new();
    for s in panels.iter().flat_map(|p| &p.series) {
        if !labels.contains(&s.label.as_str()) {
            labels.push(&s.label);
        }
    }
    labels
}

/// Legend layout: (slot width, items per row, rows).
fn legend_layout(labels: &[&str], width: u32) -> (u32, u32, u32) {
    let longest = labels.iter().map(|l| l.chars().count()).max().unwrap_or(0) as u32;
    let slot = (longest * 9 + 44).clamp(110, width.max(110));
    let per_row = (width.saturating_sub(2 * LEGEND_PAD) / slot).max(1);
    let rows = (labels.len() as u32).div_ceil(per_row);
    (slot, per_row, rows)
}

/// The pixel size of the image [`spot_diagram`] draws for these panels: panels of
/// 422 × 478 px in a grid (one row up to 3 panels, otherwise ⌈√n⌉ columns), a 48 px title band
/// and a legend band of 28 px per row of legend entries.
pub fn spot_diagram_size(panels: &[SpotPanel]) -> (u32, u32) {
    let (cols, rows) = grid(panels.len());
    let width = cols * CELL_W;
    let (_, _, legend_rows) = legend_layout(&legend_labels(panels), width);
    let legend_h = legend_rows * LEGEND_ROW_H + 2 * LEGEND_PAD;
    (width, TITLE_H + rows * CELL_H + legend_h)
}

/// Smallest "nice" number (1, 1.5, 2, 2.5, 3, 4, 5, 6, 8 × 10^k) ≥ `v` (`v` > 0).
fn nice_ceil(v: f64) -> f64 {
    let m = 10f64.powf(v.log10().floor());
    for k in [1.0, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0] {
        if k * m >= v * (1.0 - 1e-12) {
            return k * m;
        }
    }
    10.0 * m
}

struct PanelStats {
    cx: f64,
    cy: f64,
    rms: f64,
    geo: f64,
    /// Largest |dx| or |dy| from the centroid.
    half_width: f64,
    n: usize,
}

fn panel_stats(p: &SpotPanel) -> Option<PanelStats> {
    let n: usize = p.series.iter().map(|s| s.x_um.len()).sum();
    if n == 0 {
        return None;
    }
    let pts = || p.series.iter().flat_map(|s| s.x_um.iter().zip(&s.y_um));
    let (sx, sy) = pts().fold((0.0, 0.0), |(a, b), (x, y)| (a + x, b + y));
    let (cx, cy) = (sx / n as f64, sy / n as f64);
    let (mut r2, mut geo, mut hw) = (0.0f64, 0.0f64, 0.0f64);
    for (x, y) in pts() {
        let (dx, dy) = (x - cx, y - cy);
        let d2 = dx * dx + dy * dy;
        r2 += d2;
        geo = geo.max(d2.sqrt());
        hw = hw.max(dx.abs()).max(dy.abs());
    }
    Some(PanelStats {
        cx,
        cy,
        rms: (r2 / n as f64).sqrt(),
        geo,
        half_width: hw,
        n,
    })
}

/// Draw a spot diagram (see the [module documentation](self)) to the PNG file `path`.
pub fn spot_diagram(
    path: impl AsRef<Path>,
    title: &str,
    panels: &[SpotPanel],
) -> Result<(), PlotError> {
    if panels.is_empty() {
        return Err(PlotError::Empty {
            what: "spot diagram: the list of panels".to_string(),
        });
    }
    for p in panels {
        for s in &p.series {
            let what = |axis: &str| {
                format!(
                    "spot diagram: panel '{}', series '{}' {axis}",
                    p.label, s.label
                )
            };
            check_same_len(|| what(""), "x_um", s.x_um.len(), "y_um", s.y_um.len())?;
            check_finite(|| what("x_um"), &s.x_um)?;
            check_finite(|| what("y_um"), &s.y_um)?;
        }
    }
    let stats: Vec<Option<PanelStats>> = panels.iter().map(panel_stats).collect();
    if stats.iter().all(Option::is_none) {
        return Err(PlotError::Empty {
            what: "spot diagram: every panel's point list".to_string(),
        });
    }
    let max_hw = stats
        .iter()
        .flatten()
        .map(|s| s.half_width)
        .fold(0.0, f64::max);
    let r = if max_hw > 0.0 {
        // At least ±1 pm, so numerically identical points still give a usable axis.
        nice_ceil((max_hw * 1.04).max(1e-6))
    } else {
        1.0
    };
    check_range("spot diagram: x/y about the centroid (µm)", -r, r)?;
    for (p, st) in panels.iter().zip(&stats) {
        if let Some(st) = st {
            if !(st.cx.is_finite() && st.cy.is_finite() && st.rms.is_finite()) {
                return Err(PlotError::InvalidArgument(format!(
                    "spot diagram: panel '{}': coordinates too large (centroid/RMS overflow)",
                    p.label
                )));
            }
        }
    }

    let labels = legend_labels(panels);
    let color_of = |label: &str| -> RGBColor {
        match parse_wavelength_nm(label) {
            Some(nm) => wavelength_to_plot_rgb(nm),
            None => palette(labels.iter().position(|l| *l == label).unwrap_or(0)),
        }
    };

    let size = spot_diagram_size(panels);
    let (cols, _) = grid(panels.len());
    render(path.as_ref(), size, |root| {
        draw_centered(root, title, &font(TITLE_SIZE), size.0 as i32 / 2, 12)?;
        for (k, (panel, st)) in panels.iter().zip(&stats).enumerate() {
            let (col, row) = (k as u32 % cols, k as u32 / cols);
            let (x0, y0) = (col * CELL_W, TITLE_H + row * CELL_H);
            let cell = root.clone().shrink((x0, y0), (CELL_W, CELL_H));
            draw_panel(&cell, panel, st.as_ref(), r, &color_of)?;
        }
        // Legend band.
        let legend_y = TITLE_H + grid(panels.len()).1 * CELL_H;
        let (slot, per_row, _) = legend_layout(&labels, size.0);
        let used = per_row.min(labels.len() as u32) * slot;
        let x_start = (size.0.saturating_sub(used) / 2) as i32;
        for (i, label) in labels.iter().enumerate() {
            let (c, rw) = (i as u32 % per_row, i as u32 / per_row);
            let x = x_start + (c * slot) as i32;
            let y = (legend_y + LEGEND_PAD + rw * LEGEND_ROW_H) as i32 + LEGEND_ROW_H as i32 / 2;
            root.draw(&Circle::new((x + 12, y), 6, color_of(label).filled()))?;
            root.draw_text(
                label,
                &font(LABEL_SIZE).pos(text_anchor::Pos::new(
                    text_anchor::HPos::Left,
                    text_anchor::VPos::Center,
                )),
                (x + 26, y),
            )?;
        }
        Ok(())
    })
}

fn draw_panel(
    cell: &Area<'_>,
    panel: &SpotPanel,
    st: Option<&PanelStats>,
    r: f64,
    color_of: &dyn Fn(&str) -> RGBColor,
) -> Result<(), PlotError> {
    let cx = CELL_W as i32 / 2 + (Y_LABEL_W as i32 - MARGIN as i32) / 2;
    draw_centered(cell, &panel.label, &font(LABEL_SIZE + 2.0), cx, 6)?;
    let small = font(TICK_SIZE);
    match st {
        Some(st) => {
            let line = format!(
                "RMS {} µm · GEO {} µm · {} pts",
                fmt_sig(st.rms, 3),
                fmt_sig(st.geo, 3),
                st.n
            );
            draw_centered(cell, &line, &small, cx, 28)?;
            let c = format!(
                "centroid ({}, {}) µm",
                fmt_fixed(st.cx, 2),
                fmt_fixed(st.cy, 2)
            );
            draw_centered(cell, &c, &small.color(&RGBColor(90, 90, 90)), cx, 46)?;
        }
        None => draw_centered(cell, "no rays", &small, cx, 28)?,
    }

    let area = cell
        .clone()
        .shrink((0, CAPTION_H), (CELL_W, CELL_H - CAPTION_H));
    let mut chart = ChartBuilder::on(&area)
        .margin(MARGIN)
        .x_label_area_size(X_LABEL_H)
        .y_label_area_size(Y_LABEL_W)
        .build_cartesian_2d(-r..r, -r..r)?;
    let fmt = tick_formatter(-r, r, 5);
    chart
        .configure_mesh()
        .x_labels(5)
        .y_labels(5)
        .x_label_formatter(&fmt)
        .y_label_formatter(&fmt)
        .x_desc("x − centroid (µm)")
        .y_desc("y − centroid (µm)")
        .axis_desc_style(font(TICK_SIZE))
        .label_style(font(TICK_SIZE))
        .bold_line_style(BLACK.mix(0.10))
        .light_line_style(TRANSPARENT)
        .draw()?;
    // Cross-hair through the centroid.
    let guide = RGBColor(150, 150, 150).stroke_width(1);
    chart.draw_series([
        PathElement::new(vec![(-r, 0.0), (r, 0.0)], guide),
        PathElement::new(vec![(0.0, -r), (0.0, r)], guide),
    ])?;
    if let Some(st) = st {
        // Small dots for dense spots so the ray pattern stays visible.
        let radius = if st.n > 1500 { 1 } else { 2 };
        for s in &panel.series {
            let color = color_of(&s.label).mix(0.8).filled();
            chart.draw_series(
                s.x_um
                    .iter()
                    .zip(&s.y_um)
                    .map(|(x, y)| Circle::new((x - st.cx, y - st.cy), radius, color)),
            )?;
        }
    }
    debug_assert_eq!(chart.plotting_area().dim_in_pixel(), (PLOT_PX, PLOT_PX));
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::super::test_util::assert_png;
    use super::*;

    fn ring(n: usize, r: f64, cx: f64, cy: f64) -> (Vec<f64>, Vec<f64>) {
        (0..n)
            .map(|i| {
                let t = i as f64 / n as f64 * std::f64::consts::TAU;
                (cx + r * t.cos(), cy + r * t.sin() * 0.7)
            })
            .unzip()
    }

    fn panels(n: usize) -> Vec<SpotPanel> {
        (0..n)
            .map(|f| SpotPanel {
                label: format!("F{} ({}, 0) mm", f + 1, f as f64 * 2.5),
                series: [450.0, 520.0, 650.0]
                    .iter()
                    .enumerate()
                    .map(|(k, nm)| {
                        let (x_um, y_um) = ring(
                            300,
                            2.0 + k as f64 * 1.5 + f as f64,
                            -3000.0 * f as f64 + k as f64,
                            10.0,
                        );
                        SpotSeries {
                            label: format!("{nm} nm"),
                            x_um,
                            y_um,
                        }
                    })
                    .collect(),
            })
            .collect()
    }

    #[test]
    fn writes_png_of_expected_size() {
        let tmp = tempfile::tempdir().unwrap();
        for n in [1, 3, 4, 5] {
            let p = tmp.path().join(format!("spot{n}.png"));
            let ps = panels(n);
            spot_diagram(&p, "Spot diagram — SP, 450/520/650 nm", &ps).unwrap();
            let size = spot_diagram_size(&ps);
            assert_png(&p, size);
            let (cols, rows) = grid(n);
            assert_eq!(size.0, cols * CELL_W);
            assert_eq!(
                size.1,
                TITLE_H + rows * CELL_H + LEGEND_ROW_H + 2 * LEGEND_PAD
            );
        }
        assert_eq!(grid(4), (2, 2));
        assert_eq!(grid(9), (3, 3));
        assert_eq!(grid(3), (3, 1));
    }

    #[test]
    fn degenerate_and_partial_inputs() {
        let tmp = tempfile::tempdir().unwrap();
        // A perfect point focus, a panel without rays, an empty series, unlabelled wavelengths.
        let ps = vec![
            SpotPanel {
                label: "point".into(),
                series: vec![SpotSeries {
                    label: "W1".into(),
                    x_um: vec![5.0; 10],
                    y_um: vec![-1.0; 10],
                }],
            },
            SpotPanel {
                label: "vignetted".into(),
                series: vec![SpotSeries {
                    label: "W2".into(),
                    x_um: vec![],
                    y_um: vec![],
                }],
            },
        ];
        let p = tmp.path().join("degenerate.png");
        spot_diagram(&p, "degenerate", &ps).unwrap();
        assert_png(&p, spot_diagram_size(&ps));
    }

    #[test]
    fn rejects_bad_input() {
        let tmp = tempfile::tempdir().unwrap();
        let p = tmp.path().join("bad.png");
        let msg = |ps: &[SpotPanel]| spot_diagram(&p, "t", ps).unwrap_err().to_string();
        assert!(msg(&[]).contains("empty"));
        assert!(msg(&[SpotPanel::default()]).contains("empty"));
        let mut ps = panels(2);
        ps[1].series[2].y_um[7] = f64::NAN;
        let m = msg(&ps);
        assert!(
            m.contains("F2") && m.contains("650 nm") && m.contains("y_um[7]") && m.contains("NaN"),
            "{m}"
        );
        let mut ps = panels(1);
        ps[0].series[0].x_um[0] = f64::INFINITY;
        assert!(msg(&ps).contains("x_um[0] is inf"));
        let mut ps = panels(1);
        ps[0].series[1].x_um.pop();
        assert!(msg(&ps).contains("x_um has 299 values but y_um has 300"));
        assert!(!p.exists());
    }

    #[test]
    fn stats_and_scale() {
        let p = SpotPanel {
            label: "x".into(),
            series: vec![SpotSeries {
                label: "500 nm".into(),
                x_um: vec![1.0, 3.0, 1.0, 3.0],
                y_um: vec![0.0, 0.0, 2.0, 2.0],
            }],
        };
        let s = panel_stats(&p).unwrap();
        assert_eq!((s.cx, s.cy, s.n), (2.0, 1.0, 4));
        assert!((s.rms - 2f64.sqrt()).abs() < 1e-12);
        assert!((s.geo - 2f64.sqrt()).abs() < 1e-12);
        assert_eq!(s.half_width, 1.0);
        assert_eq!(nice_ceil(1.0), 1.0);
        assert_eq!(nice_ceil(1.01), 1.5);
        assert_eq!(nice_ceil(0.034), 0.04);
        assert_eq!(nice_ceil(870.0), 1000.0);
    }
}
