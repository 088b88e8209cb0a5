use super::aimed_ray;
use crate::error::{Error, Result};
use crate::system::SequentialSystem;
use glam::DVec3;

/// Rays in object space, struct-of-arrays (mm, unit directions, nm), in the object surface's frame.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RayBatch {
    pub origin_x: Vec<f64>,
    pub origin_y: Vec<f64>,
    pub origin_z: Vec<f64>,
    pub dir_x: Vec<f64>,
    pub dir_y: Vec<f64>,
    pub dir_z: Vec<f64>,
    pub wavelength_nm: Vec<f64>,
}

impl RayBatch {
    pub fn with_capacity(n: usize) -> Self {
        RayBatch {
            origin_x: Vec::with_capacity(n),
            origin_y: Vec::with_capacity(n),
            origin_z: Vec::with_capacity(n),
            dir_x: Vec::with_capacity(n),
            dir_y: Vec::with_capacity(n),
            dir_z: Vec::with_capacity(n),
            wavelength_nm: Vec::with_capacity(n),
        }
    }

    /// [`RayBatch::with_capacity`] that reports an allocation the system refuses as an error rather than
    /// aborting the process (`what` names the request). The memory budget is checked before, but a budget set
    /// near the address space (round 21: `set_limits(1e300)` then 2⁴⁰ seeded rays from C++) passed that check
    /// and the allocator's failure aborted the caller's program (SIGABRT) instead of returning the error the
    /// API promises.
    pub fn try_with_capacity(n: usize, what: &str) -> Result<Self> {
        fn column(n: usize, what: &str) -> Result<Vec<f64>> {
            let mut v = Vec::new();
            v.try_reserve_exact(n).map_err(|e| {
                Error::invalid(format!("{what}: cannot allocate {} rays ({} per column): {e}", n, crate::limits::fmt_gb(n as f64 * 8.0)))
            })?;
            Ok(v)
        }
        Ok(RayBatch {
            origin_x: column(n, what)?,
            origin_y: column(n, what)?,
            origin_z: column(n, what)?,
            dir_x: column(n, what)?,
            dir_y: column(n, what)?,
            dir_z: column(n, what)?,
            wavelength_nm: column(n, what)?,
        })
    }
    pub fn len(&self) -> usize {
        self.origin_x.len()
    }
    pub fn is_empty(&self) -> bool {
        self.origin_x.is_empty()
    }
    pub fn push(&mut self, origin: DVec3, direction: DVec3, wavelength_nm: f64) {
        self.origin_x.push(origin.x);
        self.origin_y.push(origin.y);
        self.origin_z.push(origin.z);
        self.dir_x.push(direction.x);
        self.dir_y.push(direction.y);
        self.dir_z.push(direction.z);
        self.wavelength_nm.push(wavelength_nm);
    }
    pub fn origin(&self, i: usize) -> DVec3 {
        DVec3::new(self.origin_x[i], self.origin_y[i], self.origin_z[i])
    }
    pub fn direction(&self, i: usize) -> DVec3 {
        DVec3::new(self.dir_x[i], self.dir_y[i], self.dir_z[i])
    }
    /// Append another batch.
    pub fn extend(&mut self, other: &RayBatch) {
        self.origin_x.extend_from_slice(&other.origin_x);
        self.origin_y.extend_from_slice(&other.origin_y);
        self.origin_z.extend_from_slice(&other.origin_z);
        self.dir_x.extend_from_slice(&other.dir_x);
        self.dir_y.extend_from_slice(&other.dir_y);
        self.dir_z.extend_from_slice(&other.dir_z);
        self.wavelength_nm.extend_from_slice(&other.wavelength_nm);
    }
    /// All columns have the same length.
    pub fn is_consistent(&self) -> bool {
        let n = self.len();
        [self.origin_y.len(), self.origin_z.len(), self.dir_x.len(), self.dir_y.len(), self.dir_z.len(), self.wavelength_nm.len()]
            .iter()
            .all(|&l| l == n)
    }

    /// Rays of one field point (object height, mm) through normalised pupil points at one wavelength,
    /// aimed as the system says ([`crate::spec::RayAiming`]). Errors: a non-finite input, a wavelength
    /// outside a glass's range, or a ray that cannot be aimed.
    pub fn for_field(system: &SequentialSystem, field_mm: [f64; 2], pupil: &[[f64; 2]], wavelength_nm: f64) -> Result<Self> {
        check_field(field_mm)?;
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

    /// Chief rays of many field points at one wavelength, aimed as the system says.
    pub fn chief_rays(system: &SequentialSystem, fields_mm: &[[f64; 2]], wavelength_nm: f64) -> Result<Self> {
        let n = system.indices(wavelength_nm)?;
        let mut batch = RayBatch::with_capacity(fields_mm.len());
        for &f in fields_mm {
            check_field(f)?;
            let (o, d) = aimed_ray(system, &n, f, 0.0, 0.0)?;
            batch.push(o, d, wavelength_nm);
        }
        Ok(batch)
    }

    /// A reproducible benchmark workload: `rays_per_wavelength` rays per wavelength, cycling over the
    /// system's fields (the axis if it has none), pupil points uniform in the disk from a ChaCha8 stream
    /// seeded with `seed + wavelength index`, aimed as the system says.
    pub fn seeded_workload(system: &SequentialSystem, rays_per_wavelength: usize, wavelengths_nm: &[f64], seed: u64) -> Result<Self> {
        // 7 f64 columns per ray, within the memory budget (8 G rays from C++ aborted on allocation), plus one
        // wavelength's pupil points (2 f64 per ray).
        let what = format!("seeded workload of {rays_per_wavelength} rays × {} wavelengths", wavelengths_nm.len());
        crate::limits::check_memory(&what, rays_per_wavelength as f64 * (wavelengths_nm.len() as f64 * 56.0 + 16.0))?;
        let fields = system.fields_or_axis();
        let total = rays_per_wavelength.checked_mul(wavelengths_nm.len()).ok_or_else(|| Error::invalid(format!("{what}: too many rays")))?;
        let mut batch = RayBatch::try_with_capacity(total, &what)?;
        for (k, &w) in wavelengths_nm.iter().enumerate() {
            let n = system.indices(w)?;
            let pupil = super::PupilPattern::Random { n: rays_per_wavelength, seed: seed + k as u64 }.points();
            for (i, p) in pupil.iter().enumerate() {
                let (o, d) = aimed_ray(system, &n, fields[i % fields.len()], p[0], p[1])?;
                batch.push(o, d, w);
            }
        }
        Ok(batch)
    }

}

fn check_field(field_mm: [f64; 2]) -> Result<()> {
    if field_mm[0].is_finite() && field_mm[1].is_finite() {
        Ok(())
    } else {
        Err(Error::invalid(format!("field point ({}, {}) mm is not finite", field_mm[0], field_mm[1])))
    }
}

#[cfg(test)]
mod try_capacity_tests {
    use super::RayBatch;

    /// An allocation the system refuses is an error naming the request, not an abort (round 21); a usual
    /// size gives an empty batch with the room asked for.
    #[test]
    fn refused_allocation_is_an_error() {
        let e = RayBatch::try_with_capacity(usize::MAX / 4, "seeded workload of 2⁶² rays").unwrap_err().to_string();
        assert!(e.contains("seeded workload of 2⁶² rays: cannot allocate"), "{e}");
        let b = RayBatch::try_with_capacity(100, "x").unwrap();
        assert!(b.is_empty() && b.origin_x.capacity() >= 100 && b.wavelength_nm.capacity() >= 100);
    }
}
