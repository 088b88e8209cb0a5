use crate::error::{Error, Result};
use crate::rays::aimed_ray;
use crate::system::SequentialSystem;
use crate::tracer::kernel::trace_steps_recording;
use glam::DVec3;

/// [`automatic_semi_diameters`] (no margin, 32 edge samples) of the system's fields mirrored to all four
/// quadrants: the *mechanical* clear radii a solid needs for a system whose fields cover one quadrant only
/// (the non-sequential solids of `tracer::nonseq::solids` and the mounts of `mechanics::parts`).
pub fn mirrored_semi_diameters(system: &SequentialSystem) -> Result<Vec<(usize, f64)>> {
    let mut mirrored = system.clone();
    mirrored.fields = mirrored_fields(system);
    automatic_semi_diameters(&mirrored, 0.0, 32)
}

/// The system's fields (the axis when it has none) mirrored to all four quadrants, each once (0.0 and −0.0
/// are one field), in a fixed order: the fields of [`mirrored_semi_diameters`] and of the non-sequential
/// solids' design beam (`crate::tracer::nonseq::design_beam`).
pub fn mirrored_fields(system: &SequentialSystem) -> Vec<[f64; 2]> {
    let mut fields = Vec::new();
    for f in system.fields_or_axis() {
        for (sx, sy) in [(1.0, 1.0), (-1.0, 1.0), (1.0, -1.0), (-1.0, -1.0)] {
            let g = [sx * f[0], sy * f[1]];
            if !fields.contains(&g) {
                fields.push(g);
            }
        }
    }
    fields
}

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
    let fields = system.fields_or_axis();
    let mut hits: Vec<DVec3> = Vec::new();
    let stop_step = steps.iter().position(|&s| s == system.stop_index);
    for (fi, field) in fields.iter().enumerate() {
        for &w in &system.spec.wavelengths_nm {
            let n = system.indices(w)?;
            let primary_on_axis = fi == 0 && w == system.primary_wavelength_nm();
            // Radii at every step of the edge ray at angle a (None when the ray fails).
            let mut radii = |a: f64| -> Option<Vec<f64>> {
                let (o, d) = aimed_ray(system, &n, *field, a.cos(), a.sin()).ok()?;
                trace_steps_recording(&system.path, &n, o, d, &mut hits).ok()?;
                Some(hits.iter().map(|h| h.x.hypot(h.y)).collect())
            };
            let step = std::f64::consts::TAU / edge_samples as f64;
            // One pass over the edge samples finds, for every surface, the best sample…
            let mut sampled: Vec<(f64, f64)> = vec![(0.0, f64::NEG_INFINITY); steps.len()];
            for j in 0..edge_samples {
                let a = j as f64 * step;
                if let Some(r) = radii(a) {
                    for k in 0..steps.len() {
                        if r[k] > sampled[k].1 {
                            sampled[k] = (a, r[k]);
                        }
                    }
                }
            }
            // …then a golden-section search refines each surface's maximum around it.
            for k in 0..steps.len() {
                if (Some(k) == stop_step && !primary_on_axis) || !sampled[k].1.is_finite() {
                    continue;
                }
                let at = |a: f64, radii: &mut dyn FnMut(f64) -> Option<Vec<f64>>| radii(a).map(|r| r[k]).unwrap_or(f64::NEG_INFINITY);
                let (mut lo, mut hi) = (sampled[k].0 - step, sampled[k].0 + step);
                let g = 0.5 * (5f64.sqrt() - 1.0);
                for _ in 0..60 {
                    let (m1, m2) = (hi - g * (hi - lo), lo + g * (hi - lo));
                    if at(m1, &mut radii) > at(m2, &mut radii) {
                        hi = m2;
                    } else {
                        lo = m1;
                    }
                }
                best[k] = best[k].max(at(0.5 * (lo + hi), &mut radii).max(sampled[k].1));
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
