//! Borrowed struct-of-arrays rays: trace caller-owned columns without copying them into a [`RayBatch`]
//! (the C++ API passes its `std::vector`s/spans through here).
//!
//! ```
//! use diffcassi::{presets, rays::RayBatch, system::SequentialSystem, tracer::{AnalyticTracer, RaySlices, Tracer}};
//! let sys = SequentialSystem::build(&presets::spec("sp")?)?;
//! let owned = RayBatch::chief_rays(&sys, &[[0.0, 0.0], [1.0, 2.0]], 520.0)?;
//! // The same columns, borrowed (e.g. from another language's buffers): the results are identical.
//! let view = RaySlices::new(&owned.origin_x, &owned.origin_y, &owned.origin_z,
//!                           &owned.dir_x, &owned.dir_y, &owned.dir_z, &owned.wavelength_nm)?;
//! let tracer = AnalyticTracer::default();
//! assert_eq!(tracer.trace_slices(&sys, view)?, tracer.trace(&sys, &owned)?);
//! # Ok::<(), diffcassi::Error>(())
//! ```
use crate::error::{Error, Result};
use crate::rays::RayBatch;
use glam::DVec3;

/// Rays in object space as borrowed columns (mm, direction not necessarily unit, nm), in the object
/// surface's frame: the borrowed twin of [`RayBatch`]. All columns have the same length (checked by
/// [`RaySlices::new`]).
#[derive(Clone, Copy, Debug)]
pub struct RaySlices<'a> {
    pub(crate) origin_x: &'a [f64],
    pub(crate) origin_y: &'a [f64],
    pub(crate) origin_z: &'a [f64],
    pub(crate) dir_x: &'a [f64],
    pub(crate) dir_y: &'a [f64],
    pub(crate) dir_z: &'a [f64],
    pub(crate) wavelength_nm: &'a [f64],
}

impl<'a> RaySlices<'a> {
    /// Borrow seven equally long columns; an error names the lengths when they differ.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        origin_x: &'a [f64],
        origin_y: &'a [f64],
        origin_z: &'a [f64],
        dir_x: &'a [f64],
        dir_y: &'a [f64],
        dir_z: &'a [f64],
        wavelength_nm: &'a [f64],
    ) -> Result<Self> {
        let lens = [origin_x.len(), origin_y.len(), origin_z.len(), dir_x.len(), dir_y.len(), dir_z.len(), wavelength_nm.len()];
        if lens.iter().any(|&l| l != lens[0]) {
            return Err(Error::invalid(format!(
                "ray batch columns have different lengths (origin_x {}, origin_y {}, origin_z {}, dir_x {}, dir_y {}, dir_z {}, wavelength_nm {})",
                lens[0], lens[1], lens[2], lens[3], lens[4], lens[5], lens[6]
            )));
        }
        Ok(RaySlices { origin_x, origin_y, origin_z, dir_x, dir_y, dir_z, wavelength_nm })
    }
    pub fn len(&self) -> usize {
        self.origin_x.len()
    }
    pub fn is_empty(&self) -> bool {
        self.origin_x.is_empty()
    }
    pub fn origin(&self, i: usize) -> DVec3 {
        DVec3::new(self.origin_x[i], self.origin_y[i], self.origin_z[i])
    }
    pub fn direction(&self, i: usize) -> DVec3 {
        DVec3::new(self.dir_x[i], self.dir_y[i], self.dir_z[i])
    }
    pub fn wavelength_nm(&self) -> &'a [f64] {
        self.wavelength_nm
    }
    /// An owned copy (for backends that need one).
    pub fn to_batch(&self) -> RayBatch {
        RayBatch {
            origin_x: self.origin_x.to_vec(),
            origin_y: self.origin_y.to_vec(),
            origin_z: self.origin_z.to_vec(),
            dir_x: self.dir_x.to_vec(),
            dir_y: self.dir_y.to_vec(),
            dir_z: self.dir_z.to_vec(),
            wavelength_nm: self.wavelength_nm.to_vec(),
        }
    }
}

impl RayBatch {
    /// The batch's columns, borrowed; an error when they have different lengths.
    pub fn as_slices(&self) -> Result<RaySlices<'_>> {
        RaySlices::new(&self.origin_x, &self.origin_y, &self.origin_z, &self.dir_x, &self.dir_y, &self.dir_z, &self.wavelength_nm)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    #[test]
    fn lengths_are_checked_and_named() {
        let a = [0.0; 3];
        let b = [0.0; 2];
        let e = RaySlices::new(&a, &a, &a, &a, &b, &a, &a).unwrap_err().to_string();
        assert!(e.contains("dir_y 2") && e.contains("origin_x 3"), "{e}");
        let ok = RaySlices::new(&a, &a, &a, &a, &a, &a, &a).unwrap();
        assert_eq!(ok.len(), 3);
        assert_eq!(ok.to_batch().as_slices().unwrap().len(), 3);
    }
}
