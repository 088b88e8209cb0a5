//! Analyses of a traced system: spot diagrams, grid distortion, spatio-spectral dispersion, the mapping
//! cube. Each computes only what it reports: chief rays only where chief rays suffice, no per-ray storage
//! when only statistics are asked for.
//!
//! ```
//! use diffcassi::prelude::*;
//! let sys = SequentialSystem::build(&presets::spec("ap")?)?;
//! let grid = analysis::grid_distortion(&sys, &AnalyticTracer::default(), 520.0, 5, 2.5)?;
//! assert_eq!(grid.points.len(), 25);
//! # Ok::<(), diffcassi::Error>(())
//! ```
mod dispersion;
mod distortion;
mod mapping;
mod semi_diameter;
mod spot;

pub use dispersion::*;
pub use distortion::*;
pub use mapping::*;
pub use semi_diameter::*;
pub use spot::*;

use crate::error::{Error, Result};
use crate::rays::{aimed_ray, RayBatch};
use crate::system::SequentialSystem;

/// Rays of one field through normalised pupil points at one wavelength, honouring the system's ray aiming.
pub fn field_rays(system: &SequentialSystem, field_mm: [f64; 2], pupil: &[[f64; 2]], wavelength_nm: f64) -> Result<RayBatch> {
    let n = system.indices(wavelength_nm)?;
    let mut batch = RayBatch::with_capacity(pupil.len());
    for &[px, py] in pupil {
        if !(px.is_finite() && py.is_finite()) {
            return Err(Error::invalid(format!("pupil coordinate ({px}, {py}) is not finite")));
        }
        let (o, d) = aimed_ray(system, &n, field_mm, px, py)?;
        batch.push(o, d, wavelength_nm);
    }
    Ok(batch)
}

/// Chief rays of many field points at one wavelength, honouring the system's ray aiming.
pub fn chief_rays(system: &SequentialSystem, fields_mm: &[[f64; 2]], wavelength_nm: f64) -> Result<RayBatch> {
    let n = system.indices(wavelength_nm)?;
    let mut batch = RayBatch::with_capacity(fields_mm.len());
    for &f in fields_mm {
        if !(f[0].is_finite() && f[1].is_finite()) {
            return Err(Error::invalid(format!("field point ({}, {}) mm is not finite", f[0], f[1])));
        }
        let (o, d) = aimed_ray(system, &n, f, 0.0, 0.0)?;
        batch.push(o, d, wavelength_nm);
    }
    Ok(batch)
}
