//! The ray sets the trade-off is measured on: fixed and seeded, so every run traces the same rays.
//!
//! * [`RaySetSpec::tradeoff`]: the issue's set — an N×N grid-distortion set of chief rays over the object
//!   field (13×13 over ±2.5 mm for the presets) plus full-pupil spots (uniform random pupil points from a
//!   seeded ChaCha8 stream) of the system's fields, at every wavelength (28 from 450 to 650 nm).
//! * [`RaySetSpec::calibration`]: the small set `--tolerance-um` measures candidates on: a 5×5 field grid
//!   plus the system's fields, a hexapolar pupil of 3 rings (37 rays), at the job's own wavelengths;
//!   [`RaySetSpec::covering`] widens it to a job's own field (a render's scene, a mapping's cube) where that
//!   reaches beyond the system's fields: f32's error grows with the field, and a lens file with only an axial
//!   field was calibrated on the axis alone.
//! * [`RaySetSpec::fresh`]: an independent check set (random fields inside the field extent, random pupil
//!   points, another seed), for verifying a selection on rays it was not calibrated on.
//!
//! ```
//! use diffcassi::prelude::*;
//! use diffcassi::fidelity::RaySetSpec;
//! let sys = SequentialSystem::build(&presets::spec("sp")?)?;
//! let set = RaySetSpec::tradeoff(13, 50, 7).build(&sys, &[450.0, 650.0])?;
//! assert_eq!(set.len(), 2 * (169 + 4 * 50));
//! # Ok::<(), diffcassi::Error>(())
//! ```
use crate::error::{Error, Result};
use crate::rays::{PupilPattern, RayBatch};
use crate::system::SequentialSystem;
use rand::{Rng, SeedableRng};

/// Which rays: a grid of chief rays, pupil samples of fields, at each wavelength.
#[derive(Clone, Debug, PartialEq)]
pub struct RaySetSpec {
    /// Chief rays on a `grid × grid` lattice over ±(field half width) in x and y (0: none).
    pub grid: usize,
    /// Pupil points traced for each field.
    pub pupil: PupilPattern,
    /// Fields: the system's own (`None`), or `Some(k)` random fields inside the field extent from `seed`.
    pub random_fields: Option<usize>,
    pub seed: u64,
    /// The job's own field half width (mm, or rad for an object at infinity: the unit of the system's
    /// fields), where it is wider than the system's fields: the grid spans it and its four corners and four
    /// edge midpoints join the pupil-sampled fields ([`RaySetSpec::covering`]; `None`: the system's fields).
    pub cover_half_width: Option<f64>,
}

impl RaySetSpec {
    /// The trade-off bench set: `grid`² chief rays plus `pupil_rays` seeded full-pupil rays per system field.
    pub fn tradeoff(grid: usize, pupil_rays: usize, seed: u64) -> Self {
        RaySetSpec { grid, pupil: PupilPattern::Random { n: pupil_rays, seed }, random_fields: None, seed, cover_half_width: None }
    }
    /// The small calibration set of `--tolerance-um`.
    pub fn calibration() -> Self {
        RaySetSpec { grid: 5, pupil: PupilPattern::Hexapolar { rings: 3 }, random_fields: None, seed: 0, cover_half_width: None }
    }
    /// A fresh check set, independent of the calibration set: `fields` random fields × `pupil_rays` random
    /// pupil points each, seeded.
    pub fn fresh(fields: usize, pupil_rays: usize, seed: u64) -> Self {
        RaySetSpec { grid: 0, pupil: PupilPattern::Random { n: pupil_rays, seed: seed ^ 0x5eed }, random_fields: Some(fields), seed, cover_half_width: None }
    }
    /// This set over a job's field of half width `half_width` (the system's unit) as well as the system's
    /// fields: a width no wider than the system's changes nothing (the set, and its calibration cache key,
    /// stay the system's).
    pub fn covering(self, system: &SequentialSystem, half_width: f64) -> Self {
        let wider = half_width.is_finite() && half_width > field_half_width_mm(system);
        RaySetSpec { cover_half_width: wider.then_some(half_width), ..self }
    }

    /// Build the rays for `system` at `wavelengths_nm`.
    pub fn build(&self, system: &SequentialSystem, wavelengths_nm: &[f64]) -> Result<RayBatch> {
        if wavelengths_nm.is_empty() {
            return Err(Error::invalid("a ray set needs at least one wavelength"));
        }
        let half = self.cover_half_width.unwrap_or(0.0).max(field_half_width_mm(system));
        let mut grid_fields = Vec::with_capacity(self.grid * self.grid);
        if self.grid > 0 && half > 0.0 {
            let step = if self.grid > 1 { 2.0 * half / (self.grid - 1) as f64 } else { 0.0 };
            for i in 0..self.grid {
                for j in 0..self.grid {
                    let (x, y) = if self.grid == 1 { (0.0, 0.0) } else { (-half + i as f64 * step, -half + j as f64 * step) };
                    grid_fields.push([x, y]);
                }
            }
        } else if self.grid > 0 {
            grid_fields.push([0.0, 0.0]);
        }
        let fields: Vec<[f64; 2]> = match self.random_fields {
            None => {
                let mut f = system.fields_or_axis();
                if let Some(h) = self.cover_half_width {
                    f.extend([[-h, -h], [h, -h], [-h, h], [h, h], [0.0, h], [0.0, -h], [h, 0.0], [-h, 0.0]]);
                }
                f
            }
            Some(k) => {
                let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(self.seed);
                (0..k).map(|_| [half * (2.0 * rng.gen::<f64>() - 1.0), half * (2.0 * rng.gen::<f64>() - 1.0)]).collect()
            }
        };
        let pupil = self.pupil.points();
        let mut batch = RayBatch::with_capacity(wavelengths_nm.len() * (grid_fields.len() + fields.len() * pupil.len()));
        for &w in wavelengths_nm {
            if !grid_fields.is_empty() {
                batch.extend(&RayBatch::chief_rays(system, &grid_fields, w)?);
            }
            for f in &fields {
                batch.extend(&RayBatch::for_field(system, *f, &pupil, w)?);
            }
        }
        Ok(batch)
    }
}

/// Half width of the square that holds a `height`×`width` scene or mapping cube of pixel pitch `pitch` (the
/// system's field unit: mm, or rad at infinity), to its outer pixel edges: the field a render or a mapping
/// calibrates over ([`RaySetSpec::covering`]).
pub fn scene_half_width(height: usize, width: usize, pitch: f64) -> f64 {
    height.max(width) as f64 * pitch / 2.0
}

/// Half width (mm, or rad for an object at infinity) of the square object field the system's fields span (largest |x| or |y|); 0 when the
/// system has no off-axis field.
pub fn field_half_width_mm(system: &SequentialSystem) -> f64 {
    system.fields.iter().map(|f| f[0].abs().max(f[1].abs())).fold(0.0, f64::max)
}
