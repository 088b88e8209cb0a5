//! Generic line plots: several `(label, x, y)` series on one pair of axes, with a legend.
//!
//! Series are drawn in the given order with distinct palette colours (or the wavelength colour
//! when the label names a wavelength, e.g. `"450 nm"`), as 2 px lines; series with at most 40
//! points also get point markers, so a single-point series stays visible. Series with an empty
//! label are left out of the legend. Axis ranges cover all data with 5 % padding.
//!
//! # Example
//!
//! ```
//! use diffcassi::plot::{line_plot, png_dimensions, LINE_PLOT_SIZE};
//!
//! # fn main() -> Result<(), diffcassi::plot::PlotError> {
//! let n: Vec<f64> = (1..=20).map(|i| i as f64).collect();
//! let err: Vec<f64> = n.iter().map(|i| 10f64.powf(-i / 2.0)).collect();
//! let path = std::env::temp_dir().join(format!("diffcassi_line_doc_{}.png", std::process::id()));
//! line_plot(&path, "Convergence", "iteration", "log10 error", &[
//!     ("Newton".to_string(), n.clone(), err.iter().map(|e| e.log10()).collect()),
//! ])?;
//! assert_eq!(png_dimensions(&path)?, LINE_PLOT_SIZE);
//! # std::fs::remove_file(&path).ok();
//! # Ok(())
//! # }
//! ```

use std::path::Path;

use plotters::prelude::*;

use super::colors::{palette, parse_wavelength_nm, wavelength_to_plot_rgb};
use super::{
    check_finite, check_range, check_same_len, font, min_max, padded_range, render, tick_formatter,
    PlotError, LABEL_SIZE, TICK_SIZE, TITLE_SIZE,
};

/// Image size of [`line_plot`] in pixels.
pub const LINE_PLOT_SIZE: (u32, u32) = (1000, 700);

/// Draw `series` (each `(label, x, y)` with `x.len() == y.len() > 0`) to the PNG file `path`.
pub fn line_plot(
    path: impl AsRef<Path>,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[(String, Vec<f64>, Vec<f64>)],
) -> Result<(), PlotError> {
    if series.is_empty() {
        return Err(PlotError::Empty {
            what: "line plot: the list of series".to_string(),
        });
    }
    for (label, x, y) in series {
        let what = |axis: &str| format!("line plot: series '{label}'{axis}");
        check_same_len(|| what(""), "x", x.len(), "y", y.len())?;
        if x.is_empty() {
            return Err(PlotError::Empty { what: what("") });
        }
        check_finite(|| what(" x"), x)?;
        check_finite(|| what(" y"), y)?;
    }
    let (x_lo, x_hi) = min_max(series.iter().flat_map(|s| s.1.iter().copied())).unwrap();
    let (y_lo, y_hi) = min_max(series.iter().flat_map(|s| s.2.iter().copied())).unwrap();
    let unit = |lo: f64, hi: f64| {
        let m = lo.abs().max(hi.abs());
        if m > 0.0 {
            m * 0.1
        } else {
            1.0
        }
    };
    let (x_lo, x_hi) = padded_range(x_lo, x_hi, 0.03, unit(x_lo, x_hi));
    let (y_lo, y_hi) = padded_range(y_lo, y_hi, 0.05, unit(y_lo, y_hi));
    check_range("line plot: x", x_lo, x_hi)?;
    check_range("line plot: y", y_lo, y_hi)?;

    render(path.as_ref(), LINE_PLOT_SIZE, |root| {
        let mut chart = ChartBuilder::on(root)
            .caption(title, font(TITLE_SIZE))
            .margin(15)
            .margin_right(30)
            .x_label_area_size(55)
            .y_label_area_size(100)
            .build_cartesian_2d(x_lo..x_hi, y_lo..y_hi)?;
        let fx = tick_formatter(x_lo, x_hi, 10);
        let fy = tick_formatter(y_lo, y_hi, 8);
        chart
            .configure_mesh()
            .x_labels(10)
            .y_labels(8)
            .x_label_formatter(&fx)
            .y_label_formatter(&fy)
            .x_desc(x_label)
            .y_desc(y_label)
            .axis_desc_style(font(LABEL_SIZE))
            .label_style(font(TICK_SIZE))
            .bold_line_style(BLACK.mix(0.10))
            .light_line_style(TRANSPARENT)
            .draw()?;

        let mut any_label = false;
        for (i, (label, x, y)) in series.iter().enumerate() {
            let color = parse_wavelength_nm(label).map_or(palette(i), wavelength_to_plot_rgb);
            let pts = || x.iter().copied().zip(y.iter().copied());
            let drawn = chart.draw_series(LineSeries::new(pts(), color.stroke_width(2)))?;
            if !label.is_empty() {
                any_label = true;
                drawn.label(label.as_str()).legend(move |(lx, ly)| {
                    PathElement::new(vec![(lx, ly), (lx + 24, ly)], color.stroke_width(2))
                });
            }
            if x.len() <= 40 {
                chart.draw_series(pts().map(|p| Circle::new(p, 3, color.filled())))?;
            }
        }
        if any_label {
            chart
                .configure_series_labels()
                .position(SeriesLabelPosition::UpperRight)
                .margin(12)
                .legend_area_size(32)
                .label_font(font(LABEL_SIZE))
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK.mix(0.4))
                .draw()?;
        }
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::super::test_util::assert_png;
    use super::*;

    #[test]
    fn writes_png() {
        let tmp = tempfile::tempdir().unwrap();
        let p = tmp.path().join("line.png");
        let x: Vec<f64> = (0..200).map(|i| i as f64 * 0.05).collect();
        let s = vec![
            (
                "sin".to_string(),
                x.clone(),
                x.iter().map(|v| v.sin()).collect(),
            ),
            (
                "cos · 0.5".to_string(),
                x.clone(),
                x.iter().map(|v| 0.5 * v.cos()).collect(),
            ),
            ("".to_string(), vec![2.0, 4.0, 6.0], vec![0.8, -0.8, 0.8]),
            ("450 nm".to_string(), vec![5.0], vec![0.0]),
        ];
        line_plot(&p, "Generic line plot", "x (rad)", "y", &s).unwrap();
        assert_png(&p, LINE_PLOT_SIZE);
        // Constant data and a single point work too.
        line_plot(
            &p,
            "flat",
            "x",
            "y",
            &[("c".into(), vec![1.0, 2.0], vec![3.0, 3.0])],
        )
        .unwrap();
        line_plot(&p, "dot", "x", "y", &[("".into(), vec![0.0], vec![0.0])]).unwrap();
        assert_png(&p, LINE_PLOT_SIZE);
    }

    #[test]
    fn rejects_bad_input() {
        let tmp = tempfile::tempdir().unwrap();
        let p = tmp.path().join("bad.png");
        let e = |s: &[(String, Vec<f64>, Vec<f64>)]| {
            line_plot(&p, "t", "x", "y", s).unwrap_err().to_string()
        };
        assert!(e(&[]).contains("empty"));
        assert_eq!(
            e(&[("a".into(), vec![], vec![])]),
            "line plot: series 'a' is empty: nothing to plot"
        );
        assert_eq!(
            e(&[("a".into(), vec![1.0, 2.0], vec![1.0])]),
            "line plot: series 'a': x has 2 values but y has 1"
        );
        assert_eq!(
            e(&[("a".into(), vec![1.0, f64::NAN], vec![1.0, 2.0])]),
            "line plot: series 'a' x[1] is NaN: NaN and infinite values cannot be plotted"
        );
        assert!(e(&[("b".into(), vec![1.0], vec![f64::NEG_INFINITY])])
            .contains("series 'b' y[0] is -inf"));
        assert!(line_plot(
            tmp.path().join("x.svg"),
            "t",
            "x",
            "y",
            &[("a".into(), vec![1.0], vec![1.0])]
        )
        .is_err());
        assert!(!p.exists());
    }
}
