//! Paraxial (first-order) data: the y–nu trace used to locate the entrance pupil, as Zemax does it.
//! Coordinate Breaks are ignored by paraxial tracing (only their thickness counts), as in OpticStudio.
use crate::spec::{SurfaceKind, SystemAperture};

/// The paraxial entrance pupil at the primary wavelength.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EntrancePupil {
    /// Distance from the object plane to the pupil along the object-space axis (mm; negative = behind the
    /// object, i.e. a virtual pupil; infinite = telecentric object space).
    pub distance_mm: f64,
    /// Entrance pupil radius (mm); for telecentric object space, unused.
    pub radius_mm: f64,
    /// Sine of the object-space marginal-ray angle (NA / n₀).
    pub sin_marginal: f64,
    /// Paraxial marginal-ray height at the stop (mm): the stop radius that the aperture implies.
    pub stop_radius_mm: f64,
    /// Sign of the pupil magnification m_p = 1/A (entrance pupil height / stop height): −1 when the
    /// entrance pupil is an inverted image of the stop.
    pub magnification_sign: f64,
}

impl EntrancePupil {
    pub fn is_telecentric(&self) -> bool {
        !self.distance_mm.is_finite()
    }
}

/// Inputs of a paraxial trace per surface.
pub(crate) struct ParaxialSurface {
    pub kind: SurfaceKind,
    /// Curvature of the paraxial figure (c + 2α₁ for even aspheres), mm⁻¹.
    pub curvature: f64,
    pub focal_length_mm: f64,
    pub thickness_mm: f64,
    pub n_after: f64,
}

/// Height at the stop of the paraxial ray leaving the object plane with height `y0` and reduced angle
/// `nu0` (= n₀ u₀).
fn height_at_stop(surfaces: &[ParaxialSurface], stop: usize, y0: f64, nu0: f64) -> f64 {
    let (mut y, mut nu) = (y0, nu0);
    for i in 1..=stop {
        let prev = &surfaces[i - 1];
        y += prev.thickness_mm * nu / prev.n_after;
        if i == stop {
            break;
        }
        let s = &surfaces[i];
        let power = match s.kind {
            // A grating's substrate refracts paraxially; its constant deflection is no power (like a break).
            SurfaceKind::Standard | SurfaceKind::EvenAsphere | SurfaceKind::Toroidal | SurfaceKind::DiffractionGrating => s.curvature * (s.n_after - prev.n_after),
            SurfaceKind::Paraxial => s.n_after / s.focal_length_mm,
            SurfaceKind::CoordinateBreak => 0.0,
        };
        nu -= y * power;
    }
    y
}

pub(crate) fn entrance_pupil(surfaces: &[ParaxialSurface], stop: usize, aperture: SystemAperture) -> Result<EntrancePupil, String> {
    let n0 = surfaces[0].n_after;
    // y_stop = A·y0 + B·nu0
    let a = height_at_stop(surfaces, stop, 1.0, 0.0);
    let b = height_at_stop(surfaces, stop, 0.0, 1.0);
    if !(a.is_finite() && b.is_finite()) {
        return Err("paraxial trace to the stop is not finite".into());
    }
    if b == 0.0 {
        return Err("the stop is conjugate to the object (paraxial B = 0): no entrance pupil".into());
    }
    // The chief ray (through the stop centre) from height y0 has nu0 = −A y0 / B; it crosses the axis
    // at z = −y0 n0 / nu0 = n0 B / A from the object plane.
    let distance_mm = if a.abs() < 1e-14 * b.abs() { f64::INFINITY } else { n0 * b / a };
    let (radius_mm, sin_marginal) = match aperture {
        SystemAperture::ObjectSpaceNa(na) => {
            let s = na / n0;
            if s >= 1.0 {
                return Err(format!("object-space NA {na} ≥ object index {n0}"));
            }
            let tan = s / (1.0 - s * s).sqrt();
            (distance_mm.abs() * tan, s)
        }
        SystemAperture::EntrancePupilDiameter(d) => {
            if !distance_mm.is_finite() {
                return Err("entrance pupil diameter is meaningless with a telecentric object space".into());
            }
            let tan = 0.5 * d / distance_mm.abs();
            (0.5 * d, tan / (1.0 + tan * tan).sqrt())
        }
    };
    // Paraxial marginal ray: from the axial object point through the pupil edge.
    let tan_m = sin_marginal / (1.0 - sin_marginal * sin_marginal).sqrt();
    let stop_radius_mm = (b * n0 * tan_m).abs();
    let magnification_sign = if a < 0.0 { -1.0 } else { 1.0 };
    Ok(EntrancePupil { distance_mm, radius_mm, sin_marginal, stop_radius_mm, magnification_sign })
}
