//! `System` and the traces and analyses on it: each delegates to the Rust API unchanged, so NumPy results
//! are the Rust results bit for bit.
use crate::arrays::{check_finite, f64_list, input, output, seed_arg, size_arg, Input};
use crate::errors::{file_error, value_error, IntoPy};
use crate::pool::run;
use diffcassi::analysis;
use diffcassi::diff::ParamSet;
use diffcassi::rays::RayBatch;
use diffcassi::system::SequentialSystem;
use diffcassi::tracer::{BackendConfig, RaySlices, Tracer, TracedBatch};
use numpy::{PyArray1, PyArray2, PyArrayDyn, PyArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::sync::Arc;
use std::time::Instant;

/// An optical system (built from a preset or a spec file), immutable and shareable between threads.
#[pyclass(name = "System", module = "diffcassi", frozen)]
pub struct PySystem {
    pub inner: Arc<SequentialSystem>,
    /// The content identities of the spec's glass catalogue files, `(entry, identity)`, taken when the system
    /// was built from them ([`SequentialSystem::catalog_identities`]): a copy (pickle, `copy`) carries them
    /// and is refused when a file changed since, instead of tracing the glasses it holds now.
    pub catalogs: Arc<Vec<(String, String)>>,
}

/// The tracer of a backend name (`analytic`, `embree-user[:f64|:none]`, `embree-mesh[:SAG_UM][:f64|:none]`).
pub fn tracer(name: &str) -> PyResult<Box<dyn Tracer>> {
    let cfg: BackendConfig = name.parse().py()?;
    if cfg.backend == diffcassi::tracer::Backend::AnalyticF32 {
        // These entry points (trace, spot, distortion, mapping) are compared to Zemax: f64 only.
        return Err(value_error(format!("backend `{name}`: the Python API traces in f64 (the f32 kernel is the renderer's --precision f32)")));
    }
    cfg.build().py()
}

fn points2(name: &str, obj: &Bound<'_, PyAny>) -> PyResult<Vec<[f64; 2]>> {
    let a = input::<f64>(name, obj, "float64", 2, "(N, 2)")?;
    if a.shape[1] != 2 {
        return Err(value_error(format!("{name}: expected shape (N, 2), got {:?}", a.shape)));
    }
    check_finite(name, a.slice(), &a.shape)?;
    Ok(a.slice().chunks_exact(2).map(|p| [p[0], p[1]]).collect())
}

fn pair(name: &str, v: &[f64]) -> PyResult<[f64; 2]> {
    match v {
        [x, y] if x.is_finite() && y.is_finite() => Ok([*x, *y]),
        _ => Err(value_error(format!("{name}: expected two finite numbers (x, y), got {v:?}"))),
    }
}

/// The borrowed, checked ray arrays: (N, 3) origins, (N, 3) directions and (N,) wavelengths (float64,
/// C-contiguous, the same N). Finiteness is not checked here (see [`ray_batch`]).
pub fn ray_arrays<'py>(origins: &Bound<'py, PyAny>, directions: &Bound<'py, PyAny>, wavelengths_nm: &Bound<'py, PyAny>) -> PyResult<(Input<'py, f64>, Input<'py, f64>, Input<'py, f64>)> {
    let o = input::<f64>("origins", origins, "float64", 2, "(N, 3)")?;
    let d = input::<f64>("directions", directions, "float64", 2, "(N, 3)")?;
    let w = input::<f64>("wavelengths_nm", wavelengths_nm, "float64", 1, "(N,)")?;
    let n = o.shape[0];
    if o.shape[1] != 3 || d.shape != [n, 3] || w.shape != [n] {
        return Err(value_error(format!(
            "rays: origins {:?}, directions {:?}, wavelengths_nm {:?}: expected (N, 3), (N, 3) and (N,) with the same N",
            o.shape, d.shape, w.shape
        )));
    }
    Ok((o, d, w))
}

/// A ray batch (owned columns) from (N, 3) origins, (N, 3) directions and (N,) wavelengths (float64,
/// C-contiguous), wavelengths checked finite.
pub fn ray_batch(origins: &Bound<'_, PyAny>, directions: &Bound<'_, PyAny>, wavelengths_nm: &Bound<'_, PyAny>) -> PyResult<RayBatch> {
    let (o, d, w) = ray_arrays(origins, directions, wavelengths_nm)?;
    check_finite("wavelengths_nm", w.slice(), &w.shape)?;
    let (os, ds) = (o.slice(), d.slice());
    let column = |v: &[f64], k: usize| -> Vec<f64> { v.chunks_exact(3).map(|p| p[k]).collect() };
    Ok(RayBatch {
        origin_x: column(os, 0),
        origin_y: column(os, 1),
        origin_z: column(os, 2),
        dir_x: column(ds, 0),
        dir_y: column(ds, 1),
        dir_z: column(ds, 2),
        wavelength_nm: w.slice().to_vec(),
    })
}

/// A ray batch interleaved as plain vectors: origins (3N, row-major (N, 3)), directions (3N) and wavelengths
/// (N). Computed without the GIL ([`run`]); [`rays_out`] wraps the vectors as NumPy arrays without a copy.
struct RayArrays {
    origins: Vec<f64>,
    directions: Vec<f64>,
    wavelengths_nm: Vec<f64>,
}

impl RayArrays {
    fn of(b: RayBatch) -> Self {
        let n = b.len();
        let mut origins = Vec::with_capacity(3 * n);
        let mut directions = Vec::with_capacity(3 * n);
        for i in 0..n {
            origins.extend_from_slice(&[b.origin_x[i], b.origin_y[i], b.origin_z[i]]);
            directions.extend_from_slice(&[b.dir_x[i], b.dir_y[i], b.dir_z[i]]);
        }
        RayArrays { origins, directions, wavelengths_nm: b.wavelength_nm }
    }
}

/// The rays as the tuple (origins (N, 3), directions (N, 3), wavelengths_nm (N,)) — the vectors handed to
/// NumPy as they are (no copy, so no work with the GIL held).
fn rays_out<'py>(py: Python<'py>, r: RayArrays) -> PyResult<(Bound<'py, PyArrayDyn<f64>>, Bound<'py, PyArrayDyn<f64>>, Bound<'py, PyArrayDyn<f64>>)> {
    let n = r.wavelengths_nm.len();
    Ok((output(py, r.origins, &[n, 3])?, output(py, r.directions, &[n, 3])?, output(py, r.wavelengths_nm, &[n])?))
}

/// A traced batch as plain vectors: positions and directions (3N, row-major (N, 3)) in the image-surface
/// frame, status codes and stopping surfaces (N). Computed without the GIL; [`traced_out`] wraps them.
pub struct TracedArrays {
    positions: Vec<f64>,
    directions: Vec<f64>,
    status: Vec<u8>,
    surface: Vec<u32>,
}

impl TracedArrays {
    pub fn of(t: TracedBatch) -> Self {
        let n = t.len();
        let interleave = |a: &[f64], b: &[f64], c: &[f64]| -> Vec<f64> {
            let mut v = vec![0.0; 3 * n];
            for (((o, x), y), z) in v.chunks_exact_mut(3).zip(a).zip(b).zip(c) {
                o.copy_from_slice(&[*x, *y, *z]);
            }
            v
        };
        TracedArrays {
            positions: interleave(&t.x, &t.y, &t.z),
            directions: interleave(&t.dir_x, &t.dir_y, &t.dir_z),
            status: t.status.iter().map(|s| *s as u8).collect(),
            surface: t.surface,
        }
    }
}

/// A traced batch as a dict: positions (N, 3) mm and directions (N, 3) in the image-surface frame, status
/// (N,) uint8 (0 = ok; `diffcassi.STATUS` names the codes), surface (N,) uint32 (where a ray stopped).
pub fn traced_out<'py>(py: Python<'py>, t: TracedArrays) -> PyResult<Bound<'py, PyDict>> {
    let n = t.status.len();
    let dict = PyDict::new(py);
    dict.set_item("positions", output(py, t.positions, &[n, 3])?)?;
    dict.set_item("directions", output(py, t.directions, &[n, 3])?)?;
    dict.set_item("status", output(py, t.status, &[n])?)?;
    dict.set_item("surface", output(py, t.surface, &[n])?)?;
    Ok(dict)
}

/// Distortion points per JSON chunk: `diffcassi.distortion` parses the chunks one by one in a Python loop, where
/// CPython's switch interval hands the GIL to a waiting thread between two chunks.
const POINTS_PER_YIELD: usize = 2048;

fn json(v: &impl serde::Serialize) -> PyResult<String> {
    json_text(v).py()
}

/// [`json`] for use without the GIL (inside [`run`]).
fn json_text(v: &impl serde::Serialize) -> diffcassi::Result<String> {
    serde_json::to_string(v).map_err(|e| diffcassi::Error::invalid(format!("internal: JSON encoding failed: {e}")))
}

impl PySystem {
    fn wrap(s: SequentialSystem, catalogs: Vec<(String, String)>) -> Self {
        PySystem { inner: Arc::new(s), catalogs: Arc::new(catalogs) }
    }

    /// Another Python object of this same system (shared: it is immutable), with its catalogue identities.
    pub fn share(&self) -> Self {
        PySystem { inner: Arc::clone(&self.inner), catalogs: Arc::clone(&self.catalogs) }
    }

    /// Build `spec` (without the GIL), its catalogue files' identities taken first
    /// ([`SequentialSystem::catalog_identities`]: before the files are read for the build).
    fn build_recorded(spec: &diffcassi::spec::SystemSpec) -> diffcassi::Result<(SequentialSystem, Vec<(String, String)>)> {
        Self::build_recorded_from(spec, diffcassi::system::SystemOrigin::Spec)
    }

    /// [`Self::build_recorded`] for a spec read from a file of `origin`: a `.zmx` system's errors, at the
    /// build and later (a `trace` wavelength outside a glass's range), name the file's own fixes
    /// ([`diffcassi::system::SystemOrigin`]).
    fn build_recorded_from(spec: &diffcassi::spec::SystemSpec, origin: diffcassi::system::SystemOrigin) -> diffcassi::Result<(SequentialSystem, Vec<(String, String)>)> {
        let catalogs = SequentialSystem::catalog_identities(spec);
        Ok((SequentialSystem::build_from(spec, origin)?, catalogs))
    }

    /// [`Self::wrap`], raising each of the system's load-time warnings ([`SequentialSystem::warnings`]: glasses
    /// whose catalogue contradicts itself, semi-diameters beyond a surface's edge) as a `UserWarning`, as the
    /// CLI prints them. Unpickling and copying (`from_string` on the spec's text) warn as any load does; Python's
    /// default filter shows a warning once per place that raised it, so a training loop's copies do not repeat it.
    fn wrap_warned(py: Python<'_>, (s, catalogs): (SequentialSystem, Vec<(String, String)>)) -> PyResult<Self> {
        for w in s.warnings() {
            let text = std::ffi::CString::new(crate::errors::pythonic(&w)).unwrap_or_default();
            PyErr::warn(py, &py.get_type::<pyo3::exceptions::PyUserWarning>(), &text, 1)?;
        }
        Ok(Self::wrap(s, catalogs))
    }
}

impl PySystem {
    /// One field point in the system's own unit from exactly one of `field_mm` (a finite object) and
    /// `field_deg` (an object at infinity), as `rays_for_field`, `spot` and `dispersion` take it: a height in mm
    /// where the object is at infinity (read as radians before: a held-out battery) is refused, naming it.
    fn field_of(&self, field_mm: Option<&[f64]>, field_deg: Option<&[f64]>, mm: &str, deg: &str) -> PyResult<[f64; 2]> {
        use diffcassi::system::FieldUnit;
        match (field_mm, field_deg) {
            (Some(f), None) => self.inner.field_point(pair(mm, f)?, FieldUnit::Mm, mm).py(),
            (None, Some(f)) => self.inner.field_point(pair(deg, f)?, FieldUnit::Deg, deg).py(),
            _ => Err(crate::errors::value_error(format!("give exactly one of {mm} (finite objects) and {deg} (objects at infinity)"))),
        }
    }
}

#[pymethods]
impl PySystem {
    /// One of the presets: `sp`, `ap`, `msp`, `map`, `gsp` (case-insensitive).
    #[staticmethod]
    fn preset(py: Python<'_>, name: &str) -> PyResult<Self> {
        let name = name.to_string();
        let s = run(py, move || Self::build_recorded(&diffcassi::presets::spec(&name)?)).py()?;
        Self::wrap_warned(py, s)
    }

    /// A spec file, by extension: `.toml`, `.json`, `.yml`/`.yaml` (the paper's format), `.csv` (Zemax).
    #[staticmethod]
    fn from_file(py: Python<'_>, path: std::path::PathBuf) -> PyResult<Self> {
        if path.is_dir() {
            return Err(file_error(format!("{}: is a directory, not a system file", path.display())));
        }
        // Only a missing path is "no such file"; a named pipe (FIFO) or a device (/dev/zero, /dev/null) is named
        // as such by the reader's own input check (diffcassi::io::input), which refuses it before reading.
        if std::fs::metadata(&path).is_err() {
            return Err(file_error(format!("{}: no such file", path.display())));
        }
        let origin = diffcassi::system::SystemOrigin::of_path(&path);
        let s = run(py, move || Self::build_recorded_from(&diffcassi::spec::load_spec_file(&path)?, origin)).py()?;
        Self::wrap_warned(py, s)
    }

    /// A TOML or JSON spec held in a string (`format`: `toml`, `json`).
    #[staticmethod]
    #[pyo3(signature = (text, format = "toml"))]
    fn from_string(py: Python<'_>, text: &str, format: &str) -> PyResult<Self> {
        let spec = match format {
            "toml" => diffcassi::spec::from_toml(text, "<string>"),
            "json" => diffcassi::spec::from_json(text, "<string>"),
            other => return Err(value_error(format!("format `{other}`: use toml or json"))),
        }
        .py()?;
        let s = run(py, move || Self::build_recorded(&spec)).py()?;
        Self::wrap_warned(py, s)
    }

    /// The rebuild of a copy (`__reduce__`): the spec as JSON and the catalogue identities recorded when the
    /// original was built. Each catalogue file is checked against its identity first (a file edited since is
    /// refused, naming it: the copy would trace other glasses with the same prescription); the copy keeps
    /// the recorded identities, so a copy of a copy checks against the original's files.
    #[staticmethod]
    fn _from_copy(py: Python<'_>, text: &str, catalogs: Vec<(String, String)>) -> PyResult<Self> {
        let spec = diffcassi::spec::from_json(text, "<copy>").py()?;
        let s = run(py, move || -> diffcassi::Result<_> {
            SequentialSystem::check_catalog_identities(&catalogs)?;
            Ok((SequentialSystem::build(&spec)?, catalogs))
        })
        .py()?;
        Self::wrap_warned(py, s)
    }

    /// The system's load-time warnings (raised as `UserWarning`s when it was made): glasses whose catalogue
    /// contradicts itself, semi-diameters beyond a surface's edge. Empty for a spec as its author meant it.
    #[getter]
    fn warnings(&self) -> Vec<String> {
        self.inner.warnings().iter().map(|w| crate::errors::pythonic(w)).collect()
    }

    #[getter]
    fn name(&self) -> String {
        self.inner.name().to_string()
    }

    #[getter]
    fn description(&self) -> String {
        self.inner.spec.description.clone()
    }

    /// The system's wavelengths (nm), primary first as in the spec.
    #[getter]
    fn wavelengths_nm(&self) -> Vec<f64> {
        self.inner.spec.wavelengths_nm.clone()
    }

    #[getter]
    fn primary_wavelength_nm(&self) -> f64 {
        self.inner.primary_wavelength_nm()
    }

    /// The spec's field points (x, y) mm of object height (or image height, by `field_type`).
    #[getter]
    fn fields_mm(&self) -> Vec<[f64; 2]> {
        self.inner.spec.fields_mm.clone()
    }

    /// The spec's field angles (x, y) in degrees (`field_type` "angle"; empty otherwise).
    #[getter]
    fn fields_deg(&self) -> Vec<[f64; 2]> {
        self.inner.spec.fields_deg.clone()
    }

    /// The spec's vignetting factors, one `[VDX, VDY, VCX, VCY]` per field (empty: none).
    #[getter]
    fn vignetting_factors(&self) -> Vec<[f64; 4]> {
        self.inner.spec.vignetting_factors.clone()
    }

    /// The spec's field type: "object_height", "angle", "paraxial_image_height" or "real_image_height".
    #[getter]
    fn field_type(&self) -> String {
        serde_json::to_value(self.inner.spec.field_type).ok().and_then(|v| v.as_str().map(str::to_string)).unwrap_or_default()
    }

    /// Whether the object is at infinity (fields are angles; rays start on surface 1's vertex plane).
    #[getter]
    fn object_at_infinity(&self) -> bool {
        self.inner.object_at_infinity()
    }

    /// First-order data at the primary wavelength as a dict: efl_mm, bfl_mm, enp_from_surface1_mm,
    /// enp_diameter_mm, exp_from_last_surface_mm, exp_from_image_mm, chief_image_height_per_field. A value that
    /// is not finite is None: an afocal system (a flat grating) has efl_mm None (its EFL is infinite), never
    /// -inf; its BFL and exit pupil may be None too.
    fn first_order(&self) -> std::collections::BTreeMap<String, Option<f64>> {
        let f = &self.inner.first_order;
        [
            ("efl_mm", f.efl_mm),
            ("bfl_mm", f.bfl_mm),
            ("enp_from_surface1_mm", f.enp_from_surface1_mm),
            ("enp_diameter_mm", f.enp_diameter_mm),
            ("exp_from_last_surface_mm", f.exp_from_last_surface_mm),
            ("exp_from_image_mm", f.exp_from_image_mm),
            ("chief_image_height_per_field", f.chief_image_height_per_field),
        ]
        .into_iter()
        .map(|(k, v)| (k.to_string(), v.is_finite().then_some(v)))
        .collect()
    }

    #[getter]
    fn stop_index(&self) -> usize {
        self.inner.stop_index
    }

    /// The resolved Lens Data Editor as JSON (one object per surface; `diffcassi.System.surfaces` parses it).
    fn _surfaces_json(&self) -> PyResult<String> {
        let rows: Vec<serde_json::Value> = self
            .inner
            .surfaces
            .iter()
            .zip(&self.inner.spec.surfaces)
            .map(|(r, s)| {
                let cell = |c: &Option<diffcassi::spec::Cell>| c.as_ref().map(|c| c.value);
                serde_json::json!({
                    "index": r.index,
                    "kind": r.kind.label(),
                    "comment": r.comment,
                    "is_stop": r.is_stop,
                    "material": s.material,
                    "radius_mm": cell(&s.radius_mm),
                    "thickness_mm": r.thickness_mm,
                    "conic": cell(&s.conic),
                    "semi_diameter_mm": r.semi_diameter_mm,
                    "decenter_x_mm": cell(&s.decenter_x_mm),
                    "decenter_y_mm": cell(&s.decenter_y_mm),
                    "tilt_x_deg": cell(&s.tilt_x_deg),
                    "tilt_y_deg": cell(&s.tilt_y_deg),
                    "tilt_z_deg": cell(&s.tilt_z_deg),
                    "vertex_global_mm": r.frame.origin.to_array(),
                })
            })
            .collect();
        json(&rows)
    }

    /// The spec as TOML (loads back with `System.from_string`).
    fn to_toml(&self) -> PyResult<String> {
        diffcassi::spec::to_toml(&self.inner.spec).py()
    }

    fn to_json(&self) -> PyResult<String> {
        diffcassi::spec::to_json(&self.inner.spec).py()
    }

    /// SHA-256 (hex) of the system's prescription (`diffcassi::spec::system_sha256`: solved and picked-up
    /// values left out, other floats to 12 significant digits): the identity learned weights record.
    fn prescription_sha256(&self) -> PyResult<String> {
        diffcassi::spec::system_sha256(&self.inner.spec).py()
    }

    fn __repr__(&self) -> String {
        format!("System('{}', {} surfaces)", self.inner.name(), self.inner.surfaces.len())
    }

    /// Pickling, `copy.copy` and `copy.deepcopy` (a model holding a system, snapshotted for EMA or the best
    /// checkpoint): rebuilt by `System._from_copy` from the spec as JSON, whose floats read back bit-identical
    /// (`to_json`), and the content identities of its glass catalogue files taken when it was built — the
    /// rebuild reads the files again, and refuses one whose content changed since, so the copy traces the
    /// original's numbers or none. (Pickles made before carried no identities: `System.from_string(text,
    /// "json")`, which still loads them.)
    fn __reduce__<'py>(&self, py: Python<'py>) -> PyResult<(Bound<'py, PyAny>, (String, Vec<(String, String)>))> {
        let rebuild = py.get_type::<PySystem>().getattr("_from_copy")?;
        Ok((rebuild, (diffcassi::spec::to_json(&self.inner.spec).py()?, self.catalogs.as_ref().clone())))
    }

    /// The rays of one field through normalised pupil points: (origins (N, 3), directions (N, 3),
    /// wavelengths_nm (N,)), float64, object frame. `pupil` is an (N, 2) float64 array or a pattern
    /// (`chief`, `marginal`, `hexapolar:RINGS`, `grid:N`, `random:N:SEED`).
    /// For an object at infinity give `field_deg` (angles, degrees) instead of `field_mm`.
    /// `apply_vignetting` (default true): a defined field's pupil points are mapped by its vignetting factors
    /// (`vignetting_factors`, OpticStudio's VDX, VDY, VCX, VCY) as `trace` and `spot` do; false traces the
    /// whole pupil.
    #[pyo3(signature = (field_mm, wavelength_nm, pupil = None, field_deg = None, apply_vignetting = true))]
    fn rays_for_field<'py>(
        &self,
        py: Python<'py>,
        field_mm: Option<Vec<f64>>,
        wavelength_nm: &Bound<'py, PyAny>,
        pupil: Option<&Bound<'py, PyAny>>,
        field_deg: Option<Vec<f64>>,
        apply_vignetting: bool,
    ) -> PyResult<(Bound<'py, PyArrayDyn<f64>>, Bound<'py, PyArrayDyn<f64>>, Bound<'py, PyArrayDyn<f64>>)> {
        let wavelength_nm = crate::arrays::real_arg("wavelength_nm", wavelength_nm)?;
        let pupil = pupil_arg(pupil)?;
        let field = self.field_of(field_mm.as_deref(), field_deg.as_deref(), "field_mm", "field_deg")?;
        let sys = Arc::clone(&self.inner);
        // The pupil points (a `random:N` pattern draws them), the rays and their interleaving: without the GIL.
        let rays = run(py, move || -> diffcassi::Result<_> {
            let pts = pupil.points();
            let pts = if apply_vignetting { sys.vignetted_pupil(field, &pts) } else { pts };
            Ok(RayArrays::of(RayBatch::for_field(&sys, field, &pts, wavelength_nm)?))
        })
        .py()?;
        rays_out(py, rays)
    }

    /// Chief rays of the (N, 2) float64 field points at one wavelength: `fields_mm` (object heights, a finite
    /// object) or `fields_deg` (field angles, an object at infinity; give `fields_mm=None`).
    #[pyo3(signature = (fields_mm, wavelength_nm, fields_deg = None))]
    fn chief_rays<'py>(
        &self,
        py: Python<'py>,
        fields_mm: Option<&Bound<'py, PyAny>>,
        wavelength_nm: &Bound<'py, PyAny>,
        fields_deg: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<(Bound<'py, PyArrayDyn<f64>>, Bound<'py, PyArrayDyn<f64>>, Bound<'py, PyArrayDyn<f64>>)> {
        let wavelength_nm = crate::arrays::real_arg("wavelength_nm", wavelength_nm)?;
        use diffcassi::system::FieldUnit;
        let (mm, deg) = (fields_mm.map(|f| points2("fields_mm", f)).transpose()?, fields_deg.map(|f| points2("fields_deg", f)).transpose()?);
        let (points, unit, name) = match (mm, deg) {
            (Some(p), None) => (p, FieldUnit::Mm, "fields_mm"),
            (None, Some(p)) => (p, FieldUnit::Deg, "fields_deg"),
            _ => return Err(value_error("give exactly one of fields_mm (finite objects) and fields_deg (objects at infinity)")),
        };
        let sys = Arc::clone(&self.inner);
        // Each point checked in the system's field unit (`field_point`, as `field_of`), then the rays: without the GIL.
        let rays = run(py, move || -> diffcassi::Result<_> {
            let f = points.iter().map(|q| sys.field_point(*q, unit, name)).collect::<diffcassi::Result<Vec<_>>>()?;
            Ok(RayArrays::of(RayBatch::chief_rays(&sys, &f, wavelength_nm)?))
        })
        .py()?;
        rays_out(py, rays)
    }

    /// `n` seeded random rays per wavelength over the fields and the pupil (the benchmarks' workload).
    fn seeded_rays<'py>(
        &self,
        py: Python<'py>,
        rays_per_wavelength: &Bound<'py, PyAny>,
        wavelengths_nm: &Bound<'py, PyAny>,
        seed: &Bound<'py, PyAny>,
    ) -> PyResult<(Bound<'py, PyArrayDyn<f64>>, Bound<'py, PyArrayDyn<f64>>, Bound<'py, PyArrayDyn<f64>>)> {
        let (rays_per_wavelength, seed) = (size_arg("rays_per_wavelength", rays_per_wavelength)?, seed_arg("seed", seed)?);
        let ws = f64_list("wavelengths_nm", wavelengths_nm)?;
        let what = format!("rays_per_wavelength × wavelengths_nm ({rays_per_wavelength} × {})", ws.len());
        let n = rays_per_wavelength as f64 * ws.len() as f64;
        diffcassi::limits::check_traced_rays(&what, &what, n).py()?;
        let sys = Arc::clone(&self.inner);
        let rays = run(py, move || RayBatch::seeded_workload(&sys, rays_per_wavelength, &ws, seed).map(RayArrays::of)).py()?;
        rays_out(py, rays)
    }
}

/// A `pupil` argument: a pattern (its points drawn later, without the GIL: `random:N` makes N of them) or
/// (N, 2) points given, checked in the unit disc.
enum Pupil {
    Pattern(diffcassi::rays::PupilPattern),
    Points(Vec<[f64; 2]>),
}

impl Pupil {
    fn points(self) -> Vec<[f64; 2]> {
        match self {
            Pupil::Pattern(p) => p.points(),
            Pupil::Points(v) => v,
        }
    }
}

fn pupil_arg(pupil: Option<&Bound<'_, PyAny>>) -> PyResult<Pupil> {
    match pupil {
        None => Ok(Pupil::Pattern("hexapolar:12".parse::<diffcassi::rays::PupilPattern>().py()?)),
        Some(p) => match p.extract::<String>() {
            Ok(text) => Ok(Pupil::Pattern(text.parse::<diffcassi::rays::PupilPattern>().py()?)),
            Err(_) => {
                let pts = points2("pupil", p)?;
                if let Some((i, q)) = diffcassi::analysis::first_point_outside_pupil(&pts) {
                    return Err(value_error(format!("pupil row {i} (px, py) = ({}, {}): normalised pupil coordinates must satisfy px² + py² ≤ 1", q[0], q[1])));
                }
                Ok(Pupil::Points(pts))
            }
        },
    }
}

/// Trace rays through `system`: dict of positions (N, 3), directions (N, 3), status (N,) uint8, surface (N,).
#[pyfunction]
#[pyo3(signature = (system, origins, directions, wavelengths_nm, backend = "analytic"))]
fn trace<'py>(py: Python<'py>, system: &PySystem, origins: &Bound<'py, PyAny>, directions: &Bound<'py, PyAny>, wavelengths_nm: &Bound<'py, PyAny>, backend: &str) -> PyResult<Bound<'py, PyDict>> {
    let (o, d, w) = ray_arrays(origins, directions, wavelengths_nm)?;
    let n = w.shape[0];
    let t = tracer(backend)?;
    // The CLI's budgets of a trace (`diffcassi trace`/`spot`), before the outputs are allocated (round 21: 18 000
    // rays were traced under max_rays=1000).
    diffcassi::limits::check_traced_rays(&format!("trace of N = {n} rays"), "the rays", n as f64).py()?;
    let sys = Arc::clone(&system.inner);
    // The outputs are allocated by NumPy (zeroed lazily by the OS: first touched by the threads that fill them).
    let positions = PyArray2::<f64>::zeros(py, [n, 3], false);
    let directions_out = PyArray2::<f64>::zeros(py, [n, 3], false);
    let status = PyArray1::<u8>::zeros(py, n, false);
    let surface = PyArray1::<u32>::zeros(py, n, false);
    {
        let (mut p, mut dd, mut st, mut sf) = (positions.readwrite(), directions_out.readwrite(), status.readwrite(), surface.readwrite());
        let out = TraceOut {
            positions: p.as_slice_mut().map_err(|e| value_error(format!("internal: {e}")))?,
            directions: dd.as_slice_mut().map_err(|e| value_error(format!("internal: {e}")))?,
            status: st.as_slice_mut().map_err(|e| value_error(format!("internal: {e}")))?,
            surface: sf.as_slice_mut().map_err(|e| value_error(format!("internal: {e}")))?,
        };
        let (os, ds, ws) = (o.slice(), d.slice(), w.slice());
        run(py, move || trace_interleaved(t.as_ref(), &sys, os, ds, ws, out)).py()?;
    }
    let dict = PyDict::new(py);
    dict.set_item("positions", positions)?;
    dict.set_item("directions", directions_out)?;
    dict.set_item("status", status)?;
    dict.set_item("surface", surface)?;
    Ok(dict)
}

/// Where [`trace_interleaved`] writes: positions and directions (N, 3) row-major, status and surface (N,).
struct TraceOut<'a> {
    positions: &'a mut [f64],
    directions: &'a mut [f64],
    status: &'a mut [u8],
    surface: &'a mut [u32],
}

/// Rays per block of [`trace_interleaved`] (fixed; results are per ray, so they do not depend on it).
const TRACE_BLOCK: usize = 16 * 1024;

/// Trace rays given as (N, 3) row-major origins and directions straight into (N, 3) outputs: blocks of
/// [`TRACE_BLOCK`] rays, in parallel, each transposed into small column buffers (cache-resident),
/// traced through [`Tracer::trace_slices`] and interleaved into its slice of the outputs — no N-sized
/// temporary. Runs without the GIL. Errors (a wavelength outside a glass's range) are the first block's
/// in block order, so the message does not depend on the thread count.
fn trace_interleaved(t: &dyn Tracer, sys: &SequentialSystem, origins: &[f64], dirs: &[f64], wavelengths_nm: &[f64], out: TraceOut<'_>) -> diffcassi::Result<()> {
    use rayon::prelude::*;
    if let Some(i) = wavelengths_nm.iter().position(|v| !v.is_finite()) {
        return Err(diffcassi::Error::invalid(format!("wavelengths_nm: value {} at index [{i}] is not finite", wavelengths_nm[i])));
    }
    let results: Vec<diffcassi::Result<()>> = out
        .positions
        .par_chunks_mut(3 * TRACE_BLOCK)
        .zip(out.directions.par_chunks_mut(3 * TRACE_BLOCK))
        .zip(out.status.par_chunks_mut(TRACE_BLOCK))
        .zip(out.surface.par_chunks_mut(TRACE_BLOCK))
        .enumerate()
        .map_init(
            || vec![Vec::<f64>::with_capacity(TRACE_BLOCK); 6],
            |cols, (blk, (((pos, dir), st), sf))| {
                let (a, m) = (blk * TRACE_BLOCK, st.len());
                let (o, d) = (&origins[3 * a..3 * (a + m)], &dirs[3 * a..3 * (a + m)]);
                for (k, c) in cols.iter_mut().enumerate() {
                    let src = if k < 3 { o } else { d };
                    c.clear();
                    c.extend(src.chunks_exact(3).map(|p| p[k % 3]));
                }
                let rays = RaySlices::new(&cols[0], &cols[1], &cols[2], &cols[3], &cols[4], &cols[5], &wavelengths_nm[a..a + m])?;
                let tb = t.trace_slices(sys, rays)?;
                for (i, (p, dd)) in pos.chunks_exact_mut(3).zip(dir.chunks_exact_mut(3)).enumerate() {
                    p.copy_from_slice(&[tb.x[i], tb.y[i], tb.z[i]]);
                    dd.copy_from_slice(&[tb.dir_x[i], tb.dir_y[i], tb.dir_z[i]]);
                }
                for (s, v) in st.iter_mut().zip(&tb.status) {
                    *s = *v as u8;
                }
                sf.copy_from_slice(&tb.surface);
                Ok(())
            },
        )
        .collect();
    results.into_iter().collect()
}

/// Seconds per trace of the rays, `reps` times, timed inside Rust (the overhead benchmark's references for
/// `trace` called from Python): `Tracer::trace` on an owned `RayBatch` (the library's API), or with
/// `blocked`, the very function `trace` runs (`trace_interleaved`) writing into Rust vectors — the
/// difference to `trace` from Python is then the binding alone (argument checks, NumPy allocation, dict).
#[pyfunction]
#[pyo3(signature = (system, origins, directions, wavelengths_nm, reps = 3, backend = "analytic", blocked = false))]
#[allow(clippy::too_many_arguments)]
fn _time_rust_trace(
    py: Python<'_>,
    system: &PySystem,
    origins: &Bound<'_, PyAny>,
    directions: &Bound<'_, PyAny>,
    wavelengths_nm: &Bound<'_, PyAny>,
    reps: usize,
    backend: &str,
    blocked: bool,
) -> PyResult<Vec<f64>> {
    let t = tracer(backend)?;
    let sys = Arc::clone(&system.inner);
    if blocked {
        let (o, d, w) = ray_arrays(origins, directions, wavelengths_nm)?;
        let (os, ds, ws) = (o.slice(), d.slice(), w.slice());
        let n = ws.len();
        return run(py, move || {
            let mut times = Vec::new();
            for _ in 0..reps {
                let t0 = Instant::now();
                let (mut p, mut dd, mut st, mut sf) = (vec![0.0f64; 3 * n], vec![0.0f64; 3 * n], vec![0u8; n], vec![0u32; n]);
                trace_interleaved(t.as_ref(), &sys, os, ds, ws, TraceOut { positions: &mut p, directions: &mut dd, status: &mut st, surface: &mut sf })?;
                times.push(t0.elapsed().as_secs_f64());
                std::hint::black_box((p, dd, st, sf));
            }
            Ok(times)
        })
        .py();
    }
    let rays = ray_batch(origins, directions, wavelengths_nm)?;
    run(py, move || {
        let mut times = Vec::new();
        for _ in 0..reps {
            let t0 = Instant::now();
            let out = t.trace(&sys, &rays)?;
            times.push(t0.elapsed().as_secs_f64());
            std::hint::black_box(out);
        }
        Ok(times)
    })
    .py()
}

/// The per-ray parts of a spot diagram, as NumPy arrays and a list: pupil (N, 2), x_mm (N,), y_mm (N,),
/// status (N statuses by name, `Ok`, `Vignetted`, …).
type SpotRays<'py> = (Bound<'py, PyArrayDyn<f64>>, Bound<'py, PyArrayDyn<f64>>, Bound<'py, PyArrayDyn<f64>>, Bound<'py, pyo3::types::PyList>);

/// Spot diagram of one field and wavelength: (the diagram as JSON with its per-ray vectors left empty, the
/// per-ray parts); `diffcassi.spot` parses the one and puts the other in. Everything but wrapping the
/// vectors runs without the GIL — the pupil's points, the trace, the JSON — so that a large spot (a
/// million rays) does not stall the caller's other Python threads (a JSON of the rays parsed in Python
/// held the GIL for seconds: a held-out battery, round 18).
#[pyfunction]
#[pyo3(signature = (system, field_mm, wavelength_nm, pupil = None, backend = "analytic", field_deg = None))]
fn _spot<'py>(
    py: Python<'py>,
    system: &PySystem,
    field_mm: Option<Vec<f64>>,
    wavelength_nm: f64,
    pupil: Option<&Bound<'py, PyAny>>,
    backend: &str,
    field_deg: Option<Vec<f64>>,
) -> PyResult<(String, SpotRays<'py>)> {
    let pupil = pupil_arg(pupil)?;
    let f = system.field_of(field_mm.as_deref(), field_deg.as_deref(), "field_mm", "field_deg")?;
    let t = tracer(backend)?;
    let sys = Arc::clone(&system.inner);
    let (text, pupil, x, y, status) = run(py, move || -> diffcassi::Result<_> {
        let mut s = analysis::spot_diagram(&sys, t.as_ref(), f, wavelength_nm, &pupil.points())?;
        let pupil: Vec<f64> = std::mem::take(&mut s.pupil).into_iter().flatten().collect();
        let (x, y, status) = (std::mem::take(&mut s.x_mm), std::mem::take(&mut s.y_mm), std::mem::take(&mut s.status));
        Ok((json_text(&s)?, pupil, x, y, status))
    })
    .py()?;
    let n = x.len();
    // The status names as the JSON wrote them (serde's variant names): one Python string per distinct status.
    let mut names: std::collections::HashMap<u8, Bound<'py, pyo3::types::PyString>> = std::collections::HashMap::new();
    let mut items = Vec::with_capacity(n);
    for s in status {
        let name = match names.entry(s as u8) {
            std::collections::hash_map::Entry::Occupied(e) => e.get().clone(),
            std::collections::hash_map::Entry::Vacant(e) => {
                let label = serde_json::to_value(s).ok().and_then(|v| v.as_str().map(str::to_string)).unwrap_or_else(|| s.label().to_string());
                e.insert(pyo3::types::PyString::new(py, &label)).clone()
            }
        };
        items.push(name);
    }
    let status = pyo3::types::PyList::new(py, items)?;
    Ok((text, (output(py, pupil, &[n, 2])?, output(py, x, &[n])?, output(py, y, &[n])?, status)))
}

/// Zemax-style grid distortion: (the grid as JSON with `points` left empty, the points as JSON arrays of at
/// most [`POINTS_PER_YIELD`] dicts, keys in the JSON's order); `diffcassi.distortion` parses the chunks and
/// puts the list in. The trace and the JSON run without the GIL. The chunks are parsed by Python's
/// `json.loads` (which needs the GIL) in a Python loop, not here: CPython hands the GIL to a thread that has
/// waited a switch interval (5 ms) only from its interpreter loop, and a native loop that released and took
/// back the GIL between chunks kept it whenever a chunk took less than that interval (the waiting thread,
/// woken by each release, found the GIL taken again and never asked for it: a 0.2–0.4 s stall of the
/// caller's other threads in about one grid=501 call in three; round 18, again in round 22).
#[pyfunction]
#[pyo3(signature = (system, wavelength_nm, grid = None, half_width_mm = 2.5, backend = "analytic"))]
fn _distortion(py: Python<'_>, system: &PySystem, wavelength_nm: f64, grid: Option<&Bound<'_, PyAny>>, half_width_mm: f64, backend: &str) -> PyResult<(String, Vec<String>)> {
    let grid = grid.map(|g| size_arg("grid", g)).transpose()?.unwrap_or(13);
    // The CLI's checks (`diffcassi distortion`), naming the Python arguments.
    if !(half_width_mm.is_finite() && half_width_mm > 0.0 && half_width_mm <= diffcassi::limits::MAX_LENGTH_MM) {
        return Err(value_error(format!("half_width_mm {}: the half width must be in (0, {:e}] mm", diffcassi::limits::fmt_num(half_width_mm), diffcassi::limits::MAX_LENGTH_MM)));
    }
    let n = grid as f64 * grid as f64;
    diffcassi::limits::check_rays(&format!("grid {grid}"), n).py()?;
    diffcassi::limits::check_memory(&format!("grid {grid}"), diffcassi::limits::bytes_distortion(grid)).py()?;
    let t = tracer(backend)?;
    let sys = Arc::clone(&system.inner);
    run(py, move || -> diffcassi::Result<_> {
        let mut g = analysis::grid_distortion(&sys, t.as_ref(), wavelength_nm, grid, half_width_mm)?;
        let points = std::mem::take(&mut g.points);
        let chunks = points.chunks(POINTS_PER_YIELD).map(|c| json_text(&c)).collect::<diffcassi::Result<Vec<_>>>()?;
        Ok((json_text(&g)?, chunks))
    })
    .py()
}

/// Chief-ray dispersion curve of one field (JSON).
#[pyfunction]
#[pyo3(signature = (system, field_mm, wavelengths_nm, backend = "analytic", field_deg = None))]
fn _dispersion(py: Python<'_>, system: &PySystem, field_mm: Option<Vec<f64>>, wavelengths_nm: &Bound<'_, PyAny>, backend: &str, field_deg: Option<Vec<f64>>) -> PyResult<String> {
    let ws = f64_list("wavelengths_nm", wavelengths_nm)?;
    let f = system.field_of(field_mm.as_deref(), field_deg.as_deref(), "field_mm", "field_deg")?;
    let t = tracer(backend)?;
    let sys = Arc::clone(&system.inner);
    let c = run(py, move || analysis::dispersion_curve(&sys, t.as_ref(), f, &ws)).py()?;
    json(&c)
}

/// The chief-ray mapping cube: positions (H, W, L, 2) float64 detector mm and valid (H, W, L) bool.
/// `device` "cuda" (or "cuda:N") traces the chief rays with the GPU trace kernels (`mapping --device cuda`), "cpu-twin" with
/// the same kernels on the CPU; `precision` "f32" with the f32 kernels. A device other than the CPU takes
/// the default backend only. At infinity give `scene_fov_deg` (the full angle across `width`, degrees) as
/// `mapping --scene-fov-deg`; `pitch_mm` is then not used.
#[pyfunction]
#[pyo3(signature = (system, height, width, wavelengths_nm, pitch_mm = None, backend = "analytic", device = "cpu", precision = "f64", scene_fov_deg = None))]
#[allow(clippy::too_many_arguments)]
fn mapping<'py>(
    py: Python<'py>,
    system: &PySystem,
    height: &Bound<'py, PyAny>,
    width: &Bound<'py, PyAny>,
    wavelengths_nm: &Bound<'py, PyAny>,
    pitch_mm: Option<&Bound<'py, PyAny>>,
    backend: &str,
    device: &str,
    precision: &str,
    scene_fov_deg: Option<&Bound<'py, PyAny>>,
) -> PyResult<(Bound<'py, PyArrayDyn<f64>>, Bound<'py, PyArrayDyn<bool>>)> {
    // `None`: 10 µm, the CLI's default (`mapping --pitch-mm`).
    let pitch_mm = pitch_mm.filter(|v| !v.is_none()).map_or(Ok(0.01), |v| crate::arrays::real_arg("pitch_mm", v))?;
    let scene_fov_deg = scene_fov_deg.filter(|v| !v.is_none()).map(|v| crate::arrays::real_arg("scene_fov_deg", v)).transpose()?;
    let dev = crate::settings::parse_device(device)?;
    let prec = precision.parse::<diffcassi::tracer::Precision>().map_err(|_| value_error(format!("precision `{precision}`: use \"f64\" or \"f32\"")))?;
    if (dev != diffcassi::render::Device::Cpu || prec != diffcassi::tracer::Precision::F64) && backend != "analytic" {
        return Err(value_error(format!("device=\"{device}\", precision=\"{precision}\": the GPU kernels and the f32 kernel trace on their own; backend=\"{backend}\" cannot be combined with them")));
    }
    let (height, width) = (size_arg("height", height)?, size_arg("width", width)?);
    let ws = f64_list("wavelengths_nm", wavelengths_nm)?;
    // The CLI's checks and budgets (`diffcassi mapping`), before anything is allocated.
    if ws.is_empty() || ws.len() > diffcassi::limits::MAX_WAVELENGTHS {
        return Err(value_error(format!("wavelengths_nm: {} values; give 1..={}", ws.len(), diffcassi::limits::MAX_WAVELENGTHS)));
    }
    if !(pitch_mm.is_finite() && pitch_mm > 0.0 && pitch_mm <= diffcassi::limits::MAX_LENGTH_MM) {
        return Err(value_error(format!("pitch_mm {}: must be in (0, {:e}] mm", diffcassi::limits::fmt_num(pitch_mm), diffcassi::limits::MAX_LENGTH_MM)));
    }
    // The scene pitch in the system's field unit, as `mapping --scene-fov-deg`: mm on a finite object plane, a
    // pixel's angle at infinity (`pitch_mm` was read as radians there: a held-out battery) — required there.
    let mut cfg = diffcassi::render::RenderConfig::paper(1);
    (cfg.scene_width, cfg.scene_pitch_mm, cfg.scene_fov_deg) = (width, pitch_mm, scene_fov_deg);
    let pitch_mm = diffcassi::render::scene_pitch_for(&system.inner, &cfg).py()?;
    let what = format!("height × width × wavelengths_nm ({height} × {width} × {})", ws.len());
    // The cube returned (float64 positions, a bool per entry) and, off the analytic kernel (another backend, a
    // GPU device), one wavelength's chief-ray batch: the library's figures, as `diffcassi mapping --f64`.
    let batched = dev != diffcassi::render::Device::Cpu || backend != "analytic";
    let batch = if batched { diffcassi::limits::bytes_mapping_batch(height, width) } else { 0.0 };
    diffcassi::limits::check_memory(&what, diffcassi::limits::bytes_mapping_written(height, width, ws.len(), true) + batch).py()?;
    diffcassi::limits::check_rays(&what, height as f64 * width as f64 * ws.len() as f64).py()?;
    let t = if dev == diffcassi::render::Device::Cpu && prec == diffcassi::tracer::Precision::F64 {
        tracer(backend)?
    } else {
        // Python's spelling, as `render(device=)`'s: the library's reason without the CLI's `--device` words.
        if let Some(why) = dev.unavailable() {
            return Err(value_error(format!("device \"{device}\": {why} (use device=\"cpu\")")));
        }
        dev.tracer(prec).map_err(|e| value_error(format!("device=\"{device}\": {e}")))?
    };
    let sys = Arc::clone(&system.inner);
    let l = ws.len();
    let (positions, valid) = run(py, move || {
        analysis::mapping_cube(&sys, t.as_ref(), height, width, pitch_mm, &ws).map(|cube| (cube.positions_mm, cube.valid.iter().map(|&v| v == 1).collect::<Vec<bool>>()))
    })
    .py()?;
    Ok((output(py, positions, &[height, width, l, 2])?, output(py, valid, &[height, width, l])?))
}

/// Trace rays with their Jacobians with respect to the named free parameters (comma-separated or a list;
/// the names `diffcassi calibrate --free` takes). Returns the traced dict plus `jacobian` (N, 6, K) float64
/// (∂(x, y, z, dir_x, dir_y, dir_z)/∂θ_k, image frame), `parameters` (canonical names), `available` (N,)
/// bool and `reasons` (why a ray's Jacobian is unavailable, "" otherwise).
#[pyfunction]
#[pyo3(signature = (system, parameters, origins, directions, wavelengths_nm, backend = "analytic"))]
fn jacobian<'py>(
    py: Python<'py>,
    system: &PySystem,
    parameters: &Bound<'py, PyAny>,
    origins: &Bound<'py, PyAny>,
    directions: &Bound<'py, PyAny>,
    wavelengths_nm: &Bound<'py, PyAny>,
    backend: &str,
) -> PyResult<Bound<'py, PyDict>> {
    let list = match parameters.extract::<String>() {
        Ok(s) => s,
        Err(_) => parameters.extract::<Vec<String>>().map_err(|_| value_error("parameters: expected a comma-separated string or a list of names"))?.join(","),
    };
    let n_rays = ray_arrays(origins, directions, wavelengths_nm)?.2.shape[0];
    let config: BackendConfig = backend.parse().py()?;
    let (sys, catalogs) = (Arc::clone(&system.inner), Arc::clone(&system.catalogs));
    // The parameter set first (its count K sizes the result), without the GIL.
    let ds = run(py, move || -> diffcassi::Result<_> {
        // The parameter set reads the catalogue files again: refused if one changed since the system was built
        // (as a copy of it is; round 18).
        SequentialSystem::check_catalog_identities(&catalogs)?;
        ParamSet::for_system(&sys, &list)?.build()
    })
    .py()?;
    // The ray and memory budgets before the rays are copied or anything N × K is allocated: the (N, 6, K)
    // Jacobian is a K-fold amplification of the input (round 21: 10⁶ rays × 24 parameters peaked at 1.43 GB
    // under a 0.5 GB budget, unchecked).
    let what = format!("jacobian of N × K = {n_rays} rays × {} parameters", ds.k());
    diffcassi::limits::check_jacobian(&what, "the rays or the parameters", n_rays as f64, ds.k()).py()?;
    let rays = ray_batch(origins, directions, wavelengths_nm)?;
    // The trace and the reshaping into the returned arrays: without the GIL.
    let (n, k, available, reasons, params, jac, traced) = run(py, move || -> diffcassi::Result<_> {
        let hj = ds.trace_with_backend(&config, &rays)?;
        let (n, k) = (hj.batch.len(), hj.batch.k());
        let available: Vec<bool> = hj.unavailable.iter().map(Option::is_none).collect();
        let reasons: Vec<String> = hj.unavailable.into_iter().map(Option::unwrap_or_default).collect();
        Ok((n, k, available, reasons, hj.batch.params, hj.batch.jac, TracedArrays::of(hj.batch.traced)))
    })
    .py()?;
    let dict = traced_out(py, traced)?;
    dict.set_item("jacobian", output(py, jac, &[n, 6, k])?)?;
    dict.set_item("parameters", params)?;
    dict.set_item("available", output(py, available, &[n])?)?;
    dict.set_item("reasons", reasons)?;
    Ok(dict)
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PySystem>()?;
    m.add_function(wrap_pyfunction!(trace, m)?)?;
    m.add_function(wrap_pyfunction!(_time_rust_trace, m)?)?;
    m.add_function(wrap_pyfunction!(_spot, m)?)?;
    m.add_function(wrap_pyfunction!(_distortion, m)?)?;
    m.add_function(wrap_pyfunction!(_dispersion, m)?)?;
    m.add_function(wrap_pyfunction!(mapping, m)?)?;
    m.add_function(wrap_pyfunction!(jacobian, m)?)?;
    Ok(())
}
