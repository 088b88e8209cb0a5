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
use super::{mapping_cube, MappingCube};
use crate::error::{Error, Result};
use crate::rays::RayBatch;
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

/// Traced node positions at every wavelength: `[λ][node_row][node_col][xy]`.
pub(crate) struct NodeGrid {
    pub stride: usize,
    pub rows: usize,
    pub cols: usize,
    pub values: Vec<f64>,
}

impl NodeGrid {
    /// Chief rays traced per wavelength for an H×W cube at `stride`.
    pub(crate) fn count(height: usize, width: usize, stride: usize) -> usize {
        nodes(height, stride) * nodes(width, stride)
    }

    pub(crate) fn trace(system: &SequentialSystem, tracer: &dyn Tracer, height: usize, width: usize, pitch_mm: f64, wavelengths_nm: &[f64], stride: usize) -> Result<Self> {
        let (rows, cols) = (nodes(height, stride), nodes(width, stride));
        let s = stride as i64;
        let mut fields = Vec::with_capacity(rows * cols);
        for i in 0..rows as i64 {
            for j in 0..cols as i64 {
                fields.push(scene_xy_any(height, width, pitch_mm, (i - 1) * s, (j - 1) * s));
            }
        }
        let nl = wavelengths_nm.len();
        let mut values = vec![0.0; nl * rows * cols * 2];
        for (b, &w) in wavelengths_nm.iter().enumerate() {
            let out = tracer.trace(system, &RayBatch::chief_rays(system, &fields, w)?)?;
            if let Some(k) = out.status.iter().position(|s| *s != RayStatus::Ok) {
                return Err(Error::invalid(format!(
                    "interpolated mapping (stride {stride}): the chief ray of node ({}, {}) mm at {w} nm does not arrive ({}); use the exact cube (stride 1)",
                    fields[k][0], fields[k][1], out.status[k].label()
                )));
            }
            let base = b * rows * cols * 2;
            for k in 0..rows * cols {
                values[base + 2 * k] = out.x[k];
                values[base + 2 * k + 1] = out.y[k];
            }
        }
        Ok(NodeGrid { stride, rows, cols, values })
    }

    /// Interval index and Catmull–Rom weights of pixel index `p` along an axis of `nodes_n` nodes.
    #[inline]
    fn axis(&self, p: usize, nodes_n: usize) -> (usize, [f64; 4]) {
        let i = (p / self.stride).min(nodes_n - 4); // interval [i, i+1] in scene-node units
        let t = (p as f64 - (i * self.stride) as f64) / self.stride as f64;
        (i, catmull_rom(t)) // lattice nodes i .. i+3 ↔ scene nodes i−1 .. i+2
    }

    /// Interpolated (x, y) mm of pixel (row, col) at band `b`.
    pub(crate) fn at(&self, row: usize, col: usize, b: usize) -> [f64; 2] {
        let (i, wr) = self.axis(row, self.rows);
        let (j, wc) = self.axis(col, self.cols);
        let base = b * self.rows * self.cols * 2;
        let mut v = [0.0; 2];
        for (di, a) in wr.iter().enumerate() {
            let mut h = [0.0; 2];
            for (dj, c) in wc.iter().enumerate() {
                let k = base + 2 * ((i + di) * self.cols + j + dj);
                h[0] += c * self.values[k];
                h[1] += c * self.values[k + 1];
            }
            v[0] += a * h[0];
            v[1] += a * h[1];
        }
        v
    }
}

/// The mapping cube of [`mapping_cube`] from chief rays traced on every `stride`-th pixel (and a ring of
/// nodes outside), interpolated by separable cubic Catmull–Rom in between. `stride = 1` is the exact
/// cube. Rows are filled in parallel; each value depends only on its nodes, so the result does not
/// depend on the thread count.
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
    positions_mm.par_chunks_mut(width * nl * 2).enumerate().for_each(|(r, row)| {
        for c in 0..width {
            for b in 0..nl {
                let v = g.at(r, c, b);
                let k = (c * nl + b) * 2;
                row[k] = v[0];
                row[k + 1] = v[1];
            }
        }
    });
    Ok(MappingCube { height, width, wavelength_nm: wavelengths_nm.to_vec(), pixel_pitch_mm, positions_mm, valid: vec![1; height * width * nl] })
}

#[cfg(test)]
mod tests {
    use super::*;

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
}
