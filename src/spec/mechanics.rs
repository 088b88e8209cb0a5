//! The optional `[mechanics]` section of a spec: mounts generated from the system (a lens tube per lens
//! group, the prism holder, the detector housing, a baffle) and user meshes (STL, OBJ) placed by a
//! transform, each absorbing or Lambertian-scattering. Built into geometry by [`crate::mechanics`].
//!
//! ```toml
//! [mechanics]
//! generate = true                     # the generated mounts (default true)
//! resolution = "medium"               # coarse | medium | fine: ≈ 10³, 10⁴, 10⁵ triangles on SP
//! surface = { model = "lambertian", reflectance = 0.04 }   # of the generated mounts (default absorbing)
//!
//! [[mechanics.meshes]]
//! path = "bracket.stl"                # relative to the spec file (or the working directory for presets)
//! translate_mm = [0.0, 12.0, 40.0]
//! rotate_deg = [0.0, 0.0, 90.0]       # about x, then y, then z (Zemax's tilt order)
//! scale = 1.0                         # file units → mm
//! surface = { model = "absorbing" }
//! closed = true                       # the mesh must enclose a solid (default true)
//! ```
use serde::{Deserialize, Serialize};

/// What a mechanical surface does to a ray that reaches it. Read from `{ model = "absorbing" }` or
/// `{ model = "lambertian", reflectance = 0.3 }`: any other key, and a `reflectance` on an absorber (which
/// would be ignored), is an error naming it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(tag = "model", rename_all = "snake_case", try_from = "SurfaceModelRepr")]
pub enum SurfaceModel {
    /// Absorbs every ray (a black mount).
    #[default]
    Absorbing,
    /// Scatters a fraction `reflectance` ∈ [0, 1] of the energy into a cosine (Lambertian) lobe about the
    /// normal on the side the ray came from; the rest is absorbed.
    Lambertian { reflectance: f64 },
}

/// The table a [`SurfaceModel`] is read from (serde's tagged enums let a unit variant ignore unknown keys,
/// so the model is read as a plain table and checked).
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SurfaceModelRepr {
    model: String,
    reflectance: Option<f64>,
}

impl TryFrom<SurfaceModelRepr> for SurfaceModel {
    type Error = String;
    fn try_from(r: SurfaceModelRepr) -> Result<Self, String> {
        match (r.model.as_str(), r.reflectance) {
            ("absorbing", None) => Ok(SurfaceModel::Absorbing),
            ("absorbing", Some(x)) => Err(format!("surface model `absorbing` takes no `reflectance` (got {x}: it would be ignored, an absorber reflects nothing); use model = \"lambertian\" for a scattering surface")),
            ("lambertian", Some(x)) => Ok(SurfaceModel::Lambertian { reflectance: x }),
            ("lambertian", None) => Err("surface model `lambertian` needs `reflectance` (in [0, 1])".to_string()),
            (m, _) => Err(format!("unknown surface model `{m}`: expected `absorbing` or `lambertian`")),
        }
    }
}

impl SurfaceModel {
    /// The reflectance (0 for an absorber).
    pub fn reflectance(&self) -> f64 {
        match self {
            SurfaceModel::Absorbing => 0.0,
            SurfaceModel::Lambertian { reflectance } => *reflectance,
        }
    }
}

/// Triangle budget of the generated mounts.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MechanicsResolution {
    /// ≈ 10³ triangles on SP.
    #[default]
    Coarse,
    /// ≈ 10⁴ triangles on SP.
    Medium,
    /// ≈ 10⁵ triangles on SP.
    Fine,
}

impl MechanicsResolution {
    /// Polygon vertices around a tube or sleeve (the other subdivisions follow from it).
    pub fn segments(&self) -> usize {
        match self {
            MechanicsResolution::Coarse => 16,
            MechanicsResolution::Medium => 48,
            MechanicsResolution::Fine => 152,
        }
    }
}

fn yes() -> bool {
    true
}
fn is_true(v: &bool) -> bool {
    *v
}
fn one() -> f64 {
    1.0
}
fn is_one(v: &f64) -> bool {
    *v == 1.0
}
fn is_zero3(v: &[f64; 3]) -> bool {
    *v == [0.0; 3]
}
fn is_default<T: Default + PartialEq>(v: &T) -> bool {
    *v == T::default()
}

/// A user mesh placed in the system's global frame: `p' = R · (scale · p) + translate_mm`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MeshPartSpec {
    /// STL (binary or ASCII) or OBJ file, relative to the spec file.
    pub path: String,
    #[serde(default, skip_serializing_if = "is_zero3")]
    pub translate_mm: [f64; 3],
    /// Rotation about x, then y, then z, degrees.
    #[serde(default, skip_serializing_if = "is_zero3")]
    pub rotate_deg: [f64; 3],
    /// Uniform scale (file units to mm), non-zero.
    #[serde(default = "one", skip_serializing_if = "is_one")]
    pub scale: f64,
    #[serde(default, skip_serializing_if = "is_default")]
    pub surface: SurfaceModel,
    /// Require a closed solid (every edge shared by exactly two triangles).
    #[serde(default = "yes", skip_serializing_if = "is_true")]
    pub closed: bool,
}

/// The `[mechanics]` section.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MechanicsSpec {
    /// Generate the mounts from the system.
    #[serde(default = "yes", skip_serializing_if = "is_true")]
    pub generate: bool,
    #[serde(default, skip_serializing_if = "is_default")]
    pub resolution: MechanicsResolution,
    /// Surface model of the generated mounts.
    #[serde(default, skip_serializing_if = "is_default")]
    pub surface: SurfaceModel,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub meshes: Vec<MeshPartSpec>,
}

impl Default for MechanicsSpec {
    fn default() -> Self {
        MechanicsSpec { generate: true, resolution: MechanicsResolution::default(), surface: SurfaceModel::default(), meshes: Vec::new() }
    }
}

fn check_surface(at: &str, s: &SurfaceModel) -> Result<(), String> {
    if let SurfaceModel::Lambertian { reflectance } = s {
        if !(reflectance.is_finite() && (0.0..=1.0).contains(reflectance)) {
            return Err(format!("{at}.surface.reflectance = {reflectance}: must be in [0, 1]"));
        }
    }
    Ok(())
}

impl MechanicsSpec {
    /// Field checks; `Err` names the field (`mechanics.meshes[1].scale = 0: ...`).
    pub fn validate(&self) -> Result<(), String> {
        check_surface("mechanics", &self.surface)?;
        for (i, m) in self.meshes.iter().enumerate() {
            let at = format!("mechanics.meshes[{i}]");
            if m.path.trim().is_empty() {
                return Err(format!("{at}.path: empty"));
            }
            if !(m.scale.is_finite() && (1e-6..=1e6).contains(&m.scale.abs())) {
                return Err(format!(
                    "{at}.scale = {}: must be finite with 1e-6 ≤ |scale| ≤ 1e6 (file units → mm: 1e-6 for a file in nm, 1e6 for one in km)",
                    crate::limits::fmt_num(m.scale)
                ));
            }
            for (k, v) in m.translate_mm.iter().enumerate() {
                if !(v.is_finite() && v.abs() <= crate::limits::MAX_LENGTH_MM) {
                    return Err(format!("{at}.translate_mm[{k}] = {v}: must be finite and within ±{} mm", crate::limits::MAX_LENGTH_MM));
                }
            }
            for (k, v) in m.rotate_deg.iter().enumerate() {
                if !(v.is_finite() && v.abs() <= crate::limits::MAX_TILT_DEG) {
                    return Err(format!("{at}.rotate_deg[{k}] = {v}: must be finite and within ±{}°", crate::limits::MAX_TILT_DEG));
                }
            }
            check_surface(&at, &m.surface)?;
        }
        if !self.generate && self.meshes.is_empty() {
            return Err("mechanics: `generate = false` and no meshes: the section describes nothing (remove it)".into());
        }
        Ok(())
    }
}
