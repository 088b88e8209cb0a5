//! Exact derivatives of traced rays with respect to system parameters, by forward-mode differentiation
//! with **implicit differentiation at hit points** (never through the intersection solver's iterations).
//!
//! - [`param`]: which numbers are free ([`Param`], [`ParamSet`]): any Lens Data Editor cell (thickness,
//!   radius/curvature, conic, asphere αᵢ, paraxial focal length, Coordinate Break decenters and tilts),
//!   glasses as continuous (n_d, V_d) ([`glass_model`]), the rays' wavelength and the input ray.
//! - [`DiffSystem`] ([`system`]): the built system plus the derivatives of its path steps, figures and
//!   indices; pickups and chief-ray solves propagate (see [`system`]).
//! - [`hit`]: the public building block [`hit::hit_tangent`] — the derivative of a hit from (hit point,
//!   direction, surface) only, so an Embree backend refining its mesh hit onto the surface gets the same
//!   derivatives.
//! - [`kernel`]: the per-ray forward trace (frame changes, hits, vector Snell, ideal lens).
//! - [`jacobian`]: [`DiffSystem::trace`] → [`JacobianBatch`] for a [`crate::rays::RayBatch`].
//! - [`adjoint`]: reverse accumulation — ∂L/∂θ for every parameter at a per-ray cost independent of their
//!   number (the differentiable acquisition, [`crate::render::gradient`]); [`adjoint_lanes`]: the same
//!   reverse sweep on the SIMD lanes of [`crate::tracer::simd`] (a block of rays at once).
//! - [`from_hits`]: [`DiffSystem::jacobian_from_hits`] — the same Jacobians at hits another backend found
//!   (the Embree tracer's refined hits: `DiffSystem::trace_embree`), with a reason for every ray whose
//!   recorded path is not the sequential one.
//!
//! ```
//! use diffcassi::diff::{Param, ParamSet};
//! use diffcassi::materials::GlassCatalog;
//! use diffcassi::rays::RayBatch;
//! let set = ParamSet::new(diffcassi::presets::spec("sp")?, GlassCatalog::builtin(), vec![Param::parse("s4.tilt_x_deg")?])?;
//! let ds = set.build()?;
//! let rays = RayBatch::chief_rays(&ds.system, &[[0.0, 0.0]], 520.0)?;
//! let j = ds.trace(&rays)?;
//! // Tilting the prism about x moves the image in y (mm per degree).
//! assert!(j.d_position(0, 0).y.abs() > 1e-3);
//! # Ok::<(), diffcassi::Error>(())
//! ```
pub mod adjoint;
pub mod adjoint_lanes;
pub mod dispersion;
pub mod dual;
pub mod from_hits;
pub mod glass_model;
pub mod hit;
pub mod jacobian;
pub mod kernel;
pub mod param;
pub mod system;

pub use from_hits::HitJacobianBatch;
pub use jacobian::JacobianBatch;
pub use param::{preset_alias, Param, ParamSet};
pub use system::DiffSystem;
