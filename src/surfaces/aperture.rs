/// A surface aperture in the surface's local (x, y), mm. Rays landing outside are vignetted.
///
/// Zemax semi-diameters alone do not clip rays; only an explicit aperture does (the "(aper)" mark in the
/// Lens Data Editor). diffcassi follows that rule: `Aperture::None` passes every ray.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum Aperture {
    None,
    /// Clear semi-diameter (and optional central obscuration radius), centred on the vertex unless decentred.
    Circular {
        semi_diameter_mm: f64,
        #[serde(default)]
        min_radius_mm: f64,
        #[serde(default)]
        decenter_x_mm: f64,
        #[serde(default)]
        decenter_y_mm: f64,
    },
    /// |x − dx| ≤ half_width_x and |y − dy| ≤ half_width_y.
    Rectangular {
        half_width_x_mm: f64,
        half_width_y_mm: f64,
        #[serde(default)]
        decenter_x_mm: f64,
        #[serde(default)]
        decenter_y_mm: f64,
    },
    /// A central obscuration (OpticStudio's "Circular Obscuration" aperture type, `.zmx` `OBSC rmin rmax` with
    /// `OBDC dx dy`; OpticStudio User Manual, "Aperture" under the Surface Properties of the Lens Data Editor):
    /// rays landing in the annulus min_radius ≤ r ≤ max_radius about (dx, dy) are vignetted, all others pass
    /// (the inverse of [`Aperture::Circular`]). `min_radius_mm` = 0 is a disc (a secondary mirror's shadow).
    CircularObscuration {
        #[serde(default)]
        min_radius_mm: f64,
        max_radius_mm: f64,
        #[serde(default)]
        decenter_x_mm: f64,
        #[serde(default)]
        decenter_y_mm: f64,
    },
}

impl Default for Aperture {
    fn default() -> Self {
        Aperture::None
    }
}

impl Aperture {
    pub fn circular(semi_diameter_mm: f64) -> Self {
        Aperture::Circular { semi_diameter_mm, min_radius_mm: 0.0, decenter_x_mm: 0.0, decenter_y_mm: 0.0 }
    }
    /// Whether the local point (x, y) passes. Points exactly on the edge pass (closed set), as in Zemax.
    #[inline]
    pub fn contains(&self, x: f64, y: f64) -> bool {
        match *self {
            Aperture::None => true,
            Aperture::Circular { semi_diameter_mm, min_radius_mm, decenter_x_mm, decenter_y_mm } => {
                let (u, v) = (x - decenter_x_mm, y - decenter_y_mm);
                let r2 = u * u + v * v;
                r2 <= semi_diameter_mm * semi_diameter_mm && r2 >= min_radius_mm * min_radius_mm
            }
            Aperture::Rectangular { half_width_x_mm, half_width_y_mm, decenter_x_mm, decenter_y_mm } => {
                (x - decenter_x_mm).abs() <= half_width_x_mm && (y - decenter_y_mm).abs() <= half_width_y_mm
            }
            Aperture::CircularObscuration { min_radius_mm, max_radius_mm, decenter_x_mm, decenter_y_mm } => {
                // The blocked annulus is closed (its edges block), so the clear region is open; a NaN point
                // is outside every aperture, as for the clear apertures above.
                let (u, v) = (x - decenter_x_mm, y - decenter_y_mm);
                let r2 = u * u + v * v;
                r2 < min_radius_mm * min_radius_mm || r2 > max_radius_mm * max_radius_mm
            }
        }
    }
    /// Whether this aperture bounds the surface (a clear aperture: circular or rectangular). `None` and a
    /// circular obscuration pass rays arbitrarily far from the vertex.
    pub fn is_bounded(&self) -> bool {
        matches!(self, Aperture::Circular { .. } | Aperture::Rectangular { .. })
    }
    /// Checks sizes are finite and non-negative; the message names the bad field.
    pub fn validate(&self) -> Result<(), String> {
        let check = |name: &str, v: f64, positive: bool| -> Result<(), String> {
            if !v.is_finite() {
                return Err(format!("aperture {name} = {v} is not finite"));
            }
            if positive && v <= 0.0 {
                return Err(format!("aperture {name} = {v} must be > 0"));
            }
            Ok(())
        };
        match *self {
            Aperture::None => Ok(()),
            Aperture::Circular { semi_diameter_mm, min_radius_mm, decenter_x_mm, decenter_y_mm } => {
                check("semi_diameter_mm", semi_diameter_mm, true)?;
                check("min_radius_mm", min_radius_mm, false)?;
                if min_radius_mm < 0.0 || min_radius_mm >= semi_diameter_mm {
                    return Err(format!("aperture min_radius_mm = {min_radius_mm} must be in [0, semi_diameter_mm)"));
                }
                check("decenter_x_mm", decenter_x_mm, false)?;
                check("decenter_y_mm", decenter_y_mm, false)
            }
            Aperture::Rectangular { half_width_x_mm, half_width_y_mm, decenter_x_mm, decenter_y_mm } => {
                check("half_width_x_mm", half_width_x_mm, true)?;
                check("half_width_y_mm", half_width_y_mm, true)?;
                check("decenter_x_mm", decenter_x_mm, false)?;
                check("decenter_y_mm", decenter_y_mm, false)
            }
            Aperture::CircularObscuration { min_radius_mm, max_radius_mm, decenter_x_mm, decenter_y_mm } => {
                check("min_radius_mm", min_radius_mm, false)?;
                check("max_radius_mm", max_radius_mm, true)?;
                if min_radius_mm < 0.0 || min_radius_mm > max_radius_mm {
                    return Err(format!("obscuration min_radius_mm = {min_radius_mm} must be in [0, max_radius_mm = {max_radius_mm}]"));
                }
                check("decenter_x_mm", decenter_x_mm, false)?;
                check("decenter_y_mm", decenter_y_mm, false)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    #[test]
    fn edges_pass_outside_fails() {
        let c = Aperture::circular(2.0);
        assert!(c.contains(2.0, 0.0));
        assert!(!c.contains(2.0 + 1e-12, 0.0));
        let r = Aperture::Rectangular { half_width_x_mm: 1.0, half_width_y_mm: 2.0, decenter_x_mm: 0.5, decenter_y_mm: 0.0 };
        assert!(r.contains(1.5, 2.0));
        assert!(!r.contains(-0.6, 0.0));
        assert!(Aperture::circular(-1.0).validate().is_err());
    }
    #[test]
    fn obscuration_blocks_its_annulus_and_passes_the_rest() {
        let o = Aperture::CircularObscuration { min_radius_mm: 0.0, max_radius_mm: 25.0, decenter_x_mm: 1.0, decenter_y_mm: 0.0 };
        assert!(!o.contains(1.0, 0.0) && !o.contains(26.0, 0.0) && !o.contains(1.0, 25.0));
        assert!(o.contains(26.0 + 1e-12, 0.0) && o.contains(-30.0, 40.0) && !o.contains(f64::NAN, 0.0));
        let ring = Aperture::CircularObscuration { min_radius_mm: 5.0, max_radius_mm: 10.0, decenter_x_mm: 0.0, decenter_y_mm: 0.0 };
        assert!(ring.contains(4.9, 0.0) && !ring.contains(5.0, 0.0) && !ring.contains(0.0, -7.0) && ring.contains(0.0, 10.1));
        assert!(ring.validate().is_ok() && !ring.is_bounded());
        for (lo, hi) in [(-1.0, 5.0), (6.0, 5.0), (f64::NAN, 5.0), (0.0, f64::NAN), (0.0, 0.0), (0.0, f64::INFINITY)] {
            let bad = Aperture::CircularObscuration { min_radius_mm: lo, max_radius_mm: hi, decenter_x_mm: 0.0, decenter_y_mm: 0.0 };
            assert!(bad.validate().is_err(), "{lo} {hi}");
        }
    }
}
