//! Vignetting factors: OpticStudio's per-field description of the beam that passes the apertures, as a
//! decentred and compressed pupil.
//!
//! OpticStudio ("Conventions and Definitions → Vignetting factors"; the `VDXN`, `VDYN`, `VCXN`, `VCYN`
//! records of a `.zmx` file) gives every defined field four numbers in normalised pupil units: the
//! decentres VDX, VDY and the compressions VCX, VCY. A ray of that field at normalised pupil coordinates
//! (Px, Py) is traced at
//!
//! ```text
//! Px' = VDX + Px (1 − VCX),   Py' = VDY + Py (1 − VCY)
//! ```
//!
//! so the unit circle of pupil coordinates covers the ellipse of rays the apertures let through (the
//! factors are what OpticStudio's "Set Vignetting" computes from the clear apertures). The mapped point is
//! then aimed like any pupil point (paraxial entrance pupil, or the stop under real ray aiming).
//!
//! Where diffcassi applies them (docs/zemax-files.md):
//! * the analyses that sample the pupil of a field — `trace`, `spot`, Python `System.rays_for_field` — for
//!   a field point equal to one of the system's defined fields; any other field point is traced with the
//!   full pupil (the factors belong to the defined fields: diffcassi does not interpolate between them);
//! * not the field's reference ray: the chief ray (distortion, real-image-height fields, `mapping`, a spot
//!   diagram's chief-ray reference) passes through the centre of the stop whatever the factors;
//! * not the renderer, the operators or the non-sequential backends: they sample the whole pupil and the
//!   system's clear apertures vignette the rays physically (the factors only approximate those apertures).
//!
//! OpticStudio's fifth factor, the vignetting angle VAN (`VANN`), rotates the vignetted pupil; a file with a
//! non-zero VAN is refused by line (not modelled).
//!
//! ```
//! use diffcassi::system::VignettingFactors;
//! let v = VignettingFactors::from_row([0.0, 0.1, 0.0, 0.2]);
//! assert_eq!(v.apply([0.0, 1.0]), [0.0, 0.1 + 0.8]);
//! assert_eq!(v.apply([0.0, -1.0]), [0.0, 0.1 - 0.8]);
//! assert!(VignettingFactors::from_row([0.0; 4]).is_none());
//! ```

/// One field's vignetting factors (normalised pupil units).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VignettingFactors {
    /// Decentre of the vignetted pupil, (VDX, VDY).
    pub decenter: [f64; 2],
    /// Compression of the vignetted pupil, (VCX, VCY): its half-widths are 1 − VC.
    pub compression: [f64; 2],
}

impl VignettingFactors {
    /// From the spec's row `[VDX, VDY, VCX, VCY]` (`SystemSpec::vignetting_factors`).
    pub fn from_row(v: [f64; 4]) -> Self {
        VignettingFactors { decenter: [v[0], v[1]], compression: [v[2], v[3]] }
    }

    /// Whether every factor is zero (the full pupil).
    pub fn is_none(&self) -> bool {
        self.decenter == [0.0, 0.0] && self.compression == [0.0, 0.0]
    }

    /// The pupil point traced for normalised pupil point `p`: (VDX + px(1 − VCX), VDY + py(1 − VCY)).
    #[inline]
    pub fn apply(&self, p: [f64; 2]) -> [f64; 2] {
        [self.decenter[0] + p[0] * (1.0 - self.compression[0]), self.decenter[1] + p[1] * (1.0 - self.compression[1])]
    }
}

impl super::SequentialSystem {
    /// The vignetting factors of the defined field equal to `field` (an object-space field point as in
    /// [`super::SequentialSystem::fields`]), `None` for a field point that is not a defined field or whose
    /// factors are all zero.
    pub fn vignetting_of(&self, field: [f64; 2]) -> Option<VignettingFactors> {
        let k = self.fields.iter().position(|f| *f == field)?;
        let v = VignettingFactors::from_row(*self.spec.vignetting_factors.get(k)?);
        (!v.is_none()).then_some(v)
    }

    /// The pupil points traced for normalised pupil points `pupil` of field point `field`: mapped by the
    /// field's vignetting factors when it is a defined field that has some ([`VignettingFactors::apply`]),
    /// unchanged otherwise.
    pub fn vignetted_pupil(&self, field: [f64; 2], pupil: &[[f64; 2]]) -> Vec<[f64; 2]> {
        match self.vignetting_of(field) {
            Some(v) => pupil.iter().map(|p| v.apply(*p)).collect(),
            None => pupil.to_vec(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::system::SequentialSystem;

    /// The double Gauss of tests/fixtures/zmx (US 583,336): its second field's factors as the file holds them.
    const DG_F2: [f64; 4] = [0.0, 6.208442661354e-2, 2.455956935883e-3, 1.556542586327e-1];

    #[test]
    fn the_mapping_is_opticstudios_and_rayoptics_agrees_at_the_pupil_edge() {
        let v = VignettingFactors::from_row(DG_F2);
        // Centre: the decentre.
        assert_eq!(v.apply([0.0, 0.0]), [0.0, DG_F2[1]]);
        // rayoptics' asymmetric form (vly = vcy + vdy, vuy = vcy − vdy; Py ≥ 0 → Py(1 − vuy), Py < 0 →
        // Py(1 − vly)) is the same map at the four edge points Py = ±1, Px = ±1 and differs inside.
        let (vly, vuy) = (DG_F2[3] + DG_F2[1], DG_F2[3] - DG_F2[1]);
        assert!((v.apply([0.0, 1.0])[1] - (1.0 - vuy)).abs() < 1e-16);
        assert!((v.apply([0.0, -1.0])[1] + (1.0 - vly)).abs() < 1e-16);
        assert!((v.apply([1.0, 0.0])[0] - (1.0 - DG_F2[2])).abs() < 1e-16);
        assert!((v.apply([0.0, 0.5])[1] - 0.5 * (1.0 - vuy)).abs() > 1e-3);
    }

    #[test]
    fn only_defined_fields_with_factors_are_vignetted() {
        let mut spec = crate::presets::spec("sp").unwrap();
        let nf = spec.field_values().len();
        assert!(nf >= 2, "{nf}");
        let mut rows = vec![[0.0; 4]; nf];
        rows[1] = DG_F2;
        spec.vignetting_factors = rows;
        let sys = SequentialSystem::build(&spec).unwrap();
        let pupil = [[0.0, 1.0], [0.3, -0.2]];
        assert_eq!(sys.vignetted_pupil(sys.fields[0], &pupil), pupil.to_vec(), "all-zero factors: the full pupil");
        let v = VignettingFactors::from_row(DG_F2);
        assert_eq!(sys.vignetted_pupil(sys.fields[1], &pupil), vec![v.apply(pupil[0]), v.apply(pupil[1])]);
        let other = [sys.fields[1][0] + 1e-9, sys.fields[1][1]];
        assert_eq!(sys.vignetted_pupil(other, &pupil), pupil.to_vec(), "a field point that is not a defined field");
    }

    #[test]
    fn bad_factors_are_refused_by_row_and_name() {
        let mut spec = crate::presets::spec("sp").unwrap();
        let nf = spec.field_values().len();
        spec.vignetting_factors = vec![[0.0; 4]; nf + 1];
        let e = spec.validate().unwrap_err();
        assert!(e.contains("vignetting_factors") && e.contains(&format!("{nf} field(s)")), "{e}");
        let mut rows = vec![[0.0; 4]; nf];
        rows[0] = [0.0, f64::NAN, 0.0, 0.0];
        spec.vignetting_factors = rows.clone();
        let e = spec.validate().unwrap_err();
        assert!(e.contains("vignetting_factors[0]") && e.contains("VDY") && e.contains("not finite"), "{e}");
        rows[0] = [0.0, 0.0, 0.0, 1.0];
        spec.vignetting_factors = rows;
        let e = spec.validate().unwrap_err();
        assert!(e.contains("VCY = 1") && e.contains("< 1"), "{e}");
    }
}
