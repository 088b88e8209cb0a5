//! Jacobians through the bridge: free parameters declared by name (the names `diffcassi calibrate --free`
//! takes: `s<N>.<column>`, `s<N>.curvature`, `glass_nd:<GLASS>`, `glass_vd:<GLASS>`, `wavelength`,
//! `ray.origin_x|y|z`, `ray.dir_x|y|z`, and on the presets the aliases `prism_tilt_x|y|z`), and
//! ∂(image position, direction)/∂θ of a batch as struct-of-arrays in one allocation.
//!
//! Layout of [`Jacobian::values`]: 6·K·N f64, `values[(c·K + k)·N + i]` = ∂(component c of x, y, z,
//! dir_x, dir_y, dir_z)/∂θ_k of ray i (image-surface frame; mm or direction units per parameter unit). So
//! each (component, parameter) column is contiguous over the rays. The values are those of
//! `diffcassi::diff::DiffSystem::trace_with_backend` (the Rust API), transposed, bit for bit.
//!
//! ```
//! let sys = diffcassi_cpp::load_preset("sp")?;
//! let rays = diffcassi::rays::RayBatch::chief_rays(sys.system(), &[[0.0, 0.0], [2.5, 0.0]], 520.0)?;
//! let j = sys.trace_jacobian("analytic", "prism_tilt_x, wavelength", &rays.origin_x, &rays.origin_y, &rays.origin_z,
//!                            &rays.dir_x, &rays.dir_y, &rays.dir_z, &rays.wavelength_nm)?;
//! assert_eq!((j.len(), j.parameter_count()), (2, 2));
//! assert_eq!(j.parameters(), vec!["s4.tilt_x_deg".to_string(), "wavelength".to_string()]);
//! // Tilting the prism about x moves the image in y: ∂y/∂θ₀ of ray 0 is values[(1·2 + 0)·2 + 0].
//! assert!(j.values()[4].abs() > 1e-3);
//! let e = sys.trace_jacobian("analytic", "s4.tilt_q_deg", &[], &[], &[], &[], &[], &[], &[]).err().unwrap();
//! assert!(e.to_string().contains("free parameter `s4.tilt_q_deg`"), "{e}");
//! # Ok::<(), diffcassi::Error>(())
//! ```
use crate::system::System;
use diffcassi::diff::{Param, ParamSet};
use diffcassi::error::Result;
use diffcassi::tracer::{BackendConfig, RaySlices, TracedBatch};

/// A batch's Jacobians: the traced values, the parameters' canonical names, the SoA derivatives, and per
/// ray whether the Jacobian is available (with the reason when it is not).
pub struct Jacobian {
    pub traced: TracedBatch,
    pub params: Vec<String>,
    pub values: Vec<f64>,
    pub available: Vec<u8>,
    pub reasons: Vec<String>,
}

/// The free parameters named in `list` (comma-separated) for a system called `system_name` (preset
/// aliases apply to the presets): [`diffcassi::diff::param::parse_parameter_list`].
pub fn parse_parameters(system_name: &str, list: &str) -> Result<Vec<Param>> {
    diffcassi::diff::param::parse_parameter_list(system_name, list)
}

/// The parameter set of `parameters` on the loaded system: [`ParamSet::for_system`].
pub fn parameter_set(system: &diffcassi::system::SequentialSystem, parameters: &str) -> Result<ParamSet> {
    ParamSet::for_system(system, parameters)
}

impl System {
    /// Trace caller-owned columns with their Jacobians for the comma-separated `parameters`, with the
    /// named backend (`analytic`, or an Embree one with f64 refinement). A free glass is traced as its
    /// (n_d, V_d) Cauchy model, as in the Rust API.
    #[allow(clippy::too_many_arguments)]
    pub fn trace_jacobian(
        &self,
        backend: &str,
        parameters: &str,
        origin_x: &[f64],
        origin_y: &[f64],
        origin_z: &[f64],
        dir_x: &[f64],
        dir_y: &[f64],
        dir_z: &[f64],
        wavelength_nm: &[f64],
    ) -> Result<Box<Jacobian>> {
        // In this process's pool: a fresh one in a fork() child (diffcassi::pool).
        diffcassi::pool::install(|| {
            let slices = RaySlices::new(origin_x, origin_y, origin_z, dir_x, dir_y, dir_z, wavelength_nm)?;
            let config: BackendConfig = backend.parse()?;
            let set = parameter_set(self.system(), parameters)?;
            // The ray and memory budgets before the rays are copied or anything N × K is allocated (round 21: 4·10⁵
            // rays × 70 parameters peaked at 2.7 GB under a 1 GB budget, unchecked): the library's figure for a
            // bindings' Jacobian (Python's, `limits::bytes_jacobian`) plus this bridge's transposed copy of the
            // values (48·K B per ray, alive beside the library's until it returns).
            let (n_rays, k) = (origin_x.len(), set.len());
            let what = format!("Jacobian of N × K = {n_rays} rays × {k} parameters");
            let reduce = "the rays or the parameters";
            diffcassi::limits::check_rays_reducing(&what, reduce, n_rays as f64)?;
            let transposed = n_rays as f64 * 48.0 * k as f64 * 1.1;
            diffcassi::limits::check_memory_reducing(&what, reduce, diffcassi::limits::bytes_jacobian(n_rays as f64, k) + transposed)?;
            let rays = slices.to_batch();
            let hj = set.build()?.trace_with_backend(&config, &rays)?;
            let (n, kk) = (hj.batch.len(), hj.batch.k());
            crate::system::checked_size("Jacobian (rays, 6, parameters)", &[n, 6, kk])?;
            let mut values = vec![0.0; 6 * kk * n];
            for i in 0..n {
                for c in 0..6 {
                    for (k, v) in hj.batch.row(i, c).iter().enumerate() {
                        values[(c * kk + k) * n + i] = *v;
                    }
                }
            }
            let available = hj.unavailable.iter().map(|r| r.is_none() as u8).collect();
            let reasons = hj.unavailable.into_iter().map(Option::unwrap_or_default).collect();
            Ok(Box::new(Jacobian { traced: hj.batch.traced, params: hj.batch.params, values, available, reasons }))
        })
    }
}

impl Jacobian {
    pub fn len(&self) -> usize {
        self.traced.len()
    }
    pub fn is_empty(&self) -> bool {
        self.traced.is_empty()
    }
    pub fn parameter_count(&self) -> usize {
        self.params.len()
    }
    /// Canonical names of the parameters, in column order (aliases resolved).
    pub fn parameters(&self) -> Vec<String> {
        self.params.clone()
    }
    /// The SoA derivatives (see the module docs for the layout).
    pub fn values(&self) -> &[f64] {
        &self.values
    }
    /// 1 where ray i's Jacobian is available.
    pub fn available(&self) -> &[u8] {
        &self.available
    }
    /// Why ray i's Jacobian is unavailable ("" when it is available or `i` is out of range).
    pub fn reason(&self, i: usize) -> &str {
        self.reasons.get(i).map_or("", String::as_str)
    }
    pub fn traced(&self) -> &TracedBatch {
        &self.traced
    }
    /// The traced batch's columns (as [`crate::Traced`]'s).
    pub fn traced_x(&self) -> &[f64] {
        &self.traced.x
    }
    pub fn traced_y(&self) -> &[f64] {
        &self.traced.y
    }
    pub fn traced_z(&self) -> &[f64] {
        &self.traced.z
    }
    pub fn traced_dir_x(&self) -> &[f64] {
        &self.traced.dir_x
    }
    pub fn traced_dir_y(&self) -> &[f64] {
        &self.traced.dir_y
    }
    pub fn traced_dir_z(&self) -> &[f64] {
        &self.traced.dir_z
    }
    pub fn traced_status(&self) -> &[u8] {
        crate::results::status_bytes(&self.traced.status)
    }
}
