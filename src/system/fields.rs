//! Field points: the spec's fields ([`FieldType`]: object heights, angles, paraxial or real image heights,
//! in mm or degrees) resolved into the object-space field points every ray generator takes — object heights
//! (x, y) in mm for a finite object, field angles (θx, θy) in radians for an object at infinity.
//!
//! Conventions (OpticStudio's, "System Explorer → Fields"): an angle field's chief ray has the object-space
//! direction (tan θx, tan θy, 1) normalised and passes through the centre of the paraxial entrance pupil; for
//! a finite object the angle is that of the chief ray from the object point to the pupil centre, so the object
//! height is −z_ep·tan θ (z_ep the pupil distance from the object). Paraxial image heights are divided by the
//! paraxial chief ray's image height per unit field (per mm of object, or per unit tan θ); real image heights
//! are found by Newton iteration on the real chief ray at the primary wavelength, landing on the image surface
//! (its local x, y) at the given point.
use super::{EntrancePupil, FirstOrder, SequentialSystem};
use crate::spec::{FieldType, SystemSpec};

/// The spec's fields as object-space field points; for [`FieldType::RealImageHeight`] the paraxial first
/// guess, refined by [`real_image_height_fields`] once the system is built.
pub(crate) fn object_fields(spec: &SystemSpec, pupil: &EntrancePupil, fo: &FirstOrder) -> Result<Vec<[f64; 2]>, String> {
    let infinite = pupil.object_at_infinity;
    let values = spec.field_values();
    match spec.field_type {
        FieldType::ObjectHeight if !infinite => Ok(spec.fields_mm.clone()),
        // Validated: only on-axis points, the same field as angle (0, 0).
        FieldType::ObjectHeight => Ok(vec![[0.0, 0.0]; values.len()]),
        FieldType::Angle if infinite => Ok(values.iter().map(|f| [f[0].to_radians(), f[1].to_radians()]).collect()),
        FieldType::Angle => {
            if pupil.is_telecentric() {
                return Err("fields_deg: field angles need an entrance pupil at a finite distance (object space is telecentric); give object heights".into());
            }
            let z = pupil.distance_mm;
            Ok(values.iter().map(|f| [-z * f[0].to_radians().tan(), -z * f[1].to_radians().tan()]).collect())
        }
        FieldType::ParaxialImageHeight | FieldType::RealImageHeight => {
            let k = fo.chief_image_height_per_field;
            if !(k.is_finite() && k != 0.0) {
                return Err(format!(
                    "fields_mm ({}): the paraxial chief ray's image height per unit field is {k}, so image heights cannot be turned into object fields",
                    spec.field_type.label()
                ));
            }
            let out: Vec<[f64; 2]> = values.iter().map(|f| if infinite { [(f[0] / k).atan(), (f[1] / k).atan()] } else { [f[0] / k, f[1] / k] }).collect();
            check_converted(spec, infinite, &out)?;
            Ok(out)
        }
    }
}

/// Fields converted from image heights (or, for real image heights, found by the chief ray) within the limits
/// of the fields a user gives: an angle within (−90, 90)° (`--field-deg`), an object height within ±1e6 mm
/// (`--field-mm`). An image height of 1e300 mm converted to exactly 90° and was traced; a tiny chief-ray
/// height per field turns a moderate image height into an absurd object height.
fn check_converted(spec: &SystemSpec, infinite: bool, fields: &[[f64; 2]]) -> Result<(), String> {
    for (i, (f, given)) in fields.iter().zip(&spec.fields_mm).enumerate() {
        let bad = if infinite {
            f.iter().any(|a| !(a.is_finite() && a.abs() < std::f64::consts::FRAC_PI_2) || a.to_degrees().abs() >= 90.0)
        } else {
            f.iter().any(|h| !(h.is_finite() && h.abs() <= crate::limits::MAX_LENGTH_MM))
        };
        if bad {
            let (shown, unit, range) = if infinite {
                ([f[0].to_degrees(), f[1].to_degrees()], "°", "within (-90, 90) degrees (the range of --field-deg)".to_string())
            } else {
                (*f, " mm", format!("within ±{:e} mm (the range of --field-mm)", crate::limits::MAX_LENGTH_MM))
            };
            return Err(format!(
                "fields_mm[{i}] = ({}, {}) mm ({}) converts to the field ({}, {}){unit}, which is not {range}",
                crate::limits::fmt_num(given[0]),
                crate::limits::fmt_num(given[1]),
                spec.field_type.label(),
                crate::limits::fmt_num(shown[0]),
                crate::limits::fmt_num(shown[1]),
            ));
        }
    }
    Ok(())
}

/// Real image heights: the object fields whose real chief rays (primary wavelength, the system's ray
/// aiming) land on the image surface at `system.spec.fields_mm` (its local x, y), from the paraxial guesses.
pub(crate) fn real_image_height_fields(system: &SequentialSystem, guess: &[[f64; 2]]) -> Result<Vec<[f64; 2]>, String> {
    let n = system.indices(system.spec.primary_wavelength_nm).map_err(|e| e.to_string())?;
    let land = |f: [f64; 2]| -> Result<[f64; 2], String> {
        let (o, d) = crate::rays::aimed_ray(system, &n, f, 0.0, 0.0).map_err(|e| e.to_string())?;
        let (p, _) = crate::tracer::kernel::trace_steps(&system.path, &n, o, d).map_err(|(st, s)| format!("chief ray {st:?} at surface {s}"))?;
        Ok([p.x, p.y])
    };
    let mut out = Vec::with_capacity(guess.len());
    for (i, (&target, &start)) in system.spec.fields_mm.iter().zip(guess).enumerate() {
        let fail = |why: String| format!("fields_mm[{i}] = ({}, {}) mm (real image height): {why}", target[0], target[1]);
        let mut f = start;
        let scale = if system.object_at_infinity() { 1.0 } else { 1.0 + f[0].abs().max(f[1].abs()) };
        let mut done = false;
        for _ in 0..40 {
            let p = land(f).map_err(&fail)?;
            let (ex, ey) = (p[0] - target[0], p[1] - target[1]);
            if ex.abs().max(ey.abs()) <= 1e-12 * (1.0 + target[0].abs().max(target[1].abs())) {
                done = true;
                break;
            }
            let h = 1e-7 * scale;
            let px = land([f[0] + h, f[1]]).map_err(&fail)?;
            let py = land([f[0], f[1] + h]).map_err(&fail)?;
            let (a, c) = ((px[0] - p[0]) / h, (px[1] - p[1]) / h);
            let (b, d) = ((py[0] - p[0]) / h, (py[1] - p[1]) / h);
            let det = a * d - b * c;
            if !(det.is_finite() && det != 0.0) {
                return Err(fail("singular Jacobian of the chief ray's landing point".into()));
            }
            f = [f[0] - (d * ex - b * ey) / det, f[1] - (-c * ex + a * ey) / det];
            if system.object_at_infinity() && !(f[0].abs() < std::f64::consts::FRAC_PI_2 && f[1].abs() < std::f64::consts::FRAC_PI_2) {
                return Err(fail("no field angle within ±90° reaches it".into()));
            }
        }
        if !done {
            return Err(fail("no convergence in 40 Newton steps".into()));
        }
        out.push(f);
    }
    check_converted(&system.spec, system.object_at_infinity(), &out)?;
    Ok(out)
}
