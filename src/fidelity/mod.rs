//! Speed against accuracy: measure what each backend and model costs and how far it is from the exact
//! analytic f64 tracer, and pick the cheapest one that meets a tolerance ("model only what a scene
//! requires").
//!
//! * [`measure`]: image-plane error against the reference ([`ErrorStats`]), throughput, the candidate
//!   configurations.
//! * [`workload`]: the fixed, seeded ray sets ([`RaySetSpec`]).
//! * [`tradeoff`]: `diffcassi bench tradeoff`, the speed/accuracy frontier (CSV, table, plot).
//! * [`select`]: `--tolerance-um`: calibrate the candidates on the job's own system and wavelengths,
//!   choose, explain; [`cache`] keeps calibrations.
//! * [`render_tracing`]: a render's tracer, rays per pixel and precision, given or chosen for a tolerance
//!   (what every front end resolves before it renders).
//!
//! ```
//! use diffcassi::prelude::*;
//! use diffcassi::fidelity::{calibrate_backends, choose_backend, CacheOptions};
//! let sys = SequentialSystem::build(&presets::spec("sp")?)?;
//! let (cal, _) = calibrate_backends(&sys, &[450.0, 650.0], &CacheOptions::none())?;
//! let choice = choose_backend(&cal, 1.0, 100_000)?;
//! assert!(choice.error_um <= 1.0);
//! println!("{}", choice.explanation);
//! # Ok::<(), diffcassi::Error>(())
//! ```
pub mod cache;
pub mod measure;
pub mod render_tracing;
pub mod select;
pub mod tradeoff;
pub mod workload;

pub use measure::{backend_text, candidate_configs, describe, ErrorAccumulator, ErrorStats, Measured};
pub use render_tracing::{RenderTracing, TracerSource};
pub use select::*;
pub use tradeoff::{mapping_error, run_tradeoff, TradeoffOptions, TradeoffRow};
pub use workload::RaySetSpec;
