//! Result objects handed to C++ as opaque boxes whose columns C++ views in place (no copy out), and the
//! free helper functions of the bridge.
//!
//! ```
//! let sys = diffcassi_cpp::load_preset("ap")?;
//! let rays = sys.chief_rays(&[0.0, 1.0], &[0.0, 2.0], 520.0)?;
//! let out = sys.trace_rays("analytic", &rays)?;
//! assert_eq!((out.len(), out.ok_count()), (2, 2));
//! assert_eq!(out.status(), &[0, 0]); // RayStatus::Ok
//! # Ok::<(), diffcassi::Error>(())
//! ```
use crate::ffi::{PupilPoints, SpotStats};
use diffcassi::analysis::{MappingCube, SpotDiagram};
use diffcassi::error::Result;
use diffcassi::rays::RayBatch;
use diffcassi::tracer::{RayStatus, TracedBatch};

/// Rays made by the library.
pub struct Rays(pub RayBatch);
/// A traced batch, exactly as `Tracer::trace` returned it.
pub struct Traced(pub TracedBatch);
/// A spot diagram, exactly as `analysis::spot_diagram` returned it.
pub struct Spot(pub SpotDiagram);
/// A mapping cube, exactly as `analysis::mapping_cube` returned it.
pub struct Mapping(pub MappingCube);

/// `RayStatus` is `#[repr(u8)]` with discriminants 0..=8, so a slice of it is a valid slice of `u8`.
pub(crate) fn status_bytes(s: &[RayStatus]) -> &[u8] {
    const _: () = assert!(std::mem::size_of::<RayStatus>() == 1 && std::mem::align_of::<RayStatus>() == 1);
    // SAFETY: same size and alignment (checked above), every RayStatus value is a valid u8, and the
    // returned slice borrows `s` immutably for its whole lifetime.
    unsafe { std::slice::from_raw_parts(s.as_ptr().cast::<u8>(), s.len()) }
}

impl Rays {
    pub fn len(&self) -> usize {
        self.0.len()
    }
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }
    pub fn origin_x(&self) -> &[f64] {
        &self.0.origin_x
    }
    pub fn origin_y(&self) -> &[f64] {
        &self.0.origin_y
    }
    pub fn origin_z(&self) -> &[f64] {
        &self.0.origin_z
    }
    pub fn dir_x(&self) -> &[f64] {
        &self.0.dir_x
    }
    pub fn dir_y(&self) -> &[f64] {
        &self.0.dir_y
    }
    pub fn dir_z(&self) -> &[f64] {
        &self.0.dir_z
    }
    pub fn wavelength_nm(&self) -> &[f64] {
        &self.0.wavelength_nm
    }
}

impl Traced {
    pub fn len(&self) -> usize {
        self.0.len()
    }
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }
    pub fn ok_count(&self) -> usize {
        self.0.ok_count()
    }
    pub fn x(&self) -> &[f64] {
        &self.0.x
    }
    pub fn y(&self) -> &[f64] {
        &self.0.y
    }
    pub fn z(&self) -> &[f64] {
        &self.0.z
    }
    pub fn dir_x(&self) -> &[f64] {
        &self.0.dir_x
    }
    pub fn dir_y(&self) -> &[f64] {
        &self.0.dir_y
    }
    pub fn dir_z(&self) -> &[f64] {
        &self.0.dir_z
    }
    pub fn status(&self) -> &[u8] {
        status_bytes(&self.0.status)
    }
    pub fn surface(&self) -> &[u32] {
        &self.0.surface
    }
}

impl Spot {
    pub fn field_mm(&self) -> [f64; 2] {
        self.0.field_mm
    }
    pub fn wavelength_nm(&self) -> f64 {
        self.0.wavelength_nm
    }
    pub fn x_mm(&self) -> &[f64] {
        &self.0.x_mm
    }
    pub fn y_mm(&self) -> &[f64] {
        &self.0.y_mm
    }
    pub fn status(&self) -> &[u8] {
        status_bytes(&self.0.status)
    }
    pub fn has_chief(&self) -> bool {
        self.0.chief_mm.is_some()
    }
    pub fn chief_mm(&self) -> [f64; 2] {
        self.0.chief_mm.unwrap_or([0.0, 0.0])
    }
    pub fn stats(&self) -> SpotStats {
        match self.0.stats {
            Some(s) => SpotStats {
                valid: true,
                count: s.count,
                centroid_x_mm: s.centroid_mm[0],
                centroid_y_mm: s.centroid_mm[1],
                rms_radius_um: s.rms_radius_um,
                geo_radius_um: s.geo_radius_um,
            },
            None => SpotStats { valid: false, count: 0, centroid_x_mm: 0.0, centroid_y_mm: 0.0, rms_radius_um: 0.0, geo_radius_um: 0.0 },
        }
    }
    pub fn rms_radius_chief_um(&self) -> f64 {
        self.0.rms_radius_chief_um.unwrap_or(0.0)
    }
}

impl Mapping {
    pub fn height(&self) -> usize {
        self.0.height
    }
    pub fn width(&self) -> usize {
        self.0.width
    }
    pub fn pixel_pitch_mm(&self) -> f64 {
        self.0.pixel_pitch_mm
    }
    pub fn wavelength_nm(&self) -> &[f64] {
        &self.0.wavelength_nm
    }
    pub fn positions_mm(&self) -> &[f64] {
        &self.0.positions_mm
    }
    pub fn valid(&self) -> &[u8] {
        &self.0.valid
    }
    pub fn invalid_count(&self) -> usize {
        self.0.invalid_count()
    }
}

pub(crate) fn preset_names() -> Vec<String> {
    diffcassi::presets::ALL_NAMES.iter().map(|s| s.to_string()).collect()
}

pub(crate) fn backend_names() -> Vec<String> {
    crate::system::known_backends()
}

pub(crate) fn version() -> String {
    env!("CARGO_PKG_VERSION").to_string()
}

pub(crate) fn pupil_points(pattern: &str) -> Result<PupilPoints> {
    // Like every entry point, name the budgets first: a refusal as the first call named the CLI's
    // `--max-memory-gb` (round 21).
    name_budgets();
    let pts = pattern.parse::<diffcassi::rays::PupilPattern>()?.points();
    Ok(PupilPoints { px: pts.iter().map(|p| p[0]).collect(), py: pts.iter().map(|p| p[1]).collect() })
}

/// The budgets' names in C++ messages: `max_memory_gb (diffcassi::set_limits)`.
fn budget_names() -> diffcassi::limits::BudgetNames {
    diffcassi::limits::BudgetNames { memory: "max_memory_gb".into(), rays: "max_rays".into(), separator: "=".into(), setter: "diffcassi::set_limits".into() }
}

/// Name the budgets for C++ once (the first load of a system, `linspace`, `pupil_points`, `denoise`, `set_limits`,
/// `set_num_threads`, `set_calibration_cache`): a refusal then says how to raise them from C++.
pub(crate) fn name_budgets() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        // This process owns the threads from here on: a fork() child's calls build their own pool
        // (`diffcassi::pool`).
        diffcassi::pool::init();
        diffcassi::limits::name_budgets(budget_names());
        // The library's messages name settings as C++ does (`RenderOptions::rays_per_pixel`, not `--rays`).
        diffcassi::frontend::set(diffcassi::frontend::Frontend::Cpp);
    });
}

/// The threads of every following call: 1..=1024 (the CLI's `--threads` range), or 0 for rayon's default (all
/// cores or `RAYON_NUM_THREADS`); results do not depend on it. Shared with Python's `set_num_threads`
/// (`diffcassi::pool`).
pub(crate) fn set_num_threads(n: usize) -> diffcassi::error::Result<()> {
    name_budgets();
    diffcassi::pool::set_num_threads(n, "diffcassi::set_num_threads")
}

/// The threads the following calls use.
pub(crate) fn get_num_threads() -> diffcassi::error::Result<usize> {
    name_budgets();
    diffcassi::pool::num_threads()
}

/// The memory (GB, > 0) and ray (≥ 1) budgets of every following call, process-wide; `has_…` false: the
/// default (half of the physical memory; 2·10¹⁰ rays). Both are replaced at each call.
pub(crate) fn set_limits(has_memory: bool, max_memory_gb: f64, has_rays: bool, max_rays: f64) -> diffcassi::error::Result<()> {
    name_budgets();
    diffcassi::limits::set_budget_named(has_memory.then_some(max_memory_gb), has_rays.then_some(max_rays), budget_names())
}

pub(crate) fn linspace(first: f64, last: f64, count: usize) -> diffcassi::error::Result<Vec<f64>> {
    name_budgets();
    // Finite ends and a count within the memory budget (2⁴⁰ values aborted the process on allocation; NaN ends
    // gave NaNs; a held-out battery, round 9).
    if !(first.is_finite() && last.is_finite()) {
        return Err(diffcassi::error::Error::invalid(format!("linspace({first}, {last}, {count}): the ends must be finite")));
    }
    diffcassi::limits::check_memory(&format!("linspace of {count} values"), count as f64 * 8.0)?;
    Ok(diffcassi::analysis::linspace(first, last, count))
}
