//! What a system's front ends warn about when it is loaded: a spec that builds and traces, but not as its
//! author likely meant.
//!
//! * **Glasses** whose catalogue contradicts itself ([`SequentialSystem::glass_warnings`]).
//! * **Semi-diameters beyond a surface's edge** ([`SequentialSystem::surface_edge_warnings`]): a conic
//!   z = c r² / (1 + √(1 − (1+k) c² r²)) with (1 + k) > 0 is defined only for r ≤ 1 / (|c| √(1 + k)) (a
//!   sphere's hemisphere, r ≤ |R|); a semi-diameter beyond it claims a clear aperture the surface does not
//!   have. Rays beyond the edge miss the surface (`RayStatus::Miss`), and near it the sag's slope diverges, so
//!   the f32 kernel's rounding grows without bound (83 µm was measured at 99.9 % of a sphere's radius). OpticStudio
//!   draws such a surface only to its edge. The same bound holds for an even asphere's base conic and for a
//!   toroid's YZ curve (in y); a toroid also ends in x, where the circle its YZ curve is rotated on does:
//!   |x| ≤ |R − z_y(y)| for the radius of rotation R ([`toroid_x_edge_warning`]; a semi-diameter of 12 mm on
//!   R = 10 mm loaded silently, its rays beyond |x| = 10 mm missing: a held-out battery, round 15).
//! * **Faces of one glass crossing inside a semi-diameter** ([`SequentialSystem::edge_crossing_warnings`],
//!   `edge_thickness`): a negative edge thickness (round 21).
//! * **Real ray aiming at a beam that is not round** ([`SequentialSystem::real_aiming_warnings`]): the stop
//!   radius real aiming aims at is measured along +y, as OpticStudio does; where the beam's radius along the
//!   other pupil directions differs, the traced beam depends on the system's orientation (round 18).
//!
//! ```
//! use diffcassi::system::SequentialSystem;
//! let mut spec = diffcassi::presets::spec("sp").unwrap();
//! assert!(SequentialSystem::build(&spec).unwrap().warnings().is_empty());
//! // SP's doublet: surface 17 has R = −22.28 mm; a 25 mm semi-diameter reaches beyond its hemisphere.
//! spec.surfaces[17].semi_diameter_mm = Some(25.0);
//! let w = SequentialSystem::build(&spec).unwrap().warnings();
//! assert_eq!(w.len(), 1);
//! assert!(w[0].starts_with("surface 17: semi-diameter 25 mm is beyond the surface's edge at r = 22.28 mm"), "{}", w[0]);
//! ```
use super::SequentialSystem;
use crate::surfaces::SurfaceShape;

/// The radius (mm) beyond which a conic of curvature `c` (1/mm) and conic constant `k` is undefined, or
/// `None` where it is defined everywhere (a plane, a paraboloid, a hyperboloid: (1 + k) c² ≤ 0).
pub fn conic_edge_mm(c: f64, k: f64) -> Option<f64> {
    let q = (1.0 + k) * c * c;
    (q > 0.0 && q.is_finite()).then(|| 1.0 / q.sqrt())
}

/// A toroid's edge in x: the YZ curve z_y(y) rotated about the axis at z = R (the radius of rotation, c_R =
/// 1/R) reaches |x| = |R − z_y(y)| at height y (`surfaces::toroidal`). The warning for a semi-diameter
/// reaching beyond it at some y of the aperture (the heights where the YZ curve is defined, sampled), naming
/// the height where it reaches furthest beyond, and the largest semi-diameter inside the edge; `None` for a
/// cylinder (c_R = 0) or a semi-diameter within it.
pub fn toroid_x_edge_warning(index: usize, sd: f64, c: f64, k: f64, alpha: &[f64], c_rot: f64) -> Option<String> {
    if c_rot == 0.0 || !(sd > 0.0) {
        return None;
    }
    const N: usize = 2048;
    // (|x| the aperture asks / |x| the surface reaches, y, that reach) at the worst height; the largest inside
    // semi-diameter.
    let (mut worst, mut largest_inside) = ((0.0f64, 0.0f64, 0.0f64), sd);
    for i in 0..=N {
        let y = sd * i as f64 / N as f64;
        let (zy, _, _) = crate::surfaces::toroidal::yz_curve(c, k, alpha, y);
        if !zy.is_finite() {
            continue; // beyond the YZ curve's own edge: its own warning
        }
        let reach = (1.0 / c_rot - zy).abs();
        let asked = (sd * sd - y * y).max(0.0).sqrt();
        if asked / reach > worst.0 {
            worst = (asked / reach, y, reach);
        }
        if asked > reach {
            // The disc of radius √(reach² + y²) stays within the edge at this height.
            largest_inside = largest_inside.min((reach * reach + y * y).sqrt());
        }
    }
    if worst.0 <= 1.0 + 1e-9 {
        return None;
    }
    let fmt = crate::limits::fmt_num;
    let (_, y, reach) = worst;
    Some(format!(
        "surface {index}: semi-diameter {} mm is beyond the toroid's edge in x: at y = {} mm the surface reaches |x| = {} mm (radius of rotation {} mm), so rays beyond it miss the surface; give a semi-diameter ≤ {} mm",
        fmt(sd),
        fmt((y * 1e6).round() / 1e6),
        fmt((reach * 1e6).round() / 1e6),
        fmt(1.0 / c_rot),
        fmt((largest_inside * 1e6).floor() / 1e6)
    ))
}

impl SequentialSystem {
    /// Every load-time warning: [`Self::glass_warnings`], [`Self::surface_edge_warnings`],
    /// [`Self::real_aiming_warnings`] and [`Self::edge_crossing_warnings`] (two faces of one glass crossing
    /// inside a semi-diameter). The CLI prints
    /// them on stderr (`warning: …`), Python raises them as `UserWarning`s when a `System` is made, C++ returns
    /// them from `System::warnings()`.
    pub fn warnings(&self) -> Vec<String> {
        let mut out = self.glass_warnings();
        out.extend(self.surface_edge_warnings());
        out.extend(self.real_aiming_warnings());
        out.extend(self.edge_crossing_warnings());
        out
    }

    /// Real ray aiming (`RAIM 0 2`, `ray_aiming = "real"`) aims every ray at (px, py) × one stop radius, the
    /// real axial beam's along +y (OpticStudio's and optiland's convention, [`crate::rays::real_stop_radius`]).
    /// Where the beam at the stop is not round (a stop decentred behind a lens with coma, an anamorphic beam),
    /// its radius along −y, +x and −x differs, and the traced beam, F/# and spots depend on the system's
    /// orientation about its axis ([`crate::rays::real_stop_radii`]). One warning where they differ by more
    /// than [`Self::REAL_STOP_RADIUS_SPREAD`] of the +y radius, naming the four radii and the paraxial one.
    pub fn real_aiming_warnings(&self) -> Vec<String> {
        if self.spec.ray_aiming != crate::spec::RayAiming::Real || self.spec.aperture == crate::spec::SystemAperture::FloatByStopSize {
            return Vec::new();
        }
        let Some(r) = crate::rays::real_stop_radii(self) else { return Vec::new() };
        let (lo, hi) = r.iter().fold((f64::INFINITY, 0.0f64), |(lo, hi), &v| (lo.min(v), hi.max(v)));
        if (hi - lo) <= Self::REAL_STOP_RADIUS_SPREAD * r[0] {
            return Vec::new();
        }
        let f = |v: f64| crate::limits::fmt_num((v * 1e6).round() / 1e6);
        vec![format!(
            "real ray aiming: the real axial beam at the stop (surface {}) is not round: its radius is {} mm along +y, {} mm along -y, {} mm along +x, {} mm along -x (paraxial {} mm); rays are aimed at the +y radius, as OpticStudio does, so the traced beam depends on how the system is turned about its axis (a spread of {:.1} %); paraxial aiming does not",
            self.stop_index,
            f(r[0]),
            f(r[1]),
            f(r[2]),
            f(r[3]),
            f(self.pupil.stop_radius_mm),
            100.0 * (hi - lo) / r[0]
        )]
    }

    /// The relative spread of the real axial beam's radii at the stop beyond which
    /// [`Self::real_aiming_warnings`] warns: 1 %.
    pub const REAL_STOP_RADIUS_SPREAD: f64 = 0.01;

    /// Warnings about the glasses of the system whose catalogue is inconsistent: the formula's n at the d line
    /// differs from the `NM` line's n_d by more than [`crate::materials::Glass::ND_TOLERANCE`] (`CD -0.5 …`
    /// under `NM … 1.5 …` gave n = 0.696 unflagged). One line per glass; the CLI prints them as warnings.
    pub fn glass_warnings(&self) -> Vec<String> {
        let mut out: Vec<String> = Vec::new();
        for s in &self.surfaces {
            let Some(g) = s.medium_after.glass() else { continue };
            if let Some((n, nd)) = g.nd_mismatch() {
                let w = format!(
                    "glass {} (catalogue {}): its dispersion formula gives n = {} at {} nm, but the catalogue's NM line says n_d = {} (they differ by more than {}): check the catalogue's CD line",
                    g.name,
                    g.catalog,
                    crate::limits::fmt_num(n),
                    crate::materials::D_LINE_NM,
                    nd,
                    crate::materials::Glass::ND_TOLERANCE
                );
                if !out.contains(&w) {
                    out.push(w);
                }
            }
        }
        out
    }

    /// One line per surface whose semi-diameter reaches beyond the radius where its conic is defined
    /// ([`conic_edge_mm`]; a relative margin of 10⁻⁹ for a hemisphere given exactly).
    pub fn surface_edge_warnings(&self) -> Vec<String> {
        let mut out = Vec::new();
        for s in &self.surfaces {
            let (Some(sd), Some(shape)) = (s.semi_diameter_mm, &s.shape) else { continue };
            // The conic that bounds the surface: its own, an even asphere's base conic, a toroid's YZ curve.
            let (c, k, what) = match shape {
                SurfaceShape::Conic { curvature, conic } | SurfaceShape::EvenAsphere { curvature, conic, .. } => (*curvature, *conic, "r"),
                SurfaceShape::Toroidal { curvature, conic, .. } => (*curvature, *conic, "|y|"),
                SurfaceShape::Plane | SurfaceShape::Paraxial { .. } => continue,
            };
            if let SurfaceShape::Toroidal { curvature, conic, coefficients, rotation_curvature } = shape {
                out.extend(toroid_x_edge_warning(s.index, sd, *curvature, *conic, coefficients, *rotation_curvature));
            }
            let Some(edge) = conic_edge_mm(c, k) else { continue };
            if sd > edge * (1.0 + 1e-9) {
                let fmt = crate::limits::fmt_num;
                out.push(format!(
                    "surface {}: semi-diameter {} mm is beyond the surface's edge at {what} = {} mm (radius {} mm, conic {}): the surface is not defined there, so rays beyond the edge miss it; give a semi-diameter ≤ {} mm",
                    s.index,
                    fmt(sd),
                    fmt(edge),
                    fmt(1.0 / c),
                    fmt(k),
                    fmt(edge)
                ));
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A toroid of radius of rotation 10 mm ends at |x| = 10 mm (at y = 0; nearer where its YZ curve bends
    /// toward the axis of rotation): a 12 mm semi-diameter is warned about, a 9.9 mm one and a cylinder are not.
    #[test]
    fn a_toroid_ends_in_x_where_its_circle_of_rotation_does() {
        let (c, k, c_rot) = (1.0 / 20.0, -0.5, 1.0 / 10.0);
        let w = toroid_x_edge_warning(1, 12.0, c, k, &[], c_rot).expect("beyond the edge in x");
        assert!(w.starts_with("surface 1: semi-diameter 12 mm is beyond the toroid's edge in x: at y = 0 mm the surface reaches |x| = 10 mm (radius of rotation 10 mm)"), "{w}");
        assert!(w.contains("give a semi-diameter ≤ 10 mm"), "{w}");
        assert_eq!(toroid_x_edge_warning(1, 9.9, c, k, &[], c_rot), None);
        assert_eq!(toroid_x_edge_warning(1, 12.0, c, k, &[], 0.0), None);
        // A negative radius of rotation ends at |R| too.
        assert!(toroid_x_edge_warning(1, 12.0, c, k, &[], -c_rot).is_some());
    }
}
