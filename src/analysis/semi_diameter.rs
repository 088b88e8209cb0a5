use crate::error::{Error, Result};
use crate::rays::aimed_ray;
use crate::system::SequentialSystem;
use crate::tracer::kernel::trace_steps_recording;
use glam::DVec3;

/// Zemax's automatic semi-diameters: for every traced surface, the largest radial height at which the
/// marginal rays (the pupil edge) of any field at any system wavelength cross it, plus `margin_mm` (Zemax's
/// "Semi-Diameter Margin" system setting). The stop's is the edge of the first field at the primary
/// wavelength only (the stop size the system aperture defines), without margin. The object's is the
/// largest field radius. Returns (surface index, semi-diameter mm) for the object and every traced surface.
///
/// The edge is sampled at `edge_samples` angles and each maximum refined by golden-section search, so the
/// result is exact to ~1e-9 mm for smooth footprints.
pub fn automatic_semi_diameters(system: &SequentialSystem, margin_mm: f64, edge_samples: usize) -> Result<Vec<(usize, f64)>> {
    if edge_samples < 8 {
        return Err(Error::invalid("automatic semi-diameters need at least 8 edge samples"));
    }
    let steps: Vec<usize> = system.surfaces.iter().skip(1).filter(|s| s.shape.is_some()).map(|s| s.index).collect();
    let mut best = vec![0.0f64; steps.len()];
    let fields = if system.spec.fields_mm.is_empty() { vec![[0.0, 0.0]] } else { system.spec.fields_mm.clone() };
    let mut hits: Vec<DVec3> = Vec::new();
    let stop_step = steps.iter().position(|&s| s == system.stop_index);
    for (fi, field) in fields.iter().enumerate() {
        for &w in &system.spec.wavelengths_nm {
            let n = system.indices(w)?;
            let primary_on_axis = fi == 0 && w == system.primary_wavelength_nm();
            // Radius at step k of the edge ray at angle a (NaN when the ray fails).
            let mut radius = |a: f64, k: usize| -> f64 {
                let Ok((o, d)) = aimed_ray(system, &n, *field, a.cos(), a.sin()) else { return f64::NAN };
                match trace_steps_recording(&system.path, &n, o, d, &mut hits) {
                    Ok(_) => hits[k].x.hypot(hits[k].y),
                    Err(_) => f64::NAN,
                }
            };
            for k in 0..steps.len() {
                if Some(k) == stop_step && !primary_on_axis {
                    continue;
                }
                let step = std::f64::consts::TAU / edge_samples as f64;
                let (mut a_best, mut r_best) = (0.0, f64::NEG_INFINITY);
                for j in 0..edge_samples {
                    let a = j as f64 * step;
                    let r = radius(a, k);
                    if r > r_best {
                        a_best = a;
                        r_best = r;
                    }
                }
                // Golden-section refinement of the maximum around the best sample.
                let (mut lo, mut hi) = (a_best - step, a_best + step);
                let g = 0.5 * (5f64.sqrt() - 1.0);
                for _ in 0..60 {
                    let (m1, m2) = (hi - g * (hi - lo), lo + g * (hi - lo));
                    if radius(m1, k) > radius(m2, k) {
                        hi = m2;
                    } else {
                        lo = m1;
                    }
                }
                let r = radius(0.5 * (lo + hi), k).max(r_best);
                if r.is_finite() {
                    best[k] = best[k].max(r);
                }
            }
        }
    }
    let object = fields.iter().map(|f| f[0].hypot(f[1])).fold(0.0, f64::max);
    let mut out = vec![(0, object)];
    for (k, &s) in steps.iter().enumerate() {
        out.push((s, if Some(k) == stop_step { best[k] } else { best[k] + margin_mm }));
    }
    Ok(out)
}
