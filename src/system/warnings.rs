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
//!   toroid's YZ curve (in y).
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

impl SequentialSystem {
    /// Every load-time warning: [`Self::glass_warnings`] then [`Self::surface_edge_warnings`]. The CLI prints
    /// them on stderr (`warning: …`), Python raises them as `UserWarning`s when a `System` is made, C++ returns
    /// them from `System::warnings()`.
    pub fn warnings(&self) -> Vec<String> {
        let mut out = self.glass_warnings();
        out.extend(self.surface_edge_warnings());
        out
    }

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
