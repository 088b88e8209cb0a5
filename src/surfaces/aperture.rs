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
        }
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
}
