//! Rigid frames and Zemax tilt conventions.
//!
//! Every surface of a sequential system owns a [`Frame`]: its vertex (origin) and its local axes, both in
//! global coordinates. Coordinate Breaks compose frames exactly as Zemax OpticStudio does
//! ([`coordinate_break_frame`]).
//!
//! ```
//! use diffcassi::geometry::{Frame, rotation_xyz};
//! use glam::DVec3;
//! let f = Frame::new(DVec3::new(0.0, 0.0, 10.0), rotation_xyz(0.0, 30f64.to_radians(), 0.0));
//! let p = f.point_to_local(f.point_to_global(DVec3::X));
//! assert!((p - DVec3::X).length() < 1e-12);
//! ```
mod frame;
pub use frame::*;
