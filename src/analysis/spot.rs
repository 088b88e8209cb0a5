use crate::rays::RayBatch;
use crate::error::{Error, Result};
use crate::system::SequentialSystem;
use crate::tracer::{RayStatus, Tracer};

/// Centroid, RMS and GEO radius of a set of image points (mm in, µm radii out).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct SpotStats {
    pub count: usize,
    pub centroid_mm: [f64; 2],
    /// √(mean squared distance to the centroid), µm.
    pub rms_radius_um: f64,
    /// Largest distance to the centroid, µm.
    pub geo_radius_um: f64,
}

/// Statistics of the points (x, y) in mm. `None` when there are no points.
pub fn spot_stats(points: impl Iterator<Item = (f64, f64)> + Clone) -> Option<SpotStats> {
    let (mut n, mut sx, mut sy) = (0usize, 0.0, 0.0);
    for (x, y) in points.clone() {
        n += 1;
        sx += x;
        sy += y;
    }
    if n == 0 {
        return None;
    }
    let (cx, cy) = (sx / n as f64, sy / n as f64);
    let (mut s2, mut max2): (f64, f64) = (0.0, 0.0);
    for (x, y) in points {
        let r2 = (x - cx).powi(2) + (y - cy).powi(2);
        s2 += r2;
        max2 = max2.max(r2);
    }
    Some(SpotStats { count: n, centroid_mm: [cx, cy], rms_radius_um: 1e3 * (s2 / n as f64).sqrt(), geo_radius_um: 1e3 * max2.sqrt() })
}

/// A spot diagram: every ray of one field and wavelength at the image surface.
///
/// The per-ray vectors (`pupil`, `x_mm`, `y_mm`, `status`) are empty after [`SpotDiagram::keep_statistics_only`];
/// `rays` still counts the traced rays.
#[derive(Clone, Debug, serde::Serialize)]
pub struct SpotDiagram {
    pub field_mm: [f64; 2],
    pub wavelength_nm: f64,
    /// Rays traced (without the chief ray).
    pub rays: usize,
    pub pupil: Vec<[f64; 2]>,
    pub x_mm: Vec<f64>,
    pub y_mm: Vec<f64>,
    pub status: Vec<RayStatus>,
    /// Chief-ray position (mm), when the chief ray arrives.
    pub chief_mm: Option<[f64; 2]>,
    /// Statistics of the arrived rays about their centroid (`None` when none arrived).
    pub stats: Option<SpotStats>,
    /// RMS radius about the chief ray (µm), Zemax's default reference.
    pub rms_radius_chief_um: Option<f64>,
    /// The rays that did not reach the image, by outcome and the surface where they stopped (most first);
    /// kept by [`SpotDiagram::keep_statistics_only`], so a spot with no ray arrived can say why.
    pub lost: Vec<LostRays>,
}

/// Rays of one spot that stopped with the same outcome at the same surface.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct LostRays {
    /// Written as its label (`evanescent`, `vignetted`, …), as the CSV tables write a ray's status.
    #[serde(serialize_with = "RayStatus::serialize_label")]
    pub status: RayStatus,
    /// Surface index (the object is 0) where the rays stopped.
    pub surface: u32,
    pub count: usize,
}

/// Count the failed rays of `status`/`surface` (a tracer's per-ray outcome and stopping surface) by
/// (outcome, surface), most frequent first; ties in (surface, outcome) order, so the list is deterministic.
pub fn lost_rays(status: &[RayStatus], surface: &[u32]) -> Vec<LostRays> {
    let mut counts = std::collections::BTreeMap::<(u32, u8), (RayStatus, usize)>::new();
    for (s, k) in status.iter().zip(surface) {
        if *s != RayStatus::Ok {
            counts.entry((*k, *s as u8)).or_insert((*s, 0)).1 += 1;
        }
    }
    let mut lost: Vec<LostRays> = counts.into_iter().map(|((surface, _), (status, count))| LostRays { status, surface, count }).collect();
    lost.sort_by(|a, b| b.count.cmp(&a.count));
    lost
}

/// The first `at_most` causes of `lost` described and joined by "; ", then how many more there are.
pub fn describe_lost(lost: &[LostRays], at_most: usize) -> String {
    let mut text = lost.iter().take(at_most).map(LostRays::describe).collect::<Vec<_>>().join("; ");
    if lost.len() > at_most {
        text += &format!("; {} more causes", lost.len() - at_most);
    }
    text
}

impl LostRays {
    /// "19 evanescent at surface 4 (the grating order does not propagate)".
    pub fn describe(&self) -> String {
        format!("{} {} at surface {} ({})", self.count, self.status.label(), self.surface, self.status.meaning())
    }
}

impl SpotDiagram {
    /// Drop the per-ray results, keeping the statistics: for callers that want only centroids and radii,
    /// so a sweep over many fields and wavelengths holds one spot's rays at a time.
    pub fn keep_statistics_only(&mut self) {
        for v in [&mut self.x_mm, &mut self.y_mm] {
            *v = Vec::new();
        }
        self.pupil = Vec::new();
        self.status = Vec::new();
    }

    /// RMS radius about the centroid (µm), 0 when no ray arrived (see `stats`).
    pub fn rms_radius_um(&self) -> f64 {
        self.stats.map(|s| s.rms_radius_um).unwrap_or(0.0)
    }
}

/// Normalised pupil points (px, py) must lie in the unit disc (a 1e-9 tolerance for exported rims): the first
/// one that does not, as (its index, the point) — `spot --pupil-csv` and the bindings' `spot(pupil=...)` both
/// refuse it, naming the row.
pub fn first_point_outside_pupil(points: &[[f64; 2]]) -> Option<(usize, [f64; 2])> {
    points.iter().enumerate().find(|(_, p)| !(p[0].is_finite() && p[1].is_finite() && p[0].hypot(p[1]) <= 1.0 + 1e-9)).map(|(i, p)| (i, *p))
}

/// Refuse a normalised pupil point outside the unit disc ([`first_point_outside_pupil`]), naming its index.
pub fn check_pupil_points(points: &[[f64; 2]]) -> Result<()> {
    match first_point_outside_pupil(points) {
        Some((i, p)) => Err(Error::invalid(format!("pupil point {i} (px, py) = ({}, {}): normalised pupil coordinates must satisfy px² + py² ≤ 1", p[0], p[1]))),
        None => Ok(()),
    }
}

/// Trace the normalised pupil points `pupil` of field `field_mm` at `wavelength_nm`: mapped by the field's
/// vignetting factors when it is a defined field that has some ([`SequentialSystem::vignetted_pupil`]);
/// `SpotDiagram::pupil` keeps the points as given.
pub fn spot_diagram(system: &SequentialSystem, tracer: &dyn Tracer, field_mm: [f64; 2], wavelength_nm: f64, pupil: &[[f64; 2]]) -> Result<SpotDiagram> {
    // Normalised pupil coordinates live in the unit disc: a point at radius 2 traced "ok" and tripled the RMS
    // (C++; the CLI's --pupil-csv and Python refused it already).
    check_pupil_points(pupil)?;
    // A defined field's vignetting factors map its pupil points (src/system/vignetting.rs); the chief ray,
    // traced alongside, passes through the stop centre whatever they are.
    let mut pts = system.vignetted_pupil(field_mm, pupil);
    pts.push([0.0, 0.0]);
    let out = tracer.trace(system, &RayBatch::for_field(system, field_mm, &pts, wavelength_nm)?)?;
    let n = pupil.len();
    let chief_mm = (out.status[n] == RayStatus::Ok).then(|| [out.x[n], out.y[n]]);
    let ok = |i: &usize| out.status[*i] == RayStatus::Ok;
    let stats = spot_stats((0..n).filter(ok).map(|i| (out.x[i], out.y[i])));
    let rms_radius_chief_um = chief_mm.and_then(|c| {
        let (mut s, mut k) = (0.0, 0usize);
        for i in (0..n).filter(ok) {
            s += (out.x[i] - c[0]).powi(2) + (out.y[i] - c[1]).powi(2);
            k += 1;
        }
        (k > 0).then(|| 1e3 * (s / k as f64).sqrt())
    });
    Ok(SpotDiagram {
        field_mm,
        wavelength_nm,
        rays: n,
        pupil: pupil.to_vec(),
        x_mm: out.x[..n].to_vec(),
        y_mm: out.y[..n].to_vec(),
        status: out.status[..n].to_vec(),
        chief_mm,
        stats,
        rms_radius_chief_um,
        lost: lost_rays(&out.status[..n], &out.surface[..n]),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tracer::AnalyticTracer;

    /// Statistics-only spots keep the numbers and the ray count, and hold no per-ray results.
    #[test]
    fn statistics_only_keeps_the_statistics() {
        let system = SequentialSystem::build(&crate::presets::spec("sp").unwrap()).unwrap();
        let pupil = crate::rays::PupilPattern::Hexapolar { rings: 4 }.points();
        let full = spot_diagram(&system, &AnalyticTracer::default(), [2.5, 0.0], 520.0, &pupil).unwrap();
        let mut lean = full.clone();
        lean.keep_statistics_only();
        assert_eq!(lean.rays, pupil.len());
        assert_eq!(full.rays, full.status.len());
        assert!(lean.x_mm.is_empty() && lean.y_mm.is_empty() && lean.status.is_empty() && lean.pupil.is_empty());
        assert_eq!(lean.stats, full.stats);
        assert_eq!(lean.chief_mm, full.chief_mm);
        assert_eq!(lean.rms_radius_chief_um, full.rms_radius_chief_um);
        assert!(full.stats.unwrap().count > 0);
        assert_eq!(lean.lost, full.lost);
    }

    /// Lost rays are counted by (outcome, surface), most first, and account for every failed ray; a spot
    /// whose every ray is lost says why (here: a grating of 10 lines/µm, whose first order cannot propagate
    /// at 520 nm, so every ray is evanescent at the grating).
    #[test]
    fn lost_rays_say_why() {
        use RayStatus::*;
        let lost = lost_rays(&[Ok, Vignetted, Missed, Vignetted, Vignetted, Ok], &[u32::MAX, 3, 5, 3, 7, u32::MAX]);
        assert_eq!(lost, vec![LostRays { status: Vignetted, surface: 3, count: 2 }, LostRays { status: Missed, surface: 5, count: 1 }, LostRays { status: Vignetted, surface: 7, count: 1 }]);
        assert_eq!(lost[0].describe(), "2 vignetted at surface 3 (outside the surface's aperture)");
        assert_eq!(describe_lost(&lost, 1), "2 vignetted at surface 3 (outside the surface's aperture); 2 more causes");
        assert_eq!(describe_lost(&lost, 3).matches("; ").count(), 2);

        let mut spec = crate::presets::spec("gsp").unwrap();
        let g = spec.surfaces.iter().position(|s| s.grating_lines_per_um.is_some()).unwrap();
        spec.surfaces[g].grating_lines_per_um = Some(10.0.into());
        for s in &mut spec.surfaces {
            for c in [&mut s.decenter_x_mm, &mut s.decenter_y_mm, &mut s.tilt_y_deg] {
                if let Some(c) = c.as_mut() {
                    c.driver = crate::spec::Driver::Fixed;
                }
            }
        }
        let system = SequentialSystem::build(&spec).unwrap();
        let pupil = crate::rays::PupilPattern::Hexapolar { rings: 2 }.points();
        let spot = spot_diagram(&system, &AnalyticTracer::default(), [0.0, 0.0], 520.0, &pupil).unwrap();
        assert!(spot.stats.is_none());
        assert_eq!(spot.lost, vec![LostRays { status: Evanescent, surface: g as u32, count: pupil.len() }]);
        let sp = spot_diagram(&SequentialSystem::build(&crate::presets::spec("sp").unwrap()).unwrap(), &AnalyticTracer::default(), [0.0, 0.0], 520.0, &pupil).unwrap();
        assert!(sp.lost.is_empty() && sp.stats.unwrap().count == pupil.len());
    }
}
