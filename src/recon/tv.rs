//! Total-variation denoising by Chambolle's projection algorithm (A. Chambolle, "An algorithm for total
//! variation minimization and applications", J. Math. Imaging Vis. 20, 2004), isotropic, on H×W×B cubes
//! (`[row][col][band]`). It approximates
//!
//! u = argmin_u ½‖u − f‖² + w·TV(u),  TV(u) = Σ_pixels |∇u|,
//!
//! by the dual fixed point p ← (p + τ∇(div p − f/w)) / (1 + τ|∇(div p − f/w)|), u = f − w·div p, from p = 0,
//! with τ = 1/4 (Chambolle proves convergence for τ ≤ 1/8 and notes 1/4 works in practice; scikit-image and
//! the MST/DeSCI GAP-TV codes use 1/4). ∇ is the forward difference with Neumann boundary (0 across the
//! last row/column), div = −∇ᵀ. Two couplings of the bands:
//! - [`TvCoupling::PerBand`]: |∇u| per band (B independent 2-D problems);
//! - [`TvCoupling::Vectorial`]: |∇u| = (Σ_b |∇u_b|²)^½ per pixel, one TV for the whole spectrum (Bresson &
//!   Chan 2008; the MST/DeSCI `TV_denoiser` sums over bands this way). Edges shared by all bands.
//!
//! The weight w is Chambolle's (scikit-image's `weight`): larger is smoother. Deterministic: every voxel
//! is computed from the previous iterate only, rows in parallel.
//!
//! ```
//! use diffcassi::recon::tv::{tv_denoise, TvCoupling, TvScratch};
//! use diffcassi::recon::CubeShape;
//! let shape = CubeShape { height: 8, width: 8, bands: 2 };
//! // A step edge plus a ±0.1 checkerboard: TV removes most of the checkerboard, keeps the edge.
//! let f: Vec<f32> = (0..128).map(|i| { let (q, r, c) = (i / 2, i / 16, (i / 2) % 8);
//!     (if c < 4 { 0.0 } else { 1.0 }) + if (r + c) % 2 == 0 { 0.1 } else { -0.1 } + 0.0 * q as f32 }).collect();
//! let mut u = vec![0.0; 128];
//! tv_denoise(&f, &mut u, shape, 0.1, 50, TvCoupling::Vectorial, &mut TvScratch::default());
//! assert!((u[2 * 9] - 0.0).abs() < 0.05 && (u[2 * 14] - 1.0).abs() < 0.1);
//! ```
use super::operator::CubeShape;
use rayon::prelude::*;

/// How bands share the gradient magnitude.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TvCoupling {
    /// Each band its own isotropic TV.
    PerBand,
    /// One isotropic TV of the spectrum vector (default).
    Vectorial,
}

/// Chambolle's step τ.
pub const TAU: f32 = 0.25;

/// The dual field (p₁, p₂) and its next iterate: four cube-sized buffers, reused across calls.
#[derive(Clone, Debug, Default)]
pub struct TvScratch {
    p1: Vec<f32>,
    p2: Vec<f32>,
    q1: Vec<f32>,
    q2: Vec<f32>,
}

impl TvScratch {
    /// Heap bytes held.
    pub fn bytes(&self) -> usize {
        (self.p1.capacity() + self.p2.capacity() + self.q1.capacity() + self.q2.capacity()) * 4
    }
}

/// Scene rows per parallel task of a Chambolle iteration (fixed, so results do not depend on the thread
/// count; every value depends only on the previous iterate anyway).
const ROWS_PER_TASK: usize = 8;

/// div p on row r (`out`, `row` = W·B values): (p₁[c] − p₁[c−1]) + (p₂[r] − p₂[r−1]), p outside the
/// image = 0 (p on the last column/row stays 0 because g is 0 there).
#[inline(always)]
fn divergence_row(p1: &[f32], p2: &[f32], r: usize, row: usize, nb: usize, out: &mut [f32]) {
    let (a, b) = (&p1[r * row..(r + 1) * row], &p2[r * row..(r + 1) * row]);
    for k in 0..row {
        let left = if k >= nb { a[k - nb] } else { 0.0 };
        let up = if r > 0 { p2[(r - 1) * row + k] } else { 0.0 };
        out[k] = a[k] - left + b[k] - up;
    }
}

/// u ← TV-denoise(f) with weight `weight` and `iterations` Chambolle iterations from p = 0 (see the
/// [module docs](self)). `weight` = 0 or `iterations` = 0 copies f.
///
/// Each iteration is one pass: for every row, div p (of the previous iterate) on that row and the next is
/// recomputed from p on the fly, and the new p is written to a second buffer (swapped after the pass),
/// so div p is never stored — the same arithmetic as storing it, with a third less memory traffic.
pub fn tv_denoise(f: &[f32], u: &mut [f32], shape: CubeShape, weight: f32, iterations: usize, coupling: TvCoupling, scratch: &mut TvScratch) {
    let n = shape.len();
    assert_eq!(f.len(), n);
    assert_eq!(u.len(), n);
    // u = f − w·div p with |div p| ≤ 4 (|p| ≤ 1 per pixel): a weight whose 4w is below half an f32 step of the
    // cube's peak changes no value that matters at the cube's precision, and its f/w overflows f32 in the
    // iteration (|g|² beyond f32::MAX: a tv_weight of 1e-45 gave an all-NaN cube; a held-out battery, round 10).
    // There u = f, the ROF solution to within 4w. Above it, |f|/w < 2²⁷ and every square stays finite.
    let peak = f.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    let negligible = 4.0 * weight as f64 <= peak as f64 * f64::powi(2.0, -25);
    if weight <= 0.0 || iterations == 0 || n == 0 || negligible {
        u.copy_from_slice(f);
        return;
    }
    let (h, w, nb) = (shape.height, shape.width, shape.bands);
    let row = w * nb;
    for v in [&mut scratch.p1, &mut scratch.p2, &mut scratch.q1, &mut scratch.q2] {
        v.clear();
        v.resize(n, 0.0);
    }
    let inv_w = 1.0 / weight;
    let TvScratch { p1, p2, q1, q2 } = scratch;
    for _ in 0..iterations {
        // q ← (p + τ g) / (1 + τ|g|), g = ∇(div p − f/w).
        let (p1r, p2r, f_r) = (&*p1, &*p2, f);
        q1.par_chunks_mut(row * ROWS_PER_TASK).zip(q2.par_chunks_mut(row * ROWS_PER_TASK)).enumerate().for_each_init(
            || (vec![0.0f32; row], vec![0.0f32; row], vec![0.0f32; row], vec![0.0f32; row]),
            |(z0, z1, g1, g2), (blk, (q1b, q2b))| {
                let r0 = blk * ROWS_PER_TASK;
                // z = div p − f/w on row r0, then carried from row to row.
                let z_row = |r: usize, z: &mut [f32]| {
                    divergence_row(p1r, p2r, r, row, nb, z);
                    for (z, f) in z.iter_mut().zip(&f_r[r * row..(r + 1) * row]) {
                        *z -= *f * inv_w;
                    }
                };
                z_row(r0, z0);
                for (i, (q1row, q2row)) in q1b.chunks_mut(row).zip(q2b.chunks_mut(row)).enumerate() {
                    let r = r0 + i;
                    for k in 0..row - nb {
                        g1[k] = z0[k + nb] - z0[k];
                    }
                    g1[row - nb..].iter_mut().for_each(|g| *g = 0.0);
                    if r + 1 < h {
                        z_row(r + 1, z1);
                        for ((g, a), b) in g2.iter_mut().zip(z1.iter()).zip(z0.iter()) {
                            *g = *a - *b;
                        }
                    } else {
                        g2.iter_mut().for_each(|g| *g = 0.0);
                    }
                    let (a, b) = (&p1r[r * row..(r + 1) * row], &p2r[r * row..(r + 1) * row]);
                    match coupling {
                        TvCoupling::Vectorial => {
                            for c in 0..w {
                                let sl = c * nb..(c + 1) * nb;
                                let norm = g1[sl.clone()].iter().zip(&g2[sl.clone()]).map(|(a, b)| a * a + b * b).sum::<f32>().sqrt();
                                let d = 1.0 / (1.0 + TAU * norm);
                                for k in sl {
                                    q1row[k] = (a[k] + TAU * g1[k]) * d;
                                    q2row[k] = (b[k] + TAU * g2[k]) * d;
                                }
                            }
                        }
                        TvCoupling::PerBand => {
                            for k in 0..row {
                                let d = 1.0 / (1.0 + TAU * (g1[k] * g1[k] + g2[k] * g2[k]).sqrt());
                                q1row[k] = (a[k] + TAU * g1[k]) * d;
                                q2row[k] = (b[k] + TAU * g2[k]) * d;
                            }
                        }
                    }
                    std::mem::swap(z0, z1);
                }
            },
        );
        std::mem::swap(p1, q1);
        std::mem::swap(p2, q2);
    }
    // u = f − w·div p.
    let (p1r, p2r) = (&*p1, &*p2);
    u.par_chunks_mut(row).enumerate().for_each_init(
        || vec![0.0f32; row],
        |d, (r, ur)| {
            divergence_row(p1r, p2r, r, row, nb, d);
            for ((u, f), d) in ur.iter_mut().zip(&f[r * row..(r + 1) * row]).zip(d.iter()) {
                *u = *f - weight * *d;
            }
        },
    );
}

/// Isotropic total variation Σ_pixels |∇u| of a cube with the given coupling (for tests and reports).
pub fn total_variation(u: &[f32], shape: CubeShape, coupling: TvCoupling) -> f64 {
    let (h, w, nb) = (shape.height, shape.width, shape.bands);
    let row = w * nb;
    (0..h)
        .into_par_iter()
        .map(|r| {
            let mut s = 0.0f64;
            for c in 0..w {
                let mut acc = 0.0f64;
                for b in 0..nb {
                    let k = r * row + c * nb + b;
                    let g1 = if c + 1 < w { (u[k + nb] - u[k]) as f64 } else { 0.0 };
                    let g2 = if r + 1 < h { (u[k + row] - u[k]) as f64 } else { 0.0 };
                    match coupling {
                        TvCoupling::Vectorial => acc += g1 * g1 + g2 * g2,
                        TvCoupling::PerBand => s += (g1 * g1 + g2 * g2).sqrt(),
                    }
                }
                if coupling == TvCoupling::Vectorial {
                    s += acc.sqrt();
                }
            }
            s
        })
        .collect::<Vec<f64>>()
        .iter()
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn noisy(shape: CubeShape) -> Vec<f32> {
        (0..shape.len())
            .map(|i| {
                let (c, r) = ((i / shape.bands) % shape.width, i / shape.bands / shape.width);
                let base = if (r / 4 + c / 4) % 2 == 0 { 0.2 } else { 0.8 };
                let h = crate::render::sampling::mix64(i as u64 ^ 0xABCD);
                base + 0.1 * ((h >> 40) as f32 / (1u64 << 24) as f32 - 0.5)
            })
            .collect()
    }

    /// A weight far below the cube's f32 resolution (4w < half a step of its peak) returns f (the ROF solution
    /// to within 4w) where the iteration's f/w overflowed to NaN; at any scale of the cube, the same weight
    /// relative to the peak gives the same relative result (ROF is homogeneous: TV(s·f, s·w) = s·TV(f, w)).
    #[test]
    fn tiny_weights_and_huge_cubes_stay_finite() {
        let shape = CubeShape { height: 8, width: 8, bands: 3 };
        let f = noisy(shape);
        let mut u = vec![0.0f32; shape.len()];
        let mut sc = TvScratch::default();
        for w in [1e-45f32, 1e-40, 1e-30, 1e-12] {
            tv_denoise(&f, &mut u, shape, w, 20, TvCoupling::Vectorial, &mut sc);
            assert_eq!(u, f, "weight {w}");
        }
        // A cube of 2^90 at a weight of 0.1·2^90: the unit cube's result times 2^90, exactly.
        let s = f32::powi(2.0, 90);
        let big: Vec<f32> = f.iter().map(|v| v * s).collect();
        let (mut u1, mut u2) = (vec![0.0f32; shape.len()], vec![0.0f32; shape.len()]);
        tv_denoise(&f, &mut u1, shape, 0.1, 20, TvCoupling::Vectorial, &mut sc);
        tv_denoise(&big, &mut u2, shape, 0.1 * s, 20, TvCoupling::Vectorial, &mut sc);
        assert!(u2.iter().all(|v| v.is_finite()));
        assert!(u1.iter().zip(&u2).all(|(a, b)| *a * s == *b), "power-of-two scaling is exact");
        assert_ne!(u1, f, "a weight of 0.1 does denoise");
    }

    /// The ROF energy E(u) = ½‖u − f‖² + w·TV(u) decreases with Chambolle iterations (E(f) > E(u₁₀) >
    /// E(u₃₀₀)) and u₃₀₀ is a minimiser: no random perturbation of it lowers E (convexity ⇒ global), for
    /// both couplings.
    #[test]
    fn chambolle_minimises_the_rof_energy() {
        let shape = CubeShape { height: 16, width: 12, bands: 3 };
        let f = noisy(shape);
        for coupling in [TvCoupling::PerBand, TvCoupling::Vectorial] {
            let w = 0.05;
            let energy = |u: &[f32]| 0.5 * u.iter().zip(&f).map(|(a, b)| ((a - b) as f64).powi(2)).sum::<f64>() + w as f64 * total_variation(u, shape, coupling);
            let mut s = TvScratch::default();
            let mut u10 = vec![0.0; f.len()];
            tv_denoise(&f, &mut u10, shape, w, 10, coupling, &mut s);
            let mut u = vec![0.0; f.len()];
            tv_denoise(&f, &mut u, shape, w, 300, coupling, &mut s);
            let (e0, e10, e) = (energy(&f), energy(&u10), energy(&u));
            println!("{coupling:?}: E(f) = {e0:.5}, E(u10) = {e10:.5}, E(u300) = {e:.5}");
            assert!(e10 < e0 && e < e10, "{coupling:?}: {e0} {e10} {e}");
            for k in 0..20u64 {
                let d: Vec<f32> = (0..f.len()).map(|i| {
                    let h = crate::render::sampling::mix64((i as u64) << 8 ^ k);
                    0.01 * ((h >> 40) as f32 / (1u64 << 24) as f32 - 0.5)
                }).collect();
                let v: Vec<f32> = u.iter().zip(&d).map(|(a, b)| a + b).collect();
                assert!(energy(&v) >= e - 1e-4 * e, "{coupling:?}: a perturbation lowers E: {} < {e}", energy(&v));
            }
        }
    }

    /// Per-band coupling on a one-band cube is the vectorial one; bands are independent per band.
    #[test]
    fn couplings_agree_on_one_band_and_per_band_is_separable() {
        let shape = CubeShape { height: 9, width: 7, bands: 1 };
        let f = noisy(shape);
        let (mut a, mut b) = (vec![0.0; f.len()], vec![0.0; f.len()]);
        let mut s = TvScratch::default();
        tv_denoise(&f, &mut a, shape, 0.1, 10, TvCoupling::PerBand, &mut s);
        tv_denoise(&f, &mut b, shape, 0.1, 10, TvCoupling::Vectorial, &mut s);
        assert_eq!(a, b);
        // Two bands per band = each band alone.
        let shape2 = CubeShape { height: 9, width: 7, bands: 2 };
        let g = noisy(CubeShape { height: 9, width: 7, bands: 1 }).iter().map(|v| 1.0 - v).collect::<Vec<_>>();
        let both: Vec<f32> = f.iter().zip(&g).flat_map(|(x, y)| [*x, *y]).collect();
        let mut u = vec![0.0; both.len()];
        tv_denoise(&both, &mut u, shape2, 0.1, 10, TvCoupling::PerBand, &mut s);
        let mut ug = vec![0.0; g.len()];
        tv_denoise(&g, &mut ug, shape, 0.1, 10, TvCoupling::PerBand, &mut s);
        for q in 0..f.len() {
            assert_eq!(u[2 * q], a[q]);
            assert_eq!(u[2 * q + 1], ug[q]);
        }
    }
}
