//! The medium after a surface: system air or a catalogue glass.
//!
//! System air is the reference of all catalogue (relative) indices, so — as in Zemax at
//! the catalogue reference temperature and pressure — [`Medium::Air`] has index exactly
//! `1.0` at every wavelength.
//!
//! [`WavelengthPolicy`] decides what happens outside a glass's catalogue `LD` range:
//! [`Strict`](WavelengthPolicy::Strict) (default) is an error,
//! [`AllowExtrapolation`](WavelengthPolicy::AllowExtrapolation) evaluates the formula anyway.
//!
//! # Example
//!
//! ```
//! use diffcassi::materials::{GlassCatalog, Medium, WavelengthPolicy};
//!
//! let sf10 = Medium::Glass(GlassCatalog::builtin().get("SF10")?);
//! assert_eq!(sf10.name(), "SF10");
//! let n = sf10.refractive_index(520.0, WavelengthPolicy::Strict)?;
//! assert!(n > 1.7);
//! assert!(sf10.refractive_index(350.0, WavelengthPolicy::Strict).is_err()); // LD starts at 380 nm
//! assert!(sf10.refractive_index(350.0, WavelengthPolicy::AllowExtrapolation).is_ok());
//! assert_eq!(Medium::Air.refractive_index(350.0, WavelengthPolicy::Strict)?, 1.0);
//! # Ok::<(), diffcassi::materials::MaterialError>(())
//! ```

use std::fmt;
use std::sync::Arc;

use serde::{Deserialize, Serialize};

use super::glass::Glass;
use super::MaterialError;

/// What to do with a wavelength outside a glass's catalogue range.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum WavelengthPolicy {
    /// Outside the `LD` range is [`MaterialError::WavelengthOutOfRange`] (Zemax default).
    /// (Also read as `strict`: specs spell their other keys in snake case.)
    #[default]
    #[serde(alias = "strict")]
    Strict,
    /// Evaluate the dispersion formula outside the `LD` range (explicit opt-in). Also read as
    /// `allow_extrapolation` (the spelling docs/accuracy.md and the `.zmx` `DCWP` record use).
    #[serde(alias = "allow_extrapolation")]
    AllowExtrapolation,
}

/// A propagation medium.
#[derive(Clone, Debug, PartialEq)]
pub enum Medium {
    /// System air, the index reference: n = 1 exactly.
    Air,
    /// A catalogue glass.
    Glass(Arc<Glass>),
}

impl Medium {
    /// Relative refractive index at `wavelength_nm`.
    ///
    /// # Errors
    /// [`MaterialError::NonFiniteWavelength`] for NaN/±∞ (also for air);
    /// for glasses, [`MaterialError::WavelengthOutOfRange`] under
    /// [`WavelengthPolicy::Strict`] and [`MaterialError::NonFiniteIndex`] if the formula
    /// result is invalid.
    pub fn refractive_index(
        &self,
        wavelength_nm: f64,
        policy: WavelengthPolicy,
    ) -> Result<f64, MaterialError> {
        match self {
            Medium::Air => {
                if wavelength_nm.is_finite() {
                    Ok(1.0)
                } else {
                    Err(MaterialError::NonFiniteWavelength {
                        medium: "AIR".to_string(),
                        wavelength_nm,
                    })
                }
            }
            Medium::Glass(glass) => match policy {
                WavelengthPolicy::Strict => glass.refractive_index(wavelength_nm),
                WavelengthPolicy::AllowExtrapolation => {
                    glass.refractive_index_extrapolated(wavelength_nm)
                }
            },
        }
    }

    /// `"AIR"` or the glass name.
    pub fn name(&self) -> &str {
        match self {
            Medium::Air => "AIR",
            Medium::Glass(glass) => &glass.name,
        }
    }

    /// `true` for [`Medium::Air`].
    pub fn is_air(&self) -> bool {
        matches!(self, Medium::Air)
    }

    /// The glass, if any.
    pub fn glass(&self) -> Option<&Arc<Glass>> {
        match self {
            Medium::Air => None,
            Medium::Glass(glass) => Some(glass),
        }
    }
}

impl fmt::Display for Medium {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl From<Arc<Glass>> for Medium {
    fn from(glass: Arc<Glass>) -> Self {
        Medium::Glass(glass)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::materials::GlassCatalog;

    #[test]
    fn air_is_exactly_one() {
        for w in [200.0, 587.5618, 10_000.0] {
            for p in [
                WavelengthPolicy::Strict,
                WavelengthPolicy::AllowExtrapolation,
            ] {
                assert_eq!(Medium::Air.refractive_index(w, p).unwrap(), 1.0);
            }
        }
        assert!(Medium::Air
            .refractive_index(f64::NAN, WavelengthPolicy::Strict)
            .is_err());
        assert_eq!(Medium::Air.name(), "AIR");
        assert!(Medium::Air.is_air());
        assert!(Medium::Air.glass().is_none());
    }

    #[test]
    fn glass_policy() {
        let g = GlassCatalog::builtin().get("N-BK7").unwrap();
        let m = Medium::from(g.clone());
        assert_eq!(m.to_string(), "N-BK7");
        assert_eq!(
            m.refractive_index(550.0, WavelengthPolicy::Strict).unwrap(),
            g.refractive_index(550.0).unwrap()
        );
        let e = m
            .refractive_index(5000.0, WavelengthPolicy::Strict)
            .unwrap_err();
        assert!(matches!(e, MaterialError::WavelengthOutOfRange { .. }));
        assert_eq!(
            m.refractive_index(5000.0, WavelengthPolicy::AllowExtrapolation)
                .unwrap(),
            g.refractive_index_unchecked(5000.0)
        );
        assert!(m
            .refractive_index(f64::NAN, WavelengthPolicy::AllowExtrapolation)
            .is_err());
    }

    #[test]
    fn policy_default_and_serde() {
        assert_eq!(WavelengthPolicy::default(), WavelengthPolicy::Strict);
        let s = serde_json::to_string(&WavelengthPolicy::AllowExtrapolation).unwrap();
        assert_eq!(s, "\"AllowExtrapolation\"");
        let p: WavelengthPolicy = serde_json::from_str(&s).unwrap();
        assert_eq!(p, WavelengthPolicy::AllowExtrapolation);
    }
}
