//! Limits in one place: the physically meaningful range of every quantity a user (or a pickup/solve) can
//! put into a system, the sizes and counts a command accepts, and each command's resource budget — memory
//! estimated *before* allocating and traced rays — with the refusal naming the option and the estimate.
//!
//! The budget is process-wide, set by the command line (`--max-memory-gb`, `--max-rays`) or a binding
//! (Python's `diffcassi.set_limits(max_memory_gb=…, max_rays=…)`, whose messages name those keywords:
//! [`set_budget_named`], [`BudgetNames`]); library users get the defaults ([`Budget::default_for_machine`])
//! unless they call [`set_budget`].
//!
//! ```
//! use diffcassi::limits;
//! // 10⁶ × 10⁶ × 28 mapping entries at ~19 bytes each: refused, naming the options and the estimate.
//! let e = limits::check_memory("--height/--width/--wavelengths-nm", limits::bytes_mapping(1_000_000, 1_000_000, 28)).unwrap_err();
//! assert!(e.to_string().contains("--max-memory-gb"));
//! assert!(limits::check_plausible_length("thickness_mm", 50.0).is_ok());
//! assert!(limits::check_plausible_length("thickness_mm", 1e308).is_err());
//! ```
use crate::error::{Error, Result};
use std::sync::RwLock;

// ------------------------------------------------------------------ value ranges (resolved systems, rays)

/// Largest plausible |length| of a resolved system (thickness, decenter), mm:
/// 1 km. A bench-top CASSI is ~0.3 m long; anything beyond is a typo or an overflowing pickup.
pub const MAX_LENGTH_MM: f64 = 1e6;
/// Smallest plausible entrance pupil diameter, mm (1 nm, the smallest plausible radius): given (`ENPD`,
/// `entrance_pupil_diameter`) or produced by an image-space F/# (EFL / F/#; `FNUM 1e300` gave a 1e-302 mm pupil).
pub const MIN_PUPIL_DIAMETER_MM: f64 = 1e-6;
/// Largest plausible |curvature| of a surface, mm⁻¹ (`.zmx` `CURV`): a radius of at least 1 nm.
pub const MAX_CURVATURE_PER_MM: f64 = 1e6;
/// Largest plausible |tilt| of a coordinate break, degrees (one full turn).
pub const MAX_TILT_DEG: f64 = 360.0;
/// The largest conic constant |k| a surface may have (real surfaces: |k| ≲ 10²).
pub const MAX_CONIC: f64 = 1e6;
/// The largest asphere coefficient |α_k| (mm^(1−2k)): keeps α·r^(2k) and its square finite out to ±[`MAX_LENGTH_MM`]
/// for every term order (micro-optics reach 10⁶ at most).
pub const MAX_ASPHERE_COEFFICIENT: f64 = 1e12;
/// The largest grating frequency (lines/µm): a period of 1 nm (real gratings: ≲ 10 lines/µm).
pub const MAX_GRATING_LINES_PER_UM: f64 = 1e3;
/// Most polynomial terms of an even asphere (r², r⁴, …, r¹⁶) or a Toroidal surface's YZ curve (y², …, y¹⁶):
/// OpticStudio's PARM 1–8 (a toroid's PARM 2–9). The GPU kernels carry this many (`DC_MAX_COEF`).
pub const MAX_ASPHERE_TERMS: usize = 8;
/// Largest plausible |coordinate| of a traced ray on the image surface, mm; a ray landing farther (or at a
/// non-finite position) is classified [`crate::tracer::RayStatus::OutOfRange`], never reported `ok`.
pub const MAX_IMAGE_COORD_MM: f64 = 1e6;
/// Wavelengths accepted on the command line, nm (far UV to far IR; glasses narrow it further).
pub const WAVELENGTH_RANGE_NM: (f64, f64) = (100.0, 20_000.0);
/// Most wavelengths in one `first:last:count` list.
pub const MAX_WAVELENGTHS: usize = 100_000;
/// Most spectral planes of a render (the paper uses 112).
pub const MAX_PLANES: usize = 100_000;
/// Airy disk diameter of a render, pixels (the paper: 2.5). The kernel has ~(2.7·d)² taps, convolved with
/// every plane, so its cost grows as d².
pub const MAX_AIRY_DIAMETER_PX: f64 = 100.0;
/// Largest first-zero radius of one plane's Airy kernel, px: the largest disk `render` accepts
/// ([`MAX_AIRY_DIAMETER_PX`] at 520 nm) scaled ∝ λ to 4× its wavelength (2080 nm, beyond every built-in
/// glass). The kernel has ~(5.3·r)² taps, each integrated over 8×8 sub-samples.
pub const MAX_AIRY_RADIUS_PX: f64 = 2.0 * MAX_AIRY_DIAMETER_PX;
/// Most images of one command's scene set (`study --synthetic N`, scenes found in a folder), before the
/// memory budget: far beyond any study (the paper's has 10 scenes).
pub const MAX_SCENES: usize = 1_000_000;
/// Most iterations of an iterative command (`design --iterations`, `reconstruct --iterations`, solver TV
/// iterations): 10⁵, far beyond every default (400 Adam steps, 100 GAP/ADMM iterations), so a mistyped count
/// is refused at once instead of running for days.
pub const MAX_ITERATIONS: usize = 100_000;
/// Most timing repetitions of a benchmark (`bench --repeat`, best of N): far beyond any useful count (the
/// default is 3), so a mistyped `--repeat 1000000000` is refused at once instead of running until killed.
pub const MAX_REPEAT: usize = 1000;
/// Largest text input read whole (spec files `.toml`/`.json`/`.yml`/`.csv`/`.zmx`, AGF catalogues, CSV
/// tables such as `--pupil-csv`, wavelength lists, `render.json`): 64 MiB, far beyond any real one (a Zemax
/// lens file is a few kB, the Schott catalogue 1 MB). Binary inputs (NPY, EXR, PNG) are bounded by the
/// memory budget instead, meshes by [`crate::mechanics::mesh_io::MAX_MESH_FILE_BYTES`].
pub const MAX_TEXT_FILE_BYTES: u64 = 64 << 20;
/// Most surfaces of a sequential system, in every reader (`.zmx`, TOML/JSON/YAML specs, prescription CSVs) and
/// in the build: 10 000. A CASSI has 20–40 surfaces and the largest real lens files (zooms, lithography
/// objectives) a few hundred, so the bound is ≥ 25× any real design. A system costs ~4 kB per surface once read
/// and built (measured round 19: 0.39 GB at 10⁵ `SURF`/`DISZ` pairs, 1.58 GB at 4·10⁵), so the bound keeps any
/// system under ~50 MB, the order of the process's own fixed overhead, which the memory budget does not count.
/// Without it the [`MAX_TEXT_FILE_BYTES`] limit let a 64 MiB `.zmx` of ~3.6 million surfaces reach ~14 GB.
pub const MAX_SURFACES: usize = 10_000;

/// A system of `count` surfaces: at most [`MAX_SURFACES`]. `Err` holds the reason (the caller names the file).
pub fn check_surface_count(count: usize) -> std::result::Result<(), String> {
    if count > MAX_SURFACES {
        return Err(format!(
            "{count} surfaces: more than the {MAX_SURFACES} a system may have (real lens files have a few hundred; a system holds ~4 kB per surface)"
        ));
    }
    Ok(())
}
/// Most worker threads (`--threads`); results do not depend on the count.
pub const MAX_THREADS: usize = 1024;
/// Radiance values of a scene must stay below this so that a pixel's sum over planes, rays and the Airy
/// kernel cannot overflow the f32 images: f32::MAX / 10⁹.
pub const MAX_SCENE_VALUE: f64 = f32::MAX as f64 / 1e9;
/// The smallest brightest value of a scene that is not black: 1e-20, 10¹⁸ above f32's smallest normal number,
/// so that an acquisition (the scene × 1/rays × B/K × the Airy kernel) keeps f32's full precision.
pub const MIN_SCENE_PEAK: f64 = 1e-20;

// ------------------------------------------------------------------ budget

/// Memory (bytes) and work (traced rays) a command may use.
#[derive(Clone, Debug, PartialEq)]
pub struct Budget {
    pub memory_bytes: f64,
    /// Where the memory budget comes from (for messages).
    pub memory_source: String,
    pub rays: f64,
    /// How users set the budgets, for messages.
    pub names: BudgetNames,
}

/// How the users of a front end set the budgets, for messages: the option (or keyword) of each, how a value
/// is written after it (`--max-memory-gb 2`: " ", `max_memory_gb=2`: "="), and the call that sets them
/// (empty for the command line).
#[derive(Clone, Debug, PartialEq)]
pub struct BudgetNames {
    pub memory: String,
    pub rays: String,
    pub separator: String,
    pub setter: String,
}

impl BudgetNames {
    /// The command line's: `--max-memory-gb`, `--max-rays`.
    pub fn cli() -> Self {
        BudgetNames { memory: "--max-memory-gb".into(), rays: "--max-rays".into(), separator: " ".into(), setter: String::new() }
    }

    /// `name` as a message shows how to raise it: `--max-rays`, `max_rays (diffcassi.set_limits)`.
    fn raise(&self, name: &str) -> String {
        if self.setter.is_empty() {
            name.to_string()
        } else {
            format!("{name} ({})", self.setter)
        }
    }

    /// `name` with the value `v`: `--max-memory-gb 2`, `max_memory_gb=2`.
    fn with_value(&self, name: &str, v: f64) -> String {
        format!("{name}{}{v}", self.separator)
    }
}

/// Default ray budget: 2·10¹⁰ rays, 34 paper-scale acquisitions (512² × 112 planes × 20 rays = 5.9·10⁸).
pub const DEFAULT_MAX_RAYS: f64 = 2e10;
/// The largest memory budget (GB) any front end accepts (`--max-memory-gb`, Python's and C++'s `set_limits`):
/// 2⁴⁷ bytes, the user address space of a 64-bit process (x86-64's and AArch64's 47/48-bit virtual
/// addresses). A larger budget cannot protect anything: every request under it that the machine cannot map
/// reached the allocator, which aborts (round 21: `set_limits(1e300)`).
pub const MAX_MEMORY_GB: f64 = 140_737.488_355_328;
/// The largest ray budget: 2⁵³, the largest count an f64 holds exactly.
pub const MAX_RAYS_BUDGET: f64 = 9_007_199_254_740_992.0;
/// Fallback memory budget when /proc/meminfo is unreadable: 16 GB.
pub const FALLBACK_MEMORY_BYTES: f64 = 16e9;

impl Budget {
    /// Half of the physical memory (`MemTotal` of /proc/meminfo), else 16 GB; [`DEFAULT_MAX_RAYS`].
    pub fn default_for_machine() -> Self {
        let (memory_bytes, memory_source) = match physical_memory_bytes() {
            Some(b) => (b / 2.0, format!("default: half of the {:.1} GB of physical memory", b / 1e9)),
            None => (FALLBACK_MEMORY_BYTES, "default: 16 GB".to_string()),
        };
        Budget { memory_bytes, memory_source, rays: DEFAULT_MAX_RAYS, names: BudgetNames::cli() }
    }
}

/// `MemTotal` from /proc/meminfo, bytes.
pub fn physical_memory_bytes() -> Option<f64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemTotal:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024.0)
}

static BUDGET: RwLock<Option<Budget>> = RwLock::new(None);

/// Set the process-wide budget from `--max-memory-gb` / `--max-rays` (each `None`: the default). Values
/// must be finite and > 0 (rays ≥ 1).
pub fn set_budget(max_memory_gb: Option<f64>, max_rays: Option<f64>) -> Result<()> {
    set_budget_named(max_memory_gb, max_rays, BudgetNames::cli())
}

/// [`set_budget`] for a front end whose users set the budgets by `names` (its messages name them); replaces
/// the current budget. A refused value leaves the budget as it was.
pub fn set_budget_named(max_memory_gb: Option<f64>, max_rays: Option<f64>, names: BudgetNames) -> Result<()> {
    let mut b = Budget::default_for_machine();
    if let Some(gb) = max_memory_gb {
        if !(gb.is_finite() && gb > 0.0) {
            return Err(Error::invalid(format!("{}: must be a finite number of GB > 0", names.with_value(&names.memory, gb))));
        }
        if gb > MAX_MEMORY_GB {
            return Err(Error::invalid(format!(
                "{}: beyond the {MAX_MEMORY_GB:.0} GB a 64-bit process can address (2⁴⁷ bytes): such a budget protects nothing, and a \
                 request under it fails in the allocator; give at most {MAX_MEMORY_GB:.0} (the default is half of the physical memory)",
                format!("{}{}{}", names.memory, names.separator, fmt_num(gb))
            )));
        }
        b.memory_bytes = gb * 1e9;
        b.memory_source = names.with_value(&names.memory, gb);
    }
    if let Some(r) = max_rays {
        if !(r.is_finite() && r >= 1.0) {
            return Err(Error::invalid(format!("{}: must be a finite count ≥ 1", names.with_value(&names.rays, r))));
        }
        // A ray count is a whole number; 1.5 was accepted and meant 1 (round 21). Above 2⁵³ an f64 no longer
        // holds every count exactly.
        if r.fract() != 0.0 || r > MAX_RAYS_BUDGET {
            return Err(Error::invalid(format!("{}{}{}: must be a whole number of rays, 1..={MAX_RAYS_BUDGET:.0}", names.rays, names.separator, fmt_num(r))));
        }
        b.rays = r;
    }
    b.names = names;
    *BUDGET.write().unwrap_or_else(|p| p.into_inner()) = Some(b);
    Ok(())
}

/// Name the budgets for a front end whose users set them by `names`, keeping their values, unless a front end
/// named them already: the C++ library, which has no start-up hook, calls it on its first entry, so that a
/// refusal names `diffcassi::set_limits` rather than the command line's options.
pub fn name_budgets(names: BudgetNames) {
    let mut guard = BUDGET.write().unwrap_or_else(|p| p.into_inner());
    let b = guard.get_or_insert_with(Budget::default_for_machine);
    if b.names == BudgetNames::cli() {
        b.names = names;
    }
}

/// The process-wide budget (a copy).
pub fn budget() -> Budget {
    if let Some(b) = BUDGET.read().unwrap_or_else(|p| p.into_inner()).as_ref() {
        return b.clone();
    }
    let mut guard = BUDGET.write().unwrap_or_else(|p| p.into_inner());
    guard.get_or_insert_with(Budget::default_for_machine).clone()
}

/// Refuse `bytes` over the memory budget, naming the options that set the size (`what`). What the process
/// holds already ([`hold`]: a render record, an exact operator's kept transport, a solver's arrays) counts
/// against the budget too, and a refusal names it.
pub fn check_memory(what: &str, bytes: f64) -> Result<()> {
    memory_within_budget(what, bytes, Some(what))
}

/// [`check_memory`] where `what` carries figures beside the options (`--order 4 × --rings 12 (3.2e4 ray trees,
/// 118 detector paths each)`): a refusal names `what` once, then `reduce` (the options alone) after "reduce"
/// (round 21: the whole figure string was repeated there).
pub fn check_memory_reducing(what: &str, reduce: &str, bytes: f64) -> Result<()> {
    memory_within_budget(what, bytes, Some(reduce))
}

/// [`check_memory`] for a workload no option sizes (`what` says what it is): a refusal names only the budget
/// to raise, not `what` to reduce (`design amici`'s 13×13 distortion grids said "reduce distortion grid
/// 13×13", not an option of `design`; round 19).
pub fn check_fixed_memory(what: &str, bytes: f64) -> Result<()> {
    memory_within_budget(what, bytes, None)
}

fn memory_within_budget(what: &str, bytes: f64, reducible: Option<&str>) -> Result<()> {
    let b = budget();
    let (held, terms) = held_now();
    if !(bytes + held <= b.memory_bytes) {
        // The held memory after the budget, so that every refusal reads "needs an estimated X of memory,
        // over the budget of B" whatever the process holds.
        let with = if terms.is_empty() { String::new() } else { format!(" with the {} held already ({})", gb(held), terms.join(", ")) };
        let reduce = reducible.map(|r| format!("reduce {r} or ")).unwrap_or_default();
        return Err(Error::invalid(format!(
            "{what}: needs an estimated {} of memory, over the budget of {} ({}){with}; {reduce}raise {}",
            gb(bytes),
            gb(b.memory_bytes),
            b.memory_source,
            b.names.raise(&b.names.memory)
        )));
    }
    Ok(())
}

/// Memory the process holds while a [`Held`] lives (bytes, with what it is), counted by every
/// [`check_memory`] meanwhile: a solver's denoiser is checked beside the solver's arrays, the operator's
/// transport and the render record, not against the whole budget as if nothing else were resident
/// (round 19: a PnP run peaked at 0.92 GB under a 0.5 GB budget).
static HELD: std::sync::Mutex<Vec<(u64, String, f64)>> = std::sync::Mutex::new(Vec::new());
static HELD_ID: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);

/// What [`hold`] registered; released when dropped.
#[derive(Debug)]
pub struct Held(u64);

impl Drop for Held {
    fn drop(&mut self) {
        HELD.lock().unwrap_or_else(|p| p.into_inner()).retain(|(id, ..)| *id != self.0);
    }
}

/// Register `bytes` held by the caller (`what`: "the render record") until the returned [`Held`] is dropped.
pub fn hold(what: impl Into<String>, bytes: f64) -> Held {
    let id = HELD_ID.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    HELD.lock().unwrap_or_else(|p| p.into_inner()).push((id, what.into(), if bytes.is_finite() { bytes.max(0.0) } else { f64::MAX }));
    Held(id)
}

/// The bytes held now ([`hold`]) and each term for messages ("the render record 0.06 GB").
pub fn held_now() -> (f64, Vec<String>) {
    let h = HELD.lock().unwrap_or_else(|p| p.into_inner());
    (h.iter().map(|(_, _, b)| b).sum(), h.iter().map(|(_, w, b)| format!("{w} {}", gb(*b))).collect())
}

/// Refuse more than the ray budget, naming the options that set the count (`what`).
pub fn check_rays(what: &str, rays: f64) -> Result<()> {
    check_rays_reducing(what, what, rays)
}

/// [`check_rays`] naming `what` once and `reduce` (the options alone) after "reduce", as
/// [`check_memory_reducing`].
pub fn check_rays_reducing(what: &str, reduce: &str, rays: f64) -> Result<()> {
    let b = budget();
    if !(rays <= b.rays) {
        return Err(Error::invalid(format!(
            "{what}: {} rays to trace, over the budget of {} ({}; default {DEFAULT_MAX_RAYS:.0e}, 34 paper-scale acquisitions); reduce {reduce} or raise {}",
            fmt_count(rays),
            fmt_count(b.rays),
            b.names.rays,
            b.names.raise(&b.names.rays)
        )));
    }
    Ok(())
}

/// A ray count for messages, so that two different counts never print alike (`2.294e5 rays … over the budget
/// of 2.294e5` hid 229 376 against 229 375; round 19): a whole number below 10¹⁵ exactly (229376), anything
/// else in the shortest form that tells it from every other f64 (`1.3e23`, `229375.5`).
pub fn fmt_count(v: f64) -> String {
    if v.is_finite() && v.fract() == 0.0 && v.abs() < 1e15 {
        format!("{v:.0}")
    } else if v.is_finite() && (1e-4..1e15).contains(&v.abs()) {
        format!("{v}")
    } else {
        format!("{v:e}")
    }
}

/// `bytes` as messages print them ("0.24 GB", "3.120e-3 GB" below 10 MB).
pub fn fmt_gb(bytes: f64) -> String {
    gb(bytes)
}

fn gb(bytes: f64) -> String {
    // Budgets below 10 MB (`--max-memory-gb 0.000001`) were both "0.00 GB" (round 9).
    if bytes.is_finite() && bytes < 1e7 {
        format!("{:.3e} GB", bytes / 1e9)
    } else if bytes.is_finite() && bytes < 1e15 {
        format!("{:.2} GB", bytes / 1e9)
    } else if bytes.is_finite() {
        format!("{:.2e} GB", bytes / 1e9)
    } else {
        "more than 10^308 bytes".into()
    }
}

/// A count option in `1..=max`: `Err` names the option, its value and the range.
pub fn check_count(option: &str, value: usize, max: usize) -> Result<usize> {
    if value == 0 || value > max {
        return Err(Error::invalid(format!("{option} {value}: must be in 1..={max}")));
    }
    Ok(value)
}

/// The environment's `RAYON_NUM_THREADS` (rayon's default pool size when `--threads` / `set_num_threads` is
/// not given): a number above [`MAX_THREADS`] would start that many threads (100 000 hung a render); refused,
/// naming the variable. Unset, empty or 0: rayon's own default (the core count). Anything else that is not a
/// whole number (`abc`, `-1`, `2.5`, one beyond u64) is refused too: rayon ignores it silently, so a typo ran
/// on every core while the user believed otherwise.
pub fn check_rayon_env() -> Result<()> {
    let Some(v) = std::env::var_os("RAYON_NUM_THREADS") else { return Ok(()) };
    let help = format!("must be a whole number in 1..={MAX_THREADS}, or 0 / unset for all cores; `--threads` or `diffcassi.set_num_threads` sets the count");
    let Some(text) = v.to_str() else {
        return Err(Error::invalid(format!("environment RAYON_NUM_THREADS={}: {help}", v.to_string_lossy())));
    };
    let t = text.trim();
    if t.is_empty() {
        return Ok(());
    }
    match t.parse::<u64>() {
        Ok(n) if n <= MAX_THREADS as u64 => Ok(()),
        _ => Err(Error::invalid(format!("environment RAYON_NUM_THREADS={text}: {help}"))),
    }
}

/// `--threads`: 1..=[`MAX_THREADS`].
pub fn check_threads(n: usize) -> Result<usize> {
    let cores = std::thread::available_parallelism().map(|c| c.get()).unwrap_or(1);
    if n == 0 || n > MAX_THREADS {
        return Err(Error::invalid(format!("--threads {n}: must be in 1..={MAX_THREADS} (this machine has {cores} cores; results do not depend on the thread count)")));
    }
    Ok(n)
}

// ------------------------------------------------------------------ value checks

/// A number for messages: plain when moderate, scientific when huge or tiny (`1e308`, not 309 digits).
pub fn fmt_num(v: f64) -> String {
    if v != 0.0 && v.is_finite() && !(1e-4..1e7).contains(&v.abs()) {
        format!("{v:e}")
    } else {
        format!("{v}")
    }
}

/// A resolved length (mm): finite and |v| ≤ [`MAX_LENGTH_MM`]. `Err` holds the reason.
pub fn check_plausible_length(field: &str, v: f64) -> std::result::Result<(), String> {
    if !v.is_finite() {
        return Err(format!("{field} = {v} is not finite"));
    }
    if v.abs() > MAX_LENGTH_MM {
        return Err(format!("{field} = {} mm is outside the plausible range ±{MAX_LENGTH_MM:e} mm (1 km)", fmt_num(v)));
    }
    Ok(())
}

/// A resolved tilt (degrees): finite and |v| ≤ [`MAX_TILT_DEG`].
pub fn check_plausible_tilt(field: &str, v: f64) -> std::result::Result<(), String> {
    if !v.is_finite() {
        return Err(format!("{field} = {v} is not finite"));
    }
    if v.abs() > MAX_TILT_DEG {
        return Err(format!("{field} = {}° is outside the plausible range ±{MAX_TILT_DEG}°", fmt_num(v)));
    }
    Ok(())
}

/// A resolved Lens Data Editor cell (after pickups and solves), by column: lengths (`*_mm` except the
/// radius and the focal length, which may be huge for a flat or an inert paraxial lens, f = 10¹⁵ mm) within ±[`MAX_LENGTH_MM`], tilts (`*_deg`) within ±[`MAX_TILT_DEG`], everything else (radius,
/// conic, asphere coefficients) finite. `Err` holds the reason.
pub fn check_resolved_cell(column: &str, v: f64) -> std::result::Result<(), String> {
    if column == "conic" && v.is_finite() && v.abs() > MAX_CONIC {
        // Conics, asphere terms and grating frequencies had no bound (a conic of 1e308 was printed with 309
        // digits and missed every ray; `PARM 3 1e308` on a toroid missed even on axis; a held-out battery,
        // round 10).
        Err(format!("conic = {}: beyond ±{MAX_CONIC:e}, no real surface's", fmt_num(v)))
    } else if column.starts_with("asphere_") && v.is_finite() && v.abs() > MAX_ASPHERE_COEFFICIENT {
        Err(format!("{column} = {}: beyond ±{MAX_ASPHERE_COEFFICIENT:e} (mm^(1−2k) for the r^(2k) term), no real surface's", fmt_num(v)))
    } else if column == "grating_lines_per_um" && v.is_finite() && v.abs() > MAX_GRATING_LINES_PER_UM {
        Err(format!("grating_lines_per_um = {}: beyond {MAX_GRATING_LINES_PER_UM:e} lines/µm (a period below 1 nm), no real grating's", fmt_num(v)))
    } else if column.ends_with("_deg") {
        check_plausible_tilt(column, v)
    } else if (column == "radius_mm" || column == "rotation_radius_mm") && v.is_finite() && v != 0.0 && v.abs() < 1.0 / MAX_CURVATURE_PER_MM {
        // The `.zmx` reader's bound on CURV, for every spec format (a radius of rotation of 1e-300 mm was taken).
        Err(format!("{column} = {} mm is below the plausible radius of 1 nm (a curvature above {MAX_CURVATURE_PER_MM:e} mm⁻¹)", fmt_num(v)))
    } else if column.ends_with("_mm") && column != "radius_mm" && column != "focal_length_mm" {
        check_plausible_length(column, v)
    } else if !v.is_finite() {
        Err(format!("{column} = {v} is not finite"))
    } else {
        Ok(())
    }
}

/// Every value finite (an array about to be written): the error names the array, the first bad index and
/// value.
pub fn check_finite_array(what: &str, values: impl IntoIterator<Item = f64>) -> Result<()> {
    for (i, v) in values.into_iter().enumerate() {
        if !v.is_finite() {
            return Err(Error::invalid(format!("{what}: element {i} is {v}; refusing to write a non-finite value")));
        }
    }
    Ok(())
}

/// Every number of a JSON value finite before it is written: `serde_json` writes inf/NaN as `null`, which
/// would hide them. Returns the JSON path of the first non-finite number. (A `serde_json::Value` cannot
/// hold one, so the check runs on the serializable value through a checking serializer.)
pub fn check_json_finite<T: serde::Serialize + ?Sized>(what: &str, value: &T) -> Result<()> {
    let mut path = Vec::new();
    match value.serialize(FiniteCheck { path: &mut path }) {
        Ok(()) => Ok(()),
        Err(NonFinite(p)) => Err(Error::invalid(format!("{what}: `{p}` is not finite (inf/NaN); refusing to write it as JSON null"))),
    }
}

// ------------------------------------------------------------------ memory estimates (bytes)

/// Bytes per traced ray held by `trace`/`spot` (ray batch 56 B, traced batch 60 B, spot columns ~40 B).
pub const BYTES_PER_RAY: f64 = 160.0;

/// Bytes one entry (pixel × wavelength) of a traced mapping cube ([`crate::analysis::MappingCube`]) holds:
/// the chief ray's landing point as two f64 detector coordinates (16 B) and its validity flag (1 B).
pub const BYTES_PER_MAPPING_ENTRY: f64 = 17.0;
/// Bytes per entry of the float32 copy written as `mapping.npy` (two f32 coordinates); float64 output
/// (`mapping --f64`) writes the cube's own positions, no copy.
pub const BYTES_PER_MAPPING_ENTRY_F32_COPY: f64 = 8.0;
/// Margin on the mapping figures, which are the exact sizes of the buffers (allocator slack, the process's
/// own pages): 10 %. Measured (round 19, SP, 28 wavelengths): peak RSS 0.73 GB for a 1024² cube written as
/// float32 (24.4 B per entry, the estimate 27.5 B), 0.50 GB as float64 (16.6 B, the estimate 18.7 B).
const MAPPING_MARGIN: f64 = 1.1;

/// Memory of [`crate::analysis::mapping_cube`] for an H×W×Nλ cube: [`BYTES_PER_MAPPING_ENTRY`] per entry
/// (≈ 18.7 B with the margin). The analytic tracer traces each scene row in place (a row's fields only); any
/// other tracer ([`bytes_mapping_batch`]) holds one wavelength's chief-ray batch at a time beside it.
pub fn bytes_mapping(height: usize, width: usize, wavelengths: usize) -> f64 {
    height as f64 * width as f64 * wavelengths as f64 * BYTES_PER_MAPPING_ENTRY * MAPPING_MARGIN
}

/// [`bytes_mapping`] plus what writing it costs: the float32 copy of the positions (`mapping.npy`, 8 B per
/// entry; none for float64 output): ≈ 27.5 B per entry as float32, 18.7 B as float64.
pub fn bytes_mapping_written(height: usize, width: usize, wavelengths: usize, float64: bool) -> f64 {
    let copy = if float64 { 0.0 } else { BYTES_PER_MAPPING_ENTRY_F32_COPY };
    height as f64 * width as f64 * wavelengths as f64 * (BYTES_PER_MAPPING_ENTRY + copy) * MAPPING_MARGIN
}

/// The batched route of a mapping cube (a tracer other than the analytic one: one batch of every pixel's
/// chief ray per wavelength): the fields (16 B), the ray batch and its traced copy ([`BYTES_PER_RAY`]) per
/// scene pixel.
pub fn bytes_mapping_batch(height: usize, width: usize) -> f64 {
    height as f64 * width as f64 * (16.0 + BYTES_PER_RAY)
}

/// Bytes per point of a distortion grid ([`crate::analysis::grid_distortion`] and its clients): the field,
/// its chief ray and traced copy, the grid point's record, the CSV/JSON rows written; measured 440 B per
/// point at 1000² and 1500² (round 19: 250 B was assumed), with a 10 % margin.
pub const BYTES_PER_DISTORTION_POINT: f64 = 480.0;

/// Memory of a `grid × grid` distortion grid ([`BYTES_PER_DISTORTION_POINT`] per point).
pub fn bytes_distortion(grid: usize) -> f64 {
    (grid as f64).powi(2) * BYTES_PER_DISTORTION_POINT
}

/// A render of an N×N scene: the scene cube (8 B per pixel and scene band), mapping cube (16 B per pixel
/// and band), mask, detector images (at most 2N² pixels: f64 sum, f32 per band, ×planes with --cube),
/// and the Airy kernels (one per plane).
pub fn bytes_render(n: usize, scene_bands: usize, bands: usize, planes: usize, cube: bool, airy_diameter_px: Option<f64>) -> f64 {
    let n2 = n as f64 * n as f64;
    let detector = 2.0 * n2;
    let images = detector * (8.0 + 4.0 * bands as f64 + if cube { 4.0 * bands as f64 } else { 0.0 });
    bytes_render_scene(n2, scene_bands, bands, planes, airy_diameter_px) + images
}

/// The scene-sized part of [`bytes_render`] for `pixels` scene pixels: scene cube, mapping cube and mask,
/// and the Airy kernels.
pub fn bytes_render_scene(pixels: f64, scene_bands: usize, bands: usize, planes: usize, airy_diameter_px: Option<f64>) -> f64 {
    let taps = airy_diameter_px.map(|d| (2.0 * (1.33 * d * 1.3 + 1.5) + 1.0).powi(2)).unwrap_or(0.0);
    pixels * (8.0 * scene_bands as f64 + 8.0) + bytes_render_mapping(pixels, bands) + planes as f64 * (taps * 12.0 + 64.0)
}

/// The mapping cube's term of a render's estimate ([`bytes_render_scene`]), 16 B per scene pixel and band: it is
/// traced and written after the acquisition, whose per-band images and tracing buffers are freed by then, so it
/// adds this much to the render's peak (measured round 19, SP 28 bands: +0.118 GB at 512², +0.47 GB at 1024²,
/// 16.1 B per entry), not the whole [`bytes_mapping_written`] (27.5 B).
pub fn bytes_render_mapping(pixels: f64, bands: usize) -> f64 {
    pixels * 16.0 * bands as f64
}

/// Bytes per surface of the system for a `--tolerance-um` calibration: the Embree candidates' scenes (the
/// finest mesh tessellates each surface to 0.1 µm of sag) dominate; measured round 19: 0.06 GB for SP (20
/// surfaces), 0.11 GB for DDSP (~40), i.e. ≤ 3 MB per surface, estimated at 4 MB.
pub const BYTES_CALIBRATION_PER_SURFACE: f64 = 4e6;

/// A `--tolerance-um` calibration of a render or mapping: [`BYTES_CALIBRATION_PER_SURFACE`] per surface and the
/// ray set (`rays`: the set of each wavelength, all wavelengths) with its reference and one candidate's traces.
pub fn bytes_calibration(surfaces: usize, rays: f64) -> f64 {
    surfaces as f64 * BYTES_CALIBRATION_PER_SURFACE + 3.0 * rays * BYTES_PER_RAY
}

/// The buffers of a render the size of its **detector** (known only once the dispersed footprint is traced,
/// [`crate::render::Renderer::new`]; [`bytes_render`] assumes 2N² pixels): the acquisition's f64 sum and
/// its f32 copy written out (16 B), every band's f32 image, held until they are summed (4 B × bands), and
/// per worker thread an f64 band sum and a padded f32 plane (12 B × threads).
pub fn bytes_detector(pixels: f64, bands: usize, threads: usize) -> f64 {
    pixels * (16.0 + 4.0 * bands as f64 + 12.0 * threads as f64)
}

/// A spectral cube H×W×B held in memory (f32 values, 4 B), with its sRGB preview or a fitted copy beside
/// it (another 4 B per value): 8 B per value.
pub fn bytes_cube(height: usize, width: usize, bands: usize) -> f64 {
    height as f64 * width as f64 * bands as f64 * 8.0
}

/// Decoding an H×W RGB(A) photograph: the decoded 8/16-bit pixels (≤ 8 B) and the f32 RGB copy (12 B).
pub fn bytes_rgb_decode(height: usize, width: usize) -> f64 {
    height as f64 * width as f64 * 20.0
}

/// [`crate::diff::DiffSystem::trace`] of `rays` rays for `params` free parameters: the Jacobian, ∂ of the six
/// image coordinates per parameter (48·K B per ray, allocated once and written in place), the finite flags
/// (1 B), and the traced columns (53 B: six f64, a status, a u32 surface) held twice while the chunks are
/// gathered: 107 + 48·K B per ray.
pub fn bytes_jacobian_trace(rays: f64, params: usize) -> f64 {
    rays * (107.0 + 48.0 * params as f64)
}

/// A ray-batch Jacobian as the bindings return it (Python's `diffcassi.jacobian`): the caller's rays copied
/// into a batch (56 B per ray), [`bytes_jacobian_trace`], then beside the Jacobian the per-ray reasons (two
/// 24 B vectors, a flag, an 8 B list entry) and the interleaved positions/directions/status/surface copy
/// (53 B): 220 + 48·K B per ray, with a 10 % margin (allocator slack). Measured round 21 (SP, analytic, peak
/// RSS over the process before the call): see `docs/python.md` "Limits".
pub fn bytes_jacobian(rays: f64, params: usize) -> f64 {
    rays * (220.0 + 48.0 * params as f64) * JACOBIAN_MARGIN
}

/// Margin on the Jacobian figures, which are the buffers' exact sizes: 10 %.
const JACOBIAN_MARGIN: f64 = 1.1;

/// Rays per block of [`crate::render::DiffRenderer::mapping_jacobian`]: it traces its H·W·L chief rays a block
/// at a time into the returned arrays, so only one block's batch and Jacobian are alive beside them.
pub const MAPPING_JACOBIAN_BLOCK: usize = 1 << 16;

/// [`crate::render::DiffRenderer::mapping_jacobian`] of an H×W scene at `wavelengths` wavelengths for `params`
/// free parameters: the returned positions (16 B per entry), Jacobian (2 coordinates × K × 8 B) and validity
/// (1 B), plus one block of [`MAPPING_JACOBIAN_BLOCK`] rays (the ray batch, 56 B, and its
/// [`bytes_jacobian_trace`]), with a 10 % margin.
pub fn bytes_mapping_jacobian(height: usize, width: usize, wavelengths: usize, params: usize) -> f64 {
    let entries = height as f64 * width as f64 * wavelengths as f64;
    let block = entries.min(MAPPING_JACOBIAN_BLOCK as f64);
    (entries * (17.0 + 16.0 * params as f64) + block * 56.0 + bytes_jacobian_trace(block, params)) * JACOBIAN_MARGIN
}

/// The budgets of tracing `rays` rays given by the caller (the command line's `trace`/`spot`, Python's
/// `trace`, `System.seeded_rays`): the ray budget, and [`BYTES_PER_RAY`] each against the memory budget.
/// `what` names the workload, `reduce` what sets the count (the options, or the arguments).
pub fn check_traced_rays(what: &str, reduce: &str, rays: f64) -> Result<()> {
    check_rays_reducing(what, reduce, rays)?;
    check_memory_reducing(what, reduce, rays * BYTES_PER_RAY)
}

/// The budgets of a ray-batch Jacobian ([`bytes_jacobian`]) of `rays` rays for `params` parameters: the ray
/// budget and the memory budget, before anything of its size is allocated. `what` names the workload,
/// `reduce` what sets its size.
pub fn check_jacobian(what: &str, reduce: &str, rays: f64, params: usize) -> Result<()> {
    check_rays_reducing(what, reduce, rays)?;
    check_memory_reducing(what, reduce, bytes_jacobian(rays, params))
}

// ------------------------------------------------------------------ JSON finiteness checker

#[derive(Debug)]
struct NonFinite(String);
impl std::fmt::Display for NonFinite {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "non-finite number at {}", self.0)
    }
}
impl std::error::Error for NonFinite {}
impl serde::ser::Error for NonFinite {
    fn custom<M: std::fmt::Display>(msg: M) -> Self {
        NonFinite(format!("(serialization error: {msg})"))
    }
}

struct FiniteCheck<'a> {
    path: &'a mut Vec<String>,
}

impl FiniteCheck<'_> {
    fn float(self, v: f64) -> std::result::Result<(), NonFinite> {
        if v.is_finite() {
            Ok(())
        } else {
            Err(NonFinite(format!("{}{}", if self.path.is_empty() { "(root)".to_string() } else { self.path.join("") }, if v.is_nan() { " = NaN".to_string() } else { format!(" = {v}") })))
        }
    }
    fn nested<T: serde::Serialize + ?Sized>(&mut self, seg: String, v: &T) -> std::result::Result<(), NonFinite> {
        self.path.push(seg);
        let r = v.serialize(FiniteCheck { path: self.path });
        self.path.pop();
        r
    }
}

struct Compound<'a> {
    path: &'a mut Vec<String>,
    index: usize,
    key: Option<String>,
}

macro_rules! ok_scalars {
    ($($f:ident: $t:ty),*) => {$(fn $f(self, _v: $t) -> std::result::Result<(), NonFinite> { Ok(()) })*};
}

impl<'a> serde::Serializer for FiniteCheck<'a> {
    type Ok = ();
    type Error = NonFinite;
    type SerializeSeq = Compound<'a>;
    type SerializeTuple = Compound<'a>;
    type SerializeTupleStruct = Compound<'a>;
    type SerializeTupleVariant = Compound<'a>;
    type SerializeMap = Compound<'a>;
    type SerializeStruct = Compound<'a>;
    type SerializeStructVariant = Compound<'a>;
    ok_scalars!(serialize_bool: bool, serialize_i8: i8, serialize_i16: i16, serialize_i32: i32, serialize_i64: i64, serialize_u8: u8, serialize_u16: u16, serialize_u32: u32, serialize_u64: u64, serialize_char: char, serialize_str: &str, serialize_bytes: &[u8]);
    fn serialize_f32(self, v: f32) -> std::result::Result<(), NonFinite> {
        self.float(v as f64)
    }
    fn serialize_f64(self, v: f64) -> std::result::Result<(), NonFinite> {
        self.float(v)
    }
    fn serialize_none(self) -> std::result::Result<(), NonFinite> {
        Ok(())
    }
    fn serialize_some<T: serde::Serialize + ?Sized>(self, v: &T) -> std::result::Result<(), NonFinite> {
        v.serialize(self)
    }
    fn serialize_unit(self) -> std::result::Result<(), NonFinite> {
        Ok(())
    }
    fn serialize_unit_struct(self, _: &'static str) -> std::result::Result<(), NonFinite> {
        Ok(())
    }
    fn serialize_unit_variant(self, _: &'static str, _: u32, _: &'static str) -> std::result::Result<(), NonFinite> {
        Ok(())
    }
    fn serialize_newtype_struct<T: serde::Serialize + ?Sized>(self, _: &'static str, v: &T) -> std::result::Result<(), NonFinite> {
        v.serialize(self)
    }
    fn serialize_newtype_variant<T: serde::Serialize + ?Sized>(mut self, _: &'static str, _: u32, variant: &'static str, v: &T) -> std::result::Result<(), NonFinite> {
        self.nested(format!(".{variant}"), v)
    }
    fn serialize_seq(self, _: Option<usize>) -> std::result::Result<Compound<'a>, NonFinite> {
        Ok(Compound { path: self.path, index: 0, key: None })
    }
    fn serialize_tuple(self, _: usize) -> std::result::Result<Compound<'a>, NonFinite> {
        Ok(Compound { path: self.path, index: 0, key: None })
    }
    fn serialize_tuple_struct(self, _: &'static str, _: usize) -> std::result::Result<Compound<'a>, NonFinite> {
        Ok(Compound { path: self.path, index: 0, key: None })
    }
    fn serialize_tuple_variant(self, _: &'static str, _: u32, _: &'static str, _: usize) -> std::result::Result<Compound<'a>, NonFinite> {
        Ok(Compound { path: self.path, index: 0, key: None })
    }
    fn serialize_map(self, _: Option<usize>) -> std::result::Result<Compound<'a>, NonFinite> {
        Ok(Compound { path: self.path, index: 0, key: None })
    }
    fn serialize_struct(self, _: &'static str, _: usize) -> std::result::Result<Compound<'a>, NonFinite> {
        Ok(Compound { path: self.path, index: 0, key: None })
    }
    fn serialize_struct_variant(self, _: &'static str, _: u32, _: &'static str, _: usize) -> std::result::Result<Compound<'a>, NonFinite> {
        Ok(Compound { path: self.path, index: 0, key: None })
    }
}

impl Compound<'_> {
    fn element<T: serde::Serialize + ?Sized>(&mut self, v: &T) -> std::result::Result<(), NonFinite> {
        let seg = format!("[{}]", self.index);
        self.index += 1;
        FiniteCheck { path: self.path }.nested(seg, v)
    }
    fn field<T: serde::Serialize + ?Sized>(&mut self, key: &str, v: &T) -> std::result::Result<(), NonFinite> {
        FiniteCheck { path: self.path }.nested(format!(".{key}"), v)
    }
}

macro_rules! seq_like {
    ($($tr:ident :: $m:ident),*) => {$(
        impl serde::ser::$tr for Compound<'_> {
            type Ok = ();
            type Error = NonFinite;
            fn $m<T: serde::Serialize + ?Sized>(&mut self, v: &T) -> std::result::Result<(), NonFinite> {
                self.element(v)
            }
            fn end(self) -> std::result::Result<(), NonFinite> {
                Ok(())
            }
        }
    )*};
}
seq_like!(SerializeSeq::serialize_element, SerializeTuple::serialize_element, SerializeTupleStruct::serialize_field, SerializeTupleVariant::serialize_field);

impl serde::ser::SerializeMap for Compound<'_> {
    type Ok = ();
    type Error = NonFinite;
    fn serialize_key<T: serde::Serialize + ?Sized>(&mut self, k: &T) -> std::result::Result<(), NonFinite> {
        self.key = Some(serde_json::to_value(k).ok().and_then(|v| v.as_str().map(String::from).or(Some(v.to_string()))).unwrap_or_default());
        Ok(())
    }
    fn serialize_value<T: serde::Serialize + ?Sized>(&mut self, v: &T) -> std::result::Result<(), NonFinite> {
        let k = self.key.take().unwrap_or_default();
        self.field(&k, v)
    }
    fn end(self) -> std::result::Result<(), NonFinite> {
        Ok(())
    }
}

impl serde::ser::SerializeStruct for Compound<'_> {
    type Ok = ();
    type Error = NonFinite;
    fn serialize_field<T: serde::Serialize + ?Sized>(&mut self, key: &'static str, v: &T) -> std::result::Result<(), NonFinite> {
        self.field(key, v)
    }
    fn end(self) -> std::result::Result<(), NonFinite> {
        Ok(())
    }
}

impl serde::ser::SerializeStructVariant for Compound<'_> {
    type Ok = ();
    type Error = NonFinite;
    fn serialize_field<T: serde::Serialize + ?Sized>(&mut self, key: &'static str, v: &T) -> std::result::Result<(), NonFinite> {
        self.field(key, v)
    }
    fn end(self) -> std::result::Result<(), NonFinite> {
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Radii below 1 nm are refused in every spec format, as the `.zmx` reader's CURV bound (a radius of rotation
    /// of 1e-300 mm was taken: a held-out battery); larger ones, flats (0 is the validator's) and huge radii pass.
    #[test]
    fn radii_below_a_nanometre_are_implausible() {
        for col in ["radius_mm", "rotation_radius_mm"] {
            for v in [1e-300, -1e-300, 5e-7, -9.9e-7] {
                let e = check_resolved_cell(col, v).unwrap_err();
                assert!(e.contains(col) && e.contains("below the plausible radius of 1 nm"), "{e}");
            }
            for v in [1e-6, -2e-6, 35.0, 1e5, 0.0] {
                check_resolved_cell(col, v).unwrap();
            }
        }
        // A radius of curvature may be huge (a near-flat); a radius of rotation is a length (≤ 1 km).
        check_resolved_cell("radius_mm", 1e12).unwrap();
        assert!(check_resolved_cell("rotation_radius_mm", 1e12).is_err());
    }

    #[test]
    fn json_check_names_the_path_of_a_non_finite_number() {
        #[derive(serde::Serialize)]
        struct S {
            a: f64,
            b: Vec<[f64; 2]>,
            c: Option<f64>,
        }
        check_json_finite("x.json", &S { a: 1.0, b: vec![[0.0, 1.0]], c: None }).unwrap();
        let e = check_json_finite("x.json", &S { a: 1.0, b: vec![[0.0, 1.0], [2.0, f64::INFINITY]], c: None }).unwrap_err().to_string();
        assert!(e.contains("x.json") && e.contains(".b[1][1] = inf"), "{e}");
        let e = check_json_finite("x.json", &S { a: f64::NAN, b: vec![], c: None }).unwrap_err().to_string();
        assert!(e.contains(".a = NaN"), "{e}");
        let e = check_json_finite("x.json", &S { a: 0.0, b: vec![], c: Some(f64::NEG_INFINITY) }).unwrap_err().to_string();
        assert!(e.contains(".c = -inf"), "{e}");
        // Maps (serde_json::json! values hold only finite numbers, but HashMaps of f64 may not).
        let mut m = std::collections::BTreeMap::new();
        m.insert("rms_um", f64::INFINITY);
        let e = check_json_finite("m.json", &m).unwrap_err().to_string();
        assert!(e.contains(".rms_um = inf"), "{e}");
    }

    #[test]
    fn plausible_ranges() {
        assert!(check_plausible_length("t", 1e6).is_ok());
        assert!(check_plausible_length("t", -1e6 - 1.0).unwrap_err().contains("plausible"));
        assert!(check_plausible_length("t", f64::INFINITY).unwrap_err().contains("not finite"));
        assert!(check_plausible_tilt("tilt_x_deg", 30.0).is_ok());
        assert!(check_plausible_tilt("tilt_x_deg", 3e10).unwrap_err().contains("tilt_x_deg"));
        assert!(check_threads(0).is_err() && check_threads(100_000).is_err() && check_threads(2).is_ok());
    }

    #[test]
    fn estimates_grow_with_the_options() {
        assert!(bytes_mapping(512, 512, 28) < 2e9);
        // 2.8·10¹¹ entries × 17 B × 1.1 (two f64 coordinates and a flag each): 5.2 TB.
        assert!(bytes_mapping(100_000, 100_000, 28) > 5e12);
        assert!(bytes_mapping_written(512, 512, 28, false) > bytes_mapping_written(512, 512, 28, true) && bytes_mapping_written(512, 512, 28, true) == bytes_mapping(512, 512, 28));
        let paper = bytes_render(512, 31, 28, 112, false, Some(2.5));
        assert!(paper > 1e8 && paper < 2e9, "{paper}");
        assert!(bytes_render(512, 31, 28, 112, false, Some(1e6)) > 1e15);
        assert!(bytes_render(1_000_000, 31, 28, 112, false, Some(2.5)) > 1e14);
        assert!(bytes_cube(100_000, 100_000, 28) > 1e12 && bytes_cube(256, 256, 28) < 2e7);
        assert!(bytes_rgb_decode(20_000, 20_000) > 7e9);
    }
}

// ------------------------------------------------------------------ rectangular renders (Python API)

/// [`bytes_render`] for a `height × width` scene (the Python API renders rectangles; the CLI squares):
/// the same terms with the pixel count `height · width`, so `bytes_render_hw(n, n, ..) == bytes_render(n, ..)`.
pub fn bytes_render_hw(height: usize, width: usize, scene_bands: usize, bands: usize, planes: usize, cube: bool, airy_diameter_px: Option<f64>) -> f64 {
    let pixels = height as f64 * width as f64;
    let detector = 2.0 * pixels;
    let images = detector * (8.0 + 4.0 * bands as f64 + if cube { 4.0 * bands as f64 } else { 0.0 });
    bytes_render_scene(pixels, scene_bands, bands, planes, airy_diameter_px) + images
}

#[cfg(test)]
mod tests_hw {
    #[test]
    fn rectangle_estimate_equals_the_square_one() {
        for (n, airy) in [(1, None), (128, Some(2.5)), (512, Some(100.0))] {
            assert_eq!(super::bytes_render_hw(n, n, 31, 28, 112, true, airy), super::bytes_render(n, 31, 28, 112, true, airy));
        }
        // A 1 × 10⁹ strip: 10⁹ pixels × ~940 bytes, as large as the 31 623² square of the same area.
        assert!(super::bytes_render_hw(1, 1_000_000_000, 31, 28, 112, false, None) > 9e11);
    }
}
