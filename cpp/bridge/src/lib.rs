//! # diffcassi-cpp: the C++ API of diffcassi, through a [`cxx`] bridge
//!
//! C++ tools load a system (preset, spec file or spec string), list its surfaces and wavelengths, trace
//! struct-of-arrays batches with a named backend (zero copy in: the C++ columns are read in place; one
//! allocation out: the tracer's own result columns, viewed from C++ without copying), and run the spot,
//! grid-distortion and mapping-cube analyses. Rust errors arrive in C++ as exceptions carrying the Rust
//! message (`rust::Error`, rethrown as `diffcassi::Error` by the wrapper header).
//!
//! This crate is a workspace member of its own (`cpp/bridge`) so that the main crate and its `build.rs`
//! stay free of C++; `cargo build -p diffcassi-cpp` produces `libdiffcassi_cpp.a`, and `cpp/CMakeLists.txt`
//! turns it into the installed static and shared libraries. C++ code includes
//! `cpp/include/diffcassi/diffcassi.hpp` (RAII, span-like views, exceptions) or the raw generated header
//! `cpp/include/diffcassi/bridge.h` (written by `build.rs`; `scripts/test.sh` fails if the committed copy
//! is stale).
//!
//! Used from Rust (the same calls C++ makes):
//! ```
//! let sys = diffcassi_cpp::load_preset("sp")?;
//! let grid = sys.distortion_grid("analytic", 520.0, 3, 2.5)?;
//! assert_eq!(grid.points.len(), 9);
//! let err = sys.trace("warp-drive", &[], &[], &[], &[], &[], &[], &[]).err().unwrap();
//! assert!(err.to_string().contains("unknown backend `warp-drive`"));
//! # Ok::<(), diffcassi::Error>(())
//! ```
//!
//! ## Thread safety
//! A loaded [`System`] is immutable: every method takes `&self`, the type is `Send + Sync` (checked at
//! compile time below), and traces from several C++ threads on one `System` run concurrently on the library's
//! pool ([`diffcassi::pool`]: rayon's global pool, or `set_num_threads`'s; a fresh one in a `fork()` child)
//! with results identical to sequential calls (each ray is independent; see
//! `cpp/tests/test_threads.cpp`). The only shared mutable state is the per-system backend cache, behind a
//! mutex held just long enough to look a backend up. Result objects (`Traced`, `Spot`, `Mapping`, `Rays`)
//! are owned values: read them from any thread, move them between threads.
//!
//! ## Jacobians and rendering
//! - **Jacobians** ([`jacobian`]): free parameters by name (those of `diffcassi calibrate --free`),
//!   ∂(image position, direction)/∂θ of a batch as struct-of-arrays in one allocation, with the analytic
//!   or an Embree backend (f64-refined hits); per ray, whether it is available and why not.
//! - **Rendering** ([`render`]): a coded acquisition of a caller's scene cube and mask (or a random mask
//!   from opening and seed) into the caller's buffer, sized by [`System::render_detector`]; no files.
//! - **Backends**: every backend name goes through [`backend::tracer_for`] (`analytic`,
//!   `embree-user[:f64|:none]`, `embree-mesh[:SAG_UM][:f64|:none]`).

pub mod backend;
pub mod denoise;
pub mod jacobian;
pub mod render;
mod results;
mod system;

pub use denoise::denoise;
pub use jacobian::Jacobian;
pub use render::{default_render_options, set_calibration_cache};
pub use results::{Mapping, Rays, Spot, Traced};
pub use system::{load_preset, load_spec_file, load_spec_string, System};

use results::{backend_names, get_num_threads, linspace, preset_names, pupil_points, set_limits, set_num_threads, version};

#[cxx::bridge(namespace = "diffcassi::ffi")]
pub mod ffi {
    /// One row of the resolved Lens Data Editor (pickups and solves evaluated). Lengths mm, angles degrees.
    #[derive(Clone, Debug)]
    struct SurfaceInfo {
        index: usize,
        /// "Standard", "Even Asphere", "Paraxial", "Coordinate Break".
        kind: String,
        comment: String,
        is_stop: bool,
        /// Glass after the surface; empty for air.
        material: String,
        /// Radius of curvature; +infinity for a flat surface (Zemax shows "Infinity").
        radius_mm: f64,
        thickness_mm: f64,
        conic: f64,
        /// Paraxial surface focal length (0 for other kinds).
        focal_length_mm: f64,
        /// Semi-diameter (given or automatic); `has_semi_diameter` false when unknown (then 0).
        semi_diameter_mm: f64,
        has_semi_diameter: bool,
        /// Coordinate Break decenters and tilts (0 for other kinds), and its order flag.
        decenter_x_mm: f64,
        decenter_y_mm: f64,
        tilt_x_deg: f64,
        tilt_y_deg: f64,
        tilt_z_deg: f64,
        order: u8,
        /// The surface's local frame origin in global coordinates.
        vertex_global_mm: [f64; 3],
    }

    /// Spot statistics about the centroid (`valid` false when no ray arrived; then all 0).
    #[derive(Clone, Copy, Debug)]
    struct SpotStats {
        valid: bool,
        count: usize,
        centroid_x_mm: f64,
        centroid_y_mm: f64,
        rms_radius_um: f64,
        geo_radius_um: f64,
    }

    /// One point of a Zemax-style Grid Distortion (see `diffcassi::analysis::DistortionPoint`).
    #[derive(Clone, Copy, Debug)]
    struct DistortionPoint {
        i: i32,
        j: i32,
        x_field_mm: f64,
        y_field_mm: f64,
        real_x_mm: f64,
        real_y_mm: f64,
        pred_x_mm: f64,
        pred_y_mm: f64,
        distortion_pct: f64,
        /// `diffcassi::RayStatus` as u8 (0 ok, 1 missed, 2 vignetted, 3 tir, 4 no_convergence, 5 invalid_input).
        status: u8,
    }

    /// A grid distortion at one wavelength.
    #[derive(Clone, Debug)]
    struct DistortionGrid {
        wavelength_nm: f64,
        /// Image of the on-axis field (Zemax's Xref, Yref), mm.
        reference_mm: [f64; 2],
        /// Predicted-coordinate matrix [A, B, C, D].
        abcd: [f64; 4],
        max_distortion_pct: f64,
        /// n × n points, x-major (Zemax's listing order).
        points: Vec<DistortionPoint>,
    }

    /// Render settings (see `render.rs`; `default_render_options()` gives the paper's).
    #[derive(Clone, Copy, Debug)]
    struct RenderOptions {
        /// Spectral planes over the bands' range (0: 4 per band).
        planes: usize,
        rays_per_pixel: usize,
        seed: u64,
        scene_pitch_mm: f64,
        detector_pitch_mm: f64,
        /// Airy blur, disk diameter in detector pixels at 520 nm (∝ λ).
        airy: bool,
        airy_diameter_px: f64,
        /// Random binary mask used when no mask values are given.
        mask_opening: f64,
        mask_seed: u64,
        /// An object at infinity: the scene's full angular extent across its width (degrees, in (0, 180);
        /// pixels uniform in field angle; `scene_pitch_mm` unused). 0 for a finite object (the default).
        scene_fov_deg: f64,
        /// The ray kernel's float precision (`Auto`: f64, or what `tolerance_um` chooses).
        precision: RenderPrecision,
        /// The error tolerance (µm, image plane) that chooses the backend, the rays per pixel and the
        /// precision (the CLI's `--tolerance-um`): 0 for none (the default). With a tolerance,
        /// `rays_per_pixel` must be 0, `precision` `Auto` and the backend argument empty.
        tolerance_um: f64,
    }

    /// A render's float precision: `Auto` (f64 unless a tolerance chooses), or given.
    #[derive(Debug)]
    enum RenderPrecision {
        Auto,
        F64,
        F32,
    }

    /// The detector of a render (and, after a render, its ray counts).
    #[derive(Clone, Debug)]
    struct RenderInfo {
        detector_height: usize,
        detector_width: usize,
        detector_pitch_mm: f64,
        /// x of the left edge of column 0 and y of the top edge of row 0 (mm, image-surface frame).
        x_left_mm: f64,
        y_top_mm: f64,
        planes: usize,
        rays_traced: u64,
        rays_arrived: u64,
        /// What traced the render: the tracer's name as render.json's `tracer` records it (`analytic-f64`,
        /// `analytic-f32`, `embree-user…`), the rays per pixel and the precision (`F64` or `F32`): the
        /// options' or a tolerance's choice.
        tracer: String,
        rays_per_pixel: usize,
        precision: RenderPrecision,
        /// With a tolerance, the error its choice predicts (µm: trace error + σ/√N; render.json's
        /// `tolerance_predicted_error_um`); 0 without one.
        predicted_error_um: f64,
        /// What the CLI warns about on the same render (and Python raises as UserWarnings): an acquisition
        /// that is zero everywhere, planes beyond the scene's bands, a dual disperser's dark planes, the f32
        /// kernel's measured rounding. Empty from `render_detector`.
        warnings: Vec<String>,
    }

    /// Normalised pupil points (px, py) of a pattern.
    #[derive(Clone, Debug)]
    struct PupilPoints {
        px: Vec<f64>,
        py: Vec<f64>,
    }

    extern "Rust" {
        /// A loaded, immutable, thread-safe system.
        type System;
        /// Rays made by the library (aimed as the system says); columns viewable from C++.
        type Rays;
        /// A traced batch: image-surface positions/directions, status, stop surface per ray.
        type Traced;
        /// A spot diagram.
        type Spot;
        /// A scene → detector mapping cube.
        type Mapping;
        /// A batch's Jacobians (SoA, one allocation) with its traced values.
        type Jacobian;

        // ---- loading (errors: unknown preset, unreadable/malformed spec, unknown glass, …)
        fn load_preset(name: &str) -> Result<Box<System>>;
        /// `.toml`, `.json` (our format), `.yml` (the paper's), `.csv` (Zemax prescription).
        fn load_spec_file(path: &str) -> Result<Box<System>>;
        /// `format`: "toml", "json" or "auto" (JSON if the text starts with `{`, after blanks and a byte-order mark); `source_name` names the
        /// text in error messages.
        fn load_spec_string(text: &str, format: &str, source_name: &str) -> Result<Box<System>>;
        fn preset_names() -> Vec<String>;
        /// Every backend name `trace` accepts (some may be unavailable in this build).
        fn backend_names() -> Vec<String>;
        fn version() -> String;
        /// `chief`, `marginal`, `hexapolar:R`, `grid:N`, `grid-step:S`, `random:N:SEED`.
        fn pupil_points(pattern: &str) -> Result<PupilPoints>;
        /// The learned denoiser on a cube [row][col][band] f32 into `out` (same size); `weights` empty: embedded.
        fn denoise(cube: &[f32], height: usize, width: usize, bands: usize, sigma: f64, weights: &str, out: &mut [f32]) -> Result<()>;
        /// `count` evenly spaced values from `first` to `last` (inclusive).
        fn linspace(first: f64, last: f64, count: usize) -> Result<Vec<f64>>;
        fn default_render_options() -> RenderOptions;
        /// The memory and ray budgets of every following call (`has_…` false: the default).
        fn set_limits(has_memory: bool, max_memory_gb: f64, has_rays: bool, max_rays: f64) -> Result<()>;
        /// The threads of every following call (0: all cores or `RAYON_NUM_THREADS`; at most 1024).
        fn set_num_threads(n: usize) -> Result<()>;
        /// The threads the following calls use.
        fn get_num_threads() -> Result<usize>;
        /// The folder of the render tolerance's calibration cache (the CLI's `--calibration-cache`) for every
        /// following call; empty: the default (`$DIFFCASSI_CACHE_DIR`, `$XDG_CACHE_HOME/diffcassi`,
        /// `~/.cache/diffcassi`). A path that exists and is not a folder is refused.
        fn set_calibration_cache(dir: &str) -> Result<()>;

        // ---- system data
        fn name(self: &System) -> &str;
        fn description(self: &System) -> &str;
        fn surfaces(self: &System) -> Vec<SurfaceInfo>;
        fn surface_count(self: &System) -> usize;
        /// Load-time warnings: glasses whose catalogue contradicts itself, semi-diameters beyond a surface's edge.
        fn warnings(self: &System) -> Vec<String>;
        fn stop_index(self: &System) -> usize;
        fn wavelengths_nm(self: &System) -> &[f64];
        fn primary_wavelength_nm(self: &System) -> f64;
        /// Field points, interleaved (x0, y0, x1, y1, …), mm.
        fn fields_mm(self: &System) -> Vec<f64>;
        /// Ray–surface intersections per traced ray.
        fn surfaces_per_ray(self: &System) -> usize;
        /// The resolved spec in our TOML / JSON format.
        fn to_toml(self: &System) -> Result<String>;
        fn to_json(self: &System) -> Result<String>;

        // ---- rays
        fn rays_for_field(self: &System, field_x_mm: f64, field_y_mm: f64, px: &[f64], py: &[f64], wavelength_nm: f64) -> Result<Box<Rays>>;
        fn chief_rays(self: &System, field_x_mm: &[f64], field_y_mm: &[f64], wavelength_nm: f64) -> Result<Box<Rays>>;
        fn seeded_workload(self: &System, rays_per_wavelength: usize, wavelengths_nm: &[f64], seed: u64) -> Result<Box<Rays>>;

        // ---- tracing (zero copy in, one allocation out)
        #[allow(clippy::too_many_arguments)]
        fn trace(
            self: &System,
            backend: &str,
            origin_x: &[f64],
            origin_y: &[f64],
            origin_z: &[f64],
            dir_x: &[f64],
            dir_y: &[f64],
            dir_z: &[f64],
            wavelength_nm: &[f64],
        ) -> Result<Box<Traced>>;
        /// Trace library-made rays (no copy either way).
        fn trace_rays(self: &System, backend: &str, rays: &Rays) -> Result<Box<Traced>>;
        /// Bench helper: time `reps` traces of `rays` natively in Rust (no FFI inside the loop); seconds per trace.
        fn time_rust_trace(self: &System, backend: &str, rays: &Rays, reps: usize) -> Result<Vec<f64>>;

        // ---- analyses
        #[allow(clippy::too_many_arguments)]
        fn spot_diagram(self: &System, backend: &str, field_x_mm: f64, field_y_mm: f64, wavelength_nm: f64, px: &[f64], py: &[f64]) -> Result<Box<Spot>>;
        fn distortion_grid(self: &System, backend: &str, wavelength_nm: f64, n: usize, half_width_mm: f64) -> Result<DistortionGrid>;
        fn mapping_cube(self: &System, backend: &str, height: usize, width: usize, pixel_pitch_mm: f64, wavelengths_nm: &[f64]) -> Result<Box<Mapping>>;

        // ---- Jacobians (free parameters by name, comma-separated; errors: unknown name, no parameter,
        //      ragged columns, unrefined Embree backend)
        #[allow(clippy::too_many_arguments)]
        fn trace_jacobian(
            self: &System,
            backend: &str,
            parameters: &str,
            origin_x: &[f64],
            origin_y: &[f64],
            origin_z: &[f64],
            dir_x: &[f64],
            dir_y: &[f64],
            dir_z: &[f64],
            wavelength_nm: &[f64],
        ) -> Result<Box<Jacobian>>;

        // ---- rendering into a caller buffer (scene [row][col][band] f32; mask H×W or empty; out: detector)
        fn render_detector(self: &System, backend: &str, height: usize, width: usize, wavelengths_nm: &[f64], options: &RenderOptions) -> Result<RenderInfo>;
        #[allow(clippy::too_many_arguments)]
        fn render(
            self: &System,
            backend: &str,
            height: usize,
            width: usize,
            wavelengths_nm: &[f64],
            scene: &[f32],
            mask: &[f32],
            options: &RenderOptions,
            out: &mut [f64],
        ) -> Result<RenderInfo>;

        // ---- Jacobian: values[(c·K + k)·N + i], c over x, y, z, dir_x, dir_y, dir_z
        fn len(self: &Jacobian) -> usize;
        fn parameter_count(self: &Jacobian) -> usize;
        fn parameters(self: &Jacobian) -> Vec<String>;
        fn values(self: &Jacobian) -> &[f64];
        fn available(self: &Jacobian) -> &[u8];
        fn reason(self: &Jacobian, i: usize) -> &str;
        fn traced_x(self: &Jacobian) -> &[f64];
        fn traced_y(self: &Jacobian) -> &[f64];
        fn traced_z(self: &Jacobian) -> &[f64];
        fn traced_dir_x(self: &Jacobian) -> &[f64];
        fn traced_dir_y(self: &Jacobian) -> &[f64];
        fn traced_dir_z(self: &Jacobian) -> &[f64];
        fn traced_status(self: &Jacobian) -> &[u8];

        // ---- Rays columns
        fn len(self: &Rays) -> usize;
        fn origin_x(self: &Rays) -> &[f64];
        fn origin_y(self: &Rays) -> &[f64];
        fn origin_z(self: &Rays) -> &[f64];
        fn dir_x(self: &Rays) -> &[f64];
        fn dir_y(self: &Rays) -> &[f64];
        fn dir_z(self: &Rays) -> &[f64];
        fn wavelength_nm(self: &Rays) -> &[f64];

        // ---- Traced columns (image surface frame; failed rays: 0 and the surface where they stopped)
        fn len(self: &Traced) -> usize;
        fn ok_count(self: &Traced) -> usize;
        fn x(self: &Traced) -> &[f64];
        fn y(self: &Traced) -> &[f64];
        fn z(self: &Traced) -> &[f64];
        fn dir_x(self: &Traced) -> &[f64];
        fn dir_y(self: &Traced) -> &[f64];
        fn dir_z(self: &Traced) -> &[f64];
        fn status(self: &Traced) -> &[u8];
        /// Surface where a failed ray stopped (`u32::MAX` for arrived rays).
        fn surface(self: &Traced) -> &[u32];

        // ---- Spot
        fn field_mm(self: &Spot) -> [f64; 2];
        fn wavelength_nm(self: &Spot) -> f64;
        fn x_mm(self: &Spot) -> &[f64];
        fn y_mm(self: &Spot) -> &[f64];
        fn status(self: &Spot) -> &[u8];
        fn has_chief(self: &Spot) -> bool;
        fn chief_mm(self: &Spot) -> [f64; 2];
        fn stats(self: &Spot) -> SpotStats;
        /// RMS radius about the chief ray (µm; 0 without a chief ray or arrived rays).
        fn rms_radius_chief_um(self: &Spot) -> f64;

        // ---- Mapping
        fn height(self: &Mapping) -> usize;
        fn width(self: &Mapping) -> usize;
        fn pixel_pitch_mm(self: &Mapping) -> f64;
        fn wavelength_nm(self: &Mapping) -> &[f64];
        /// Detector (x, y) mm, C order [row][col][λ][xy]; 0 where `valid` is 0.
        fn positions_mm(self: &Mapping) -> &[f64];
        /// 1 where the chief ray arrived, C order [row][col][λ].
        fn valid(self: &Mapping) -> &[u8];
        fn invalid_count(self: &Mapping) -> usize;
    }
}

// A loaded system is shared between C++ threads by `const System&`.
const _: fn() = || {
    fn shareable<T: Send + Sync>() {}
    shareable::<System>();
    shareable::<Traced>();
    shareable::<Rays>();
    shareable::<Spot>();
    shareable::<Mapping>();
    shareable::<Jacobian>();
};
