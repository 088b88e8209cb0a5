//! PNG plots of simulation results (plotters' bitmap backend, embedded DejaVu Sans font, no
//! fontconfig or system fonts needed).
//!
//! The functions take plain data (no other diffcassi types):
//!
//! | function | image | size (px) |
//! |---|---|---|
//! | [`spot_diagram`] | one square panel per field, points coloured by wavelength, µm about each panel's centroid | [`spot_diagram_size`] |
//! | [`distortion_map`] | paraxial grid + magnified arrows to the real positions, coloured by \|Δ\| | [`DISTORTION_MAP_SIZE`] |
//! | [`dispersion_curve`] | detector x and y vs wavelength, spread in µm | [`DISPERSION_CURVE_SIZE`] |
//! | [`line_plot`] | generic x/y line series with legend | [`LINE_PLOT_SIZE`] |
//! | [`grouped_bars`] | grouped bars (mean) with ± whiskers | [`BAR_PLOT_SIZE`] |
//!
//! Common behaviour:
//!
//! * the output is always a PNG; the path must end in `.png` (any case) and missing parent
//!   directories are created. The image is rendered to a temporary file in the same directory and
//!   renamed into place, so a failed plot never leaves a truncated file behind;
//! * NaN or infinite inputs, empty inputs and mismatched lengths are rejected with a [`PlotError`]
//!   that names the offending series and index; none of the functions panics on bad data;
//! * [`png_dimensions`] reads the width and height of a PNG file (handy in tests).
//!
//! # Example
//!
//! ```
//! use diffcassi::plot::{line_plot, png_dimensions, LINE_PLOT_SIZE};
//!
//! # fn main() -> Result<(), diffcassi::plot::PlotError> {
//! let path = std::env::temp_dir().join(format!("diffcassi_plot_doc_{}.png", std::process::id()));
//! let x: Vec<f64> = (0..50).map(|i| i as f64 * 0.1).collect();
//! let y: Vec<f64> = x.iter().map(|v| v.sin()).collect();
//! line_plot(&path, "sin", "x (rad)", "sin x", &[("sin".to_string(), x, y)])?;
//! assert_eq!(png_dimensions(&path)?, LINE_PLOT_SIZE);
//!
//! // Bad data is an error, not a panic:
//! let err = line_plot(&path, "t", "x", "y", &[("s".into(), vec![0.0, 1.0], vec![0.0, f64::NAN])]);
//! assert!(err.unwrap_err().to_string().contains("NaN"));
//! # std::fs::remove_file(&path).ok();
//! # Ok(())
//! # }
//! ```

pub mod bars;
pub mod colors;
pub mod dispersion;
pub mod distortion;
pub mod font;
pub mod frontier;
pub mod line;
pub mod spot;

use std::io::Read;
use std::path::{Path, PathBuf};

use plotters::coord::Shift;
use plotters::prelude::*;

pub use bars::{grouped_bars, BarSeries, BAR_PLOT_SIZE};
pub use colors::wavelength_to_rgb;
pub use dispersion::{dispersion_curve, DISPERSION_CURVE_SIZE};
pub use distortion::{distortion_map, DistortionPoint, DISTORTION_MAP_SIZE};
pub use font::ensure_font;
pub use frontier::{frontier_plot, FrontierPoint, FRONTIER_PANEL_SIZE};
pub use line::{line_plot, LINE_PLOT_SIZE};
pub use spot::{spot_diagram, spot_diagram_size, SpotPanel, SpotSeries};

/// Errors of the [`plot`](self) module.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum PlotError {
    /// Nothing to plot (no panels, no series, no points...).
    #[error("{what} is empty: nothing to plot")]
    Empty { what: String },

    /// A NaN or infinite input value.
    #[error("{what}[{index}] is {value}: NaN and infinite values cannot be plotted")]
    NonFinite {
        what: String,
        index: usize,
        value: f64,
    },

    /// Paired inputs of different lengths.
    #[error("{what}: {first} has {first_len} values but {second} has {second_len}")]
    LengthMismatch {
        what: String,
        first: &'static str,
        first_len: usize,
        second: &'static str,
        second_len: usize,
    },

    /// Any other invalid argument (e.g. a non-positive arrow scale).
    #[error("{0}")]
    InvalidArgument(String),

    /// The output path does not end in `.png`.
    #[error("{}: plot output must be a .png file", path.display())]
    NotPng { path: PathBuf },

    /// The embedded font could not be registered.
    #[error("font error: {0}")]
    Font(String),

    /// Creating directories, renaming or reading a file failed.
    #[error("{}: {action}: {source}", path.display())]
    Io {
        path: PathBuf,
        action: &'static str,
        #[source]
        source: std::io::Error,
    },

    /// plotters failed to draw or encode the image.
    #[error("{}: drawing failed: {message}", path.display())]
    Draw { path: PathBuf, message: String },

    /// [`png_dimensions`]: the file is not a PNG.
    #[error("{}: not a valid PNG file: {reason}", path.display())]
    InvalidPng { path: PathBuf, reason: String },
}

impl<E: std::error::Error + Send + Sync> From<DrawingAreaErrorKind<E>> for PlotError {
    fn from(e: DrawingAreaErrorKind<E>) -> Self {
        // The path is filled in by `render`.
        PlotError::Draw {
            path: PathBuf::new(),
            message: e.to_string(),
        }
    }
}

/// Width and height of a PNG file, read from its signature and `IHDR` chunk.
pub fn png_dimensions(path: impl AsRef<Path>) -> Result<(u32, u32), PlotError> {
    let path = path.as_ref();
    let invalid = |reason: &str| PlotError::InvalidPng {
        path: path.to_path_buf(),
        reason: reason.to_string(),
    };
    let mut head = [0u8; 24];
    let mut f = std::fs::File::open(path).map_err(|source| PlotError::Io {
        path: path.to_path_buf(),
        action: "cannot open",
        source,
    })?;
    let mut n = 0;
    while n < head.len() {
        match f.read(&mut head[n..]) {
            Ok(0) => break,
            Ok(k) => n += k,
            Err(source) => {
                return Err(PlotError::Io {
                    path: path.to_path_buf(),
                    action: "cannot read",
                    source,
                })
            }
        }
    }
    if n < 8 || head[..8] != *b"\x89PNG\r\n\x1a\n" {
        return Err(invalid("missing PNG signature"));
    }
    if n < 24 || &head[12..16] != b"IHDR" || head[8..12] != [0, 0, 0, 13] {
        return Err(invalid("first chunk is not a 13-byte IHDR"));
    }
    let w = u32::from_be_bytes([head[16], head[17], head[18], head[19]]);
    let h = u32::from_be_bytes([head[20], head[21], head[22], head[23]]);
    if w == 0 || h == 0 {
        return Err(invalid("zero width or height"));
    }
    Ok((w, h))
}

// ---------------------------------------------------------------------------------------------
// Shared helpers for the plot implementations.

type Area<'a> = DrawingArea<BitMapBackend<'a>, Shift>;

/// Text colour and sizes used throughout.
const TITLE_SIZE: f64 = 24.0;
const LABEL_SIZE: f64 = 16.0;
const TICK_SIZE: f64 = 14.0;

/// Black text of about `size` px. The size is rounded to an even number of pixels: plotters'
/// ab_glyph renderer places glyphs at `size / 2 + top` truncated to an integer, which puts
/// small glyphs such as '.' one pixel too high at odd sizes.
fn font(size: f64) -> TextStyle<'static> {
    let even = ((size / 2.0).round() * 2.0).max(2.0);
    (font::FONT_FAMILY, even).into_font().color(&BLACK)
}

/// Render a PNG of `size` pixels to `path` via a temporary file + rename.
fn render<F>(path: &Path, size: (u32, u32), draw: F) -> Result<(), PlotError>
where
    F: FnOnce(&Area<'_>) -> Result<(), PlotError>,
{
    let is_png = path
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("png"));
    let file_name = path.file_name().and_then(|n| n.to_str());
    let (true, Some(_)) = (is_png, file_name) else {
        return Err(PlotError::NotPng {
            path: path.to_path_buf(),
        });
    };
    ensure_font()?;
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    std::fs::create_dir_all(&dir).map_err(|source| PlotError::Io {
        path: dir.clone(),
        action: "cannot create directory",
        source,
    })?;
    // `.NAME.stage-HOST-PID-START-N.png` (the encoder picks the format by the extension); a killed run's are
    // removed first (crate::io::stale).
    let _ = crate::io::stale::remove_stale(path);
    let mut tmp = crate::io::stale::temp_path(path);
    if !tmp.extension().is_some_and(|e| e.eq_ignore_ascii_case("png")) {
        tmp.as_mut_os_string().push(".png");
    }
    let with_path = |e: PlotError| match e {
        PlotError::Draw { message, .. } => PlotError::Draw {
            path: path.to_path_buf(),
            message,
        },
        other => other,
    };
    let result = (|| {
        let root = BitMapBackend::new(&tmp, size).into_drawing_area();
        root.fill(&WHITE)?;
        draw(&root)?;
        root.present()?;
        Ok(())
    })()
    .map_err(with_path)
    .and_then(|()| {
        std::fs::rename(&tmp, path).map_err(|source| PlotError::Io {
            path: path.to_path_buf(),
            action: "cannot move the rendered image into place",
            source,
        })
    });
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// Error unless every value is finite.
fn check_finite(what: impl Fn() -> String, values: &[f64]) -> Result<(), PlotError> {
    match values.iter().position(|v| !v.is_finite()) {
        None => Ok(()),
        Some(index) => Err(PlotError::NonFinite {
            what: what(),
            index,
            value: values[index],
        }),
    }
}

fn check_same_len(
    what: impl Fn() -> String,
    first: &'static str,
    a: usize,
    second: &'static str,
    b: usize,
) -> Result<(), PlotError> {
    if a == b {
        Ok(())
    } else {
        Err(PlotError::LengthMismatch {
            what: what(),
            first,
            first_len: a,
            second,
            second_len: b,
        })
    }
}

/// `(min, max)` of finite values (None when empty).
fn min_max(values: impl IntoIterator<Item = f64>) -> Option<(f64, f64)> {
    values.into_iter().fold(None, |acc, v| match acc {
        None => Some((v, v)),
        Some((lo, hi)) => Some((lo.min(v), hi.max(v))),
    })
}

/// Pad a data range by `frac` of its width on both sides; a degenerate range is widened to at
/// least `min_width` (or to a fraction of the value's magnitude).
fn padded_range(lo: f64, hi: f64, frac: f64, min_width: f64) -> (f64, f64) {
    let width = hi - lo;
    let min_width = min_width.max(1e-9 * lo.abs().max(hi.abs()));
    if width < min_width {
        let c = 0.5 * (lo + hi);
        (c - 0.5 * min_width, c + 0.5 * min_width)
    } else {
        (lo - frac * width, hi + frac * width)
    }
}

/// Error unless `[lo, hi]` is an axis range plotters can handle: finite, non-empty, with
/// magnitudes up to 1e100 and a width of at least 1e-100 (plotters' tick search does not
/// terminate on infinite or absurd ranges).
fn check_range(what: &str, lo: f64, hi: f64) -> Result<(), PlotError> {
    let width = hi - lo;
    let ok = lo.is_finite()
        && hi.is_finite()
        && width.is_finite()
        && width >= 1e-100
        && lo.abs().max(hi.abs()) <= 1e100;
    if ok {
        Ok(())
    } else {
        Err(PlotError::InvalidArgument(format!(
            "{what}: the data range [{lo:e}, {hi:e}] cannot be plotted (values must be within \
             ±1e100 and span at least 1e-100)"
        )))
    }
}

/// Tick-label formatter with enough decimals for `n_labels` ticks over `[lo, hi]` (plotters puts
/// ticks at multiples of 1, 2 or 5 × 10^k at least `(hi - lo) / n_labels` apart).
fn tick_formatter(lo: f64, hi: f64, n_labels: usize) -> impl Fn(&f64) -> String {
    let step = (hi - lo).abs() / n_labels.max(1) as f64;
    let decimals = if step > 0.0 && step.is_finite() {
        (-step.log10().floor()).clamp(0.0, 12.0) as usize
    } else {
        3
    };
    move |v: &f64| fmt_fixed(*v, decimals)
}

/// A number rounded to `sig` significant digits, trailing zeros removed, without exponent for
/// everyday magnitudes, with a typographic minus sign.
fn fmt_sig(v: f64, sig: usize) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{}", v.abs());
    }
    let mag = v.abs().log10().floor() as i32;
    let s = if !(-4..=6).contains(&mag) {
        format!("{:.*e}", sig.saturating_sub(1), v)
    } else {
        let decimals = (sig as i32 - 1 - mag).max(0) as usize;
        let s = format!("{v:.decimals$}");
        if s.contains('.') {
            s.trim_end_matches('0').trim_end_matches('.').to_string()
        } else {
            s
        }
    };
    s.replace('-', "\u{2212}")
}

/// `v` with a fixed number of decimals, typographic minus, and no "-0.00".
fn fmt_fixed(v: f64, decimals: usize) -> String {
    let s = format!("{v:.decimals$}");
    if s.starts_with('-') && s[1..].chars().all(|c| c == '0' || c == '.') {
        s[1..].to_string()
    } else {
        s.replace('-', "\u{2212}")
    }
}

/// Draw `text` centred horizontally at `(x, y)` (top of the text at `y`).
fn draw_centered(
    area: &Area<'_>,
    text: &str,
    style: &TextStyle<'_>,
    x: i32,
    y: i32,
) -> Result<(), PlotError> {
    let style = style.pos(plotters::style::text_anchor::Pos::new(
        plotters::style::text_anchor::HPos::Center,
        plotters::style::text_anchor::VPos::Top,
    ));
    area.draw_text(text, &style, (x, y))?;
    Ok(())
}

#[cfg(test)]
pub(crate) mod test_util {
    use super::*;

    /// Assert that `path` is a PNG of `size` and not a blank image.
    pub fn assert_png(path: &Path, size: (u32, u32)) {
        assert_eq!(png_dimensions(path).unwrap(), size, "{}", path.display());
        let len = std::fs::metadata(path).unwrap().len();
        assert!(
            len > 5_000,
            "{} suspiciously small ({len} bytes)",
            path.display()
        );
        // No temporary files left behind.
        let dir = path.parent().unwrap();
        for e in std::fs::read_dir(dir).unwrap() {
            let name = e.unwrap().file_name().to_string_lossy().into_owned();
            assert!(!name.contains(".stage-"), "leftover temporary file {name}");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn value() -> impl Strategy<Value = f64> {
        prop_oneof![
            -1e3..1e3f64,
            (-300i32..300).prop_map(|e| 10f64.powi(e)),
            (-300i32..300).prop_map(|e| -(10f64.powi(e))),
            Just(0.0),
            Just(f64::MAX),
            Just(f64::NAN),
            Just(f64::INFINITY),
        ]
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(24))]
        /// Arbitrary data never panics or hangs: each call returns Ok or a PlotError.
        #[test]
        fn prop_plots_never_panic(
            xs in proptest::collection::vec(value(), 0..6),
            ys in proptest::collection::vec(value(), 0..6),
            scale in value(),
        ) {
            let tmp = tempfile::tempdir().unwrap();
            let p = tmp.path().join("f.png");
            let _ = line_plot(&p, "f", "x", "y", &[("s".into(), xs.clone(), ys.clone())]);
            let _ = dispersion_curve(&p, "f", &xs, &ys, &xs);
            let pts: Vec<DistortionPoint> = xs
                .iter()
                .zip(&ys)
                .map(|(&a, &b)| DistortionPoint { paraxial_x_mm: a, paraxial_y_mm: b, real_x_mm: b, real_y_mm: a })
                .collect();
            let _ = distortion_map(&p, "f", &pts, scale);
            let panel = SpotPanel {
                label: "p".into(),
                series: vec![SpotSeries { label: "500 nm".into(), x_um: xs.clone(), y_um: ys.clone() }],
            };
            let _ = spot_diagram(&p, "f", &[panel]);
        }
    }

    #[test]
    fn png_dimensions_validates() {
        let tmp = tempfile::tempdir().unwrap();
        let p = tmp.path().join("x.png");
        std::fs::write(&p, b"GIF89a....").unwrap();
        assert!(png_dimensions(&p)
            .unwrap_err()
            .to_string()
            .contains("signature"));
        let mut png = b"\x89PNG\r\n\x1a\n\0\0\0\x0dIHDR".to_vec();
        png.extend_from_slice(&640u32.to_be_bytes());
        png.extend_from_slice(&480u32.to_be_bytes());
        std::fs::write(&p, &png).unwrap();
        assert_eq!(png_dimensions(&p).unwrap(), (640, 480));
        std::fs::write(&p, &png[..20]).unwrap();
        assert!(png_dimensions(&p).is_err());
        assert!(png_dimensions(tmp.path().join("none.png")).is_err());
    }

    #[test]
    fn rejects_non_png_path_and_cleans_up() {
        let tmp = tempfile::tempdir().unwrap();
        let e = render(&tmp.path().join("a.jpg"), (10, 10), |_| Ok(())).unwrap_err();
        assert!(e.to_string().contains("a.jpg"), "{e}");
        let e = render(&tmp.path().join("b.png"), (10, 10), |_| {
            Err(PlotError::InvalidArgument("stop".into()))
        })
        .unwrap_err();
        assert_eq!(e.to_string(), "stop");
        assert_eq!(std::fs::read_dir(tmp.path()).unwrap().count(), 0);
        let p = tmp.path().join("nested/dir/c.PNG");
        render(&p, (32, 16), |_| Ok(())).unwrap();
        assert_eq!(png_dimensions(&p).unwrap(), (32, 16));
    }

    #[test]
    fn helpers() {
        let f = tick_formatter(-0.5, 0.5, 5);
        assert_eq!(f(&0.2), "0.2");
        assert_eq!(f(&-0.2), "\u{2212}0.2");
        assert_eq!(f(&-0.0), "0.0");
        let f = tick_formatter(1.2345670, 1.2345690, 5);
        assert_eq!(f(&1.234568), "1.2345680");
        assert_eq!(padded_range(1.0, 1.0, 0.1, 0.002), (0.999, 1.001));
        assert_eq!(padded_range(0.0, 10.0, 0.1, 0.002), (-1.0, 11.0));
        assert_eq!(fmt_sig(1234.5678, 4), "1235");
        assert_eq!(fmt_sig(0.012345, 3), "0.0123");
        assert_eq!(fmt_sig(-990.0, 4), "\u{2212}990");
        assert_eq!(fmt_sig(0.1000, 4), "0.1");
        assert_eq!(fmt_sig(-0.0, 4), "0");
        assert_eq!(fmt_sig(1.5e-7, 3), "1.50e\u{2212}7");
        assert_eq!(fmt_fixed(-0.001, 2), "0.00");
        assert_eq!(fmt_fixed(-2.5, 1), "\u{2212}2.5");
        assert_eq!(min_max([3.0, -1.0, 2.0]), Some((-1.0, 3.0)));
        assert_eq!(min_max([]), None);
    }
}
