use crate::rays::RayBatch;
use crate::error::{Error, Result};
use crate::system::SequentialSystem;
use crate::tracer::{RayStatus, Tracer};

/// One grid point of a Zemax-style Grid Distortion listing (mm on the image surface, its own frame).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct DistortionPoint {
    /// Grid indices (−N/2..N/2): `i` along x (outer loop, as Zemax lists), `j` along y.
    pub i: i32,
    pub j: i32,
    /// Grid coordinates: object heights in mm, or for an object at infinity tan θx, tan θy (the grid of
    /// a flat distant object; the angles are in `x_field_deg`, `y_field_deg`).
    pub x_field_mm: f64,
    pub y_field_mm: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub x_field_deg: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub y_field_deg: Option<f64>,
    /// Real chief-ray position, absolute (Zemax's real + ref).
    pub real_x_mm: f64,
    pub real_y_mm: f64,
    /// Predicted position, absolute: ref + ABCD · field.
    pub pred_x_mm: f64,
    pub pred_y_mm: f64,
    /// sign(|real−ref| − |pred−ref|) · 100 · |real − pred| / |pred − ref| (Zemax's definition).
    pub distortion_pct: f64,
    /// Written as its label (`ok`, `tir`, …), as the CSV writes it.
    #[serde(serialize_with = "RayStatus::serialize_label")]
    pub status: RayStatus,
}

/// A grid distortion at one wavelength.
#[derive(Clone, Debug, serde::Serialize)]
pub struct DistortionGrid {
    pub wavelength_nm: f64,
    /// Image of the on-axis field (Zemax's Xref, Yref).
    pub reference_mm: [f64; 2],
    /// Predicted-coordinate matrix [A, B, C, D]: d(image)/d(field) of the chief ray at the axis.
    pub abcd: [f64; 4],
    pub points: Vec<DistortionPoint>,
    /// Largest |distortion_pct|, with its sign.
    pub max_distortion_pct: f64,
}

/// Trace an `n × n` grid of chief rays over ±`half_width_mm` of object field at `wavelength_nm`.
///
/// The predicted (paraxial) coordinates use the first-order matrix of the real chief-ray map at the axis,
/// computed by central differences over ±1e-4 of the half width: for a system with coordinate breaks this
/// is what Zemax's "Predicted coordinate ABCD matrix" reports (e.g. A = −1.003 for SP).
/// The smallest half width of a grid in mm (1 µm): below it the ABCD fit is rounding noise.
pub const MIN_GRID_HALF_WIDTH_MM: f64 = 1e-3;

pub fn grid_distortion(system: &SequentialSystem, tracer: &dyn Tracer, wavelength_nm: f64, n: usize, half_width_mm: f64) -> Result<DistortionGrid> {
    if system.object_at_infinity() {
        return Err(Error::invalid(format!("system `{}` has its object at infinity: its distortion grid is given in degrees (grid_distortion_angle, --half-width-deg)", system.name())));
    }
    grid_core(system, tracer, wavelength_nm, n, half_width_mm, false)
}

/// [`grid_distortion`] for an object at infinity: the grid is uniform in (tan θx, tan θy) over
/// ±tan(`half_width_deg`) — a flat, distant object, as Zemax's grid for angle fields — and the predicted
/// positions are linear in tan θ (the f·tan θ mapping of a distortion-free lens).
pub fn grid_distortion_angle(system: &SequentialSystem, tracer: &dyn Tracer, wavelength_nm: f64, n: usize, half_width_deg: f64) -> Result<DistortionGrid> {
    if !system.object_at_infinity() {
        return Err(Error::invalid(format!("system `{}` has a finite object: its distortion grid is given in mm (--half-width-mm)", system.name())));
    }
    if !(half_width_deg.is_finite() && half_width_deg > 0.0 && half_width_deg < 90.0) {
        return Err(Error::invalid(format!("distortion half width {half_width_deg}°: must be in (0, 90) degrees")));
    }
    grid_core(system, tracer, wavelength_nm, n, half_width_deg.to_radians().tan(), true)
}

/// The grid over ±`half_width` of grid coordinates: object heights (mm), or tan θ at infinity (`tan`).
fn grid_core(system: &SequentialSystem, tracer: &dyn Tracer, wavelength_nm: f64, n: usize, half_width_mm: f64, tan: bool) -> Result<DistortionGrid> {
    let to_fields = |g: &[[f64; 2]]| -> Vec<[f64; 2]> { if tan { g.iter().map(|p| [p[0].atan(), p[1].atan()]).collect() } else { g.to_vec() } };
    if n < 1 {
        return Err(Error::invalid("distortion grid size must be at least 1"));
    }
    if !(half_width_mm.is_finite() && half_width_mm > 0.0) {
        return Err(Error::invalid(format!("distortion half width {half_width_mm} mm: must be finite and > 0")));
    }
    // From 1 µm to the largest plausible length: below it the ABCD fit to the grid is rounding noise (1e-12 mm
    // reported 200 % distortion through C++ and Python; the CLI refused it since round 6).
    if !tan && !(MIN_GRID_HALF_WIDTH_MM..=crate::limits::MAX_LENGTH_MM).contains(&half_width_mm) {
        return Err(Error::invalid(format!(
            "distortion half width {} mm: must be in [{MIN_GRID_HALF_WIDTH_MM:e}, {:e}] mm",
            crate::limits::fmt_num(half_width_mm),
            crate::limits::MAX_LENGTH_MM
        )));
    }
    crate::limits::check_memory(&format!("distortion grid {n}×{n}"), crate::limits::bytes_distortion(n))?;
    let h = 1e-4 * half_width_mm;
    let probes = [[0.0, 0.0], [h, 0.0], [-h, 0.0], [0.0, h], [0.0, -h]];
    let pr = tracer.trace(system, &RayBatch::chief_rays(system, &to_fields(&probes), wavelength_nm)?)?;
    if pr.status.iter().any(|s| *s != RayStatus::Ok) {
        let why = super::describe_lost(&super::lost_rays(&pr.status, &pr.surface), usize::MAX);
        return Err(Error::invalid(format!("the near-axis chief rays do not reach the image at {wavelength_nm} nm: of 5, {why}")));
    }
    let reference_mm = [pr.x[0], pr.y[0]];
    let a = (pr.x[1] - pr.x[2]) / (2.0 * h);
    let c = (pr.y[1] - pr.y[2]) / (2.0 * h);
    let b = (pr.x[3] - pr.x[4]) / (2.0 * h);
    let d = (pr.y[3] - pr.y[4]) / (2.0 * h);

    let half = (n as i32 - 1) / 2;
    let step = if n > 1 { 2.0 * half_width_mm / (n - 1) as f64 } else { 0.0 };
    let mut fields = Vec::with_capacity(n * n);
    let mut idx = Vec::with_capacity(n * n);
    for ii in 0..n as i32 {
        for jj in 0..n as i32 {
            let (x, y) = (-half_width_mm + ii as f64 * step, -half_width_mm + jj as f64 * step);
            fields.push([if n == 1 { 0.0 } else { x }, if n == 1 { 0.0 } else { y }]);
            idx.push((ii - half, jj - half));
        }
    }
    let out = tracer.trace(system, &RayBatch::chief_rays(system, &to_fields(&fields), wavelength_nm)?)?;
    let mut points = Vec::with_capacity(fields.len());
    let mut max_distortion_pct: f64 = 0.0;
    for (k, f) in fields.iter().enumerate() {
        let (px, py) = (a * f[0] + b * f[1], c * f[0] + d * f[1]);
        let ok = out.status[k] == RayStatus::Ok;
        let (rx, ry) = if ok { (out.x[k] - reference_mm[0], out.y[k] - reference_mm[1]) } else { (0.0, 0.0) };
        let pred_r = px.hypot(py);
        let distortion_pct = if ok && pred_r > 0.0 {
            let sign = if rx.hypot(ry) < pred_r { -1.0 } else { 1.0 };
            sign * 100.0 * (rx - px).hypot(ry - py) / pred_r
        } else {
            0.0
        };
        if distortion_pct.abs() > max_distortion_pct.abs() {
            max_distortion_pct = distortion_pct;
        }
        points.push(DistortionPoint {
            i: idx[k].0,
            j: idx[k].1,
            x_field_mm: f[0],
            y_field_mm: f[1],
            x_field_deg: tan.then(|| f[0].atan().to_degrees()),
            y_field_deg: tan.then(|| f[1].atan().to_degrees()),
            real_x_mm: if ok { out.x[k] } else { 0.0 },
            real_y_mm: if ok { out.y[k] } else { 0.0 },
            pred_x_mm: reference_mm[0] + px,
            pred_y_mm: reference_mm[1] + py,
            distortion_pct,
            status: out.status[k],
        });
    }
    Ok(DistortionGrid { wavelength_nm, reference_mm, abcd: [a, b, c, d], points, max_distortion_pct })
}
