//! Glass as a continuous (n_d, V_d) pair: the dispersion model used when a glass is a free parameter, and
//! the distance from such a point to the nearest catalogue glass (the design loss L_g).
//!
//! **Model: two-term Cauchy, n(λ) = A + B/λ²**, fitted so that the model's n_d and Abbe number
//! V_d = (n_d − 1)/(n_F − n_C) are *exactly* the parameters (d = 587.5618 nm, F = 486.1327 nm,
//! C = 656.2725 nm):
//!
//! B = (n_d − 1) / (V_d (λ_F⁻² − λ_C⁻²)),  A = n_d − B/λ_d².
//!
//! This is the model of the reference paper's tracer (dO / SIMCA "cauchy" glasses). It is written into a
//! catalogue as an ordinary AGF *Schott* formula glass (formula 1, n² = a0 + a2 λ⁻² + a3 λ⁻⁴ with
//! a0 = A², a2 = 2AB, a3 = B², λ in µm), so a system with model glasses traces with the unchanged tracer.
//!
//! Relation to the catalogue: a catalogue glass has a full Sellmeier curve; its Cauchy model shares only
//! its n_d and V_d (i.e. n_d, n_F − n_C). [`model_deviation`] measures the largest |n_Cauchy − n_Sellmeier|
//! over 450–650 nm: 2e-5 (N-SK2, SK10), 9e-5 (N-BK7), 2e-4 (N-BAF10), 1.3e-3 (N-SF10, SF10: a two-term
//! Cauchy cannot follow a dense flint's blue end). Reproduce with
//! `cargo test --release --test integration derivatives:: -- --nocapture glass_model`.
//!
//! ```
//! use diffcassi::diff::glass_model::CauchyGlass;
//! let g = CauchyGlass::new(1.5168, 64.17);
//! assert!((g.index(587.5618) - 1.5168).abs() < 1e-14);
//! assert!((g.abbe_number() - 64.17).abs() < 1e-9);
//! ```
use crate::materials::{DispersionFormula, Glass, GlassCatalog, GlassStatus, C_LINE_NM, D_LINE_NM, F_LINE_NM};

/// A two-term Cauchy glass defined by its n_d and V_d.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CauchyGlass {
    pub nd: f64,
    pub vd: f64,
}

/// λ_F⁻² − λ_C⁻² in µm⁻².
fn k_fc() -> f64 {
    let (f, c) = (F_LINE_NM / 1000.0, C_LINE_NM / 1000.0);
    1.0 / (f * f) - 1.0 / (c * c)
}

impl CauchyGlass {
    pub fn new(nd: f64, vd: f64) -> Self {
        CauchyGlass { nd, vd }
    }
    /// (A, B) of n = A + B/λ², λ in µm.
    pub fn coefficients(&self) -> (f64, f64) {
        let b = (self.nd - 1.0) / (self.vd * k_fc());
        let ld = D_LINE_NM / 1000.0;
        (self.nd - b / (ld * ld), b)
    }
    /// n(λ).
    pub fn index(&self, wavelength_nm: f64) -> f64 {
        let (a, b) = self.coefficients();
        let l = wavelength_nm / 1000.0;
        a + b / (l * l)
    }
    /// (n, ∂n/∂n_d, ∂n/∂V_d, ∂n/∂λ [per nm]) at `wavelength_nm`.
    pub fn index_derivatives(&self, wavelength_nm: f64) -> (f64, f64, f64, f64) {
        let (_, b) = self.coefficients();
        let l = wavelength_nm / 1000.0;
        let ld = D_LINE_NM / 1000.0;
        let u = 1.0 / (l * l) - 1.0 / (ld * ld); // n = n_d + B u
        let n = self.nd + b * u;
        let dn_dnd = 1.0 + u / (self.vd * k_fc());
        let dn_dvd = -b / self.vd * u;
        let dn_dl_um = -2.0 * b / (l * l * l);
        (n, dn_dnd, dn_dvd, dn_dl_um / 1000.0)
    }
    /// (n_d − 1)/(n_F − n_C) of the model (equals `vd` up to rounding).
    pub fn abbe_number(&self) -> f64 {
        (self.index(D_LINE_NM) - 1.0) / (self.index(F_LINE_NM) - self.index(C_LINE_NM))
    }
    /// The model as a catalogue glass called `name` (Schott formula, see the module docs), valid 300–2500 nm.
    pub fn to_glass(&self, name: &str) -> Glass {
        let (a, b) = self.coefficients();
        let formula = DispersionFormula::Schott([a * a, 0.0, 2.0 * a * b, b * b, 0.0, 0.0]);
        let mut g = Glass::new(name, formula, self.nd, self.vd, 300.0, 2500.0, "CAUCHY-MODEL");
        g.info.comment = format!("two-term Cauchy model of nd = {}, Vd = {}", self.nd, self.vd);
        g
    }
}

/// Largest |n_model(λ) − n_catalogue(λ)| over `[from_nm, to_nm]` (201 samples) for the Cauchy model built
/// from the glass's catalogue n_d, V_d.
pub fn model_deviation(glass: &Glass, from_nm: f64, to_nm: f64) -> f64 {
    let m = CauchyGlass::new(glass.nd, glass.vd);
    (0..=200)
        .map(|i| from_nm + (to_nm - from_nm) * i as f64 / 200.0)
        .map(|w| (m.index(w) - glass.refractive_index_unchecked(w)).abs())
        .fold(0.0, f64::max)
}

/// The (n_d, V_d) cloud of a catalogue and its ranges, for the glass distance L_g.
#[derive(Clone, Debug)]
pub struct GlassMap {
    pub names: Vec<String>,
    pub nd: Vec<f64>,
    pub vd: Vec<f64>,
    /// max − min of n_d and of V_d over the catalogue (the normalisation of the paper's L_g).
    pub nd_range: f64,
    pub vd_range: f64,
}

/// The nearest catalogue glass to a point and the normalised squared distance to it.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct NearestGlass {
    pub name: String,
    pub nd: f64,
    pub vd: f64,
    /// ((n_d − n_d,cat)/Δn_d)² + ((V_d − V_d,cat)/ΔV_d)².
    pub distance2: f64,
}

impl GlassMap {
    /// Every glass of `catalog` with a finite catalogue n_d, V_d, leaving out obsolete glasses and model
    /// glasses. Errors if none is left.
    pub fn from_catalog(catalog: &GlassCatalog) -> crate::Result<Self> {
        let (mut names, mut nd, mut vd) = (Vec::new(), Vec::new(), Vec::new());
        for g in catalog.iter() {
            if g.catalog == "CAUCHY-MODEL" || g.info.status == Some(GlassStatus::Obsolete) {
                continue;
            }
            if g.nd.is_finite() && g.vd.is_finite() && g.nd > 1.0 && g.vd > 0.0 {
                names.push(g.name.clone());
                nd.push(g.nd);
                vd.push(g.vd);
            }
        }
        if names.is_empty() {
            return Err(crate::Error::invalid("glass map: the catalogue has no usable glass (finite nd > 1, vd > 0)"));
        }
        let range = |v: &[f64]| v.iter().cloned().fold(f64::MIN, f64::max) - v.iter().cloned().fold(f64::MAX, f64::min);
        let (nd_range, vd_range) = (range(&nd).max(1e-6), range(&vd).max(1e-6));
        Ok(GlassMap { names, nd, vd, nd_range, vd_range })
    }

    /// The nearest glass (ties: the first in name order).
    pub fn nearest(&self, nd: f64, vd: f64) -> NearestGlass {
        let mut best = (f64::INFINITY, 0usize);
        for i in 0..self.names.len() {
            let a = (nd - self.nd[i]) / self.nd_range;
            let b = (vd - self.vd[i]) / self.vd_range;
            let d2 = a * a + b * b;
            if d2 < best.0 {
                best = (d2, i);
            }
        }
        let i = best.1;
        NearestGlass { name: self.names[i].clone(), nd: self.nd[i], vd: self.vd[i], distance2: best.0 }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn model_reproduces_nd_vd_and_its_schott_form() {
        let m = CauchyGlass::new(1.72, 28.5);
        let g = m.to_glass("M");
        for w in [450.0, 520.0, 587.5618, 650.0] {
            assert!((g.refractive_index(w).unwrap() - m.index(w)).abs() < 1e-15);
        }
        assert!((g.abbe_number().unwrap() - 28.5).abs() < 1e-9);
    }

    #[test]
    fn derivatives_match_finite_differences() {
        let m = CauchyGlass::new(1.6, 40.0);
        let w = 470.0;
        let (_, a, b, c) = m.index_derivatives(w);
        let h = 1e-6;
        let fd_nd = (CauchyGlass::new(1.6 + h, 40.0).index(w) - CauchyGlass::new(1.6 - h, 40.0).index(w)) / (2.0 * h);
        let fd_vd = (CauchyGlass::new(1.6, 40.0 + h).index(w) - CauchyGlass::new(1.6, 40.0 - h).index(w)) / (2.0 * h);
        let fd_w = (m.index(w + 1e-4) - m.index(w - 1e-4)) / 2e-4;
        assert!((a - fd_nd).abs() < 1e-8 && (b - fd_vd).abs() < 1e-10 && (c - fd_w).abs() < 1e-10);
    }
}
