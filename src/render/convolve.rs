//! Register-blocked direct convolution and correlation with an [`AiryKernel`], on a detector-sized scratch
//! image with zero margins ([`PaddedLayout`]), restricted to the rectangle that holds the non-zero values
//! ([`Rect`]). Shared by the renderer (per-scene and dataset mode, [`super::engine`]) and the exact
//! reconstruction operator ([`crate::recon::exact`]).
//!
//! Each output tile of [`TILE`] consecutive pixels of a row is accumulated in registers over all taps
//! (kernel rows outer, columns inner: row-major, zero taps skipped) and handed once to an *epilogue*
//! closure (add into an f64 band image, store into a scratch image, ...), instead of one saxpy per tap
//! over the whole row (two loads and one store per multiply-add). Per output pixel the sums are exactly
//! those of [`AiryKernel::convolve`] — the same products added in the same order, each product rounded
//! before its addition (no fused multiply-add) — so every dispatch path ([`BlurPath`]: AVX-512, AVX2,
//! portable) gives bit-identical results, equal to [`AiryKernel::convolve`] (up to the sign of zero sums).
//! [`correlate`] is the exact transpose (taps mirrored, terms outside the image dropped).
//!
//! ```
//! use diffcassi::render::AiryKernel;
//! use diffcassi::render::convolve::{convolve, PaddedLayout, Rect, TILE};
//! let k = AiryKernel::for_wavelength(520.0, 2.5, 520.0, 3).unwrap();
//! let (w, h) = (20, 9);
//! let lay = PaddedLayout::new(w, h, k.half);
//! let mut src = vec![0.0f32; lay.len()];
//! src[lay.index(3, 4)] = 1.0;
//! let mut out = vec![0.0f32; w * h];
//! convolve(&k, &src, &lay, Rect { y0: 4, y1: 5, x0: 3, x1: 4 }, &mut |y, x, valid, tile: &[f32; TILE]| {
//!     out[y * w + x..y * w + x + valid].copy_from_slice(&tile[..valid]);
//! });
//! let dense: Vec<f32> = (0..w * h).map(|i| if i == 4 * w + 3 { 1.0 } else { 0.0 }).collect();
//! assert_eq!(out, k.convolve(&dense, w, h));
//! ```
use super::airy::AiryKernel;

/// Output pixels accumulated in registers per tile (4 AVX-512 / 8 AVX2 vectors).
pub const TILE: usize = 64;

/// A half-open pixel rectangle on the detector: rows `y0..y1`, columns `x0..x1`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct Rect {
    pub y0: usize,
    pub y1: usize,
    pub x0: usize,
    pub x1: usize,
}

impl Rect {
    pub fn is_empty(&self) -> bool {
        self.y0 >= self.y1 || self.x0 >= self.x1
    }

    /// The smallest rectangle holding both (an empty one is ignored).
    pub fn union(&self, o: &Rect) -> Rect {
        if self.is_empty() {
            return *o;
        }
        if o.is_empty() {
            return *self;
        }
        Rect { y0: self.y0.min(o.y0), y1: self.y1.max(o.y1), x0: self.x0.min(o.x0), x1: self.x1.max(o.x1) }
    }
}

/// Row layout of a detector-sized (`width × height`) scratch image with a zero margin of `pad` columns on
/// the left and at least `pad + TILE` on the right: pixel (x, y) lives at `y·stride + pad + x`, so a tile
/// and its kernel neighbourhood can be read and written without bounds tests along the row.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PaddedLayout {
    pub width: usize,
    pub height: usize,
    pub pad: usize,
    pub stride: usize,
}

impl PaddedLayout {
    /// A layout for kernels of half-width up to `max_half` (the margin is at least 4, for 4-wide windows).
    pub fn new(width: usize, height: usize, max_half: usize) -> Self {
        let pad = max_half.max(4);
        let stride = (2 * pad + width + TILE).div_ceil(16) * 16;
        PaddedLayout { width, height, pad, stride }
    }

    /// Values in a buffer of this layout.
    pub fn len(&self) -> usize {
        self.stride * self.height
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Index of pixel (x, y).
    #[inline]
    pub fn index(&self, x: usize, y: usize) -> usize {
        y * self.stride + self.pad + x
    }

    /// Copy a dense row-major `width × height` image into `out` (margins zero).
    pub fn pad_image(&self, dense: &[f32], out: &mut Vec<f32>) {
        out.clear();
        out.resize(self.len(), 0.0);
        for (y, row) in dense.chunks_exact(self.width.max(1)).enumerate().take(self.height) {
            let o = self.index(0, y);
            out[o..o + self.width].copy_from_slice(row);
        }
    }

    /// Zero the pixels of `r` (columns clipped to the buffer's row) in `buf`.
    pub fn clear(&self, buf: &mut [f32], r: Rect) {
        if r.is_empty() {
            return;
        }
        let x1 = (self.pad + r.x1).min(self.stride) - self.pad;
        for y in r.y0..r.y1.min(self.height) {
            buf[self.index(r.x0, y)..self.index(x1, y)].iter_mut().for_each(|v| *v = 0.0);
        }
    }
}

/// Which instruction set the blocked kernels run with (all give bit-identical results).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BlurPath {
    Avx512,
    Avx2,
    Portable,
}

impl BlurPath {
    /// The widest path this CPU supports.
    pub fn detect() -> Self {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx512f") {
                return BlurPath::Avx512;
            }
            if std::arch::is_x86_feature_detected!("avx2") {
                return BlurPath::Avx2;
            }
        }
        BlurPath::Portable
    }

    /// Every path this CPU can run (for tests and benchmarks).
    pub fn available() -> Vec<Self> {
        let mut v = Vec::new();
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx512f") {
                v.push(BlurPath::Avx512);
            }
            if std::arch::is_x86_feature_detected!("avx2") {
                v.push(BlurPath::Avx2);
            }
        }
        v.push(BlurPath::Portable);
        v
    }
}

/// The output rectangle of convolving values confined to `support`: `support` dilated by the kernel's
/// half-width, clipped to the image.
pub fn dilate(k: &AiryKernel, support: Rect, width: usize, height: usize) -> Rect {
    if support.is_empty() {
        return Rect::default();
    }
    let h = k.half;
    Rect { y0: support.y0.saturating_sub(h), y1: (support.y1 + h).min(height), x0: support.x0.saturating_sub(h), x1: (support.x1 + h).min(width) }
}

/// A ∗ src on the detector, for `src` (layout `lay`, zero outside the image) whose non-zero values all lie
/// in `support`: for every tile of [`TILE`] pixels of the output rectangle ([`dilate`]) calls
/// `emit(y, x, valid, tile)` with the convolution at (x .. x + TILE, y); only the first `valid` values lie
/// in the rectangle (the others are convolution values outside it, zero inside the image). Returns the
/// output rectangle.
pub fn convolve<F: FnMut(usize, usize, usize, &[f32; TILE])>(k: &AiryKernel, src: &[f32], lay: &PaddedLayout, support: Rect, emit: &mut F) -> Rect {
    convolve_with(BlurPath::detect(), k, src, lay, support, emit)
}

/// [`convolve`] on a given path (falls back to the portable one if the CPU lacks it).
pub fn convolve_with<F: FnMut(usize, usize, usize, &[f32; TILE])>(path: BlurPath, k: &AiryKernel, src: &[f32], lay: &PaddedLayout, support: Rect, emit: &mut F) -> Rect {
    check(k, src, lay);
    #[cfg(target_arch = "x86_64")]
    match path {
        // SAFETY: the CPU supports the feature (checked in each arm).
        BlurPath::Avx512 if std::arch::is_x86_feature_detected!("avx512f") => return unsafe { convolve_avx512(k, src, lay, support, emit) },
        BlurPath::Avx2 if std::arch::is_x86_feature_detected!("avx2") => return unsafe { convolve_avx2(k, src, lay, support, emit) },
        _ => {}
    }
    let _ = path;
    convolve_body(k, src, lay, support, emit)
}

/// Aᵀ y restricted to `target`: for every tile of `target`, `emit(y, x, valid, tile)` with
/// z(s) = Σ_taps w(ki, kj)·y(s + (ki − half, kj − half)) (the correlation; `y` in layout `lay`, zero
/// outside the image). The exact transpose of [`convolve`].
pub fn correlate<F: FnMut(usize, usize, usize, &[f32; TILE])>(k: &AiryKernel, y: &[f32], lay: &PaddedLayout, target: Rect, emit: &mut F) {
    correlate_with(BlurPath::detect(), k, y, lay, target, emit)
}

/// [`correlate`] on a given path (falls back to the portable one if the CPU lacks it).
pub fn correlate_with<F: FnMut(usize, usize, usize, &[f32; TILE])>(path: BlurPath, k: &AiryKernel, y: &[f32], lay: &PaddedLayout, target: Rect, emit: &mut F) {
    check(k, y, lay);
    #[cfg(target_arch = "x86_64")]
    match path {
        // SAFETY: the CPU supports the feature (checked in each arm).
        BlurPath::Avx512 if std::arch::is_x86_feature_detected!("avx512f") => return unsafe { correlate_avx512(k, y, lay, target, emit) },
        BlurPath::Avx2 if std::arch::is_x86_feature_detected!("avx2") => return unsafe { correlate_avx2(k, y, lay, target, emit) },
        _ => {}
    }
    let _ = path;
    correlate_body(k, y, lay, target, emit)
}

fn check(k: &AiryKernel, src: &[f32], lay: &PaddedLayout) {
    assert!(k.half <= lay.pad, "kernel half-width {} exceeds the layout's margin {}", k.half, lay.pad);
    assert_eq!(src.len(), lay.len(), "image buffer does not match its layout");
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn convolve_avx512<F: FnMut(usize, usize, usize, &[f32; TILE])>(k: &AiryKernel, src: &[f32], lay: &PaddedLayout, support: Rect, emit: &mut F) -> Rect {
    convolve_body(k, src, lay, support, emit)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn convolve_avx2<F: FnMut(usize, usize, usize, &[f32; TILE])>(k: &AiryKernel, src: &[f32], lay: &PaddedLayout, support: Rect, emit: &mut F) -> Rect {
    convolve_body(k, src, lay, support, emit)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn correlate_avx512<F: FnMut(usize, usize, usize, &[f32; TILE])>(k: &AiryKernel, y: &[f32], lay: &PaddedLayout, target: Rect, emit: &mut F) {
    correlate_body(k, y, lay, target, emit)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn correlate_avx2<F: FnMut(usize, usize, usize, &[f32; TILE])>(k: &AiryKernel, y: &[f32], lay: &PaddedLayout, target: Rect, emit: &mut F) {
    correlate_body(k, y, lay, target, emit)
}

/// acc[l] += w · s[l] over one tile (multiply, then add: no contraction).
#[inline(always)]
fn tap(acc: &mut [f32; TILE], w: f32, s: &[f32]) {
    let s: &[f32; TILE] = s.try_into().expect("a tile of source values");
    for l in 0..TILE {
        acc[l] += w * s[l];
    }
}

#[inline(always)]
fn convolve_body<F: FnMut(usize, usize, usize, &[f32; TILE])>(k: &AiryKernel, src: &[f32], lay: &PaddedLayout, support: Rect, emit: &mut F) -> Rect {
    let out = dilate(k, support, lay.width, lay.height);
    if out.is_empty() {
        return out;
    }
    let (h, n) = (k.half, 2 * k.half + 1);
    for y in out.y0..out.y1 {
        let mut x = out.x0;
        while x < out.x1 {
            let mut acc = [0.0f32; TILE];
            for ki in 0..n {
                // out(x, y) += w(ki, kj) · src(x − (kj − h), y − (ki − h))
                let sy = y as isize - ki as isize + h as isize;
                if sy < support.y0 as isize || sy >= support.y1 as isize {
                    continue;
                }
                let base = lay.index(x, sy as usize) - h;
                let row = &src[base..base + TILE + 2 * h];
                let wk = &k.weights[ki * n..(ki + 1) * n];
                for (kj, &w) in wk.iter().enumerate() {
                    if w != 0.0 {
                        tap(&mut acc, w, &row[2 * h - kj..2 * h - kj + TILE]);
                    }
                }
            }
            emit(y, x, TILE.min(out.x1 - x), &acc);
            x += TILE;
        }
    }
    out
}

#[inline(always)]
fn correlate_body<F: FnMut(usize, usize, usize, &[f32; TILE])>(k: &AiryKernel, y: &[f32], lay: &PaddedLayout, target: Rect, emit: &mut F) {
    if target.is_empty() {
        return;
    }
    let (h, n) = (k.half, 2 * k.half + 1);
    for sy in target.y0..target.y1.min(lay.height) {
        let mut x = target.x0;
        while x < target.x1 {
            let mut acc = [0.0f32; TILE];
            for ki in 0..n {
                // z(x, sy) += w(ki, kj) · y(x + kj − h, sy + ki − h)
                let yy = sy as isize + ki as isize - h as isize;
                if yy < 0 || yy >= lay.height as isize {
                    continue;
                }
                let base = lay.index(x, yy as usize) - h;
                let row = &y[base..base + TILE + 2 * h];
                let wk = &k.weights[ki * n..(ki + 1) * n];
                for (kj, &w) in wk.iter().enumerate() {
                    if w != 0.0 {
                        tap(&mut acc, w, &row[kj..kj + TILE]);
                    }
                }
            }
            emit(sy, x, TILE.min(target.x1 - x), &acc);
            x += TILE;
        }
    }
}

/// Output pixels of one f64 tile of [`kernel_pass_f64`] (4 AVX-512 / 8 AVX2 vectors).
pub const TILE_F64: usize = 32;

/// The f64 blur of the differentiable renderer ([`super::gradient`]) and its adjoint, on a dense
/// row-major `width × height` image: for every pixel (x, y) the sum
/// Σ_{ki, kj} w[ki, kj] · img[y − dir·(ki − half), x − dir·(kj − half)] over the taps that fall inside the
/// image, kernel rows outer and columns inner, each product rounded before its addition; `dir = 1` is the
/// convolution K ⊛ img, `dir = −1` its transpose (the correlation Kᵀ img). `emit(i, sums)` receives the
/// sums of the pixels i .. i + sums.len() of one row (a tile of at most [`TILE_F64`]).
///
/// Tiled as [`convolve`]: the image is copied into a zero-margined buffer ([`PaddedLayout`]) so that a
/// tile is accumulated in registers with no bounds test per tap; kernel rows outside the image and zero
/// taps are skipped. Every sum is bit-identical to the plain double loop over the in-image taps: the terms
/// this adds or skips beyond those are products with a zero, ±0, added to a sum that starts at +0 and is
/// never −0 (finite inputs), which leaves it unchanged; the other terms come in the same order.
///
/// ```
/// use diffcassi::render::convolve::kernel_pass_f64;
/// let (w, h) = (5, 4);
/// let k = [0.0, 0.25, 0.0, 0.25, 0.5, 0.0, 0.0, 0.0, 0.0]; // half = 1
/// let mut img = vec![0.0; w * h];
/// img[2 * w + 2] = 1.0;
/// let mut out = vec![0.0; w * h];
/// kernel_pass_f64(&k, 1, &img, w, h, 1, &mut |i, s: &[f64]| out[i..i + s.len()].copy_from_slice(s));
/// // K ⊛ δ at (2, 2): tap (ki, kj) lands at (2 − (kj − 1), 2 − (ki − 1)).
/// assert_eq!((out[2 * w + 2], out[w + 2], out[2 * w + 1]), (0.5, 0.25, 0.25));
/// kernel_pass_f64(&k, 1, &img, w, h, -1, &mut |i, s: &[f64]| out[i..i + s.len()].copy_from_slice(s));
/// assert_eq!((out[2 * w + 2], out[3 * w + 2], out[2 * w + 3]), (0.5, 0.25, 0.25)); // its transpose
/// ```
pub fn kernel_pass_f64<F: FnMut(usize, &[f64])>(weights: &[f64], half: usize, img: &[f64], width: usize, height: usize, dir: isize, emit: &mut F) {
    kernel_pass_f64_with(BlurPath::detect(), weights, half, img, width, height, dir, emit)
}

/// [`kernel_pass_f64`] on a given path (falls back to the portable one if the CPU lacks it).
#[allow(clippy::too_many_arguments)]
pub fn kernel_pass_f64_with<F: FnMut(usize, &[f64])>(path: BlurPath, weights: &[f64], half: usize, img: &[f64], width: usize, height: usize, dir: isize, emit: &mut F) {
    let n = 2 * half + 1;
    assert_eq!(weights.len(), n * n, "kernel of half-width {half} needs {} weights", n * n);
    assert_eq!(img.len(), width * height, "image buffer does not match {width}×{height}");
    assert!(dir == 1 || dir == -1, "dir must be ±1");
    if width == 0 || height == 0 {
        return;
    }
    let lay = PaddedLayout::new(width, height, half);
    let mut src = vec![0.0f64; lay.len()];
    for (y, row) in img.chunks_exact(width).enumerate() {
        let o = lay.index(0, y);
        src[o..o + width].copy_from_slice(row);
    }
    #[cfg(target_arch = "x86_64")]
    match path {
        // SAFETY: the CPU supports the feature (checked in each arm).
        BlurPath::Avx512 if std::arch::is_x86_feature_detected!("avx512f") => return unsafe { pass_f64_avx512(weights, half, &src, &lay, dir, emit) },
        BlurPath::Avx2 if std::arch::is_x86_feature_detected!("avx2") => return unsafe { pass_f64_avx2(weights, half, &src, &lay, dir, emit) },
        _ => {}
    }
    let _ = path;
    pass_f64_body(weights, half, &src, &lay, dir, emit)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn pass_f64_avx512<F: FnMut(usize, &[f64])>(weights: &[f64], half: usize, src: &[f64], lay: &PaddedLayout, dir: isize, emit: &mut F) {
    pass_f64_body(weights, half, src, lay, dir, emit)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn pass_f64_avx2<F: FnMut(usize, &[f64])>(weights: &[f64], half: usize, src: &[f64], lay: &PaddedLayout, dir: isize, emit: &mut F) {
    pass_f64_body(weights, half, src, lay, dir, emit)
}

#[inline(always)]
fn pass_f64_body<F: FnMut(usize, &[f64])>(weights: &[f64], half: usize, src: &[f64], lay: &PaddedLayout, dir: isize, emit: &mut F) {
    let (h, n, width, height) = (half as isize, 2 * half + 1, lay.width, lay.height as isize);
    for y in 0..lay.height {
        let mut x = 0;
        while x < width {
            let mut acc = [0.0f64; TILE_F64];
            for ki in 0..n {
                // Source row y − dir·(ki − half); columns x + l − dir·(kj − half) for the tile's pixel l.
                let sy = y as isize - dir * (ki as isize - h);
                if sy < 0 || sy >= height {
                    continue;
                }
                let base = lay.index(x, sy as usize) - half;
                let row = &src[base..base + TILE_F64 + 2 * half];
                for (kj, &w) in weights[ki * n..(ki + 1) * n].iter().enumerate() {
                    if w == 0.0 {
                        continue;
                    }
                    let off = if dir == 1 { 2 * half - kj } else { kj };
                    let s: &[f64; TILE_F64] = row[off..off + TILE_F64].try_into().expect("a tile of source values");
                    for l in 0..TILE_F64 {
                        acc[l] += w * s[l];
                    }
                }
            }
            let valid = TILE_F64.min(width - x);
            emit(y * width + x, &acc[..valid]);
            x += TILE_F64;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn image(w: usize, h: usize, seed: u64, r: Rect) -> Vec<f32> {
        (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                if x < r.x0 || x >= r.x1 || y < r.y0 || y >= r.y1 {
                    return 0.0;
                }
                let m = crate::render::sampling::mix64(i as u64 ^ seed.wrapping_mul(0x9E37_79B9_7F4A_7C15));
                (m >> 40) as f32 / (1u64 << 24) as f32 - 0.3
            })
            .collect()
    }

    fn cases() -> Vec<(usize, usize, Rect)> {
        vec![
            // whole image, odd sizes; support touching every border; interior support; one pixel
            (37, 23, Rect { y0: 0, y1: 23, x0: 0, x1: 37 }),
            (131, 9, Rect { y0: 0, y1: 9, x0: 60, x1: 131 }),
            (70, 41, Rect { y0: 5, y1: 30, x0: 11, x1: 40 }),
            (5, 3, Rect { y0: 1, y1: 2, x0: 2, x1: 3 }),
        ]
    }

    /// The blocked convolution equals [`AiryKernel::convolve`] bit for bit, on every path the CPU has
    /// (odd sizes, supports touching the borders, kernels of half-width 4 and 5).
    #[test]
    fn blocked_convolution_equals_airy_convolve_on_every_path() {
        for (lambda, seed) in [(450.0, 1), (650.0, 2)] {
            let k = AiryKernel::for_wavelength(lambda, 2.5, 520.0, 3).unwrap();
            for (w, h, sup) in cases() {
                let dense = image(w, h, seed, sup);
                let want = k.convolve(&dense, w, h);
                let lay = PaddedLayout::new(w, h, 5);
                let mut src = Vec::new();
                lay.pad_image(&dense, &mut src);
                for path in BlurPath::available() {
                    let mut got = vec![0.0f32; w * h];
                    let r = convolve_with(path, &k, &src, &lay, sup, &mut |y, x, valid, t: &[f32; TILE]| {
                        got[y * w + x..y * w + x + valid].copy_from_slice(&t[..valid]);
                    });
                    assert_eq!(r, dilate(&k, sup, w, h));
                    assert_eq!(got, want, "{path:?} {w}×{h} {sup:?} λ {lambda}");
                }
            }
        }
    }

    /// ⟨A x, y⟩ = ⟨x, Aᵀ y⟩ in exact (f64) arithmetic of the f32 values: the correlation is the exact
    /// transpose of the convolution, and all paths agree bit for bit.
    #[test]
    fn correlation_is_the_exact_transpose() {
        let k = AiryKernel::for_wavelength(600.0, 2.5, 520.0, 3).unwrap();
        for (w, h, sup) in cases() {
            let x = image(w, h, 7, sup);
            let yv = image(w, h, 8, Rect { y0: 0, y1: h, x0: 0, x1: w });
            let lay = PaddedLayout::new(w, h, k.half);
            let (mut xp, mut yp) = (Vec::new(), Vec::new());
            lay.pad_image(&x, &mut xp);
            lay.pad_image(&yv, &mut yp);
            // The transpose as an explicit sum over (output pixel, tap): Σ_o y(o) Σ_taps w x(o − d).
            let ax = k.convolve(&x, w, h);
            let lhs: f64 = ax.iter().zip(&yv).map(|(a, b)| *a as f64 * *b as f64).sum();
            let mut reference: Option<Vec<f32>> = None;
            for path in BlurPath::available() {
                let mut z = vec![0.0f32; w * h];
                correlate_with(path, &k, &yp, &lay, sup, &mut |yy, xx, valid, t: &[f32; TILE]| {
                    z[yy * w + xx..yy * w + xx + valid].copy_from_slice(&t[..valid]);
                });
                let rhs: f64 = z.iter().zip(&x).map(|(a, b)| *a as f64 * *b as f64).sum();
                let scale: f64 = ax.iter().map(|v| (*v as f64).abs()).sum::<f64>() * yv.iter().map(|v| (*v as f64).abs()).fold(0.0, f64::max);
                assert!((lhs - rhs).abs() <= 1e-6 * scale, "{path:?} {w}×{h}: {lhs} vs {rhs}");
                match &reference {
                    Some(r) => assert_eq!(&z, r, "{path:?}"),
                    None => reference = Some(z),
                }
            }
            // Term by term: z(s) = Σ_o y(o)·A(o, s), with A(o, s) the convolution's weight from s to o.
            let n = 2 * k.half + 1;
            let hh = k.half as isize;
            let mut z = vec![0.0f32; w * h];
            correlate(&k, &yp, &lay, sup, &mut |yy, xx, valid, t: &[f32; TILE]| {
                z[yy * w + xx..yy * w + xx + valid].copy_from_slice(&t[..valid]);
            });
            for sy in sup.y0..sup.y1 {
                for sx in sup.x0..sup.x1 {
                    let mut s = 0.0f32;
                    for ki in 0..n {
                        for kj in 0..n {
                            let (oy, ox) = (sy as isize + ki as isize - hh, sx as isize + kj as isize - hh);
                            let wgt = k.weights[ki * n + kj];
                            if wgt != 0.0 && oy >= 0 && oy < h as isize && ox >= 0 && ox < w as isize {
                                s += wgt * yv[oy as usize * w + ox as usize];
                            }
                        }
                    }
                    assert_eq!(z[sy * w + sx], s, "({sx}, {sy})");
                }
            }
        }
    }
}
