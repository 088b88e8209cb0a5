//! Colours for plots: wavelength → RGB, a sequential colour map and a categorical palette.
//!
//! * [`wavelength_to_rgb`]: the approximate perceived colour of monochromatic light (Dan Bruton's
//!   piecewise-linear approximation, with intensity roll-off near the ends of the visible range and
//!   gamma 0.8). Wavelengths outside 380–780 nm are clamped to the end colours, so UV and NIR bands
//!   still get a visible violet / dark red.
//! * [`wavelength_to_plot_rgb`]: the same hue darkened where it is too light to read on a white
//!   background (yellow, green); used for markers and lines.
//! * [`parse_wavelength_nm`]: reads the wavelength out of a label such as `"450 nm"` or
//!   `"0.55 µm"`; plots use it to colour series by wavelength.
//! * [`viridis`]: sequential colour map for magnitudes; [`palette`]: 10 distinct colours
//!   (matplotlib's "tab10") for series that are not wavelengths.
//!
//! # Example
//!
//! ```
//! use diffcassi::plot::colors::{parse_wavelength_nm, wavelength_to_rgb};
//! use plotters::style::RGBColor;
//!
//! assert_eq!(wavelength_to_rgb(650.0), RGBColor(255, 0, 0));
//! let blue = wavelength_to_rgb(450.0);
//! assert!(blue.2 > 200 && blue.0 < 100);
//! assert_eq!(parse_wavelength_nm("450 nm"), Some(450.0));
//! assert_eq!(parse_wavelength_nm("λ = 0.55 µm"), Some(550.0));
//! assert_eq!(parse_wavelength_nm("field 1"), None);
//! ```

use plotters::style::RGBColor;

/// Approximate colour of monochromatic light of wavelength `nm` (clamped to 380–780 nm; a
/// non-finite input gives mid grey).
pub fn wavelength_to_rgb(nm: f64) -> RGBColor {
    if !nm.is_finite() {
        return RGBColor(128, 128, 128);
    }
    let w = nm.clamp(380.0, 780.0);
    let (r, g, b) = if w < 440.0 {
        (-(w - 440.0) / (440.0 - 380.0), 0.0, 1.0)
    } else if w < 490.0 {
        (0.0, (w - 440.0) / (490.0 - 440.0), 1.0)
    } else if w < 510.0 {
        (0.0, 1.0, -(w - 510.0) / (510.0 - 490.0))
    } else if w < 580.0 {
        ((w - 510.0) / (580.0 - 510.0), 1.0, 0.0)
    } else if w < 645.0 {
        (1.0, -(w - 645.0) / (645.0 - 580.0), 0.0)
    } else {
        (1.0, 0.0, 0.0)
    };
    // Intensity falls off near the limits of vision.
    let factor = if w < 420.0 {
        0.3 + 0.7 * (w - 380.0) / (420.0 - 380.0)
    } else if w > 700.0 {
        0.3 + 0.7 * (780.0 - w) / (780.0 - 700.0)
    } else {
        1.0
    };
    let ch = |c: f64| -> u8 {
        if c <= 0.0 {
            0
        } else {
            ((c * factor).powf(0.8) * 255.0).round().clamp(0.0, 255.0) as u8
        }
    };
    RGBColor(ch(r), ch(g), ch(b))
}

/// [`wavelength_to_rgb`] darkened so that its relative luminance is at most 0.55, keeping yellow
/// and green readable on white.
pub fn wavelength_to_plot_rgb(nm: f64) -> RGBColor {
    darken_to_luminance(wavelength_to_rgb(nm), 0.55)
}

fn darken_to_luminance(c: RGBColor, max_luminance: f64) -> RGBColor {
    let l = (0.2126 * c.0 as f64 + 0.7152 * c.1 as f64 + 0.0722 * c.2 as f64) / 255.0;
    if l <= max_luminance {
        return c;
    }
    let k = max_luminance / l;
    let s = |v: u8| (v as f64 * k).round() as u8;
    RGBColor(s(c.0), s(c.1), s(c.2))
}

/// The wavelength in nm named by a label, if any.
///
/// Recognised: a number followed by a unit `nm`, `µm`/`μm`/`um` (e.g. `"450 nm"`, `"W1 0.45um"`,
/// `"λ=520nm"`), or a label that is only a number (≥ 100 is taken as nm, smaller as µm). Anything
/// else (e.g. `"W1"`, `"field 2"`) gives `None`.
pub fn parse_wavelength_nm(label: &str) -> Option<f64> {
    let s = label.trim();
    if let Ok(v) = s.parse::<f64>() {
        return (v.is_finite() && v > 0.0).then_some(if v >= 100.0 { v } else { v * 1000.0 });
    }
    let bytes = s.as_bytes();
    let mut i = 0;
    while i < bytes.len() {
        if bytes[i].is_ascii_digit() && (i == 0 || !bytes[i - 1].is_ascii_alphanumeric()) {
            let start = i;
            while i < bytes.len() && (bytes[i].is_ascii_digit() || bytes[i] == b'.') {
                i += 1;
            }
            let value: Option<f64> = s[start..i].parse().ok();
            let unit = s[i..].trim_start();
            if let Some(v) = value.filter(|v| v.is_finite() && *v > 0.0) {
                let word_end = |rest: &str| !rest.starts_with(|c: char| c.is_alphanumeric());
                if let Some(rest) = unit.strip_prefix("nm") {
                    if word_end(rest) {
                        return Some(v);
                    }
                }
                for micro in ["µm", "μm", "um"] {
                    if let Some(rest) = unit.strip_prefix(micro) {
                        if word_end(rest) {
                            return Some(v * 1000.0);
                        }
                    }
                }
            }
        } else {
            i += 1;
        }
    }
    None
}

/// Sequential "viridis" colour map (dark purple → blue → green → yellow) for `t` in `[0, 1]`
/// (clamped; NaN gives the low end).
pub fn viridis(t: f64) -> RGBColor {
    const STOPS: [(f64, [f64; 3]); 9] = [
        (0.000, [68.0, 1.0, 84.0]),
        (0.125, [71.0, 44.0, 123.0]),
        (0.250, [59.0, 82.0, 139.0]),
        (0.375, [44.0, 114.0, 142.0]),
        (0.500, [33.0, 145.0, 140.0]),
        (0.625, [39.0, 173.0, 129.0]),
        (0.750, [92.0, 200.0, 99.0]),
        (0.875, [170.0, 220.0, 50.0]),
        (1.000, [253.0, 231.0, 37.0]),
    ];
    let t = if t.is_nan() { 0.0 } else { t.clamp(0.0, 1.0) };
    let k = STOPS
        .windows(2)
        .position(|w| t <= w[1].0)
        .unwrap_or(STOPS.len() - 2);
    let (t0, c0) = STOPS[k];
    let (t1, c1) = STOPS[k + 1];
    let f = (t - t0) / (t1 - t0);
    let mix = |i: usize| (c0[i] + (c1[i] - c0[i]) * f).round().clamp(0.0, 255.0) as u8;
    RGBColor(mix(0), mix(1), mix(2))
}

/// The `i`-th colour of a 10-colour categorical palette (matplotlib "tab10"), cycling.
pub fn palette(i: usize) -> RGBColor {
    const TAB10: [RGBColor; 10] = [
        RGBColor(31, 119, 180),
        RGBColor(255, 127, 14),
        RGBColor(44, 160, 44),
        RGBColor(214, 39, 40),
        RGBColor(148, 103, 189),
        RGBColor(140, 86, 75),
        RGBColor(227, 119, 194),
        RGBColor(127, 127, 127),
        RGBColor(188, 189, 34),
        RGBColor(23, 190, 207),
    ];
    TAB10[i % TAB10.len()]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spectrum_anchor_colours() {
        assert_eq!(wavelength_to_rgb(440.0), RGBColor(0, 0, 255));
        assert_eq!(wavelength_to_rgb(510.0), RGBColor(0, 255, 0));
        assert_eq!(wavelength_to_rgb(580.0), RGBColor(255, 255, 0));
        assert_eq!(wavelength_to_rgb(645.0), RGBColor(255, 0, 0));
        // Hue ordering across the CASSI band: blue dominates at 450, green at 520, red at 650.
        let b = wavelength_to_rgb(450.0);
        let g = wavelength_to_rgb(520.0);
        assert!(b.2 > b.0 && b.2 > b.1);
        assert!(g.1 > g.0 && g.1 > g.2);
        // Clamping and roll-off keep the extremes visible and ordered.
        assert_eq!(wavelength_to_rgb(300.0), wavelength_to_rgb(380.0));
        assert_eq!(wavelength_to_rgb(1000.0), wavelength_to_rgb(780.0));
        assert!(wavelength_to_rgb(780.0).0 > 60);
        assert_eq!(wavelength_to_rgb(f64::NAN), RGBColor(128, 128, 128));
    }

    #[test]
    fn plot_colours_are_readable() {
        for nm in (380..=780).step_by(5) {
            let c = wavelength_to_plot_rgb(nm as f64);
            let l = (0.2126 * c.0 as f64 + 0.7152 * c.1 as f64 + 0.0722 * c.2 as f64) / 255.0;
            assert!(l <= 0.555, "{nm} nm too light: {c:?}");
        }
        assert_eq!(wavelength_to_plot_rgb(650.0), RGBColor(255, 0, 0));
    }

    #[test]
    fn wavelength_labels() {
        for (label, nm) in [
            ("450 nm", Some(450.0)),
            ("450nm", Some(450.0)),
            ("  520.5 nm ", Some(520.5)),
            ("0.65 µm", Some(650.0)),
            ("0.65 μm", Some(650.0)),
            ("W2 (0.52um)", Some(520.0)),
            ("λ=600nm, field 2", Some(600.0)),
            ("650", Some(650.0)),
            ("0.45", Some(450.0)),
            ("W1", None),
            ("field 2", None),
            ("3 nmol", None),
            ("", None),
            ("-450 nm", Some(450.0)),
        ] {
            assert_eq!(parse_wavelength_nm(label), nm, "{label:?}");
        }
    }

    #[test]
    fn viridis_ends_and_monotone_luminance() {
        assert_eq!(viridis(0.0), RGBColor(68, 1, 84));
        assert_eq!(viridis(1.0), RGBColor(253, 231, 37));
        assert_eq!(viridis(-5.0), viridis(0.0));
        assert_eq!(viridis(f64::NAN), viridis(0.0));
        let lum = |c: RGBColor| 0.2126 * c.0 as f64 + 0.7152 * c.1 as f64 + 0.0722 * c.2 as f64;
        let mut prev = -1.0;
        for i in 0..=100 {
            let l = lum(viridis(i as f64 / 100.0));
            assert!(l >= prev - 1e-9);
            prev = l;
        }
        assert_ne!(palette(0), palette(1));
        assert_eq!(palette(10), palette(0));
    }
}
