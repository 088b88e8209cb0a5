//! The learned prior: `SpectralUNet` (arch `spectral-unet-v2`), a small U-Net with a noise-level input channel
//! behind a linear spectral path (FFDNet: K. Zhang, W. Zuo, L. Zhang, "FFDNet: toward a fast and flexible
//! solution for CNN-based image denoising", IEEE TIP 2018; DRUNet: K. Zhang et al., "Plug-and-play image
//! restoration with deep denoiser prior", IEEE TPAMI 2021): `z = E·x`, `out = D·(z − U([z, σ])) + G·x`, with
//! E (bands → K), D (K → bands) and G (bands → bands) learned 1×1 convolutions without bias and U the U-Net
//! on the K-channel latent (src/recon/prior/MODEL.md says why). Its graph is defined once, in PyTorch, by
//! `diffcassi/denoiser.py` (layer by layer in its module docs); this file runs the same graph for the CLI,
//! Python (`diffcassi.denoise`) and C++ (`diffcassi::denoise`), loading the same safetensors weights. Equal to
//! PyTorch within 1e-4 of the peak (`tests/python/test_denoiser_inference.py`).
//!
//! **Inference crate: candle** (`candle-core` 0.11, Hugging Face, MIT/Apache-2.0): pure Rust, maintained,
//! CPU convolutions by tiled im2col + the `gemm` crate, nothing downloaded at build or run time (no C/C++
//! library, no model hub access: the weights are bytes we hand it). The alternatives: `tract` (Sonos;
//! ONNX/NNEF inference, also pure Rust) would need the graph exported to ONNX, a second weights format beside
//! the safetensors the training writes; `burn` is a full training framework (autodiff, its own module
//! system and record format) — more than running sixteen fixed convolutions needs. Only `candle-core` is used
//! (tensors, `conv2d`, `conv_transpose2d`, `relu`; `candle-nn` would only wrap these); the weights file is
//! read by the `safetensors` crate candle itself depends on, so its metadata (arch, bands, width, latent) and every
//! tensor are checked before the network is built.
//!
//! **Determinism.** Every convolution is cut into fixed tiles of output pixels (candle's TILE_SIZE) and each
//! output is one gemm dot product in a fixed order; threads (rayon, the caller's pool) only pick which tile
//! they compute. The result is bit-identical for any thread count (tested: 1- vs 2-thread pools).
//!
//! **Weights.** [`SpectralUNet::embedded`] is the committed checkpoint
//! (`src/recon/prior/weights/spectral-unet-v2-28.safetensors`, 28 bands; `include_bytes!`, so the CLI needs
//! no path); [`SpectralUNet::from_file`] reads a user's. Both check the metadata (`arch` = `spectral-unet-v2`,
//! `bands`, `width`, `latent`), that every tensor the graph needs is there with its shape, in f32, with finite
//! values, and that nothing else is: errors name the file and the field or tensor. The
//! metadata `stage` tells a Gaussian denoiser (absent or `gaussian`: the embedded file, `denoise`, the Gaussian
//! benchmark) from a **PnP-stage network** (`pnp`: `scripts/train_denoiser.py --stage-net`, trained only on the
//! iterates of `pnp-gap`'s own schedule, MODEL.md round 6). [`SpectralUNet::load`] (a Gaussian denoiser: the
//! CLI/Python/C++ `denoise`) refuses a PnP-stage file; the PnP solvers ([`SpectralUNet::load_pnp`]) take either
//! and record its `stage`; any other value is refused. (Round 1–2's
//! `spectral-unet-v1` is v2 with K = bands, E = D = I, G = 0; `diffcassi.denoiser.from_v1` converts such a file.)
//!
//! **Input.** Cubes H×W×B `[row][col][band]` with B = the network's bands, scaled by the caller to a peak of
//! about 1 (the training scale); σ the noise standard deviation on that scale. H and W need not be multiples
//! of 4: the cube is padded at the bottom/right by edge replication and the output cropped, as `denoise()` in
//! `diffcassi/denoiser.py` does.
//!
//! **Mean-colour neutralisation** ([`SpectralUNet::neutral`]; round 5 of MODEL.md): the graph sees
//! `x − m + ḡ` (m the cube's per-band spatial mean, ḡ its mean over the bands) and `m − ḡ` is added back.
//! The committed network shifts a saturated cube's mean colour (retina's orange: a constant cube of its mean
//! spectrum comes back with a per-band bias of 0.015 RMS at σ 0.05); neutralised, the colour it sees is grey,
//! where its training colours are dense (the Gaussian benchmark: retina +4.5 dB at σ 0.02, mean +0.9 dB).
//! Off by default: on PnP's iterates (round 4 fine-tuned the weights on them un-neutralised) one-call PnP
//! lost 0.03 dB with it, and the mean follows an outlier voxel (a voxel at 100× the peak moved the output
//! 12 px away by 0.056 of the peak, `tests/recon_pnp.rs`'s bound is 0.02).
//! **Self-ensemble** ([`SpectralUNet::self_ensemble`], off by default: 8× the time): the mean over the eight
//! flips/rotations ([`DIHEDRAL`]) of the denoised transformed cube, +0.6–0.7 dB on the benchmark.
//!
//! ```no_run
//! use diffcassi::recon::prior::{network::SpectralUNet, Denoiser};
//! use diffcassi::recon::CubeShape;
//! let mut net = SpectralUNet::embedded()?;
//! let shape = CubeShape { height: 32, width: 30, bands: 28 };
//! let noisy = vec![0.5f32; shape.len()];
//! let mut clean = vec![0.0f32; shape.len()];
//! net.denoise(&noisy, &mut clean, shape, 0.05)?;
//! # Ok::<(), diffcassi::Error>(())
//! ```
use super::dihedral::Dihedral;
use super::Denoiser;
use crate::error::{Error, Result};
use crate::recon::operator::CubeShape;
use candle_core::{Device, Tensor};
use std::path::Path;

/// The architecture name the weights' metadata must carry.
pub const ARCH: &str = "spectral-unet-v2";

/// Where the embedded weights come from (for error messages and records).
pub const EMBEDDED_PATH: &str = "src/recon/prior/weights/spectral-unet-v2-28.safetensors";

static EMBEDDED: &[u8] = include_bytes!("weights/spectral-unet-v2-28.safetensors");

/// What a weights file was trained for (metadata `stage`; absent = `gaussian`, rounds 1–5's files and the
/// embedded one). `pnp`: a plug-and-play stage network (`scripts/train_denoiser.py --stage-net`, round 6 of
/// MODEL.md: the same graph trained only on the iterates of `pnp-gap`'s multi-call schedule); none is embedded
/// (round 6's did not pay on validation).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    /// A Gaussian denoiser (σ the noise's standard deviation): `denoise`, the Gaussian benchmark.
    Gaussian,
    /// A plug-and-play stage network (σ the schedule's per-call value; trained on PnP's iterates).
    Pnp,
}

impl Stage {
    pub fn name(&self) -> &'static str {
        match self {
            Stage::Gaussian => "gaussian",
            Stage::Pnp => "pnp",
        }
    }
}

/// CRC-32 of the weights' bytes (the embedded file for `None`): identifies the checkpoint in records.
pub fn weights_crc32(path: Option<&Path>) -> Result<u32> {
    match path {
        None => Ok(crc32fast::hash(EMBEDDED)),
        Some(p) => read_weights(p).map(|b| crc32fast::hash(&b)),
    }
}

/// One convolution's weight and bias (also the layers of the unrolled network's stage denoisers,
/// [`super::unrolled`]).
pub(super) struct Layer {
    pub(super) weight: Tensor,
    /// (1, C_out, 1, 1), ready to broadcast; `None` for the linear spectral maps (no bias).
    pub(super) bias: Option<Tensor>,
}

impl Layer {
    /// The convolution (PyTorch's `Conv2d` with this `padding` and `stride`), its bias, then a ReLU if `relu`.
    pub(super) fn conv(&self, x: &Tensor, padding: usize, stride: usize, relu: bool) -> Result<Tensor> {
        let y = x.conv2d(&self.weight, padding, stride, 1, 1).map_err(cerr)?;
        let y = match &self.bias {
            Some(b) => y.broadcast_add(b).map_err(cerr)?,
            None => y,
        };
        if relu {
            y.relu().map_err(cerr)
        } else {
            Ok(y)
        }
    }

    /// The 2×2 stride-2 transposed convolution and its bias, plus the skip connection.
    pub(super) fn up(&self, x: &Tensor, skip: &Tensor) -> Result<Tensor> {
        let y = x.conv_transpose2d(&self.weight, 0, 0, 2, 1).map_err(cerr)?;
        let y = match &self.bias {
            Some(b) => y.broadcast_add(b).map_err(cerr)?,
            None => y,
        };
        (y + skip).map_err(cerr)
    }
}

/// The network: its layers, in the order of `diffcassi/denoiser.py`'s graph.
pub struct SpectralUNet {
    /// Bands the network was trained for.
    pub bands: usize,
    /// Width C (channels at full resolution).
    pub width: usize,
    /// Latent channels K of the linear spectral path (≤ bands).
    pub latent: usize,
    /// Where the weights came from (file path, or the embedded file's repository path).
    pub source: String,
    /// CRC-32 of the weights file's bytes.
    pub crc32: u32,
    /// What the weights were trained for (metadata `stage`).
    pub stage: Stage,
    /// Mean-colour neutralisation (default off, so PnP is unchanged; round 5, MODEL.md): the graph sees
    /// `x − m + ḡ` (m the cube's per-band spatial mean, ḡ the mean of m over the bands) and the output gets
    /// `m − ḡ` back, as `denoise(…, neutral=True)` in `diffcassi/denoiser.py`.
    pub neutral: bool,
    /// Geometric self-ensemble (default off: 8× the time): the mean over the eight dihedral transforms
    /// (quarter turns × a width flip, in [`DIHEDRAL`]'s order), as `denoise(…, ensemble=True)`.
    pub self_ensemble: bool,
    layers: Vec<Layer>,
    /// The caller's stop request ([`Denoiser::set_cancel`]), polled before each layer.
    cancel: Option<crate::cancel::Cancel>,
}

/// The self-ensemble's transforms, in the order both inferences sum them: (quarter turns k, flip) = a rotation
/// by k·90° as `torch.rot90(x, k, dims=(H, W))` (k = 1 maps out\[r\]\[c\] = in\[c\]\[W−1−r\]), then a reversal
/// of the width axis if flip.
pub const DIHEDRAL: [(u8, bool); 8] = [(0, false), (0, true), (1, false), (1, true), (2, false), (2, true), (3, false), (3, true)];

/// Source (row, col) in an `h`×`w` image of output pixel (r, c) of the transform (k, flip): the map of
/// [`Dihedral::source`], which both the self-ensemble and equivariant PnP use.
fn dihedral_src(k: u8, flip: bool, h: usize, w: usize, r: usize, c: usize) -> (usize, usize) {
    Dihedral { quarter_turns: k, flip }.source(h, w, r, c)
}

/// (name, transposed, C_in, C_out, kernel, bias) of every layer, in `diffcassi/denoiser.py`'s order;
/// transposed: weight C_in × C_out × k × k (PyTorch's layout), otherwise C_out × C_in × k × k. The 1×1
/// spectral maps `lat_enc` (E), `lat_dec` (D) and `bypass` (G) have no bias.
fn graph(bands: usize, c: usize, k: usize) -> [(&'static str, bool, usize, usize, usize, bool); 16] {
    let c2 = 2 * c;
    [
        ("lat_enc", false, bands, k, 1, false),
        ("head", false, k + 1, c, 3, true),
        ("enc1", false, c, c, 3, true),
        ("down1", false, c, c2, 2, true),
        ("enc2a", false, c2, c2, 3, true),
        ("enc2b", false, c2, c2, 3, true),
        ("down2", false, c2, c2, 2, true),
        ("mid_a", false, c2, c2, 3, true),
        ("mid_b", false, c2, c2, 3, true),
        ("up2", true, c2, c2, 2, true),
        ("dec2", false, c2, c2, 3, true),
        ("up1", true, c2, c, 2, true),
        ("dec1", false, c, c, 3, true),
        ("tail", false, c, k, 3, true),
        ("lat_dec", false, k, bands, 1, false),
        ("bypass", false, bands, bands, 1, false),
    ]
}

pub(super) fn ferr(source: &str, m: impl Into<String>) -> Error {
    Error::File { path: source.to_string(), message: m.into() }
}

/// The largest weights file read: 1 GiB (a width-1024 network of this architecture; the embedded width-64 one
/// is 4 MB).
pub const MAX_WEIGHTS_BYTES: u64 = 1 << 30;

/// The bytes of a weights file, which must be a regular file (not a folder, nor a FIFO, socket or device:
/// `/dev/zero` would be read until memory runs out, a FIFO would block) of at most [`MAX_WEIGHTS_BYTES`];
/// checked before it is opened.
fn read_weights(path: &Path) -> Result<Vec<u8>> {
    read_weights_as(path, "denoiser weights")
}

/// [`read_weights`] for the weights of `what` (named in the messages: `denoiser weights`, `unrolled weights`).
pub(super) fn read_weights_as(path: &Path, what: &str) -> Result<Vec<u8>> {
    use std::io::Read;
    let name = path.display().to_string();
    let cannot = |e: std::io::Error| ferr(&name, format!("cannot read the {what}: {e}"));
    let meta = std::fs::metadata(path).map_err(cannot)?;
    if meta.is_dir() {
        return Err(ferr(&name, format!("is a directory, not a weights file: the {what} must be a safetensors file")));
    }
    if !meta.is_file() {
        return Err(ferr(&name, format!("is not a regular file (a FIFO, socket or device such as /dev/zero): the {what} must be a safetensors file")));
    }
    let too_big = |n: u64| ferr(&name, format!("{n} bytes: larger than the {MAX_WEIGHTS_BYTES} bytes (1 GiB) a {what} file may have"));
    if meta.len() > MAX_WEIGHTS_BYTES {
        return Err(too_big(meta.len()));
    }
    let mut bytes = Vec::with_capacity(meta.len() as usize);
    std::fs::File::open(path).and_then(|f| f.take(MAX_WEIGHTS_BYTES + 1).read_to_end(&mut bytes)).map_err(cannot)?;
    if bytes.len() as u64 > MAX_WEIGHTS_BYTES {
        return Err(too_big(bytes.len() as u64));
    }
    Ok(bytes)
}

pub(super) fn cerr(e: candle_core::Error) -> Error {
    Error::invalid(format!("denoiser network (candle): {e}"))
}

/// Tensor `name` of a safetensors file, checked: present, f32, of `shape`, finite; errors name the file
/// (`source`), the tensor and `arch` (the architecture that needs it).
pub(super) fn load_tensor(st: &safetensors::SafeTensors, source: &str, name: &str, shape: &[usize], arch: &str) -> Result<Tensor> {
    let view = st.tensor(name).map_err(|_| ferr(source, format!("tensor `{name}` is missing ({arch} needs it, shape {shape:?})")))?;
    if view.dtype() != safetensors::Dtype::F32 {
        return Err(ferr(source, format!("tensor `{name}` is {:?}, expected F32", view.dtype())));
    }
    if view.shape() != shape {
        return Err(ferr(source, format!("tensor `{name}` has shape {:?}, expected {shape:?} (weights for another band count or width?)", view.shape())));
    }
    let data: Vec<f32> = view.data().chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect();
    if let Some(i) = data.iter().position(|v| !v.is_finite()) {
        return Err(ferr(source, format!("tensor `{name}` value {i} is {} (not finite)", data[i])));
    }
    Tensor::from_vec(data, shape, &Device::Cpu).map_err(cerr)
}

impl SpectralUNet {
    /// The committed checkpoint (a Gaussian denoiser), embedded in the binary.
    pub fn embedded() -> Result<Self> {
        Self::from_bytes(EMBEDDED, &format!("{EMBEDDED_PATH} (embedded)"))
    }

    /// The PnP solvers' network: the embedded weights (`None`) or a file's, of either stage — a Gaussian
    /// denoiser (the default) or a PnP-stage network (`stage` = `pnp`); the record says which (`stage`).
    pub fn load_pnp(path: Option<&Path>) -> Result<Self> {
        match path {
            None => Self::embedded(),
            Some(p) => Self::from_file(p),
        }
    }

    /// Weights from a safetensors file.
    pub fn from_file(path: &Path) -> Result<Self> {
        let bytes = read_weights(path)?;
        Self::from_bytes(&bytes, &path.display().to_string())
    }

    /// A Gaussian denoiser: the embedded weights (`None`) or a file's; a PnP-stage file (metadata `stage` =
    /// `pnp`: trained on PnP's iterates with the schedule's σ, not on Gaussian noise) is refused.
    pub fn load(path: Option<&Path>) -> Result<Self> {
        let net = match path {
            None => Self::embedded()?,
            Some(p) => Self::from_file(p)?,
        };
        if net.stage == Stage::Pnp {
            return Err(ferr(&net.source, "metadata `stage` = `pnp`: a plug-and-play stage network (trained on PnP's iterates), not a Gaussian denoiser; use it with --solver pnp-gap/pnp-admm, or give Gaussian weights"));
        }
        Ok(net)
    }

    /// Weights from the bytes of a safetensors file; `source` names it in errors.
    pub fn from_bytes(bytes: &[u8], source: &str) -> Result<Self> {
        let st = safetensors::SafeTensors::deserialize(bytes).map_err(|e| ferr(source, format!("not a valid safetensors file: {e}")))?;
        let (_, meta) = safetensors::SafeTensors::read_metadata(bytes).map_err(|e| ferr(source, format!("not a valid safetensors file: {e}")))?;
        let meta = meta.metadata().clone().unwrap_or_default();
        let get = |k: &str| meta.get(k).ok_or_else(|| ferr(source, format!("metadata field `{k}` is missing (expected arch = {ARCH}, bands, width, latent)")));
        let arch = get("arch")?;
        if arch != ARCH {
            let hint = if arch == "spectral-unet-v1" { " (a round-1/2 file: convert it with diffcassi.denoiser.from_v1)" } else { "" };
            return Err(ferr(source, format!("metadata `arch` = `{arch}`: this inference implements `{ARCH}` only{hint}")));
        }
        let num = |k: &str| -> Result<usize> {
            let v = get(k)?;
            v.trim().parse::<usize>().ok().filter(|n| *n > 0 && *n <= 4096).ok_or_else(|| ferr(source, format!("metadata `{k}` = `{v}` is not a positive integer ≤ 4096")))
        };
        let (bands, width, latent) = (num("bands")?, num("width")?, num("latent")?);
        let stage = match meta.get("stage").map(|s| s.as_str()) {
            None | Some("gaussian") => Stage::Gaussian,
            Some("pnp") => Stage::Pnp,
            Some(other) => return Err(ferr(source, format!("metadata `stage` = `{other}`: expected `gaussian` (or absent) or `pnp`"))),
        };
        if latent > bands {
            return Err(ferr(source, format!("metadata `latent` = {latent} exceeds `bands` = {bands}")));
        }
        let g = graph(bands, width, latent);
        let mut layers = Vec::with_capacity(g.len());
        let mut expected = std::collections::BTreeSet::new();
        for (name, transposed, cin, cout, k, has_bias) in g {
            let wshape = if transposed { [cin, cout, k, k] } else { [cout, cin, k, k] };
            let weight = Self::tensor(&st, source, &format!("{name}.weight"), &wshape)?;
            expected.insert(format!("{name}.weight"));
            let bias = if has_bias {
                expected.insert(format!("{name}.bias"));
                Some(Self::tensor(&st, source, &format!("{name}.bias"), &[cout])?.reshape((1, cout, 1, 1)).map_err(cerr)?)
            } else {
                None
            };
            layers.push(Layer { weight, bias });
        }
        if let Some(extra) = st.names().into_iter().find(|n| !expected.contains(*n)) {
            return Err(ferr(source, format!("tensor `{extra}` is not part of {ARCH} (expected {} tensors: lat_enc, head, …, tail, lat_dec, bypass)", expected.len())));
        }
        Ok(SpectralUNet { bands, width, latent, source: source.to_string(), crc32: crc32fast::hash(bytes), stage, neutral: false, self_ensemble: false, layers, cancel: None })
    }

    /// Tensor `name` of the file, checked: present, f32, of `shape`, finite.
    fn tensor(st: &safetensors::SafeTensors, source: &str, name: &str, shape: &[usize]) -> Result<Tensor> {
        load_tensor(st, source, name, shape, ARCH)
    }

    fn conv(&self, i: usize, x: &Tensor, padding: usize, stride: usize, relu: bool) -> Result<Tensor> {
        // The network's stop poll: one forward pass is ~0.5 s at 128² (seconds at 512²), 16 convolutions.
        crate::cancel::check(self.cancel.as_ref())?;
        self.layers[i].conv(x, padding, stride, relu)
    }

    fn up(&self, i: usize, x: &Tensor, skip: &Tensor) -> Result<Tensor> {
        self.layers[i].up(x, skip)
    }

    /// The graph on x (1, bands, H, W) and the σ plane (1, 1, H, W), H and W multiples of 4: returns
    /// `D·(z − U([z, σ])) + G·x` with `z = E·x` (1, bands, H, W).
    fn forward(&self, x: &Tensor, sigma: &Tensor) -> Result<Tensor> {
        let lat = self.conv(0, x, 0, 1, false)?;
        let z = Tensor::cat(&[&lat, sigma], 1).map_err(cerr)?;
        let z = self.conv(1, &z, 1, 1, true)?;
        let e1 = self.conv(2, &z, 1, 1, true)?;
        let z = self.conv(3, &e1, 0, 2, true)?;
        let z = self.conv(4, &z, 1, 1, true)?;
        let e2 = self.conv(5, &z, 1, 1, true)?;
        let z = self.conv(6, &e2, 0, 2, true)?;
        let z = self.conv(7, &z, 1, 1, true)?;
        let z = self.conv(8, &z, 1, 1, true)?;
        let z = self.up(9, &z, &e2)?;
        let z = self.conv(10, &z, 1, 1, true)?;
        let z = self.up(11, &z, &e1)?;
        let z = self.conv(12, &z, 1, 1, true)?;
        let u = self.conv(13, &z, 1, 1, false)?;
        let clean = (lat - u).map_err(cerr)?;
        let y = self.conv(14, &clean, 0, 1, false)?;
        (y + self.conv(15, x, 0, 1, false)?).map_err(cerr)
    }

    /// Memory of one call (bytes, f32 activations at their peak, about): the budget [`Denoiser::denoise`]
    /// checks (in f64: sizes from C++ or Python may overflow a `usize` product).
    pub fn activation_bytes(&self, height: usize, width: usize) -> f64 {
        let (h, w) = (height.div_ceil(4) as f64 * 4.0, width.div_ceil(4) as f64 * 4.0);
        // The band planes three times (the padded input, the output tensor and its flattened copy), the latent
        // and its σ-concatenated copy, at full resolution five C-channel tensors at once (e1, kept to the
        // end, and at dec1/up1: the layer's input, candle's NHWC copy of it, the convolution's output and
        // its bias-added copy; measured 0.69 GB at 512² where the earlier 3 C gave 0.48 GB, round 19), e2 and
        // two half-resolution temporaries; im2col tiles apart.
        4.0 * h * w * (3 * self.bands + 2 * (self.latent + 1) + 5 * self.width + 3 * 2 * self.width / 4) as f64
    }
}

impl Denoiser for SpectralUNet {
    fn name(&self) -> String {
        ARCH.into()
    }

    fn set_cancel(&mut self, cancel: Option<crate::cancel::Cancel>) {
        self.cancel = cancel;
    }

    fn denoise(&mut self, x: &[f32], out: &mut [f32], shape: CubeShape, sigma: f32) -> Result<()> {
        let (h, w, b) = (shape.height, shape.width, shape.bands);
        if b != self.bands {
            // A mismatch of the data, not a bad file: a value error (Python raised an OSError; round 15).
            return Err(Error::invalid(format!("{}: the denoiser was trained for {} bands, the cube has {b}", self.source, self.bands)));
        }
        if x.len() != shape.len() || out.len() != shape.len() || h == 0 || w == 0 {
            return Err(Error::invalid(format!("denoiser: the cube has {} values (output {}), shape {h}×{w}×{b} needs {}", x.len(), out.len(), shape.len())));
        }
        if !sigma.is_finite() || sigma < 0.0 {
            return Err(Error::invalid(format!("denoiser: the noise level σ = {sigma} must be finite and ≥ 0")));
        }
        // Its activations within the memory budget: a 2048×2048 cube asked for gigabytes and aborted the process
        // on allocation (C++ and Python; a held-out battery, round 9).
        // Checked beside what the process holds (the solver's arrays, the operator's transport, the render
        // record: [`crate::limits::hold`]), not against the whole budget (round 19: 0.92 GB under 0.5 GB).
        crate::limits::check_memory(&format!("denoiser on a {h}×{w}×{b} cube (activations)"), self.activation_bytes(h, w) + 8.0 * shape.len() as f64)?;
        // Mean-colour neutralisation: shift_b = m_b − ḡ (f64 sums; PyTorch's f32 mean agrees to ~1e-7).
        let shift: Vec<f32> = if self.neutral {
            let mut m = vec![0.0f64; b];
            for px in x.chunks_exact(b) {
                for (a, v) in m.iter_mut().zip(px) {
                    *a += *v as f64;
                }
            }
            let n = (h * w) as f64;
            let g = m.iter().sum::<f64>() / (n * b as f64);
            m.iter().map(|a| (a / n - g) as f32).collect()
        } else {
            vec![0.0; b]
        };
        let xs: Vec<f32> = x.chunks_exact(b).flat_map(|px| px.iter().zip(&shift).map(|(v, s)| v - s)).collect();
        if !self.self_ensemble {
            self.run(&xs, out, h, w, sigma)?;
        } else {
            // Σ over the transforms of T⁻¹(net(T x)), then / 8 (the order of DIHEDRAL, as PyTorch sums it).
            let mut acc = vec![0.0f32; shape.len()];
            let mut t = vec![0.0f32; shape.len()];
            let mut o = vec![0.0f32; shape.len()];
            for (k, flip) in DIHEDRAL {
                let (th, tw) = if k % 2 == 1 { (w, h) } else { (h, w) };
                for r in 0..th {
                    for c in 0..tw {
                        let (sr, sc) = dihedral_src(k, flip, h, w, r, c);
                        t[(r * tw + c) * b..][..b].copy_from_slice(&xs[(sr * w + sc) * b..][..b]);
                    }
                }
                self.run(&t, &mut o, th, tw, sigma)?;
                // Back: output pixel (r, c) of the transformed image came from (sr, sc) of the original.
                for r in 0..th {
                    for c in 0..tw {
                        let (sr, sc) = dihedral_src(k, flip, h, w, r, c);
                        for (a, v) in acc[(sr * w + sc) * b..][..b].iter_mut().zip(&o[(r * tw + c) * b..][..b]) {
                            *a += *v;
                        }
                    }
                }
            }
            for (d, a) in out.iter_mut().zip(&acc) {
                *d = a / DIHEDRAL.len() as f32;
            }
        }
        for px in out.chunks_exact_mut(b) {
            for (v, s) in px.iter_mut().zip(&shift) {
                *v += s;
            }
        }
        if let Some(i) = out.iter().position(|v| !v.is_finite()) {
            return Err(Error::invalid(format!("denoiser ({}): output value {i} is not finite (input out of the network's range?)", self.source)));
        }
        Ok(())
    }

    fn describe(&self) -> serde_json::Value {
        serde_json::json!({ "name": ARCH, "weights": self.source, "weights_crc32": self.crc32, "stage": self.stage.name(), "bands": self.bands, "width": self.width, "latent": self.latent, "neutral_mean_colour": self.neutral, "self_ensemble": self.self_ensemble })
    }
}

impl SpectralUNet {
    /// The graph on one h×w cube `[row][col][band]` (already neutralised), padded to multiples of 4 by edge
    /// replication and cropped back into `out`.
    fn run(&self, x: &[f32], out: &mut [f32], h: usize, w: usize, sigma: f32) -> Result<()> {
        let b = self.bands;
        // (1, B, Hp, Wp), padded at the bottom/right by edge replication, and the σ plane.
        let (input, hp, wp) = padded_band_planes(x, h, w, b);
        let plane = hp * wp;
        let t = Tensor::from_vec(input, (1, b, hp, wp), &Device::Cpu).map_err(cerr)?;
        let s = Tensor::from_vec(vec![sigma; plane], (1, 1, hp, wp), &Device::Cpu).map_err(cerr)?;
        let y = self.forward(&t, &s)?.flatten_all().and_then(|n| n.to_vec1::<f32>()).map_err(cerr)?;
        // Cropped, back to [row][col][band].
        for r in 0..h {
            for c in 0..w {
                let o = (r * w + c) * b;
                for k in 0..b {
                    out[o + k] = y[k * plane + r * wp + c];
                }
            }
        }
        Ok(())
    }
}

/// `out` ← (v + L v) + U(v), PyTorch's order of the sums, for the unrolled networks' stage priors: `v` the
/// `h × w × b` cube ([row][col][band]), `lin` = L v and `tail` = U(v) as (1, b, hp, wp) tensors of the padded
/// planes ([`padded_band_planes`]), cropped back to h × w.
#[allow(clippy::too_many_arguments)]
pub(crate) fn add_residual_cropped(v: &[f32], lin: Tensor, tail: Tensor, out: &mut [f32], h: usize, w: usize, b: usize, wp: usize) -> Result<()> {
    let flat = |t: Tensor| t.flatten_all().and_then(|t| t.to_vec1::<f32>()).map_err(cerr);
    let (lin, tail) = (flat(lin)?, flat(tail)?);
    let plane = lin.len() / b.max(1);
    for r in 0..h {
        for c in 0..w {
            let o = (r * w + c) * b;
            for j in 0..b {
                let i = j * plane + r * wp + c;
                out[o + j] = (v[o + j] + lin[i]) + tail[i];
            }
        }
    }
    Ok(())
}

/// A `h × w × b` cube ([row][col][band]) as `b` band planes (band-major, the (1, B, Hp, Wp) tensor layout) of
/// `hp × wp`, the sides rounded up to multiples of 4 and padded at the bottom and right by edge replication
/// (what the U-Nets' two 2× downsamplings need). Returns the planes, hp and wp.
pub(crate) fn padded_band_planes(x: &[f32], h: usize, w: usize, b: usize) -> (Vec<f32>, usize, usize) {
    let (hp, wp) = (h.div_ceil(4) * 4, w.div_ceil(4) * 4);
    let plane = hp * wp;
    let mut input = vec![0.0f32; b * plane];
    for r in 0..hp {
        let rs = r.min(h - 1);
        for c in 0..wp {
            for (k, v) in x[(rs * w + c.min(w - 1)) * b..][..b].iter().enumerate() {
                input[k * plane + r * wp + c] = *v;
            }
        }
    }
    (input, hp, wp)
}

