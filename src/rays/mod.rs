//! Rays: struct-of-arrays batches, object-space ray aiming from Zemax normalised pupil coordinates, and
//! pupil sampling patterns (chief, marginal, hexapolar, square grid, seeded random).
//!
//! ```
//! use diffcassi::{presets, rays::{PupilPattern, RayBatch}, system::SequentialSystem};
//! let sys = SequentialSystem::build(&presets::spec("sp").unwrap()).unwrap();
//! let pupil = PupilPattern::Hexapolar { rings: 6 }.points();
//! let batch = RayBatch::for_field(&sys, [0.0, 2.5], &pupil, 520.0).unwrap();
//! assert_eq!(batch.len(), pupil.len());
//! ```
mod aim;
mod batch;
mod pupil;
pub use aim::*;
pub use batch::*;
pub use pupil::*;
