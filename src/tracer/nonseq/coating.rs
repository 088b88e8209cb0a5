//! Per-surface coatings and the interface coefficients the ray tree uses.
//!
//! * bare surface: the Fresnel amplitudes of [`super::fresnel`];
//! * [`Coating::Reflectance`]`(R)`: a given power reflectance for both polarisations at every angle and
//!   wavelength (amplitudes √R and √(1 − R), no phase); R = 1 under total internal reflection;
//! * [`Coating::Mgf2QuarterWaveNm`]`(λ₀)`: one MgF₂ layer of optical thickness λ₀/4 at normal incidence
//!   (physical thickness λ₀/(4 n_MgF₂(λ₀))), by the single-film (Airy) formula of Born & Wolf §1.6.4
//!   (eq. (57)): r = (r₀₁ + r₁₂ e^{2iβ})/(1 + r₀₁ r₁₂ e^{2iβ}), β = (2π/λ) n₁ d cos θ₁, with the s or p
//!   Fresnel amplitudes r₀₁, r₁₂ of the two boundaries at complex cosines where needed. The film and the
//!   media are lossless, so the transmitted power is 1 − R; the phase of the transmitted amplitude
//!   (a small s/p retardance) is not modelled.
//!
//! MgF₂ index: the ordinary ray of M. J. Dodge, "Refractive properties of magnesium fluoride",
//! Appl. Opt. 23, 1980–1985 (1984), Sellmeier fit 0.2–7 µm:
//! n² − 1 = 0.48755108 λ²/(λ² − 0.04338408²) + 0.39875031 λ²/(λ² − 0.09461442²) + 2.3120353 λ²/(λ² − 23.793604²), λ in µm.
//!
//! ```
//! use diffcassi::spec::Coating;
//! use diffcassi::tracer::nonseq::coating::{interface_coefficients, mgf2_index};
//! assert!((mgf2_index(550.0) - 1.3777).abs() < 1e-3);
//! let bare = interface_coefficients(None, 1.0, 1.5168, 1.0, 550.0);
//! let ar = interface_coefficients(Some(&Coating::Mgf2QuarterWaveNm(550.0)), 1.0, 1.5168, 1.0, 550.0);
//! assert!(ar.reflectance() < 0.015 && bare.reflectance() > 0.04);
//! ```
use super::fresnel::amplitudes;
use crate::spec::Coating;
use num_complex::Complex64 as C64;

/// Refractive index of MgF₂ (ordinary ray, Dodge 1984) at `wavelength_nm`.
pub fn mgf2_index(wavelength_nm: f64) -> f64 {
    let l2 = (wavelength_nm * 1e-3).powi(2);
    let term = |b: f64, c: f64| b * l2 / (l2 - c * c);
    (1.0 + term(0.48755108, 0.04338408) + term(0.39875031, 0.09461442) + term(2.3120353, 23.793604)).sqrt()
}

/// Interface coefficients for the ray tree: complex reflected amplitudes and flux-normalised transmitted
/// amplitudes (|t̃|² is the transmitted power fraction), for s and p.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Coefficients {
    pub rs: C64,
    pub rp: C64,
    pub ts: C64,
    pub tp: C64,
    /// Total internal reflection (nothing transmitted).
    pub tir: bool,
}

impl Coefficients {
    /// The s/p-averaged power reflectance (the scalar model).
    pub fn reflectance(&self) -> f64 {
        0.5 * (self.rs.norm_sqr() + self.rp.norm_sqr())
    }
}

/// The coefficients of an interface with `coating` (None: bare) for light from `n1` into `n2` at
/// cos θᵢ = `cos_i`, wavelength `wavelength_nm`.
pub fn interface_coefficients(coating: Option<&Coating>, n1: f64, n2: f64, cos_i: f64, wavelength_nm: f64) -> Coefficients {
    let bare = amplitudes(n1, n2, cos_i);
    let flux = |r: C64| C64::new((1.0 - r.norm_sqr()).max(0.0).sqrt(), 0.0);
    match coating {
        None => {
            if bare.tir {
                return Coefficients { rs: bare.rs, rp: bare.rp, ts: C64::new(0.0, 0.0), tp: C64::new(0.0, 0.0), tir: true };
            }
            let f = (bare.n2 * bare.cos_t / (bare.n1 * bare.cos_i)).sqrt();
            Coefficients { rs: bare.rs, rp: bare.rp, ts: bare.ts * f, tp: bare.tp * f, tir: false }
        }
        Some(Coating::Reflectance(r)) => {
            if bare.tir {
                return Coefficients { rs: C64::new(1.0, 0.0), rp: C64::new(1.0, 0.0), ts: C64::new(0.0, 0.0), tp: C64::new(0.0, 0.0), tir: true };
            }
            let (a, t) = (C64::new(r.sqrt(), 0.0), C64::new((1.0 - r).sqrt(), 0.0));
            Coefficients { rs: a, rp: a, ts: t, tp: t, tir: false }
        }
        Some(Coating::Mgf2QuarterWaveNm(design_nm)) => {
            let nf = mgf2_index(wavelength_nm);
            let thickness_nm = design_nm / (4.0 * mgf2_index(*design_nm));
            let ci = bare.cos_i;
            let s2 = 1.0 - ci * ci; // sin² θ₀
            let cos_in = |n: f64| C64::new(1.0 - (n1 / n) * (n1 / n) * s2, 0.0).sqrt();
            let (c0, c1, c2) = (C64::new(ci, 0.0), cos_in(nf), cos_in(n2));
            let rs_ab = |na: f64, ca: C64, nb: f64, cb: C64| (ca * na - cb * nb) / (ca * na + cb * nb);
            let rp_ab = |na: f64, ca: C64, nb: f64, cb: C64| (ca * nb - cb * na) / (ca * nb + cb * na);
            let phase = (C64::i() * 2.0 * (2.0 * std::f64::consts::PI / wavelength_nm) * nf * thickness_nm * c1).exp();
            let film = |r01: C64, r12: C64| (r01 + r12 * phase) / (C64::new(1.0, 0.0) + r01 * r12 * phase);
            let rs = film(rs_ab(n1, c0, nf, c1), rs_ab(nf, c1, n2, c2));
            let rp = film(rp_ab(n1, c0, nf, c1), rp_ab(nf, c1, n2, c2));
            if bare.tir {
                // Beyond the critical angle of n₁ → n₂ the film cannot transmit: |r| = 1 (up to rounding).
                return Coefficients { rs: rs / rs.norm(), rp: rp / rp.norm(), ts: C64::new(0.0, 0.0), tp: C64::new(0.0, 0.0), tir: true };
            }
            Coefficients { rs, rp, ts: flux(rs), tp: flux(rp), tir: false }
        }
    }
}

/// A command-line override of the spec's per-surface coatings (`render --coating SPEC`): a comma list of
/// `TARGET=VALUE`, applied left to right, where TARGET is `all` or a sequential surface index and VALUE is
/// `bare` (no coating: Fresnel), `R<x>` (a given reflectance x ∈ [0, 1], e.g. `R0.01`) or `mgf2@<nm>` (a
/// quarter-wave MgF₂ layer designed for that wavelength, in [200, 7000] nm). Example:
/// `all=mgf2@550,16=R0.001`.
#[derive(Clone, Debug, PartialEq)]
pub struct CoatingOverride {
    /// (surface index or `None` for all, the coating or `None` for bare), in order.
    pub items: Vec<(Option<usize>, Option<Coating>)>,
    /// The text it was parsed from (for reports).
    pub text: String,
}

impl std::str::FromStr for CoatingOverride {
    type Err = String;
    /// Errors name the item and the value.
    fn from_str(text: &str) -> Result<Self, String> {
        let mut items = Vec::new();
        for item in text.split(',').map(str::trim) {
            let Some((target, value)) = item.split_once('=') else {
                return Err(format!("`{item}`: expected TARGET=VALUE (TARGET all or a surface index; VALUE bare, R<reflectance> or mgf2@<nm>)"));
            };
            let target = match target.trim() {
                "all" => None,
                t => Some(t.parse::<usize>().map_err(|_| format!("`{item}`: the target `{t}` is neither `all` nor a surface index"))?),
            };
            let value = value.trim();
            let coating = if value == "bare" {
                None
            } else if let Some(r) = value.strip_prefix('R').or_else(|| value.strip_prefix('r')) {
                let x: f64 = r.parse().map_err(|_| format!("`{item}`: the reflectance `{r}` is not a number (a fraction in [0, 1], written without a space or suffix: R0.01)"))?;
                // A value that rounds to 0 is not the 0 written (R1e-400 read as 0): refused; −0 is 0.
                let mantissa = r.split(['e', 'E']).next().unwrap_or("");
                if x == 0.0 && mantissa.bytes().any(|b| (b'1'..=b'9').contains(&b)) {
                    return Err(format!("`{item}`: the reflectance `{r}` is below f64's range and would be read as 0: write R0 for none"));
                }
                Some(Coating::Reflectance(x + 0.0))
            } else if let Some(w) = value.strip_prefix("mgf2@") {
                // One rule for every value: a plain number, its unit implied (reflectance: a fraction; design
                // wavelength: nm), no unit suffix and no space inside (`mgf2@550nm` and `R 0.01` alike refused).
                let w: f64 = w.parse().map_err(|_| format!("`{item}`: the design wavelength `{w}` is not a number of nm (written without a space or unit suffix: mgf2@550)"))?;
                Some(Coating::Mgf2QuarterWaveNm(w))
            } else {
                return Err(format!("`{item}`: the coating `{value}` is not bare, R<reflectance> (e.g. R0.01) or mgf2@<nm> (e.g. mgf2@550)"));
            };
            if let Some(c) = &coating {
                // Tidied: clap prints a parser's message as it is (`mgf2@1e300` printed 300 digits; round 9).
                c.validate().map_err(|e| crate::error::tidy_numbers(&format!("`{item}`: {e}")).into_owned())?;
            }
            items.push((target, coating));
        }
        Ok(CoatingOverride { items, text: text.to_string() })
    }
}

impl CoatingOverride {
    /// The coatings of `surfaces` (the spec's, one per sequential surface) with the override applied.
    /// `not_an_interface(k)` says why a coating on surface k would do nothing
    /// ([`super::solids::coating_sites`]): `all` coats every other surface; a surface index
    /// beyond the system, or naming such a surface, is an error naming it.
    pub fn apply(&self, surfaces: &[Option<Coating>], not_an_interface: &dyn Fn(usize) -> Option<String>) -> crate::error::Result<Vec<Option<Coating>>> {
        let mut out = surfaces.to_vec();
        for (target, coating) in &self.items {
            match target {
                None => out.iter_mut().enumerate().filter(|(k, _)| not_an_interface(*k).is_none()).for_each(|(_, c)| *c = coating.clone()),
                Some(k) if *k < out.len() => {
                    if let (Some(what), Some(_)) = (not_an_interface(*k), coating) {
                        return Err(crate::error::Error::invalid(format!("--coating `{}`: surface {k} is {what}: a coating there would do nothing", self.text)));
                    }
                    out[*k] = coating.clone()
                }
                Some(k) => return Err(crate::error::Error::invalid(format!("--coating `{}`: surface {k} does not exist (the system has surfaces 0..={})", self.text, out.len().saturating_sub(1)))),
            }
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn coating_override_syntax() {
        let o: CoatingOverride = "all=mgf2@550, 2=R0.01,3=bare".parse().unwrap();
        let c = o.apply(&[None, Some(Coating::Reflectance(0.5)), None, Some(Coating::Reflectance(0.2))], &|_| None).unwrap();
        assert_eq!(c, vec![Some(Coating::Mgf2QuarterWaveNm(550.0)), Some(Coating::Mgf2QuarterWaveNm(550.0)), Some(Coating::Reflectance(0.01)), None]);
        // `all` skips surfaces that are not interfaces; naming one is an error.
        let object = |k: usize| (k == 0).then(|| "the object surface, not a refracting interface".to_string());
        let c = "all=R0.01".parse::<CoatingOverride>().unwrap().apply(&[None, None], &object).unwrap();
        assert_eq!(c, vec![None, Some(Coating::Reflectance(0.01))]);
        let e = "0=R0.01".parse::<CoatingOverride>().unwrap().apply(&[None, None], &object).unwrap_err().to_string();
        assert!(e.contains("surface 0 is the object surface"), "{e}");
        for (bad, needle) in [("all=R1.5", "reflectance 1.5"), ("all=R-0.1", "reflectance -0.1"), ("all=Rx", "`x` is not a number"), ("x=R0", "target `x`"), ("all", "TARGET=VALUE"), ("all=gold", "`gold`"), ("all=mgf2@100", "mgf2_quarter_wave_nm 100"), ("16=mgf2@550nm", "`550nm` is not a number of nm"), ("16=R 0.01", "` 0.01` is not a number")] {
            let e = bad.parse::<CoatingOverride>().unwrap_err();
            assert!(e.contains(needle), "{bad}: {e}");
        }
        // R1e-400 is not the 0 it would be read as; −0 is recorded as 0.
        assert!("all=R1e-400".parse::<CoatingOverride>().unwrap_err().contains("below f64's range"));
        let zero = "all=R-0".parse::<CoatingOverride>().unwrap();
        assert!(matches!(zero.items[0].1, Some(Coating::Reflectance(r)) if r.to_bits() == 0));
        assert!("all=R0e-400".parse::<CoatingOverride>().is_ok());
        let e = "7=R0".parse::<CoatingOverride>().unwrap().apply(&[None, None], &|_| None).unwrap_err().to_string();
        assert!(e.contains("surface 7"), "{e}");
    }

    #[test]
    fn quarter_wave_minimum_at_design() {
        // At normal incidence and the design wavelength R = ((n₀n₂ − n₁²)/(n₀n₂ + n₁²))² (Born & Wolf §1.6.4).
        let (n0, n2) = (1.0, 1.5168);
        let nf = mgf2_index(550.0);
        let c = interface_coefficients(Some(&Coating::Mgf2QuarterWaveNm(550.0)), n0, n2, 1.0, 550.0);
        let expect = ((n0 * n2 - nf * nf) / (n0 * n2 + nf * nf)).powi(2);
        assert!((c.reflectance() - expect).abs() < 1e-12, "{} {expect}", c.reflectance());
        // Thinner film (zero thickness limit) is the bare surface: check the reverse direction is symmetric.
        let back = interface_coefficients(Some(&Coating::Mgf2QuarterWaveNm(550.0)), n2, n0, 1.0, 550.0);
        assert!((back.reflectance() - expect).abs() < 1e-12);
        // Away from the design wavelength the reflectance rises.
        let off = interface_coefficients(Some(&Coating::Mgf2QuarterWaveNm(550.0)), n0, n2, 1.0, 450.0);
        assert!(off.reflectance() > c.reflectance());
    }

    #[test]
    fn given_reflectance() {
        let c = interface_coefficients(Some(&Coating::Reflectance(0.01)), 1.0, 1.5, 0.8, 500.0);
        assert!((c.reflectance() - 0.01).abs() < 1e-15 && (c.ts.norm_sqr() - 0.99).abs() < 1e-15);
    }
}
