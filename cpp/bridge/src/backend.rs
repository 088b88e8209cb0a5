//! Backend selection by name: the one place a C++ backend string becomes a [`Tracer`]. Add a backend here
//! (and to [`NAMES`]) and every bridge entry point (trace, spot, distortion, mapping) accepts it.
//!
//! ```
//! let sys = diffcassi::system::SequentialSystem::build(&diffcassi::presets::spec("sp")?)?;
//! assert_eq!(diffcassi_cpp::backend::tracer_for(&sys, "analytic")?.name(), "analytic-f64");
//! assert!(diffcassi_cpp::backend::tracer_for(&sys, "embree-mesh:0.5:none")?.name().starts_with("embree-mesh"));
//! let e = diffcassi_cpp::backend::tracer_for(&sys, "embree-mush").err().unwrap().to_string();
//! assert!(e.contains("unknown backend"), "{e}");
//! # Ok::<(), diffcassi::Error>(())
//! ```
use diffcassi::error::{Error, Result};
use diffcassi::system::SequentialSystem;
use diffcassi::tracer::{BackendConfig, Tracer};
use std::sync::{Arc, Mutex};

/// Backend names accepted by the C++ API (`analytic-f64`, the tracer's own name, is an alias of `analytic`);
/// the Embree ones take options as in `diffcassi::tracer::BackendConfig`: `embree-user[:f64|:none]`,
/// `embree-mesh[:SAG_UM][:f64|:none]`.
pub const NAMES: [&str; 3] = ["analytic", "embree-user", "embree-mesh"];

/// Make the backend `name` for `system` (the Embree backends build their scene from it on first use).
/// Errors name the backend and list the known ones.
pub fn tracer_for(system: &SequentialSystem, name: &str) -> Result<Arc<dyn Tracer>> {
    let _ = system;
    let cfg: BackendConfig = name.parse().map_err(|e: Error| Error::invalid(format!("{e}; backends: {}", NAMES.join(", "))))?;
    if cfg.backend == diffcassi::tracer::Backend::AnalyticF32 {
        // The bridge's entry points (trace, spot, distortion, mapping) are compared to Zemax: f64 only.
        return Err(Error::invalid(format!("backend `{name}`: the C++ API traces in f64 (the f32 kernel is the renderer's --precision f32); backends: {}", NAMES.join(", "))));
    }
    Ok(Arc::from(cfg.build()?))
}

/// Backends made so far for one system, shared by all threads (construction can be costly for mesh
/// backends, so each is made once). The lock is held only to look up or insert.
#[derive(Default)]
pub(crate) struct BackendCache(Mutex<Vec<(String, Arc<dyn Tracer>)>>);

impl BackendCache {
    pub(crate) fn get(&self, system: &SequentialSystem, name: &str) -> Result<Arc<dyn Tracer>> {
        // A panic while holding the lock cannot leave the list inconsistent (push is the only mutation).
        let mut made = self.0.lock().unwrap_or_else(|p| p.into_inner());
        if let Some((_, t)) = made.iter().find(|(n, _)| n == name) {
            return Ok(Arc::clone(t));
        }
        let t = tracer_for(system, name)?;
        made.push((name.to_string(), Arc::clone(&t)));
        Ok(t)
    }
}
