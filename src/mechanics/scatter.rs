//! Lambertian scattering off a mechanical surface: a cosine-weighted direction about the normal on the
//! side the ray came from (Malley's method: a uniform point on the unit disk lifted to the hemisphere; pdf
//! cos θ / π, so the Lambertian BRDF ρ/π times cos θ over the pdf leaves the weight ρ), carrying the
//! fraction `reflectance` of the ray's energy.
//!
//! Determinism: the two uniforms come from a counter-based key of (seed, ray index, bounce)
//! ([`crate::render::sampling::key`], SplitMix64 chains), never from a shared generator, so every ray's
//! walk is the same whatever thread traces it and in whatever order.
//!
//! ```
//! use diffcassi::mechanics::scatter::lambertian;
//! use glam::DVec3;
//! let n = DVec3::Z;
//! let (d, w) = lambertian(n, DVec3::new(0.0, 0.0, -1.0), 0.05, 7, 42, 0).unwrap();
//! assert!(d.z > 0.0 && (d.length() - 1.0).abs() < 1e-12 && w == 0.05);
//! assert_eq!(lambertian(n, -DVec3::Z, 0.05, 7, 42, 0), lambertian(n, -DVec3::Z, 0.05, 7, 42, 0));
//! ```
use crate::render::sampling::key;
use glam::DVec3;

/// Uniform in [0, 1) from a 64-bit key (53 high bits).
#[inline]
fn unit(k: u64) -> f64 {
    (k >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// The scattered unit direction and its energy weight (`reflectance`) for a ray arriving along
/// `incoming` at a surface with normal `normal` (either orientation); `None` for an absorber
/// (`reflectance == 0`) or a degenerate normal/direction.
pub fn lambertian(normal: DVec3, incoming: DVec3, reflectance: f64, seed: u64, ray: u64, bounce: u64) -> Option<(DVec3, f64)> {
    if !(reflectance > 0.0) {
        return None;
    }
    let n = normal.try_normalize()?;
    let cos_in = n.dot(incoming);
    if cos_in == 0.0 || !cos_in.is_finite() {
        return None;
    }
    // The lobe is on the side the ray came from.
    let n = if cos_in > 0.0 { -n } else { n };
    let (u1, u2) = (unit(key(seed, ray, bounce, 0)), unit(key(seed, ray, bounce, 1)));
    let r = u1.sqrt();
    let (s, c) = (std::f64::consts::TAU * u2).sin_cos();
    let (x, y) = (r * c, r * s);
    let z = (1.0 - u1).max(0.0).sqrt();
    let helper = if n.x.abs() < 0.9 { DVec3::X } else { DVec3::Y };
    let t = (helper - n * helper.dot(n)).normalize();
    let b = n.cross(t);
    Some(((t * x + b * y + n * z).normalize(), reflectance))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cosine_weighted_moments_and_determinism() {
        // E[cos θ] = 2/3 and E[cos² θ] = 1/2 for a cosine lobe; 40k samples: σ ≈ 0.0012.
        let n = DVec3::new(1.0, 2.0, 2.0) / 3.0;
        let (mut m1, mut m2) = (0.0, 0.0);
        let count = 40_000;
        for i in 0..count {
            let (d, w) = lambertian(n, -n, 0.3, 11, i, 2).unwrap();
            assert_eq!(w, 0.3);
            let c = d.dot(n);
            assert!(c > 0.0);
            m1 += c;
            m2 += c * c;
        }
        m1 /= count as f64;
        m2 /= count as f64;
        assert!((m1 - 2.0 / 3.0).abs() < 0.006, "{m1}");
        assert!((m2 - 0.5).abs() < 0.006, "{m2}");
        // Arriving from the other side scatters to that side; other bounces give other directions.
        let (d, _) = lambertian(n, n, 0.3, 11, 5, 2).unwrap();
        assert!(d.dot(n) < 0.0);
        assert_ne!(lambertian(n, -n, 0.3, 11, 5, 2), lambertian(n, -n, 0.3, 11, 5, 3));
        assert!(lambertian(n, -n, 0.0, 11, 5, 2).is_none());
    }
}
