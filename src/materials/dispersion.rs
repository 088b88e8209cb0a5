//! The 13 dispersion formulas of Zemax AGF glass catalogues, and a tabulated index.
//!
//! Each variant stores its coefficients **in the order of the AGF `CD` record**, and
//! evaluates the formula of the Zemax OpticStudio manual ("The Glass Dispersion Formulas").
//! In all formulas λ is the wavelength in **micrometres**; the `_nm` entry point divides by
//! 1000 first. Results are relative indices (relative to air at the catalogue reference
//! temperature and 1 atm).
//!
//! | AGF | variant | formula |
//! |----:|---------|---------|
//! | 1 | [`Schott`](DispersionFormula::Schott) | n² = a0 + a1 λ² + a2 λ⁻² + a3 λ⁻⁴ + a4 λ⁻⁶ + a5 λ⁻⁸ |
//! | 2 | [`Sellmeier1`](DispersionFormula::Sellmeier1) | n² − 1 = Σ₁³ Kᵢλ²/(λ² − Lᵢ) |
//! | 3 | [`Herzberger`](DispersionFormula::Herzberger) | n = A + B L + C L² + D λ² + E λ⁴ + F λ⁶, L = 1/(λ² − 0.028) |
//! | 4 | [`Sellmeier2`](DispersionFormula::Sellmeier2) | n² − 1 = A + B1 λ²/(λ² − λ1²) + B2/(λ² − λ2²) |
//! | 5 | [`Conrady`](DispersionFormula::Conrady) | n = n0 + A/λ + B/λ^3.5 |
//! | 6 | [`Sellmeier3`](DispersionFormula::Sellmeier3) | n² − 1 = Σ₁⁴ Kᵢλ²/(λ² − Lᵢ) |
//! | 7 | [`HandbookOfOptics1`](DispersionFormula::HandbookOfOptics1) | n² = A + B/(λ² − C) − D λ² |
//! | 8 | [`HandbookOfOptics2`](DispersionFormula::HandbookOfOptics2) | n² = A + B λ²/(λ² − C) − D λ² |
//! | 9 | [`Sellmeier4`](DispersionFormula::Sellmeier4) | n² = A + B λ²/(λ² − C) + D λ²/(λ² − E) |
//! | 10 | [`Extended`](DispersionFormula::Extended) | n² = a0 + a1 λ² + a2 λ⁻² + a3 λ⁻⁴ + a4 λ⁻⁶ + a5 λ⁻⁸ + a6 λ⁻¹⁰ + a7 λ⁻¹² |
//! | 11 | [`Sellmeier5`](DispersionFormula::Sellmeier5) | n² − 1 = Σ₁⁵ Kᵢλ²/(λ² − Lᵢ) |
//! | 12 | [`Extended2`](DispersionFormula::Extended2) | n² = a0 + a1 λ² + a2 λ⁻² + a3 λ⁻⁴ + a4 λ⁻⁶ + a5 λ⁻⁸ + a6 λ⁴ + a7 λ⁶ |
//! | 13 | [`Extended3`](DispersionFormula::Extended3) | n² = a0 + a1 λ² + a2 λ⁴ + a3 λ⁻² + a4 λ⁻⁴ + a5 λ⁻⁶ + a6 λ⁻⁸ + a7 λ⁻¹⁰ + a8 λ⁻¹² |
//! | — | [`Tabulated`](DispersionFormula::Tabulated) | the vendor's (λ, n) points, monotone cubic (PCHIP) in λ ([`super::tabulated`]) |
//! | — | [`Buchdahl`](DispersionFormula::Buchdahl) | n = n0 + ν1 ω + ν2 ω², ω = (λ − λ0)/(1 + 2.5 (λ − λ0)) |
//!
//! `Tabulated` is no AGF formula (OpticStudio's AGF has none): it holds a glass published as a table only
//! (SCHOTT B 270), carried by the built-in catalogues ([`super::builtin_catalogs`]), never read from a
//! user's AGF file. It has points, not coefficients ([`DispersionFormula::coefficients`] is empty, its
//! [`agf_number`](DispersionFormula::agf_number) 0), and is defined on its table's range only.
//!
//! `Buchdahl` is no AGF formula either: the quadratic model in Buchdahl's chromatic coordinate ω (H. A.
//! Buchdahl, *Optical Aberration Coefficients*, 1954; α = 2.5 for optical glasses), in which P. N. Robb and
//! R. I. Mercado published fits of the 1980 glass catalogues ("Calculation of refractive indices using
//! Buchdahl's chromatic coordinate", Appl. Opt. 22, 1198 (1983), Table V). It holds the legacy glasses of
//! the built-in `SCHOTT1980` catalogue ([`super::builtin_catalogs`]) and is never read from a user's AGF
//! file; its [`coefficients`](DispersionFormula::coefficients) are `[λ0 (µm), n0, ν1, ν2]`.
//!
//! Formulas 1 (Schott) and 2 (Sellmeier 1) are the only ones used by the Schott catalogue
//! and are validated against its `nd`/`vd` columns. Note on Sellmeier 2: the Zemax manual's
//! second term is `B2/(λ² − λ2²)` *without* a λ² factor; several third-party AGF readers
//! use `B2 λ²/(λ² − λ2²)` instead. This module follows the manual.
//!
//! # Example
//!
//! ```
//! use diffcassi::materials::DispersionFormula;
//!
//! // N-BK7, Sellmeier 1 coefficients K1 L1 K2 L2 K3 L3 from SCHOTT.AGF.
//! let bk7 = DispersionFormula::Sellmeier1([
//!     1.039612120E+00, 6.000698670E-03, 2.317923440E-01,
//!     2.001791440E-02, 1.010469450E+00, 1.035606530E+02,
//! ]);
//! assert_eq!(bk7.agf_number(), 2);
//! let n_d = bk7.refractive_index(587.5618);
//! assert!((n_d - 1.5168).abs() < 1e-4);
//! assert_eq!(n_d, bk7.refractive_index_um(0.5875618));
//! ```

use serde::{Deserialize, Serialize};

use super::tabulated::TabulatedIndex;
use super::MaterialError;

/// Helium d line, the wavelength of the catalogue `nd` column (nm).
pub const D_LINE_NM: f64 = 587.5618;
/// Hydrogen F line (nm), used for the Abbe number vd = (nd − 1)/(nF − nC).
pub const F_LINE_NM: f64 = 486.1327;
/// Hydrogen C line (nm), used for the Abbe number vd = (nd − 1)/(nF − nC).
pub const C_LINE_NM: f64 = 656.2725;

/// N-BK7's Sellmeier 1 coefficients K1 L1 K2 L2 K3 L3 (L in µm²), from SCHOTT.AGF: the built-in catalogue's
/// N-BK7 ([`super::GlassCatalog::builtin`]) and the reference glass of the materials tests.
pub const N_BK7_SELLMEIER1: [f64; 6] = [1.039612120E+00, 6.000698670E-03, 2.317923440E-01, 2.001791440E-02, 1.010469450E+00, 1.035606530E+02];

/// A Zemax AGF dispersion formula with its coefficients, in `CD` record order.
///
/// See the [module documentation](self) for the formulas.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum DispersionFormula {
    /// AGF 1: n² = a0 + a1 λ² + a2 λ⁻² + a3 λ⁻⁴ + a4 λ⁻⁶ + a5 λ⁻⁸. Coefficients `[a0..a5]`.
    Schott([f64; 6]),
    /// AGF 2: n² − 1 = K1λ²/(λ²−L1) + K2λ²/(λ²−L2) + K3λ²/(λ²−L3).
    /// Coefficients `[K1, L1, K2, L2, K3, L3]` (L in µm²).
    Sellmeier1([f64; 6]),
    /// AGF 3: n = A + B L + C L² + D λ² + E λ⁴ + F λ⁶ with L = 1/(λ² − 0.028).
    /// Coefficients `[A, B, C, D, E, F]`.
    Herzberger([f64; 6]),
    /// AGF 4: n² − 1 = A + B1λ²/(λ² − λ1²) + B2/(λ² − λ2²).
    /// Coefficients `[A, B1, λ1, B2, λ2]` (λ1, λ2 in µm).
    Sellmeier2([f64; 5]),
    /// AGF 5: n = n0 + A/λ + B/λ^3.5. Coefficients `[n0, A, B]`.
    Conrady([f64; 3]),
    /// AGF 6: n² − 1 = Σ_{i=1..4} Kᵢλ²/(λ² − Lᵢ). Coefficients `[K1, L1, .., K4, L4]`.
    Sellmeier3([f64; 8]),
    /// AGF 7: n² = A + B/(λ² − C) − Dλ². Coefficients `[A, B, C, D]`.
    HandbookOfOptics1([f64; 4]),
    /// AGF 8: n² = A + Bλ²/(λ² − C) − Dλ². Coefficients `[A, B, C, D]`.
    HandbookOfOptics2([f64; 4]),
    /// AGF 9: n² = A + Bλ²/(λ² − C) + Dλ²/(λ² − E). Coefficients `[A, B, C, D, E]`.
    Sellmeier4([f64; 5]),
    /// AGF 10: n² = a0 + a1λ² + a2λ⁻² + a3λ⁻⁴ + a4λ⁻⁶ + a5λ⁻⁸ + a6λ⁻¹⁰ + a7λ⁻¹².
    /// Coefficients `[a0..a7]`.
    Extended([f64; 8]),
    /// AGF 11: n² − 1 = Σ_{i=1..5} Kᵢλ²/(λ² − Lᵢ). Coefficients `[K1, L1, .., K5, L5]`.
    Sellmeier5([f64; 10]),
    /// AGF 12: n² = a0 + a1λ² + a2λ⁻² + a3λ⁻⁴ + a4λ⁻⁶ + a5λ⁻⁸ + a6λ⁴ + a7λ⁶.
    /// Coefficients `[a0..a7]`.
    Extended2([f64; 8]),
    /// AGF 13: n² = a0 + a1λ² + a2λ⁴ + a3λ⁻² + a4λ⁻⁴ + a5λ⁻⁶ + a6λ⁻⁸ + a7λ⁻¹⁰ + a8λ⁻¹².
    /// Coefficients `[a0..a8]`.
    Extended3([f64; 9]),
    /// No AGF formula: n at the vendor's tabulated wavelengths, interpolated by a monotone cubic in λ
    /// ([`TabulatedIndex`]). Built-in catalogues only (see the [module documentation](self)).
    Tabulated(TabulatedIndex),
    /// No AGF formula: Buchdahl's quadratic model n = n0 + ν1 ω + ν2 ω² in the chromatic coordinate
    /// ω = (λ − λ0)/(1 + 2.5 (λ − λ0)) (λ, λ0 in µm; n0 the index at λ0). Coefficients `[λ0, n0, ν1, ν2]`.
    /// Built-in legacy catalogues only (see the [module documentation](self)).
    Buchdahl([f64; 4]),
}

/// Buchdahl's α for optical glasses: ω = Δλ/(1 + α Δλ), Δλ in µm (Robb & Mercado 1983 use 2.5).
pub const BUCHDAHL_ALPHA_PER_UM: f64 = 2.5;

/// Buchdahl's chromatic coordinate ω of `wavelength_um` about `base_um`, and dω/dλ (µm⁻¹).
#[inline]
pub fn buchdahl_omega(wavelength_um: f64, base_um: f64) -> (f64, f64) {
    let d = wavelength_um - base_um;
    let q = 1.0 + BUCHDAHL_ALPHA_PER_UM * d;
    (d / q, 1.0 / (q * q))
}

/// Copies the first `N` values; the caller has checked the length.
fn take<const N: usize>(c: &[f64]) -> [f64; N] {
    let mut out = [0.0; N];
    out.copy_from_slice(&c[..N]);
    out
}

/// λ⁻², λ⁻⁴, …, λ⁻¹² from λ² (the power series of the Schott and Extended formulas; each power computed as
/// the formulas always have: λ⁻⁶ = λ⁻⁴λ⁻², λ⁻⁸ = λ⁻⁴λ⁻⁴, λ⁻¹⁰ = λ⁻⁸λ⁻², λ⁻¹² = λ⁻⁸λ⁻⁴).
#[inline]
fn inverse_powers(l2: f64) -> [f64; 6] {
    let i2 = 1.0 / l2;
    let i4 = i2 * i2;
    let i8 = i4 * i4;
    [i2, i4, i4 * i2, i8, i8 * i2, i8 * i4]
}

/// a₀ + a₁p₁ + a₂p₂ + … summed left to right (as the formulas are written out), `powers` = p₁, p₂, ….
#[inline]
fn series(a: &[f64], powers: &[f64]) -> f64 {
    a[1..].iter().zip(powers).fold(a[0], |s, (c, p)| s + c * p)
}

/// Σ Kᵢλ²/(λ² − Lᵢ) over `(K, L)` pairs.
#[inline]
fn sellmeier_sum(l2: f64, pairs: &[f64]) -> f64 {
    pairs
        .chunks_exact(2)
        .map(|kl| kl[0] * l2 / (l2 - kl[1]))
        .sum()
}

impl DispersionFormula {
    /// Number of coefficients used by AGF formula `formula_number`, or `None` if the
    /// number is not one of 1..=13.
    pub const fn coefficient_count(formula_number: u32) -> Option<usize> {
        match formula_number {
            1 => Some(6),
            2 => Some(6),
            3 => Some(6),
            4 => Some(5),
            5 => Some(3),
            6 => Some(8),
            7 => Some(4),
            8 => Some(4),
            9 => Some(5),
            10 => Some(8),
            11 => Some(10),
            12 => Some(8),
            13 => Some(9),
            _ => None,
        }
    }

    /// Builds a formula from the AGF formula number (`NM` record) and the coefficients
    /// (`CD` record). Extra trailing coefficients are ignored (catalogues pad `CD` with
    /// zeros to 8 or 10 values); too few is an error.
    ///
    /// `glass` is only used in error messages.
    pub fn from_agf(
        glass: &str,
        formula_number: u32,
        coefficients: &[f64],
    ) -> Result<Self, MaterialError> {
        let expected = Self::coefficient_count(formula_number).ok_or_else(|| {
            MaterialError::UnsupportedFormula {
                glass: glass.to_string(),
                formula: i64::from(formula_number),
            }
        })?;
        if coefficients.len() < expected {
            return Err(MaterialError::CoefficientCount {
                glass: glass.to_string(),
                formula: formula_number,
                formula_name: Self::name_of(formula_number).unwrap_or("?"),
                expected,
                found: coefficients.len(),
            });
        }
        let c = coefficients;
        Ok(match formula_number {
            1 => Self::Schott(take(c)),
            2 => Self::Sellmeier1(take(c)),
            3 => Self::Herzberger(take(c)),
            4 => Self::Sellmeier2(take(c)),
            5 => Self::Conrady(take(c)),
            6 => Self::Sellmeier3(take(c)),
            7 => Self::HandbookOfOptics1(take(c)),
            8 => Self::HandbookOfOptics2(take(c)),
            9 => Self::Sellmeier4(take(c)),
            10 => Self::Extended(take(c)),
            11 => Self::Sellmeier5(take(c)),
            12 => Self::Extended2(take(c)),
            13 => Self::Extended3(take(c)),
            _ => unreachable!("coefficient_count accepted formula {formula_number}"),
        })
    }

    /// Zemax name of AGF formula `formula_number` (e.g. `"Sellmeier 1"`).
    pub const fn name_of(formula_number: u32) -> Option<&'static str> {
        match formula_number {
            1 => Some("Schott"),
            2 => Some("Sellmeier 1"),
            3 => Some("Herzberger"),
            4 => Some("Sellmeier 2"),
            5 => Some("Conrady"),
            6 => Some("Sellmeier 3"),
            7 => Some("Handbook of Optics 1"),
            8 => Some("Handbook of Optics 2"),
            9 => Some("Sellmeier 4"),
            10 => Some("Extended"),
            11 => Some("Sellmeier 5"),
            12 => Some("Extended 2"),
            13 => Some("Extended 3"),
            _ => None,
        }
    }

    /// The AGF formula number (1..=13); 0 for [`Tabulated`](Self::Tabulated), which has none.
    pub const fn agf_number(&self) -> u32 {
        match self {
            Self::Schott(_) => 1,
            Self::Sellmeier1(_) => 2,
            Self::Herzberger(_) => 3,
            Self::Sellmeier2(_) => 4,
            Self::Conrady(_) => 5,
            Self::Sellmeier3(_) => 6,
            Self::HandbookOfOptics1(_) => 7,
            Self::HandbookOfOptics2(_) => 8,
            Self::Sellmeier4(_) => 9,
            Self::Extended(_) => 10,
            Self::Sellmeier5(_) => 11,
            Self::Extended2(_) => 12,
            Self::Extended3(_) => 13,
            Self::Tabulated(_) | Self::Buchdahl(_) => 0,
        }
    }

    /// The Zemax name of this formula (e.g. `"Schott"`); `"Tabulated"` for a tabulated index, `"Buchdahl"`
    /// for Buchdahl's model.
    pub fn name(&self) -> &'static str {
        match self {
            Self::Tabulated(_) => "Tabulated",
            Self::Buchdahl(_) => "Buchdahl",
            _ => Self::name_of(self.agf_number()).unwrap_or("?"),
        }
    }

    /// What `info` shows: `Sellmeier 1 (AGF 2)`, `tabulated (8 points, monotone cubic (PCHIP) in λ)`, or
    /// `Buchdahl quadratic about 0.574 µm`.
    pub fn label(&self) -> String {
        match self {
            Self::Tabulated(t) => t.label(),
            Self::Buchdahl(c) => format!("Buchdahl quadratic about {} µm", c[0]),
            _ => format!("{} (AGF {})", self.name(), self.agf_number()),
        }
    }

    /// The table of a [`Tabulated`](Self::Tabulated) index, `None` for a formula.
    pub fn tabulated(&self) -> Option<&TabulatedIndex> {
        match self {
            Self::Tabulated(t) => Some(t),
            _ => None,
        }
    }

    /// The coefficients in AGF `CD` order; empty for a [`Tabulated`](Self::Tabulated) index, which has
    /// points instead ([`tabulated`](Self::tabulated)); `[λ0 (µm), n0, ν1, ν2]` for [`Buchdahl`](Self::Buchdahl).
    pub fn coefficients(&self) -> &[f64] {
        match self {
            Self::Schott(c) | Self::Sellmeier1(c) | Self::Herzberger(c) => c,
            Self::Sellmeier2(c) | Self::Sellmeier4(c) => c,
            Self::Conrady(c) => c,
            Self::Sellmeier3(c) | Self::Extended(c) | Self::Extended2(c) => c,
            Self::HandbookOfOptics1(c) | Self::HandbookOfOptics2(c) => c,
            Self::Sellmeier5(c) => c,
            Self::Extended3(c) => c,
            Self::Buchdahl(c) => c,
            Self::Tabulated(_) => &[],
        }
    }

    /// Relative index at `wavelength_nm` (converted to µm as `wavelength_nm / 1000`).
    /// No range or finiteness check: may return NaN (negative n²) or ±∞ (at a pole).
    #[inline]
    pub fn refractive_index(&self, wavelength_nm: f64) -> f64 {
        self.refractive_index_um(wavelength_nm / 1000.0)
    }

    /// Relative index at `wavelength_um` (micrometres), evaluating the formula of the
    /// variant (see the [module table](self)). No range or finiteness check (a tabulated index continues as
    /// the straight line of its end slope outside its table: [`TabulatedIndex::index_um`]).
    pub fn refractive_index_um(&self, wavelength_um: f64) -> f64 {
        let w = wavelength_um;
        let l2 = w * w;
        match self {
            Self::Schott(a) => {
                let [i2, i4, i6, i8, ..] = inverse_powers(l2);
                series(a, &[l2, i2, i4, i6, i8]).sqrt()
            }
            Self::Sellmeier1(c) => (1.0 + sellmeier_sum(l2, c)).sqrt(),
            Self::Herzberger(c) => {
                let l = 1.0 / (l2 - 0.028);
                let l4 = l2 * l2;
                c[0] + c[1] * l + c[2] * l * l + c[3] * l2 + c[4] * l4 + c[5] * l4 * l2
            }
            Self::Sellmeier2(c) => {
                let n2 = 1.0 + c[0] + c[1] * l2 / (l2 - c[2] * c[2]) + c[3] / (l2 - c[4] * c[4]);
                n2.sqrt()
            }
            Self::Conrady(c) => c[0] + c[1] / w + c[2] / w.powf(3.5),
            Self::Sellmeier3(c) => (1.0 + sellmeier_sum(l2, c)).sqrt(),
            Self::HandbookOfOptics1(c) => (c[0] + c[1] / (l2 - c[2]) - c[3] * l2).sqrt(),
            Self::HandbookOfOptics2(c) => (c[0] + c[1] * l2 / (l2 - c[2]) - c[3] * l2).sqrt(),
            Self::Sellmeier4(c) => {
                (c[0] + c[1] * l2 / (l2 - c[2]) + c[3] * l2 / (l2 - c[4])).sqrt()
            }
            Self::Extended(a) => {
                let [i2, i4, i6, i8, i10, i12] = inverse_powers(l2);
                series(a, &[l2, i2, i4, i6, i8, i10, i12]).sqrt()
            }
            Self::Sellmeier5(c) => (1.0 + sellmeier_sum(l2, c)).sqrt(),
            Self::Extended2(a) => {
                let [i2, i4, i6, i8, ..] = inverse_powers(l2);
                let l4 = l2 * l2;
                series(a, &[l2, i2, i4, i6, i8, l4, l4 * l2]).sqrt()
            }
            Self::Extended3(a) => {
                let [i2, i4, i6, i8, i10, i12] = inverse_powers(l2);
                series(a, &[l2, l2 * l2, i2, i4, i6, i8, i10, i12]).sqrt()
            }
            Self::Tabulated(t) => t.index_um(w),
            Self::Buchdahl(c) => {
                let (o, _) = buchdahl_omega(w, c[0]);
                c[1] + c[2] * o + c[3] * o * o
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const BK7: [f64; 6] = N_BK7_SELLMEIER1;

    #[test]
    fn sellmeier1_n_bk7_d_line() {
        let f = DispersionFormula::Sellmeier1(BK7);
        let n = f.refractive_index(D_LINE_NM);
        assert!((n - 1.5168).abs() < 1e-4, "n = {n}");
        // Independent hand evaluation of the same formula.
        let w2 = 0.5875618_f64 * 0.5875618;
        let expect = (1.0
            + BK7[0] * w2 / (w2 - BK7[1])
            + BK7[2] * w2 / (w2 - BK7[3])
            + BK7[4] * w2 / (w2 - BK7[5]))
            .sqrt();
        assert!((n - expect).abs() < 1e-15);
    }

    #[test]
    fn schott_formula_b270() {
        // B270 (SCHOTT.AGF, formula 1): nd = 1.523080.
        let f = DispersionFormula::Schott([
            2.286575000E+000,
            -8.733458200E-003,
            1.174288400E-002,
            2.904175600E-004,
            -1.250669500E-005,
            9.264625300E-007,
        ]);
        assert!((f.refractive_index(D_LINE_NM) - 1.523080).abs() < 1e-5);
    }

    #[test]
    fn all_formulas_constructible_and_numbered() {
        for k in 1..=13u32 {
            let n = DispersionFormula::coefficient_count(k).unwrap();
            let f = DispersionFormula::from_agf("X", k, &vec![0.0; n]).unwrap();
            assert_eq!(f.agf_number(), k);
            assert_eq!(f.coefficients().len(), n);
            assert_eq!(Some(f.name()), DispersionFormula::name_of(k));
        }
        assert!(matches!(
            DispersionFormula::from_agf("X", 14, &[0.0; 10]),
            Err(MaterialError::UnsupportedFormula { formula: 14, .. })
        ));
        assert!(matches!(
            DispersionFormula::from_agf("X", 2, &[1.0; 5]),
            Err(MaterialError::CoefficientCount {
                expected: 6,
                found: 5,
                ..
            })
        ));
    }

    /// Formulas that must reduce to each other for suitable coefficients.
    #[test]
    fn formula_cross_consistency() {
        let w = 0.55;
        let s1 = DispersionFormula::Sellmeier1(BK7).refractive_index_um(w);
        // Sellmeier 3 / 5 with trailing zero terms (L = 0 keeps the term finite).
        let mut c8 = [0.0; 8];
        c8[..6].copy_from_slice(&BK7);
        let mut c10 = [0.0; 10];
        c10[..6].copy_from_slice(&BK7);
        assert!((DispersionFormula::Sellmeier3(c8).refractive_index_um(w) - s1).abs() < 1e-15);
        assert!((DispersionFormula::Sellmeier5(c10).refractive_index_um(w) - s1).abs() < 1e-15);
        // Sellmeier 4 with A = 1 and two terms equals Sellmeier 1 with two terms.
        let s1_two = DispersionFormula::Sellmeier1([BK7[0], BK7[1], BK7[2], BK7[3], 0.0, 0.0])
            .refractive_index_um(w);
        let s4 = DispersionFormula::Sellmeier4([1.0, BK7[0], BK7[1], BK7[2], BK7[3]])
            .refractive_index_um(w);
        assert!((s4 - s1_two).abs() < 1e-15);
        // Sellmeier 2 with B2 = 0: n² = 1 + A + B1 λ²/(λ² − λ1²).
        let s2 = DispersionFormula::Sellmeier2([0.0, BK7[0], BK7[1].sqrt(), 0.0, 0.0])
            .refractive_index_um(w);
        let s1_one = DispersionFormula::Sellmeier1([BK7[0], BK7[1], 0.0, 0.0, 0.0, 0.0])
            .refractive_index_um(w);
        assert!((s2 - s1_one).abs() < 1e-14);
        // Sellmeier 2 second term has no λ² factor: n² = 1 + B2/(λ² − λ2²).
        let s2b = DispersionFormula::Sellmeier2([0.0, 0.0, 0.0, 0.5, 0.1]).refractive_index_um(w);
        assert!((s2b - (1.0 + 0.5 / (w * w - 0.01)).sqrt()).abs() < 1e-15);
        // Extended / Extended 2 / Extended 3 reduce to Schott with extra terms zero.
        let sc = [2.2, -0.01, 0.012, 3e-4, -1e-5, 1e-6];
        let schott = DispersionFormula::Schott(sc).refractive_index_um(w);
        let mut e = [0.0; 8];
        e[..6].copy_from_slice(&sc);
        assert!((DispersionFormula::Extended(e).refractive_index_um(w) - schott).abs() < 1e-15);
        assert!((DispersionFormula::Extended2(e).refractive_index_um(w) - schott).abs() < 1e-15);
        let e3 = [sc[0], sc[1], 0.0, sc[2], sc[3], sc[4], sc[5], 0.0, 0.0];
        assert!((DispersionFormula::Extended3(e3).refractive_index_um(w) - schott).abs() < 1e-15);
        // Higher-order terms individually.
        let x = 1.3_f64;
        let mut e = [0.0; 8];
        e[0] = 1.0;
        e[6] = 0.1; // λ⁻¹⁰ in Extended, λ⁴ in Extended 2
        e[7] = 0.01; // λ⁻¹² in Extended, λ⁶ in Extended 2
        let ext = DispersionFormula::Extended(e).refractive_index_um(x);
        assert!((ext - (1.0 + 0.1 * x.powi(-10) + 0.01 * x.powi(-12)).sqrt()).abs() < 1e-14);
        let ext2 = DispersionFormula::Extended2(e).refractive_index_um(x);
        assert!((ext2 - (1.0 + 0.1 * x.powi(4) + 0.01 * x.powi(6)).sqrt()).abs() < 1e-14);
        let ext3 = DispersionFormula::Extended3([1.0, 0.0, 0.2, 0.0, 0.0, 0.0, 0.0, 0.1, 0.01])
            .refractive_index_um(x);
        assert!(
            (ext3 - (1.0 + 0.2 * x.powi(4) + 0.1 * x.powi(-10) + 0.01 * x.powi(-12)).sqrt()).abs()
                < 1e-14
        );
    }

    #[test]
    fn closed_forms_of_non_sellmeier_formulas() {
        let w: f64 = 0.6;
        let h = DispersionFormula::Herzberger([1.5, 0.01, 0.001, -0.002, 1e-4, -1e-6]);
        let l = 1.0 / (w * w - 0.028);
        let expect = 1.5 + 0.01 * l + 0.001 * l * l - 0.002 * w.powi(2) + 1e-4 * w.powi(4)
            - 1e-6 * w.powi(6);
        assert!((h.refractive_index_um(w) - expect).abs() < 1e-15);

        let c = DispersionFormula::Conrady([1.5, 0.01, 0.001]);
        assert!((c.refractive_index_um(w) - (1.5 + 0.01 / w + 0.001 / w.powf(3.5))).abs() < 1e-15);

        let h1 = DispersionFormula::HandbookOfOptics1([2.3, 0.01, 0.02, 0.01]);
        let e1 = (2.3 + 0.01 / (w * w - 0.02) - 0.01 * w * w).sqrt();
        assert!((h1.refractive_index_um(w) - e1).abs() < 1e-15);

        let h2 = DispersionFormula::HandbookOfOptics2([2.3, 0.01, 0.02, 0.01]);
        let e2 = (2.3 + 0.01 * w * w / (w * w - 0.02) - 0.01 * w * w).sqrt();
        assert!((h2.refractive_index_um(w) - e2).abs() < 1e-15);
    }

    #[test]
    fn nm_and_um_entry_points_agree() {
        let f = DispersionFormula::Sellmeier1(BK7);
        assert_eq!(f.refractive_index(500.0), f.refractive_index_um(0.5));
    }

    #[test]
    fn serde_round_trip() {
        let f = DispersionFormula::Sellmeier1(BK7);
        let s = serde_json::to_string(&f).unwrap();
        let g: DispersionFormula = serde_json::from_str(&s).unwrap();
        assert_eq!(f, g);
        let t = DispersionFormula::Tabulated(TabulatedIndex::new(vec![(0.5, 1.52), (0.6, 1.51), (0.7, 1.505)]).unwrap());
        let s = serde_json::to_string(&t).unwrap();
        assert_eq!(serde_json::from_str::<DispersionFormula>(&s).unwrap(), t);
    }

    /// Buchdahl's model written out (Robb & Mercado's SCHOTT BK7 row: n0 1.517385 at 0.574 µm): n0 at λ0, the
    /// closed form elsewhere, no AGF number, its label and serde round trip.
    #[test]
    fn buchdahl_quadratic_in_the_chromatic_coordinate() {
        let c = [0.574, 1.517385, -0.44736e-1, -0.32737e-2];
        let f = DispersionFormula::Buchdahl(c);
        assert_eq!(f.refractive_index_um(0.574), 1.517385);
        let w: f64 = 0.48613;
        let o = (w - 0.574) / (1.0 + 2.5 * (w - 0.574));
        assert!((f.refractive_index_um(w) - (1.517385 - 0.44736e-1 * o - 0.32737e-2 * o * o)).abs() < 1e-15);
        assert_eq!((f.agf_number(), f.name(), f.coefficients()), (0, "Buchdahl", &c[..]));
        assert_eq!(f.label(), "Buchdahl quadratic about 0.574 µm");
        let s = serde_json::to_string(&f).unwrap();
        assert_eq!(serde_json::from_str::<DispersionFormula>(&s).unwrap(), f);
    }

    #[test]
    fn tabulated_has_no_agf_number_nor_coefficients() {
        let t = DispersionFormula::Tabulated(TabulatedIndex::new(vec![(0.5, 1.52), (0.6, 1.51)]).unwrap());
        assert_eq!((t.agf_number(), t.name(), t.coefficients().len()), (0, "Tabulated", 0));
        assert_eq!(t.label(), "tabulated (2 points, monotone cubic (PCHIP) in λ)");
        assert_eq!(DispersionFormula::Sellmeier1(BK7).label(), "Sellmeier 1 (AGF 2)");
        assert_eq!(t.refractive_index(500.0), 1.52);
        assert!(t.tabulated().is_some() && DispersionFormula::Sellmeier1(BK7).tabulated().is_none());
    }
}
