//! The embedded plot font: DejaVu Sans (Bitstream Vera licence, see `assets/fonts/LICENSE-DejaVu.txt`),
//! registered with plotters' `ab_glyph` text renderer as the `"sans-serif"` family, so plots render
//! text identically everywhere without fontconfig or system fonts.
//!
//! Every plotting function calls [`ensure_font`] first; calling it yourself is only needed when you
//! draw with plotters directly:
//!
//! ```
//! diffcassi::plot::ensure_font().expect("embedded font is valid");
//! // plotters text styles such as ("sans-serif", 20) now resolve to DejaVu Sans.
//! ```

use std::sync::OnceLock;

use plotters::style::FontStyle;

use super::PlotError;

/// The raw TrueType data of DejaVu Sans (Debian package `fonts-dejavu-core`).
pub const DEJAVU_SANS_TTF: &[u8] = include_bytes!("../../assets/fonts/DejaVuSans.ttf");

/// The font family name under which the font is registered.
pub const FONT_FAMILY: &str = "sans-serif";

/// Register the embedded font for [`FONT_FAMILY`] (once per process; later calls are free).
pub fn ensure_font() -> Result<(), PlotError> {
    static REGISTERED: OnceLock<Result<(), String>> = OnceLock::new();
    REGISTERED
        .get_or_init(|| {
            plotters::style::register_font(FONT_FAMILY, FontStyle::Normal, DEJAVU_SANS_TTF)
                .map_err(|_| "the embedded DejaVu Sans font could not be parsed".to_string())
        })
        .clone()
        .map_err(PlotError::Font)
}

#[cfg(test)]
mod tests {
    use super::*;
    use plotters::style::IntoFont;

    #[test]
    fn font_registers_and_measures_text() {
        ensure_font().unwrap();
        ensure_font().unwrap();
        let font = (FONT_FAMILY, 20).into_font();
        let (w, h) = font.box_size("spot 450 nm µm Δλ").unwrap();
        assert!(w > 100 && h > 10, "text box {w}x{h}");
    }
}
