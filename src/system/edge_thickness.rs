//! Edge thickness: where the two faces that bound one glass cross.
//!
//! A lens is the glass between two faces; its thickness at height r, measured along the axis, is
//! t(r) = t₀ + sag₂(r) − sag₁(r). Where t(r) changes sign (N-BK7, R₁ = +10 mm, R₂ = −10 mm, 1 mm thick:
//! r ≈ 3.1 mm) the faces cross: beyond it the "lens" has a negative edge thickness, a solid that cannot
//! exist. A sequential tracer does not care (it intersects each face's extension in turn, propagating
//! backwards between them where needed, as OpticStudio's sequential mode does), but a solid built to that
//! radius has its back face in front of its front face, and a non-sequential tracer walking it finds
//! nonsense (a reflection "order 1" that reached the detector of a refracting singlet; round 21).
//!
//! [`faces_crossing_radius`] finds the smallest radius where two faces cross, for faces whose **axes are
//! parallel** (coaxial faces, and faces decentred or turned about their axis relative to each other: the gap
//! is measured along the common axis direction, exactly). Faces whose axes are tilted relative to each
//! other (a prism's faces, a wedge: a Coordinate Break tilt between them) are not checked: they are meant to
//! meet somewhere (a prism's apex), their gap has no common axis to be measured along, and the solids
//! join their rims by a ruled wall whatever the angle.
//!
//! [`SequentialSystem::edge_crossing_warnings`] warns (at load, once per pair) where the crossing lies inside
//! both faces' semi-diameters; the non-sequential solids (`tracer::nonseq::solids`) end the glass at a
//! crossing outside the system's beam and refuse one the beam reaches.
//!
//! ```
//! use diffcassi::system::SequentialSystem;
//! let spec = diffcassi::presets::spec("sp").unwrap();
//! assert!(SequentialSystem::build(&spec).unwrap().edge_crossing_warnings().is_empty());
//! ```
use super::{Interaction, SequentialSystem};
use crate::geometry::Frame;
use crate::surfaces::{Aperture, SurfaceShape};

/// Where two faces bounding one glass cross, inside a semi-diameter.
#[derive(Clone, Debug, PartialEq)]
pub struct FaceCrossing {
    /// The sequential surfaces of the two faces, in path order.
    pub front: usize,
    pub back: usize,
    /// The medium between them (a glass name).
    pub glass: String,
    /// Smallest radius from the first face's axis where they cross (mm).
    pub radius_mm: f64,
}

/// Whether the outer bound of `ap` (its clear region, ignoring a central hole) contains local (x, y);
/// `None` bounds nothing.
fn outer_contains(ap: &Aperture, x: f64, y: f64) -> bool {
    match *ap {
        Aperture::Circular { semi_diameter_mm, decenter_x_mm, decenter_y_mm, .. } => (x - decenter_x_mm).hypot(y - decenter_y_mm) <= semi_diameter_mm,
        Aperture::Rectangular { .. } => ap.contains(x, y),
        Aperture::None | Aperture::CircularObscuration { .. } => true,
    }
}

/// The largest distance from the local origin of a point inside `ap` (`None` for an unbounded one).
fn reach_of(ap: &Aperture) -> Option<f64> {
    match *ap {
        Aperture::Circular { semi_diameter_mm, decenter_x_mm, decenter_y_mm, .. } => Some(semi_diameter_mm + decenter_x_mm.hypot(decenter_y_mm)),
        Aperture::Rectangular { half_width_x_mm, half_width_y_mm, decenter_x_mm, decenter_y_mm } => {
            Some((decenter_x_mm.abs() + half_width_x_mm).hypot(decenter_y_mm.abs() + half_width_y_mm))
        }
        Aperture::None | Aperture::CircularObscuration { .. } => None,
    }
}

/// The smallest radius (mm, from face `a`'s axis, within `a`'s and `b`'s apertures `domain`) where face `b`
/// crosses face `a`: where the gap between them along their common axis direction, g(x, y) = z_b − sag_a
/// in `a`'s frame, has the opposite sign to its value on `a`'s axis (the centre thickness). `None` when
/// they do not cross there, when their axes are not parallel (not checked: see the module docs), when `a`'s
/// axis does not meet `b` inside `b`'s domain, when the faces touch on the axis (no centre thickness to
/// compare with), or when a domain is unbounded.
///
/// Radial samples (256 per azimuth, 72 azimuths; one azimuth for rotationally symmetric coaxial faces with
/// centred round domains) find the first sign change, then bisection places it to 1e-12 of the radius.
/// Gaps within 1e-9 mm of zero (faces meeting exactly at the rim) are not a crossing.
pub fn faces_crossing_radius(a: (&SurfaceShape, &Frame, &Aperture), b: (&SurfaceShape, &Frame, &Aperture)) -> Option<f64> {
    let (sa, fa, da) = a;
    let (sb, fb, db) = b;
    // Parallel (or antiparallel, after a mirror) axes only.
    if fa.rotation.z_axis.dot(fb.rotation.z_axis).abs() < 1.0 - 1e-12 {
        return None;
    }
    let reach = reach_of(da)?.min(reach_of(db)? + fa.point_to_local(fb.origin).truncate().length());
    if !(reach > 0.0 && reach.is_finite()) {
        return None;
    }
    // The gap at a-local (x, y): b's face point on the line through (x, y, ·) along a's axis, minus a's sag;
    // None outside either domain or where a figure is undefined (its own error elsewhere).
    let gap = |x: f64, y: f64| -> Option<f64> {
        if !outer_contains(da, x, y) {
            return None;
        }
        let q = fb.point_to_local(fa.point_to_global(glam::DVec3::new(x, y, 0.0)));
        if !outer_contains(db, q.x, q.y) {
            return None;
        }
        let zb = fa.point_to_local(fb.point_to_global(glam::DVec3::new(q.x, q.y, sb.sag(q.x, q.y)))).z;
        let g = zb - sa.sag(x, y);
        g.is_finite().then_some(g)
    };
    let g0 = gap(0.0, 0.0)?;
    if g0.abs() < 1e-12 {
        return None;
    }
    let s = g0.signum();
    let symmetric = |sh: &SurfaceShape| !matches!(sh, SurfaceShape::Toroidal { .. });
    let centred = |ap: &Aperture| match *ap {
        Aperture::Circular { decenter_x_mm, decenter_y_mm, .. } => decenter_x_mm == 0.0 && decenter_y_mm == 0.0,
        _ => false,
    };
    let off_axis = fa.point_to_local(fb.origin).truncate().length();
    let azimuths = if symmetric(sa) && symmetric(sb) && centred(da) && centred(db) && off_axis <= 1e-9 * (1.0 + fb.origin.length()) { 1 } else { 72 };
    const RADIAL: usize = 256;
    let mut best: Option<f64> = None;
    for k in 0..azimuths {
        let phi = std::f64::consts::TAU * k as f64 / azimuths as f64;
        let (c, sn) = (phi.cos(), phi.sin());
        let at = |r: f64| gap(r * c, r * sn);
        let mut prev = 0.0;
        for i in 1..=RADIAL {
            let r = reach * i as f64 / RADIAL as f64;
            let Some(g) = at(r) else { continue };
            if s * g < -1e-9 {
                // Bisect on the sign of s·g (samples outside a domain count as not crossed).
                let (mut lo, mut hi) = (prev, r);
                for _ in 0..60 {
                    let mid = 0.5 * (lo + hi);
                    if at(mid).is_some_and(|g| s * g < 0.0) {
                        hi = mid;
                    } else {
                        lo = mid;
                    }
                    if hi - lo <= 1e-12 * reach {
                        break;
                    }
                }
                best = Some(best.map_or(hi, |b: f64| b.min(hi)));
                break;
            }
            prev = r;
        }
    }
    best
}

impl SequentialSystem {
    /// The pairs of consecutive faces of the sequential path that bound one glass (the medium after the
    /// first is not air; surfaces with the same medium on both sides in between — dummies — are skipped, a
    /// mirror is a face), as (first, second) surface indices.
    pub(crate) fn glass_face_pairs(&self) -> Vec<(usize, usize)> {
        let medium = |s: usize| &self.surfaces[s].medium_after;
        let real = |s: usize| {
            let r = &self.surfaces[s];
            r.interaction != Interaction::Refract || matches!(r.shape, Some(SurfaceShape::Paraxial { .. })) || s == 0 || medium(s - 1) != medium(s) || s + 1 == self.surfaces.len()
        };
        let faces: Vec<usize> = self.path.iter().map(|p| p.surface).filter(|&s| real(s)).collect();
        faces.windows(2).filter(|w| !medium(w[0]).is_air()).map(|w| (w[0], w[1])).collect()
    }

    /// The faces that bound one glass and cross inside both their semi-diameters ([`faces_crossing_radius`]
    /// within the smaller of the two: the given `semi_diameter_mm`, else the automatic one of the system's
    /// beam), where the lens as drawn cannot exist. A crossing beyond one face's semi-diameter is not one: that
    /// face, and the glass behind it, end before it (SP's doublet with its surface 17 drawn to 25 mm crosses
    /// surface 16's extension at 14.73 mm, beyond surface 16's 12.7 mm). Coaxial and decentred faces with
    /// parallel axes are checked; tilted ones are not (see the module docs).
    pub fn edge_crossings(&self) -> Vec<FaceCrossing> {
        let pairs = self.glass_face_pairs();
        if pairs.is_empty() {
            return Vec::new();
        }
        let mut automatic: Option<Vec<(usize, f64)>> = None;
        let mut out = Vec::new();
        for (a, b) in pairs {
            let (Some(sa), Some(sb)) = (&self.surfaces[a].shape, &self.surfaces[b].shape) else { continue };
            if matches!(sa, SurfaceShape::Paraxial { .. }) || matches!(sb, SurfaceShape::Paraxial { .. }) {
                continue; // an ideal lens has no figure to cross
            }
            let mut sd = |s: usize| -> f64 {
                self.surfaces[s].semi_diameter_mm.unwrap_or_else(|| {
                    let auto = automatic.get_or_insert_with(|| crate::analysis::automatic_semi_diameters(self, 0.0, 32).unwrap_or_default());
                    auto.iter().find(|(i, _)| *i == s).map(|(_, v)| *v).unwrap_or(0.0)
                })
            };
            let r = sd(a).min(sd(b));
            if !(r > 0.0) {
                continue;
            }
            let ap = Aperture::circular(r);
            if let Some(rc) = faces_crossing_radius((sa, &self.surfaces[a].frame, &ap), (sb, &self.surfaces[b].frame, &ap)) {
                out.push(FaceCrossing { front: a, back: b, glass: self.surfaces[a].medium_after.to_string(), radius_mm: rc });
            }
        }
        out
    }

    /// One warning per pair of [`Self::edge_crossings`]: the sequential tracers trace such a lens as
    /// OpticStudio's sequential mode does (each face's extension in turn), but no real lens has that shape;
    /// the non-sequential solids end the glass at the crossing, or refuse it where the beam reaches it.
    pub fn edge_crossing_warnings(&self) -> Vec<String> {
        let f = |v: f64| crate::limits::fmt_num((v * 1e4).round() / 1e4);
        self.edge_crossings()
            .into_iter()
            .map(|c| {
                let sd = |s: usize| self.surfaces[s].semi_diameter_mm.map(|v| format!("{} mm", f(v))).unwrap_or_else(|| "automatic".into());
                format!(
                    "surfaces {} and {} ({} between them) cross at r = {} mm, inside their semi-diameters ({}, {}): the lens has a negative edge thickness beyond r = {} mm; the sequential trace follows each face's extension there as OpticStudio's sequential mode does, but no real lens has that shape, and the non-sequential backends (Embree, ghosts, render --ghosts/--mechanics) end the glass at the crossing where the system's beam stays inside it and refuse the lens where the beam reaches it; give a smaller semi_diameter_mm or thicken the lens",
                    c.front,
                    c.back,
                    c.glass,
                    f(c.radius_mm),
                    sd(c.front),
                    sd(c.back),
                    f(c.radius_mm)
                )
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{DMat3, DVec3};

    /// R₁ = +10, R₂ = −10, 1 mm thick: t(r) = 1 − 2(10 − √(100 − r²)) = 0 where 10 − √(100 − r²) = 0.5,
    /// r = √(100 − 9.5²) = √9.75 ≈ 3.1225 mm.
    #[test]
    fn a_biconvex_lens_crosses_where_its_sags_sum_to_its_thickness() {
        let front = SurfaceShape::Conic { curvature: 0.1, conic: 0.0 };
        let back = SurfaceShape::Conic { curvature: -0.1, conic: 0.0 };
        let fa = Frame::IDENTITY;
        let fb = Frame::new(DVec3::new(0.0, 0.0, 1.0), DMat3::IDENTITY);
        let ap = Aperture::circular(4.0);
        let r = faces_crossing_radius((&front, &fa, &ap), (&back, &fb, &ap)).unwrap();
        assert!((r - 9.75f64.sqrt()).abs() < 1e-9, "{r}");
        // Inside r = 3: no crossing.
        let small = Aperture::circular(3.0);
        assert_eq!(faces_crossing_radius((&front, &fa, &small), (&back, &fb, &small)), None);
        // Decentred by 0.5 mm in y (parallel axes): the crossing moves toward the decentre's side.
        let fd = Frame::new(DVec3::new(0.0, 0.5, 1.0), DMat3::IDENTITY);
        let rd = faces_crossing_radius((&front, &fa, &ap), (&back, &fd, &ap)).unwrap();
        assert!(rd < 9.75f64.sqrt() && rd > 2.0, "{rd}");
        // Tilted axes: not checked.
        let ft = Frame::new(DVec3::new(0.0, 0.0, 1.0), crate::geometry::rot_x(0.1));
        assert_eq!(faces_crossing_radius((&front, &fa, &ap), (&back, &ft, &ap)), None);
    }
}
