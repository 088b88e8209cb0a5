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
/// backends, so each is made once). Keyed by the parsed configuration (`embree-mesh:0.5` and `embree-mesh:0.50`
/// are one backend) and bounded to [`BackendCache::CAPACITY`] entries, the least recently used dropped first
/// (400 mesh resolutions kept 2.2 GB of tessellations; a held-out battery, round 9): a dropped backend still
/// in use lives on in its `Arc`. The lock is held only to look up or insert.
#[derive(Default)]
pub(crate) struct BackendCache(Mutex<Vec<(String, Arc<dyn Tracer>)>>);

impl BackendCache {
    /// Backends kept per system.
    pub(crate) const CAPACITY: usize = 8;

    pub(crate) fn get(&self, system: &SequentialSystem, name: &str) -> Result<Arc<dyn Tracer>> {
        crate::system::no_nul("backend", name)?;
        let key = name.parse::<BackendConfig>().map(|c| format!("{c:?}")).unwrap_or_else(|_| name.to_string());
        // A panic while holding the lock cannot leave the list inconsistent (remove/push keep it a list).
        let mut made = self.0.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(i) = made.iter().position(|(n, _)| *n == key) {
            let hit = made.remove(i);
            let t = Arc::clone(&hit.1);
            made.push(hit); // the most recently used last
            return Ok(t);
        }
        let t = tracer_for(system, name)?;
        if made.len() >= Self::CAPACITY {
            made.remove(0);
        }
        made.push((key, Arc::clone(&t)));
        Ok(t)
    }

    /// Backends held now.
    #[cfg(test)]
    pub(crate) fn len(&self) -> usize {
        self.0.lock().unwrap_or_else(|p| p.into_inner()).len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_cache_is_keyed_by_configuration_and_bounded() {
        let sys = diffcassi::system::SequentialSystem::build(&diffcassi::presets::spec("sp").unwrap()).unwrap();
        let cache = BackendCache::default();
        let a = cache.get(&sys, "analytic").unwrap();
        let b = cache.get(&sys, "analytic-f64").unwrap();
        assert!(Arc::ptr_eq(&a, &b), "one configuration, one backend");
        for i in 0..3 * BackendCache::CAPACITY {
            cache.get(&sys, &format!("embree-user:{}", if i % 2 == 0 { "f64" } else { "none" })).unwrap();
        }
        assert_eq!(cache.len(), 3, "analytic and the two embree-user refinements");
        for i in 0..BackendCache::CAPACITY + 2 {
            cache.get(&sys, &format!("embree-mesh:{}", 20.0 + i as f64)).unwrap();
        }
        assert_eq!(cache.len(), BackendCache::CAPACITY);
        let e = cache.get(&sys, "analytic\0x").err().unwrap().to_string();
        assert!(e.contains("NUL") && e.contains("\\0x"), "{e}");
    }
}
