//! The loaded system behind the C++ `diffcassi::ffi::System`: loading (preset, spec file, spec string),
//! system data, and the traces and analyses, each delegating to the Rust API unchanged so that C++ and
//! Rust results are the same bits.
//!
//! ```
//! let sys = diffcassi_cpp::load_spec_string(&diffcassi::spec::to_toml(&diffcassi::presets::spec("ap")?)?, "auto", "ap.toml")?;
//! assert_eq!(sys.name(), "ap");
//! assert_eq!(sys.wavelengths_nm(), &[450.0, 520.0, 650.0]);
//! # Ok::<(), diffcassi::Error>(())
//! ```
use crate::backend::{self, BackendCache};
use crate::ffi::{DistortionGrid, DistortionPoint, SurfaceInfo};
use crate::results::{Mapping, Rays, Spot, Traced};
use diffcassi::analysis;
use diffcassi::error::{Error, Result};
use diffcassi::rays::RayBatch;
use diffcassi::spec::{Cell, SystemSpec};
use diffcassi::system::SequentialSystem;
use diffcassi::tracer::RaySlices;
use std::time::Instant;

/// A built [`SequentialSystem`] plus the backends made for it so far.
pub struct System {
    system: SequentialSystem,
    pub(crate) backends: BackendCache,
}

fn wrap(system: SequentialSystem) -> Box<System> {
    Box::new(System { system, backends: BackendCache::default() })
}

/// A string from C++ without NUL bytes: C++ shows an error's text up to its first NUL, so a name holding one
/// was reported cut (`unknown preset `sp`); refused, the name quoted with its NUL escaped.
pub(crate) fn no_nul(what: &str, text: &str) -> Result<()> {
    if text.contains('\0') {
        return Err(Error::invalid(format!("{what} {text:?} contains a NUL byte")));
    }
    Ok(())
}

/// Load one of the presets (`sp`, `ap`, `msp`, `map`; case-insensitive).
pub fn load_preset(name: &str) -> Result<Box<System>> {
    // In this process's pool: a fresh one in a fork() child (diffcassi::pool).
    diffcassi::pool::install(|| {
        crate::results::name_budgets();
        no_nul("preset name", name)?;
        Ok(wrap(SequentialSystem::build(&diffcassi::presets::spec(name)?)?))
    })
}

/// Load a spec file by extension (`.toml`, `.json`, `.yml`/`.yaml`, `.csv`, `.zmx`); a `.zmx` system's errors
/// name the file's own fixes (`diffcassi::system::SystemOrigin`).
pub fn load_spec_file(path: &str) -> Result<Box<System>> {
    // In this process's pool: a fresh one in a fork() child (diffcassi::pool).
    diffcassi::pool::install(|| {
        crate::results::name_budgets();
        no_nul("spec file path", path)?;
        let origin = diffcassi::system::SystemOrigin::of_path(std::path::Path::new(path));
        Ok(wrap(SequentialSystem::build_from(&diffcassi::spec::load_spec_file(path)?, origin)?))
    })
}

/// Parse a spec held in memory: `format` is `toml`, `json` or `auto` (JSON when the first non-blank
/// character after an optional UTF-8 byte-order mark is `{`, TOML otherwise; [`diffcassi::spec::from_text`]).
pub fn load_spec_string(text: &str, format: &str, source_name: &str) -> Result<Box<System>> {
    // In this process's pool: a fresh one in a fork() child (diffcassi::pool).
    diffcassi::pool::install(|| {
        crate::results::name_budgets();
        no_nul("spec source name", source_name)?;
        let spec: SystemSpec = diffcassi::spec::from_text(text, format, source_name)?;
        Ok(wrap(SequentialSystem::build(&spec)?))
    })
}

fn value(c: &Option<Cell>) -> f64 {
    c.as_ref().map_or(0.0, |c| c.value)
}

/// The element count of an output of the given dimensions, or an error when it cannot be allocated (an
/// overflowing size from C++ would otherwise panic, and a panic across the bridge aborts the process).
pub(crate) fn checked_size(what: &str, dims: &[usize]) -> Result<usize> {
    const LIMIT: usize = isize::MAX as usize / 16; // elements of at most 16 bytes must fit an allocation
    dims.iter()
        .try_fold(1usize, |n, &d| n.checked_mul(d))
        .filter(|&n| n <= LIMIT)
        .ok_or_else(|| Error::invalid(format!("{what} {dims:?} is too large to allocate")))
}

fn check_same_len(what: &str, a: &[f64], b: &[f64]) -> Result<()> {
    if a.len() != b.len() {
        return Err(Error::invalid(format!("{what}: x has {} values but y has {}", a.len(), b.len())));
    }
    Ok(())
}

impl System {
    /// The Rust system (for Rust callers of this crate).
    pub fn system(&self) -> &SequentialSystem {
        &self.system
    }
    pub fn name(&self) -> &str {
        self.system.name()
    }
    pub fn description(&self) -> &str {
        &self.system.spec.description
    }
    pub fn surface_count(&self) -> usize {
        self.system.surfaces.len()
    }
    /// The system's load-time warnings ([`SequentialSystem::warnings`]), spelled for C++.
    pub fn warnings(&self) -> Vec<String> {
        self.system.warnings().iter().map(|w| diffcassi::frontend::spell(w, diffcassi::frontend::Frontend::Cpp).into_owned()).collect()
    }
    pub fn stop_index(&self) -> usize {
        self.system.stop_index
    }
    pub fn wavelengths_nm(&self) -> &[f64] {
        &self.system.spec.wavelengths_nm
    }
    pub fn primary_wavelength_nm(&self) -> f64 {
        self.system.primary_wavelength_nm()
    }
    pub fn fields_mm(&self) -> Vec<f64> {
        self.system.spec.fields_mm.iter().flatten().copied().collect()
    }
    pub fn surfaces_per_ray(&self) -> usize {
        self.system.surfaces_per_ray()
    }
    pub fn to_toml(&self) -> Result<String> {
        diffcassi::spec::to_toml(&self.system.spec)
    }
    pub fn to_json(&self) -> Result<String> {
        diffcassi::spec::to_json(&self.system.spec)
    }

    /// The resolved Lens Data Editor, one row per surface.
    pub fn surfaces(&self) -> Vec<SurfaceInfo> {
        self.system
            .surfaces
            .iter()
            .zip(&self.system.spec.surfaces)
            .map(|(r, s)| SurfaceInfo {
                index: r.index,
                kind: r.kind.label().to_string(),
                comment: r.comment.clone(),
                is_stop: r.is_stop,
                material: s.material.clone().unwrap_or_default(),
                radius_mm: match &s.radius_mm {
                    Some(c) if c.value != 0.0 && c.value.is_finite() => c.value,
                    _ => f64::INFINITY,
                },
                thickness_mm: r.thickness_mm,
                conic: value(&s.conic),
                focal_length_mm: value(&s.focal_length_mm),
                semi_diameter_mm: r.semi_diameter_mm.unwrap_or(0.0),
                has_semi_diameter: r.semi_diameter_mm.is_some(),
                decenter_x_mm: value(&s.decenter_x_mm),
                decenter_y_mm: value(&s.decenter_y_mm),
                tilt_x_deg: value(&s.tilt_x_deg),
                tilt_y_deg: value(&s.tilt_y_deg),
                tilt_z_deg: value(&s.tilt_z_deg),
                order: s.order,
                vertex_global_mm: r.frame.origin.to_array(),
            })
            .collect()
    }

    // ---------------------------------------------------------------- rays

    pub fn rays_for_field(&self, field_x_mm: f64, field_y_mm: f64, px: &[f64], py: &[f64], wavelength_nm: f64) -> Result<Box<Rays>> {
        // In this process's pool: a fresh one in a fork() child (diffcassi::pool).
        diffcassi::pool::install(|| {
            check_same_len("pupil points", px, py)?;
            let pupil: Vec<[f64; 2]> = px.iter().zip(py).map(|(x, y)| [*x, *y]).collect();
            // Normalised pupil coordinates live in the unit disc (px = 2 traced "ok"; the CLI and Python refuse it).
            analysis::check_pupil_points(&pupil)?;
            Ok(Box::new(Rays(RayBatch::for_field(&self.system, [field_x_mm, field_y_mm], &pupil, wavelength_nm)?)))
        })
    }

    pub fn chief_rays(&self, field_x_mm: &[f64], field_y_mm: &[f64], wavelength_nm: f64) -> Result<Box<Rays>> {
        // In this process's pool: a fresh one in a fork() child (diffcassi::pool).
        diffcassi::pool::install(|| {
            check_same_len("field points", field_x_mm, field_y_mm)?;
            let fields: Vec<[f64; 2]> = field_x_mm.iter().zip(field_y_mm).map(|(x, y)| [*x, *y]).collect();
            Ok(Box::new(Rays(RayBatch::chief_rays(&self.system, &fields, wavelength_nm)?)))
        })
    }

    pub fn seeded_workload(&self, rays_per_wavelength: usize, wavelengths_nm: &[f64], seed: u64) -> Result<Box<Rays>> {
        // In this process's pool: a fresh one in a fork() child (diffcassi::pool).
        diffcassi::pool::install(|| {
            checked_size("seeded workload (rays per wavelength, wavelengths)", &[rays_per_wavelength, wavelengths_nm.len()])?;
            Ok(Box::new(Rays(RayBatch::seeded_workload(&self.system, rays_per_wavelength, wavelengths_nm, seed)?)))
        })
    }

    // ---------------------------------------------------------------- tracing

    /// Trace caller-owned columns in place with the named backend.
    #[allow(clippy::too_many_arguments)]
    pub fn trace(
        &self,
        backend: &str,
        origin_x: &[f64],
        origin_y: &[f64],
        origin_z: &[f64],
        dir_x: &[f64],
        dir_y: &[f64],
        dir_z: &[f64],
        wavelength_nm: &[f64],
    ) -> Result<Box<Traced>> {
        // In this process's pool: a fresh one in a fork() child (diffcassi::pool).
        diffcassi::pool::install(|| {
            let rays = RaySlices::new(origin_x, origin_y, origin_z, dir_x, dir_y, dir_z, wavelength_nm)?;
            let tracer = self.backends.get(&self.system, backend)?;
            Ok(Box::new(Traced(tracer.trace_slices(&self.system, rays)?)))
        })
    }

    pub fn trace_rays(&self, backend: &str, rays: &Rays) -> Result<Box<Traced>> {
        // In this process's pool: a fresh one in a fork() child (diffcassi::pool).
        diffcassi::pool::install(|| {
            let tracer = self.backends.get(&self.system, backend)?;
            Ok(Box::new(Traced(tracer.trace(&self.system, &rays.0)?)))
        })
    }

    /// Seconds per trace of `rays`, `reps` times, timed in Rust around `Tracer::trace` (the reference the
    /// C++ bench compares its own calls with).
    pub fn time_rust_trace(&self, backend: &str, rays: &Rays, reps: usize) -> Result<Vec<f64>> {
        // In this process's pool: a fresh one in a fork() child (diffcassi::pool).
        diffcassi::pool::install(|| {
            diffcassi::limits::check_memory(&format!("{reps} repetitions"), reps as f64 * 8.0)?;
            let tracer = self.backends.get(&self.system, backend)?;
            let mut times = Vec::with_capacity(reps);
            for _ in 0..reps {
                let t = Instant::now();
                let out = tracer.trace(&self.system, &rays.0)?;
                times.push(t.elapsed().as_secs_f64());
                std::hint::black_box(&out);
            }
            Ok(times)
        })
    }

    // ---------------------------------------------------------------- analyses

    #[allow(clippy::too_many_arguments)]
    pub fn spot_diagram(&self, backend: &str, field_x_mm: f64, field_y_mm: f64, wavelength_nm: f64, px: &[f64], py: &[f64]) -> Result<Box<Spot>> {
        // In this process's pool: a fresh one in a fork() child (diffcassi::pool).
        diffcassi::pool::install(|| {
            check_same_len("pupil points", px, py)?;
            let pupil: Vec<[f64; 2]> = px.iter().zip(py).map(|(x, y)| [*x, *y]).collect();
            let tracer = self.backends.get(&self.system, backend)?;
            Ok(Box::new(Spot(analysis::spot_diagram(&self.system, tracer.as_ref(), [field_x_mm, field_y_mm], wavelength_nm, &pupil)?)))
        })
    }

    pub fn distortion_grid(&self, backend: &str, wavelength_nm: f64, n: usize, half_width_mm: f64) -> Result<DistortionGrid> {
        // In this process's pool: a fresh one in a fork() child (diffcassi::pool).
        diffcassi::pool::install(|| {
            checked_size("distortion grid", &[n, n])?;
            let tracer = self.backends.get(&self.system, backend)?;
            let g = analysis::grid_distortion(&self.system, tracer.as_ref(), wavelength_nm, n, half_width_mm)?;
            Ok(DistortionGrid {
                wavelength_nm: g.wavelength_nm,
                reference_mm: g.reference_mm,
                abcd: g.abcd,
                max_distortion_pct: g.max_distortion_pct,
                points: g
                    .points
                    .iter()
                    .map(|p| DistortionPoint {
                        i: p.i,
                        j: p.j,
                        x_field_mm: p.x_field_mm,
                        y_field_mm: p.y_field_mm,
                        real_x_mm: p.real_x_mm,
                        real_y_mm: p.real_y_mm,
                        pred_x_mm: p.pred_x_mm,
                        pred_y_mm: p.pred_y_mm,
                        distortion_pct: p.distortion_pct,
                        status: p.status as u8,
                    })
                    .collect(),
            })
        })
    }

    pub fn mapping_cube(&self, backend: &str, height: usize, width: usize, pixel_pitch_mm: f64, wavelengths_nm: &[f64]) -> Result<Box<Mapping>> {
        // In this process's pool: a fresh one in a fork() child (diffcassi::pool).
        diffcassi::pool::install(|| {
            checked_size("mapping cube (height, width, wavelengths, xy)", &[height, width, wavelengths_nm.len(), 2])?;
            let tracer = self.backends.get(&self.system, backend)?;
            Ok(Box::new(Mapping(analysis::mapping_cube(&self.system, tracer.as_ref(), height, width, pixel_pitch_mm, wavelengths_nm)?)))
        })
    }
}

/// The names [`backend::tracer_for`] knows (re-exported for the bridge).
pub(crate) fn known_backends() -> Vec<String> {
    backend::NAMES.iter().map(|s| s.to_string()).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use diffcassi::tracer::{AnalyticTracer, Tracer};

    #[test]
    fn loading_errors_carry_the_rust_message() {
        let e = load_preset("nope").err().unwrap().to_string();
        assert!(e.contains("unknown preset `nope`"), "{e}");
        let e = load_spec_string("name = \"x\"\nsurfaces = [", "toml", "mine.toml").err().unwrap().to_string();
        assert!(e.starts_with("mine.toml: invalid TOML spec"), "{e}");
        let e = load_spec_string("{\"name\": 3}", "auto", "mine.json").err().unwrap().to_string();
        assert!(e.starts_with("mine.json: invalid JSON spec"), "{e}");
        let e = load_spec_string("", "yaml", "x").err().unwrap().to_string();
        assert!(e.contains("unknown spec format `yaml`"), "{e}");
        let e = load_spec_file("/nonexistent/sys.toml").err().unwrap().to_string();
        assert!(e.starts_with("/nonexistent/sys.toml: cannot read"), "{e}");
        let sys = load_preset("sp").unwrap();
        let e = sys.mapping_cube("analytic", usize::MAX / 2, 3, 0.01, &[520.0]).err().unwrap().to_string();
        assert!(e.contains("too large"), "{e}");
        let e = sys.distortion_grid("analytic", 520.0, 1 << 40, 2.5).err().unwrap().to_string();
        assert!(e.contains("too large"), "{e}");
        let e = sys.seeded_workload(usize::MAX, &[450.0, 520.0], 1).err().unwrap().to_string();
        assert!(e.contains("too large"), "{e}");
        // What the CLI and Python refused and C++ took (round 9): checked in the library or here.
        let e = sys.distortion_grid("analytic", 520.0, 5, 1e-12).err().unwrap().to_string();
        assert!(e.contains("half width") && e.contains("[1e-3"), "{e}");
        let e = sys.mapping_cube("analytic", 2, 2, 1e300, &[520.0]).err().unwrap().to_string();
        assert!(e.contains("from the axis"), "{e}");
        let e = sys.rays_for_field(0.0, 0.0, &[2.0], &[0.0], 520.0).err().unwrap().to_string();
        assert!(e.contains("px² + py² ≤ 1"), "{e}");
        let e = sys.spot_diagram("analytic", 0.0, 0.0, 520.0, &[0.0, 1.5], &[0.0, 0.0]).err().unwrap().to_string();
        assert!(e.contains("pupil point 1"), "{e}");
        let e = sys.seeded_workload(1 << 33, &[520.0], 1).err().unwrap().to_string();
        assert!(e.contains("memory"), "{e}");
        assert!(crate::results::linspace(0.0, f64::NAN, 3).is_err());
        let e = load_preset("sp\0x").err().unwrap().to_string();
        assert!(e.contains("NUL byte") && e.contains("sp\\0x"), "{e}");
    }

    #[test]
    fn trace_equals_the_rust_api_bitwise() {
        let sys = load_preset("map").unwrap();
        let rays = RayBatch::seeded_workload(sys.system(), 50, &[450.0, 650.0], 3).unwrap();
        let via_bridge = sys.trace("analytic", &rays.origin_x, &rays.origin_y, &rays.origin_z, &rays.dir_x, &rays.dir_y, &rays.dir_z, &rays.wavelength_nm).unwrap();
        let direct = AnalyticTracer::default().trace(sys.system(), &rays).unwrap();
        assert_eq!(via_bridge.0, direct);
        assert!(direct.ok_count() > 0);
        let e = sys.trace("analytic", &rays.origin_x, &rays.origin_y[1..], &rays.origin_z, &rays.dir_x, &rays.dir_y, &rays.dir_z, &rays.wavelength_nm).err().unwrap();
        assert!(e.to_string().contains("different lengths"), "{e}");
    }

    #[test]
    fn surfaces_list_the_lde() {
        let sys = load_preset("sp").unwrap();
        let s = sys.surfaces();
        assert_eq!(s.len(), 20);
        assert_eq!(s.iter().filter(|r| r.is_stop).count(), 1);
        assert_eq!(s[sys.stop_index()].index, sys.stop_index());
        assert!(s.iter().any(|r| r.material == "N-BK7"));
        assert!(s.iter().any(|r| r.kind == "Coordinate Break"));
        assert!(s.iter().all(|r| !r.radius_mm.is_nan() && r.vertex_global_mm.iter().all(|v| v.is_finite())));
        assert_eq!(sys.fields_mm().len(), 2 * sys.system().spec.fields_mm.len());
    }
}
