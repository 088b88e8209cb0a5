//! Render settings from Python keywords, parsed in one place for every call that takes them (`render`,
//! `Transport`, `exact`, `mapping_operator`, `shift_operator`): the keywords arrive as `**settings`, each
//! is checked here (type and name; a `ValueError` names a wrong one and lists the valid ones), and every
//! setting left out or `None` takes the library's default ([`diffcassi::render::RenderSettings::default`],
//! the CLI's too), checked and turned into a configuration by the library
//! ([`diffcassi::render::RenderSettings::config_hw`]).
//!
//! ```text
//! diffcassi.Transport(sp, 32, 32, rays=4, airy=False)   # -> Settings { options: rays 4, airy false, .. }
//! ```
use crate::arrays::{f64_list, input, is_bool, Input};
use crate::errors::{value_error, IntoPy};
use diffcassi::render::{Device, Mask, MaskSource, RenderConfig, RenderSettings, Sampling};
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// The render keywords every settings-taking call accepts (besides `mask`, which is positional).
pub const RENDER_KEYS: [&str; 13] = ["bands_nm", "planes", "rays", "seed", "sampling", "opening", "mask_seed", "airy_diameter_px", "airy", "backend", "device", "precision", "scene_fov_deg"];

/// Render settings from Python keywords; `None` = the library's default.
#[derive(Default, Clone)]
pub struct Options {
    pub bands_nm: Option<Vec<f64>>,
    pub planes: Option<usize>,
    pub rays: Option<usize>,
    pub seed: Option<u64>,
    pub sampling: Option<String>,
    pub opening: Option<f64>,
    pub mask_seed: Option<u64>,
    pub airy_diameter_px: Option<f64>,
    pub airy: Option<bool>,
    pub device: Option<String>,
    /// `"f64"` (the default) or `"f32"` (the ray kernel's precision, as `--precision`).
    pub precision: Option<String>,
    /// An object at infinity: the scene's full angular extent across its width (degrees, `--scene-fov-deg`).
    pub scene_fov_deg: Option<f64>,
    /// `render`'s `tolerance_um` chooses the rays ([`RenderSettings::tolerance_chooses_rays`]): the ray
    /// budget is checked at the rays it may choose, not at the default it replaces.
    pub tolerance_chooses_rays: bool,
}

impl Options {
    /// The library's settings: its defaults, overridden by the keywords given.
    pub fn settings(&self) -> PyResult<RenderSettings> {
        // Python's calls write no chief-ray mapping cube (the CLI's `render` does, unless `--no-mapping`): its
        // memory term is not theirs.
        let mut s = RenderSettings { mapping: false, ..RenderSettings::default() };
        if let Some(b) = &self.bands_nm {
            if b.is_empty() {
                return Err(value_error("bands_nm: empty"));
            }
            s.bands_nm = b.clone();
        }
        if let Some(p) = self.planes {
            s.planes = p;
        }
        s.rays = self.rays;
        s.tolerance_chooses_rays = self.tolerance_chooses_rays;
        s.seed = self.seed.unwrap_or(s.seed);
        if let Some(name) = &self.sampling {
            s.sampling = match name.as_str() {
                "stratified" => Sampling::Stratified,
                "independent" => Sampling::Independent,
                _ => return Err(value_error(format!("--sampling `{name}`: use stratified or independent"))),
            };
        }
        if let MaskSource::Random { opening, seed } = &mut s.mask {
            *opening = self.opening.unwrap_or(*opening);
            *seed = self.mask_seed.unwrap_or(*seed);
        }
        if self.airy == Some(false) && self.airy_diameter_px.is_some() {
            return Err(value_error("airy=False with airy_diameter_px: give one or the other (airy_diameter_px sets the blur that airy=False turns off)"));
        }
        if let Some(d) = self.airy_diameter_px {
            s.airy_diameter_px = Some(d);
        }
        if self.airy == Some(false) {
            s.airy_diameter_px = None;
        }
        if let Some(p) = &self.precision {
            s.precision = Some(p.parse().map_err(|_| value_error(format!("precision `{p}`: use \"f64\" or \"f32\"")))?);
        }
        // Checked by the library against the system when the renderer is built (`render::scene_pitch_for`:
        // refused on a finite object, required at infinity, in (0, 180) degrees).
        s.scene_fov_deg = self.scene_fov_deg;
        if let Some(d) = &self.device {
            s.device = parse_device(d)?;
            if let Some(why) = s.device.unavailable() {
                return Err(value_error(format!("device \"{d}\": {why} (use device=\"cpu\")")));
            }
        }
        Ok(s)
    }
}

/// The render configuration and mask for a `height × width` scene (the library's checks and budgets,
/// then the caller's mask array if any).
pub fn configure(height: usize, width: usize, o: &Options, mask: Option<&Bound<'_, PyAny>>) -> PyResult<(RenderConfig, Mask)> {
    let s = o.settings()?;
    if mask.is_some() && (o.opening.is_some() || o.mask_seed.is_some()) {
        return Err(value_error("mask with opening or mask_seed: those set the random mask, which a given mask replaces; give one or the other"));
    }
    let (cfg, mut m) = s.config_hw(height, width).py()?;
    if let Some(obj) = mask {
        let a: Input<f32> = input("mask", obj, "float32", 2, "(H, W)")?;
        if a.shape != [height, width] {
            return Err(value_error(format!("mask: expected shape ({height}, {width}) (the scene's), got {:?}", a.shape)));
        }
        let v = a.slice();
        if let Some(i) = v.iter().position(|x| !(0.0..=1.0).contains(x)) {
            return Err(value_error(format!("mask: value {} at index ({}, {}) is not in [0, 1]", v[i], i / width, i % width)));
        }
        m = Mask { height, width, values: v.to_vec(), description: "caller-provided array".into() }.at_png_steps();
    }
    Ok((cfg, m))
}

/// The parsed keywords: the render options, the backend name, and the call's own extra keywords (those
/// named in `extra`, still as Python objects, `None` values dropped).
pub struct Settings<'py> {
    pub options: Options,
    pub backend: String,
    pub extra: Bound<'py, PyDict>,
}

/// Keyword `name`'s value as `T`, or a `ValueError` naming it, `what` it must be and what it is (the render
/// keywords' and `study`'s one reader).
pub(crate) fn get<'py, T: FromPyObject<'py>>(name: &str, v: &Bound<'py, PyAny>, what: &str) -> PyResult<T> {
    let bad = || {
        let ty = v.get_type().name().map(|n| n.to_string()).unwrap_or_else(|_| "?".into());
        value_error(format!("{name}: expected {what} or None, got {ty} {}", v.repr().map(|r| r.to_string()).unwrap_or_default()))
    };
    // A bool is an int to Python: `planes=True` rendered one plane, `opening=True` an all-open mask and
    // `tolerance_um=True` a 1 µm tolerance. Integer and number settings refuse it, as the positional integer
    // arguments do (`arrays::uint_arg`): only a setting that wants True or False takes one.
    if (what.starts_with("an integer") || what.starts_with("a number")) && is_bool(v) {
        return Err(bad());
    }
    v.extract::<T>().map_err(|_| bad())
}

/// Parse `kwargs`: the render keywords ([`RENDER_KEYS`]) and the call's `extra` ones; anything else is a
/// `ValueError` naming it.
pub fn settings<'py>(py: Python<'py>, kwargs: Option<&Bound<'py, PyDict>>, extra: &[&str]) -> PyResult<Settings<'py>> {
    let mut s = Settings { options: Options::default(), backend: "analytic".to_string(), extra: PyDict::new(py) };
    let Some(kw) = kwargs else { return Ok(s) };
    for (k, v) in kw.iter() {
        let key: String = k.extract()?;
        if v.is_none() {
            continue;
        }
        let o = &mut s.options;
        match key.as_str() {
            "bands_nm" => o.bands_nm = Some(f64_list("bands_nm", &v)?),
            "planes" => o.planes = Some(get(&key, &v, crate::arrays::COUNT)?),
            "rays" => o.rays = Some(get(&key, &v, crate::arrays::COUNT)?),
            "seed" => o.seed = Some(get(&key, &v, crate::arrays::SEED)?),
            "sampling" => o.sampling = Some(get(&key, &v, "a string")?),
            "opening" => o.opening = Some(get(&key, &v, "a number")?),
            "mask_seed" => o.mask_seed = Some(get(&key, &v, crate::arrays::SEED)?),
            "airy_diameter_px" => o.airy_diameter_px = Some(get(&key, &v, "a number")?),
            "airy" => o.airy = Some(get(&key, &v, "True or False")?),
            "device" => o.device = Some(get(&key, &v, "\"cpu\"")?),
            "precision" => o.precision = Some(get(&key, &v, "\"f64\" or \"f32\"")?),
            "scene_fov_deg" => o.scene_fov_deg = Some(get(&key, &v, "a number (degrees)")?),
            "backend" => s.backend = get(&key, &v, "a backend name")?,
            other if extra.contains(&other) => s.extra.set_item(other, v)?,
            other => {
                let mut valid: Vec<&str> = RENDER_KEYS.to_vec();
                valid.extend_from_slice(extra);
                return Err(value_error(format!("unexpected keyword `{other}` (valid: {})", valid.join(", "))));
            }
        }
    }
    Ok(s)
}

/// An extra keyword of [`Settings::extra`] as `T` (`None` when absent).
pub fn extra<'py, T: FromPyObject<'py>>(s: &Settings<'py>, name: &str, what: &str) -> PyResult<Option<T>> {
    match s.extra.get_item(name)? {
        Some(v) => get(name, &v, what).map(Some),
        None => Ok(None),
    }
}

/// `device` as the library reads it (`cpu`, `cuda`, `cuda:N`, `cpu-twin`), its error in keyword spelling
/// (`device "cuda:x": after `cuda:` give a device ordinal …`).
pub fn parse_device(d: &str) -> PyResult<Device> {
    d.parse::<Device>().map_err(|e| {
        let msg = e.to_string();
        let why = msg.split_once("`: ").map_or(msg.as_str(), |(_, w)| w);
        value_error(format!("device \"{d}\": {why}"))
    })
}

/// Refuse a `device` other than `"cpu"` where the call computes on the host (`exact`, the model operators,
/// `Transport`): never silently ignored. Their torch modules move to a GPU (`.to("cuda")`, docs/gpu.md).
pub fn host_only(o: &Options, what: &str) -> PyResult<()> {
    match o.device.as_deref() {
        None | Some("cpu") => Ok(()),
        // A device string that is no device at all: configure's own message ("use cpu, cuda or cuda:N").
        Some(d) if diffcassi::render::Device::parse_value(d).is_err() => Ok(()),
        Some(d) => Err(value_error(format!(
            "{what}: device=\"{d}\": {what} computes on the CPU (device=\"cpu\"); to apply the operator on a GPU, move its torch module: diffcassi.torch.CassiOperator.from_operator(op, matrix_free=True).to(\"cuda\")"
        ))),
    }
}
