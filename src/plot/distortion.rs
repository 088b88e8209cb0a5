//! Distortion maps: paraxial grid points with arrows to the real image positions.
//!
//! Each point is drawn at its paraxial (predicted) position with an arrow towards the real
//! position; the arrow is the displacement Δ = real − paraxial magnified by `arrow_scale`, so small
//! distortions become visible (`arrow_scale = 1` draws arrows that end exactly at the real
//! positions). The scale is stated under the title. Arrows are coloured by |Δ| (true, not
//! magnified, in µm) with a colour bar; the axes are in mm with equal x/y scales.
//!
//! # Example
//!
//! ```
//! use diffcassi::plot::{distortion_map, png_dimensions, DistortionPoint, DISTORTION_MAP_SIZE};
//!
//! # fn main() -> Result<(), diffcassi::plot::PlotError> {
//! // Barrel distortion on a 5 x 5 grid.
//! let mut points = Vec::new();
//! for i in -2..=2 {
//!     for j in -2..=2 {
//!         let (x, y) = (i as f64, j as f64);
//!         let k = 1.0 - 0.01 * (x * x + y * y);
//!         points.push(DistortionPoint {
//!             paraxial_x_mm: x, paraxial_y_mm: y, real_x_mm: k * x, real_y_mm: k * y,
//!         });
//!     }
//! }
//! let path = std::env::temp_dir().join(format!("diffcassi_dist_doc_{}.png", std::process::id()));
//! distortion_map(&path, "Grid distortion", &points, 5.0)?;
//! assert_eq!(png_dimensions(&path)?, DISTORTION_MAP_SIZE);
//! # std::fs::remove_file(&path).ok();
//! # Ok(())
//! # }
//! ```

use std::path::Path;

use plotters::prelude::*;
use plotters::style::text_anchor;

use super::colors::viridis;
use super::{
    check_finite, check_range, draw_centered, fmt_sig, font, min_max, padded_range, render,
    tick_formatter, PlotError, LABEL_SIZE, TICK_SIZE, TITLE_SIZE,
};

/// One grid point: paraxial (predicted) and real image positions, in mm.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct DistortionPoint {
    pub paraxial_x_mm: f64,
    pub paraxial_y_mm: f64,
    pub real_x_mm: f64,
    pub real_y_mm: f64,
}

/// Image size of [`distortion_map`] in pixels.
pub const DISTORTION_MAP_SIZE: (u32, u32) = (1000, 900);

const HEADER_H: u32 = 72;
const MAIN_W: u32 = 860;
const MARGIN: u32 = 15;
const X_LABEL_H: u32 = 50;
const Y_LABEL_W: u32 = 80;
const PLOT_W: u32 = MAIN_W - 2 * MARGIN - Y_LABEL_W;
const PLOT_H: u32 = DISTORTION_MAP_SIZE.1 - HEADER_H - 2 * MARGIN - X_LABEL_H;
/// Fraction of the colour map used (its bright yellow end is hard to see on white).
const CMAP_MAX: f64 = 0.88;

/// Draw a distortion map (see the [module documentation](self)) to the PNG file `path`.
///
/// `arrow_scale` must be finite and positive.
pub fn distortion_map(
    path: impl AsRef<Path>,
    title: &str,
    points: &[DistortionPoint],
    arrow_scale: f64,
) -> Result<(), PlotError> {
    if points.is_empty() {
        return Err(PlotError::Empty {
            what: "distortion map: the list of points".to_string(),
        });
    }
    if !(arrow_scale.is_finite() && arrow_scale > 0.0) {
        return Err(PlotError::InvalidArgument(format!(
            "distortion map: arrow_scale must be finite and positive, got {arrow_scale}"
        )));
    }
    let col = |f: fn(&DistortionPoint) -> f64| points.iter().map(f).collect::<Vec<f64>>();
    let (px, py) = (col(|p| p.paraxial_x_mm), col(|p| p.paraxial_y_mm));
    let (rx, ry) = (col(|p| p.real_x_mm), col(|p| p.real_y_mm));
    check_finite(|| "distortion map: points, paraxial_x_mm".into(), &px)?;
    check_finite(|| "distortion map: points, paraxial_y_mm".into(), &py)?;
    check_finite(|| "distortion map: points, real_x_mm".into(), &rx)?;
    check_finite(|| "distortion map: points, real_y_mm".into(), &ry)?;

    // Per point: paraxial position (mm), arrow tip (mm) and |Δ| (µm).
    type Arrow = ((f64, f64), (f64, f64), f64);
    let arrows: Vec<Arrow> = points
        .iter()
        .map(|p| {
            let (dx, dy) = (p.real_x_mm - p.paraxial_x_mm, p.real_y_mm - p.paraxial_y_mm);
            let tip = (
                p.paraxial_x_mm + arrow_scale * dx,
                p.paraxial_y_mm + arrow_scale * dy,
            );
            ((p.paraxial_x_mm, p.paraxial_y_mm), tip, dx.hypot(dy) * 1e3)
        })
        .collect();
    if arrows
        .iter()
        .any(|a| !(a.1 .0.is_finite() && a.1 .1.is_finite() && a.2.is_finite()))
    {
        return Err(PlotError::InvalidArgument(format!(
            "distortion map: arrow_scale {arrow_scale} makes the arrows overflow"
        )));
    }
    let max_d_um = arrows.iter().map(|a| a.2).fold(0.0, f64::max);

    // Data ranges with equal scales on both axes.
    let (x_lo, x_hi) = min_max(arrows.iter().flat_map(|a| [a.0 .0, a.1 .0])).unwrap();
    let (y_lo, y_hi) = min_max(arrows.iter().flat_map(|a| [a.0 .1, a.1 .1])).unwrap();
    let span = (x_hi - x_lo).max(y_hi - y_lo);
    let min_w = if span > 0.0 {
        (span * 0.05).max(1e-6)
    } else {
        1.0
    };
    let (x_lo, x_hi) = padded_range(x_lo, x_hi, 0.06, min_w);
    let (y_lo, y_hi) = padded_range(y_lo, y_hi, 0.06, min_w);
    let mm_per_px = ((x_hi - x_lo) / PLOT_W as f64).max((y_hi - y_lo) / PLOT_H as f64);
    let (xc, yc) = (0.5 * (x_lo + x_hi), 0.5 * (y_lo + y_hi));
    let (hx, hy) = (
        0.5 * PLOT_W as f64 * mm_per_px,
        0.5 * PLOT_H as f64 * mm_per_px,
    );
    let (x_range, y_range) = ((xc - hx)..(xc + hx), (yc - hy)..(yc + hy));
    check_range("distortion map: x", x_range.start, x_range.end)?;
    check_range("distortion map: y", y_range.start, y_range.end)?;

    let vmax = if max_d_um > 0.0 { max_d_um } else { 1.0 };
    let color_of = |d_um: f64| viridis(d_um / vmax * CMAP_MAX);

    render(path.as_ref(), DISTORTION_MAP_SIZE, |root| {
        let width = DISTORTION_MAP_SIZE.0 as i32;
        draw_centered(root, title, &font(TITLE_SIZE), width / 2, 10)?;
        let scale_txt = if arrow_scale == 1.0 {
            "arrows: real − paraxial (true length)".to_string()
        } else {
            format!(
                "arrows: real − paraxial, magnified ×{}",
                fmt_sig(arrow_scale, 4)
            )
        };
        // Sub-header: legend symbols + scale + maximum.
        let sub = font(LABEL_SIZE);
        let y = 50;
        root.draw(&Circle::new(
            (40, y),
            4,
            RGBColor(60, 60, 60).stroke_width(1),
        ))?;
        let left = sub.pos(text_anchor::Pos::new(
            text_anchor::HPos::Left,
            text_anchor::VPos::Center,
        ));
        root.draw_text("paraxial grid point", &left, (52, y))?;
        let c = color_of(max_d_um * 0.7);
        root.draw(&PathElement::new(
            vec![(230, y), (270, y)],
            c.stroke_width(2),
        ))?;
        root.draw(&PathElement::new(
            vec![(262, y - 5), (270, y), (262, y + 5)],
            c.stroke_width(2),
        ))?;
        root.draw_text(
            &format!("{scale_txt};  max |Δ| = {} µm", fmt_sig(max_d_um, 4)),
            &left,
            (280, y),
        )?;

        let main = root
            .clone()
            .shrink((0, HEADER_H), (MAIN_W, DISTORTION_MAP_SIZE.1 - HEADER_H));
        let mut chart = ChartBuilder::on(&main)
            .margin(MARGIN)
            .x_label_area_size(X_LABEL_H)
            .y_label_area_size(Y_LABEL_W)
            .build_cartesian_2d(x_range.clone(), y_range.clone())?;
        debug_assert_eq!(chart.plotting_area().dim_in_pixel(), (PLOT_W, PLOT_H));
        let fx = tick_formatter(x_range.start, x_range.end, 8);
        let fy = tick_formatter(y_range.start, y_range.end, 8);
        chart
            .configure_mesh()
            .x_labels(8)
            .y_labels(8)
            .x_label_formatter(&fx)
            .y_label_formatter(&fy)
            .x_desc("x (mm)")
            .y_desc("y (mm)")
            .axis_desc_style(font(LABEL_SIZE))
            .label_style(font(TICK_SIZE))
            .bold_line_style(BLACK.mix(0.08))
            .light_line_style(TRANSPARENT)
            .draw()?;

        chart.draw_series(
            arrows
                .iter()
                .map(|a| Circle::new(a.0, 3, RGBColor(60, 60, 60).stroke_width(1))),
        )?;
        let head_px = 9.0;
        for &(p0, p1, d_um) in &arrows {
            let (dx, dy) = (p1.0 - p0.0, p1.1 - p0.1);
            let len = dx.hypot(dy);
            if len / mm_per_px < 1.0 {
                continue;
            }
            let style = color_of(d_um).stroke_width(2);
            let head = (0.4 * len).min(head_px * mm_per_px);
            let (ux, uy) = (dx / len, dy / len);
            let (c, s) = (25f64.to_radians().cos(), 25f64.to_radians().sin());
            let wing = |sign: f64| {
                // Rotate the backwards unit vector by ±25°.
                let (bx, by) = (-ux, -uy);
                (
                    p1.0 + head * (bx * c - sign * by * s),
                    p1.1 + head * (sign * bx * s + by * c),
                )
            };
            chart.draw_series([
                PathElement::new(vec![p0, p1], style),
                PathElement::new(vec![wing(1.0), p1, wing(-1.0)], style),
            ])?;
        }

        // Colour bar.
        let bar_area = root.clone().shrink(
            (MAIN_W, HEADER_H),
            (
                DISTORTION_MAP_SIZE.0 - MAIN_W,
                DISTORTION_MAP_SIZE.1 - HEADER_H,
            ),
        );
        let mut bar = ChartBuilder::on(&bar_area)
            .margin_top(MARGIN)
            .margin_bottom(MARGIN + X_LABEL_H)
            .margin_left(10)
            .margin_right(10)
            .right_y_label_area_size(90)
            .build_cartesian_2d(0.0..1.0, 0.0..vmax)?;
        let fb = tick_formatter(0.0, vmax, 8);
        bar.configure_mesh()
            .disable_x_mesh()
            .disable_y_mesh()
            .x_labels(0)
            .y_labels(8)
            .y_label_formatter(&fb)
            .set_all_tick_mark_size(6)
            .y_desc("|Δ| = |real − paraxial| (µm)")
            .axis_desc_style(font(LABEL_SIZE))
            .label_style(font(TICK_SIZE))
            .draw()?;
        let steps = 200;
        bar.draw_series((0..steps).map(|i| {
            let (a, b) = (i as f64 / steps as f64, (i + 1) as f64 / steps as f64);
            Rectangle::new(
                [(0.0, a * vmax), (1.0, b * vmax)],
                viridis(a * CMAP_MAX).filled(),
            )
        }))?;
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::super::test_util::assert_png;
    use super::*;

    /// 13 x 13 grid like Zemax's Grid Distortion, with ~5 % barrel distortion and a shift.
    fn grid() -> Vec<DistortionPoint> {
        let mut v = Vec::new();
        for i in -6..=6 {
            for j in -6..=6 {
                let (x, y) = (i as f64 * 2.5 / 6.0, j as f64 * 2.5 / 6.0);
                let k = 1.0 - 0.004 * (x * x + y * y);
                v.push(DistortionPoint {
                    paraxial_x_mm: -1.003 * x,
                    paraxial_y_mm: -1.003 * y,
                    real_x_mm: -1.003 * x * k - 0.01,
                    real_y_mm: -1.003 * y * k,
                });
            }
        }
        v
    }

    #[test]
    fn writes_png() {
        let tmp = tempfile::tempdir().unwrap();
        let p = tmp.path().join("dist.png");
        distortion_map(&p, "Grid distortion — SP, 450 nm", &grid(), 5.0).unwrap();
        assert_png(&p, DISTORTION_MAP_SIZE);
        // Scale 1, a single point and zero distortion are all fine.
        distortion_map(&p, "unit scale", &grid(), 1.0).unwrap();
        let one = [DistortionPoint {
            paraxial_x_mm: 1.0,
            paraxial_y_mm: 2.0,
            real_x_mm: 1.0,
            real_y_mm: 2.0,
        }];
        distortion_map(&p, "single", &one, 10.0).unwrap();
        assert_png(&p, DISTORTION_MAP_SIZE);
    }

    #[test]
    fn rejects_bad_input() {
        let tmp = tempfile::tempdir().unwrap();
        let p = tmp.path().join("bad.png");
        assert!(distortion_map(&p, "t", &[], 1.0)
            .unwrap_err()
            .to_string()
            .contains("empty"));
        for s in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            let e = distortion_map(&p, "t", &grid(), s).unwrap_err().to_string();
            assert!(e.contains("arrow_scale"), "{e}");
        }
        let mut g = grid();
        g[5].real_y_mm = f64::NEG_INFINITY;
        let e = distortion_map(&p, "t", &g, 1.0).unwrap_err().to_string();
        assert!(e.contains("real_y_mm[5] is -inf"), "{e}");
        let far = [DistortionPoint {
            paraxial_x_mm: 0.0,
            paraxial_y_mm: 0.0,
            real_x_mm: 10.0,
            real_y_mm: 0.0,
        }];
        let e = distortion_map(&p, "t", &far, 1e308)
            .unwrap_err()
            .to_string();
        assert!(e.contains("overflow"), "{e}");
        assert!(!p.exists());
    }
}
