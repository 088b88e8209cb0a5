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
pub mod ghosts;
mod mapping;
mod mapping_interp;
mod semi_diameter;
mod spot;

pub use dispersion::*;
pub use distortion::*;
pub use mapping::*;
pub use mapping_interp::mapping_cube_interpolated;
pub(crate) use mapping_interp::NodeGrid;
pub use semi_diameter::*;
pub use spot::*;

