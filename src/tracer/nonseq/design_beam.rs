//! The **design beam** against the solids: checks that no solid built with a mechanical margin stands in
//! the beam the system was designed for.
//!
//! In a folded system (mirrors, fold mirrors behind coordinate breaks, a tilted concave mirror whose
//! image lies beside the incoming beam) a face enlarged by its mechanical margin — above all the detector
//! disc with its [`SolidsOptions::detector_margin_mm`] — can reach into the beam on its way to an earlier
//! surface; the non-sequential backends would then stop those rays there: a silently wrong result.
//!
//! The design beam: per field of the system (the axis when it has none; mirrored to all four quadrants,
//! as the mechanical semi-diameters are), at the primary wavelength, the
//! chief ray and eight rim rays (pupil ±x, ±y and the four diagonals at radius 1: the pupil's outline as an
//! octagon, so that a face reaching into the beam between the axes is seen too), traced by the analytic
//! sequential tracer with its
//! point on every real face ([`sequential_hits`]; points on virtual surfaces — dummies between equal media —
//! are left out: no solid stands there, and a dummy placed behind the next face would make a segment that
//! no real ray runs). Rays the sequential tracer vignettes or fails are skipped (only rays that arrive
//! define the design beam), and so are rays that reach a real face at a negative distance (no walk
//! follows them); a field whose chief ray fails is skipped whole. Each segment between two
//! consecutive crossings (the first starting where the non-sequential walk starts the ray: the object
//! point, or the [`super::launch::StartPlane`] at infinity) is tested against every optical solid except
//! those it starts and ends on:
//! * the **detector** with a mechanical aperture: its margin shrinks to the largest value that clears
//!   every segment, less [`DETECTOR_CLEARANCE_MM`] ([`DesignBeam::detector_margin_mm`]); when even margin 0
//!   is crossed (the image disc itself stands in the beam) it is an error;
//! * **any other face** with a mechanical aperture, crossed in its margin (beyond its semi-diameter): an
//!   error naming the surface, the field, the segment's surfaces and the radius at which the beam crosses
//!   ([`DesignBeam::check_faces`]). Faces with an explicit clear aperture, and crossings inside a face's own
//!   semi-diameter, are the design's own geometry and are left as they are.
//!
//! A handful of rays × surfaces: cheap and deterministic (no sampling).
use super::launch::StartPlane;
use super::solids::{Role, Solid, Solids, SolidsOptions};
use crate::error::{Error, Result};
use crate::rays::RayBatch;
use crate::surfaces::Aperture;
use crate::system::{Interaction, SequentialSystem};
use crate::tracer::hits::{sequential_hits, HitKind, HitRecord};
use crate::tracer::RayStatus;
use glam::DVec3;

/// Normalised pupil points of the design rays: the chief ray, the marginal rays ±x, ±y, then the four
/// diagonal rim rays (radius 1).
const DESIGN_PUPIL: [[f64; 2]; 9] = [
    [0.0, 0.0],
    [1.0, 0.0],
    [-1.0, 0.0],
    [0.0, 1.0],
    [0.0, -1.0],
    [std::f64::consts::FRAC_1_SQRT_2, std::f64::consts::FRAC_1_SQRT_2],
    [-std::f64::consts::FRAC_1_SQRT_2, std::f64::consts::FRAC_1_SQRT_2],
    [std::f64::consts::FRAC_1_SQRT_2, -std::f64::consts::FRAC_1_SQRT_2],
    [-std::f64::consts::FRAC_1_SQRT_2, -std::f64::consts::FRAC_1_SQRT_2],
];

/// What a shrunk detector rim keeps between itself and the nearest crossing of the design beam (mm).
pub const DETECTOR_CLEARANCE_MM: f64 = 1e-3;

/// Crossings closer than this to a segment's ends (mm, plus 1e-9 of its length) are the segment's own
/// surfaces (a face the path crosses again is one solid that lists only its first crossing's surfaces).
const END_TOLERANCE_MM: f64 = 1e-6;

/// Most crossings of one segment with one figure looked for (a conic has two; a safe bound for aspheres).
const MAX_CROSSINGS: usize = 8;

/// One straight piece of a design ray, between two consecutive crossings (global coordinates, mm).
#[derive(Clone, Debug, PartialEq)]
pub struct Segment {
    /// The field (system units: mm, or radians at infinity) and the normalised pupil point of the ray.
    pub field: [f64; 2],
    pub pupil: [f64; 2],
    /// Sequential surfaces at the segment's start (0: the object, or the start plane at infinity) and end.
    pub from_surface: usize,
    pub to_surface: usize,
    pub start: DVec3,
    pub end: DVec3,
}

/// Where a segment crosses an optical solid's figure inside its clear aperture.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Crossing {
    /// Distance from the aperture's centre in the solid's local x, y (mm).
    radius_mm: f64,
}

/// The design beam of a system, as segments.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DesignBeam {
    pub segments: Vec<Segment>,
}

/// The detector margin the design beam allows ([`DesignBeam::detector_margin_mm`]).
#[derive(Clone, Debug, PartialEq)]
pub struct DetectorFit {
    /// The margin to build with (mm): the requested one, or less where the beam needs it.
    pub margin_mm: f64,
    /// Why it was shrunk (`None`: unchanged).
    pub note: Option<String>,
}

impl DesignBeam {
    /// Trace the design rays of `system` (see the module doc). `start_plane`: where the walks start rays
    /// of an object at infinity. Never fails: rays that cannot be aimed or traced are left out.
    pub fn trace(system: &SequentialSystem, start_plane: Option<&StartPlane>) -> Self {
        let wavelength_nm = system.primary_wavelength_nm();
        let fields = crate::analysis::mirrored_fields(system);
        let mut segments = Vec::new();
        for field in fields {
            // The chief ray first: a field whose chief ray cannot be aimed or does not arrive is skipped.
            let mut rays = RayBatch::default();
            let mut pupils = Vec::new();
            for pupil in DESIGN_PUPIL {
                match RayBatch::for_field(system, field, &[pupil], wavelength_nm) {
                    Ok(r) => {
                        rays.extend(&r);
                        pupils.push(pupil);
                    }
                    Err(_) if pupil == DESIGN_PUPIL[0] => break,
                    Err(_) => {}
                }
            }
            if pupils.first() != Some(&DESIGN_PUPIL[0]) {
                continue;
            }
            let Ok((traced, log)) = sequential_hits(system, &rays) else { continue };
            if traced.status[0] != RayStatus::Ok {
                continue;
            }
            for (i, pupil) in pupils.iter().enumerate() {
                if traced.status[i] == RayStatus::Ok {
                    segments.extend(ray_segments(system, start_plane, field, *pupil, rays.origin(i), rays.direction(i), log.ray(i)).into_iter().flatten());
                }
            }
        }
        DesignBeam { segments }
    }

    /// The detector margin (mm) to build with: `options.detector_margin_mm`, or the largest margin that
    /// clears every segment less [`DETECTOR_CLEARANCE_MM`] when the detector disc of `solids` (built with
    /// `options`) stands in the beam. The margin applies only to a detector with a mechanical (circular,
    /// no explicit) aperture; otherwise it is returned unchanged (an explicit aperture is the user's
    /// choice). Error: even margin 0 is crossed — the image disc itself stands in the beam.
    pub fn detector_margin_mm(&self, system: &SequentialSystem, solids: &Solids, options: &SolidsOptions) -> Result<DetectorFit> {
        let unchanged = DetectorFit { margin_mm: options.detector_margin_mm, note: None };
        let Some((k, detector)) = mechanical_detector(solids) else { return Ok(unchanged) };
        let Some(Aperture::Circular { semi_diameter_mm, .. }) = detector.patch.as_ref().map(|p| &p.aperture) else { return Ok(unchanged) };
        let base_mm = semi_diameter_mm - options.detector_margin_mm;
        // The nearest crossing of the beam to the detector's centre, with the segment that makes it.
        let nearest = self
            .segments
            .iter()
            .flat_map(|s| segment_crossings(solids, k, s).into_iter().map(move |c| (c.radius_mm, s)))
            .min_by(|a, b| a.0.total_cmp(&b.0));
        let Some((radius_mm, seg)) = nearest else { return Ok(unchanged) };
        if radius_mm <= base_mm {
            return Err(Error::invalid(format!(
                "system `{}`: the image surface {} stands in the design beam even without a detector margin: {} crosses its plane at r = {radius_mm:.4} mm, inside its semi-diameter {base_mm:.4} mm (with the mechanical margin); the non-sequential backends would stop those rays on the detector (use the analytic backend, or move the image out of the beam)",
                system.name(),
                solids.image_surface,
                describe(system, seg),
            )));
        }
        let margin_mm = (radius_mm - base_mm - DETECTOR_CLEARANCE_MM).max(0.0);
        let note = format!(
            "detector margin of image surface {} shrunk from {} mm to {margin_mm:.4} mm: with it the detector disc (r = {:.4} mm) stood in the design beam ({} crosses its plane at r = {radius_mm:.4} mm)",
            solids.image_surface,
            options.detector_margin_mm,
            semi_diameter_mm,
            describe(system, seg),
        );
        Ok(DetectorFit { margin_mm, note: Some(note) })
    }

    /// Error if a segment crosses a face of `solids` (built with `options`) whose clear aperture is the
    /// mechanical one — Zemax's or the automatic semi-diameter plus [`SolidsOptions::mechanical_margin_mm`]
    /// — in its margin (beyond the semi-diameter): the margin the solids add stands in the beam. The error
    /// names the surface, the field, the segment's surfaces and the radius, and what the user can do.
    /// Not checked: the detector (its margin is [`Self::detector_margin_mm`]'s), faces with an explicit
    /// clear aperture (the user's choice), and crossings inside a face's own semi-diameter (the design's
    /// own geometry, as a Cassegrain primary without a hole in its file: docs/ghosts.md).
    pub fn check_faces(&self, system: &SequentialSystem, solids: &Solids, options: &SolidsOptions) -> Result<()> {
        for seg in &self.segments {
            for (k, o) in solids.objects.iter().enumerate() {
                if !o.is_optical() || matches!(o.role, Role::Detector { .. }) || o.apertures.iter().any(|(_, ap)| ap.is_bounded()) {
                    continue;
                }
                let Some(Aperture::Circular { semi_diameter_mm, .. }) = o.patch.as_ref().map(|p| &p.aperture) else { continue };
                let base_mm = semi_diameter_mm - options.mechanical_margin_mm;
                if let Some(c) = segment_crossings(solids, k, seg).into_iter().find(|c| c.radius_mm > base_mm) {
                    let surface = object_surface(o);
                    return Err(Error::invalid(format!(
                        "system `{}`: surface {surface} stands in the design beam: {} crosses it at r = {:.4} mm, inside its mechanical clear aperture ({base_mm:.4} mm semi-diameter + {} mm mechanical margin = {semi_diameter_mm:.4} mm); the non-sequential backends would stop those rays there. Give surface {surface} an explicit clear aperture that leaves the beam free, or a smaller mechanical margin (SolidsOptions::mechanical_margin_mm, below {:.4} mm)",
                        system.name(),
                        describe(system, seg),
                        c.radius_mm,
                        options.mechanical_margin_mm,
                        c.radius_mm - base_mm,
                    )));
                }
            }
        }
        Ok(())
    }
}

/// The segments of one arrived design ray: from where the walk starts it (the object point, or the start
/// plane at infinity) through its points on every real face (`hits`: its sequential records).
///
/// `None` when the sequential ray reaches a real face at a negative distance (a segment that runs against
/// the ray's own direction there, as across the tilted coincident halves of a split prism): no
/// non-sequential walk follows that path, so it defines no beam.
fn ray_segments(system: &SequentialSystem, start_plane: Option<&StartPlane>, field: [f64; 2], pupil: [f64; 2], origin: DVec3, direction: DVec3, hits: &[HitRecord]) -> Option<Vec<Segment>> {
    let mut from = (0usize, super::launch::launch_origin(start_plane, origin, direction.normalize()));
    let mut out = Vec::new();
    for h in hits.iter().filter(|h| is_real_face(system, h)) {
        let s = h.first_surface as usize;
        let frame = &system.surfaces[s].frame;
        let point = frame.point_to_global(h.point);
        if (point - from.1).length() > 1e-9 {
            if (point - from.1).dot(frame.dir_to_global(h.direction)) <= 0.0 {
                return None;
            }
            out.push(Segment { field, pupil, from_surface: from.0, to_surface: s, start: from.1, end: point });
        }
        from = (s, point);
    }
    Some(out)
}

/// A record on a face that has a solid: a mirror, an ideal lens, the image, or a refraction between
/// different media (a dummy between equal media is virtual: no solid).
fn is_real_face(system: &SequentialSystem, h: &HitRecord) -> bool {
    let s = h.first_surface as usize;
    match h.kind {
        HitKind::Mirror | HitKind::Detector | HitKind::Deflection | HitKind::Reflection => true,
        HitKind::Refraction => {
            system.surfaces[s].interaction == Interaction::Reflect
                || system.surfaces[h.medium_in as usize].medium_after != system.surfaces[h.medium_out as usize].medium_after
        }
    }
}

/// The detector object, when its clear aperture is the mechanical one (no explicit bounded aperture).
fn mechanical_detector(solids: &Solids) -> Option<(usize, &Solid)> {
    solids
        .objects
        .iter()
        .enumerate()
        .find(|(_, o)| matches!(o.role, Role::Detector { .. }))
        .filter(|(_, o)| !o.apertures.iter().any(|(_, ap)| ap.is_bounded()))
}

/// The sequential surfaces an optical object stands for.
fn object_surfaces(o: &Solid) -> &[usize] {
    match &o.role {
        Role::Interface { surfaces, .. } => surfaces,
        Role::Mirror { surface, .. } | Role::Detector { surface, .. } => std::slice::from_ref(surface),
        _ => &[],
    }
}

/// The first sequential surface of an optical object (for messages).
fn object_surface(o: &Solid) -> usize {
    object_surfaces(o).first().copied().unwrap_or(0)
}

/// Where segment `seg` crosses optical object `k` of `solids` inside its clear aperture, nearest its start
/// first; none when the segment starts or ends on that object.
fn segment_crossings(solids: &Solids, k: usize, seg: &Segment) -> Vec<Crossing> {
    let o = &solids.objects[k];
    let Some(patch) = o.patch.as_ref() else { return Vec::new() };
    if object_surfaces(o).iter().any(|&s| s == seg.from_surface || s == seg.to_surface) {
        return Vec::new();
    }
    let length = (seg.end - seg.start).length();
    if !(length > 0.0) {
        return Vec::new();
    }
    let p = o.frame.point_to_local(seg.start);
    let d = o.frame.dir_to_local((seg.end - seg.start) / length);
    let tol = END_TOLERANCE_MM + 1e-9 * length;
    let (cx, cy) = match patch.aperture {
        Aperture::Circular { decenter_x_mm, decenter_y_mm, .. } | Aperture::Rectangular { decenter_x_mm, decenter_y_mm, .. } => (decenter_x_mm, decenter_y_mm),
        _ => (0.0, 0.0),
    };
    let mut out = Vec::new();
    let mut tmin = tol;
    while out.len() < MAX_CROSSINGS {
        let Some(t) = patch.first_hit(p, d, tmin, length - tol) else { break };
        let q = p + d * t;
        out.push(Crossing { radius_mm: (q.x - cx).hypot(q.y - cy) });
        tmin = t + tol;
    }
    out
}

/// "the design ray (field …, pupil …) from surface a to surface b", for messages.
fn describe(system: &SequentialSystem, seg: &Segment) -> String {
    let (f, unit) = system.field_display(seg.field);
    let from = if seg.from_surface == 0 { "the object".to_string() } else { format!("surface {}", seg.from_surface) };
    format!(
        "the design ray of field ({}, {}) {unit}, pupil ({}, {}), on its way from {from} to surface {}",
        f[0], f[1], seg.pupil[0], seg.pupil[1], seg.to_surface
    )
}
