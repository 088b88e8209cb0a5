//! `DiffRenderer`: the differentiable acquisition (`diffcassi::render::gradient`) for co-design — the
//! acquisition of a batch of scenes and its vector–Jacobian product with respect to the free optical
//! parameters, the mask and the scenes. Thin: arrays are borrowed (float64, C-contiguous), the GIL is
//! released while Rust works, results are handed to NumPy without a copy. `diffcassi.torch.CassiRenderer`
//! wraps it as an `nn.Module`.
use crate::arrays::{f64_list, input, output, seed_arg, size_arg};
use crate::errors::{value_error, IntoPy};
use crate::pool::run;
use crate::system::PySystem;
use diffcassi::diff::ParamSet;
use diffcassi::rays::PupilAim;
use diffcassi::render::gradient::{DiffRenderer, Wanted};
use diffcassi::render::{AiryConfig, RenderConfig, SpectralSampling};
use numpy::PyArrayDyn;
use pyo3::prelude::*;

#[pyclass(name = "DiffRenderer", module = "diffcassi", frozen)]
pub struct PyDiffRenderer {
    inner: DiffRenderer,
    /// The entrance-pupil aim at construction (the renderer keeps it fixed; [`Self::_csr`] needs the
    /// current system's to equal it).
    aim: PupilAim,
    /// How it was built, for pickling ([`crate::recipe`]).
    recipe: std::sync::Arc<crate::recipe::Recipe>,
}

type Arr<'py> = Bound<'py, PyArrayDyn<f64>>;

impl PyDiffRenderer {
    /// N of a (N, B, H, W) scene array, its radiances within the CLI's limit and its rays within the ray
    /// budget.
    fn batch(&self, scene: &[usize], values: &[f64]) -> PyResult<usize> {
        let (b, h, w) = (self.inner.scene_wavelengths_nm.len(), self.inner.config.scene_height, self.inner.config.scene_width);
        if scene[1..] != [b, h, w] {
            return Err(value_error(format!("scene: expected shape (N, {b}, {h}, {w}), got {scene:?}")));
        }
        let max = diffcassi::limits::MAX_SCENE_VALUE;
        if let Some(i) = values.iter().position(|v| v.abs() > max) {
            let idx = [i / (b * h * w), i / (h * w) % b, i / w % h, i % w];
            return Err(value_error(format!("scene: value {} at index {idx:?}: radiances must be ≤ {max:.3e} in magnitude (f32 range / 10⁹, as `diffcassi render` requires, so the acquisition cannot overflow)", diffcassi::limits::fmt_num(values[i]))));
        }
        self.check_batch_of(scene[0])?;
        Ok(scene[0])
    }

    /// A batch of `n` scenes within the ray and memory budgets ([`check_budget`]).
    fn check_batch_of(&self, n: usize) -> PyResult<()> {
        let c = &self.inner.config;
        check_budget(c.scene_height, c.scene_width, self.inner.scene_wavelengths_nm.len(), c.spectral.planes(), c.rays_per_pixel, c.airy.is_some(), Some(n))
    }
}

/// Memory of a differentiable render of `n` scenes with its backward pass, as Python's `CassiRenderer` runs it
/// (forward and `backward()`): per scene, the buffers of an H × W render ([`limits::bytes_render_hw`]) and the
/// float64 scene, acquisition and their gradients torch holds beside them (16 B per pixel and 8 B per
/// pixel-band, at float32 half of the float64 copies); for the renderer, its traced transport, kept for the
/// backward pass (16 B per pixel-plane), and the sampler's tables (24 B per ray of a pixel). Round 19 measured
/// the peak rise over `import torch` against this: 0.098 GB at 256² × 28 planes (estimate 0.098), 0.164 GB at
/// 112 planes (0.186), 0.239 GB for a batch of 4 (0.30), 0.63 GB at 512² × 112 (0.74); the old estimate
/// (one render's buffers) ignored both planes and the batch.
fn bytes_renderer(height: usize, width: usize, bands: usize, planes: usize, rays: usize, airy: bool, n: usize) -> f64 {
    use diffcassi::limits;
    let pixels = height as f64 * width as f64;
    let per_scene = limits::bytes_render_hw(height, width, bands, bands, planes, false, airy.then_some(2.5)) + pixels * (16.0 + 4.0 * bands as f64);
    n as f64 * per_scene + pixels * planes as f64 * 16.0 + 24.0 * rays as f64
}

/// The ray and memory budgets of a renderer, before anything of its size is allocated: its rays (H × W ×
/// planes × rays per scene) and [`bytes_renderer`], for one scene at construction (`batch` `None`) or for a
/// batch of N before a forward pass.
fn check_budget(height: usize, width: usize, bands: usize, planes: usize, rays: usize, airy: bool, batch: Option<usize>) -> PyResult<()> {
    use diffcassi::limits;
    if planes == 0 || planes > limits::MAX_PLANES {
        return Err(value_error(format!("planes {planes}: must be in 1..={}", limits::MAX_PLANES)));
    }
    let what = match batch {
        None => format!("H × W × planes × rays ({height} × {width} × {planes} × {rays})"),
        Some(n) => format!("N × H × W × planes × rays ({n} × {height} × {width} × {planes} × {rays})"),
    };
    let n = batch.unwrap_or(1);
    limits::check_rays(&what, n as f64 * height as f64 * width as f64 * planes as f64 * rays as f64).py()?;
    limits::check_memory(&what, bytes_renderer(height, width, bands, planes, rays, airy, n)).py()
}

#[pymethods]
impl PyDiffRenderer {
    /// `DiffRenderer(system, height, width, free, rays=4, planes=28, seed=0, bands_nm=None, airy=True,
    /// scene_fov_deg=None)`: `free` a list of parameter names (`calibrate --free` names, preset aliases such
    /// as `prism_tilt_x`), scene bands `bands_nm` (default 28 bands 450–650 nm), `planes` spectral planes over
    /// them. `scene_fov_deg`: for a system whose object is at infinity, the scene's full angular extent across
    /// its width (degrees, in (0, 180); pixels uniform in field angle, as `render(..., scene_fov_deg=)`):
    /// required there, refused on a finite object.
    #[new]
    #[pyo3(signature = (system, height, width, free, rays = None, planes = None, seed = None, bands_nm = None, airy = true, scene_fov_deg = None))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        system: &PySystem,
        height: &Bound<'_, PyAny>,
        width: &Bound<'_, PyAny>,
        free: Vec<String>,
        rays: Option<&Bound<'_, PyAny>>,
        planes: Option<&Bound<'_, PyAny>>,
        seed: Option<&Bound<'_, PyAny>>,
        bands_nm: Option<&Bound<'_, PyAny>>,
        airy: bool,
        scene_fov_deg: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Self> {
        // Counts and the seed are read by the shared argument readers, so 2**64, -1, 2.5 or True are refused
        // naming the argument and its range (`arrays::size_arg`, `seed_arg`), not as a bare OverflowError or
        // TypeError from the binding's conversion; None keeps the default.
        let (height, width) = (size_arg("height", height)?, size_arg("width", width)?);
        let rays = rays.map(|v| size_arg("rays", v)).transpose()?.unwrap_or(4);
        let planes = planes.map(|v| size_arg("planes", v)).transpose()?.unwrap_or(28);
        let seed = seed.map(|v| seed_arg("seed", v)).transpose()?.unwrap_or(0);
        // A number or None, as the render keywords take it (`settings::settings`); its range and whether the
        // system wants it are the library's checks (`render::scene_pitch_for`, in `DiffRenderer::new`).
        let scene_fov_deg = match scene_fov_deg {
            Some(v) if !v.is_none() => Some(v.extract::<f64>().map_err(|_| {
                let ty = v.get_type().name().map(|n| n.to_string()).unwrap_or_else(|_| "?".into());
                value_error(format!("scene_fov_deg: expected a number (degrees) or None, got {ty} {}", v.repr().map(|r| r.to_string()).unwrap_or_default()))
            })?),
            _ => None,
        };
        let bands = match bands_nm {
            Some(b) => f64_list("bands_nm", b)?,
            None => diffcassi::analysis::linspace(450.0, 650.0, 28),
        };
        if free.is_empty() {
            return Err(value_error("free: name ≥ 1 parameter (e.g. [\"prism_tilt_x\"])"));
        }
        check_budget(height, width, bands.len(), planes, rays, airy, None)?;
        let recipe = {
            let sys = Py::new(py, system.share())?;
            let args = pyo3::types::PyTuple::new(py, [sys.into_any(), height.into_pyobject(py)?.into_any().unbind(), width.into_pyobject(py)?.into_any().unbind(), free.clone().into_pyobject(py)?.into_any().unbind()])?;
            let kw = pyo3::types::PyDict::new(py);
            kw.set_item("rays", rays)?;
            kw.set_item("planes", planes)?;
            kw.set_item("seed", seed)?;
            kw.set_item("bands_nm", bands.clone())?;
            kw.set_item("airy", airy)?;
            kw.set_item("scene_fov_deg", scene_fov_deg)?;
            crate::recipe::Recipe::new(py, "DiffRenderer", args, Some(&kw))?
        };
        // The free parameters' glasses come from the catalogue files, read again here: refused if one changed since
        // the system was built (as a copy of it is; round 18).
        diffcassi::system::SequentialSystem::check_catalog_identities(&system.catalogs).py()?;
        let set = ParamSet::for_system(&system.inner, &free.join(",")).py()?;
        let mut cfg = RenderConfig::paper(height.max(1));
        (cfg.scene_height, cfg.scene_width) = (height, width);
        cfg.spectral = SpectralSampling::with_planes(bands.clone(), planes).py()?;
        cfg.rays_per_pixel = rays;
        cfg.seed = seed;
        cfg.airy = airy.then(AiryConfig::default);
        cfg.scene_fov_deg = scene_fov_deg;
        let inner = run(py, move || DiffRenderer::new(set, cfg, bands)).py()?;
        let aim = PupilAim::of(&inner.ds.system);
        Ok(PyDiffRenderer { inner, aim, recipe })
    }

    /// Pickling, `copy.copy` and `copy.deepcopy` (a `CassiRenderer` saved with `torch.save` or snapshotted):
    /// rebuilt by `DiffRenderer(...)` with the same arguments (the same seed: the same samples), then moved to
    /// this renderer's parameter values when `with_values` made it ([`crate::recipe`]).
    fn __reduce__<'py>(&self, py: Python<'py>) -> PyResult<(Bound<'py, PyAny>, (&'static str, Py<pyo3::types::PyTuple>, Py<pyo3::types::PyDict>, Option<Vec<f64>>))> {
        self.recipe.reduce(py)
    }

    /// The free parameters' names.
    fn names(&self) -> Vec<String> {
        self.inner.names()
    }

    /// Their current values (spec units: mm, degrees, …).
    fn values(&self) -> PyResult<Vec<f64>> {
        self.inner.values().py()
    }

    /// The scene bands (nm).
    fn bands_nm(&self) -> Vec<f64> {
        self.inner.scene_wavelengths_nm.clone()
    }

    /// Detector (h, w).
    fn image_shape(&self) -> (usize, usize) {
        self.inner.image_shape()
    }

    /// The same renderer (detector, samples) with the free parameters set to `values`; an error names a
    /// parameter out of its valid range (a glass outside the catalogue's range, a system that does not build).
    fn with_values(&self, py: Python<'_>, values: &Bound<'_, PyAny>) -> PyResult<Self> {
        let x = f64_list("values", values)?;
        if x.len() != self.inner.set.free.len() {
            return Err(value_error(format!("values: {} values for {} free parameters", x.len(), self.inner.set.free.len())));
        }
        let inner = run(py, || self.inner.with_values(&x)).py()?;
        Ok(PyDiffRenderer { inner, aim: self.aim, recipe: self.recipe.with_values(py, x) })
    }

    /// `_check_batch(n)`: a batch of `n` scenes within the ray and memory budgets (forward and backward), checked
    /// by `CassiRenderer` before its float64 copy of the batch is made.
    fn _check_batch(&self, n: usize) -> PyResult<()> {
        self.check_batch_of(n)
    }

    /// Acquisitions (N, h, w) float64 of `scene` (N, B, H, W) float64 through `mask` (H, W) float64.
    fn render<'py>(&self, py: Python<'py>, scene: &Bound<'py, PyAny>, mask: &Bound<'py, PyAny>) -> PyResult<Arr<'py>> {
        let s = input::<f64>("scene", scene, "float64", 4, "(N, B, H, W)")?;
        let m = input::<f64>("mask", mask, "float64", 2, "(H, W)")?;
        let n = self.batch(&s.shape, s.slice())?;
        let (ss, ms) = (s.slice(), m.slice());
        let img = run(py, || self.inner.render(ss, n, ms)).py()?;
        let (h, w) = self.inner.image_shape();
        output(py, img, &[n, h, w])
    }

    /// The vector–Jacobian product for the upstream gradient `grad` (N, h, w) float64:
    /// (∂L/∂θ (P,), ∂L/∂mask (H, W), ∂L/∂scene (N, B, H, W)). `params`, `mask_grad`, `scene_grad` say which are
    /// wanted (torch's `needs_input_grad`); one not wanted is `None` and its work is skipped (no reverse
    /// sweep without `params`, the closed mask pixels' rays not traced without `mask_grad`); the others are
    /// bit-identical to those of the call that wants all three.
    #[pyo3(signature = (scene, mask, grad, params = true, mask_grad = true, scene_grad = true))]
    #[allow(clippy::too_many_arguments)]
    fn vjp<'py>(&self, py: Python<'py>, scene: &Bound<'py, PyAny>, mask: &Bound<'py, PyAny>, grad: &Bound<'py, PyAny>, params: bool, mask_grad: bool, scene_grad: bool) -> PyResult<(Option<Arr<'py>>, Option<Arr<'py>>, Option<Arr<'py>>)> {
        let s = input::<f64>("scene", scene, "float64", 4, "(N, B, H, W)")?;
        let m = input::<f64>("mask", mask, "float64", 2, "(H, W)")?;
        let g = input::<f64>("grad", grad, "float64", 3, "(N, h, w)")?;
        let n = self.batch(&s.shape, s.slice())?;
        let (ss, ms, gs) = (s.slice(), m.slice(), g.slice());
        let wanted = Wanted { params, mask: mask_grad, scene: scene_grad };
        let v = run(py, || self.inner.vjp_wanted(ss, n, ms, gs, wanted)).py()?;
        let (p, sh) = (v.params.len(), s.shape.clone());
        let gp = if params { Some(output(py, v.params, &[p])?) } else { None };
        let gm = if mask_grad { Some(output(py, v.mask, &[sh[2], sh[3]])?) } else { None };
        let gsc = if scene_grad { Some(output(py, v.scene, &sh)?) } else { None };
        Ok((gp, gm, gsc))
    }

    /// The linear map scene → acquisition at the current parameters with every mask pixel open, as the
    /// library's CSR export (`diffcassi::recon::sparse`, the exact operator of a renderer with this
    /// renderer's system, settings, seed and detector): (indptr int64 (h·w + 1), indices int32, data
    /// float32, (h·w, H·W·B)); columns in C order [row][col][band]. The acquisition through a mask m is
    /// this matrix applied to m ⊙ scene (the renderer is linear in the mask per pixel); it equals
    /// [`Self::render`] to f32 rounding (footprints, Airy kernels and interpolation weights stored in f32).
    /// Refused when the current parameters move the entrance pupil (the differentiable renderer keeps its
    /// construction-time aim, a fresh trace would not), and, naming the size, when assembling would take
    /// more than `memory_budget_bytes` (also the budget of the traced transport).
    fn _csr<'py>(
        &self,
        py: Python<'py>,
        memory_budget_bytes: u64,
    ) -> PyResult<(Bound<'py, PyArrayDyn<i64>>, Bound<'py, PyArrayDyn<i32>>, Bound<'py, PyArrayDyn<f32>>, (usize, usize))> {
        use diffcassi::recon::{ExactOperator, SparseExport};
        use diffcassi::render::{Mask, Renderer};
        let d = &self.inner;
        if PupilAim::of(&d.ds.system) != self.aim {
            let vals: Vec<String> = d.names().iter().zip(d.values().unwrap_or_default()).map(|(n, v)| format!("{n} = {v}")).collect();
            return Err(value_error(format!("the free parameters ({}) move the entrance pupil, which the differentiable renderer keeps at its construction-time aim: no operator table matches its render", vals.join(", "))));
        }
        let (h, w) = (d.config.scene_height, d.config.scene_width);
        let csr = run(py, || -> diffcassi::Result<_> {
            let tracer = diffcassi::tracer::AnalyticTracer::default();
            let mut r = Renderer::new(&d.ds.system, &tracer, d.config.clone(), Mask::open(h, w))?;
            r.detector = d.detector;
            let op = ExactOperator::new(r, &d.scene_wavelengths_nm, memory_budget_bytes)?;
            op.to_csr(memory_budget_bytes)
        })
        .py()?;
        if csr.cols > i32::MAX as usize {
            return Err(value_error(format!("CassiRenderer: {} columns exceed int32 column indices", csr.cols)));
        }
        let (rows, cols, nnz) = (csr.rows, csr.cols, csr.nnz());
        let indptr: Vec<i64> = csr.indptr.into_iter().map(|v| v as i64).collect();
        let indices: Vec<i32> = csr.indices.into_iter().map(|v| v as i32).collect();
        Ok((output(py, indptr, &[rows + 1])?, output(py, indices, &[nnz])?, output(py, csr.data, &[nnz])?, (rows, cols)))
    }

    /// The chief-ray mapping cube at `wavelengths_nm` and its Jacobian: (positions (H, W, L, 2) mm,
    /// jacobian (H, W, L, 2, P), valid (H, W, L) bool).
    fn mapping_jacobian<'py>(&self, py: Python<'py>, wavelengths_nm: &Bound<'py, PyAny>) -> PyResult<(Arr<'py>, Arr<'py>, Bound<'py, PyArrayDyn<bool>>)> {
        let wl = f64_list("wavelengths_nm", wavelengths_nm)?;
        let (pos, jac, valid) = run(py, || self.inner.mapping_jacobian(&wl)).py()?;
        let (h, w, l, p) = (self.inner.config.scene_height, self.inner.config.scene_width, wl.len(), self.inner.set.free.len());
        Ok((output(py, pos, &[h, w, l, 2])?, output(py, jac, &[h, w, l, 2, p])?, output(py, valid, &[h, w, l])?))
    }

    fn __repr__(&self) -> String {
        let (h, w) = self.inner.image_shape();
        format!("DiffRenderer(free={:?}, scene {}×{}, detector {h}×{w}, {} planes, {} rays)", self.inner.names(), self.inner.config.scene_height, self.inner.config.scene_width, self.inner.config.spectral.planes(), self.inner.config.rays_per_pixel)
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyDiffRenderer>()
}
