//! Sparse export: each reconstruction operator as an explicit CSR matrix Φ (rows = detector pixels
//! row-major, columns = cube entries in C order `[row][col][band]`, so `Φ · cube = apply(cube)`), built
//! directly from the operator's parts instead of from `apply` on unit cubes:
//!
//! - **exact** ([`ExactOperator`]): column (q, b) = Σ_p w · M(q) · c_{p,b} · A_p ∗ F_{p,q}, summed over the
//!   render planes p, with c_{p,b} the bands → planes interpolation weight of band b in plane p (1 − t_p for
//!   the lower band k_p, t_p for the upper band; [`ExactOperator::interpolation`]), M the mask, F_{p,q} the
//!   pixel's footprint window ([`PlaneTransport::footprints`]/`weights`), A_p the plane's Airy kernel (zero
//!   outside the detector, exactly [`AiryKernel::convolve`]'s taps) and w = B/K the plane weight — the five
//!   steps of [`super::exact`]'s forward model, multiplied out;
//! - **mapping** ([`MappingOperator`]): column (q, b) = M(q) · δ_{f(q, b)} (its nearest or bilinear taps);
//! - **shift** ([`ShiftOperator`]): column (q, b) = M(q) at (r₀ + σ_y·r, c_b + σ_x·c).
//!
//! Each column is accumulated in f64 over a dense box (the union of its planes' blurred windows) and
//! stored as f32. Compared with `apply`, which rounds each plane image, blur and sum to f32 in another
//! order, `Φ·x` differs by float rounding only: for x ≥ 0 every term is ≥ 0 and the relative difference per
//! pixel is bounded by the f32 rounding of the longest chain of sums (≈ 100 · 2⁻²⁴ ≈ 6·10⁻⁶); the tests
//! (`tests/recon_sparse.rs`) assert |Φ·x − apply(x)| ≤ 10⁻⁵ of the peak and the same for Φᵀ·y against
//! `adjoint(y)`.
//!
//! **Memory**: a pre-pass bounds the non-zeros by the columns' box areas (exact for shift and mapping, an
//! upper bound for exact) and refuses, with an error naming both sizes, when the bytes of the assembly
//! (20 bytes per non-zero: 12 while bucketing, 8 in the CSR arrays, plus 8 per row) exceed the caller's
//! budget. **Parallel and deterministic**: columns are generated in fixed blocks of scene pixels, each block
//! bucketing its entries by fixed row blocks; the CSR is then assembled in parallel over the row blocks,
//! each reading the column blocks in order, so the matrix (values, order) never depends on the thread count.
//!
//! ```
//! use diffcassi::recon::sparse::SparseExport;
//! use diffcassi::recon::{shift::ShiftOperator, CubeShape, ImageShape, Operator};
//! use diffcassi::render::Mask;
//! let op = ShiftOperator::new(CubeShape { height: 2, width: 3, bands: 2 }, ImageShape { height: 2, width: 5 },
//!                             &Mask::open(2, 3), 0, vec![0, 2], 1, 1)?;
//! let csr = op.to_csr(1 << 20)?;
//! assert_eq!((csr.rows, csr.cols, csr.nnz()), (10, 12, 12));
//! let x: Vec<f32> = (0..12).map(|i| i as f32).collect();
//! assert_eq!(csr.matvec(&x)?, (&op as &dyn Operator).apply(&x)?);
//! assert!(op.to_csr(100).unwrap_err().to_string().contains("memory budget"));
//! # Ok::<(), diffcassi::Error>(())
//! ```
use super::exact::ExactOperator;
use super::mapping::MappingOperator;
use super::operator::Operator;
use super::shift::ShiftOperator;
use crate::error::{Error, Result};
use crate::render::{Footprint, PlaneTransport};
use rayon::prelude::*;
use std::borrow::Cow;

/// Scene pixels per column block (fixed: the blocks, hence the result, do not depend on the thread count).
const PIXEL_BLOCK: usize = 64;
/// Rows (detector pixels) are assembled in this many fixed blocks.
const ROW_BLOCKS: usize = 64;
/// Bytes of the assembly per non-zero (a (row, col, value) triple while bucketing + column index and
/// value in the CSR) and per row (the row pointer).
const BYTES_PER_NONZERO: u64 = 12 + 8;
const BYTES_PER_ROW: u64 = 8;

/// A sparse matrix in compressed sparse row form (SciPy's `csr_matrix` layout): row r's entries are
/// `indices[indptr[r]..indptr[r + 1]]` (column indices, ascending) and the same range of `data`.
#[derive(Clone, Debug, PartialEq)]
pub struct CsrMatrix {
    pub rows: usize,
    pub cols: usize,
    pub indptr: Vec<u64>,
    pub indices: Vec<u32>,
    pub data: Vec<f32>,
}

impl CsrMatrix {
    pub fn nnz(&self) -> usize {
        self.data.len()
    }

    /// Heap bytes of the three arrays.
    pub fn bytes(&self) -> usize {
        self.indptr.len() * 8 + self.indices.len() * 4 + self.data.len() * 4
    }

    /// A · x (f64 sums per row, rounded to f32).
    pub fn matvec(&self, x: &[f32]) -> Result<Vec<f32>> {
        if x.len() != self.cols {
            return Err(Error::invalid(format!("CSR matvec: x has {} values, the matrix {} columns", x.len(), self.cols)));
        }
        Ok((0..self.rows)
            .into_par_iter()
            .map(|r| {
                let (a, b) = (self.indptr[r] as usize, self.indptr[r + 1] as usize);
                self.indices[a..b].iter().zip(&self.data[a..b]).map(|(c, v)| *v as f64 * x[*c as usize] as f64).sum::<f64>() as f32
            })
            .collect())
    }

    /// Aᵀ · y (f64 sums, rounded to f32; sequential, for checks).
    pub fn matvec_transpose(&self, y: &[f32]) -> Result<Vec<f32>> {
        if y.len() != self.rows {
            return Err(Error::invalid(format!("CSR transposed matvec: y has {} values, the matrix {} rows", y.len(), self.rows)));
        }
        let mut acc = vec![0.0f64; self.cols];
        for (r, yr) in y.iter().enumerate() {
            let (a, b) = (self.indptr[r] as usize, self.indptr[r + 1] as usize);
            for (c, v) in self.indices[a..b].iter().zip(&self.data[a..b]) {
                acc[*c as usize] += *v as f64 * *yr as f64;
            }
        }
        Ok(acc.into_iter().map(|v| v as f32).collect())
    }
}

/// Operators that can write themselves out as a [`CsrMatrix`].
pub trait SparseExport: Operator {
    /// Φ as CSR; an error (naming the estimated size) when assembling it would take more than
    /// `memory_budget_bytes`.
    fn to_csr(&self, memory_budget_bytes: u64) -> Result<CsrMatrix>;
}

/// Receives one pixel's columns: `push(band, row, value)` with bands in increasing order.
type Emit<'e> = dyn FnMut(usize, u32, f32) + 'e;

/// Assemble the CSR of an operator with `rows` detector pixels and `npix × bands` columns whose pixel
/// `q`'s columns `fill(q, emit)` produces (bands increasing). `nnz_bound` bounds the non-zeros (checked
/// against the budget before anything is allocated).
fn assemble(name: &str, rows: usize, npix: usize, bands: usize, nnz_bound: u64, budget: u64, fill: impl Fn(usize, &mut Emit<'_>) + Sync) -> Result<CsrMatrix> {
    let cols = npix * bands;
    if cols > u32::MAX as usize || rows > u32::MAX as usize {
        return Err(Error::invalid(format!("sparse export of `{name}`: {rows} rows × {cols} columns exceed the 32-bit index range")));
    }
    let need = nnz_bound.saturating_mul(BYTES_PER_NONZERO).saturating_add((rows as u64 + 1) * BYTES_PER_ROW);
    if need > budget {
        return Err(Error::invalid(format!(
            "sparse export of `{name}` ({rows} × {cols}): about {need} bytes ({:.3} GB for up to {nnz_bound} non-zeros) exceed the memory budget of {budget} bytes ({:.3} GB); raise the budget or export a smaller problem",
            need as f64 / 1e9,
            budget as f64 / 1e9
        )));
    }
    let rows_per_block = rows.div_ceil(ROW_BLOCKS).max(1);
    let row_blocks = rows.div_ceil(rows_per_block);
    // 1. Columns, in fixed pixel blocks; each block's entries bucketed by row block, in column order.
    let pixel_blocks = npix.div_ceil(PIXEL_BLOCK);
    let buckets: Vec<Vec<Vec<(u32, u32, f32)>>> = (0..pixel_blocks)
        .into_par_iter()
        .map(|pb| {
            let mut out: Vec<Vec<(u32, u32, f32)>> = vec![Vec::new(); row_blocks];
            for q in pb * PIXEL_BLOCK..((pb + 1) * PIXEL_BLOCK).min(npix) {
                let mut emit = |b: usize, row: u32, v: f32| {
                    out[row as usize / rows_per_block].push((row, (q * bands + b) as u32, v));
                };
                fill(q, &mut emit);
            }
            out
        })
        .collect();
    // 2. Row counts per row block, then the row pointer.
    let counts: Vec<Vec<u64>> = (0..row_blocks)
        .into_par_iter()
        .map(|rb| {
            let r0 = rb * rows_per_block;
            let mut c = vec![0u64; rows_per_block.min(rows - r0)];
            for blk in &buckets {
                for &(r, _, _) in &blk[rb] {
                    c[r as usize - r0] += 1;
                }
            }
            c
        })
        .collect();
    let mut indptr = Vec::with_capacity(rows + 1);
    indptr.push(0u64);
    for c in counts.iter().flatten() {
        indptr.push(indptr.last().copied().unwrap_or(0) + c);
    }
    let nnz = *indptr.last().unwrap_or(&0) as usize;
    // 3. Fill each row block's slice of the arrays: columns ascending within a row (the buckets are in
    // column order and the placement is stable).
    let mut indices = vec![0u32; nnz];
    let mut data = vec![0.0f32; nnz];
    let mut slices = Vec::with_capacity(row_blocks);
    let (mut ri, mut rd) = (indices.as_mut_slice(), data.as_mut_slice());
    for rb in 0..row_blocks {
        let r0 = rb * rows_per_block;
        let r1 = (r0 + rows_per_block).min(rows);
        let len = (indptr[r1] - indptr[r0]) as usize;
        let (a, b) = std::mem::take(&mut ri).split_at_mut(len);
        let (c, d) = std::mem::take(&mut rd).split_at_mut(len);
        slices.push((rb, a, c));
        ri = b;
        rd = d;
    }
    slices.into_par_iter().for_each(|(rb, idx, val)| {
        let r0 = rb * rows_per_block;
        let base = indptr[r0];
        let mut next: Vec<usize> = (r0..(r0 + rows_per_block).min(rows)).map(|r| (indptr[r] - base) as usize).collect();
        for blk in &buckets {
            for &(r, c, v) in &blk[rb] {
                let k = &mut next[r as usize - r0];
                idx[*k] = c;
                val[*k] = v;
                *k += 1;
            }
        }
    });
    Ok(CsrMatrix { rows, cols, indptr, indices, data })
}

impl SparseExport for ShiftOperator {
    fn to_csr(&self, memory_budget_bytes: u64) -> Result<CsrMatrix> {
        let (cs, is) = (self.cube_shape(), self.image_shape());
        let npix = cs.height * cs.width;
        assemble(self.name(), is.len(), npix, cs.bands, (npix * cs.bands) as u64, memory_budget_bytes, |q, emit| {
            let (r, c) = (q / cs.width, q % cs.width);
            if let Some(i) = self.detector_row(r) {
                for b in 0..cs.bands {
                    // The mask the pixel sees in this band (per band for a dual-disperser system) times the band's weight.
                    let m = self.coefficient(q, b);
                    if m == 0.0 {
                        continue;
                    }
                    if let Some(j) = self.detector_column(b, c) {
                        emit(b, (i * is.width + j) as u32, m);
                    }
                }
            }
        })
    }
}

impl SparseExport for MappingOperator {
    fn to_csr(&self, memory_budget_bytes: u64) -> Result<CsrMatrix> {
        let (cs, is) = (self.cube_shape(), self.image_shape());
        let npix = cs.height * cs.width;
        let taps = match self.interpolation() {
            super::MappingInterpolation::Nearest => 1,
            super::MappingInterpolation::Bilinear => 4,
        };
        assemble(self.name(), is.len(), npix, cs.bands, (npix * cs.bands * taps) as u64, memory_budget_bytes, |q, emit| {
            for b in 0..cs.bands {
                // The mask the pixel sees in this band (per band for a dual-disperser system) times the band's weight.
                let m = self.coefficient(q, b);
                if m == 0.0 {
                    continue;
                }
                // Taps of one point are distinct pixels in increasing order.
                self.point_taps(q, b, |k, w| emit(b, k as u32, w * m));
            }
        })
    }
}

/// Footprint of scene pixel `q` in a plane (footprints are stored in increasing pixel order, at most one
/// per pixel).
fn footprint_of(t: &PlaneTransport, q: usize) -> Option<&Footprint> {
    let i = t.footprints.partition_point(|f| (f.pixel as usize) < q);
    t.footprints.get(i).filter(|f| f.pixel as usize == q && f.w > 0 && f.h > 0)
}

/// Half-open detector rectangle [y0, y1) × [x0, x1).
#[derive(Clone, Copy)]
struct Boxed {
    y0: usize,
    y1: usize,
    x0: usize,
    x1: usize,
}

impl SparseExport for ExactOperator<'_> {
    fn to_csr(&self, memory_budget_bytes: u64) -> Result<CsrMatrix> {
        let (cs, is) = (self.cube_shape(), self.image_shape());
        let npix = cs.height * cs.width;
        let r = self.renderer();
        let (dw, dh) = (is.width, is.height);
        let weight = r.config.spectral.plane_weight;
        let mask = r.object_mask();
        // The transport: kept, or traced now (a streaming operator keeps none).
        let planes: Cow<'_, [PlaneTransport]> = match self.transport() {
            Some(t) => Cow::Borrowed(t),
            None => Cow::Owned(r.trace_all(&|_| {})?),
        };
        // Per band: the planes that read it and with which weight (plane order).
        let interp = self.interpolation();
        let per_band: Vec<Vec<(usize, f64)>> = (0..cs.bands)
            .map(|b| {
                interp
                    .iter()
                    .enumerate()
                    .filter_map(|(p, &(k, k1, t))| {
                        let c = if k == b { 1.0 - t as f64 } else { 0.0 } + if k1 == b { t as f64 } else { 0.0 };
                        (k == b || k1 == b).then_some((p, c))
                    })
                    .collect()
            })
            .collect();
        let half = |p: usize| r.kernels[p].as_ref().map_or(0, |k| k.half);
        // Blurred window of a footprint, clipped to the detector.
        let blurred = |f: &Footprint, h: usize| Boxed {
            y0: (f.y0 as usize).saturating_sub(h),
            y1: (f.y0 as usize + f.h as usize + h).min(dh),
            x0: (f.x0 as usize).saturating_sub(h),
            x1: (f.x0 as usize + f.w as usize + h).min(dw),
        };
        // Union of band b's blurred windows of pixel q (None when no plane's footprint arrived).
        let column_box = |q: usize, b: usize| -> Option<Boxed> {
            let mut bx: Option<Boxed> = None;
            for &(p, _) in &per_band[b] {
                if let Some(f) = footprint_of(&planes[p], q) {
                    let w = blurred(f, half(p));
                    bx = Some(match bx {
                        None => w,
                        Some(a) => Boxed { y0: a.y0.min(w.y0), y1: a.y1.max(w.y1), x0: a.x0.min(w.x0), x1: a.x1.max(w.x1) },
                    });
                }
            }
            bx.filter(|a| a.y0 < a.y1 && a.x0 < a.x1)
        };
        let nnz_bound: u64 = (0..npix)
            .into_par_iter()
            .map(|q| {
                if mask[q] == 0.0 {
                    return 0;
                }
                (0..cs.bands).filter_map(|b| column_box(q, b)).map(|a| ((a.y1 - a.y0) * (a.x1 - a.x0)) as u64).sum::<u64>()
            })
            .sum();
        assemble(self.name(), is.len(), npix, cs.bands, nnz_bound, memory_budget_bytes, |q, emit| {
            let m = mask[q] as f64;
            if m == 0.0 {
                return;
            }
            let mut acc: Vec<f64> = Vec::new();
            for b in 0..cs.bands {
                let Some(bx) = column_box(q, b) else { continue };
                let bw = bx.x1 - bx.x0;
                acc.clear();
                acc.resize((bx.y1 - bx.y0) * bw, 0.0);
                for &(p, c) in &per_band[b] {
                    let Some(f) = footprint_of(&planes[p], q) else { continue };
                    let scale = weight * m * c;
                    let ws = &planes[p].weights[f.start as usize..f.start as usize + f.w as usize * f.h as usize];
                    match &r.kernels[p] {
                        None => {
                            for (rr, row) in ws.chunks_exact(f.w as usize).enumerate() {
                                let y = f.y0 as usize + rr;
                                for (cc, fw) in row.iter().enumerate() {
                                    let x = f.x0 as usize + cc;
                                    acc[(y - bx.y0) * bw + (x - bx.x0)] += scale * *fw as f64;
                                }
                            }
                        }
                        Some(k) => {
                            // out[y][x] += a(ki, kj) · src[y − (ki − h)][x − (kj − h)], zero outside the detector.
                            let (n, h) = (2 * k.half + 1, k.half as isize);
                            for (rr, row) in ws.chunks_exact(f.w as usize).enumerate() {
                                let sy = (f.y0 as usize + rr) as isize;
                                for (cc, fw) in row.iter().enumerate() {
                                    if *fw == 0.0 {
                                        continue;
                                    }
                                    let sx = (f.x0 as usize + cc) as isize;
                                    let v = scale * *fw as f64;
                                    for ki in 0..n {
                                        let y = sy + ki as isize - h;
                                        if y < 0 || y >= dh as isize {
                                            continue;
                                        }
                                        let arow = &mut acc[(y as usize - bx.y0) * bw..(y as usize - bx.y0 + 1) * bw];
                                        for kj in 0..n {
                                            let a = k.weights[ki * n + kj];
                                            let x = sx + kj as isize - h;
                                            if a == 0.0 || x < 0 || x >= dw as isize {
                                                continue;
                                            }
                                            arow[x as usize - bx.x0] += v * a as f64;
                                        }
                                    }
                                }
                            }
                        }
                    }
                }
                for (i, v) in acc.iter().enumerate() {
                    if *v != 0.0 {
                        let (y, x) = (bx.y0 + i / bw, bx.x0 + i % bw);
                        emit(b, (y * dw + x) as u32, *v as f32);
                    }
                }
            }
        })
    }
}
