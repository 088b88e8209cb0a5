//! Optical materials: glass catalogues, dispersion formulas and media.
//!
//! This module reproduces how Zemax OpticStudio turns a glass name into a
//! refractive index:
//!
//! * [`agf`] reads Zemax `.AGF` glass catalogues (UTF-8, Windows-1252 or UTF-16; any line end, as a `.zmx` file),
//! * [`dispersion`] evaluates the 13 AGF dispersion formulas (wavelength in µm inside) and a tabulated
//!   index ([`tabulated`]: a vendor's (λ, n) points and their monotone cubic interpolant),
//! * [`glass`] holds one catalogue entry ([`Glass`]) with its valid wavelength range,
//! * [`catalog`] stores glasses by case-insensitive name ([`GlassCatalog`]), including a
//!   small built-in table so the binary works without any catalogue file,
//! * [`builtin_catalogs`] embeds the SCHOTT, OHARA, HOYA, CDGM, SUMITA and HIKARI optical glasses
//!   (converted from the refractiveindex.info database, CC0), loaded by name (`builtin:OHARA`), and the
//!   legacy SCHOTT1980 (the 1980 SCHOTT glasses of old lens files, Robb & Mercado's Buchdahl fits),
//! * [`medium`] is what a surface of the ray tracer refracts into ([`Medium`]).
//!
//! All public wavelengths are in **nanometres** (`wavelength_nm`); the conversion to the
//! micrometres used by the AGF formulas happens inside [`DispersionFormula`].
//!
//! Indices are *relative to air* exactly as the catalogue gives them. Zemax evaluates the
//! catalogue formula unchanged when the system temperature/pressure equal the catalogue
//! reference (20 °C, 1 atm), which is the only case modelled here: thermal (`TD`) data are
//! parsed and kept in [`Glass::thermal`] but never applied. System air is the index
//! reference, so [`Medium::Air`] has index exactly `1.0`.
//!
//! # Example
//!
//! ```
//! use diffcassi::materials::{GlassCatalog, Medium, WavelengthPolicy};
//!
//! let catalog = GlassCatalog::builtin();
//! let bk7 = catalog.get("n-bk7")?; // case-insensitive, like Zemax
//! let n_d = bk7.refractive_index(587.5618)?;
//! assert!((n_d - 1.5168).abs() < 1e-4);
//!
//! // Out of the catalogue's LD range is an error unless explicitly allowed.
//! assert!(bk7.refractive_index(5000.0).is_err());
//! let medium = Medium::Glass(bk7);
//! let n_ir = medium.refractive_index(5000.0, WavelengthPolicy::AllowExtrapolation)?;
//! assert!(n_ir.is_finite());
//! assert_eq!(Medium::Air.refractive_index(550.0, WavelengthPolicy::Strict)?, 1.0);
//! # Ok::<(), diffcassi::materials::MaterialError>(())
//! ```

pub mod agf;
pub mod builtin_catalogs;
pub mod catalog;
pub mod dispersion;
pub mod glass;
pub mod medium;
pub mod tabulated;

pub use agf::{decode_agf_bytes, parse_agf, parse_agf_document, AgfDocument};
pub use catalog::GlassCatalog;
pub use dispersion::{DispersionFormula, C_LINE_NM, D_LINE_NM, F_LINE_NM};
pub use glass::{ExtraData, Glass, GlassInfo, GlassStatus, ThermalData, TransmissionPoint};
pub use medium::{Medium, WavelengthPolicy};
pub use tabulated::TabulatedIndex;

/// How a spec file allows extrapolation, in [`MaterialError::WavelengthOutOfRange`]'s message.
pub const EXTRAPOLATION_HINT: &str = "set `wavelength_policy = \"AllowExtrapolation\"` in the system spec; Rust: WavelengthPolicy::AllowExtrapolation";
/// How a `.zmx` file allows it: its own record (`crate::spec::zmx::with_zmx_hints` puts it in the message of a
/// system read from a `.zmx` file).
pub const EXTRAPOLATION_HINT_ZMX: &str = "add the record `DCWP allow_extrapolation` to the .zmx file's system data (before its first SURF)";

/// Everything that can go wrong when reading catalogues or evaluating indices.
///
/// Every message names the glass (or medium) and the offending value; parse errors name the
/// source (file name or path) and the 1-based line number.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MaterialError {
    /// No glass of that name in the catalogue (lookup is case-insensitive).
    #[error("unknown glass '{name}'{}", format_suggestions(.suggestions))]
    UnknownGlass {
        /// The name that was asked for, as given.
        name: String,
        /// A few catalogue names close to `name` (may be empty).
        suggestions: Vec<String>,
    },

    /// The wavelength is outside the catalogue's `LD` range of the glass.
    #[error(
        "wavelength {} nm is outside the valid range [{min_nm}, {max_nm}] nm of glass {glass} (to evaluate its formula there anyway, {})",
        crate::limits::fmt_num(*.wavelength_nm),
        EXTRAPOLATION_HINT
    )]
    WavelengthOutOfRange {
        /// Glass name.
        glass: String,
        /// Requested wavelength.
        wavelength_nm: f64,
        /// Lower end of the catalogue range.
        min_nm: f64,
        /// Upper end of the catalogue range.
        max_nm: f64,
    },

    /// The requested wavelength is NaN or infinite.
    #[error("non-finite wavelength {wavelength_nm} nm requested for {medium}")]
    NonFiniteWavelength {
        /// Glass or medium name.
        medium: String,
        /// The offending wavelength.
        wavelength_nm: f64,
    },

    /// The dispersion formula produced NaN, ±∞ or a non-positive index
    /// (e.g. a negative n² far outside the fitted range: a Sellmeier term past its pole). The message names
    /// the formula and, when the wavelength is outside the catalogue range (extrapolation allowed), says
    /// that the extrapolation is what failed (round 21: "set AllowExtrapolation" led to a bare "invalid
    /// index NaN at 520 nm").
    #[error(
        "glass {glass} (catalogue {catalog}): its dispersion formula {formula} gives no refractive index at {} nm (n = {index}{}): {}",
        crate::limits::fmt_num(*.wavelength_nm),
        if .index.is_nan() { ", n² < 0" } else { "" },
        match .extrapolated { Some((lo, hi)) => format!("{} nm is outside the glass's valid range [{}, {}] nm and the formula extrapolated there fails; allowing extrapolation cannot help at this wavelength: use wavelengths inside the range, or a glass (catalogue) whose data cover {} nm", crate::limits::fmt_num(*.wavelength_nm), crate::limits::fmt_num(*lo), crate::limits::fmt_num(*hi), crate::limits::fmt_num(*.wavelength_nm)), None => "the catalogue's formula coefficients (CD line) are damaged".to_string() }
    )]
    NonFiniteIndex {
        /// Glass name.
        glass: String,
        /// The catalogue it comes from.
        catalog: String,
        /// The formula's label (`Sellmeier 1 (AGF 2)`).
        formula: String,
        /// Wavelength at which the formula was evaluated.
        wavelength_nm: f64,
        /// The invalid result.
        index: f64,
        /// The glass's valid range (nm) when the wavelength is outside it (extrapolation was allowed).
        extrapolated: Option<(f64, f64)>,
    },

    /// The dispersion formula gives a finite index outside the physical range
    /// [`glass::MIN_INDEX`, `glass::MAX_INDEX`] at a wavelength used (a damaged catalogue: `CD 1e300 …` gave
    /// n = 1e153 and every ray TIR; `CD -0.5 …` gave n = 0.696).
    #[error(
        "glass {glass} (catalogue {catalog}): its dispersion formula gives n = {} at {} nm, outside the physical range [{}, {}] of a refractive index: {}",
        crate::limits::fmt_num(*.index),
        crate::limits::fmt_num(*.wavelength_nm),
        glass::MIN_INDEX,
        glass::MAX_INDEX,
        if *.extrapolated { "the wavelength is outside the glass's catalogue range, where its formula (extrapolated) means nothing" } else { "the catalogue's formula coefficients (CD line) are damaged" }
    )]
    ImplausibleIndex {
        /// Glass name.
        glass: String,
        /// The catalogue it comes from.
        catalog: String,
        /// Wavelength at which the formula was evaluated.
        wavelength_nm: f64,
        /// The implausible result.
        index: f64,
        /// The wavelength is outside the glass's catalogue range (extrapolation was allowed).
        extrapolated: bool,
    },

    /// Malformed AGF text. `source_name` is the file name/path given to the parser
    /// (the field cannot be called `source`: thiserror reserves that name for error chains).
    #[error("{source_name}:{line}: {message}")]
    AgfParse {
        /// File name or path of the catalogue.
        source_name: String,
        /// 1-based line number.
        line: usize,
        /// What is wrong (names the glass and the offending token where relevant).
        message: String,
    },

    /// The AGF formula number is not one of 1..=13.
    #[error("glass {glass}: unsupported dispersion formula number {formula} (Zemax AGF formulas are 1..=13)")]
    UnsupportedFormula {
        /// Glass name.
        glass: String,
        /// The formula number found.
        formula: i64,
    },

    /// Fewer dispersion coefficients than the formula needs.
    #[error("glass {glass}: dispersion formula {formula} ({formula_name}) needs {expected} coefficients, found {found}")]
    CoefficientCount {
        /// Glass name.
        glass: String,
        /// AGF formula number.
        formula: u32,
        /// Formula name.
        formula_name: &'static str,
        /// Number of coefficients the formula uses.
        expected: usize,
        /// Number of coefficients provided.
        found: usize,
    },

    /// A catalogue file could not be read.
    #[error("cannot read glass catalogue {path}: {message}")]
    Io {
        /// Path as given.
        path: String,
        /// The I/O error text.
        message: String,
    },

    /// The bytes of a catalogue could not be decoded to text.
    #[error("{source_name}: cannot decode glass catalogue text: {message}")]
    Encoding {
        /// File name or path of the catalogue.
        source_name: String,
        /// What is wrong.
        message: String,
    },
}

fn format_suggestions(suggestions: &[String]) -> String {
    if suggestions.is_empty() {
        String::new()
    } else {
        format!(" (did you mean: {}?)", suggestions.join(", "))
    }
}
