//! The learned part of the unrolled network v2 (arch `unrolled-dauhst-v2`, `UnrolledDAUHST` in
//! `diffcassi/unrolled.py`, model card `diffcassi/weights/UNROLLED.md`): per stage a degradation estimator E_k
//! and a noise-conditioned spectral–spatial prior P_k, read from the safetensors file the PyTorch training
//! writes and run on candle's CPU tensors in f32. The graph around them (GAP initialisation, scale, the data
//! steps with the exact operator) is [`crate::recon::unrolled`]; this file knows no operator.
//!
//! **Degradation estimator** (`DegradationEstimator`, B bands): on [x/s, r/s] (2B channels, unpadded):
//! 3×3/2 (→ 32, padding 1), ReLU, 3×3/2 (32 → 32), ReLU, mean over the pixels, linear 32 → 32, ReLU, linear
//! 32 → 2, softplus (PyTorch's: x above 20 is kept) → (μ, σ).
//!
//! **Prior** (`SpectralSpatialUNet`, width C): P(v, σ) = (v + L v) + U([v, σ]) — L a 1×1 B → B convolution
//! without bias; U, on the input padded at the bottom and right by edge replication to multiples of 4 with σ as
//! a constant extra channel: embed 3×3 (B + 1 → C), block; 4×4/2 down (C → 2C, padding 1), block; 4×4/2 down
//! (→ 4C), two blocks; 2×2/2 transposed up (4C → 2C), concatenated with level 2, 1×1 fuse (4C → 2C), block;
//! the same to C; 3×3 out (C → B), cropped back. A **block** (`SpectralSpatialBlock`) is x + S-MSA(LN x), then
//! + FFN(LN x): LN a layer norm over the channels of each pixel (ε 1e-6, affine); S-MSA MST's spectral-wise
//! attention — 1×1 to q, k, v (no bias); per head (C/heads = C channels, heads 1, 2, 4 at the three levels) q
//! and k L2-normalised over the pixels (ε 1e-12), softmax((q kᵀ) · temperature_head) over the last axis, times
//! v; a 1×1 projection (bias) plus a depth-wise 3×3 convolution of v (bias); FFN 1×1 (C → 2C), GELU (erf),
//! depth-wise 3×3, GELU, 1×1 (2C → C).
//!
//! ```
//! // The architecture tag v2 weights carry.
//! assert_eq!(diffcassi::recon::prior::unrolled_v2::ARCH_V2, "unrolled-dauhst-v2");
//! ```
use super::network::{cerr, ferr, load_tensor};
use crate::recon::layout::to_band_major;
use crate::error::Result;
use candle_core::{Device, Tensor, D};
use std::collections::BTreeSet;

/// The architecture name v2 weights' metadata carries.
pub const ARCH_V2: &str = "unrolled-dauhst-v2";

/// Hidden width of the degradation estimators (`DegradationEstimator(bands, hidden=32)`).
const HIDDEN: usize = 32;

/// Reads the v2 tensors of a safetensors file, recording each name it takes (so that the caller can refuse any
/// other tensor); without a file (`st` `None`) it lists the names and shapes and gives zeros.
struct Reader<'a> {
    st: Option<&'a safetensors::SafeTensors<'a>>,
    source: &'a str,
    taken: BTreeSet<String>,
    listing: Vec<(String, Vec<usize>)>,
}

impl Reader<'_> {
    fn tensor(&mut self, name: &str, shape: &[usize]) -> Result<Tensor> {
        let t = match self.st {
            Some(st) => load_tensor(st, self.source, name, shape, ARCH_V2)?,
            None => Tensor::zeros(shape, candle_core::DType::F32, &Device::Cpu).map_err(cerr)?,
        };
        self.taken.insert(name.to_string());
        self.listing.push((name.to_string(), shape.to_vec()));
        Ok(t)
    }

    /// A convolution (or, `transposed`, a transposed convolution: weight C_in × C_out × k × k) with `groups`.
    fn conv(&mut self, name: &str, cin: usize, cout: usize, k: usize, groups: usize, bias: bool, transposed: bool) -> Result<Conv> {
        let shape = if transposed { [cin, cout, k, k] } else { [cout, cin / groups, k, k] };
        let weight = self.tensor(&format!("{name}.weight"), &shape)?;
        let bias = if bias { Some(self.tensor(&format!("{name}.bias"), &[cout])?.reshape((1, cout, 1, 1)).map_err(cerr)?) } else { None };
        Ok(Conv { weight, bias, groups })
    }

    fn norm(&mut self, name: &str, c: usize) -> Result<Norm> {
        let weight = self.tensor(&format!("{name}.weight"), &[c])?.reshape((1, c, 1, 1)).map_err(cerr)?;
        let bias = self.tensor(&format!("{name}.bias"), &[c])?.reshape((1, c, 1, 1)).map_err(cerr)?;
        Ok(Norm { weight, bias })
    }

    fn block(&mut self, name: &str, c: usize, heads: usize) -> Result<Block> {
        Ok(Block {
            n1: self.norm(&format!("{name}.n1"), c)?,
            qkv: self.conv(&format!("{name}.attn.qkv"), c, 3 * c, 1, 1, false, false)?,
            temperature: self.tensor(&format!("{name}.attn.temperature"), &[heads, 1, 1])?.reshape((1, heads, 1, 1)).map_err(cerr)?,
            proj: self.conv(&format!("{name}.attn.proj"), c, c, 1, 1, true, false)?,
            pos: self.conv(&format!("{name}.attn.pos"), c, c, 3, c, true, false)?,
            n2: self.norm(&format!("{name}.n2"), c)?,
            ffn0: self.conv(&format!("{name}.ffn.0"), c, 2 * c, 1, 1, true, false)?,
            ffn2: self.conv(&format!("{name}.ffn.2"), 2 * c, 2 * c, 3, 2 * c, true, false)?,
            ffn4: self.conv(&format!("{name}.ffn.4"), 2 * c, c, 1, 1, true, false)?,
            heads,
        })
    }

    fn linear(&mut self, name: &str, cin: usize, cout: usize) -> Result<(Tensor, Tensor)> {
        // y = x Wᵀ + b with W (out, in): stored transposed once, (in, out).
        let w = self.tensor(&format!("{name}.weight"), &[cout, cin])?.t().and_then(|t| t.contiguous()).map_err(cerr)?;
        let b = self.tensor(&format!("{name}.bias"), &[cout])?.reshape((1, cout)).map_err(cerr)?;
        Ok((w, b))
    }
}

/// A convolution's weight, bias (1, C_out, 1, 1) and groups.
struct Conv {
    weight: Tensor,
    bias: Option<Tensor>,
    groups: usize,
}

impl Conv {
    fn apply(&self, x: &Tensor, padding: usize, stride: usize) -> Result<Tensor> {
        if self.groups > 1 && stride == 1 && x.dims4().is_ok_and(|(n, c, ..)| n == 1 && c == self.groups) {
            return self.depthwise(x, padding);
        }
        let y = x.conv2d(&self.weight, padding, stride, 1, self.groups).map_err(cerr)?;
        match &self.bias {
            Some(b) => y.broadcast_add(b).map_err(cerr),
            None => Ok(y),
        }
    }

    /// A depth-wise convolution (groups = channels: the blocks' 3×3 position and FFN layers), computed directly
    /// per channel: candle runs a grouped convolution as one small convolution per group, which dominated the
    /// forward pass. The same sums as PyTorch's (zero padding; taps in row-major order, then the bias).
    /// One image (n = 1) with as many channels as groups, stride 1 (what [`Self::apply`] sends here).
    fn depthwise(&self, x: &Tensor, padding: usize) -> Result<Tensor> {
        use rayon::prelude::*;
        let (_, c, h, w) = x.dims4().map_err(cerr)?;
        let (_, _, kh, kw) = self.weight.dims4().map_err(cerr)?;
        let input = x.flatten_all().and_then(|t| t.to_vec1::<f32>()).map_err(cerr)?;
        let k = self.weight.flatten_all().and_then(|t| t.to_vec1::<f32>()).map_err(cerr)?;
        let bias = match &self.bias {
            Some(b) => b.flatten_all().and_then(|t| t.to_vec1::<f32>()).map_err(cerr)?,
            None => vec![0.0; c],
        };
        let (ho, wo) = (h + 2 * padding + 1 - kh, w + 2 * padding + 1 - kw);
        let mut out = vec![0.0f32; c * ho * wo];
        out.par_chunks_mut(ho * wo).enumerate().for_each(|(ch, o)| {
            let (src, kk) = (&input[ch * h * w..(ch + 1) * h * w], &k[ch * kh * kw..(ch + 1) * kh * kw]);
            for r in 0..ho {
                for col in 0..wo {
                    let mut acc = 0.0f32;
                    for i in 0..kh {
                        let rr = (r + i) as isize - padding as isize;
                        if rr < 0 || rr >= h as isize {
                            continue;
                        }
                        for j in 0..kw {
                            let cc = (col + j) as isize - padding as isize;
                            if cc >= 0 && cc < w as isize {
                                acc += src[rr as usize * w + cc as usize] * kk[i * kw + j];
                            }
                        }
                    }
                    o[r * wo + col] = acc + bias[ch];
                }
            }
        });
        Tensor::from_vec(out, (1, c, ho, wo), &Device::Cpu).map_err(cerr)
    }

    /// The 2×2 stride-2 transposed convolution and its bias.
    fn up(&self, x: &Tensor) -> Result<Tensor> {
        let y = x.conv_transpose2d(&self.weight, 0, 0, 2, 1).map_err(cerr)?;
        match &self.bias {
            Some(b) => y.broadcast_add(b).map_err(cerr),
            None => Ok(y),
        }
    }
}

/// Layer normalisation over the channels of every pixel (`LayerNorm2d`: biased variance, ε = 1e-6).
struct Norm {
    weight: Tensor,
    bias: Tensor,
}

impl Norm {
    fn apply(&self, x: &Tensor) -> Result<Tensor> {
        let f = || -> candle_core::Result<Tensor> {
            let xc = x.broadcast_sub(&x.mean_keepdim(1)?)?;
            let var = xc.sqr()?.mean_keepdim(1)?;
            xc.broadcast_div(&(var + 1e-6)?.sqrt()?)?.broadcast_mul(&self.weight)?.broadcast_add(&self.bias)
        };
        f().map_err(cerr)
    }
}

/// One `SpectralSpatialBlock`.
struct Block {
    n1: Norm,
    qkv: Conv,
    /// (1, heads, 1, 1).
    temperature: Tensor,
    proj: Conv,
    pos: Conv,
    n2: Norm,
    ffn0: Conv,
    ffn2: Conv,
    ffn4: Conv,
    heads: usize,
}

impl Block {
    fn apply(&self, x: &Tensor) -> Result<Tensor> {
        let x = (x + self.attention(&self.n1.apply(x)?)?).map_err(cerr)?;
        let f = self.ffn0.apply(&self.n2.apply(&x)?, 0, 1)?.gelu_erf().map_err(cerr)?;
        let f = self.ffn2.apply(&f, 1, 1)?.gelu_erf().map_err(cerr)?;
        (x + self.ffn4.apply(&f, 0, 1)?).map_err(cerr)
    }

    /// MST's S-MSA: the tokens are the channels.
    fn attention(&self, x: &Tensor) -> Result<Tensor> {
        let (n, c, h, w) = x.dims4().map_err(cerr)?;
        let qkv = self.qkv.apply(x, 0, 1)?;
        let part = |i: usize| qkv.narrow(1, i * c, c).map_err(cerr);
        let (q, k, v) = (part(0)?, part(1)?, part(2)?);
        let d = c / self.heads;
        let f = || -> candle_core::Result<Tensor> {
            let split = |t: &Tensor| t.contiguous()?.reshape((n, self.heads, d, h * w));
            // F.normalize: t / max(‖t‖₂, 1e-12) over the pixels.
            let normalize = |t: Tensor| -> candle_core::Result<Tensor> {
                let norm = t.sqr()?.sum_keepdim(D::Minus1)?.sqrt()?.maximum(1e-12)?;
                t.broadcast_div(&norm)
            };
            let (q, kk, vv) = (normalize(split(&q)?)?, normalize(split(&k)?)?, split(&v)?);
            let logits = q.matmul(&kk.t()?.contiguous()?)?.broadcast_mul(&self.temperature)?;
            let e = logits.broadcast_sub(&logits.max_keepdim(D::Minus1)?)?.exp()?;
            let attn = e.broadcast_div(&e.sum_keepdim(D::Minus1)?)?;
            attn.matmul(&vv)?.reshape((n, c, h, w))
        };
        let out = f().map_err(cerr)?;
        (self.proj.apply(&out, 0, 1)? + self.pos.apply(&v, 1, 1)?).map_err(cerr)
    }
}

/// One stage's `SpectralSpatialUNet`.
struct Prior {
    linear: Conv,
    embed: Conv,
    enc1: Block,
    down1: Conv,
    enc2: Block,
    down2: Conv,
    mid: [Block; 2],
    up2: Conv,
    fuse2: Conv,
    dec2: Block,
    up1: Conv,
    fuse1: Conv,
    dec1: Block,
    out: Conv,
}

/// One stage's `DegradationEstimator`.
struct Estimator {
    conv0: Conv,
    conv2: Conv,
    mlp0: (Tensor, Tensor),
    mlp2: (Tensor, Tensor),
}

/// PyTorch's `F.softplus` (β = 1, threshold 20).
fn softplus(x: f32) -> f32 {
    if x > 20.0 {
        x
    } else {
        x.exp().ln_1p()
    }
}

/// The v2 network's learned part: per stage an estimator and a prior.
pub struct DauhstV2 {
    bands: usize,
    width: usize,
    estimators: Vec<Estimator>,
    priors: Vec<Prior>,
}

impl DauhstV2 {
    /// The tensors of `stages` stages of a v2 network (B `bands`, width C), checked (present, f32, shape,
    /// finite); returns the network and the names it read (the caller refuses any other tensor).
    pub fn read(st: &safetensors::SafeTensors<'_>, source: &str, stages: usize, bands: usize, width: usize) -> Result<(Self, BTreeSet<String>)> {
        let mut r = Reader { st: Some(st), source, taken: BTreeSet::new(), listing: Vec::new() };
        let net = Self::read_with(&mut r, stages, bands, width)?;
        Ok((net, r.taken))
    }

    /// The tensors a v2 file of `stages` stages, `bands` bands and width `width` holds: (name, shape) in the
    /// order [`Self::read`] reads them (PyTorch's `state_dict` names; e.g. to write such a file in a test).
    pub fn tensor_shapes(stages: usize, bands: usize, width: usize) -> Result<Vec<(String, Vec<usize>)>> {
        let mut r = Reader { st: None, source: "(listing)", taken: BTreeSet::new(), listing: Vec::new() };
        Self::read_with(&mut r, stages, bands, width)?;
        Ok(r.listing)
    }

    fn read_with(r: &mut Reader<'_>, stages: usize, bands: usize, width: usize) -> Result<Self> {
        let c = width;
        let (mut estimators, mut priors) = (Vec::with_capacity(stages), Vec::with_capacity(stages));
        for k in 0..stages {
            let e = format!("estimators.{k}");
            estimators.push(Estimator {
                conv0: r.conv(&format!("{e}.conv.0"), 2 * bands, HIDDEN, 3, 1, true, false)?,
                conv2: r.conv(&format!("{e}.conv.2"), HIDDEN, HIDDEN, 3, 1, true, false)?,
                mlp0: r.linear(&format!("{e}.mlp.0"), HIDDEN, HIDDEN)?,
                mlp2: r.linear(&format!("{e}.mlp.2"), HIDDEN, 2)?,
            });
            let p = format!("priors.{k}");
            priors.push(Prior {
                linear: r.conv(&format!("{p}.linear"), bands, bands, 1, 1, false, false)?,
                embed: r.conv(&format!("{p}.embed"), bands + 1, c, 3, 1, true, false)?,
                enc1: r.block(&format!("{p}.enc1"), c, 1)?,
                down1: r.conv(&format!("{p}.down1"), c, 2 * c, 4, 1, true, false)?,
                enc2: r.block(&format!("{p}.enc2"), 2 * c, 2)?,
                down2: r.conv(&format!("{p}.down2"), 2 * c, 4 * c, 4, 1, true, false)?,
                mid: [r.block(&format!("{p}.mid.0"), 4 * c, 4)?, r.block(&format!("{p}.mid.1"), 4 * c, 4)?],
                up2: r.conv(&format!("{p}.up2"), 4 * c, 2 * c, 2, 1, true, true)?,
                fuse2: r.conv(&format!("{p}.fuse2"), 4 * c, 2 * c, 1, 1, true, false)?,
                dec2: r.block(&format!("{p}.dec2"), 2 * c, 2)?,
                up1: r.conv(&format!("{p}.up1"), 2 * c, c, 2, 1, true, true)?,
                fuse1: r.conv(&format!("{p}.fuse1"), 2 * c, c, 1, 1, true, false)?,
                dec1: r.block(&format!("{p}.dec1"), c, 1)?,
                out: r.conv(&format!("{p}.out"), c, bands, 3, 1, true, false)?,
            });
        }
        Ok(DauhstV2 { bands, width, estimators, priors })
    }

    /// Stage `k` exists and every cube of `cubes` is h×w×B (an error, not a panic, from the public calls).
    fn check(&self, k: usize, cubes: &[&[f32]], h: usize, w: usize) -> Result<()> {
        let n = h * w * self.bands;
        if k >= self.priors.len() || h == 0 || w == 0 || cubes.iter().any(|c| c.len() != n) {
            let lens: Vec<usize> = cubes.iter().map(|c| c.len()).collect();
            return Err(crate::error::Error::invalid(format!("{ARCH_V2} stage {k}: a {h}×{w}×{} cube needs {n} values (got {lens:?}; {} stages)", self.bands, self.priors.len())));
        }
        Ok(())
    }

    /// Stages K.
    pub fn stages(&self) -> usize {
        self.priors.len()
    }

    /// Width C of the priors' U-Nets.
    pub fn width(&self) -> usize {
        self.width
    }

    /// (μ_k, σ_k) = E_k(x, r) for h×w cubes `[row][col][band]` already divided by the scale s (stage `k` < K).
    pub fn estimate(&self, k: usize, x: &[f32], r: &[f32], h: usize, w: usize) -> Result<(f32, f32)> {
        let b = self.bands;
        self.check(k, &[x, r], h, w)?;
        let e = &self.estimators[k];
        let mut input = to_band_major(x, h * w, b);
        input.extend(to_band_major(r, h * w, b));
        let t = Tensor::from_vec(input, (1, 2 * b, h, w), &Device::Cpu).map_err(cerr)?;
        let z = e.conv0.apply(&t, 1, 2)?.relu().map_err(cerr)?;
        let z = e.conv2.apply(&z, 1, 2)?.relu().map_err(cerr)?;
        let f = || -> candle_core::Result<Vec<f32>> {
            let m = z.mean(D::Minus1)?.mean(D::Minus1)?; // (1, 32)
            let h1 = m.matmul(&e.mlp0.0)?.broadcast_add(&e.mlp0.1)?.relu()?;
            h1.matmul(&e.mlp2.0)?.broadcast_add(&e.mlp2.1)?.flatten_all()?.to_vec1::<f32>()
        };
        let o = f().map_err(cerr)?;
        Ok((softplus(o[0]), softplus(o[1])))
    }

    /// `out` ← P_k(`v`, σ) for an h×w cube `[row][col][band]` of the network's band count (stage `k` < K).
    pub fn prior(&self, k: usize, v: &[f32], sigma: f32, out: &mut [f32], h: usize, w: usize) -> Result<()> {
        let b = self.bands;
        self.check(k, &[v, &*out], h, w)?;
        let p = &self.priors[k];
        let (input, hp, wp) = super::network::padded_band_planes(v, h, w, b);
        let x = Tensor::from_vec(input, (1, b, hp, wp), &Device::Cpu).map_err(cerr)?;
        let s = Tensor::full(sigma, (1, 1, hp, wp), &Device::Cpu).map_err(cerr)?;
        let cat = |a: &Tensor, c: &Tensor| Tensor::cat(&[a, c], 1).map_err(cerr);
        let e1 = p.enc1.apply(&p.embed.apply(&cat(&x, &s)?, 1, 1)?)?;
        let e2 = p.enc2.apply(&p.down1.apply(&e1, 1, 2)?)?;
        let z = p.mid[1].apply(&p.mid[0].apply(&p.down2.apply(&e2, 1, 2)?)?)?;
        let z = p.dec2.apply(&p.fuse2.apply(&cat(&p.up2.up(&z)?, &e2)?, 0, 1)?)?;
        let z = p.dec1.apply(&p.fuse1.apply(&cat(&p.up1.up(&z)?, &e1)?, 0, 1)?)?;
        let lin = p.linear.apply(&x, 0, 1)?;
        let tail = p.out.apply(&z, 1, 1)?;
        super::network::add_residual_cropped(v, lin, tail, out, h, w, b, wp)
    }
}

/// Checks the names of a v2 file: `taken` (what [`DauhstV2::read`] read) must be all its tensors.
pub fn refuse_extra(st: &safetensors::SafeTensors<'_>, source: &str, taken: &BTreeSet<String>, stages: usize) -> Result<()> {
    if let Some(extra) = st.names().into_iter().find(|n| !taken.contains(*n)) {
        return Err(ferr(source, format!("tensor `{extra}` is not part of {ARCH_V2} with stages = {stages} (expected {} tensors: estimators.K.…, priors.K.…)", taken.len())));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A network of zero weights (the listing reader's), so the shapes and the checks run without a file.
    fn zero_net(stages: usize, bands: usize, width: usize) -> DauhstV2 {
        let mut r = Reader { st: None, source: "(test)", taken: BTreeSet::new(), listing: Vec::new() };
        DauhstV2::read_with(&mut r, stages, bands, width).unwrap()
    }

    #[test]
    fn wrong_sizes_and_stages_are_errors_and_zero_weights_give_softplus_0_and_the_identity() {
        let net = zero_net(1, 3, 2);
        let (h, w) = (5, 6);
        let x: Vec<f32> = (0..h * w * 3).map(|i| (i % 7) as f32 * 0.1).collect();
        let (mu, sigma) = net.estimate(0, &x, &x, h, w).unwrap();
        assert_eq!((mu, sigma), (softplus(0.0), softplus(0.0)));
        assert!((mu - std::f32::consts::LN_2).abs() < 1e-7);
        // Zero L and U: P(v) = v.
        let mut out = vec![f32::NAN; x.len()];
        net.prior(0, &x, 0.05, &mut out, h, w).unwrap();
        assert_eq!(out, x);
        let e = net.estimate(0, &x[1..], &x, h, w).unwrap_err().to_string();
        assert!(e.contains("stage 0: a 5×6×3 cube needs 90 values") && e.contains("[89, 90]"), "{e}");
        assert!(net.prior(1, &x, 0.05, &mut out, h, w).unwrap_err().to_string().contains("1 stages"));
        assert!(net.prior(0, &x, 0.05, &mut out[1..], h, w).is_err());
        assert!(net.estimate(0, &[], &[], 0, 0).is_err());
    }

    /// The direct depth-wise path equals candle's grouped convolution, which it replaces, to rounding, and
    /// the sum in PyTorch's order (taps in row-major order from +0, padding skipped, then the bias) bit for
    /// bit, on 3×3 with and without padding and 1×1 kernels, signed zeros in the input.
    #[test]
    fn depthwise_rows_equal_the_direct_sum_bit_for_bit() {
        let (c, h, w) = (3usize, 7usize, 9usize);
        let mut state = 12345u64;
        let mut rnd = || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((state >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
        };
        let mut input: Vec<f32> = (0..c * h * w).map(|_| rnd()).collect();
        input[10] = 0.0;
        input[11] = -0.0;
        for (k, padding) in [(3usize, 1usize), (1, 0), (3, 0)] {
            let weights: Vec<f32> = (0..c * k * k).map(|_| rnd()).collect();
            let bias: Vec<f32> = (0..c).map(|_| rnd()).collect();
            let conv = Conv {
                weight: Tensor::from_vec(weights.clone(), (c, 1, k, k), &Device::Cpu).unwrap(),
                bias: Some(Tensor::from_vec(bias.clone(), c, &Device::Cpu).unwrap().reshape((1, c, 1, 1)).unwrap()),
                groups: c,
            };
            let x = Tensor::from_vec(input.clone(), (1, c, h, w), &Device::Cpu).unwrap();
            let got = conv.depthwise(&x, padding).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap();
            let (ho, wo) = (h + 2 * padding + 1 - k, w + 2 * padding + 1 - k);
            let mut want = vec![0.0f32; c * ho * wo];
            for ch in 0..c {
                for r in 0..ho {
                    for col in 0..wo {
                        let mut acc = 0.0f32;
                        for i in 0..k {
                            for j in 0..k {
                                let (rr, cc) = ((r + i) as isize - padding as isize, (col + j) as isize - padding as isize);
                                if rr >= 0 && rr < h as isize && cc >= 0 && cc < w as isize {
                                    acc += input[ch * h * w + rr as usize * w + cc as usize] * weights[ch * k * k + i * k + j];
                                }
                            }
                        }
                        want[ch * ho * wo + r * wo + col] = acc + bias[ch];
                    }
                }
            }
            assert!(got.iter().zip(&want).all(|(a, b)| a.to_bits() == b.to_bits()), "k {k}, padding {padding}");
            let grouped = x.conv2d(&conv.weight, padding, 1, 1, c).unwrap().broadcast_add(conv.bias.as_ref().unwrap()).unwrap();
            let grouped = grouped.flatten_all().unwrap().to_vec1::<f32>().unwrap();
            assert!(got.iter().zip(&grouped).all(|(a, b)| (a - b).abs() <= 1e-6), "k {k}: candle's grouped convolution");
        }
    }
}
