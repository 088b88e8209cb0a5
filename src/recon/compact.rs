//! The exact operator's storage of one plane's light transport: the footprints of a [`PlaneTransport`]
//! re-laid for applying it many times (a derived structure; the [`PlaneTransport`] itself is unchanged).
//!
//! Each footprint window (w × h bilinear splat weights) is cut into *pieces* four columns wide (a window
//! of width 5 gives two pieces; columns past w are zero weights), each stored as a padded-image offset
//! ([`PaddedLayout`]), its scene pixel and h rows of four weights — a row is one 128-bit load. The mask
//! transmission of the pixel is folded into the weights (w′ = M(q)·w). Pieces are grouped by row count,
//! in footprint order inside a group, so the inner loop has a fixed trip count (no branch mispredicts);
//! each row is one SSE multiply and add. Memory: 8 bytes + 16·h per piece, about the size of the footprints
//! themselves (≈ 1.0 GB at 512×512×28 with 20 rays, SP).
//!
//! ```
//! use diffcassi::recon::compact::CompactPlane;
//! use diffcassi::render::convolve::PaddedLayout;
//! use diffcassi::render::{Footprint, PlaneTransport};
//! let t = PlaneTransport {
//!     footprints: vec![Footprint { pixel: 1, x0: 2, y0: 1, w: 2, h: 2, start: 0 }],
//!     weights: vec![0.1, 0.2, 0.3, 0.4],
//!     ..Default::default()
//! };
//! let lay = PaddedLayout::new(6, 4, 4);
//! let plane = CompactPlane::new(&t, &[1.0, 0.5], &lay);
//! let mut img = vec![0.0f32; lay.len()];
//! plane.scatter(&[0.0, 2.0], &[0.0, 2.0], 0.0, &lay, &mut img); // x = 2 at pixel 1, mask 0.5
//! assert_eq!(img[lay.index(3, 2)], 0.4);
//! ```
use crate::render::convolve::{PaddedLayout, Rect};
use crate::render::PlaneTransport;

/// Pieces with the same row count.
#[derive(Clone, Debug, PartialEq)]
struct Group {
    rows: usize,
    /// Piece range.
    start: usize,
    end: usize,
    /// Index of the group's first weight row.
    row0: usize,
}

/// One plane's transport as four-wide pieces (see the [module docs](self)).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CompactPlane {
    groups: Vec<Group>,
    /// Padded-image index of each piece's top-left pixel.
    offsets: Vec<u32>,
    /// Scene pixel of each piece.
    pixels: Vec<u32>,
    /// Weight rows of all pieces, group by group, piece by piece.
    weights: Vec<[f32; 4]>,
    /// Bounding box of all pieces (four-wide, so it may reach 3 columns past the detector).
    pub support: Rect,
}

impl CompactPlane {
    /// Re-lay `t` for images of layout `lay` (the detector), folding in the mask transmissions `mask`.
    pub fn new(t: &PlaneTransport, mask: &[f32], lay: &PaddedLayout) -> Self {
        // Pieces (footprint, first column) bucketed by row count, in footprint order.
        let mut buckets: Vec<Vec<(u32, u32)>> = Vec::new();
        let mut support = Rect::default();
        let (mut pieces, mut rows_total) = (0usize, 0usize);
        for (i, f) in t.footprints.iter().enumerate() {
            let (w, h) = (f.w as usize, f.h as usize);
            if w == 0 || h == 0 {
                continue;
            }
            if buckets.len() <= h {
                buckets.resize_with(h + 1, Vec::new);
            }
            for c0 in (0..w).step_by(4) {
                buckets[h].push((i as u32, c0 as u32));
                pieces += 1;
                rows_total += h;
            }
            support = support.union(&Rect { y0: f.y0 as usize, y1: f.y0 as usize + h, x0: f.x0 as usize, x1: f.x0 as usize + w.div_ceil(4) * 4 });
        }
        let mut out = CompactPlane { support, ..Default::default() };
        out.offsets.reserve_exact(pieces);
        out.pixels.reserve_exact(pieces);
        out.weights.reserve_exact(rows_total);
        for (rows, bucket) in buckets.iter().enumerate().filter(|(_, b)| !b.is_empty()) {
            let n = out.offsets.len();
            out.groups.push(Group { rows, start: n, end: n + bucket.len(), row0: out.weights.len() });
            for &(fi, c0) in bucket {
                let f = &t.footprints[fi as usize];
                let (w, c0) = (f.w as usize, c0 as usize);
                let m = mask[f.pixel as usize];
                for row in 0..rows {
                    let src = &t.weights[f.start as usize + row * w..f.start as usize + (row + 1) * w];
                    let mut quad = [0.0f32; 4];
                    for (c, q) in quad.iter_mut().enumerate() {
                        if c0 + c < w {
                            *q = m * src[c0 + c];
                        }
                    }
                    out.weights.push(quad);
                }
                out.offsets.push(lay.index(f.x0 as usize + c0, f.y0 as usize) as u32);
                out.pixels.push(f.pixel);
            }
        }
        out
    }

    /// Heap bytes held.
    pub fn bytes(&self) -> usize {
        self.offsets.capacity() * 4 + self.pixels.capacity() * 4 + self.weights.capacity() * 16 + self.groups.capacity() * std::mem::size_of::<Group>()
    }

    /// img += T′ x_p with x_p(q) = (1 − t)·a(q) + t·b(q) (the plane between two bands, as
    /// [`crate::scene::SpectralCube::plane`]), T′ the mask-weighted transport; `img` in layout `lay`.
    pub fn scatter(&self, a: &[f32], b: &[f32], t: f32, lay: &PaddedLayout, img: &mut [f32]) {
        assert_eq!(img.len(), lay.len());
        let s = 1.0 - t;
        for g in &self.groups {
            match g.rows {
                3 => self.scatter_group::<3>(g, a, b, s, t, lay.stride, img),
                4 => self.scatter_group::<4>(g, a, b, s, t, lay.stride, img),
                5 => self.scatter_group::<5>(g, a, b, s, t, lay.stride, img),
                _ => {
                    for (i, p) in (g.start..g.end).enumerate() {
                        let q = self.pixels[p] as usize;
                        let v = s * a[q] + t * b[q];
                        let o = self.offsets[p] as usize;
                        for r in 0..g.rows {
                            add4(img, o + r * lay.stride, v, &self.weights[g.row0 + i * g.rows + r]);
                        }
                    }
                }
            }
        }
    }

    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn scatter_group<const R: usize>(&self, g: &Group, a: &[f32], b: &[f32], s: f32, t: f32, stride: usize, img: &mut [f32]) {
        let ws: &[[[f32; 4]; R]] = as_rows::<R>(&self.weights[g.row0..g.row0 + (g.end - g.start) * R]);
        for ((&o, &q), wp) in self.offsets[g.start..g.end].iter().zip(&self.pixels[g.start..g.end]).zip(ws) {
            let q = q as usize;
            let v = s * a[q] + t * b[q];
            let o = o as usize;
            for (r, wr) in wp.iter().enumerate() {
                add4(img, o + r * stride, v, wr);
            }
        }
    }

    /// The transpose of [`CompactPlane::scatter`]: for every piece, d = ⟨window of z, weights⟩, added as
    /// `ca·d` to `a[pixel]` and `cb·d` to `b[pixel]` (pass `b = None` when both bands are the same:
    /// both terms go to `a`).
    pub fn gather(&self, z: &[f32], lay: &PaddedLayout, ca: f32, cb: f32, a: &mut [f32], mut b: Option<&mut [f32]>) {
        assert_eq!(z.len(), lay.len());
        for g in &self.groups {
            match g.rows {
                3 => self.gather_group::<3>(g, z, lay.stride, ca, cb, a, b.as_deref_mut()),
                4 => self.gather_group::<4>(g, z, lay.stride, ca, cb, a, b.as_deref_mut()),
                5 => self.gather_group::<5>(g, z, lay.stride, ca, cb, a, b.as_deref_mut()),
                _ => {
                    for (i, p) in (g.start..g.end).enumerate() {
                        let o = self.offsets[p] as usize;
                        let mut acc = Quad::zero();
                        for r in 0..g.rows {
                            acc.add_product(z, o + r * lay.stride, &self.weights[g.row0 + i * g.rows + r]);
                        }
                        deposit(self.pixels[p] as usize, acc.sum(), ca, cb, a, b.as_deref_mut());
                    }
                }
            }
        }
    }

    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn gather_group<const R: usize>(&self, g: &Group, z: &[f32], stride: usize, ca: f32, cb: f32, a: &mut [f32], mut b: Option<&mut [f32]>) {
        let ws: &[[[f32; 4]; R]] = as_rows::<R>(&self.weights[g.row0..g.row0 + (g.end - g.start) * R]);
        for ((&o, &q), wp) in self.offsets[g.start..g.end].iter().zip(&self.pixels[g.start..g.end]).zip(ws) {
            let o = o as usize;
            let mut acc = Quad::zero();
            for (r, wr) in wp.iter().enumerate() {
                acc.add_product(z, o + r * stride, wr);
            }
            deposit(q as usize, acc.sum(), ca, cb, a, b.as_deref_mut());
        }
    }
}

/// dst[o + c] += v·w[c], c = 0..4, as one SSE multiply and add (each lane rounded as the scalar code).
#[inline(always)]
fn add4(dst: &mut [f32], o: usize, v: f32, w: &[f32; 4]) {
    let d: &mut [f32; 4] = (&mut dst[o..o + 4]).try_into().expect("4 values");
    #[cfg(target_arch = "x86_64")]
    // SAFETY: SSE is part of x86_64; `d` and `w` are 4 valid f32 each (unaligned loads/stores).
    unsafe {
        use std::arch::x86_64::*;
        let p = d.as_mut_ptr();
        _mm_storeu_ps(p, _mm_add_ps(_mm_loadu_ps(p), _mm_mul_ps(_mm_set1_ps(v), _mm_loadu_ps(w.as_ptr()))));
    }
    #[cfg(not(target_arch = "x86_64"))]
    for c in 0..4 {
        d[c] += v * w[c];
    }
}

/// Four running sums of products (one SSE register).
#[derive(Clone, Copy)]
struct Quad([f32; 4]);

impl Quad {
    #[inline(always)]
    fn zero() -> Self {
        Quad([0.0; 4])
    }

    /// self[c] += z[o + c]·w[c].
    #[inline(always)]
    fn add_product(&mut self, z: &[f32], o: usize, w: &[f32; 4]) {
        let zr: &[f32; 4] = (&z[o..o + 4]).try_into().expect("4 values");
        #[cfg(target_arch = "x86_64")]
        // SAFETY: SSE is part of x86_64; all pointers cover 4 valid f32 (unaligned loads/stores).
        unsafe {
            use std::arch::x86_64::*;
            let acc = _mm_loadu_ps(self.0.as_ptr());
            _mm_storeu_ps(self.0.as_mut_ptr(), _mm_add_ps(acc, _mm_mul_ps(_mm_loadu_ps(zr.as_ptr()), _mm_loadu_ps(w.as_ptr()))));
        }
        #[cfg(not(target_arch = "x86_64"))]
        for c in 0..4 {
            self.0[c] += zr[c] * w[c];
        }
    }

    #[inline(always)]
    fn sum(&self) -> f32 {
        (self.0[0] + self.0[1]) + (self.0[2] + self.0[3])
    }
}

#[inline(always)]
fn deposit(q: usize, d: f32, ca: f32, cb: f32, a: &mut [f32], b: Option<&mut [f32]>) {
    a[q] += ca * d;
    match b {
        Some(b) => b[q] += cb * d,
        None => a[q] += cb * d,
    }
}

/// View rows of four weights as pieces of `R` rows.
fn as_rows<const R: usize>(rows: &[[f32; 4]]) -> &[[[f32; 4]; R]] {
    assert_eq!(rows.len() % R, 0);
    // SAFETY: [[f32; 4]; R] has the layout of R consecutive [f32; 4] (arrays have no padding), the
    // length is a multiple of R and the alignment is that of f32.
    unsafe { std::slice::from_raw_parts(rows.as_ptr() as *const [[f32; 4]; R], rows.len() / R) }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::Footprint;

    fn transport() -> PlaneTransport {
        // windows of widths 1..=6 and heights 1..=6 at various places (one touching the right border)
        let mut t = PlaneTransport::default();
        let mut k = 0u64;
        for (i, (w, h, x0, y0)) in [(3, 3, 0, 0), (4, 3, 1, 0), (5, 4, 2, 1), (6, 6, 3, 2), (1, 1, 10, 7), (4, 5, 8, 3), (2, 3, 12, 0), (3, 2, 11, 6)].into_iter().enumerate() {
            let start = t.weights.len() as u32;
            for _ in 0..w * h {
                k += 1;
                t.weights.push((crate::render::sampling::mix64(k) >> 40) as f32 / (1u64 << 24) as f32);
            }
            t.footprints.push(Footprint { pixel: i as u32, x0, y0, w, h, start });
        }
        t
    }

    /// Scatter equals [`PlaneTransport::apply`] on the masked plane (to f32 rounding), and gather is
    /// its exact transpose (⟨T x, z⟩ = ⟨x, Tᵀ z⟩ to f32 rounding).
    #[test]
    fn scatter_matches_apply_and_gather_is_its_transpose() {
        let t = transport();
        let (dw, dh) = (15, 9);
        let lay = PaddedLayout::new(dw, dh, 4);
        let mask: Vec<f32> = (0..8).map(|i| [1.0, 0.5, 0.25, 1.0][i % 4]).collect();
        let a: Vec<f32> = (0..8).map(|i| 0.3 + i as f32 * 0.11).collect();
        let b: Vec<f32> = (0..8).map(|i| 1.1 - i as f32 * 0.07).collect();
        let tt = 0.375f32;
        let c = CompactPlane::new(&t, &mask, &lay);
        assert!(c.support.x1 <= dw + 3 && c.support.y1 <= dh);
        let mut img = vec![0.0f32; lay.len()];
        c.scatter(&a, &b, tt, &lay, &mut img);
        let values: Vec<f32> = (0..8).map(|q| ((1.0 - tt) * a[q] + tt * b[q]) * mask[q]).collect();
        let mut want = vec![0.0f32; dw * dh];
        t.apply(&values, &mut want, dw);
        for y in 0..dh {
            for x in 0..lay.stride - lay.pad {
                let got = img[y * lay.stride + lay.pad + x];
                let w = if x < dw { want[y * dw + x] } else { 0.0 };
                assert!((got - w).abs() <= 1e-6 * (1.0 + w.abs()), "({x}, {y}): {got} vs {w}");
            }
        }
        // transpose
        let z: Vec<f32> = (0..dw * dh).map(|i| ((i * 37) % 11) as f32 * 0.1 - 0.4).collect();
        let mut zp = Vec::new();
        lay.pad_image(&z, &mut zp);
        let (mut ga, mut gb) = (vec![0.0f32; 8], vec![0.0f32; 8]);
        c.gather(&zp, &lay, 1.0 - tt, tt, &mut ga, Some(&mut gb));
        let lhs: f64 = want.iter().zip(&z).map(|(p, q)| *p as f64 * *q as f64).sum();
        let rhs: f64 = (0..8).map(|q| ga[q] as f64 * a[q] as f64 + gb[q] as f64 * b[q] as f64).sum();
        assert!((lhs - rhs).abs() < 1e-5 * lhs.abs().max(1.0), "{lhs} vs {rhs}");
        // Same band twice: both terms land in `a`.
        let mut g1 = vec![0.0f32; 8];
        c.gather(&zp, &lay, 1.0 - tt, tt, &mut g1, None);
        for q in 0..8 {
            assert!((g1[q] - (ga[q] + gb[q])).abs() <= 1e-6, "{q}");
        }
    }
}
