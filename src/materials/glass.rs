//! One catalogue glass: dispersion formula, catalogue `nd`/`vd`, valid wavelength range.
//!
//! [`Glass::refractive_index`] evaluates the catalogue dispersion formula
//! ([`DispersionFormula`]) at a wavelength in nm and refuses wavelengths outside the
//! catalogue's `LD` range; [`Glass::refractive_index_unchecked`] evaluates anyway (explicit
//! opt-in extrapolation).
//!
//! The index is relative to air, exactly as the catalogue gives it. Zemax OpticStudio uses
//! the catalogue formula unchanged when the system temperature and pressure equal the
//! catalogue reference (20 °C, 1 atm for every SCHOTT glass), which is the only case
//! modelled here. The thermal coefficients of the `TD` record are parsed into
//! [`Glass::thermal`] but **not applied**.
//!
//! # Example
//!
//! ```
//! use diffcassi::materials::{DispersionFormula, Glass, D_LINE_NM};
//!
//! let bk7 = Glass::new(
//!     "N-BK7",
//!     DispersionFormula::Sellmeier1([
//!         1.039612120E+00, 6.000698670E-03, 2.317923440E-01,
//!         2.001791440E-02, 1.010469450E+00, 1.035606530E+02,
//!     ]),
//!     1.5168,
//!     64.17,
//!     300.0,
//!     2500.0,
//!     "SCHOTT",
//! );
//! assert!((bk7.refractive_index(D_LINE_NM)? - bk7.nd).abs() < 1e-4);
//! assert!((bk7.abbe_number()? - bk7.vd).abs() < 0.05);
//! assert!(!bk7.in_range(250.0));
//! assert!(bk7.refractive_index(250.0).is_err());
//! assert!(bk7.refractive_index_unchecked(250.0) > 1.5);
//! # Ok::<(), diffcassi::materials::MaterialError>(())
//! ```

use serde::{Deserialize, Serialize};

use super::dispersion::{DispersionFormula, C_LINE_NM, D_LINE_NM, F_LINE_NM};
use super::MaterialError;

/// Absolute slack (nm) of the range check, so that a wavelength equal to an `LD` bound
/// survives the µm → nm conversion rounding.
const RANGE_SLACK_NM: f64 = 1e-9;

/// A catalogue glass.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Glass {
    /// Glass name (upper case once inserted into a [`GlassCatalog`](super::GlassCatalog)).
    pub name: String,
    /// Dispersion formula and coefficients (`NM` formula number + `CD` record).
    pub formula: DispersionFormula,
    /// Catalogue index at the d line (587.5618 nm), `NM` record. Informative only: the
    /// index is always computed from [`formula`](Self::formula).
    pub nd: f64,
    /// Catalogue Abbe number vd, `NM` record. Informative only.
    pub vd: f64,
    /// Lower end of the valid range (`LD` record, µm in the file, converted ×1000).
    pub min_wavelength_nm: f64,
    /// Upper end of the valid range (`LD` record, µm in the file, converted ×1000).
    pub max_wavelength_nm: f64,
    /// Catalogue name, e.g. `"SCHOTT"` (file stem of the AGF file, upper case).
    pub catalog: String,
    /// Thermal dispersion data (`TD` record), kept but **not applied** (see module docs).
    /// `None` when the record is absent, empty or incomplete.
    pub thermal: Option<ThermalData>,
    /// Remaining catalogue data (`NM` extras, `GC`, `ED`, `IT`), informative only.
    pub info: GlassInfo,
}

/// Zemax thermal dispersion coefficients (`TD` record), for the Schott/Zemax model of the
/// absolute index change
/// Δn_abs(λ, ΔT) = (n² − 1)/(2n) · (D0 ΔT + D1 ΔT² + D2 ΔT³ + (E0 ΔT + E1 ΔT²)/(λ² − λtk²)).
///
/// Parsed and stored only; the ray tracer assumes system temperature = `reference_temperature_c`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ThermalData {
    /// D0 (1/K).
    pub d0: f64,
    /// D1 (1/K²).
    pub d1: f64,
    /// D2 (1/K³).
    pub d2: f64,
    /// E0 (µm²/K).
    pub e0: f64,
    /// E1 (µm²/K²).
    pub e1: f64,
    /// λtk (µm).
    pub lambda_tk_um: f64,
    /// Reference temperature of the catalogue data (°C).
    pub reference_temperature_c: f64,
}

/// Glass status of the `NM` record (Zemax numbering 0..=4).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum GlassStatus {
    /// 0
    Standard,
    /// 1
    Preferred,
    /// 2
    Obsolete,
    /// 3
    Special,
    /// 4
    Melt,
}

impl GlassStatus {
    /// Status from its AGF code, `None` for unknown codes.
    pub fn from_code(code: i64) -> Option<Self> {
        match code {
            0 => Some(Self::Standard),
            1 => Some(Self::Preferred),
            2 => Some(Self::Obsolete),
            3 => Some(Self::Special),
            4 => Some(Self::Melt),
            _ => None,
        }
    }
}

/// `ED` record ("extra data"). Fields are `None` when absent or a placeholder.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ExtraData {
    /// Thermal expansion coefficient −30..70 °C (10⁻⁶/K).
    pub tce_minus30_70: Option<f64>,
    /// Thermal expansion coefficient 100..300 °C (10⁻⁶/K).
    pub tce_100_300: Option<f64>,
    /// Density (g/cm³).
    pub density_g_cm3: Option<f64>,
    /// Relative partial dispersion deviation ΔPgF.
    pub delta_pg_f: Option<f64>,
    /// "Ignore thermal expansion" flag.
    pub ignore_thermal_expansion: Option<bool>,
}

/// One internal transmittance sample (`IT` record).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct TransmissionPoint {
    /// Wavelength (µm, as in the file).
    pub wavelength_um: f64,
    /// Internal transmittance (0..1) for `thickness_mm`.
    pub transmission: f64,
    /// Sample thickness (mm).
    pub thickness_mm: f64,
}

/// Informative catalogue data that does not influence the index.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct GlassInfo {
    /// MIL code token of the `NM` record, verbatim (e.g. `"517642.251"`).
    pub mil_code: String,
    /// "Exclude from substitution" flag of the `NM` record.
    pub exclude_substitution: bool,
    /// Glass status of the `NM` record.
    pub status: Option<GlassStatus>,
    /// Melt frequency of the `NM` record.
    pub melt_frequency: Option<i64>,
    /// `GC` comment, trimmed.
    pub comment: String,
    /// `ED` record.
    pub extra: Option<ExtraData>,
    /// `IT` records in file order.
    pub transmission: Vec<TransmissionPoint>,
}

/// The physical range of a (relative) refractive index at the wavelengths diffcassi traces (100 nm–20 µm):
/// optical glasses are 1.4–2.1, crystals and infrared materials up to germanium's ~4.1. A formula outside it is
/// a damaged catalogue, refused by [`Glass::refractive_index`] naming glass, catalogue, wavelength and value.
pub const MIN_INDEX: f64 = 1.0;
/// See [`MIN_INDEX`].
pub const MAX_INDEX: f64 = 5.0;

impl Glass {
    /// A glass with the given core data; [`thermal`](Self::thermal) is `None` and
    /// [`info`](Self::info) is empty.
    pub fn new(
        name: impl Into<String>,
        formula: DispersionFormula,
        nd: f64,
        vd: f64,
        min_wavelength_nm: f64,
        max_wavelength_nm: f64,
        catalog: impl Into<String>,
    ) -> Self {
        Self {
            name: name.into(),
            formula,
            nd,
            vd,
            min_wavelength_nm,
            max_wavelength_nm,
            catalog: catalog.into(),
            thermal: None,
            info: GlassInfo::default(),
        }
    }

    /// `true` if `wavelength_nm` lies in the valid range [`valid_range_nm`](Self::valid_range_nm)
    /// (inclusive, with 1e-9 nm slack for the µm → nm conversion). `false` for NaN.
    #[inline]
    pub fn in_range(&self, wavelength_nm: f64) -> bool {
        let (lo, hi) = self.valid_range_nm();
        wavelength_nm >= lo - RANGE_SLACK_NM && wavelength_nm <= hi + RANGE_SLACK_NM
    }

    /// The catalogue range `[min_wavelength_nm, max_wavelength_nm]`, narrowed for a tabulated index to its
    /// table (so that a table is never extrapolated unless asked, whatever range a glass was built with).
    #[inline]
    pub fn valid_range_nm(&self) -> (f64, f64) {
        match self.formula.tabulated() {
            Some(t) => {
                let (lo, hi) = t.range_um();
                (self.min_wavelength_nm.max(lo * 1000.0), self.max_wavelength_nm.min(hi * 1000.0))
            }
            None => (self.min_wavelength_nm, self.max_wavelength_nm),
        }
    }

    /// Relative refractive index at `wavelength_nm` from the catalogue dispersion formula.
    ///
    /// # Errors
    /// [`MaterialError::NonFiniteWavelength`] for NaN/±∞,
    /// [`MaterialError::WavelengthOutOfRange`] outside the `LD` range,
    /// [`MaterialError::NonFiniteIndex`] if the formula gives NaN, ±∞ or n ≤ 0.
    pub fn refractive_index(&self, wavelength_nm: f64) -> Result<f64, MaterialError> {
        self.check_wavelength(wavelength_nm)?;
        if !self.in_range(wavelength_nm) {
            let (min_nm, max_nm) = self.valid_range_nm();
            return Err(MaterialError::WavelengthOutOfRange {
                glass: self.name.clone(),
                wavelength_nm,
                min_nm,
                max_nm,
            });
        }
        self.checked_index(wavelength_nm)
    }

    /// Like [`refractive_index`](Self::refractive_index) but without the `LD` range check
    /// (extrapolation). Non-finite wavelengths and invalid results are still errors.
    pub fn refractive_index_extrapolated(&self, wavelength_nm: f64) -> Result<f64, MaterialError> {
        self.check_wavelength(wavelength_nm)?;
        self.checked_index(wavelength_nm)
    }

    /// Evaluates the dispersion formula at `wavelength_nm` with no check at all (explicit
    /// opt-in extrapolation). May return NaN.
    #[inline]
    pub fn refractive_index_unchecked(&self, wavelength_nm: f64) -> f64 {
        self.formula.refractive_index(wavelength_nm)
    }

    /// Abbe number computed from the formula, vd = (nd − 1)/(nF − nC) at
    /// d = 587.5618 nm, F = 486.1327 nm, C = 656.2725 nm.
    ///
    /// # Errors
    /// If one of the three lines is outside the `LD` range.
    pub fn abbe_number(&self) -> Result<f64, MaterialError> {
        let nd = self.refractive_index(D_LINE_NM)?;
        let nf = self.refractive_index(F_LINE_NM)?;
        let nc = self.refractive_index(C_LINE_NM)?;
        Ok((nd - 1.0) / (nf - nc))
    }

    fn check_wavelength(&self, wavelength_nm: f64) -> Result<(), MaterialError> {
        if wavelength_nm.is_finite() {
            Ok(())
        } else {
            Err(MaterialError::NonFiniteWavelength {
                medium: self.name.clone(),
                wavelength_nm,
            })
        }
    }

    /// How far the formula's n at the d line (587.5618 nm) may be from the catalogue's `NM` n_d before
    /// [`nd_mismatch`](Self::nd_mismatch) reports it: 1e-3, a unit of the third decimal. Vendor catalogues agree
    /// to ~1e-5 (SUMITA's formulas to 3.8e-5, the legacy SCHOTT1980 Buchdahl fit to its fit error): every
    /// built-in catalogue and SCHOTT's AGF pass (tests/zmx_round5.rs); a damaged `CD` line does not.
    pub const ND_TOLERANCE: f64 = 1e-3;

    /// The formula's n at 587.5618 nm and the catalogue n_d, when they differ by more than
    /// [`ND_TOLERANCE`](Self::ND_TOLERANCE) (or the formula gives no index there); `None` when they agree or
    /// the d line is outside the glass's range.
    pub fn nd_mismatch(&self) -> Option<(f64, f64)> {
        if !self.in_range(D_LINE_NM) || !self.nd.is_finite() || self.nd == 0.0 {
            return None;
        }
        let n = self.formula.refractive_index(D_LINE_NM);
        (!(n.is_finite() && (n - self.nd).abs() <= Self::ND_TOLERANCE)).then_some((n, self.nd))
    }

    fn checked_index(&self, wavelength_nm: f64) -> Result<f64, MaterialError> {
        let n = self.formula.refractive_index(wavelength_nm);
        if n.is_finite() && n > 0.0 && !(MIN_INDEX..=MAX_INDEX).contains(&n) {
            return Err(MaterialError::ImplausibleIndex { glass: self.name.clone(), catalog: self.catalog.clone(), wavelength_nm, index: n, extrapolated: !self.in_range(wavelength_nm) });
        }
        if n.is_finite() && n > 0.0 {
            Ok(n)
        } else {
            Err(MaterialError::NonFiniteIndex {
                glass: self.name.clone(),
                catalog: self.catalog.clone(),
                formula: self.formula.label(),
                wavelength_nm,
                index: n,
                extrapolated: (!self.in_range(wavelength_nm)).then(|| self.valid_range_nm()),
            })
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bk7() -> Glass {
        Glass::new(
            "N-BK7",
            DispersionFormula::Sellmeier1(crate::materials::dispersion::N_BK7_SELLMEIER1),
            1.5168,
            64.17,
            0.3 * 1000.0,
            2.5 * 1000.0,
            "SCHOTT",
        )
    }

    #[test]
    fn range_is_inclusive() {
        let g = bk7();
        assert!(g.in_range(300.0));
        assert!(g.in_range(2500.0));
        assert!(!g.in_range(299.999));
        assert!(!g.in_range(2500.001));
        assert!(!g.in_range(f64::NAN));
        assert!(g.refractive_index(300.0).is_ok());
        assert!(g.refractive_index(2500.0).is_ok());
    }

    #[test]
    fn out_of_range_error_names_glass_and_value() {
        let g = bk7();
        let e = g.refractive_index(100.0).unwrap_err();
        assert!(
            matches!(e, MaterialError::WavelengthOutOfRange { wavelength_nm, .. } if wavelength_nm == 100.0)
        );
        let msg = e.to_string();
        assert!(msg.contains("N-BK7") && msg.contains("100"), "{msg}");
        assert!(g.refractive_index_extrapolated(100.0).is_ok());
    }

    #[test]
    fn non_finite_wavelength_is_error() {
        let g = bk7();
        for w in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            let e = g.refractive_index(w).unwrap_err();
            assert!(
                matches!(e, MaterialError::NonFiniteWavelength { .. }),
                "{e}"
            );
            assert!(g.refractive_index_extrapolated(w).is_err());
            assert!(e.to_string().contains("N-BK7"));
        }
    }

    #[test]
    fn invalid_index_is_error_when_extrapolating() {
        // Pole of the third Sellmeier term at sqrt(103.56) µm ≈ 10176 nm: n² < 0 just below it.
        let g = bk7();
        let e = g.refractive_index_extrapolated(10_150.0).unwrap_err();
        assert!(matches!(e, MaterialError::NonFiniteIndex { .. }), "{e}");
        assert!(g.refractive_index_unchecked(10_150.0).is_nan());
    }

    #[test]
    fn abbe_number_matches_catalogue() {
        let g = bk7();
        assert!((g.abbe_number().unwrap() - 64.17).abs() < 0.05);
    }

    /// A tabulated glass built with a wider range than its table is still refused outside the table, by
    /// name and with the table's range.
    #[test]
    fn tabulated_glass_is_refused_outside_its_table() {
        let t = crate::materials::TabulatedIndex::new(vec![(0.45, 1.53), (0.55, 1.525), (0.65, 1.52)]).unwrap();
        let g = Glass::new("TAB", DispersionFormula::Tabulated(t), 1.523, 58.0, 300.0, 2500.0, "X");
        assert_eq!(g.valid_range_nm(), (450.0, 650.0));
        assert!(g.in_range(450.0) && g.in_range(650.0) && !g.in_range(449.9) && !g.in_range(650.1));
        let e = g.refractive_index(700.0).unwrap_err().to_string();
        assert!(e.contains("TAB") && e.contains("700") && e.contains("[450, 650]"), "{e}");
        assert_eq!(g.refractive_index(550.0).unwrap(), 1.525);
        assert!(g.refractive_index_extrapolated(700.0).unwrap() < 1.52);
    }

    #[test]
    fn glass_status_codes() {
        assert_eq!(GlassStatus::from_code(1), Some(GlassStatus::Preferred));
        assert_eq!(GlassStatus::from_code(4), Some(GlassStatus::Melt));
        assert_eq!(GlassStatus::from_code(7), None);
    }
}
