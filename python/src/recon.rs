//! Reconstruction from Python: operators (apply/adjoint/shapes, sparse export) and metrics.
//!
//! An `Operator` wraps any `diffcassi::recon::Operator` (float32 cube (H, W, B) ↔ image (h, w)). Its
//! sparse matrix (`_csr`) is the library's CSR export (`diffcassi::recon::sparse`), built from the
//! operator's footprints, kernels and interpolation table under a memory budget.
use crate::arrays::{check_bounded, check_finite, input, output, output_arg, size_arg};
use crate::errors::{value_error, IntoPy};
use crate::pool::run;
use crate::recipe::Recipe;
use crate::render::{check_shape, owned_exact};
use crate::settings::configure;
use crate::system::PySystem;
use diffcassi::recon::pipeline::run_solver;
use diffcassi::recon::solver::{SettingScope, SPREAD_EVERY};
use diffcassi::recon::{metrics, CubeShape, MonteCarloSpread, Denoiser, SpectralUNet, MappingInterpolation, MappingOperator, Operator, ShiftOperator, SolverConfig, SolverKind, SparseExport, TvCoupling};
use diffcassi::render::Renderer;
use diffcassi::scene::SpectralCube;
use numpy::PyArrayDyn;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::sync::Arc;

/// A linear operator Φ: cube (H, W, B) float32 → detector image (h, w) float32, with its adjoint.
#[pyclass(name = "Operator", module = "diffcassi", frozen)]
pub struct PyOperator {
    op: Arc<dyn Operator>,
    /// The same operator, for its CSR export.
    sparse: Arc<dyn SparseExport>,
    /// The mapping operator's own type, for its initialisation I = A ∘ f.
    mapping: Option<Arc<MappingOperator>>,
    /// How it was built, for pickling ([`crate::recipe`]).
    recipe: Arc<Recipe>,
}

impl PyOperator {
    pub fn new<T: SparseExport + 'static>(op: Arc<T>, recipe: Arc<Recipe>) -> Self {
        PyOperator { op: op.clone(), sparse: op, mapping: None, recipe }
    }
}

#[pymethods]
impl PyOperator {
    #[getter]
    fn name(&self) -> String {
        self.op.name().to_string()
    }

    /// Pickling, `copy.copy` and `copy.deepcopy`: rebuilt by the factory that built it (`exact`,
    /// `mapping_operator`, `shift_operator`) with the same arguments — the same seeds, so the same numbers bit
    /// for bit; an exact operator is traced again ([`crate::recipe`]).
    fn __reduce__<'py>(&self, py: Python<'py>) -> PyResult<(Bound<'py, PyAny>, (&'static str, Py<pyo3::types::PyTuple>, Py<PyDict>, Option<Vec<f64>>))> {
        self.recipe.reduce(py)
    }

    /// The `System` the operator was built from (`exact`, `mapping_operator`, `shift_operator`); `None` for one
    /// read from a file (`from_npz`, `from_scipy`). `load_unrolled` checks weights against it.
    #[getter]
    fn system<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyAny>> {
        self.recipe.system(py)
    }

    /// (H, W, B) of the cubes.
    #[getter]
    fn cube_shape(&self) -> (usize, usize, usize) {
        let c = self.op.cube_shape();
        (c.height, c.width, c.bands)
    }

    /// (h, w) of the images.
    #[getter]
    fn image_shape(&self) -> (usize, usize) {
        let i = self.op.image_shape();
        (i.height, i.width)
    }

    /// Φ cube: `cube` (H, W, B) float32 → image (h, w) float32.
    fn apply<'py>(&self, py: Python<'py>, cube: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
        let c = self.op.cube_shape();
        let a = input::<f32>("cube", cube, "float32", 3, "(H, W, B)")?;
        check_shape("cube", &a.shape, &[c.height, c.width, c.bands])?;
        check_bounded("cube", a.slice(), &a.shape)?;
        let i = self.op.image_shape();
        let mut img = vec![0.0f32; i.len()];
        let x = a.slice();
        run(py, || self.op.apply_into(x, &mut img));
        output(py, img, &[i.height, i.width])
    }

    /// The bands (indices) no detector pixel sees (Φᵀ𝟙 = 0 over the band: a reconstruction is 0 there), as
    /// the library's solvers find them.
    fn dark_bands(&self, py: Python<'_>) -> Vec<usize> {
        run(py, || self.op.dark_bands())
    }

    /// Φᵀ image: `image` (h, w) float32 → cube (H, W, B) float32.
    fn adjoint<'py>(&self, py: Python<'py>, image: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
        let i = self.op.image_shape();
        let a = input::<f32>("image", image, "float32", 2, "(h, w)")?;
        check_shape("image", &a.shape, &[i.height, i.width])?;
        check_bounded("image", a.slice(), &a.shape)?;
        let c = self.op.cube_shape();
        let mut cube = vec![0.0f32; c.len()];
        let y = a.slice();
        run(py, || self.op.adjoint_into(y, &mut cube));
        output(py, cube, &[c.height, c.width, c.bands])
    }

    /// Φ of a batch, in place (the matrix-free torch operator, `diffcassi.torch`): `cubes` (N, H, W, B)
    /// float32 C-contiguous is read where it lies, `out` (N, h, w) float32 C-contiguous is written where it
    /// lies (every element overwritten); the GIL is released for the whole batch. The input is checked as
    /// `apply`'s (finite, within ±[`diffcassi::limits::MAX_SCENE_VALUE`]: beyond it the f32 sums overflow)
    /// before the work.
    fn _apply_batch(&self, py: Python<'_>, cubes: &Bound<'_, PyAny>, out: &Bound<'_, PyAny>) -> PyResult<()> {
        let (c, i) = (self.op.cube_shape(), self.op.image_shape());
        let x = input::<f32>("x", cubes, "float32", 4, "(N, H, W, B)")?;
        let n = x.shape[0];
        check_shape("x", &x.shape, &[n, c.height, c.width, c.bands])?;
        let mut y = output_arg("out", out, &[n, i.height, i.width])?;
        let ys = y.as_slice_mut().map_err(|e| value_error(format!("out: {e}")))?;
        let xs = x.slice();
        check_bounded("x", xs, &x.shape)?;
        let op = &self.op;
        run(py, || {
            for (xc, yc) in xs.chunks_exact(c.len().max(1)).zip(ys.chunks_exact_mut(i.len().max(1))) {
                op.apply_into(xc, yc);
            }
        });
        Ok(())
    }

    /// Φᵀ of a batch, in place: `images` (N, h, w) float32 read where it lies, `out` (N, H, W, B) float32
    /// written where it lies; as [`Self::_apply_batch`].
    fn _adjoint_batch(&self, py: Python<'_>, images: &Bound<'_, PyAny>, out: &Bound<'_, PyAny>) -> PyResult<()> {
        let (c, i) = (self.op.cube_shape(), self.op.image_shape());
        let y = input::<f32>("y", images, "float32", 3, "(N, h, w)")?;
        let n = y.shape[0];
        check_shape("y", &y.shape, &[n, i.height, i.width])?;
        let mut x = output_arg("out", out, &[n, c.height, c.width, c.bands])?;
        let xs = x.as_slice_mut().map_err(|e| value_error(format!("out: {e}")))?;
        let ys = y.slice();
        check_bounded("y", ys, &y.shape)?;
        let op = &self.op;
        run(py, || {
            for (yc, xc) in ys.chunks_exact(i.len().max(1)).zip(xs.chunks_exact_mut(c.len().max(1))) {
                op.adjoint_into(yc, xc);
            }
        });
        Ok(())
    }

    /// The paper's initialisation I = A ∘ f of an acquisition (h, w) float32 (mapping operators only):
    /// each band's value at its nearest mapped detector pixel, (H, W, B) float32.
    fn initialisation<'py>(&self, py: Python<'py>, acquisition: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
        let m = self.mapping.as_ref().ok_or_else(|| value_error(format!("initialisation: only the mapping operator has one (this is `{}`)", self.op.name())))?;
        let i = self.op.image_shape();
        let a = input::<f32>("acquisition", acquisition, "float32", 2, "(h, w)")?;
        check_shape("acquisition", &a.shape, &[i.height, i.width])?;
        check_bounded("acquisition", a.slice(), &a.shape)?;
        let acq = a.slice();
        let cube = run(py, || m.initialisation(acq)).py()?;
        let c = self.op.cube_shape();
        output(py, cube, &[c.height, c.width, c.bands])
    }

    /// The matrix of Φ in CSR form: (indptr int64 (h·w + 1), indices int32, data float32, (h·w, H·W·B)).
    /// Rows are detector pixels (row-major), columns cube entries in C order [row][col][band]. Built by
    /// the library from the operator's parts (`diffcassi::recon::sparse`); a `ValueError` names the size
    /// when assembling it would take more than `memory_budget_bytes`.
    #[pyo3(signature = (memory_budget_bytes = 4_000_000_000))]
    fn _csr<'py>(
        &self,
        py: Python<'py>,
        memory_budget_bytes: u64,
    ) -> PyResult<(Bound<'py, PyArrayDyn<i64>>, Bound<'py, PyArrayDyn<i32>>, Bound<'py, PyArrayDyn<f32>>, (usize, usize))> {
        let sparse = &self.sparse;
        let csr = run(py, || sparse.to_csr(memory_budget_bytes)).py()?;
        if csr.cols > i32::MAX as usize {
            return Err(value_error(format!("to_scipy/save_npz: {} columns exceed SciPy's int32 column indices", csr.cols)));
        }
        let (rows, cols, nnz) = (csr.rows, csr.cols, csr.nnz());
        // Same-size element conversions: collected in place (no new allocation).
        let indptr: Vec<i64> = csr.indptr.into_iter().map(|v| v as i64).collect();
        let indices: Vec<i32> = csr.indices.into_iter().map(|v| v as i32).collect();
        Ok((output(py, indptr, &[rows + 1])?, output(py, indices, &[nnz])?, output(py, csr.data, &[nnz])?, (rows, cols)))
    }

    fn __repr__(&self) -> String {
        let (c, i) = (self.op.cube_shape(), self.op.image_shape());
        format!("Operator('{}', cube {}×{}×{} → image {}×{})", self.op.name(), c.height, c.width, c.bands, i.height, i.width)
    }
}

/// The `exact` operator: the renderer's light transport as a linear map (same settings and defaults as
/// `render`, the keywords of [`crate::settings`]; cubes at the render bands `bands_nm`).
#[pyfunction]
#[pyo3(signature = (system, height, width, mask = None, **settings))]
fn exact_operator(py: Python<'_>, system: &PySystem, height: &Bound<'_, PyAny>, width: &Bound<'_, PyAny>, mask: Option<&Bound<'_, PyAny>>, settings: Option<&Bound<'_, PyDict>>) -> PyResult<PyOperator> {
    let (height, width) = (size_arg("height", height)?, size_arg("width", width)?);
    let s = crate::settings::settings(py, settings, &[])?;
    // Host-only before configure: its device probe would blame a missing driver (round 12).
    crate::settings::host_only(&s.options, "exact")?;
    let (cfg, m) = configure(height, width, &s.options, mask)?;
    let recipe = Recipe::render_settings(py, "exact", system, height, width, mask.is_some().then_some(&m), settings)?;
    Ok(PyOperator::new(Arc::new(owned_exact(py, &system.inner, cfg, m, &s.backend)?), recipe))
}

/// The `mapping` (keyword `interpolation`: `nearest`, the default, or `bilinear`) or `shift` operator of
/// `system` with these render settings (the same detector and mask as `render`/`Transport` with them;
/// cubes at `bands_nm`).
#[pyfunction]
#[pyo3(signature = (kind, system, height, width, mask = None, **settings))]
fn model_operator(
    py: Python<'_>,
    kind: &str,
    system: &PySystem,
    height: &Bound<'_, PyAny>,
    width: &Bound<'_, PyAny>,
    mask: Option<&Bound<'_, PyAny>>,
    settings: Option<&Bound<'_, PyDict>>,
) -> PyResult<PyOperator> {
    let (height, width) = (size_arg("height", height)?, size_arg("width", width)?);
    let s = crate::settings::settings(py, settings, &["interpolation"])?;
    // Host-only before configure: its device probe would blame a missing driver (round 12).
    crate::settings::host_only(&s.options, &format!("{kind}_operator"))?;
    let (cfg, m) = configure(height, width, &s.options, mask)?;
    let interpolation: Option<String> = crate::settings::extra(&s, "interpolation", "a string")?;
    let interp = match interpolation.as_deref().unwrap_or("nearest") {
        "nearest" => MappingInterpolation::Nearest,
        "bilinear" => MappingInterpolation::Bilinear,
        other => return Err(value_error(format!("interpolation `{other}`: use nearest or bilinear"))),
    };
    if kind != "mapping" && kind != "shift" {
        return Err(value_error(format!("operator `{kind}`: use exact, mapping or shift")));
    }
    let tr = crate::system::tracer(&s.backend)?;
    let recipe = Recipe::render_settings(py, if kind == "mapping" { "mapping_operator" } else { "shift_operator" }, system, height, width, mask.is_some().then_some(&m), settings)?;
    let sys = Arc::clone(&system.inner);
    let kind = kind.to_string();
    // Ctrl-C stops the build (`run_cancellable`; the renderer polls the token where it traces).
    crate::pool::run_cancellable(py, move |cancel| -> diffcassi::Result<PyOperator> {
        let bands = cfg.spectral.bands_nm.clone();
        let r = Renderer::new(&sys, tr.as_ref(), cfg, m)?.with_cancel(cancel.clone());
        Ok(if kind == "mapping" {
            let op = Arc::new(MappingOperator::from_renderer(&r, &bands, interp)?);
            PyOperator { op: op.clone(), sparse: op.clone(), mapping: Some(op), recipe }
        } else {
            PyOperator::new(Arc::new(ShiftOperator::from_renderer(&r, &bands)?), recipe)
        })
    })
}

/// Reconstruct a cube from `acquisition` (h, w) float32 through `operator` with GAP-TV, ADMM-TV or PnP
/// (`diffcassi::recon::pipeline::run_solver`, the solve of `diffcassi reconstruct`); `None` settings are the library's defaults. Returns (cube (H, W, B)
/// float32, the record as JSON: settings, per-iteration residuals, seconds).
#[pyfunction]
#[pyo3(signature = (operator, acquisition, solver = "gap-tv", init = None, iterations = None, step = None, tv_weight = None,
                    tv_iterations = None, tv_coupling = None, accelerated = None, admm_eta = None, sigma_max = None,
                    sigma_min = None, tolerance = None, denoiser = None, tv_warmup = None, discrepancy = None,
                    noise_norm = None, sigma_auto = None, noise_twin = None, noise_factor = None, equivariant = None,
                    equivariant_seed = None))]
#[allow(clippy::too_many_arguments)]
fn _reconstruct<'py>(
    py: Python<'py>,
    operator: &PyOperator,
    acquisition: &Bound<'py, PyAny>,
    solver: &str,
    init: Option<&Bound<'py, PyAny>>,
    iterations: Option<usize>,
    step: Option<f64>,
    tv_weight: Option<f64>,
    tv_iterations: Option<usize>,
    tv_coupling: Option<&str>,
    accelerated: Option<bool>,
    admm_eta: Option<f64>,
    sigma_max: Option<f64>,
    sigma_min: Option<f64>,
    tolerance: Option<f64>,
    denoiser: Option<String>,
    tv_warmup: Option<usize>,
    discrepancy: Option<f64>,
    noise_norm: Option<f64>,
    sigma_auto: Option<bool>,
    noise_twin: Option<PyRef<'py, PyOperator>>,
    noise_factor: Option<f64>,
    equivariant: Option<bool>,
    equivariant_seed: Option<u64>,
) -> PyResult<(Bound<'py, PyArrayDyn<f32>>, String)> {
    let kind: SolverKind = solver.parse().py()?;
    // A keyword of another solver is refused, never ignored (the library's rule, as the CLI's).
    let given: Vec<(&str, &str)> = [
        ("accelerated", accelerated.is_some()),
        ("admm_eta", admm_eta.is_some()),
        ("sigma_max", sigma_max.is_some()),
        ("sigma_min", sigma_min.is_some()),
        ("sigma_auto", sigma_auto.is_some()),
        ("tv_warmup", tv_warmup.is_some()),
        ("denoiser", denoiser.is_some()),
        ("equivariant", equivariant.is_some()),
        ("equivariant_seed", equivariant_seed.is_some()),
    ]
    .into_iter()
    .filter(|g| g.1)
    .map(|(k, _)| (k, k))
    .collect();
    SettingScope::check(kind, &given).py()?;
    let mut cfg = SolverConfig::for_solver(kind);
    cfg.iterations = iterations.unwrap_or(cfg.iterations);
    // Settings the solvers hold in f32, checked as given (a tv_weight of 1e-50 ran as 0, 1e-45 gave an
    // all-NaN cube; a held-out battery, round 10): diffcassi::recon::solve::config::f32_setting, as the CLI's.
    let f32_of = |name: &str, v: Option<f64>, default: f32| -> PyResult<f32> {
        v.map(|v| diffcassi::recon::solve::config::f32_setting(name, v)).transpose().py().map(|v| v.unwrap_or(default))
    };
    cfg.step = f32_of("step", step, cfg.step)?;
    cfg.tv_weight = f32_of("tv_weight", tv_weight, cfg.tv_weight)?;
    cfg.tv_iterations = tv_iterations.unwrap_or(cfg.tv_iterations);
    cfg.accelerated = accelerated.unwrap_or(cfg.accelerated);
    cfg.admm_eta = f32_of("admm_eta", admm_eta, cfg.admm_eta)?;
    cfg.sigma_max = f32_of("sigma_max", sigma_max, cfg.sigma_max)?;
    cfg.sigma_min = f32_of("sigma_min", sigma_min, cfg.sigma_min)?;
    cfg.tolerance = tolerance.unwrap_or(cfg.tolerance);
    cfg.tv_warmup = tv_warmup.unwrap_or(cfg.tv_warmup);
    cfg.discrepancy = discrepancy.unwrap_or(cfg.discrepancy);
    cfg.noise_norm = noise_norm.unwrap_or(cfg.noise_norm);
    cfg.sigma_auto = sigma_auto.unwrap_or(cfg.sigma_auto);
    cfg.equivariant = equivariant.unwrap_or(cfg.equivariant);
    if let (Some(seed), false) = (equivariant_seed, cfg.equivariant) {
        return Err(value_error(format!("equivariant_seed {seed}: seeds equivariant PnP's transforms, which are off (give equivariant=True too)")));
    }
    cfg.equivariant_seed = equivariant_seed.unwrap_or(cfg.equivariant_seed);
    if denoiser.is_some() {
        cfg.denoiser = denoiser;
    }
    if let Some(c) = tv_coupling {
        cfg.tv_coupling = match c {
            "vectorial" => TvCoupling::Vectorial,
            "per_band" | "per-band" => TvCoupling::PerBand,
            other => return Err(value_error(format!("tv_coupling `{other}`: use vectorial or per_band"))),
        };
    }
    cfg.validate().py()?;
    let i = operator.op.image_shape();
    let c = operator.op.cube_shape();
    let a = input::<f32>("acquisition", acquisition, "float32", 2, "(h, w)")?;
    check_shape("acquisition", &a.shape, &[i.height, i.width])?;
    check_bounded("acquisition", a.slice(), &a.shape)?;
    let init = match init {
        Some(x) => {
            let x = input::<f32>("init", x, "float32", 3, "(H, W, B)")?;
            check_shape("init", &x.shape, &[c.height, c.width, c.bands])?;
            check_bounded("init", x.slice(), &x.shape)?;
            Some(x.slice().to_vec())
        }
        None => None,
    };
    if noise_factor.is_some() && noise_twin.is_none() {
        return Err(value_error("noise_factor: applies with noise_twin only (the data-driven δ)"));
    }
    let noise_factor = noise_factor.map(MonteCarloSpread::check_factor).transpose().py()?;
    let op = &operator.op;
    let y = a.slice();
    if let Some(t) = &noise_twin {
        check_noise_twin(py, op, &t.op)?;
    }
    // The data-driven δ: noise_norm is the fixed (sensor) part, the twin's spread the Monte-Carlo part.
    let twin = noise_twin.as_ref().map(|t| t.op.clone());
    let spread = twin.as_ref().map(|t| MonteCarloSpread { twin: t.as_ref(), factor: noise_factor.unwrap_or(1.0), sensor_norm: cfg.noise_norm, every: SPREAD_EVERY });
    // The library's solve (`recon::pipeline::run_solver`, as `reconstruct` and `study` run it).
    // Ctrl-C stops the solve at its next iteration (`run_cancellable`: the solver polls the token).
    let (rec, _) = crate::pool::run_cancellable(py, |cancel| run_solver(op.as_ref(), y, init.as_deref(), &cfg, spread.as_ref(), None, &|_, _| {}, Some(cancel)))?;
    // The CLI's record: the solver's, with `stopping` as in reconstruct.json (δ is the caller's `noise_norm`).
    let stopping = rec.stopping_record(y, None);
    // What the CLI prints beside the numbers, `stopping.warnings` (a diverged iteration, a threshold the zero
    // cube meets; round 16).
    for w in stopping["warnings"].as_array().into_iter().flatten().filter_map(serde_json::Value::as_str) {
        PyErr::warn(py, &py.get_type::<pyo3::exceptions::PyUserWarning>(), &std::ffi::CString::new(format!("reconstruct: {}", crate::errors::pythonic(w))).unwrap_or_default(), 1)?;
    }
    let mut record = serde_json::to_value(&rec).map_err(|e| value_error(format!("internal: {e}")))?;
    if let Some(o) = record.as_object_mut() {
        o.insert("stopping".into(), stopping);
    }
    let record = serde_json::to_string(&record).map_err(|e| value_error(format!("internal: {e}")))?;
    Ok((output(py, rec.cube, &[c.height, c.width, c.bands])?, record))
}

/// A `noise_twin` is the exact operator traced again with another seed: its spread ‖(Φ − Φ')θ‖ is the
/// Monte-Carlo part of δ. Any operator of the right shape was taken (a held-out battery, round 10): a mapping
/// operator gave δ 3× too large (1 iteration instead of 18), the operator itself a spread of 0 (the rule never
/// stopped). Refused: a twin or an operator that is not exact, and a twin whose images equal the operator's (the
/// same seed) on a probe cube.
fn check_noise_twin(py: Python<'_>, op: &Arc<dyn Operator>, twin: &Arc<dyn Operator>) -> PyResult<()> {
    if op.name() != "exact" {
        return Err(value_error(format!("noise_twin: the data-driven δ is the exact operator's Monte-Carlo spread; the operator is `{}` (its error is a model's, not a spread: give noise_norm)", op.name())));
    }
    if twin.name() != "exact" {
        return Err(value_error(format!("noise_twin: a `{}` operator; the twin is the exact operator traced with another seed (diffcassi.exact(..., seed=...))", twin.name())));
    }
    // Another shape is the solve's own error (the spread's "other shapes"); the probe needs the same shapes.
    let (c, i) = (op.cube_shape(), op.image_shape());
    let (tc, ti) = (twin.cube_shape(), twin.image_shape());
    if (tc.height, tc.width, tc.bands, ti.height, ti.width) != (c.height, c.width, c.bands, i.height, i.width) {
        return Ok(());
    }
    let same = Arc::ptr_eq(op, twin) || {
        // A deterministic probe in (0, 1]: two traces of different seeds differ on it.
        let probe: Vec<f32> = (0..c.len()).map(|k| 0.5 + 0.5 * ((diffcassi::render::sampling::mix64(k as u64) >> 40) as f32 / (1u64 << 24) as f32)).collect();
        let (a, b) = run(py, || Ok::<_, diffcassi::Error>((op.apply(&probe)?, twin.apply(&probe)?))).py()?;
        a == b
    };
    if same {
        return Err(value_error("noise_twin: its images equal the operator's (the same operator, or the same seed): its spread is 0 and δ would be the sensor part alone; trace the twin with another seed"));
    }
    Ok(())
}

/// The learned denoiser (`spectral-unet-v2`) on `cube` (H, W, B) float32 with noise level `sigma` (standard
/// deviation on the cube's scale: the network was trained on cubes of peak ≈ 1); `weights`: a safetensors
/// file (default: the embedded checkpoint); `neutral`: mean-colour neutralisation (default off), `ensemble`: the
/// geometric self-ensemble (8× the time), as `diffcassi.denoiser.denoise`. Returns the denoised cube (H, W, B) float32.
#[pyfunction]
#[pyo3(signature = (cube, sigma, weights = None, neutral = false, ensemble = false))]
fn denoise<'py>(py: Python<'py>, cube: &Bound<'py, PyAny>, sigma: f64, weights: Option<String>, neutral: bool, ensemble: bool) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
    // σ is on the cube's scale and the denoiser computes in f32: bounded as the cube's values are (1e300 was
    // refused as "σ = inf", the value after the cast).
    if !(sigma.is_finite() && sigma >= 0.0 && sigma <= diffcassi::limits::MAX_SCENE_VALUE) {
        return Err(value_error(format!("sigma = {}: must be finite, ≥ 0 and ≤ {:.3e} (f32's range / 10⁹)", diffcassi::limits::fmt_num(sigma), diffcassi::limits::MAX_SCENE_VALUE)));
    }
    let a = input::<f32>("cube", cube, "float32", 3, "(H, W, B)")?;
    check_finite("cube", a.slice(), &a.shape)?;
    let shape = CubeShape { height: a.shape[0], width: a.shape[1], bands: a.shape[2] };
    let x = a.slice();
    // Ctrl-C stops the network at its next layer (`run_cancellable`; the self-ensemble is 8 passes).
    let out = crate::pool::run_cancellable(py, |cancel| -> diffcassi::Result<Vec<f32>> {
        let mut net = SpectralUNet::load(weights.as_deref().map(std::path::Path::new))?;
        net.neutral = neutral;
        net.self_ensemble = ensemble;
        net.set_cancel(Some(cancel.clone()));
        let mut out = vec![0.0f32; shape.len()];
        net.denoise(x, &mut out, shape, sigma as f32)?;
        Ok(out)
    })?;
    output(py, out, &[shape.height, shape.width, shape.bands])
}

/// The unrolled network (`unrolled-gap-v1`, `diffcassi::recon::unrolled`: the Rust inference of
/// `reconstruct --solver unrolled`) on `acquisition` (h, w) float32 through `operator`. `weights`: a
/// safetensors file, or `None` for the committed weights of `system` (`sp`, `msp`); with both, the file must
/// be trained for `system` (for a preset name: its prescription, where the file records one). Returns (cube (H, W, B) float32, record JSON: the network, the scale, the
/// per-stage residuals, seconds). For tests and comparisons with `diffcassi.unrolled.UnrolledGAP`.
#[pyfunction]
#[pyo3(signature = (operator, acquisition, weights = None, system = None))]
fn _unrolled<'py>(py: Python<'py>, operator: &PyOperator, acquisition: &Bound<'py, PyAny>, weights: Option<String>, system: Option<String>) -> PyResult<(Bound<'py, PyArrayDyn<f32>>, String)> {
    use diffcassi::recon::prior::unrolled::UnrolledNetwork;
    let net = match (&weights, &system) {
        (Some(p), _) => UnrolledNetwork::from_file(std::path::Path::new(p)).py()?,
        (None, Some(s)) => UnrolledNetwork::committed(s).py()?,
        (None, None) => return Err(value_error("give weights (a safetensors file) or system (for the committed weights)")),
    };
    if let Some(s) = &system {
        if &net.meta.system != s {
            return Err(value_error(format!("{}: metadata `system` = `{}`: trained for system `{}`, not `{s}` — refused", net.source, net.meta.system, net.meta.system)));
        }
        // A preset name stands for the preset's prescription, checked as `reconstruct` checks a render's
        // system (a name that is no preset can be checked by name only).
        if let Ok(spec) = diffcassi::presets::spec(s) {
            let built = diffcassi::system::SequentialSystem::build(&spec).py()?;
            net.check_system(&built.spec).py()?;
        }
    }
    let i = operator.op.image_shape();
    let c = operator.op.cube_shape();
    let a = input::<f32>("acquisition", acquisition, "float32", 2, "(h, w)")?;
    check_shape("acquisition", &a.shape, &[i.height, i.width])?;
    check_bounded("acquisition", a.slice(), &a.shape)?;
    let y = a.slice();
    let op = &operator.op;
    let out = run(py, || diffcassi::recon::unrolled::unrolled(op.as_ref(), y, &net, &mut |_, _, _| {})).py()?;
    let record = serde_json::json!({"network": net.describe(), "scale": out.scale, "residuals": out.residuals, "final_residual": out.final_residual, "estimates": out.estimates_json(), "seconds": out.seconds});
    Ok((output(py, out.cube, &[c.height, c.width, c.bands])?, record.to_string()))
}

fn cube_arg(name: &str, obj: &Bound<'_, PyAny>) -> PyResult<(Vec<usize>, Vec<f32>)> {
    let a = input::<f32>(name, obj, "float32", 3, "(H, W, B)")?;
    check_finite(name, a.slice(), &a.shape)?;
    Ok((a.shape.clone(), a.slice().to_vec()))
}

/// RMSE, PSNR (paper and MST conventions), SSIM and SAM of `estimate` against `truth` (both (H, W, B)
/// float32), as JSON. With both wavelength lists, the truth is resampled to the estimate's (as `evaluate`).
#[pyfunction]
#[pyo3(signature = (truth, estimate, truth_wavelengths_nm = None, estimate_wavelengths_nm = None))]
fn _metrics(
    py: Python<'_>,
    truth: &Bound<'_, PyAny>,
    estimate: &Bound<'_, PyAny>,
    truth_wavelengths_nm: Option<&Bound<'_, PyAny>>,
    estimate_wavelengths_nm: Option<&Bound<'_, PyAny>>,
) -> PyResult<String> {
    let (ts, t) = cube_arg("truth", truth)?;
    let (es, e) = cube_arg("estimate", estimate)?;
    let value = match (truth_wavelengths_nm, estimate_wavelengths_nm) {
        (Some(tw), Some(ew)) => {
            let tw = crate::arrays::f64_list("truth_wavelengths_nm", tw)?;
            let ew = crate::arrays::f64_list("estimate_wavelengths_nm", ew)?;
            // Name the list, not the cube, when the counts disagree (the CLI's `--truth-wavelengths` says the
            // same; round 20: "truth: 1280 values for a 16×16×4 cube" blamed the array).
            for (name, list, shape, cube) in [("truth_wavelengths_nm", &tw, &ts, "truth"), ("estimate_wavelengths_nm", &ew, &es, "estimate")] {
                if list.len() != shape[2] {
                    return Err(value_error(format!("{name}: {} wavelengths given for the {cube}'s {} bands", list.len(), shape[2])));
                }
            }
            let tc = SpectralCube::new(ts[0], ts[1], tw, t, "truth").py()?;
            let ec = SpectralCube::new(es[0], es[1], ew, e, "estimate").py()?;
            serde_json::to_value(run(py, || metrics::evaluate(&tc, &ec)).py()?)
        }
        (None, None) => {
            if ts != es {
                return Err(value_error(format!("shape mismatch: truth {ts:?}, estimate {es:?}")));
            }
            let shape = CubeShape { height: ts[0], width: ts[1], bands: ts[2] };
            let peak = t.iter().fold(f64::NEG_INFINITY, |m, &v| m.max(v as f64));
            let m = run(py, || metrics::metrics(&t, &e, shape)).py()?;
            serde_json::to_value(&m).map(|mut v| {
                if let Some(w) = metrics::clamp_warning(peak, &m) {
                    v["warnings"] = serde_json::json!([w]);
                }
                v
            })
        }
        _ => return Err(value_error("give both truth_wavelengths_nm and estimate_wavelengths_nm, or neither")),
    };
    value.map(|v| v.to_string()).map_err(|e| value_error(format!("internal: {e}")))
}

/// δ_MC = 0.062·((1/R_a + 1/R_o)/F)^½·‖y‖ (`diffcassi::recon::solver::monte_carlo_noise_norm`, the CLI's
/// Monte-Carlo term of δ): the expected ‖y − Φ_o x_true‖₂ of an exact operator traced with another seed.
#[pyfunction]
fn monte_carlo_noise_norm(acquisition: &Bound<'_, PyAny>, acquisition_rays: usize, operator_rays: usize, planes_per_band: f64) -> PyResult<f64> {
    if acquisition_rays == 0 || operator_rays == 0 {
        return Err(value_error(format!("acquisition_rays = {acquisition_rays}, operator_rays = {operator_rays}: must be ≥ 1")));
    }
    if !(planes_per_band.is_finite() && planes_per_band >= 1.0) {
        return Err(value_error(format!("planes_per_band = {planes_per_band}: must be finite and ≥ 1")));
    }
    let a = input::<f32>("acquisition", acquisition, "float32", 2, "(h, w)")?;
    if a.slice().is_empty() {
        return Err(value_error(format!("acquisition: an empty {:?} array", a.shape)));
    }
    check_finite("acquisition", a.slice(), &a.shape)?;
    let n = a.slice().iter().map(|v| (*v as f64).powi(2)).sum::<f64>().sqrt();
    Ok(diffcassi::recon::solver::monte_carlo_noise_norm(n, acquisition_rays, operator_rays, planes_per_band))
}

/// ((1 + R_o/R_a)/2)^½: the factor from an operator's spread against its twin to the expected truth
/// residual (`diffcassi::recon::MonteCarloSpread::factor_for`; 1 for equal ray counts).
#[pyfunction]
fn spread_noise_factor(acquisition_rays: usize, operator_rays: usize) -> PyResult<f64> {
    if acquisition_rays == 0 || operator_rays == 0 {
        return Err(value_error(format!("acquisition_rays = {acquisition_rays}, operator_rays = {operator_rays}: must be ≥ 1")));
    }
    Ok(MonteCarloSpread::factor_for(acquisition_rays, operator_rays))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(monte_carlo_noise_norm, m)?)?;
    m.add_function(wrap_pyfunction!(spread_noise_factor, m)?)?;
    m.add_class::<PyOperator>()?;
    m.add_function(wrap_pyfunction!(exact_operator, m)?)?;
    m.add_function(wrap_pyfunction!(model_operator, m)?)?;
    m.add_function(wrap_pyfunction!(_reconstruct, m)?)?;
    m.add_function(wrap_pyfunction!(_metrics, m)?)?;
    m.add_function(wrap_pyfunction!(denoise, m)?)?;
    m.add_function(wrap_pyfunction!(_unrolled, m)?)?;
    Ok(())
}
