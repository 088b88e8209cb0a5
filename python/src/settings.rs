//! Render settings from Python keywords, parsed in one place for every call that takes them (`render`,
//! `Transport`, `exact`, `mapping_operator`, `shift_operator`): the keywords arrive as `**settings`, each
//! is checked here (type and name; a `ValueError` names a wrong one and lists the valid ones), and every
//! setting left out or `None` takes the CLI's default, read from the CLI's own argument definitions
//! (`diffcassi::cli::render::RenderCommon`, parsed from an empty command line) and turned into a
//! configuration by the CLI's own `config_from`.
//!
//! ```text
//! diffcassi.Transport(sp, 32, 32, rays=4, airy=False)   # -> Settings { options: rays 4, airy false, .. }
//! ```
use crate::arrays::{f64_list, input, Input};
use crate::errors::{value_error, IntoPy};
use clap::Parser;
use diffcassi::cli::render::{config_from, RenderCommon};
use diffcassi::render::{Mask, RenderConfig};
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// The render keywords every settings-taking call accepts (besides `mask`, which is positional).
pub const RENDER_KEYS: [&str; 10] = ["bands_nm", "planes", "rays", "seed", "sampling", "opening", "mask_seed", "airy_diameter_px", "airy", "backend"];

/// The CLI's render arguments with their defaults (an empty command line).
#[derive(Parser)]
struct CliDefaults {
    #[command(flatten)]
    common: RenderCommon,
}

/// Render settings from Python keywords; `None` = the CLI's default.
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
}

/// The render configuration and mask for a `height × width` scene (the CLI's `config_from`, then the
/// caller's mask array if any).
pub fn configure(height: usize, width: usize, o: &Options, mask: Option<&Bound<'_, PyAny>>) -> PyResult<(RenderConfig, Mask)> {
    let mut c = CliDefaults::try_parse_from(["diffcassi"]).map_err(|e| value_error(format!("internal: CLI defaults: {e}")))?.common;
    if height == 0 || width == 0 {
        return Err(value_error(format!("scene size {height}×{width}: must be ≥ 1")));
    }
    // The CLI's checks (sizes, planes, Airy, memory and rays of an n × n render) run in `config_from` on the
    // smaller side; a rectangle's own pixel count is checked right after, before anything of its size is
    // allocated.
    c.scene_size = height.min(width);
    if let Some(b) = &o.bands_nm {
        if b.is_empty() {
            return Err(value_error("bands_nm: empty"));
        }
        c.bands = b.iter().map(|v| format!("{v}")).collect::<Vec<_>>().join(",");
    }
    if let Some(p) = o.planes {
        c.planes = p;
    }
    c.rays = o.rays.or(c.rays);
    c.seed = o.seed.unwrap_or(c.seed);
    if let Some(s) = &o.sampling {
        c.sampling = s.clone();
    }
    c.opening = o.opening.unwrap_or(c.opening);
    c.mask_seed = o.mask_seed.unwrap_or(c.mask_seed);
    c.airy_diameter_px = o.airy_diameter_px.unwrap_or(c.airy_diameter_px);
    if let Some(a) = o.airy {
        c.no_airy = !a;
    }
    let (mut cfg, mut m) = config_from(&c).py()?;
    if width != height {
        check_rectangle(height, width, &c, &cfg).py()?;
    }
    cfg.scene_height = height;
    cfg.scene_width = width;
    if width != height {
        m = Mask::random(height, width, c.opening, c.mask_seed).py()?;
    }
    if let Some(obj) = mask {
        let a: Input<f32> = input("mask", obj, "float32", 2, "(H, W)")?;
        if a.shape != [height, width] {
            return Err(value_error(format!("mask: expected shape ({height}, {width}) (the scene's), got {:?}", a.shape)));
        }
        let v = a.slice();
        if let Some(i) = v.iter().position(|x| !(0.0..=1.0).contains(x)) {
            return Err(value_error(format!("mask: value {} at index ({}, {}) is not in [0, 1]", v[i], i / width, i % width)));
        }
        m = Mask { height, width, values: v.to_vec(), description: "caller-provided array".into() };
    }
    Ok((cfg, m))
}

/// The CLI's memory and ray budgets of a `height × width` render (`config_from` checks squares): the
/// same estimate ([`diffcassi::limits::bytes_render_hw`]) and messages, naming the Python arguments.
fn check_rectangle(height: usize, width: usize, c: &RenderCommon, cfg: &RenderConfig) -> diffcassi::Result<()> {
    use diffcassi::limits;
    let bands = cfg.spectral.bands_nm.len();
    let planes = cfg.spectral.planes();
    let airy = cfg.airy.as_ref().map(|a| a.diameter_px);
    let what = format!("height × width {height}×{width} × planes {planes} (× {bands} bands)");
    limits::check_memory(&what, limits::bytes_render_hw(height, width, bands.max(31), bands, planes, false, airy))?;
    let rays = c.rays.unwrap_or(20);
    limits::check_rays(&format!("height × width {height}×{width} × planes {planes} × rays {rays}"), height as f64 * width as f64 * planes as f64 * rays as f64)
}

/// The parsed keywords: the render options, the backend name, and the call's own extra keywords (those
/// named in `extra`, still as Python objects, `None` values dropped).
pub struct Settings<'py> {
    pub options: Options,
    pub backend: String,
    pub extra: Bound<'py, PyDict>,
}

fn get<'py, T: FromPyObject<'py>>(name: &str, v: &Bound<'py, PyAny>, what: &str) -> PyResult<T> {
    v.extract::<T>().map_err(|_| {
        let ty = v.get_type().name().map(|n| n.to_string()).unwrap_or_else(|_| "?".into());
        value_error(format!("{name}: expected {what} or None, got {ty} {}", v.repr().map(|r| r.to_string()).unwrap_or_default()))
    })
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
            "planes" => o.planes = Some(get(&key, &v, "an integer ≥ 0")?),
            "rays" => o.rays = Some(get(&key, &v, "an integer ≥ 0")?),
            "seed" => o.seed = Some(get(&key, &v, "an integer ≥ 0")?),
            "sampling" => o.sampling = Some(get(&key, &v, "a string")?),
            "opening" => o.opening = Some(get(&key, &v, "a number")?),
            "mask_seed" => o.mask_seed = Some(get(&key, &v, "an integer ≥ 0")?),
            "airy_diameter_px" => o.airy_diameter_px = Some(get(&key, &v, "a number")?),
            "airy" => o.airy = Some(get(&key, &v, "True or False")?),
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
