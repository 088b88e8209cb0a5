//! The unrolled network's learned part (arch `unrolled-gap-v1`, `diffcassi/unrolled.py`, model card
//! `diffcassi/weights/UNROLLED.md`): the per-stage denoisers D_k and steps λ_k, read from the safetensors file
//! the PyTorch training writes, checked, and run on candle's CPU tensors with the layers of
//! [`super::network`]. The graph around them (GAP initialisation, scale, data steps with the operator) is
//! [`crate::recon::unrolled`]; this file knows no operator.
//!
//! **Stage denoiser** (`StageDenoiser` in `diffcassi/unrolled.py`, width C, B bands):
//! `D(v) = v + L v + U(v)`, L a 1×1 convolution B → B without bias, U a two-level residual U-Net — head 3×3
//! (B → C) → e1; down 2×2/2 (C → 2C); enc2 3×3 → e2; down 2×2/2; mid 3×3; up 2×2/2 transposed + e2; dec2 3×3;
//! up 2×2/2 transposed (2C → C) + e1; dec1 3×3; tail 3×3 (C → B, no ReLU); ReLU after every other layer. The
//! input is padded at the bottom and right by edge replication to multiples of 4 and U's output cropped back,
//! as `pad_to_multiple` in `diffcassi/denoiser.py`. Sums in the order PyTorch writes them: `(v + L v) + U(v)`.
//!
//! **Weights.** Tensors `denoisers.{k}.{layer}.weight|bias` (k < stages) and `steps` (stages), f32; metadata
//! `arch` = `unrolled-gap-v1`, `system`, `stages`, `bands`, `width` (required), and what the training
//! recorded of its operator: `bands_nm`, `mask_sha256` (float32 C-order bytes of the training mask),
//! `planes`, `rays`, `airy_diameter_px`, `height`/`width_px` (the training scene size), `operator_seed`,
//! `acquisition_seed`, `training_step` (optional; non-string values JSON-encoded as `save_unrolled` writes
//! them). [`UnrolledNetwork::from_bytes`] checks the format, `arch`, the integers, every tensor's presence,
//! dtype, shape and finiteness, and that no other tensor is there; [`UnrolledNetwork::check`] checks the
//! network against an acquisition ([`Target`]) — **refused**: another system, band count or wavelengths
//! (beyond [`WAVELENGTH_TOLERANCE_NM`]); **warned** (and recorded): another mask (SHA-256; necessarily so at
//! another scene size), planes, rays or Airy diameter, and any of these not recorded in the file.
//!
//! **Committed weights** ([`committed`]): `diffcassi/weights/unrolled-gap-v1-{sp,msp}.safetensors`, embedded
//! with `include_bytes!` (2 × 1.24 MB), so the CLI, the Python wheel and an installed binary need no path.
use super::network::{cerr, ferr, load_tensor, read_weights_as, Layer};
pub use super::unrolled_v2::ARCH_V2;
use crate::error::{Error, Result};
use candle_core::{Device, Tensor};
use std::path::Path;

/// The architecture name the weights' metadata must carry.
pub const ARCH: &str = "unrolled-gap-v1";

/// Band centres may differ from the training's by this much (nm) before the weights are refused.
pub const WAVELENGTH_TOLERANCE_NM: f64 = 0.01;

static SP: &[u8] = include_bytes!("../../../diffcassi/weights/unrolled-gap-v1-sp.safetensors");
static MSP: &[u8] = include_bytes!("../../../diffcassi/weights/unrolled-gap-v1-msp.safetensors");

/// The committed weights of `system` (preset name, `sp` or `msp`): (repository path, bytes); `None` for a
/// system without trained weights.
pub fn committed(system: &str) -> Option<(&'static str, &'static [u8])> {
    match system {
        "sp" => Some(("diffcassi/weights/unrolled-gap-v1-sp.safetensors", SP)),
        "msp" => Some(("diffcassi/weights/unrolled-gap-v1-msp.safetensors", MSP)),
        _ => None,
    }
}

/// The spec of preset `name` as its system is built (solved cells hold their solved values): the spec a
/// render records and Python's `diffcassi.System.preset(name).to_json()` hashes.
fn built_preset(name: &str) -> Result<crate::spec::SystemSpec> {
    Ok(crate::system::SequentialSystem::build(&crate::presets::spec(name)?)?.spec)
}

/// The systems with committed weights.
pub const COMMITTED_SYSTEMS: &str = "sp, msp";

/// What the weights file's metadata says (required fields first, then the training's operator settings,
/// `None` where the file does not record them).
#[derive(Clone, Debug, serde::Serialize)]
pub struct UnrolledMeta {
    pub system: String,
    pub stages: usize,
    pub bands: usize,
    /// Width C of the stage U-Nets.
    pub width: usize,
    pub bands_nm: Option<Vec<f64>>,
    pub mask_sha256: Option<String>,
    /// SHA-256 of the training system's spec JSON ([`crate::spec::system_sha256`]; Python's
    /// `diffcassi.unrolled.system_sha256`).
    pub system_sha256: Option<String>,
    pub planes: Option<usize>,
    pub rays: Option<usize>,
    pub airy_diameter_px: Option<f64>,
    /// The training scene size (metadata `height`, `width_px`).
    pub height: Option<usize>,
    pub width_px: Option<usize>,
    pub operator_seed: Option<u64>,
    pub acquisition_seed: Option<u64>,
    pub training_step: Option<u64>,
}

/// The layers of one stage denoiser, in [`stage_graph`]'s order.
const LINEAR: usize = 0;
const TAIL: usize = 10;

/// (name, transposed, C_in, C_out, kernel, bias) of a stage denoiser's layers, in `StageDenoiser`'s order;
/// transposed: weight C_in × C_out × k × k (PyTorch's layout), otherwise C_out × C_in × k × k.
fn stage_graph(bands: usize, c: usize) -> [(&'static str, bool, usize, usize, usize, bool); 11] {
    let c2 = 2 * c;
    [
        ("linear", false, bands, bands, 1, false),
        ("head", false, bands, c, 3, true),
        ("down1", false, c, c2, 2, true),
        ("enc2", false, c2, c2, 3, true),
        ("down2", false, c2, c2, 2, true),
        ("mid", false, c2, c2, 3, true),
        ("up2", true, c2, c2, 2, true),
        ("dec2", false, c2, c2, 3, true),
        ("up1", true, c2, c, 2, true),
        ("dec1", false, c, c, 3, true),
        ("tail", false, c, bands, 3, true),
    ]
}

/// The unrolled network's learned part: the metadata, the steps λ_k and the stage denoisers.
pub struct UnrolledNetwork {
    pub meta: UnrolledMeta,
    /// Where the weights came from (file path, or the committed file's repository path).
    pub source: String,
    /// CRC-32 of the weights file's bytes.
    pub crc32: u32,
    /// λ_k, the GAP step of each stage.
    pub steps: Vec<f32>,
    /// The prescription the network was trained for: the metadata's `system_sha256`, or for the committed
    /// weights (which record none) the SHA-256 of the preset they were trained on; `None`: only the system's
    /// name is known.
    pub trained_system_sha256: Option<String>,
    stages: Vec<Vec<Layer>>,
    /// The v2 network's estimators and priors ([`super::unrolled_v2`]); `None` for `unrolled-gap-v1`.
    v2: Option<super::unrolled_v2::DauhstV2>,
}

impl std::fmt::Debug for UnrolledNetwork {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "UnrolledNetwork({}, {}, system {}, {} stages, {} bands, width {}, CRC-32 {:08x})", self.arch(), self.source, self.meta.system, self.meta.stages, self.meta.bands, self.meta.width, self.crc32)
    }
}

/// The acquisition a network is checked against ([`UnrolledNetwork::check`]).
pub struct Target<'a> {
    /// The acquisition's system (its name: the preset name for presets; its prescription).
    pub spec: &'a crate::spec::SystemSpec,
    pub bands_nm: &'a [f64],
    /// The mask, row-major, `mask_height` × `mask_width`.
    pub mask: &'a [f32],
    pub mask_height: usize,
    pub mask_width: usize,
    pub planes: usize,
    /// The operator's rays per scene pixel per plane.
    pub rays: usize,
    pub airy_diameter_px: Option<f64>,
    /// The operator's ray seed (recorded beside the training's `operator_seed`; any seed is accepted: the
    /// Monte-Carlo rays of an operator never match an acquisition's).
    pub operator_seed: Option<u64>,
}

/// The result of [`UnrolledNetwork::check`]: what was compared (JSON, for `reconstruct.json`) and the
/// warnings (also in the JSON).
pub struct CheckReport {
    pub record: serde_json::Value,
    pub warnings: Vec<String>,
}

impl UnrolledNetwork {
    /// The committed weights of `system` (a clear error naming the systems that have some).
    pub fn committed(system: &str) -> Result<Self> {
        let (path, bytes) = committed(system).ok_or_else(|| Error::invalid(format!("--solver unrolled: no committed {ARCH} weights for system `{system}` (committed: {COMMITTED_SYSTEMS}); give --weights FILE, trained for this system with scripts/train_unrolled.py")))?;
        let mut net = Self::from_bytes(bytes, &format!("{path} (embedded)"))?;
        // Trained on the preset of that name (diffcassi/weights/UNROLLED.md), before its files recorded it.
        if net.trained_system_sha256.is_none() {
            net.trained_system_sha256 = Some(crate::spec::system_sha256(&built_preset(system)?)?);
        }
        Ok(net)
    }

    /// Weights from a safetensors file (a regular file of at most 1 GiB).
    pub fn from_file(path: &Path) -> Result<Self> {
        let bytes = read_weights_as(path, "unrolled weights")?;
        Self::from_bytes(&bytes, &path.display().to_string())
    }

    /// The weights file `path`, or the committed weights of `system` when `None`.
    pub fn load(path: Option<&Path>, system: &str) -> Result<Self> {
        match path {
            Some(p) => Self::from_file(p),
            None => Self::committed(system),
        }
    }

    /// Weights from the bytes of a safetensors file; `source` names it in errors.
    pub fn from_bytes(bytes: &[u8], source: &str) -> Result<Self> {
        let bad = |e: safetensors::SafeTensorError| ferr(source, format!("not a valid safetensors file (truncated or corrupt?): {e}"));
        let st = safetensors::SafeTensors::deserialize(bytes).map_err(bad)?;
        let (_, header) = safetensors::SafeTensors::read_metadata(bytes).map_err(bad)?;
        let meta = header.metadata().clone().unwrap_or_default();
        let get = |k: &str| meta.get(k).ok_or_else(|| ferr(source, format!("metadata field `{k}` is missing (an {ARCH} or {ARCH_V2} file has arch, system, stages, bands, width)")));
        let arch = get("arch")?;
        let v2 = arch == ARCH_V2;
        if arch != ARCH && !v2 {
            return Err(ferr(source, format!("metadata `arch` = `{arch}`: this inference implements `{ARCH}` and `{ARCH_V2}` only")));
        }
        let num = |k: &str, max: usize| -> Result<usize> {
            let v = get(k)?;
            v.trim().parse::<usize>().ok().filter(|n| *n > 0 && *n <= max).ok_or_else(|| ferr(source, format!("metadata `{k}` = `{v}` is not an integer in 1..={max}")))
        };
        let (stages, bands, width) = (num("stages", 64)?, num("bands", 4096)?, num("width", 4096)?);
        let system = get("system")?.trim().to_string();
        if system.is_empty() {
            return Err(ferr(source, "metadata `system` is empty: the weights must name the system they were trained for"));
        }
        // Optional fields: JSON-encoded numbers (or a list), checked when present.
        fn opt<T: serde::de::DeserializeOwned>(meta: &std::collections::HashMap<String, String>, source: &str, k: &str, what: &str) -> Result<Option<T>> {
            match meta.get(k) {
                None => Ok(None),
                Some(v) => serde_json::from_str::<T>(v.trim()).map(Some).map_err(|_| ferr(source, format!("metadata `{k}` = `{v}` is not {what}"))),
            }
        }
        let bands_nm: Option<Vec<f64>> = opt(&meta, source, "bands_nm", "a list of wavelengths (nm)")?;
        if let Some(b) = &bands_nm {
            if b.len() != bands || b.iter().any(|v| !v.is_finite()) {
                return Err(ferr(source, format!("metadata `bands_nm` has {} finite values of {}, `bands` = {bands}", b.iter().filter(|v| v.is_finite()).count(), b.len())));
            }
        }
        let airy: Option<f64> = opt(&meta, source, "airy_diameter_px", "a number")?;
        let sha = |k: &str| -> Result<Option<String>> {
            match meta.get(k).map(|s| s.trim().to_ascii_lowercase()) {
                Some(m) if m.len() != 64 || !m.bytes().all(|c| c.is_ascii_hexdigit()) => Err(ferr(source, format!("metadata `{k}` = `{m}` is not 64 hex digits"))),
                m => Ok(m),
            }
        };
        let (mask_sha256, system_sha256) = (sha("mask_sha256")?, sha("system_sha256")?);
        let meta_out = UnrolledMeta {
            system,
            stages,
            bands,
            width,
            bands_nm,
            mask_sha256,
            system_sha256: system_sha256.clone(),
            planes: opt(&meta, source, "planes", "a non-negative integer")?,
            rays: opt(&meta, source, "rays", "a non-negative integer")?,
            airy_diameter_px: airy,
            height: opt(&meta, source, "height", "a non-negative integer")?,
            width_px: opt(&meta, source, "width_px", "a non-negative integer")?,
            operator_seed: opt(&meta, source, "operator_seed", "a non-negative integer")?,
            acquisition_seed: opt(&meta, source, "acquisition_seed", "a non-negative integer")?,
            training_step: opt(&meta, source, "training_step", "a non-negative integer")?,
        };
        if v2 {
            let (net, taken) = super::unrolled_v2::DauhstV2::read(&st, source, stages, bands, width)?;
            super::unrolled_v2::refuse_extra(&st, source, &taken, stages)?;
            return Ok(UnrolledNetwork { meta: meta_out, source: source.to_string(), crc32: crc32fast::hash(bytes), steps: Vec::new(), trained_system_sha256: system_sha256, stages: Vec::new(), v2: Some(net) });
        }
        let mut expected = std::collections::BTreeSet::new();
        let mut all = Vec::with_capacity(stages);
        for k in 0..stages {
            let mut layers = Vec::with_capacity(11);
            for (name, transposed, cin, cout, ks, has_bias) in stage_graph(bands, width) {
                let wshape = if transposed { [cin, cout, ks, ks] } else { [cout, cin, ks, ks] };
                let wname = format!("denoisers.{k}.{name}.weight");
                let weight = load_tensor(&st, source, &wname, &wshape, ARCH)?;
                expected.insert(wname);
                let bias = if has_bias {
                    let bname = format!("denoisers.{k}.{name}.bias");
                    let b = load_tensor(&st, source, &bname, &[cout], ARCH)?.reshape((1, cout, 1, 1)).map_err(cerr)?;
                    expected.insert(bname);
                    Some(b)
                } else {
                    None
                };
                layers.push(Layer { weight, bias });
            }
            all.push(layers);
        }
        let steps = load_tensor(&st, source, "steps", &[stages], ARCH)?.to_vec1::<f32>().map_err(cerr)?;
        expected.insert("steps".into());
        if let Some(extra) = st.names().into_iter().find(|n| !expected.contains(*n)) {
            return Err(ferr(source, format!("tensor `{extra}` is not part of {ARCH} with stages = {stages} (expected {} tensors: denoisers.K.LAYER.weight|bias, steps)", expected.len())));
        }
        Ok(UnrolledNetwork { meta: meta_out, source: source.to_string(), crc32: crc32fast::hash(bytes), steps, trained_system_sha256: system_sha256, stages: all, v2: None })
    }

    /// Check the network's bands against `bands_nm` (an acquisition's, or a study's `--bands` before its
    /// renders): another count, or a wavelength more than [`WAVELENGTH_TOLERANCE_NM`] off, refused; `Some`
    /// warning when the weights do not record their wavelengths (only the count is checked).
    pub fn check_bands(&self, bands_nm: &[f64]) -> Result<Option<String>> {
        let (m, src) = (&self.meta, &self.source);
        if m.bands != bands_nm.len() {
            return Err(ferr(src, format!("metadata `bands` = {}: the network is for {} bands, the acquisition has {}", m.bands, m.bands, bands_nm.len())));
        }
        match &m.bands_nm {
            Some(b) => {
                if let Some(k) = (0..b.len()).find(|&k| (b[k] - bands_nm[k]).abs() > WAVELENGTH_TOLERANCE_NM) {
                    return Err(ferr(src, format!("metadata `bands_nm`: band {k} is {} nm, the acquisition's is {} nm (tolerance {WAVELENGTH_TOLERANCE_NM} nm): trained for other wavelengths", b[k], bands_nm[k])));
                }
                Ok(None)
            }
            None => Ok(Some(format!("{src}: metadata `bands_nm` not recorded: the wavelengths are not checked (only the band count)"))),
        }
    }

    /// Check the network against an acquisition: system, band count and wavelengths refused when they
    /// differ; mask, planes, rays, Airy diameter warned about (see the module docs). Errors name the file,
    /// the metadata field and both values.
    pub fn check(&self, t: &Target<'_>) -> Result<CheckReport> {
        let m = &self.meta;
        let src = &self.source;
        let (system_sha256, unchecked) = self.check_system(t.spec)?;
        let mut warnings: Vec<String> = unchecked.into_iter().collect();
        warnings.extend(self.check_bands(t.bands_nm)?);
        let render_sha = crate::io::sha256::sha256_f32_hex(t.mask);
        let trained_size = match (m.height, m.width_px) {
            (Some(h), Some(w)) => format!("{h}×{w}"),
            _ => "an unrecorded size".into(),
        };
        match &m.mask_sha256 {
            Some(s) if *s == render_sha => {}
            Some(s) => warnings.push(format!(
                "{src}: metadata `mask_sha256` = {}…: trained with another mask (at {trained_size}) than this acquisition's ({}×{}, SHA-256 {}…); the network runs (it is convolutional and its data steps use this acquisition's operator and mask) but its prior was learned for the training coding",
                &s[..12],
                t.mask_height,
                t.mask_width,
                &render_sha[..12]
            )),
            None => warnings.push(format!("{src}: metadata `mask_sha256` not recorded: the mask is not checked")),
        }
        let mut differs = |field: &str, trained: Option<f64>, here: Option<f64>| match (trained, here) {
            (Some(a), Some(b)) if (a - b).abs() > 1e-9 * a.abs().max(1.0) => warnings.push(format!("{src}: metadata `{field}` = {a}: trained with {a}, this operator has {b}")),
            (Some(a), None) => warnings.push(format!("{src}: metadata `{field}` = {a}: trained with {a}, this operator has none")),
            _ => {}
        };
        differs("planes", m.planes.map(|v| v as f64), Some(t.planes as f64));
        differs("rays", m.rays.map(|v| v as f64), Some(t.rays as f64));
        differs("airy_diameter_px", m.airy_diameter_px, t.airy_diameter_px);
        let record = serde_json::json!({
            "system": t.spec.name,
            "system_sha256": {"weights": self.trained_system_sha256, "acquisition": system_sha256, "match": self.trained_system_sha256.as_deref().map(|w| w == system_sha256)},
            "bands": m.bands,
            "bands_nm_checked": m.bands_nm.is_some(),
            "mask_sha256": {"weights": m.mask_sha256, "acquisition": render_sha, "match": m.mask_sha256.as_deref() == Some(render_sha.as_str())},
            "scene_size": {"weights": [m.height, m.width_px], "acquisition": [t.mask_height, t.mask_width]},
            "planes": {"weights": m.planes, "operator": t.planes},
            "rays": {"weights": m.rays, "operator": t.rays},
            "airy_diameter_px": {"weights": m.airy_diameter_px, "operator": t.airy_diameter_px},
            "operator_seed": {"weights": m.operator_seed, "operator": t.operator_seed, "weights_acquisition_seed": m.acquisition_seed},
            "warnings": warnings,
        });
        Ok(CheckReport { record, warnings })
    }

    /// The network against the acquisition's system, **refused** when it was trained for another: another
    /// name, or — where the weights know their training prescription ([`Self::trained_system_sha256`]) —
    /// another prescription under the same name (a user's file named `sp` that is not the preset, a moved or
    /// re-glassed copy), the message naming the first field that differs when the name is a preset. Returns
    /// the system's SHA-256, and a warning when only its name could be checked. `spec` is a built system's
    /// ([`crate::system::SequentialSystem::spec`]: solved cells hold their solved values, as a render records it).
    pub fn check_system(&self, spec: &crate::spec::SystemSpec) -> Result<(String, Option<String>)> {
        let (m, src, name) = (&self.meta, &self.source, spec.name.as_str());
        if m.system != name {
            return Err(ferr(src, format!("metadata `system` = `{}`: the network was trained for system `{}`, the acquisition is from `{name}` — refused (give weights trained for `{name}`)", m.system, m.system)));
        }
        let here = crate::spec::system_sha256(spec)?;
        let Some(want) = &self.trained_system_sha256 else {
            return Ok((here, Some(format!("{src}: metadata `system_sha256` not recorded: only the system's name `{name}` is checked, not its prescription"))));
        };
        if *want != here {
            let what = built_preset(name).ok().and_then(|p| crate::spec::first_difference(&p, spec)).map(|d| format!("; first difference from the preset `{name}`: {d}")).unwrap_or_default();
            return Err(ferr(
                src,
                format!(
                    "the network was trained for system `{name}` with the prescription of SHA-256 {}…, and the acquisition's system `{name}` is another (SHA-256 {}…{what}) — refused: a system is its prescription, not its name (give weights trained for this system)",
                    &want[..12],
                    &here[..12]
                ),
            ));
        }
        Ok((here, None))
    }

    /// A JSON record of the network (for `reconstruct.json`).
    pub fn describe(&self) -> serde_json::Value {
        serde_json::json!({ "name": self.arch(), "weights": self.source, "weights_crc32": self.crc32, "steps": self.steps, "metadata": self.meta })
    }

    /// Number of stages K.
    pub fn stages(&self) -> usize {
        self.meta.stages
    }

    /// The architecture: [`ARCH`] or [`ARCH_V2`].
    pub fn arch(&self) -> &'static str {
        if self.v2.is_some() {
            ARCH_V2
        } else {
            ARCH
        }
    }

    /// The v2 network's estimators and priors (`None` for `unrolled-gap-v1`).
    pub fn v2(&self) -> Option<&super::unrolled_v2::DauhstV2> {
        self.v2.as_ref()
    }

    /// `out` ← D_k(`v`) for an h×w cube `[row][col][band]` of the network's band count (stage `k` < K).
    pub fn denoise_stage(&self, k: usize, v: &[f32], out: &mut [f32], h: usize, w: usize) -> Result<()> {
        let b = self.meta.bands;
        if k >= self.stages.len() || v.len() != h * w * b || out.len() != v.len() || h == 0 || w == 0 {
            return Err(Error::invalid(format!("unrolled stage {k}: a {h}×{w}×{b} cube needs {} values (got {} in, {} out; {} stages)", h * w * b, v.len(), out.len(), self.stages.len())));
        }
        let l = &self.stages[k];
        // (1, B, Hp, Wp), padded at the bottom/right by edge replication.
        let (input, hp, wp) = super::network::padded_band_planes(v, h, w, b);
        let x = Tensor::from_vec(input, (1, b, hp, wp), &Device::Cpu).map_err(cerr)?;
        let lin = l[LINEAR].conv(&x, 0, 1, false)?;
        let e1 = l[1].conv(&x, 1, 1, true)?;
        let z = l[2].conv(&e1, 0, 2, true)?;
        let e2 = l[3].conv(&z, 1, 1, true)?;
        let z = l[4].conv(&e2, 0, 2, true)?;
        let z = l[5].conv(&z, 1, 1, true)?;
        let z = l[6].up(&z, &e2)?;
        let z = l[7].conv(&z, 1, 1, true)?;
        let z = l[8].up(&z, &e1)?;
        let z = l[9].conv(&z, 1, 1, true)?;
        let tail = l[TAIL].conv(&z, 1, 1, false)?;
        super::network::add_residual_cropped(v, lin, tail, out, h, w, b, wp)
    }
}
