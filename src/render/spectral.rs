//! Spectral sampling of a render: B bands (default the paper's 28, 450–650 nm) each split into F planes
//! (default ×4 ⇒ 112). Band b covers the interval between the midpoints to its neighbours (the outer bands
//! extend symmetrically); its F planes sit at the centres of F equal sub-intervals. For evenly spaced bands
//! that is a uniform grid of B·F planes with spacing Δ/F (Δ = band spacing), and F = 1 gives the band
//! centres. The scene is interpolated linearly in λ at each plane (see [`crate::scene::SpectralCube::plane`]).
//! Each plane carries weight 1/F, so the acquisition is in band units: a band of value 1 contributes 1.
//!
//! ```
//! use diffcassi::render::SpectralSampling;
//! let s = SpectralSampling::paper();
//! assert_eq!(s.planes_nm.len(), 112);
//! assert!((s.planes_nm[1] - s.planes_nm[0] - 200.0 / 27.0 / 4.0).abs() < 1e-9);
//! assert_eq!(s.plane_band[5], 1);
//! ```
use crate::error::{Error, Result};

#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct SpectralSampling {
    pub bands_nm: Vec<f64>,
    /// Planes per band (K / B, rounded down when K is not a multiple of B).
    pub oversampling: usize,
    pub planes_nm: Vec<f64>,
    /// Band of each plane.
    pub plane_band: Vec<usize>,
    /// Weight of each plane in the sum (B/K = 1/F).
    pub plane_weight: f64,
}

impl SpectralSampling {
    /// The paper's choice: 28 bands 450–650 nm, ×4.
    pub fn paper() -> Self {
        Self::new(crate::analysis::linspace(450.0, 650.0, 28), 4).expect("valid")
    }

    /// `oversampling` planes per band.
    pub fn new(bands_nm: Vec<f64>, oversampling: usize) -> Result<Self> {
        let k = bands_nm.len() * oversampling;
        Self::with_planes(bands_nm, k)
    }

    /// `planes` planes over the bands' range. Planes sit at the centres of `planes` equal parts of
    /// [lower edge of the first band, upper edge of the last]; each belongs to the band whose interval
    /// holds it and weighs B/K (exact band units for evenly spaced bands). With K = B·F this is F planes per
    /// band, as [`SpectralSampling::new`].
    pub fn with_planes(bands_nm: Vec<f64>, planes: usize) -> Result<Self> {
        if bands_nm.is_empty() || planes == 0 {
            return Err(Error::invalid(format!("spectral sampling needs ≥ 1 band and ≥ 1 plane (got {} bands, {planes} planes)", bands_nm.len())));
        }
        if planes > crate::limits::MAX_PLANES {
            // Before the planes' allocation (2³⁰ planes from C++ allocated 8.6 GB before the refusal).
            return Err(Error::invalid(format!("{planes} spectral planes: at most {}", crate::limits::MAX_PLANES)));
        }
        for (k, w) in bands_nm.iter().enumerate() {
            if !(w.is_finite() && *w > 0.0) || (k > 0 && !(*w > bands_nm[k - 1])) {
                return Err(Error::invalid(format!("band wavelengths must be finite, > 0 and increasing: band {k} = {w} nm")));
            }
        }
        let b = bands_nm.len();
        if b == 1 {
            if planes > 1 {
                return Err(Error::invalid("a single band has no width to split into several planes: use 1 plane"));
            }
            return Ok(SpectralSampling { oversampling: 1, planes_nm: bands_nm.clone(), plane_band: vec![0], plane_weight: 1.0, bands_nm });
        }
        // Band k covers [edge k, edge k+1]: midpoints between neighbours, outer edges symmetric.
        let mut edges = Vec::with_capacity(b + 1);
        edges.push(bands_nm[0] - 0.5 * (bands_nm[1] - bands_nm[0]));
        for k in 0..b - 1 {
            edges.push(0.5 * (bands_nm[k] + bands_nm[k + 1]));
        }
        edges.push(bands_nm[b - 1] + 0.5 * (bands_nm[b - 1] - bands_nm[b - 2]));
        let (lo, hi) = (edges[0], edges[b]);
        let planes_nm: Vec<f64> = (0..planes).map(|j| lo + (hi - lo) * (j as f64 + 0.5) / planes as f64).collect();
        let plane_band = planes_nm.iter().map(|&w| (edges.partition_point(|&e| e <= w).max(1) - 1).min(b - 1)).collect();
        Ok(SpectralSampling { oversampling: planes / b, planes_nm, plane_band, plane_weight: b as f64 / planes as f64, bands_nm })
    }

    pub fn planes(&self) -> usize {
        self.planes_nm.len()
    }
}
