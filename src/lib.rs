//! # diffcassi
//!
//! Coded-aperture snapshot spectral imager (CASSI) simulation by exact ray tracing through prisms and thick
//! lenses, following Zemax OpticStudio's sequential conventions.
//!
//! Data flow: **spec** ([`spec`]: Lens-Data-Editor-like tables, TOML/JSON, Zemax CSV and paper YAML import,
//! [`presets`]) → **system** ([`system`]: placed surfaces, pickups and chief-ray solves, paraxial pupil) →
//! **tracer backend** ([`tracer`]: the [`tracer::Tracer`] trait, exact f64 [`tracer::AnalyticTracer`]) →
//! **analyses** ([`analysis`]: spots, distortion grids, dispersion, mapping cube) → **outputs** ([`io`],
//! [`plot`]); renders ([`render`]) → reconstruction ([`recon`]) → the four-system [`study`]. Glass data live in [`materials`], surface figures in [`surfaces`], frames in [`geometry`].
//!
//! ```
//! use diffcassi::prelude::*;
//! let system = SequentialSystem::build(&presets::spec("sp")?)?;
//! let spot = analysis::spot_diagram(&system, &AnalyticTracer::default(), [0.0, 0.0], 520.0,
//!                                   &PupilPattern::Hexapolar { rings: 8 }.points())?;
//! assert!(spot.rms_radius_um() < 10.0);
//! # Ok::<(), diffcassi::Error>(())
//! ```
pub mod analysis;
pub mod calibration;
pub mod cancel;
pub mod cli;
pub mod design;
pub mod diff;
pub mod error;
pub mod fidelity;
pub mod frontend;
pub mod geometry;
pub mod gpu;
pub mod io;
pub mod limits;
pub mod materials;
pub mod mechanics;
pub mod optim;
pub mod plot;
pub mod pool;
pub mod presets;
pub mod rays;
pub mod recon;
pub mod render;
pub mod scene;
pub mod spec;
pub mod study;
pub mod surfaces;
pub mod system;
pub mod tracer;

pub use error::{Error, Result};

/// The names most programs need.
pub mod prelude {
    pub use crate::analysis;
    pub use crate::presets;
    pub use crate::rays::{PupilPattern, RayBatch};
    pub use crate::spec::SystemSpec;
    pub use crate::system::SequentialSystem;
    pub use crate::tracer::{AnalyticTracer, RayStatus, TracedBatch, Tracer};
}
