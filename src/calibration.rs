//! Misalignment calibration: recover parameters of a system (e.g. the prism's tilt) from observed spot
//! centroids, by Levenberg–Marquardt on exact Jacobians ([`crate::diff`]).
//!
//! The observation is a set of spot centroids (image plane, mm): for each field point of a grid and each
//! wavelength, the mean landing point of a fixed pupil pattern. The model is the nominal system with the
//! free parameters; its centroids' derivatives are the means of the rays' position derivatives (the
//! object-space rays are regenerated from (field, pupil) at every iterate; the Jacobian treats them as
//! fixed, which is exact for parameters behind the paraxial pupil's reach — Coordinate Break tilts and
//! decenters — and a Gauss–Newton approximation otherwise).
//!
//! ```
//! use diffcassi::calibration::{calibrate, observe, CalibrationSetup};
//! use diffcassi::diff::{Param, ParamSet};
//! use diffcassi::materials::GlassCatalog;
//! let setup = CalibrationSetup::small();
//! let observed = observe(&diffcassi::system::SequentialSystem::build(&diffcassi::presets::spec("msp")?)?, &setup)?;
//! let set = ParamSet::new(diffcassi::presets::spec("sp")?, GlassCatalog::builtin(), vec![Param::parse("s4.tilt_x_deg")?])?;
//! let fit = calibrate(&set, &observed, &setup)?;
//! assert!((fit.x[0] - 5.0).abs() < 0.01);
//! # Ok::<(), diffcassi::Error>(())
//! ```
use crate::diff::ParamSet;
use crate::error::{Error, Result};
use crate::optim::{levenberg_marquardt, Bounds, Evaluation, LmOptions, OptimReport};
use crate::rays::{PupilPattern, RayBatch};
use crate::system::SequentialSystem;
use crate::tracer::{AnalyticTracer, RayStatus, Tracer};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Which centroids are observed.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct CalibrationSetup {
    /// Object field points (mm).
    pub fields_mm: Vec<[f64; 2]>,
    pub wavelengths_nm: Vec<f64>,
    /// Normalised pupil points traced per (field, wavelength).
    pub pupil: Vec<[f64; 2]>,
}

impl CalibrationSetup {
    /// 5×5 fields over ±2.5 mm, 450/520/650 nm, hexapolar pupil with 3 rings (37 rays).
    pub fn standard() -> Self {
        let grid = crate::analysis::linspace(-2.5, 2.5, 5);
        let fields_mm = grid.iter().flat_map(|&x| grid.iter().map(move |&y| [x, y])).collect();
        CalibrationSetup { fields_mm, wavelengths_nm: vec![450.0, 520.0, 650.0], pupil: PupilPattern::Hexapolar { rings: 3 }.points() }
    }
    /// 3×3 fields, two wavelengths, 7 pupil rays (for examples and quick checks).
    pub fn small() -> Self {
        let grid = [-2.5, 0.0, 2.5];
        let fields_mm = grid.iter().flat_map(|&x| grid.iter().map(move |&y| [x, y])).collect();
        CalibrationSetup { fields_mm, wavelengths_nm: vec![450.0, 650.0], pupil: PupilPattern::Hexapolar { rings: 1 }.points() }
    }
    fn batch(&self, sys: &SequentialSystem) -> Result<RayBatch> {
        let mut b = RayBatch::default();
        for &w in &self.wavelengths_nm {
            for &f in &self.fields_mm {
                b.extend(&RayBatch::for_field(sys, f, &self.pupil, w)?);
            }
        }
        Ok(b)
    }
    fn groups(&self) -> usize {
        self.wavelengths_nm.len() * self.fields_mm.len()
    }
    /// The (field, wavelength) of observation group `g` (wavelength-major, as [`observe`] orders them).
    fn group_point(&self, g: usize) -> ([f64; 2], f64) {
        let nf = self.fields_mm.len();
        (self.fields_mm[g % nf], self.wavelengths_nm[g / nf])
    }
}

/// What the rays of one (field, wavelength) group did when none reached the image: "7 vignetted at surface 16".
fn failure_summary(traced: &crate::tracer::TracedBatch, range: std::ops::Range<usize>) -> String {
    let mut counts: Vec<(String, usize)> = Vec::new();
    for i in range {
        let st = traced.status[i];
        let what = if st == RayStatus::Ok { "not finite".to_string() } else if traced.surface[i] == u32::MAX { st.label().to_string() } else { format!("{} at surface {}", st.label(), traced.surface[i]) };
        match counts.iter_mut().find(|c| c.0 == what) {
            Some(c) => c.1 += 1,
            None => counts.push((what, 1)),
        }
    }
    counts.iter().map(|(w, k)| format!("{k} {w}")).collect::<Vec<_>>().join(", ")
}

/// The error of a (field, wavelength) group none of whose rays reaches the image, naming the system, the
/// field point and the wavelength (indices alone — "observation group 0" — named neither: a held-out
/// battery, round 16).
fn no_ray_error(what: &str, setup: &CalibrationSetup, g: usize, traced: &crate::tracer::TracedBatch) -> Error {
    let m = setup.pupil.len();
    let (f, w) = setup.group_point(g);
    Error::invalid(format!(
        "{what}: no ray of field ({}, {}) mm at {} nm reaches the image ({} of {m} pupil rays: {}); a centroid needs at least one",
        crate::limits::fmt_num(f[0]),
        crate::limits::fmt_num(f[1]),
        crate::limits::fmt_num(w),
        m,
        failure_summary(traced, g * m..(g + 1) * m)
    ))
}

/// Spot centroids (x, y mm) of `system`, one per (wavelength, field) in that order. An error names "the
/// observed system"; [`observe_named`] names it otherwise.
pub fn observe(system: &SequentialSystem, setup: &CalibrationSetup) -> Result<Vec<[f64; 2]>> {
    observe_named(system, setup, "the observed system")
}

/// [`observe`], its errors naming the system `what` (e.g. "--observed msp.toml").
pub fn observe_named(system: &SequentialSystem, setup: &CalibrationSetup, what: &str) -> Result<Vec<[f64; 2]>> {
    let rays = setup.batch(system)?;
    let t = AnalyticTracer::default().trace(system, &rays)?;
    let m = setup.pupil.len();
    (0..setup.groups())
        .map(|g| {
            let ok: Vec<usize> = (g * m..(g + 1) * m).filter(|&i| t.status[i] == RayStatus::Ok).collect();
            if ok.is_empty() {
                return Err(no_ray_error(what, setup, g, &t));
            }
            let k = ok.len() as f64;
            Ok([ok.iter().map(|&i| t.x[i]).sum::<f64>() / k, ok.iter().map(|&i| t.y[i]).sum::<f64>() / k])
        })
        .collect()
}

/// How an observed system's optical surfaces differ in structure from the model's: their number, or the type
/// of one — what no value of the model's free parameters can change (a glass can: `glass_nd`, `glass_vd`).
/// Coordinate breaks and dummy planes (flat Standard surfaces with air on both sides) are left out: a
/// misaligned copy adds its own (mAP is AP with a dummy plane and five more breaks). `None`: the same structure.
pub fn structure_difference(model: &[crate::spec::SurfaceSpec], observed: &[crate::spec::SurfaceSpec]) -> Option<String> {
    use crate::spec::SurfaceKind;
    let optical = |v: &[crate::spec::SurfaceSpec]| {
        let mut before_air = true;
        let mut kinds = Vec::new();
        for (i, s) in v.iter().enumerate() {
            if s.kind == SurfaceKind::CoordinateBreak {
                continue; // keeps the medium before it
            }
            let after_air = s.material.is_none();
            let flat = s.radius_mm.as_ref().is_none_or(|r| r.value.is_infinite() || r.value == 0.0);
            let dummy = s.kind == SurfaceKind::Standard && flat && before_air && after_air && i != 0 && i + 1 != v.len();
            if !dummy {
                kinds.push(s.kind);
            }
            before_air = after_air;
        }
        kinds
    };
    let (m, o) = (optical(model), optical(observed));
    if m.len() != o.len() {
        return Some(format!("{} optical surfaces against {} (coordinate breaks and dummy planes aside)", o.len(), m.len()));
    }
    m.iter().zip(&o).enumerate().find_map(|(i, (a, b))| (a != b).then(|| format!("optical surface {i} (coordinate breaks and dummy planes aside) is {}, not {}", b.label(), a.label())))
}

/// Where the two systems' surface lists differ in layout — every surface counted, Coordinate Breaks and dummy
/// planes included, by index and type: `None` when surface N is the same kind of surface in both, for every N.
/// Unlike [`structure_difference`] (which leaves breaks and dummies aside, so that mAP is a misaligned AP),
/// this decides whether a cell of the model's surface N *means* the same as the observed's surface N.
pub fn layout_difference(model: &[crate::spec::SurfaceSpec], observed: &[crate::spec::SurfaceSpec]) -> Option<String> {
    if model.len() != observed.len() {
        return Some(format!("it has {} surfaces against --from's {}", observed.len(), model.len()));
    }
    model.iter().zip(observed).enumerate().find_map(|(i, (a, b))| (a.kind != b.kind).then(|| format!("its surface {i} is {}, --from's is {}", b.kind.label(), a.kind.label())))
}

/// The true value of the model's parameter `param` in the observed spec, or why it is unknown. A cell is read
/// from the observed surface of the same index only when the two surface lists have the same layout
/// ([`layout_difference`]): a tilt is a rotation composed with the breaks around it, so another numbering or
/// another set of breaks makes "the same cell" another quantity (`--from ap --observed map` read AP's surface 7
/// tilt from mAP's surface 7, −29.238° — AP's surface 5 — and printed an error of 53°: a held-out battery,
/// round 16). A glass, curvature, wavelength or ray parameter is not read from the observed spec.
pub fn truth_of(param: &crate::diff::Param, model: &[crate::spec::SurfaceSpec], observed: &[crate::spec::SurfaceSpec]) -> std::result::Result<f64, String> {
    use crate::diff::Param;
    match param {
        Param::Cell { surface, column } => {
            if let Some(d) = layout_difference(model, observed) {
                return Err(format!("--observed numbers its surfaces differently ({d}), so its surface {surface} is not --from's: the truth is unknown"));
            }
            match observed.get(*surface).and_then(|s| s.clone().cell_or_default(column).map(|c| c.value)) {
                Some(v) if v.is_finite() => Ok(v),
                _ => Err(format!("--observed's surface {surface} has no {column} value")),
            }
        }
        p => Err(format!("{} is not read from the observed spec (only surface cells are)", p.name())),
    }
}

/// Add independent Gaussian noise of `sigma_um` (µm, per coordinate) to centroids, from a ChaCha8 stream
/// seeded with `seed` (Box–Muller).
pub fn add_noise(centroids: &mut [[f64; 2]], sigma_um: f64, seed: u64) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    for c in centroids.iter_mut() {
        for v in c.iter_mut() {
            let (u1, u2): (f64, f64) = (rng.gen::<f64>().max(f64::MIN_POSITIVE), rng.gen());
            *v += 1e-3 * sigma_um * (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos();
        }
    }
}

/// Model centroids and their Jacobian (µm per parameter unit) at `x`: residuals (model − observed) in µm.
fn evaluate(set: &ParamSet, observed: &[[f64; 2]], setup: &CalibrationSetup, x: &[f64]) -> Result<Evaluation> {
    let ds = set.with_values(x)?.build()?;
    let rays = setup.batch(&ds.system)?;
    let j = ds.trace(&rays)?;
    let (n, m) = (x.len(), setup.pupil.len());
    let mut r = Vec::with_capacity(2 * observed.len());
    let mut jac = Vec::with_capacity(2 * observed.len() * n);
    for (g, obs) in observed.iter().enumerate() {
        let ok: Vec<usize> = (g * m..(g + 1) * m).filter(|&i| j.usable(i)).collect();
        if ok.is_empty() {
            let at: Vec<String> = set.free.iter().zip(x).map(|(p, v)| format!("{} = {}", p.name(), crate::limits::fmt_num(*v))).collect();
            return Err(no_ray_error(&format!("the model (--from's system at {})", at.join(", ")), setup, g, &j.traced));
        }
        let k = ok.len() as f64;
        for c in 0..2 {
            let pos: f64 = ok.iter().map(|&i| if c == 0 { j.traced.x[i] } else { j.traced.y[i] }).sum::<f64>() / k;
            r.push(1e3 * (pos - obs[c]));
            for p in 0..n {
                jac.push(1e3 * ok.iter().map(|&i| j.row(i, c)[p]).sum::<f64>() / k);
            }
        }
    }
    Ok(Evaluation::new(r, jac, n))
}

/// A calibration fit.
#[derive(Clone, Debug, serde::Serialize)]
pub struct CalibrationFit {
    /// Fitted values of the free parameters (their units: degrees, mm…).
    pub x: Vec<f64>,
    /// RMS and largest centroid residual at the solution (µm).
    pub residual_um: f64,
    pub max_residual_um: f64,
    /// The box the fit searched, [lower, upper] per parameter ([`bounds`]).
    pub bounds: Vec<[f64; 2]>,
    pub report: OptimReport,
}

/// Half width of the fit's box around the start for angles (`*_deg`, degrees).
pub const ANGLE_BOUND_DEG: f64 = 45.0;
/// Half width of the fit's box around the start for lengths (`*_mm`, mm).
pub const LENGTH_BOUND_MM: f64 = 10.0;

/// The box [`calibrate`] searches: ±[`ANGLE_BOUND_DEG`] around the start on angles (`*_deg`),
/// ±[`LENGTH_BOUND_MM`] on lengths (`*_mm`), unbounded otherwise (glass n_d, V_d, …). A parameter that ends
/// on its bound is warned about (the optimum may lie beyond: start closer to it); the CLI prints the box.
pub fn bounds(set: &ParamSet, x0: &[f64]) -> Result<Bounds> {
    let (lo, hi): (Vec<f64>, Vec<f64>) = set
        .free
        .iter()
        .zip(x0)
        .map(|(p, v)| {
            let w = match p.name() {
                s if s.ends_with("_deg") => ANGLE_BOUND_DEG,
                s if s.ends_with("_mm") => LENGTH_BOUND_MM,
                _ => f64::INFINITY,
            };
            (v - w, v + w)
        })
        .unzip();
    Bounds::new(lo, hi)
}

/// Fit the free parameters of `set` (starting from its current values) to `observed` centroids.
pub fn calibrate(set: &ParamSet, observed: &[[f64; 2]], setup: &CalibrationSetup) -> Result<CalibrationFit> {
    if set.is_empty() {
        return Err(Error::invalid("calibration: no free parameters"));
    }
    if observed.len() != setup.groups() {
        return Err(Error::invalid(format!("calibration: {} observed centroids for {} (field, wavelength) pairs", observed.len(), setup.groups())));
    }
    let x0 = set.values()?;
    let bounds = bounds(set, &x0)?;
    let mut loss = |x: &[f64], _it: usize| evaluate(set, observed, setup, x);
    let names = set.free.iter().map(|p| p.name()).collect();
    let report = levenberg_marquardt(&mut loss, &x0, &bounds, &LmOptions { max_iterations: 100, names, ..Default::default() })?;
    let e = evaluate(set, observed, setup, &report.x)?;
    let pairs = e.residuals.len() / 2;
    let d: Vec<f64> = (0..pairs).map(|g| e.residuals[2 * g].hypot(e.residuals[2 * g + 1])).collect();
    let residual_um = (d.iter().map(|v| v * v).sum::<f64>() / pairs as f64).sqrt();
    let max_residual_um = d.iter().cloned().fold(0.0, f64::max);
    let bounds = bounds.lower.iter().zip(&bounds.upper).map(|(&l, &u)| [l, u]).collect();
    Ok(CalibrationFit { x: report.x.clone(), residual_um, max_residual_um, bounds, report })
}

#[cfg(test)]
mod structure_tests {
    use super::*;

    #[test]
    fn structure_difference_names_what_no_parameter_changes() {
        let spec = |p: &str| crate::presets::spec(p).unwrap();
        assert_eq!(structure_difference(&spec("ap").surfaces, &spec("map").surfaces), None); // a misaligned copy
        assert_eq!(structure_difference(&spec("sp").surfaces, &spec("msp").surfaces), None);
        assert_eq!(structure_difference(&spec("map").surfaces, &spec("ap").surfaces), None);
        assert!(structure_difference(&spec("ap").surfaces, &spec("sp").surfaces).is_some());
        let d = structure_difference(&spec("sp").surfaces, &spec("ap").surfaces).unwrap();
        assert!(d.contains("optical surfaces against") || d.contains("optical surface "), "{d}");
        // Another glass is a value the fit can free (glass_nd, glass_vd), not another structure.
        let mut glass = spec("sp");
        let k = glass.surfaces.iter().position(|s| s.material.is_some()).unwrap();
        glass.surfaces[k].material = Some("N-SF10".into());
        assert_eq!(structure_difference(&spec("sp").surfaces, &glass.surfaces), None);
    }
}
