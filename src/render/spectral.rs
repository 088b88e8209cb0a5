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
        // Fewer planes than bands is a coarse render by choice (28 bands, 3 planes; the reconstruction's record
        // says which bands no pixel sees); with as many planes as bands, every band must get one.
        if planes >= b {
            check_every_band_sampled(&bands_nm, &planes_nm, lo, hi)?;
        }
        let plane_band = planes_nm.iter().map(|&w| (edges.partition_point(|&e| e <= w).max(1) - 1).min(b - 1)).collect();
        Ok(SpectralSampling { oversampling: planes / b, planes_nm, plane_band, plane_weight: b as f64 / planes as f64, bands_nm })
    }

    pub fn planes(&self) -> usize {
        self.planes_nm.len()
    }
}

/// That each band has a plane strictly between its neighbours (the outer bands: up to the outer edges `lo`,
/// `hi`, where the spectrum is held at them): the scene is interpolated linearly between the bands at each
/// plane, so band k enters the render (and the exact operator) only through those planes. Unevenly spaced bands
/// with too few planes could leave a band with none: the acquisition was blind to it and its reconstruction 0,
/// silently (450, 451, 650 nm with 6 planes 50 nm apart; a held-out battery, round 17). Refused, naming the
/// band and a plane count that samples every band (evenly spaced bands with as many planes always pass).
fn check_every_band_sampled(bands_nm: &[f64], planes_nm: &[f64], lo: f64, hi: f64) -> Result<()> {
    let (b, planes) = (bands_nm.len(), planes_nm.len());
    for k in 0..b {
        let below = if k == 0 { lo } else { bands_nm[k - 1] };
        let above = if k + 1 == b { hi } else { bands_nm[k + 1] };
        if planes_nm.iter().any(|&w| w > below && w < above) {
            continue;
        }
        let gap = bands_nm.windows(2).map(|p| p[1] - p[0]).fold(f64::INFINITY, f64::min);
        let needed = ((hi - lo) / gap).ceil().max(planes as f64 + 1.0);
        let fmt = |v: f64| crate::limits::fmt_num((v * 1e3).round() / 1e3);
        return Err(Error::invalid(format!(
            "band {k} ({} nm) gets no render plane: the {planes} planes are {} nm apart and none lies between {} and {} nm, where the band is sampled, so the acquisition is blind to it and its reconstruction would be 0; use at least {needed} planes (laid evenly over {} – {} nm) or more evenly spaced bands",
            fmt(bands_nm[k]),
            fmt((hi - lo) / planes as f64),
            fmt(below),
            fmt(above),
            fmt(lo),
            fmt(hi)
        )));
    }
    Ok(())
}

/// The weight of each band in an acquisition of evenly spread planes, relative to the mean (1 for evenly
/// spaced bands, to within an f32 step): the render and the exact operator sample the scene's spectrum,
/// interpolated linearly between the bands, at planes spread evenly over [lower edge, upper edge] (see
/// [`SpectralSampling::with_planes`]), so band k's share of the acquisition is the integral of its
/// interpolation weight, ∫ hat_k(λ) dλ: (b_{k+1} − b_{k−1})/2 inside, and for an outer band its half hat plus
/// the half band beyond it where the spectrum is held at it (b₁ − b₀, b_B − b_{B−1}). The chief-ray models
/// (`mapping`, `shift`), which place each band once, weigh band k by this ratio to the mean so that they model
/// the same acquisition for unevenly spaced bands (450, 451, 650 nm: 0.01, 1.0, 1.99, where they weighed
/// every band 1; a held-out battery, round 17). One band: [1].
pub fn band_support_weights(bands_nm: &[f64]) -> Vec<f64> {
    let b = bands_nm.len();
    if b < 2 {
        return vec![1.0; b];
    }
    let support: Vec<f64> = (0..b)
        .map(|k| match k {
            0 => bands_nm[1] - bands_nm[0],
            k if k + 1 == b => bands_nm[b - 1] - bands_nm[b - 2],
            k => 0.5 * (bands_nm[k + 1] - bands_nm[k - 1]),
        })
        .collect();
    let mean = support.iter().sum::<f64>() / b as f64;
    support.iter().map(|s| s / mean).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_band_without_a_plane_is_refused_and_even_bands_weigh_one() {
        let e = SpectralSampling::with_planes(vec![450.0, 451.0, 650.0], 6).unwrap_err().to_string();
        assert!(e.contains("band 0 (450 nm) gets no render plane") && e.contains("at least 300 planes"), "{e}");
        let e = SpectralSampling::with_planes(vec![450.0, 640.0, 650.0], 6).unwrap_err().to_string();
        assert!(e.contains("band 2 (650 nm) gets no render plane"), "{e}");
        // Fewer planes than bands: a coarse render by choice, as before.
        SpectralSampling::with_planes(crate::analysis::linspace(450.0, 650.0, 28), 3).unwrap();
        SpectralSampling::with_planes(vec![450.0, 451.0, 650.0], 2).unwrap();
        // As many planes as evenly spaced bands: every band is sampled.
        SpectralSampling::with_planes(crate::analysis::linspace(450.0, 650.0, 28), 28).unwrap();
        // The suggested count works.
        SpectralSampling::with_planes(vec![450.0, 451.0, 650.0], 300).unwrap();
        // Evenly spaced bands: every weight is 1 in f32 (the models' precision), the paper's 28 included.
        for w in band_support_weights(&crate::analysis::linspace(450.0, 650.0, 28)) {
            assert_eq!(w as f32, 1.0);
        }
        let w = band_support_weights(&[450.0, 451.0, 650.0]);
        let want = [1.0 / 300.0 * 3.0, 100.0 / 300.0 * 3.0, 199.0 / 300.0 * 3.0];
        for (a, b) in w.iter().zip(want) {
            assert!((a - b).abs() < 1e-12, "{w:?}");
        }
        assert_eq!(band_support_weights(&[500.0]), vec![1.0]);
    }
}
