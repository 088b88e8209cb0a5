//! Backend and precision selection in one place: a [`BackendConfig`] (from the CLI, a config file or the
//! C++ API) builds the [`Tracer`] it names.
//!
//! ```
//! use diffcassi::tracer::BackendConfig;
//! let cfg: BackendConfig = "analytic".parse().unwrap();
//! assert_eq!(cfg.build().unwrap().name(), "analytic-f64");
//! assert!("embree-mush".parse::<BackendConfig>().is_err());
//! let mesh: BackendConfig = "embree-mesh:0.5:none".parse().unwrap();
//! assert_eq!(mesh.mesh, diffcassi::surfaces::MeshResolution::MaxSagErrorUm(0.5));
//! ```
use super::{AnalyticTracer, Tracer};
use crate::error::{Error, Result};
use crate::surfaces::MeshResolution;

/// Which tracer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Backend {
    /// Exact f64 sequential tracer.
    Analytic,
    /// The analytic tracer's SIMD lane kernel in f32 ([`crate::tracer::Precision::F32`]): a candidate of
    /// `bench tradeoff` and of the render's `--tolerance-um` only; the commands compared to Zemax refuse it.
    AnalyticF32,
    /// Embree, analytic user geometry.
    EmbreeUser,
    /// Embree, tessellated surfaces.
    EmbreeMesh,
}

/// Hit refinement for the Embree backends.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Refine {
    F64,
    None,
}

/// A backend with its precision options.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BackendConfig {
    pub backend: Backend,
    pub refine: Refine,
    /// Tessellation of `EmbreeMesh` surfaces.
    pub mesh: MeshResolution,
}

impl Default for BackendConfig {
    fn default() -> Self {
        BackendConfig { backend: Backend::Analytic, refine: Refine::F64, mesh: MeshResolution::MaxSagErrorUm(1.0) }
    }
}

impl std::str::FromStr for BackendConfig {
    type Err = Error;
    /// `analytic` (alias `analytic-f64`), `embree-user[:f64|:none]`, `embree-mesh[:SAG_UM][:f64|:none]`
    /// (defaults: f64 refinement, 1 µm chord-sag bound).
    fn from_str(text: &str) -> Result<Self> {
        let bad = |why: &str| Error::invalid(format!("backend `{text}`: {why} ({})", BackendConfig::usage()));
        let parts: Vec<&str> = text.trim().split(':').collect();
        let backend = match parts[0] {
            "analytic" | "analytic-f64" => Backend::Analytic,
            "analytic-f32" => Backend::AnalyticF32,
            "embree-user" => Backend::EmbreeUser,
            "embree-mesh" => Backend::EmbreeMesh,
            other => return Err(bad(&format!("unknown backend `{other}`"))),
        };
        let mut cfg = BackendConfig { backend, ..Default::default() };
        let mut rest = &parts[1..];
        if backend == Backend::EmbreeMesh {
            if let Some(um) = rest.first().and_then(|v| v.parse::<f64>().ok()) {
                cfg.mesh = MeshResolution::MaxSagErrorUm(um);
                rest = &rest[1..];
            }
        }
        match rest {
            [] => {}
            [r] if !matches!(backend, Backend::Analytic | Backend::AnalyticF32) => cfg.refine = r.parse()?,
            _ => return Err(bad("unexpected options")),
        }
        Ok(cfg)
    }
}

impl std::str::FromStr for Refine {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s.trim() {
            "f64" => Ok(Refine::F64),
            "none" => Ok(Refine::None),
            other => Err(Error::invalid(format!("refine `{other}`: expected f64 or none"))),
        }
    }
}

impl BackendConfig {
    /// The configuration a tracer's [`Tracer::name`] describes (what render.json records as `tracer`):
    /// `analytic-f64`, `analytic-f32`, `embree-user,refine=f64`, `embree-mesh(max-sag=1um),refine=none`,
    /// `embree-mesh(segments=64),refine=f64` (a trailing `,single`, the packet mode, changes no result), or
    /// the `--backend` text. `reconstruct` rebuilds the render's tracer from it (the Embree names did not
    /// parse and the operator was silently the analytic tracer's).
    pub fn from_tracer_name(name: &str) -> Result<Self> {
        let bad = || Error::invalid(format!("tracer `{name}` is not one diffcassi names (analytic-f64, analytic-f32, embree-user,refine=…, embree-mesh(…),refine=…)"));
        let mut parts = name.trim().split(',');
        let head = parts.next().unwrap_or("");
        let mut cfg = match head {
            "embree-user" => BackendConfig { backend: Backend::EmbreeUser, ..Default::default() },
            h if h.starts_with("embree-mesh(") && h.ends_with(')') => {
                let inner = &h["embree-mesh(".len()..h.len() - 1];
                let mesh = if let Some(n) = inner.strip_prefix("segments=") {
                    MeshResolution::Segments(n.parse().map_err(|_| bad())?)
                } else if let Some(e) = inner.strip_prefix("max-sag=").and_then(|e| e.strip_suffix("um")) {
                    MeshResolution::MaxSagErrorUm(e.parse().map_err(|_| bad())?)
                } else {
                    return Err(bad());
                };
                BackendConfig { backend: Backend::EmbreeMesh, mesh, ..Default::default() }
            }
            _ if !name.contains(',') => return name.parse(),
            _ => return Err(bad()),
        };
        for p in parts {
            match p.trim() {
                "refine=f64" => cfg.refine = Refine::F64,
                "refine=none" => cfg.refine = Refine::None,
                "single" => {}
                _ => return Err(bad()),
            }
        }
        Ok(cfg)
    }

    /// Whether this build can construct `backend` (the Embree ones need the `embree` feature).
    pub fn available(backend: Backend) -> bool {
        matches!(backend, Backend::Analytic | Backend::AnalyticF32) || cfg!(feature = "embree")
    }

    /// The backends this build can trace with, as a refusal of a backend text lists them: a build without
    /// Embree (the wheel) lists the analytic backend alone and says what the Embree ones need (round 21: the
    /// wheel's `trace(backend="warp")` offered `embree-user`, which it then refused).
    pub fn usage() -> &'static str {
        if Self::available(Backend::EmbreeUser) {
            "use analytic, embree-user[:f64|:none] or embree-mesh[:SAG_UM][:f64|:none]"
        } else {
            "use analytic; embree-user and embree-mesh need a build with Embree 4.3"
        }
    }

    /// The tracer this configuration names.
    pub fn build(&self) -> Result<Box<dyn Tracer>> {
        match self.backend {
            Backend::Analytic => Ok(Box::new(AnalyticTracer::default())),
            Backend::AnalyticF32 => crate::tracer::Precision::F32.tracer(crate::tracer::Kernel::default()),
            #[cfg(feature = "embree")]
            Backend::EmbreeUser | Backend::EmbreeMesh => {
                use super::embree::{EmbreeOptions, EmbreeTracer, Refinement};
                let refine = match self.refine {
                    Refine::F64 => Refinement::F64,
                    Refine::None => Refinement::None,
                };
                let options = if self.backend == Backend::EmbreeUser { EmbreeOptions::user(refine) } else { EmbreeOptions::mesh(self.mesh, refine) };
                Ok(Box::new(EmbreeTracer::new(options)))
            }
            #[cfg(not(feature = "embree"))]
            Backend::EmbreeUser | Backend::EmbreeMesh => Err(embree_missing(self.backend, crate::frontend::current())),
        }
    }
}

/// The refusal of an Embree backend by a build without Embree (the `embree` feature off: the Python wheel), with
/// the fix a user of `frontend` can act on. A wheel user cannot "rebuild with the default `embree` feature" (a
/// cargo instruction, round 21: Python's `trace`, `jacobian`, `mapping` and `Transport` said so); Python's text
/// is the one `diffcassi._check_backend` gives.
pub fn embree_missing(backend: Backend, frontend: crate::frontend::Frontend) -> Error {
    let name = if backend == Backend::EmbreeMesh { "embree-mesh" } else { "embree-user" };
    Error::invalid(match frontend {
        crate::frontend::Frontend::Python => format!(
            "backend `{name}`: this diffcassi was built without Embree; install Embree 4.3 (bash scripts/setup.sh) and reinstall (pip install .), or use backend='analytic'"
        ),
        _ => format!(
            "backend `{name}`: this diffcassi was built without Embree (the default `embree` feature of the Rust crate); install Embree 4.3 (bash scripts/setup.sh) and rebuild with default features, or use the analytic backend"
        ),
    })
}

#[cfg(test)]
mod tests {
    /// The refusal names a fix the caller can act on: Python's the reinstall (as `_check_backend`), never cargo's
    /// feature alone (round 21).
    #[test]
    fn embree_missing_names_each_front_ends_fix() {
        use crate::frontend::Frontend;
        let py = super::embree_missing(super::Backend::EmbreeUser, Frontend::Python).to_string();
        assert!(py.contains("backend `embree-user`: this diffcassi was built without Embree") && py.contains("pip install .") && py.contains("backend='analytic'"), "{py}");
        let cli = super::embree_missing(super::Backend::EmbreeMesh, Frontend::Cpp).to_string();
        assert!(cli.contains("backend `embree-mesh`") && cli.contains("scripts/setup.sh") && !cli.contains("pip"), "{cli}");
    }

    use super::*;

    /// An unknown backend's refusal lists what this build can trace with: the Embree backends only where they
    /// are built in (the wheel has none).
    #[test]
    fn an_unknown_backend_lists_the_backends_of_this_build() {
        let e = "warp".parse::<BackendConfig>().unwrap_err().to_string();
        assert!(e.starts_with("backend `warp`: unknown backend `warp` (use analytic"), "{e}");
        assert_eq!(e.contains("embree-user[:f64|:none]"), cfg!(feature = "embree"), "{e}");
        assert_eq!(e.contains("need a build with Embree"), !cfg!(feature = "embree"), "{e}");
    }

    /// Every configuration's tracer name (render.json's `tracer`) reads back as that configuration.
    #[test]
    fn tracer_names_read_back_as_their_configuration() {
        let mut configs = vec![BackendConfig::default()];
        if BackendConfig::available(Backend::EmbreeUser) {
            for refine in [Refine::F64, Refine::None] {
                configs.push(BackendConfig { backend: Backend::EmbreeUser, refine, ..Default::default() });
                for mesh in [MeshResolution::MaxSagErrorUm(0.1), MeshResolution::Segments(64)] {
                    configs.push(BackendConfig { backend: Backend::EmbreeMesh, refine, mesh });
                }
            }
        }
        for cfg in configs {
            let name = cfg.build().unwrap().name();
            let back = BackendConfig::from_tracer_name(&name).unwrap_or_else(|e| panic!("{name}: {e}"));
            assert_eq!(back.backend, cfg.backend, "{name}");
            if cfg.backend != Backend::Analytic {
                assert_eq!((back.refine, back.mesh), (cfg.refine, cfg.mesh), "{name}");
            }
        }
        assert_eq!(BackendConfig::from_tracer_name("analytic-f32").unwrap().backend, Backend::AnalyticF32);
        for bad in ["embree-user,refine=fast", "embree-mesh(max-sag=x),refine=f64", "raytracer", "embree-mesh(1um)"] {
            assert!(BackendConfig::from_tracer_name(bad).is_err(), "{bad}");
        }
    }
}
