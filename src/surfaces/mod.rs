//! Optical surface shapes in their local frame: exact f64 sag, normal and ray intersection, and apertures;
//! the Toroidal figure (`toroidal`) and the diffraction grating's vector grating equation (`grating`).
//!
//! The vertex is at the local origin, the optical axis is +z, and a surface is the set z = sag(x, y).
//! Intersections follow the convention of a sequential tracer: the ray is a full line (negative distances
//! are allowed, as in Zemax's virtual propagation), and the root taken is the one on the vertex branch.
//!
//! ```
//! use diffcassi::surfaces::{SurfaceShape, intersect};
//! use glam::DVec3;
//! let sphere = SurfaceShape::Conic { curvature: 1.0 / 50.0, conic: 0.0 };
//! let hit = intersect(&sphere, DVec3::new(1.0, 0.0, -5.0), DVec3::Z).unwrap();
//! assert!((hit.point.z - sphere.sag(1.0, 0.0)).abs() < 1e-15);
//! ```
mod aperture;
pub mod grating;
mod intersect;
mod patch;
mod shape;
mod tessellate;
pub mod toroidal;
pub use aperture::*;
pub use intersect::*;
pub use patch::*;
pub use shape::*;
pub use tessellate::*;
