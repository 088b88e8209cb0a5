//! Paraxial (first-order) data: the y–nu trace used to locate the entrance pupil, as Zemax does it, and
//! the first-order data of [`FirstOrder`] (EFL, BFL, pupil positions).
//! Coordinate Breaks are ignored by paraxial tracing (only their thickness counts), as in OpticStudio.
//!
//! An object at infinity (object thickness +∞) is traced from the plane of surface 1's vertex: the
//! object surface's frame is placed there (`system/build.rs`), so the pupil distance is measured from
//! surface 1 and the object thickness counts as 0 in the y–nu trace.
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
    /// The object is at infinity: rays of one field are parallel, `distance_mm` is measured from the plane
    /// of surface 1's vertex (the object frame's z = 0, where rays start), and `sin_marginal` is 0.
    pub object_at_infinity: bool,
}

/// First-order (paraxial) data at the primary wavelength, in the conventions of OpticStudio's and
/// rayoptics' first-order reports (`parax/firstorder.py`).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct FirstOrder {
    /// Effective focal length −1/u′ of a ray parallel to the axis at unit height (image space), mm.
    pub efl_mm: f64,
    /// Back focal length: from the last surface before the image to the paraxial rear focal point, mm.
    pub bfl_mm: f64,
    /// Entrance pupil position from surface 1's vertex (positive: after it), mm.
    pub enp_from_surface1_mm: f64,
    /// Entrance pupil diameter, mm.
    pub enp_diameter_mm: f64,
    /// Exit pupil position from the last surface before the image (positive: after it), mm.
    pub exp_from_last_surface_mm: f64,
    /// Exit pupil position from the image surface, mm.
    pub exp_from_image_mm: f64,
    /// Paraxial image height per unit field of the chief ray: per mm of object height (finite object) or per
    /// unit tan θ (object at infinity), mm.
    pub chief_image_height_per_field: f64,
}

impl EntrancePupil {
    pub fn is_telecentric(&self) -> bool {
        !self.distance_mm.is_finite()
    }
}

/// Inputs of a paraxial trace per surface.
#[derive(Clone, Copy)]
pub(crate) struct ParaxialSurface {
    pub kind: SurfaceKind,
    /// Curvature of the paraxial figure (c + 2α₁ for even aspheres), mm⁻¹.
    pub curvature: f64,
    pub focal_length_mm: f64,
    pub thickness_mm: f64,
    pub n_after: f64,
}

/// Paraxial power of surface `i` (the index before it is `surfaces[i - 1].n_after`).
fn power(surfaces: &[ParaxialSurface], i: usize) -> f64 {
    let (prev, s) = (&surfaces[i - 1], &surfaces[i]);
    match s.kind {
        // A grating's substrate refracts paraxially; its constant deflection is no power (like a break).
        SurfaceKind::Standard | SurfaceKind::EvenAsphere | SurfaceKind::Toroidal | SurfaceKind::DiffractionGrating => s.curvature * (s.n_after - prev.n_after),
        SurfaceKind::Paraxial => s.n_after / s.focal_length_mm,
        SurfaceKind::CoordinateBreak => 0.0,
    }
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
        nu -= y * power(surfaces, i);
    }
    y
}

/// (y, nu) just after surface `to` (refracted) of the ray with (y, nu) just after surface `from`.
fn trace_after(surfaces: &[ParaxialSurface], from: usize, to: usize, y0: f64, nu0: f64) -> (f64, f64) {
    let (y, nu, _) = trace_with_terms(surfaces, from, to, y0, nu0);
    (y, nu)
}

/// [`trace_after`] and the largest refraction term |y φ| it subtracted from nu.
fn trace_with_terms(surfaces: &[ParaxialSurface], from: usize, to: usize, y0: f64, nu0: f64) -> (f64, f64, f64) {
    let (mut y, mut nu, mut largest) = (y0, nu0, 0.0f64);
    for i in from + 1..=to {
        let prev = &surfaces[i - 1];
        y += prev.thickness_mm * nu / prev.n_after;
        let term = y * power(surfaces, i);
        largest = largest.max(term.abs());
        nu -= term;
    }
    (y, nu, largest)
}

/// [`trace_after`] of the ray parallel to the axis at unit height after surface 0, with its final reduced
/// angle set to 0 where it is rounding: within 1e-12 of the largest refraction term |y φ| it summed. An
/// afocal system's powers cancel only to ~1e-16 of them in f64, which read as an EFL of 5.8e17 mm (a
/// paraboloid and its confocal secondary; a held-out battery, round 15); a real system's EFL is within
/// 10¹² of its elements' focal lengths.
fn parallel_ray_after(surfaces: &[ParaxialSurface], last: usize) -> (f64, f64) {
    let (y, mut nu, largest) = trace_with_terms(surfaces, 0, last, 1.0, 0.0);
    if nu.abs() <= 1e-12 * largest {
        nu = 0.0;
    }
    (y, nu)
}

/// The paraxial effective focal length (mm): −n′/nu′ of the ray parallel to the axis at unit height,
/// after the last surface before the image; infinite for an afocal system ([`parallel_ray_after`]).
/// Independent of the object distance.
pub(crate) fn effective_focal_length(surfaces: &[ParaxialSurface]) -> f64 {
    let last = surfaces.len() - 2;
    let (_, nu) = parallel_ray_after(surfaces, last);
    -surfaces[last].n_after / nu
}

/// First-order data of a system whose entrance pupil is `pupil` (the object thickness as in the trace:
/// 0 for an object at infinity).
pub(crate) fn first_order(surfaces: &[ParaxialSurface], stop: usize, pupil: &EntrancePupil) -> FirstOrder {
    let last = surfaces.len() - 2;
    let nk = surfaces[last].n_after;
    // From surface 1 on, the object gap does not count: a parallel ray at unit height.
    let mut from1: Vec<ParaxialSurface> = surfaces.to_vec();
    from1[0].thickness_mm = 0.0;
    let (y, nu) = parallel_ray_after(&from1, last);
    let efl_mm = -nk / nu;
    let bfl_mm = -y * nk / nu;
    // Chief ray: through the stop centre with a unit reduced angle there.
    let (yc, nuc) = trace_after(surfaces, stop, last, 0.0, 1.0);
    let exp_from_last_surface_mm = -yc * nk / nuc;
    let t_image = surfaces[last].thickness_mm;
    let enp_from_surface1_mm = if pupil.object_at_infinity { pupil.distance_mm } else { pupil.distance_mm - surfaces[0].thickness_mm };
    // Chief-ray image height per unit field (object height, or tan θ at infinity).
    let n0 = surfaces[0].n_after;
    let (y0, nu0) = if pupil.object_at_infinity {
        (-pupil.distance_mm, n0)
    } else if pupil.is_telecentric() {
        (1.0, 0.0)
    } else {
        (1.0, -n0 / pupil.distance_mm)
    };
    let (yi, nui) = trace_after(surfaces, 0, last, y0, nu0);
    let chief_image_height_per_field = yi + t_image * nui / nk;
    FirstOrder {
        efl_mm,
        bfl_mm,
        enp_from_surface1_mm,
        enp_diameter_mm: 2.0 * pupil.radius_mm,
        exp_from_last_surface_mm,
        exp_from_image_mm: exp_from_last_surface_mm - t_image,
        chief_image_height_per_field,
    }
}

/// The entrance pupil for the system aperture. `stop_semi_diameter_mm` is the stop surface's semi-diameter
/// (used by [`SystemAperture::FloatByStopSize`]); `object_at_infinity` says that `surfaces[0]`'s thickness is
/// the 0 of the start plane at surface 1 and the object is at infinity.
pub(crate) fn entrance_pupil(
    surfaces: &[ParaxialSurface],
    stop: usize,
    aperture: SystemAperture,
    stop_semi_diameter_mm: Option<f64>,
    object_at_infinity: bool,
) -> Result<EntrancePupil, String> {
    let n0 = surfaces[0].n_after;
    // y_stop = A·y0 + B·nu0
    let a = height_at_stop(surfaces, stop, 1.0, 0.0);
    let b = height_at_stop(surfaces, stop, 0.0, 1.0);
    if !(a.is_finite() && b.is_finite()) {
        return Err("paraxial trace to the stop is not finite".into());
    }
    // At infinity B = 0 only says that the pupil is on surface 1's plane (the stop is surface 1 or imaged there).
    if b == 0.0 && !object_at_infinity {
        return Err("the stop is conjugate to the object (paraxial B = 0): no entrance pupil".into());
    }
    // The chief ray (through the stop centre) from height y0 has nu0 = −A y0 / B; it crosses the axis
    // at z = −y0 n0 / nu0 = n0 B / A from the object plane.
    let distance_mm = if a.abs() < 1e-14 * b.abs() { f64::INFINITY } else { n0 * b / a };
    let magnification_sign = if a < 0.0 { -1.0 } else { 1.0 };
    // The image-space F/# and the stop size give the pupil diameter (or the stop radius) first.
    let aperture = match aperture {
        SystemAperture::ImageSpaceFNumber(fno) => {
            let efl = effective_focal_length(surfaces);
            if !(efl.is_finite() && efl != 0.0) {
                return Err(format!("image-space F/# {fno}: the system has no finite paraxial focal length (afocal), so the F/# defines no pupil"));
            }
            // The pupil the F/# gives is held to the limits of a given one (`entrance_pupil_diameter`).
            let d = efl.abs() / fno;
            let (lo, hi) = (crate::limits::MIN_PUPIL_DIAMETER_MM, crate::limits::MAX_LENGTH_MM);
            if !(d.is_finite() && (lo..=hi).contains(&d)) {
                return Err(format!(
                    "image-space F/# {} gives an entrance pupil diameter of {} mm (EFL {} mm / F/#), outside the plausible [{}, {}] mm of a given entrance pupil",
                    crate::limits::fmt_num(fno),
                    crate::limits::fmt_num(d),
                    crate::limits::fmt_num(efl.abs()),
                    crate::limits::fmt_num(lo),
                    crate::limits::fmt_num(hi)
                ));
            }
            SystemAperture::EntrancePupilDiameter(d)
        }
        other => other,
    };
    if object_at_infinity {
        if !distance_mm.is_finite() {
            return Err("the entrance pupil is at infinity while the object is at infinity (the stop is at the front focal point): no finite pupil to fill".into());
        }
        // A ray parallel to the axis at height h on the pupil plane meets the stop at A·h.
        let (radius_mm, stop_radius_mm) = match aperture {
            SystemAperture::EntrancePupilDiameter(d) => (0.5 * d, (0.5 * d * a).abs()),
            SystemAperture::FloatByStopSize => {
                let r = stop_semi_diameter_mm.ok_or("float by stop size: the stop has no semi-diameter")?;
                if a == 0.0 {
                    return Err("float by stop size: the stop is at a focus of the front group (paraxial A = 0)".into());
                }
                ((r / a).abs(), r)
            }
            SystemAperture::ObjectSpaceNa(_) => return Err("an object at infinity has no object-space NA".into()),
            SystemAperture::ImageSpaceFNumber(_) => unreachable!("converted above"),
        };
        if !(radius_mm.is_finite() && radius_mm > 0.0) {
            return Err(format!("entrance pupil radius {radius_mm} mm: must be finite and > 0"));
        }
        return Ok(EntrancePupil { distance_mm, radius_mm, sin_marginal: 0.0, stop_radius_mm, magnification_sign, object_at_infinity: true });
    }
    let aperture = match aperture {
        SystemAperture::FloatByStopSize => {
            let r = stop_semi_diameter_mm.ok_or("float by stop size: the stop has no semi-diameter")?;
            // Paraxial marginal ray from the axial object point to the stop edge: n0·tan θ = r / |B|.
            let tan = r / (b * n0).abs();
            SystemAperture::ObjectSpaceNa(n0 * tan / (1.0 + tan * tan).sqrt())
        }
        other => other,
    };
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
        SystemAperture::ImageSpaceFNumber(_) | SystemAperture::FloatByStopSize => unreachable!("converted above"),
    };
    // Paraxial marginal ray: from the axial object point through the pupil edge.
    let tan_m = sin_marginal / (1.0 - sin_marginal * sin_marginal).sqrt();
    let stop_radius_mm = (b * n0 * tan_m).abs();
    Ok(EntrancePupil { distance_mm, radius_mm, sin_marginal, stop_radius_mm, magnification_sign, object_at_infinity: false })
}
