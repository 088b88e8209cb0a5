//! Exact Fresnel coefficients and 3-D polarisation ray tracing at a dielectric interface.
//!
//! **Amplitudes** (Born & Wolf, *Principles of Optics*, 7th ed., §1.5.2, eqs. (20)–(21); the sign
//! convention of Chipman, Lam & Young, *Polarized Light and Optical Systems*, 2018, §8.4, where
//! r_p = −r_s at normal incidence): with cos θₜ = √(1 − (n₁/n₂)² sin² θᵢ),
//!
//! r_s = (n₁cos θᵢ − n₂cos θₜ)/(n₁cos θᵢ + n₂cos θₜ),  r_p = (n₂cos θᵢ − n₁cos θₜ)/(n₂cos θᵢ + n₁cos θₜ),
//! t_s = 2n₁cos θᵢ/(n₁cos θᵢ + n₂cos θₜ),            t_p = 2n₁cos θᵢ/(n₂cos θᵢ + n₁cos θₜ).
//!
//! Beyond the critical angle cos θₜ = +i√((n₁/n₂)² sin² θᵢ − 1) (the evanescent wave decays), r_s and r_p
//! are unimodular with the TIR phase, and nothing is transmitted. Power coefficients: R = |r|²,
//! T = (n₂cos θₜ)/(n₁cos θᵢ)·|t|² — the n·cos θ factor is the change of beam cross-section and impedance;
//! R + T = 1 for each polarisation.
//!
//! **Polarisation ray tracing** (Chipman et al., ch. 9, the polarisation ray-tracing matrix
//! P = a_s ŝŝᵀ + a_p p̂′p̂ᵀ + k̂′k̂ᵀ): ŝ = k̂ × η̂/|k̂ × η̂| (η̂ the surface normal), p̂ = k̂ × ŝ before and
//! p̂′ = k̂′ × ŝ after the interaction. The complex field is a global 3-vector; here it is *flux
//! normalised* (|E|² is the power carried, so transmitted amplitudes carry √(n₂cos θₜ/(n₁cos θᵢ))), and
//! unpolarised light is two orthogonal, mutually incoherent states of half the power each. At normal
//! incidence ŝ is any unit vector ⟂ k̂ (s and p are then the same).
//!
//! The **scalar** model applies the s/p-averaged reflectance ½(R_s + R_p) to the intensity.
//!
//! ```
//! use diffcassi::tracer::nonseq::fresnel::amplitudes;
//! let a = amplitudes(1.0, 1.5, 1.0);
//! let r = (1.0f64 - 1.5) / (1.0 + 1.5);
//! assert_eq!(a.reflectance_s(), r * r); // exactly ((n₁ − n₂)/(n₁ + n₂))²
//! let tir = amplitudes(1.5, 1.0, 0.5); // 60° inside glass: beyond the critical angle 41.8°
//! assert!(tir.tir && (tir.rs.norm() - 1.0).abs() < 1e-15);
//! ```
use glam::DVec3;
use num_complex::Complex64 as C64;

/// Fresnel amplitude coefficients of one interface at one angle of incidence.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Amplitudes {
    pub rs: C64,
    pub rp: C64,
    /// Zero under total internal reflection.
    pub ts: C64,
    pub tp: C64,
    /// cos θᵢ (≥ 0) and cos θₜ (0 under TIR).
    pub cos_i: f64,
    pub cos_t: f64,
    pub n1: f64,
    pub n2: f64,
    /// Total internal reflection.
    pub tir: bool,
}

impl Amplitudes {
    pub fn reflectance_s(&self) -> f64 {
        self.rs.norm_sqr()
    }
    pub fn reflectance_p(&self) -> f64 {
        self.rp.norm_sqr()
    }
    /// T_s = (n₂cos θₜ)/(n₁cos θᵢ)|t_s|².
    pub fn transmittance_s(&self) -> f64 {
        if self.tir {
            0.0
        } else {
            self.n2 * self.cos_t / (self.n1 * self.cos_i) * self.ts.norm_sqr()
        }
    }
    pub fn transmittance_p(&self) -> f64 {
        if self.tir {
            0.0
        } else {
            self.n2 * self.cos_t / (self.n1 * self.cos_i) * self.tp.norm_sqr()
        }
    }
}

/// The Fresnel amplitudes for light from index `n1` into `n2` at cos θᵢ = `cos_i` (its absolute value is
/// used). Non-TIR coefficients are computed in real arithmetic (so normal incidence gives
/// ((n₁−n₂)/(n₁+n₂)) to the last bit); under TIR, in complex arithmetic.
pub fn amplitudes(n1: f64, n2: f64, cos_i: f64) -> Amplitudes {
    let ci = cos_i.abs().min(1.0);
    let sin2_t = (n1 / n2) * (n1 / n2) * (1.0 - ci * ci);
    if sin2_t <= 1.0 {
        let ct = (1.0 - sin2_t).sqrt();
        let (a, b) = (n1 * ci, n2 * ct);
        let (c, d) = (n2 * ci, n1 * ct);
        Amplitudes {
            rs: C64::new((a - b) / (a + b), 0.0),
            rp: C64::new((c - d) / (c + d), 0.0),
            ts: C64::new(2.0 * a / (a + b), 0.0),
            tp: C64::new(2.0 * a / (c + d), 0.0),
            cos_i: ci,
            cos_t: ct,
            n1,
            n2,
            tir: false,
        }
    } else {
        let ct = C64::new(0.0, (sin2_t - 1.0).sqrt());
        let a = C64::new(n1 * ci, 0.0);
        let b = ct * n2;
        let c = C64::new(n2 * ci, 0.0);
        let d = ct * n1;
        Amplitudes { rs: (a - b) / (a + b), rp: (c - d) / (c + d), ts: C64::new(0.0, 0.0), tp: C64::new(0.0, 0.0), cos_i: ci, cos_t: 0.0, n1, n2, tir: true }
    }
}

/// How light is weighted at an interface.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FresnelModel {
    /// No Fresnel weighting: everything is transmitted (reflections only by TIR) — today's trace.
    Off,
    /// The s/p-averaged reflectance ½(R_s + R_p) applied to the intensity.
    Scalar,
    /// Two orthogonal incoherent polarisation states, 3-D polarisation ray tracing.
    Polarized,
}

impl FresnelModel {
    pub fn label(self) -> &'static str {
        match self {
            FresnelModel::Off => "off",
            FresnelModel::Scalar => "scalar",
            FresnelModel::Polarized => "polarized",
        }
    }
}

/// A complex 3-vector (the optical field in global coordinates).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CVec3 {
    pub re: DVec3,
    pub im: DVec3,
}

impl CVec3 {
    pub fn real(v: DVec3) -> Self {
        CVec3 { re: v, im: DVec3::ZERO }
    }
    /// E · u for a real vector u.
    pub fn dot_real(&self, u: DVec3) -> C64 {
        C64::new(self.re.dot(u), self.im.dot(u))
    }
    /// a · u for a complex scalar a and a real vector u.
    pub fn from_scaled(a: C64, u: DVec3) -> Self {
        CVec3 { re: u * a.re, im: u * a.im }
    }
    pub fn add(self, o: CVec3) -> Self {
        CVec3 { re: self.re + o.re, im: self.im + o.im }
    }
    pub fn scale(self, s: f64) -> Self {
        CVec3 { re: self.re * s, im: self.im * s }
    }
    /// |E|²: the power carried (flux-normalised field).
    pub fn norm_sqr(&self) -> f64 {
        self.re.length_squared() + self.im.length_squared()
    }
}

/// A unit vector perpendicular to unit `k` (a stable choice).
pub fn perpendicular(k: DVec3) -> DVec3 {
    let a = if k.x.abs() < 0.9 { DVec3::X } else { DVec3::Y };
    k.cross(a).normalize()
}

/// The s/p basis of an interaction: ŝ, p̂ (incident), p̂′ (outgoing) for incident `k`, normal `normal`
/// (either orientation) and outgoing `k_out`.
pub fn sp_basis(k: DVec3, normal: DVec3, k_out: DVec3) -> (DVec3, DVec3, DVec3) {
    let c = k.cross(normal);
    let len = c.length();
    let s = if len > 1e-12 { c / len } else { perpendicular(k) };
    (s, k.cross(s), k_out.cross(s))
}

/// Apply the polarisation ray-tracing matrix with (flux-normalised) amplitudes `a_s`, `a_p` to field
/// `e` (⟂ `k`): E′ = a_s (E·ŝ) ŝ + a_p (E·p̂) p̂′.
pub fn apply_prt(e: &CVec3, basis: (DVec3, DVec3, DVec3), a_s: C64, a_p: C64) -> CVec3 {
    let (s, p, p_out) = basis;
    CVec3::from_scaled(a_s * e.dot_real(s), s).add(CVec3::from_scaled(a_p * e.dot_real(p), p_out))
}

/// Two orthogonal incoherent states of power `w/2` each, ⟂ `k`: unpolarised light of power `w`.
pub fn unpolarized(k: DVec3, w: f64) -> [CVec3; 2] {
    let e1 = perpendicular(k);
    let e2 = k.cross(e1);
    let a = (0.5 * w).sqrt();
    [CVec3::real(e1 * a), CVec3::real(e2 * a)]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn power_balance_and_tir_phase() {
        for &(n1, n2) in &[(1.0, 1.5168), (1.7283, 1.0), (1.5, 1.5)] {
            for i in 0..=89 {
                let th = (i as f64).to_radians();
                let a = amplitudes(n1, n2, th.cos());
                let (rs, rp) = (a.reflectance_s(), a.reflectance_p());
                if a.tir {
                    assert!((rs - 1.0).abs() < 1e-14 && (rp - 1.0).abs() < 1e-14);
                    assert!(a.rs.arg().abs() > 0.0);
                } else {
                    assert!((rs + a.transmittance_s() - 1.0).abs() < 1e-14, "{n1} {n2} {i}");
                    assert!((rp + a.transmittance_p() - 1.0).abs() < 1e-14);
                }
            }
        }
    }

    #[test]
    fn prt_conserves_power_split() {
        let k = DVec3::new(0.3, 0.1, 1.0).normalize();
        let n = DVec3::Z;
        let a = amplitudes(1.0, 1.5, k.dot(n));
        let kt = crate::tracer::kernel::refract(k, n, 1.0, 1.5).unwrap();
        let kr = k - 2.0 * k.dot(n) * n;
        let flux = (a.n2 * a.cos_t / (a.n1 * a.cos_i)).sqrt();
        for e in unpolarized(k, 2.0) {
            let r = apply_prt(&e, sp_basis(k, n, kr), a.rs, a.rp);
            let t = apply_prt(&e, sp_basis(k, n, kt), a.ts * flux, a.tp * flux);
            assert!((r.norm_sqr() + t.norm_sqr() - e.norm_sqr()).abs() < 1e-14);
            assert!(t.re.dot(kt).abs() < 1e-14 && r.re.dot(kr).abs() < 1e-14, "fields stay transverse");
        }
    }
}
