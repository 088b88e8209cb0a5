//! A cheaper model of the mapping cube: trace the chief rays of every `stride`-th scene pixel only (plus
//! one ring of nodes beyond the border) and fill the pixels between them by separable cubic
//! Catmull–Rom interpolation (Catmull & Rom 1974; uniform knots, third-order accurate, exact at the
//! nodes). The mapping is a smooth function of the object point (distortion and dispersion vary over
//! millimetres, the nodes are `stride` × 10 µm apart), so the interpolation error is small and is
//! *measured* by [`crate::fidelity`] before `--tolerance-um` uses it; `stride = 1` is the exact cube.
//!
//! Every node must arrive: if one does not (vignetting inside the field), the model refuses with an
//! error instead of interpolating across the edge; the exact cube handles such scenes.
//!
//! ```
//! use diffcassi::prelude::*;
//! let sys = SequentialSystem::build(&presets::spec("sp")?)?;
//! let ws = [450.0, 650.0];
//! let exact = analysis::mapping_cube(&sys, &AnalyticTracer::default(), 24, 24, 0.01, &ws)?;
//! let cheap = analysis::mapping_cube_interpolated(&sys, &AnalyticTracer::default(), 24, 24, 0.01, &ws, 4)?;
//! let max_um = exact.positions_mm.iter().zip(&cheap.positions_mm).map(|(a, b)| 1e3 * (a - b).abs()).fold(0.0, f64::max);
//! assert!(max_um < 1e-3);
//! # Ok::<(), diffcassi::Error>(())
//! ```
use super::mapping::{trace_chief_rays, trace_chief_rays_batched, Bands, Landing, Route};
use super::{mapping_cube, MappingCube};
use crate::error::{Error, Result};
use crate::system::SequentialSystem;
use crate::tracer::{RayStatus, Tracer};
use rayon::prelude::*;

/// Catmull–Rom weights of the nodes −1, 0, 1, 2 at parameter t ∈ [0, 1].
#[inline]
fn catmull_rom(t: f64) -> [f64; 4] {
    let (t2, t3) = (t * t, t * t * t);
    [0.5 * (-t3 + 2.0 * t2 - t), 0.5 * (3.0 * t3 - 5.0 * t2 + 2.0), 0.5 * (-3.0 * t3 + 4.0 * t2 + t), 0.5 * (t3 - t2)]
}

/// Node count of one axis: pixel indices −s, 0, s, …, K·s, (K+1)·s with K·s ≥ n − 1 (K ≥ 1).
fn nodes(n: usize, s: usize) -> usize {
    (n - 1).div_ceil(s).max(1) + 3
}

/// Scene-plane coordinates (mm) of a (possibly virtual, outside the scene) pixel index.
fn scene_xy_any(height: usize, width: usize, pitch_mm: f64, row: i64, col: i64) -> [f64; 2] {
    [(col as f64 + 0.5 - width as f64 / 2.0) * pitch_mm, (height as f64 / 2.0 - row as f64 - 0.5) * pitch_mm]
}

/// Traced node positions: `values` in C order `[node_row][node_col][λ][xy]` (the cube's own order, so a
/// node row is one contiguous slice and interpolation runs over contiguous `λ × xy` runs).
pub(crate) struct NodeGrid {
    pub stride: usize,
    pub rows: usize,
    pub cols: usize,
    pub bands: usize,
    pub values: Vec<f64>,
}

impl NodeGrid {
    /// Chief rays traced per wavelength for an H×W cube at `stride`.
    pub(crate) fn count(height: usize, width: usize, stride: usize) -> usize {
        nodes(height, stride) * nodes(width, stride)
    }

    /// Trace every node at every wavelength: in parallel over node rows through the analytic kernel
    /// (as [`mapping_cube`]), or batched through another tracer. The first node that does not arrive (in
    /// wavelength, row, column order, whatever the thread count) is an error.
    pub(crate) fn trace(system: &SequentialSystem, tracer: &dyn Tracer, height: usize, width: usize, pitch_mm: f64, wavelengths_nm: &[f64], stride: usize) -> Result<Self> {
        let (rows, cols) = (nodes(height, stride), nodes(width, stride));
        let s = stride as i64;
        let field = |i: usize, j: usize| scene_xy_any(height, width, pitch_mm, (i as i64 - 1) * s, (j as i64 - 1) * s);
        let bands = Bands::new(system, wavelengths_nm)?;
        let nl = bands.len();
        let mut values = vec![0.0; rows * cols * nl * 2];
        // Per node row: the first failed node as (band, column, status).
        type Failure = Option<(usize, usize, RayStatus)>;
        let keep = |first: &mut Failure, b: usize, j: usize, st: RayStatus| {
            if first.map_or(true, |(fb, fj, _)| (b, j) < (fb, fj)) {
                *first = Some((b, j, st));
            }
        };
        let failures: Vec<Failure> = match Route::of(tracer)? {
            Route::Direct(kernel, precision) => {
                let results: Vec<Result<Failure>> = values
                    .par_chunks_mut(cols * nl * 2)
                    .enumerate()
                    .map(|(i, row)| {
                        let fields: Vec<[f64; 2]> = (0..cols).map(|j| field(i, j)).collect();
                        let mut first: Failure = None;
                        trace_chief_rays(system, kernel, precision, &fields, &bands, |j, b, land: Landing| match land {
                            Ok([x, y]) => {
                                row[2 * (j * nl + b)] = x;
                                row[2 * (j * nl + b) + 1] = y;
                            }
                            Err(st) => keep(&mut first, b, j, st),
                        })?;
                        Ok(first)
                    })
                    .collect();
                let mut failures = Vec::with_capacity(rows);
                for r in results {
                    failures.push(r?);
                }
                failures
            }
            Route::Batched(tracer) => {
                let fields: Vec<[f64; 2]> = (0..rows * cols).map(|k| field(k / cols, k % cols)).collect();
                let mut failures: Vec<Failure> = vec![None; rows];
                trace_chief_rays_batched(system, tracer, &fields, &bands, |k, b, land| match land {
                    Ok([x, y]) => {
                        values[2 * (k * nl + b)] = x;
                        values[2 * (k * nl + b) + 1] = y;
                    }
                    Err(st) => keep(&mut failures[k / cols], b, k % cols, st),
                })?;
                failures
            }
        };
        let first = failures.iter().enumerate().filter_map(|(i, f)| f.map(|(b, j, st)| (b, i, j, st))).min_by_key(|&(b, i, j, _)| (b, i, j));
        if let Some((b, i, j, st)) = first {
            let f = field(i, j);
            return Err(Error::invalid(format!(
                "interpolated mapping (stride {stride}): the chief ray of node ({}, {}) mm at {} nm does not arrive ({}); use the exact cube (stride 1)",
                f[0],
                f[1],
                wavelengths_nm[b],
                st.label()
            )));
        }
        Ok(NodeGrid { stride, rows, cols, bands: nl, values })
    }

    /// Interval index and Catmull–Rom weights of pixel index `p` along an axis of `nodes_n` nodes.
    #[inline]
    fn axis(&self, p: usize, nodes_n: usize) -> (usize, [f64; 4]) {
        let i = (p / self.stride).min(nodes_n - 4); // interval [i, i+1] in scene-node units
        let t = (p as f64 - (i * self.stride) as f64) / self.stride as f64;
        (i, catmull_rom(t)) // lattice nodes i .. i+3 ↔ scene nodes i−1 .. i+2
    }

    /// Interpolated (x, y) mm of pixel (row, col) at band `b`: along the row first (on each of the four
    /// node rows), then down the column — the arithmetic of [`NodeGrid::fill`], bit for bit.
    pub(crate) fn at(&self, row: usize, col: usize, b: usize) -> [f64; 2] {
        let (i, wr) = self.axis(row, self.rows);
        let (j, wc) = self.axis(col, self.cols);
        let nl = self.bands;
        let mut v = [0.0; 2];
        for (di, a) in wr.iter().enumerate() {
            let mut h = [0.0; 2];
            for (dj, c) in wc.iter().enumerate() {
                let k = 2 * (((i + di) * self.cols + j + dj) * nl + b);
                h[0] += c * self.values[k];
                h[1] += c * self.values[k + 1];
            }
            v[0] += a * h[0];
            v[1] += a * h[1];
        }
        v
    }

    /// Node row `i` interpolated along the row to every pixel column: `out[col][λ][xy]`.
    fn row_along(&self, i: usize, col_weights: &[(usize, [f64; 4])], out: &mut [f64]) {
        let e = self.bands * 2;
        let node_row = &self.values[i * self.cols * e..(i + 1) * self.cols * e];
        for (o, &(j, w)) in out.chunks_exact_mut(e).zip(col_weights) {
            let n = [&node_row[j * e..(j + 1) * e], &node_row[(j + 1) * e..(j + 2) * e], &node_row[(j + 2) * e..(j + 3) * e], &node_row[(j + 3) * e..(j + 4) * e]];
            for (k, o) in o.iter_mut().enumerate() {
                let mut h = 0.0;
                h += w[0] * n[0][k];
                h += w[1] * n[1][k];
                h += w[2] * n[2][k];
                h += w[3] * n[3][k];
                *o = h;
            }
        }
    }

    /// The H×W cube `[row][col][λ][xy]` from the nodes, separably (Catmull–Rom is a tensor product):
    /// each task takes a run of pixel rows that share a node interval, interpolates its four node rows
    /// along the row to every column once, then each pixel row down the columns — contiguous loops over
    /// `col × λ × xy`. Each value depends on its nodes only: no dependence on the thread count.
    fn fill(&self, width: usize, positions_mm: &mut [f64]) {
        let e = self.bands * 2;
        let col_weights: Vec<(usize, [f64; 4])> = (0..width).map(|c| self.axis(c, self.cols)).collect();
        positions_mm.par_chunks_mut(self.stride * width * e).enumerate().for_each(|(q, run)| {
            let mut along = vec![0.0; 4 * width * e];
            let mut interval = usize::MAX;
            for (dr, out) in run.chunks_exact_mut(width * e).enumerate() {
                let (i, wr) = self.axis(q * self.stride + dr, self.rows);
                if i != interval {
                    for (di, a) in along.chunks_exact_mut(width * e).enumerate() {
                        self.row_along(i + di, &col_weights, a);
                    }
                    interval = i;
                }
                let (a0, rest) = along.split_at(width * e);
                let (a1, rest) = rest.split_at(width * e);
                let (a2, a3) = rest.split_at(width * e);
                for (k, o) in out.iter_mut().enumerate() {
                    let mut v = 0.0;
                    v += wr[0] * a0[k];
                    v += wr[1] * a1[k];
                    v += wr[2] * a2[k];
                    v += wr[3] * a3[k];
                    *o = v;
                }
            }
        });
    }
}

/// The mapping cube of [`mapping_cube`] from chief rays traced on every `stride`-th pixel (and a ring of
/// nodes outside), interpolated by separable cubic Catmull–Rom in between. `stride = 1` is the exact
/// cube. Nodes are traced and the cube is filled in parallel; each value depends only on its nodes, so
/// the result does not depend on the thread count.
pub fn mapping_cube_interpolated(system: &SequentialSystem, tracer: &dyn Tracer, height: usize, width: usize, pixel_pitch_mm: f64, wavelengths_nm: &[f64], stride: usize) -> Result<MappingCube> {
    if stride == 0 {
        return Err(Error::invalid("mapping stride must be ≥ 1"));
    }
    if stride == 1 || height == 0 || width == 0 || wavelengths_nm.is_empty() || !(pixel_pitch_mm.is_finite() && pixel_pitch_mm > 0.0) {
        return mapping_cube(system, tracer, height, width, pixel_pitch_mm, wavelengths_nm); // (and its input errors)
    }
    let g = NodeGrid::trace(system, tracer, height, width, pixel_pitch_mm, wavelengths_nm, stride)?;
    let nl = wavelengths_nm.len();
    let mut positions_mm = vec![0.0; height * width * nl * 2];
    g.fill(width, &mut positions_mm);
    Ok(MappingCube { height, width, wavelength_nm: wavelengths_nm.to_vec(), pixel_pitch_mm, positions_mm, valid: vec![1; height * width * nl] })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tracer::AnalyticTracer;

    #[test]
    fn weights_sum_to_one_and_interpolate() {
        for t in [0.0, 0.25, 0.5, 0.9, 1.0] {
            let w = catmull_rom(t);
            assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-15);
            // Exact for linear data: Σ w_k (k − 1) = t.
            assert!((w.iter().enumerate().map(|(k, w)| w * (k as f64 - 1.0)).sum::<f64>() - t).abs() < 1e-15);
        }
        assert_eq!(catmull_rom(0.0), [0.0, 1.0, 0.0, 0.0]);
    }

    /// Any tracer but the analytic one's direct route: the analytic tracer behind another name, so the
    /// batched route is taken.
    struct Batched(AnalyticTracer);
    impl Tracer for Batched {
        fn name(&self) -> String {
            "batched-analytic".into()
        }
        fn trace(&self, system: &SequentialSystem, rays: &crate::rays::RayBatch) -> Result<crate::tracer::TracedBatch> {
            self.0.trace(system, rays)
        }
    }

    fn system(name: &str) -> SequentialSystem {
        SequentialSystem::build(&crate::presets::spec(name).unwrap()).unwrap()
    }

    /// The interpolation error bound of the bench's 512×512 SP cube at stride 16 (nodes 0.16 mm apart over a
    /// 5.12 mm field, 1e-3 µm), measured on a smaller cube with the same field and node spacing: 128×128
    /// pixels of 0.04 mm at stride 4, every preset, three wavelengths, every entry against the exact cube.
    #[test]
    fn interpolation_error_is_within_a_nanometre_at_the_bench_node_spacing() {
        let ws = [450.0, 550.0, 650.0];
        for name in crate::presets::NAMES {
            let sys = system(name);
            let exact = mapping_cube(&sys, &AnalyticTracer::default(), 128, 128, 0.04, &ws).unwrap();
            assert_eq!(exact.invalid_count(), 0, "{name}");
            let cheap = mapping_cube_interpolated(&sys, &AnalyticTracer::default(), 128, 128, 0.04, &ws, 4).unwrap();
            let e = crate::fidelity::mapping_error(&exact, &cheap);
            println!("{name}: stride 4 at 0.04 mm, max error {:.3e} µm over {} entries", e.max_um, e.compared);
            assert!(e.mismatches == 0 && e.compared == 128 * 128 * 3 && e.max_um <= 1e-3, "{name}: {e:?}");
            // Not trivially exact either: the interpolation is used between the nodes.
            assert!(e.max_um > 0.0, "{name}");
        }
    }

    /// The parallel fill is the arithmetic of `NodeGrid::at` (which the fidelity calibration measures), bit
    /// for bit; the batched route (another tracer) and one thread give the same cube.
    #[test]
    fn fill_equals_at_and_routes_and_threads_agree() {
        let sys = system("msp");
        let (h, w, s, ws) = (37, 29, 8, [450.0, 600.0]); // runs that do not divide the size
        let cube = mapping_cube_interpolated(&sys, &AnalyticTracer::default(), h, w, 0.02, &ws, s).unwrap();
        let g = NodeGrid::trace(&sys, &AnalyticTracer::default(), h, w, 0.02, &ws, s).unwrap();
        for r in 0..h {
            for c in 0..w {
                for b in 0..ws.len() {
                    assert_eq!(cube.get(r, c, b), Some(g.at(r, c, b)), "({r}, {c}, {b})");
                }
            }
        }
        let batched = mapping_cube_interpolated(&sys, &Batched(AnalyticTracer::default()), h, w, 0.02, &ws, s).unwrap();
        assert_eq!(batched.positions_mm, cube.positions_mm);
        let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap().install(|| mapping_cube_interpolated(&sys, &AnalyticTracer::default(), h, w, 0.02, &ws, s).unwrap());
        assert_eq!(one.positions_mm, cube.positions_mm);
    }

    /// A node that does not arrive is refused, never interpolated across: both when the scene itself is
    /// partly vignetted and when only the ring of nodes beyond its border is. The message is the same on
    /// both routes and names the first failing node in (wavelength, row, column) order.
    #[test]
    fn a_node_that_does_not_arrive_is_refused() {
        let sys = system("sp");
        let ws = [450.0, 650.0];
        // 16×16 pixels of 1 mm: the exact cube loses its corners.
        let exact = mapping_cube(&sys, &AnalyticTracer::default(), 16, 16, 1.0, &ws).unwrap();
        assert!(exact.invalid_count() > 0);
        // 16×16 pixels of 0.6 mm arrive everywhere, but not the corner nodes 8 pixels (4.8 mm) beyond the border.
        let inside = mapping_cube(&sys, &AnalyticTracer::default(), 16, 16, 0.6, &ws).unwrap();
        assert_eq!(inside.invalid_count(), 0);
        for (pitch, stride) in [(1.0, 2), (0.6, 8)] {
            let direct = mapping_cube_interpolated(&sys, &AnalyticTracer::default(), 16, 16, pitch, &ws, stride).unwrap_err().to_string();
            assert!(direct.contains(&format!("stride {stride}")) && direct.contains("does not arrive") && direct.contains("450 nm"), "{direct}");
            let batched = mapping_cube_interpolated(&sys, &Batched(AnalyticTracer::default()), 16, 16, pitch, &ws, stride).unwrap_err().to_string();
            assert_eq!(direct, batched);
            let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap().install(|| mapping_cube_interpolated(&sys, &AnalyticTracer::default(), 16, 16, pitch, &ws, stride).unwrap_err().to_string());
            assert_eq!(direct, one);
        }
    }
}
