//! `render` and `Transport`: coded acquisitions from NumPy scene cubes.
//!
//! The settings keywords are parsed in one place ([`crate::settings`]): every setting the caller leaves at
//! `None` takes the library's default (the CLI's too), so `render(system, scene, wl)` and
//! `diffcassi render --scene FILE --scene-size N` give the same acquisition bit for bit.
use crate::arrays::{check_bounded, check_finite, f64_list, input, output, seed_arg, size_arg, Input};
use crate::errors::{value_error, IntoPy};
use crate::pool::run;
use crate::settings::{configure, extra};
use crate::system::{tracer, PySystem};
use diffcassi::render::NoiseSettings;
use diffcassi::recon::{CsrMatrix, CubeShape, ExactOperator, ImageShape, Operator, SparseExport};
use diffcassi::render::{output as render_output, Mask, RenderConfig, Renderer};
use pyo3::types::PyDict;
use diffcassi::scene::SpectralCube;
use diffcassi::system::SequentialSystem;
use diffcassi::tracer::Tracer;
use numpy::PyArrayDyn;
use pyo3::prelude::*;
use std::sync::Arc;
use std::time::Instant;

/// A scene argument: (H, W, B) float32, C-contiguous, finite, B = the wavelengths' count.
pub fn scene_cube(scene: &Bound<'_, PyAny>, wavelengths_nm: Vec<f64>) -> PyResult<SpectralCube> {
    scene_cube_in(scene, wavelengths_nm, Vec::new())
}

/// [`scene_cube`] copying the scene into `buffer` (its capacity reused: a warm buffer saves the page
/// faults of a fresh scene-sized allocation at every call). The finiteness scan is `SpectralCube::new`'s;
/// only when it fails is the array scanned again for the message naming the argument and index. Then the
/// library's radiance limits (`diffcassi::render::settings::check_scene_values`, the CLI's too: finite, ≥ 0,
/// ≤ [`diffcassi::limits::MAX_SCENE_VALUE`], so the acquisition cannot overflow), with the CLI's message.
pub fn scene_cube_in(scene: &Bound<'_, PyAny>, wavelengths_nm: Vec<f64>, mut buffer: Vec<f32>) -> PyResult<SpectralCube> {
    let a: Input<f32> = input("scene", scene, "float32", 3, "(H, W, B)")?;
    if a.shape[2] != wavelengths_nm.len() {
        return Err(value_error(format!("scene: {} bands (shape {:?}) but {} wavelengths_nm", a.shape[2], a.shape, wavelengths_nm.len())));
    }
    buffer.clear();
    buffer.extend_from_slice(a.slice());
    let cube = SpectralCube::new(a.shape[0], a.shape[1], wavelengths_nm, buffer, "scene array").or_else(|e| {
        check_finite("scene", a.slice(), &a.shape)?;
        Err(crate::errors::to_py(e))
    })?;
    diffcassi::render::settings::check_scene_values(&cube).map_err(|m| value_error(format!("scene: {m}")))?;
    Ok(cube)
}

fn scene_description(cube: &SpectralCube) -> serde_json::Value {
    serde_json::json!({"source": "array", "native_height": cube.height, "native_width": cube.width, "native_wavelengths_nm": cube.wavelengths_nm})
}

/// Render `scene` (H, W, B float32 at `wavelengths_nm`) through `system`: (acquisition (h, w) float64,
/// render.json's content as JSON text). `settings`: the render keywords ([`crate::settings`]) and the CLI's
/// noise options (`noise`, `full_well_e`, `electrons_per_unit`, `read_noise_e`, `adc_bits`, `noise_seed`).
#[pyfunction]
#[pyo3(signature = (system, scene, wavelengths_nm, mask = None, **settings))]
fn _render<'py>(
    py: Python<'py>,
    system: &PySystem,
    scene: &Bound<'py, PyAny>,
    wavelengths_nm: &Bound<'py, PyAny>,
    mask: Option<&Bound<'py, PyAny>>,
    settings: Option<&Bound<'py, PyDict>>,
) -> PyResult<(Bound<'py, PyArrayDyn<f64>>, String)> {
    let t0 = Instant::now();
    let mut s = crate::settings::settings(py, settings, &RENDER_EXTRA_KEYS)?;
    // The tracer: the backend named, or the one `tolerance_um` chooses with the rays and the precision
    // (`diffcassi::fidelity::RenderTracing`, the CLI's `--tolerance-um`).
    let tolerance_um: Option<f64> = extra(&s, "tolerance_um", "a number (µm)")?;
    let cache_dir: Option<std::path::PathBuf> = extra(&s, "calibration_cache", "a path")?;
    s.options.tolerance_chooses_rays = tolerance_um.is_some();
    let source = match tolerance_um {
        Some(t) => {
            if settings.map(|d| d.get_item("backend")).transpose()?.flatten().is_some_and(|v| !v.is_none()) {
                return Err(value_error(format!("tolerance_um {t} chooses the backend and its precision itself; it cannot be combined with backend (drop one or the other)")));
            }
            diffcassi::fidelity::TracerSource::Tolerance { tolerance_um: t, cache: diffcassi::fidelity::CacheOptions::checked(cache_dir.as_deref()).py()? }
        }
        None if cache_dir.is_some() => return Err(value_error("calibration_cache applies to tolerance_um only")),
        None => diffcassi::fidelity::TracerSource::Given(tracer(s.backend.as_str())?),
    };
    // The library's noise settings and checks (the CLI's `render --noise ...`).
    let noise = NoiseSettings {
        noise: extra(&s, "noise", "a string")?,
        full_well_e: extra(&s, "full_well_e", "a number")?,
        electrons_per_unit: extra(&s, "electrons_per_unit", "a number")?,
        read_noise_e: extra(&s, "read_noise_e", "a number")?,
        adc_bits: extra(&s, "adc_bits", "an integer ≥ 0")?,
        noise_seed: extra(&s, "noise_seed", crate::arrays::SEED)?,
    }
    .config()
    .py()?;
    let ws = f64_list("wavelengths_nm", wavelengths_nm)?;
    let cube = scene_cube(scene, ws)?;
    let (mut cfg, m) = configure(cube.height, cube.width, &s.options, mask)?;
    let render_settings = s.options.settings()?;
    let device = render_settings.device;
    let sys = Arc::clone(&system.inner);
    let threads = crate::pool::get_num_threads()?;
    // Ctrl-C stops the render at its next scene row (`run_cancellable`: the renderer polls the token).
    let (acq, info) = crate::pool::run_cancellable(py, move |cancel| -> diffcassi::Result<_> {
        let tracing = diffcassi::fidelity::RenderTracing::resolve(source, &sys, &render_settings, &mut cfg, &m)?;
        let r = Renderer::new(&sys, tracing.tracer.as_ref(), cfg, m)?.with_cancel(cancel.clone());
        // device="cuda": the GPU kernels (render::device), recorded in render.json's `device`.
        let (mut acq, record) = diffcassi::render::device::render_for(device, &r, &cube, false, &|_| {})?;
        // The CLI's noise and its warnings (an exposure below an electron, a zero acquisition): raised as
        // UserWarnings by diffcassi.render from info["warnings"] (Python was silent; round 9).
        let said = Warnings::default();
        let noise_json = diffcassi::render::folder::apply_noise(noise.as_ref(), &mut acq, &said)?;
        let mut warnings = said.0.into_inner().unwrap_or_else(|p| p.into_inner());
        warnings.extend(diffcassi::render::folder::zero_warning(&acq, &noise_json));
        let scale = render_output::preview_scale(&acq);
        let mut info = render_output::sidecar(&r, &acq, record.as_ref(), &scene_description(&cube), scale, t0.elapsed().as_secs_f64(), threads);
        info["noise"] = noise_json;
        // As render.json (`null` without a tolerance); the choice's explanation as the CLI prints it.
        info["tolerance_um"] = tracing.tolerance_um.into();
        info["tolerance_predicted_error_um"] = tracing.predicted_error_um.into();
        if let Some(x) = &tracing.explanation {
            info["fidelity_choice"] = crate::errors::pythonic(x).into();
        }
        // The CLI's notes (`render::folder::render_notes`: its warnings and render.json's fields).
        let (notes, fields) = diffcassi::render::folder::render_notes(&r, &cube, record.as_ref())?;
        warnings.extend(notes);
        for (k, v) in fields {
            info[k] = v;
        }
        if !warnings.is_empty() {
            info["warnings"] = warnings.iter().map(|w| crate::errors::pythonic(w)).collect::<Vec<_>>().into();
        }
        Ok((acq, info))
    })?;
    let (h, w) = (acq.detector.height, acq.detector.width);
    Ok((output(py, acq.image, &[h, w])?, info.to_string()))
}

/// A render's warnings, collected to be raised in Python.
#[derive(Default)]
struct Warnings(std::sync::Mutex<Vec<String>>);

impl diffcassi::render::folder::RenderProgress for Warnings {
    fn warning(&self, text: &str) {
        self.0.lock().unwrap_or_else(|p| p.into_inner()).push(text.to_string());
    }
}

/// The GPU's figures on one render (`diffcassi.gpu_check`): `render` on the CUDA device twice, on the CPU,
/// through the host twin (`twin`), and the middle plane's landings on both ([`diffcassi::render::device::check`]),
/// as JSON text. Needs a CUDA device (an error naming what is missing otherwise), except with `dry_run`: the host
/// twin stands in for the device ([`diffcassi::render::device::check_on`]; the report says `dry_run`).
#[pyfunction]
#[pyo3(signature = (system, scene, wavelengths_nm, twin = true, dry_run = false, **settings))]
fn _gpu_check<'py>(py: Python<'py>, system: &PySystem, scene: &Bound<'py, PyAny>, wavelengths_nm: &Bound<'py, PyAny>, twin: bool, dry_run: bool, settings: Option<&Bound<'py, PyDict>>) -> PyResult<String> {
    let s = crate::settings::settings(py, settings, &[])?;
    let ws = f64_list("wavelengths_nm", wavelengths_nm)?;
    let cube = scene_cube(scene, ws)?;
    let (cfg, m) = configure(cube.height, cube.width, &s.options, None)?;
    if !dry_run {
        if let Some(why) = diffcassi::render::Device::Cuda(0).unavailable() {
            return Err(value_error(format!("gpu_check: no CUDA device to check: {why}")));
        }
    }
    let executor = if dry_run { diffcassi::render::device::Executor::Twin } else { diffcassi::render::device::Executor::Cuda(0) };
    let t = tracer(s.backend.as_str())?;
    let sys = Arc::clone(&system.inner);
    let report = run(py, move || -> diffcassi::Result<_> {
        let r = Renderer::new(&sys, t.as_ref(), cfg, m)?;
        diffcassi::render::device::check_on(&r, &cube, twin, executor)
    })
    .py()?;
    serde_json::to_string(&report).map_err(|e| value_error(format!("gpu_check: {e}")))
}

/// The GPU kernels as one CUDA source (`diffcassi::gpu::ptx::amalgamated_source`): for `nvcc -ptx` on a GPU
/// machine whose driver refuses the embedded PTX (scripts/gpu_check.sh; the launcher reads `DIFFCASSI_PTX`).
#[pyfunction]
fn _gpu_kernel_source() -> String {
    diffcassi::gpu::ptx::amalgamated_source()
}

/// `render`'s own keywords: the noise's (the CLI's `--noise` options) and the tolerance's (`--tolerance-um`,
/// `--calibration-cache`).
const RENDER_EXTRA_KEYS: [&str; 8] = ["noise", "full_well_e", "electrons_per_unit", "read_noise_e", "adc_bits", "noise_seed", "tolerance_um", "calibration_cache"];

/// The exact operator together with the system and tracer it borrows, owned as one value.
pub struct OwnedExact {
    // Field order is drop order: `op` borrows the system and the tracer below and must go first.
    pub op: ExactOperator<'static>,
    _system: Arc<SequentialSystem>,
    _tracer: Box<dyn Tracer>,
}

impl Operator for OwnedExact {
    fn name(&self) -> &str {
        self.op.name()
    }
    fn cube_shape(&self) -> CubeShape {
        self.op.cube_shape()
    }
    fn image_shape(&self) -> ImageShape {
        self.op.image_shape()
    }
    fn apply_into(&self, cube: &[f32], image: &mut [f32]) {
        self.op.apply_into(cube, image)
    }
    fn adjoint_into(&self, image: &[f32], cube: &mut [f32]) {
        self.op.adjoint_into(image, cube)
    }
}

impl SparseExport for OwnedExact {
    fn to_csr(&self, memory_budget_bytes: u64) -> diffcassi::Result<CsrMatrix> {
        self.op.to_csr(memory_budget_bytes)
    }
}

/// Refuse a transport that would not fit the memory budget, before tracing it: the library's estimate from
/// the middle plane (`TransportMemory`, the one `reconstruct`'s exact operator and `render-dataset`'s cache
/// use), the footprints and the operator's compact copy that a Python `Transport` both keeps (2.48 GB
/// against the CLI's 1.46 GB at 512×512, docs/python.md).
fn check_transport_memory(r: &Renderer<'_>) -> diffcassi::Result<()> {
    let (memory, _probe) = diffcassi::recon::exact::TransportMemory::probe(r)?;
    memory.check_traced(r)
}

/// Trace the light transport of `system` with these settings once and keep it as the exact operator.
pub fn owned_exact(py: Python<'_>, system: &Arc<SequentialSystem>, cfg: RenderConfig, mask: Mask, backend: &str) -> PyResult<OwnedExact> {
    let tr = tracer(backend)?;
    let system = Arc::clone(system);
    // SAFETY: the system lives in an Arc and the tracer in a Box, both moved into the returned value and
    // never replaced; their heap addresses do not move when the value does, and `op`, which borrows
    // them, is declared first so it is dropped before them.
    let sys_ref: &'static SequentialSystem = unsafe { &*Arc::as_ptr(&system) };
    let tr_ref: &'static dyn Tracer = unsafe { &*(tr.as_ref() as *const dyn Tracer) };
    // Ctrl-C stops the trace at its next scene row (`run_cancellable`).
    let op = crate::pool::run_cancellable(py, move |cancel| -> diffcassi::Result<_> {
        let r = Renderer::new(sys_ref, tr_ref, cfg, mask)?.with_cancel(cancel.clone());
        check_transport_memory(&r)?;
        let t = r.trace_all(&|_| {})?;
        // `from_traced` keeps the renderer without the token (the transport's later `apply`s are not this call's).
        let bands = r.config.spectral.bands_nm.clone();
        ExactOperator::from_traced(r, &bands, t)
    })?;
    Ok(OwnedExact { op, _system: system, _tracer: tr })
}

/// The dataset-mode light transport of one system, configuration and mask, traced once: `apply(scene)`
/// renders a scene with it (bit-identical to `render` with the same settings), the fast path for
/// on-the-fly training data; `adjoint(image)` is the exact operator's adjoint.
#[pyclass(name = "Transport", module = "diffcassi", frozen)]
pub struct PyTransport {
    exact: Arc<OwnedExact>,
    system: Arc<SequentialSystem>,
    /// The last scene's buffer, reused by the next `apply` (see [`scene_cube_in`]).
    scratch: std::sync::Mutex<Vec<f32>>,
    /// How it was built, for pickling ([`crate::recipe`]).
    recipe: Arc<crate::recipe::Recipe>,
}

impl PyTransport {
    fn renderer(&self) -> &Renderer<'static> {
        self.exact.op.renderer()
    }
}

#[pymethods]
impl PyTransport {
    /// `settings`: the render keywords ([`crate::settings`]); `None` = the CLI's default.
    #[new]
    #[pyo3(signature = (system, height, width, mask = None, **settings))]
    fn new(py: Python<'_>, system: &PySystem, height: &Bound<'_, PyAny>, width: &Bound<'_, PyAny>, mask: Option<&Bound<'_, PyAny>>, settings: Option<&Bound<'_, PyDict>>) -> PyResult<Self> {
        let (height, width) = (size_arg("height", height)?, size_arg("width", width)?);
        let s = crate::settings::settings(py, settings, &[])?;
        // Host-only before configure: its device probe would blame a missing driver (round 12).
        crate::settings::host_only(&s.options, "Transport")?;
        let (cfg, m) = configure(height, width, &s.options, mask)?;
        let backend = s.backend.as_str();
        let recipe = crate::recipe::Recipe::render_settings(py, "Transport", system, height, width, mask.is_some().then_some(&m), settings)?;
        let exact = owned_exact(py, &system.inner, cfg, m, backend)?;
        Ok(PyTransport { exact: Arc::new(exact), system: Arc::clone(&system.inner), scratch: Default::default(), recipe })
    }

    /// Pickling, `copy.copy` and `copy.deepcopy` (a dataset holding a transport, sent to spawn/forkserver
    /// DataLoader workers): rebuilt by `Transport(...)` with the same arguments — traced again, the same numbers
    /// bit for bit ([`crate::recipe`]).
    fn __reduce__<'py>(&self, py: Python<'py>) -> PyResult<(Bound<'py, PyAny>, (&'static str, Py<pyo3::types::PyTuple>, Py<PyDict>, Option<Vec<f64>>))> {
        self.recipe.reduce(py)
    }

    /// Render `scene` ((H, W, B) float32; bands at `wavelengths_nm`, default the transport's bands):
    /// the acquisition (h, w) float64, bit-identical to `render` with the same settings.
    #[pyo3(signature = (scene, wavelengths_nm = None))]
    fn apply<'py>(&self, py: Python<'py>, scene: &Bound<'py, PyAny>, wavelengths_nm: Option<&Bound<'py, PyAny>>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let ws = match wavelengths_nm {
            Some(w) => f64_list("wavelengths_nm", w)?,
            None => self.renderer().config.spectral.bands_nm.clone(),
        };
        let buffer = std::mem::take(&mut *self.scratch.lock().unwrap_or_else(|p| p.into_inner()));
        let cube = scene_cube_in(scene, ws, buffer)?;
        let planes = self.exact.op.transport().ok_or_else(|| value_error("internal: transport not kept"))?;
        let acq = run(py, || self.renderer().render_cached(&cube, planes, false, &|_| {}));
        *self.scratch.lock().unwrap_or_else(|p| p.into_inner()) = cube.data;
        let acq = acq.py()?;
        let (h, w) = (acq.detector.height, acq.detector.width);
        output(py, acq.image, &[h, w])
    }

    /// Seconds per `Renderer::render_cached` of `scene` (the call `apply` and the CLI's dataset mode make),
    /// `reps` times, timed inside Rust on a scene converted once (the overhead benchmark's reference).
    #[pyo3(signature = (scene, wavelengths_nm = None, reps = 1))]
    fn _time_render_cached(&self, py: Python<'_>, scene: &Bound<'_, PyAny>, wavelengths_nm: Option<&Bound<'_, PyAny>>, reps: usize) -> PyResult<Vec<f64>> {
        let ws = match wavelengths_nm {
            Some(w) => f64_list("wavelengths_nm", w)?,
            None => self.renderer().config.spectral.bands_nm.clone(),
        };
        let cube = scene_cube(scene, ws)?;
        let planes = self.exact.op.transport().ok_or_else(|| value_error("internal: transport not kept"))?;
        run(py, || {
            (0..reps)
                .map(|_| {
                    let t0 = Instant::now();
                    let acq = self.renderer().render_cached(&cube, planes, false, &|_| {})?;
                    let dt = t0.elapsed().as_secs_f64();
                    std::hint::black_box(acq);
                    Ok(dt)
                })
                .collect::<diffcassi::Result<Vec<f64>>>()
        })
        .py()
    }

    /// Φᵀ image: `image` (h, w) float32 or float64 (the detector is small; converted to float32) → the
    /// cube (H, W, B) float32 at the transport's bands (the exact operator's adjoint).
    fn adjoint<'py>(&self, py: Python<'py>, image: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
        let (h, w) = self.detector_shape();
        // Bounded as `Operator.adjoint`'s image (beyond ±MAX_SCENE_VALUE the f32 sums overflow to inf); a
        // float64 image before it is narrowed, so the message shows the value given.
        let img: Vec<f32> = match input::<f64>("image", image, "float64", 2, "(h, w)") {
            Ok(a) => {
                check_shape("image", &a.shape, &[h, w])?;
                check_bounded("image", a.slice(), &a.shape)?;
                a.slice().iter().map(|&v| v as f32).collect()
            }
            Err(_) => {
                let a = input::<f32>("image", image, "float32", 2, "(h, w)")?;
                check_shape("image", &a.shape, &[h, w])?;
                check_bounded("image", a.slice(), &a.shape)?;
                a.slice().to_vec()
            }
        };
        let c = self.exact.cube_shape();
        let mut cube = vec![0.0f32; c.len()];
        run(py, || self.exact.adjoint_into(&img, &mut cube));
        output(py, cube, &[c.height, c.width, c.bands])
    }

    /// The exact operator Φ of this transport (float32 cube (H, W, B) → image (h, w)), sharing its trace.
    #[getter]
    fn operator(&self, py: Python<'_>) -> crate::recon::PyOperator {
        crate::recon::PyOperator::new(self.exact.clone(), self.recipe.with_factory(py, "exact"))
    }

    /// (h, w) of the detector images.
    #[getter]
    fn detector_shape(&self) -> (usize, usize) {
        (self.renderer().detector.height, self.renderer().detector.width)
    }

    /// (H, W) of the scenes.
    #[getter]
    fn scene_shape(&self) -> (usize, usize) {
        (self.renderer().config.scene_height, self.renderer().config.scene_width)
    }

    /// Heap bytes of the traced transport.
    #[getter]
    fn nbytes(&self) -> usize {
        self.exact.op.transport_bytes()
    }

    /// The render bands (nm).
    #[getter]
    fn bands_nm(&self) -> Vec<f64> {
        self.renderer().config.spectral.bands_nm.clone()
    }

    /// The spectral planes (nm).
    #[getter]
    fn planes_nm(&self) -> Vec<f64> {
        self.renderer().config.spectral.planes_nm.clone()
    }

    /// The mask (H, W) float32.
    #[getter]
    fn mask<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
        let m = &self.renderer().mask;
        output(py, m.values.clone(), &[m.height, m.width])
    }

    /// The render configuration as JSON text.
    fn _config_json(&self) -> String {
        serde_json::to_string(&self.renderer().config).unwrap_or_default()
    }

    /// The detector as JSON text (width, height, pitch_mm, x_left_mm, y_top_mm; pixel (i, j)'s centre at
    /// x = x_left_mm + (j + 0.5)·pitch, y = y_top_mm − (i + 0.5)·pitch).
    fn _detector_json(&self) -> String {
        serde_json::to_string(&self.renderer().detector).unwrap_or_default()
    }

    fn __repr__(&self) -> String {
        let c = &self.renderer().config;
        format!(
            "Transport('{}', scene {}×{}, {} bands, {} planes, {} rays, detector {}×{}, {:.1} MB)",
            self.system.name(),
            c.scene_height,
            c.scene_width,
            c.spectral.bands_nm.len(),
            c.spectral.planes(),
            c.rays_per_pixel,
            self.renderer().detector.height,
            self.renderer().detector.width,
            self.nbytes() as f64 / 1e6
        )
    }
}

pub fn check_shape(name: &str, actual: &[usize], expected: &[usize]) -> PyResult<()> {
    if actual != expected {
        return Err(value_error(format!("{name}: expected shape {expected:?}, got {actual:?}")));
    }
    Ok(())
}

/// The channels of an EXR file: a list of (name, (H, W) float32 array) pairs in the file's order — `dict(read_exr(p))` for a mapping (to read the CLI's `acquisition.exr`, `cube.exr`).
#[pyfunction]
fn read_exr<'py>(py: Python<'py>, path: std::path::PathBuf) -> PyResult<Vec<(String, Bound<'py, PyArrayDyn<f32>>)>> {
    // Reading and decompressing the file: without the GIL (a large EXR takes a while; round 18's audit).
    let img = run(py, || diffcassi::io::exr::read_exr(&path)).map_err(|e| crate::errors::to_py(e.into()))?;
    img.channels.into_iter().map(|c| Ok((c.name, output(py, c.data, &[img.height, img.width])?))).collect()
}

/// A scene file (KAIST-style `.exr`, `.npy` (H, W, B) with `<stem>_wavelengths_nm.npy`, or a CAVE-style
/// folder of per-band PNGs) with the CLI's loaders: (cube (H, W, B) float32, wavelengths_nm).
#[pyfunction]
#[pyo3(signature = (path, wavelengths_nm = None))]
fn load_scene<'py>(py: Python<'py>, path: std::path::PathBuf, wavelengths_nm: Option<&Bound<'py, PyAny>>) -> PyResult<(Bound<'py, PyArrayDyn<f32>>, Vec<f64>)> {
    diffcassi::scene::check_present(&path).py()?;
    let ws = wavelengths_nm.map(|w| f64_list("wavelengths_nm", w)).transpose()?;
    check_scene_file_memory(&path, ws.as_ref().map(Vec::len))?;
    // The library's hint names the CLI's option (spelled `scene_wavelengths`); here it is this keyword.
    let cube = run(py, || diffcassi::scene::load_scene(&path, ws.as_deref())).map_err(|e| {
        let text = e.to_string().replace("--scene-wavelengths", "wavelengths_nm").replace("scene_wavelengths", "wavelengths_nm");
        match e {
            diffcassi::Error::File { .. } | diffcassi::Error::Io(_) => crate::errors::file_error(text),
            _ => value_error(text),
        }
    })?;
    let (h, w, b) = (cube.height, cube.width, cube.bands());
    Ok((output(py, cube.data, &[h, w, b])?, cube.wavelengths_nm))
}

/// Smits' RGB → reflectance uplift of an encoded sRGB image ((H, W, 3) float32 in [0, 1], e.g. an 8-bit PNG's
/// values / 255): the library's `scene::natural::rgb_scene`, the uplift `load_scene` applies to a `.png`
/// photograph (so `uplift_srgb(png / 255) == load_scene(png)` bit for bit). Values are linearised through the
/// library's 16-bit table (exact for 8- and 16-bit sources). Returns (H, W, B) float32 reflectances in
/// [0, 1] at `wavelengths_nm` (default 28 bands 450–650 nm, which must lie in 380–720 nm). Single-threaded.
#[pyfunction]
#[pyo3(signature = (srgb, wavelengths_nm = None))]
fn uplift_srgb<'py>(py: Python<'py>, srgb: &Bound<'py, PyAny>, wavelengths_nm: Option<&Bound<'py, PyAny>>) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
    let ws = match wavelengths_nm {
        Some(w) => f64_list("wavelengths_nm", w)?,
        None => diffcassi::analysis::linspace(450.0, 650.0, 28),
    };
    if ws.is_empty() || ws.len() > diffcassi::limits::MAX_WAVELENGTHS {
        return Err(value_error(format!("wavelengths_nm: {} values; give 1..={}", ws.len(), diffcassi::limits::MAX_WAVELENGTHS)));
    }
    let a: Input<f32> = input("srgb", srgb, "float32", 3, "(H, W, 3)")?;
    let (h, w, c) = (a.shape[0], a.shape[1], a.shape[2]);
    if c != 3 || h == 0 || w == 0 {
        return Err(value_error(format!("srgb: expected shape (H, W, 3) with H, W ≥ 1, got {:?}", a.shape)));
    }
    let values = a.slice();
    check_finite("srgb", values, &a.shape)?;
    if let Some(i) = values.iter().position(|v| !(0.0..=1.0).contains(v)) {
        let idx = [i / (3 * w), (i / 3) % w, i % 3];
        return Err(value_error(format!("srgb: value {} at index {idx:?} is outside [0, 1] (encoded sRGB; clip it first)", values[i])));
    }
    let image = diffcassi::scene::natural::RgbImage { height: h, width: w, srgb: values.to_vec() };
    let cube = run(py, || diffcassi::scene::natural::rgb_scene(&image, &ws)).py()?;
    output(py, cube.data, &[h, w, ws.len()])
}

/// The CLI's synthetic demo scene of `seed` ((H, W, B) float32 at `wavelengths_nm`, default the 31 bands
/// 400–700 nm the CLI uses): (cube, wavelengths_nm).
#[pyfunction]
#[pyo3(signature = (height, width, seed = None, wavelengths_nm = None))]
fn synthetic_scene<'py>(py: Python<'py>, height: &Bound<'py, PyAny>, width: &Bound<'py, PyAny>, seed: Option<&Bound<'py, PyAny>>, wavelengths_nm: Option<&Bound<'py, PyAny>>) -> PyResult<(Bound<'py, PyArrayDyn<f32>>, Vec<f64>)> {
    let (height, width) = (size_arg("height", height)?, size_arg("width", width)?);
    let seed = seed.map(|s| seed_arg("seed", s)).transpose()?.unwrap_or(0);
    let ws = match wavelengths_nm {
        Some(w) => f64_list("wavelengths_nm", w)?,
        None => diffcassi::scene::synthetic_wavelengths(),
    };
    if ws.is_empty() || ws.len() > diffcassi::limits::MAX_WAVELENGTHS {
        return Err(value_error(format!("wavelengths_nm: {} values; give 1..={}", ws.len(), diffcassi::limits::MAX_WAVELENGTHS)));
    }
    let (lo, hi) = diffcassi::limits::WAVELENGTH_RANGE_NM;
    if let Some(w) = ws.iter().find(|w| !(lo..=hi).contains(*w)) {
        return Err(value_error(format!("wavelengths_nm: {} nm is outside {lo}–{hi} nm", diffcassi::limits::fmt_num(*w))));
    }
    // Strictly increasing, as every reader of a scene requires (`[500, 400]` was accepted).
    diffcassi::scene::check_wavelengths(&ws, "wavelengths_nm").py()?;
    // The cube (4 bytes per entry), refused before it is allocated.
    let what = format!("height × width × wavelengths_nm ({height} × {width} × {})", ws.len());
    diffcassi::limits::check_memory(&what, 4.0 * height as f64 * width as f64 * ws.len() as f64).py()?;
    let cube = run(py, || diffcassi::scene::synthetic_scene(height, width, &ws, seed));
    let b = cube.bands();
    Ok((output(py, cube.data, &[height, width, b])?, cube.wavelengths_nm))
}

/// Refuse a scene file whose decoded cube would not fit the memory budget, from its header only: a `.png`
/// photograph's IHDR size (uplifted to `bands` bands, default 28; f32 cube plus the decoded RGBA and the
/// f64 working copy, ≈ 12 bytes per entry + 16 per pixel), a PNG folder's first band × its band count.
/// `.exr` and `.npy` files are checked by the library's readers themselves (a `.npy` from its header's
/// shape: the file plus 4 bytes per element; "4 × the file" missed integer cubes by 3×, round 17).
fn check_scene_file_memory(path: &std::path::Path, bands: Option<usize>) -> PyResult<()> {
    use std::io::Read;
    let ext = path.extension().and_then(|e| e.to_str()).map(|e| e.to_ascii_lowercase());
    let png_size = |p: &std::path::Path| -> Option<(f64, f64)> {
        let mut head = [0u8; 24];
        std::fs::File::open(p).ok()?.read_exact(&mut head).ok()?;
        (&head[..8] == b"\x89PNG\r\n\x1a\n" && &head[12..16] == b"IHDR").then(|| {
            let be = |b: &[u8]| u32::from_be_bytes([b[0], b[1], b[2], b[3]]) as f64;
            (be(&head[16..20]), be(&head[20..24]))
        })
    };
    let (bytes, what) = if path.is_dir() {
        let mut pngs = std::fs::read_dir(path).map(|d| d.filter_map(|e| e.ok().map(|e| e.path())).filter(|p| p.extension().and_then(|e| e.to_str()).is_some_and(|e| e.eq_ignore_ascii_case("png"))).collect::<Vec<_>>()).unwrap_or_default();
        pngs.sort();
        match pngs.first().and_then(|p| png_size(p)) {
            Some((w, h)) => (w * h * pngs.len() as f64 * 12.0, format!("{} ({w}×{h} pixels × {} bands)", path.display(), pngs.len())),
            None => return Ok(()),
        }
    } else if ext.as_deref() == Some("png") {
        match png_size(path) {
            Some((w, h)) => {
                let b = bands.unwrap_or(28) as f64;
                (w * h * (12.0 * b + 16.0), format!("{} ({w}×{h} pixels × {b} bands)", path.display()))
            }
            None => return Ok(()),
        }
    } else {
        return Ok(());
    };
    diffcassi::limits::check_memory(&what, bytes).py()
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(load_scene, m)?)?;
    m.add_function(wrap_pyfunction!(synthetic_scene, m)?)?;
    m.add_function(wrap_pyfunction!(uplift_srgb, m)?)?;
    m.add_function(wrap_pyfunction!(_render, m)?)?;
    m.add_function(wrap_pyfunction!(_gpu_check, m)?)?;
    m.add_function(wrap_pyfunction!(_gpu_kernel_source, m)?)?;
    m.add_function(wrap_pyfunction!(read_exr, m)?)?;
    m.add_class::<PyTransport>()?;
    Ok(())
}
