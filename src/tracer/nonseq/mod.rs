//! Non-sequential tracing with ray splitting: ghost images from Fresnel reflections.
//!
//! * [`solids`]: a sequential system as solids (interfaces, walls, blades, obscurations, detector), shared
//!   with the Embree scene; [`launch`]: where the rays of an object at infinity start;
//! * [`fresnel`]: exact Fresnel amplitudes and 3-D polarisation ray tracing; [`coating`]: per-surface
//!   coatings (given reflectance, quarter-wave MgF₂);
//! * [`next_hit`]: the [`NextHit`] kernel interface; [`brute`]: its brute-force f64 implementation
//!   (the Embree one is `crate::tracer::embree::EmbreeNextHit`);
//! * [`tree`]: ray trees up to a ghost order with Russian roulette and a per-tree energy ledger.
//!
//! See docs/ghosts.md for the physics, the estimator and the ghosts of the presets.
//!
//! ```
//! use diffcassi::prelude::*;
//! use diffcassi::tracer::nonseq::{BruteForce, FresnelModel, SolidsOptions, TreeOptions, trace_trees};
//! let sys = SequentialSystem::build(&presets::spec("ap")?)?;
//! let brute = BruteForce::new(&sys, &SolidsOptions::default())?;
//! let rays = RayBatch::chief_rays(&sys, &[[0.0, 0.0]], 520.0)?;
//! let off = TreeOptions { order: 0, model: FresnelModel::Off, ..Default::default() };
//! let t = &trace_trees(&brute, &sys, &rays, &off)?[0];
//! assert_eq!(t.arrivals.len(), 1);
//! assert_eq!(t.arrivals[0].power, 1.0);
//! # Ok::<(), diffcassi::Error>(())
//! ```
pub mod brute;
pub mod coating;
pub mod design_beam;
pub mod fresnel;
pub mod launch;
pub mod next_hit;
pub mod solids;
pub mod tree;

pub use brute::BruteForce;
pub use fresnel::FresnelModel;
pub use launch::StartPlane;
pub use next_hit::{Event, ExtraGeometry, ExtraHit, NextHit, Query};
pub use solids::{Role, Solid, Solids, SolidsOptions};
pub use tree::{path_label, trace_trees, walk_tree, Arrival, Ledger, RayTree, TreeOptions, MAX_GHOST_ORDER};
