//! Backend selection by name: the one place a C++ backend string becomes a [`Tracer`]. Add a backend here
//! (and to [`NAMES`]) and every bridge entry point (trace, spot, distortion, mapping) accepts it.
//!
//! ```
//! let sys = diffcassi::system::SequentialSystem::build(&diffcassi::presets::spec("sp")?)?;
//! assert_eq!(diffcassi_cpp::backend::tracer_for(&sys, "analytic")?.name(), "analytic-f64");
//! let e = diffcassi_cpp::backend::tracer_for(&sys, "embree-mesh").err().unwrap().to_string();
//! assert!(e.contains("not available"), "{e}");
//! # Ok::<(), diffcassi::Error>(())
//! ```
use diffcassi::error::{Error, Result};
use diffcassi::system::SequentialSystem;
use diffcassi::tracer::{AnalyticTracer, Tracer};
use std::sync::{Arc, Mutex};

/// Backend names accepted by the C++ API (`analytic-f64`, the tracer's own name, is an alias of `analytic`).
pub const NAMES: [&str; 3] = ["analytic", "embree-user", "embree-mesh"];

/// Make the backend `name` for `system`. Errors name the backend and list the known ones.
pub fn tracer_for(system: &SequentialSystem, name: &str) -> Result<Arc<dyn Tracer>> {
    let _ = system; // Embree backends build their scene from the system.
    match name {
        "analytic" | "analytic-f64" => Ok(Arc::new(AnalyticTracer::default())),
        // Extension point: the Embree tracer backends (issue 3) are being written; construct them here
        // (behind the `embree` feature) once `diffcassi::tracer` has them.
        "embree-user" | "embree-mesh" => Err(Error::invalid(format!(
            "backend `{name}` is not available in this build: the Embree tracer backend has not landed in diffcassi yet (available: analytic)"
        ))),
        _ => Err(Error::invalid(format!("unknown backend `{name}` (backends: {})", NAMES.join(", ")))),
    }
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
