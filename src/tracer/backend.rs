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
        let bad = |why: &str| Error::invalid(format!("backend `{text}`: {why} (use analytic, embree-user[:f64|:none] or embree-mesh[:SAG_UM][:f64|:none])"));
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
    /// Whether this build can construct `backend` (the Embree ones need the `embree` feature).
    pub fn available(backend: Backend) -> bool {
        matches!(backend, Backend::Analytic | Backend::AnalyticF32) || cfg!(feature = "embree")
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
            Backend::EmbreeUser | Backend::EmbreeMesh => {
                Err(Error::invalid("the Embree backends are not in this build (rebuild with the default `embree` feature)"))
            }
        }
    }
}
