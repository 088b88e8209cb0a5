//! The prior step the solvers share, θ ← D(x, σ): the plug-and-play σ schedule ([`sigma_schedule`]), the
//! network's input scale ([`NetworkScale`], [`denoise_at_network_scale`]) and PnP's two phases (TV, then the
//! network) in [`PriorStep`].
use super::config::{SolverConfig, PNP_SIGMA_GAIN};
use crate::error::Result;
use crate::recon::operator::CubeShape;
use crate::recon::prior::{dihedral::Dihedral, tv::TvDenoiser, Denoiser};
use rayon::prelude::*;

/// The noise-level schedule of the plug-and-play solvers: geometric from σ_max (iteration 1) to σ_min
/// (iteration K), σ_k = σ_max·(σ_min/σ_max)^((k−1)/(K−1)) — the continuous form of PnP-SCI's decreasing
/// σ stages (Yuan et al., CVPR 2020) and of DRUNet's log-spaced schedule (Zhang et al., TPAMI 2021): large σ
/// first, while the iterate is far from the measurement's solution set, small σ last, so the prior neither
/// freezes early errors nor keeps smoothing the converged cube. σ is relative to the cube's peak.
pub fn sigma_schedule(sigma_max: f32, sigma_min: f32, iterations: usize, k: usize) -> f32 {
    if iterations <= 1 {
        return sigma_max;
    }
    let t = (k.clamp(1, iterations) - 1) as f64 / (iterations - 1) as f64;
    (sigma_max as f64 * (sigma_min as f64 / sigma_max as f64).powf(t)) as f32
}

/// PnP's input scale: the network sees x/p with p the largest inlier of x, p = max{x_i : x_i ≤
/// [`PNP_SCALE_GAIN`]·Q(x)}, Q the [`PNP_SCALE_QUANTILE`] quantile of x (1 when p ≤ 0 or not finite). The
/// natural-scene cubes themselves have their peak at 1.00–1.11 × Q (the six scenes at 128², `data/scenes`);
/// the GAP iterate the network is handed has sparser spikes (max x = 1.5–3.9 × Q on the exact and shift cells
/// of SP/mSP at 128²), which the bound now leaves out: measured there, PnP changes by +0.00 to +0.08 dB
/// (docs/reconstruction.md, "Plug-and-play"). Outlier voxels (fewer than 1 − Q of them) cannot set the scale:
/// with p = max x, one voxel at 100× the peak divided the rest of the cube by 100 and the network, trained at
/// peak ≈ 1 with σ relative to it, smoothed the whole cube away.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct NetworkScale {
    /// p, the divisor.
    pub scale: f32,
    /// max x.
    pub max: f32,
    /// Q(x).
    pub quantile: f32,
}

/// PnP input scale: the quantile of x the scale is bounded by (see [`NetworkScale`]).
pub const PNP_SCALE_QUANTILE: f64 = 0.999;
/// PnP input scale: values above this gain × the [`PNP_SCALE_QUANTILE`] quantile are outliers (see [`NetworkScale`]).
pub const PNP_SCALE_GAIN: f32 = 1.5;

impl NetworkScale {
    /// The scale of `x` (`scratch` takes a copy of x for the quantile's selection; deterministic).
    pub fn of(x: &[f32], scratch: &mut Vec<f32>) -> NetworkScale {
        let max = x.par_iter().cloned().reduce(|| f32::MIN, f32::max);
        if x.is_empty() {
            return NetworkScale { scale: 1.0, max, quantile: f32::NAN };
        }
        scratch.clear();
        scratch.extend_from_slice(x);
        let k = ((x.len() - 1) as f64 * PNP_SCALE_QUANTILE).round() as usize;
        let (_, q, above) = scratch.select_nth_unstable_by(k, f32::total_cmp);
        let quantile = *q;
        // The largest inlier: max x when no voxel exceeds the bound (then bit for bit the former scale).
        let bound = PNP_SCALE_GAIN * quantile;
        let p = if max <= bound { max } else { above.iter().cloned().filter(|&v| v <= bound).fold(quantile, f32::max) };
        NetworkScale { scale: if p.is_finite() && p > 0.0 { p } else { 1.0 }, max, quantile }
    }
}

/// out ← p·D(x/p, σ) with p the [`NetworkScale`] of x: the plug-and-play solvers' call of a denoiser trained at
/// peak ≈ 1 (σ relative to p). `scratch` holds the scaled copy. Returns the scale.
pub fn denoise_at_network_scale(denoiser: &mut dyn Denoiser, x: &[f32], out: &mut [f32], shape: CubeShape, sigma: f32, scratch: &mut Vec<f32>) -> Result<NetworkScale> {
    denoise_at_network_scale_transformed(denoiser, x, out, shape, sigma, scratch, None, &mut Vec::new())
}

/// As [`denoise_at_network_scale`], the call of equivariant PnP when `transform` is given: out ←
/// p·g⁻¹ D(g·x/p, σ) (`transformed` holds g·x/p and the denoiser's output; p does not depend on g, a
/// permutation of the voxels). With `None` bit for bit [`denoise_at_network_scale`].
#[allow(clippy::too_many_arguments)]
pub fn denoise_at_network_scale_transformed(
    denoiser: &mut dyn Denoiser,
    x: &[f32],
    out: &mut [f32],
    shape: CubeShape,
    sigma: f32,
    scratch: &mut Vec<f32>,
    transform: Option<Dihedral>,
    transformed: &mut Vec<f32>,
) -> Result<NetworkScale> {
    let s = NetworkScale::of(x, scratch);
    // No positive voxel (a zero iterate: a zero acquisition, or one whose values underflow): the network,
    // trained on cubes ≥ 0 at peak ≈ 1, has no scale to see x at, and its biases at the fallback scale 1 made
    // a cube of ±0.01 from a zero acquisition (a held-out battery, round 16); as N(0·x) = 0·N(x) the step
    // keeps x.
    if !(s.max > 0.0) {
        out.copy_from_slice(x);
        return Ok(s);
    }
    let p = s.scale;
    scratch.resize(x.len(), 0.0);
    scratch.par_iter_mut().zip(x.par_iter()).for_each(|(s, x)| *s = *x / p);
    match transform {
        None => denoiser.denoise(scratch, out, shape, sigma)?,
        Some(g) => {
            // scratch = x/p → transformed = g·(x/p) → scratch = D(transformed) → out = g⁻¹·scratch.
            transformed.resize(x.len(), 0.0);
            let gshape = g.apply(scratch, shape, transformed);
            denoiser.denoise(transformed, scratch, gshape, sigma)?;
            g.invert(scratch, shape, out);
        }
    }
    out.par_iter_mut().for_each(|v| *v *= p);
    Ok(s)
}

/// The prior step the solvers share: θ ← D(x, σ), and PnP's two phases. For PnP (`normalise`) the cube is
/// divided by its scale p ([`NetworkScale`]: its peak, leaving out outliers above [`PNP_SCALE_GAIN`] times its
/// [`PNP_SCALE_QUANTILE`] quantile) before the denoiser and multiplied by p after, so the network sees the
/// scale it was trained on (peak ≈ 1) and σ is relative to p ([`denoise_at_network_scale`]); TV gets x as it
/// is (bit for bit the direct call).
///
/// **Phases (PnP).** The TV phase (GAP-TV / ADMM-TV's own step, at most `tv_warmup` iterations) ends at its
/// cap or, earlier, when the caller finds ‖y − Φθ‖ ≤ [`PNP_TV_DISCREPANCY`](super::config::PNP_TV_DISCREPANCY)·δ (GAP-TV's own stop: the
/// network starts from GAP-TV's stopped iterate). The network phase then runs at most
/// `iterations − tv_warmup` iterations with σ_j = [`sigma_schedule`](σ_1, σ_min, N, j), σ_1 the
/// configuration's (`sigma_auto`: the TV iterate's estimated error, else σ_max).
pub(crate) struct PriorStep<'d> {
    denoiser: &'d mut dyn Denoiser,
    normalise: bool,
    scaled: Vec<f32>,
    /// PnP's TV phase: (its iteration cap, the TV denoiser).
    warmup: Option<(usize, TvDenoiser)>,
    /// The last TV iteration (the network runs from the next one); `None` while the TV phase runs.
    switched_after: Option<usize>,
    /// What ended the TV phase: `discrepancy` (the TV solver's own rule, τ of the TV phase) or `iterations`
    /// (its cap, `tv_warmup`); recorded as `tv_warmup.ended_by` (the run's `stopped_by` is the network phase's).
    switched_by: &'static str,
    /// Network iterations at most (N).
    network_iterations: usize,
    /// ê: rms(x_k − TV(x_k)) / max x_k of the last TV step (what TV removed: the iterate's artefact level).
    tv_error: f32,
    sigma_first: f32,
    sigma_min: f32,
    sigma_max: f32,
    sigma_auto: bool,
    /// The network's input scale at the last network call (for the record).
    last_scale: Option<NetworkScale>,
    /// Equivariant PnP: the seed of the transforms' stream (`None`: off).
    equivariant_seed: Option<u64>,
    /// Equivariant PnP: the transformed cube (cube-sized once used).
    transformed: Vec<f32>,
    /// Equivariant PnP: the transform of every network call so far, in order (for the record).
    transforms: Vec<Dihedral>,
}

impl<'d> PriorStep<'d> {
    /// The prior step of `config`'s solver around `denoiser` (PnP: normalised, with the TV phase).
    pub(crate) fn new(denoiser: &'d mut dyn Denoiser, config: &SolverConfig) -> Self {
        let pnp = config.solver.is_pnp();
        let warmup = (pnp && config.tv_warmup > 0).then(|| (config.tv_warmup, TvDenoiser::new(config.tv_weight, config.tv_iterations, config.tv_coupling)));
        let mut s = PriorStep {
            denoiser,
            normalise: pnp,
            scaled: Vec::new(),
            switched_after: None,
            switched_by: "iterations",
            network_iterations: if pnp { config.iterations - config.tv_warmup } else { config.iterations },
            tv_error: f32::NAN,
            sigma_first: config.sigma_max,
            sigma_min: config.sigma_min,
            sigma_max: config.sigma_max,
            sigma_auto: config.sigma_auto,
            warmup,
            last_scale: None,
            equivariant_seed: (pnp && config.equivariant).then_some(config.equivariant_seed),
            transformed: Vec::new(),
            transforms: Vec::new(),
        };
        if s.warmup.is_none() {
            s.switch(0, "iterations");
        }
        s
    }

    /// Whether iteration k still belongs to the TV phase.
    pub(crate) fn in_tv_phase(&self) -> bool {
        self.switched_after.is_none()
    }

    /// The first iteration of the network phase (1 for TV solvers), once known.
    pub(crate) fn first_network_iteration(&self) -> Option<usize> {
        self.switched_after.map(|k| k + 1)
    }

    /// Whether iteration k is past the run's cap (TV phase + N network iterations).
    pub(crate) fn done(&self, k: usize) -> bool {
        self.switched_after.is_some_and(|s| k > s + self.network_iterations)
    }

    /// End the TV phase after iteration `last_tv` (`by`: the rule that ended it): σ_1 from the TV iterate's
    /// error (auto) or σ_max.
    pub(crate) fn switch(&mut self, last_tv: usize, by: &'static str) {
        if self.switched_after.is_some() {
            return;
        }
        self.switched_after = Some(last_tv);
        self.switched_by = by;
        self.sigma_first = if self.sigma_auto && self.tv_error.is_finite() && self.tv_error > 0.0 {
            (PNP_SIGMA_GAIN * self.tv_error).clamp(self.sigma_min, self.sigma_max)
        } else {
            self.sigma_max
        };
    }

    /// σ of iteration k (0 in the TV phase and for TV solvers).
    pub(crate) fn sigma(&self, k: usize) -> f32 {
        match self.switched_after {
            Some(s) if self.normalise && k > s => sigma_schedule(self.sigma_first, self.sigma_min, self.network_iterations, k - s),
            _ => 0.0,
        }
    }

    /// θ ← D(x) at iteration k (1-based). In the TV phase, also ê; at its cap, the switch.
    pub(crate) fn apply(&mut self, k: usize, x: &[f32], out: &mut [f32], shape: CubeShape) -> Result<()> {
        if let (None, Some((cap, tv))) = (self.switched_after, self.warmup.as_mut()) {
            let cap = *cap;
            tv.denoise(x, out, shape, 0.0)?;
            let peak = x.par_iter().cloned().reduce(|| f32::MIN, f32::max);
            let ss = x.par_iter().zip(out.par_iter()).map(|(a, b)| ((*a - *b) as f64).powi(2)).sum::<f64>();
            self.tv_error = if peak.is_finite() && peak > 0.0 { ((ss / x.len().max(1) as f64).sqrt() / peak as f64) as f32 } else { f32::NAN };
            if k >= cap {
                self.switch(k, "iterations");
            }
            return Ok(());
        }
        let sigma = self.sigma(k);
        if !self.normalise {
            return self.denoiser.denoise(x, out, shape, sigma);
        }
        // Equivariant PnP: the j-th network call (j = k − K_TV) draws g from (seed, j).
        let transform = match (self.equivariant_seed, self.switched_after) {
            (Some(seed), Some(s)) => {
                let g = Dihedral::draw(seed, (k - s) as u64, shape.height == shape.width);
                self.transforms.push(g);
                Some(g)
            }
            _ => None,
        };
        let scale = denoise_at_network_scale_transformed(self.denoiser, x, out, shape, sigma, &mut self.scaled, transform, &mut self.transformed)?;
        self.last_scale = Some(scale);
        Ok(())
    }

    /// Cube-sized buffers held (the scaled copy and the denoiser's).
    pub(crate) fn cube_buffers(&self) -> usize {
        usize::from(self.normalise) + usize::from(self.equivariant_seed.is_some()) + self.denoiser.cube_buffers() + self.warmup.as_ref().map_or(0, |(_, tv)| tv.cube_buffers())
    }

    pub(crate) fn describe(&self) -> serde_json::Value {
        let mut d = self.denoiser.describe();
        if let (Some(scale), Some(o)) = (self.last_scale, d.as_object_mut()) {
            o.insert("network_input_scale".into(), serde_json::json!({"scale": scale.scale, "max": scale.max, "quantile": scale.quantile, "quantile_level": PNP_SCALE_QUANTILE, "gain": PNP_SCALE_GAIN}));
        }
        if let (true, Some(o)) = (self.normalise, d.as_object_mut()) {
            // The noise schedule as planned (the σ of the calls that ran: `sigmas` of the record), and the embedded
            // checkpoint's CRC-32 beside the one that ran (`weights_crc32`).
            let calls = self.network_iterations;
            let sigmas: Vec<f32> = (1..=calls).map(|j| sigma_schedule(self.sigma_first, self.sigma_min, calls, j)).collect();
            o.insert("schedule".into(), serde_json::json!({"network_calls_max": calls, "sigma_first": self.sigma_first, "sigma_min": self.sigma_min, "sigmas": sigmas, "rule": "σ_j = σ_1·(σ_min/σ_1)^((j−1)/(N−1)), j = 1…N"}));
            o.insert(
                "equivariant".into(),
                match self.equivariant_seed {
                    Some(seed) => serde_json::json!({"on": true, "seed": seed, "transforms": self.transforms.iter().map(|g| g.name()).collect::<Vec<_>>(),
                        "rule": "θ = g⁻¹·D(g·x, σ), g = Dihedral::draw(seed, j, square) at network call j: the 8 flips/quarter turns of a square cube, the 4 flips otherwise"}),
                    None => serde_json::json!({"on": false}),
                },
            );
            o.insert("embedded_weights_crc32".into(), serde_json::json!(crate::recon::prior::network::weights_crc32(None).ok()));
        }
        if let (Some((n, tv)), Some(o)) = (&self.warmup, d.as_object_mut()) {
            o.insert(
                "tv_warmup".into(),
                serde_json::json!({"iterations": n, "iterations_run": self.switched_after, "ended_by": self.switched_after.map(|_| self.switched_by), "tv": tv.describe(),
                    "tv_error_estimate": if self.tv_error.is_finite() { Some(self.tv_error) } else { None },
                    "sigma_first": self.sigma_first, "sigma_auto": self.sigma_auto}),
            );
        }
        d
    }
}
