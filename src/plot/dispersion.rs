//! Dispersion curves: detector position of one object point (x and y) versus wavelength.
//!
//! Two stacked panels share the wavelength axis: detector x (mm) on top, detector y (mm) below.
//! Points are sorted by wavelength, joined by a line and coloured by wavelength; dashed lines mark
//! the minimum and maximum of each coordinate and the panel caption states the spread
//! (max − min) in µm. A nearly constant coordinate is drawn on a range of at least 2 µm, so
//! numerical noise does not look like a curve.
//!
//! # Example
//!
//! ```
//! use diffcassi::plot::{dispersion_curve, png_dimensions, DISPERSION_CURVE_SIZE};
//!
//! # fn main() -> Result<(), diffcassi::plot::PlotError> {
//! let nm: Vec<f64> = (0..31).map(|i| 400.0 + 10.0 * i as f64).collect();
//! let x: Vec<f64> = nm.iter().map(|l| -0.4 + 0.83 * (l - 450.0) / 200.0).collect();
//! let y = vec![0.0; nm.len()];
//! let path = std::env::temp_dir().join(format!("diffcassi_disp_doc_{}.png", std::process::id()));
//! dispersion_curve(&path, "Dispersion, on-axis field", &nm, &x, &y)?;
//! assert_eq!(png_dimensions(&path)?, DISPERSION_CURVE_SIZE);
//! # std::fs::remove_file(&path).ok();
//! # Ok(())
//! # }
//! ```

use std::path::Path;

use plotters::prelude::*;

use super::colors::wavelength_to_plot_rgb;
use super::{
    check_finite, check_range, check_same_len, draw_centered, fmt_fixed, fmt_sig, font, min_max,
    padded_range, render, tick_formatter, Area, PlotError, LABEL_SIZE, TICK_SIZE, TITLE_SIZE,
};

/// Image size of [`dispersion_curve`] in pixels.
pub const DISPERSION_CURVE_SIZE: (u32, u32) = (1000, 820);

const TITLE_H: u32 = 50;
const CAPTION_H: u32 = 30;

/// Draw detector x and y versus wavelength (see the [module documentation](self)) to the PNG
/// file `path`. The three slices must have the same, non-zero length.
pub fn dispersion_curve(
    path: impl AsRef<Path>,
    title: &str,
    wavelength_nm: &[f64],
    x_mm: &[f64],
    y_mm: &[f64],
) -> Result<(), PlotError> {
    let what = || "dispersion curve".to_string();
    check_same_len(
        what,
        "wavelength_nm",
        wavelength_nm.len(),
        "x_mm",
        x_mm.len(),
    )?;
    check_same_len(
        what,
        "wavelength_nm",
        wavelength_nm.len(),
        "y_mm",
        y_mm.len(),
    )?;
    if wavelength_nm.is_empty() {
        return Err(PlotError::Empty {
            what: "dispersion curve: wavelength_nm".to_string(),
        });
    }
    check_finite(|| "dispersion curve: wavelength_nm".into(), wavelength_nm)?;
    check_finite(|| "dispersion curve: x_mm".into(), x_mm)?;
    check_finite(|| "dispersion curve: y_mm".into(), y_mm)?;

    let mut order: Vec<usize> = (0..wavelength_nm.len()).collect();
    order.sort_by(|&a, &b| wavelength_nm[a].total_cmp(&wavelength_nm[b]));
    let (l_lo, l_hi) = min_max(wavelength_nm.iter().copied()).unwrap();
    let (l_lo, l_hi) = padded_range(l_lo, l_hi, 0.04, 20.0);
    check_range("dispersion curve: wavelength_nm", l_lo, l_hi)?;
    for (name, v) in [("x_mm", x_mm), ("y_mm", y_mm)] {
        let (lo, hi) = min_max(v.iter().copied()).unwrap();
        let (lo, hi) = padded_range(lo, hi, 0.12, 0.002);
        check_range(&format!("dispersion curve: {name}"), lo, hi)?;
    }

    render(path.as_ref(), DISPERSION_CURVE_SIZE, |root| {
        let (w, h) = DISPERSION_CURVE_SIZE;
        draw_centered(root, title, &font(TITLE_SIZE), w as i32 / 2, 12)?;
        let panel_h = (h - TITLE_H) / 2;
        for (k, (name, values)) in [("x", x_mm), ("y", y_mm)].into_iter().enumerate() {
            let area = root
                .clone()
                .shrink((0, TITLE_H + k as u32 * panel_h), (w, panel_h));
            draw_panel(&area, name, values, wavelength_nm, &order, (l_lo, l_hi))?;
        }
        Ok(())
    })
}

fn draw_panel(
    area: &Area<'_>,
    name: &str,
    values: &[f64],
    wavelength_nm: &[f64],
    order: &[usize],
    (l_lo, l_hi): (f64, f64),
) -> Result<(), PlotError> {
    let (v_min, v_max) = min_max(values.iter().copied()).unwrap();
    let at = |v: f64| {
        order
            .iter()
            .find(|&&i| values[i] == v)
            .map(|&i| wavelength_nm[i])
            .unwrap()
    };
    let spread_um = (v_max - v_min) * 1e3;
    let caption = format!(
        "detector {name}: spread {} µm  (min {} mm at {} nm, max {} mm at {} nm)",
        fmt_sig(spread_um, 4),
        fmt_fixed(v_min, 4),
        fmt_sig(at(v_min), 5),
        fmt_fixed(v_max, 4),
        fmt_sig(at(v_max), 5),
    );
    let (w, _) = area.dim_in_pixel();
    draw_centered(area, &caption, &font(LABEL_SIZE), w as i32 / 2, 6)?;

    let (lo, hi) = padded_range(v_min, v_max, 0.12, 0.002);
    let chart_area = area
        .clone()
        .shrink((0, CAPTION_H), (w, area.dim_in_pixel().1 - CAPTION_H));
    let mut chart = ChartBuilder::on(&chart_area)
        .margin(12)
        .margin_right(30)
        .x_label_area_size(48)
        .y_label_area_size(105)
        .build_cartesian_2d(l_lo..l_hi, lo..hi)?;
    let fx = tick_formatter(l_lo, l_hi, 10);
    let fy = tick_formatter(lo, hi, 6);
    chart
        .configure_mesh()
        .x_labels(10)
        .y_labels(6)
        .x_label_formatter(&fx)
        .y_label_formatter(&fy)
        .x_desc("wavelength (nm)")
        .y_desc(format!("detector {name} (mm)"))
        .axis_desc_style(font(LABEL_SIZE))
        .label_style(font(TICK_SIZE))
        .bold_line_style(BLACK.mix(0.10))
        .light_line_style(TRANSPARENT)
        .draw()?;

    let guide = RGBColor(120, 120, 120).stroke_width(1);
    for v in [v_min, v_max] {
        chart.draw_series(DashedLineSeries::new([(l_lo, v), (l_hi, v)], 6, 4, guide))?;
    }
    chart.draw_series(LineSeries::new(
        order.iter().map(|&i| (wavelength_nm[i], values[i])),
        RGBColor(70, 70, 70).stroke_width(2),
    ))?;
    let radius = if order.len() > 60 { 3 } else { 5 };
    chart.draw_series(order.iter().map(|&i| {
        Circle::new(
            (wavelength_nm[i], values[i]),
            radius,
            wavelength_to_plot_rgb(wavelength_nm[i]).filled(),
        )
    }))?;
    chart.draw_series(
        order
            .iter()
            .map(|&i| Circle::new((wavelength_nm[i], values[i]), radius, BLACK.stroke_width(1))),
    )?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::super::test_util::assert_png;
    use super::*;

    #[test]
    fn writes_png() {
        let tmp = tempfile::tempdir().unwrap();
        let p = tmp.path().join("disp.png");
        // Unsorted input, non-linear x, y constant up to 1e-7 mm noise.
        let nm = vec![650.0, 450.0, 520.0, 480.0, 600.0, 550.0, 700.0, 400.0];
        let x: Vec<f64> = nm
            .iter()
            .map(|l: &f64| -0.398 + 2.0e-3 * (l - 450.0) - 1.5e-6 * (l - 450.0).powi(2))
            .collect();
        let y: Vec<f64> = (0..nm.len()).map(|i| 1e-7 * (i % 3) as f64).collect();
        dispersion_curve(&p, "Dispersion — SP, field (0, 0)", &nm, &x, &y).unwrap();
        assert_png(&p, DISPERSION_CURVE_SIZE);
        // A single wavelength is fine.
        dispersion_curve(&p, "one", &[550.0], &[1.0], &[-2.0]).unwrap();
        assert_png(&p, DISPERSION_CURVE_SIZE);
    }

    #[test]
    fn rejects_bad_input() {
        let tmp = tempfile::tempdir().unwrap();
        let p = tmp.path().join("bad.png");
        let e = |l: &[f64], x: &[f64], y: &[f64]| {
            dispersion_curve(&p, "t", l, x, y).unwrap_err().to_string()
        };
        assert!(e(&[], &[], &[]).contains("empty"));
        assert!(e(&[1.0, 2.0], &[1.0], &[1.0, 2.0])
            .contains("wavelength_nm has 2 values but x_mm has 1"));
        assert!(e(&[1.0, 2.0], &[1.0, 2.0], &[1.0]).contains("y_mm has 1"));
        assert!(e(&[500.0, f64::NAN], &[1.0, 2.0], &[1.0, 2.0]).contains("wavelength_nm[1] is NaN"));
        assert!(e(&[500.0, 510.0], &[1.0, 2.0], &[f64::INFINITY, 2.0]).contains("y_mm[0] is inf"));
        assert!(!p.exists());
    }
}
