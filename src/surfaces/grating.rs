//! OpticStudio's Diffraction Grating (`DGRATING`): a Standard surface (plane, sphere or conic) ruled with
//! lines parallel to the local x axis, T lines per µm, traced in one diffraction order m.
//!
//! **The grating equation, vector form.** With n̂ the unit surface normal at the hit and K the unit vector
//! in the tangent plane perpendicular to the lines (K = normalise(ŷ − (ŷ·n̂) n̂): the lines are the
//! surface's sections y = const, so K is the direction across them), the tangential part of n·d changes by
//! the grating's momentum, the normal part follows from |d′| = 1:
//!
//! n₂ d′_t = n₁ d_t − s·m λ T K,   n₂ d′ = n₂ d′_t + σ √(n₂² − |n₂ d′_t|²) n̂,
//!
//! with λ in µm, s = +1 for a transmission grating and −1 for a reflective one (`GLAS MIRROR`), and σ the
//! sign that keeps the ray going on (transmission) or sends it back (reflection) across the surface. On a
//! plane grating (n̂ = ẑ) this is n₂ sin θ₂ = n₁ sin θ₁ − mλT in the y–z plane: order +1 bends toward −y.
//! When n₂² < |n₂ d′_t|² the order is **evanescent**: the ray stops with [`crate::tracer::RayStatus::Evanescent`].
//!
//! Conventions and their sources: OpticStudio's manual (lines parallel to local x, lines per µm, order);
//! the sign of the order and the unit K on curved substrates as rayoptics implements them
//! (`oprops/doe.py`, `DiffractionGrating.phase_ludwig`, after Ludwig, "Generalized grating ray-tracing
//! equations", JOSA 63, 1105 (1973)), the independent reader the tests compare against; optiland
//! (`interactions/diffractive_model.py`) has the same sign.
use glam::DVec3;

/// A grating's parameters as the tracer uses them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Grating {
    /// Lines per µm (> 0).
    pub lines_per_um: f64,
    /// Diffraction order (an integer, stored as f64).
    pub order: f64,
}

impl Grating {
    /// The grating "kick" m λ T (dimensionless) at `wavelength_nm`.
    #[inline]
    pub fn kick(&self, wavelength_nm: f64) -> f64 {
        self.order * (wavelength_nm * 1e-3) * self.lines_per_um
    }
}

/// The unit vector across the lines, K = normalise(ŷ − (ŷ·n̂) n̂), at the unit normal n̂; and 1/|ŷ − (ŷ·n̂)n̂|.
#[inline]
pub fn across_lines(normal: DVec3) -> (DVec3, f64) {
    let k = DVec3::Y - normal * normal.y;
    let inv = 1.0 / k.length();
    (k * inv, inv)
}

/// Diffract unit `d` at unit normal `normal` (any orientation) from index `n1` into `n2`, with the kick
/// g = m λ T (see [`Grating::kick`]); `reflect` for a reflective grating (then `n2 == n1`). `None` when
/// the order is evanescent.
#[inline]
pub fn diffract(d: DVec3, normal: DVec3, n1: f64, n2: f64, kick: f64, reflect: bool) -> Option<DVec3> {
    let cos_i = d.dot(normal);
    let nrm = if cos_i < 0.0 { -normal } else { normal }; // along the incoming direction
    let (k, _) = across_lines(normal);
    let s = if reflect { -1.0 } else { 1.0 };
    // n₁ d − s g K, then its tangential part.
    let v = d * n1 - k * (s * kick);
    let vn = v.dot(nrm);
    let vt = v - nrm * vn;
    let q = n2 * n2 - vt.length_squared();
    if !(q >= 0.0) {
        return None;
    }
    let along = if reflect { -q.sqrt() } else { q.sqrt() };
    Some((vt + nrm * along) / n2)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plane_grating_obeys_the_grating_equation() {
        // n₂ sin θ₂ = n₁ sin θ₁ − mλT, in the y–z plane.
        let (n1, n2, t, m, wl) = (1.0, 1.5, 0.3, 1.0, 550.0);
        let th1: f64 = 0.2;
        let d = DVec3::new(0.0, th1.sin(), th1.cos());
        let g = Grating { lines_per_um: t, order: m }.kick(wl);
        let out = diffract(d, DVec3::Z, n1, n2, g, false).unwrap();
        assert!((n2 * out.y - (n1 * th1.sin() - m * 0.55 * t)).abs() < 1e-15);
        assert!((out.length() - 1.0).abs() < 1e-15 && out.z > 0.0 && out.x == 0.0);
        // The zeroth order is Snell's law.
        let r = crate::tracer::kernel::refract(d, DVec3::Z, n1, n2).unwrap();
        assert!((diffract(d, DVec3::Z, n1, n2, 0.0, false).unwrap() - r).length() < 1e-15);
        // Reflective: the zeroth order is the mirror reflection, order m kicks the other way.
        let refl = diffract(d, -DVec3::Z, 1.0, 1.0, 0.0, true).unwrap();
        assert!((refl - DVec3::new(0.0, d.y, -d.z)).length() < 1e-15);
        let o = diffract(d, DVec3::Z, 1.0, 1.0, 0.2, true).unwrap();
        assert!((o.y - (d.y + 0.2)).abs() < 1e-15 && o.z < 0.0);
    }

    #[test]
    fn evanescent_orders_are_none_never_nan() {
        let d = DVec3::Z;
        assert!(diffract(d, DVec3::Z, 1.0, 1.0, 1.2, false).is_none());
        assert!(diffract(d, DVec3::Z, 1.0, 1.0, f64::NAN, false).is_none());
        assert!(diffract(d, DVec3::Z, 1.0, 1.0, 0.999, false).unwrap().is_finite());
    }
}
