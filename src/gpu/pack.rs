//! The traced system and a ray batch as the kernels read them: `repr(C)` twins of `dc_step` and `dc_batch`
//! in `src/gpu/kernels/dc_trace.h` (their sizes are checked against the C compiler's at run time by the
//! tests), built from a [`SequentialSystem`]'s path and its per-wavelength index tables.
use crate::error::{Error, Result};
use crate::surfaces::{Aperture, SurfaceShape};
use crate::spec::MaskSampling;
use crate::system::{MaskSurface, SequentialSystem};

/// Shape codes (`DC_SHAPE_*`).
const SHAPE_PLANE: u32 = 0;
const SHAPE_CONIC: u32 = 1;
const SHAPE_ASPHERE: u32 = 2;
const SHAPE_PARAXIAL: u32 = 3;
const SHAPE_TOROIDAL: u32 = 4;
/// Aperture codes (`DC_APERTURE_*`).
const APERTURE_NONE: u32 = 0;
const APERTURE_CIRCULAR: u32 = 1;
const APERTURE_RECTANGULAR: u32 = 2;
const APERTURE_OBSCURATION: u32 = 3;
/// Interaction codes (`DC_INTERACTION_*`).
const INTERACTION_REFRACT: u32 = 0;
const INTERACTION_REFLECT: u32 = 1;
const INTERACTION_GRATING: u32 = 2;
const INTERACTION_GRATING_REFLECT: u32 = 3;
/// `DC_MAX_COEF`: even-asphere terms r² … r¹⁶ (a toroid's y² … y¹⁶) — every term the spec allows
/// ([`crate::limits::MAX_ASPHERE_TERMS`]; a different `DC_MAX_COEF` would change `dc_step`'s size, which
/// `ffi::layouts_match` checks).
pub(crate) const MAX_COEF: usize = crate::limits::MAX_ASPHERE_TERMS;

/// One surface of the path (`dc_step`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Step {
    /// Rotation into the local frame, by columns (glam's `DMat3::to_cols_array`).
    pub rotation: [f64; 9],
    /// The local frame's origin in the previous frame, mm.
    pub offset: [f64; 3],
    pub curvature: f64,
    pub conic: f64,
    pub focal_length: f64,
    pub aperture: [f64; 4],
    pub coef: [f64; MAX_COEF],
    /// A toroid's 1/(radius of rotation), 1/mm (0: a cylinder).
    pub rotation_curvature: f64,
    /// A grating's lines per µm and diffraction order.
    pub grating_lines_per_um: f64,
    pub grating_order: f64,
    pub shape: u32,
    pub aperture_kind: u32,
    pub surface: u32,
    pub n_coef: u32,
    /// `DC_INTERACTION_*`: refract, reflect at a mirror, or diffract at a grating (transmissive or reflective).
    pub interaction: u32,
    /// A grating's wavelength slot in the index row ([`crate::system::Interaction::Grating`]).
    pub wavelength_slot: u32,
}

/// A batch in structure-of-arrays form (`dc_batch`): borrowed pointers, valid for one call.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub(crate) struct Batch {
    pub path: *const Step,
    pub tables: *const f64,
    pub table_of_ray: *const u32,
    pub ox: *const f64,
    pub oy: *const f64,
    pub oz: *const f64,
    pub dx: *const f64,
    pub dy: *const f64,
    pub dz: *const f64,
    pub x: *mut f64,
    pub y: *mut f64,
    pub z: *mut f64,
    pub ux: *mut f64,
    pub uy: *mut f64,
    pub uz: *mut f64,
    pub status: *mut u8,
    pub surface: *mut u32,
    pub n_rays: u64,
    pub n_steps: u32,
    pub n_surfaces: u32,
}

/// The system's traced path as kernel steps (a coded-mask surface is a plain step: its mask weights a render's
/// rays through [`SurfaceMask`], not the trace).
pub(crate) fn steps(system: &SequentialSystem) -> Result<Vec<Step>> {
    pack_steps(&system.path)
}

/// Ray aiming's path (`dc_landing_batch::aim_path`, [`crate::rays::aim::stop_crossing`]): the steps before the
/// stop with their apertures open (`StopProbe::open_path`), then the stop's probe (its figure, intersection
/// only); empty with ray aiming off. The count of steps before the stop is `len − 1` (`dc_aim::aim_steps`).
pub(crate) fn aim_path(system: &SequentialSystem) -> Result<Vec<Step>> {
    if system.spec.ray_aiming == crate::spec::RayAiming::Off {
        return Ok(Vec::new());
    }
    let probe = &system.stop_probe;
    if probe.steps > system.path.len() {
        return Err(Error::invalid(format!("system `{}`: ray aiming has no stop to aim at on the traced path (GPU kernels)", system.name())));
    }
    let before = probe.open_path.as_deref().unwrap_or(&system.path[..probe.steps]);
    let mut out = pack_steps(before)?;
    out.extend(pack_steps(std::slice::from_ref(&probe.probe))?);
    Ok(out)
}

/// Path steps as kernel steps.
fn pack_steps(path: &[crate::system::PathStep]) -> Result<Vec<Step>> {
    path
        .iter()
        .map(|s| {
            // The kernels (dc_trace_tmpl.h, the C twin of tracer::kernel) refract, reflect (a mirror, dc_reflect)
            // or diffract into the grating's order (dc_grating_step, the vector grating equation of
            // surfaces::grating), on every shape of SurfaceShape (a Toroidal surface: dc_toroid_local).
            let mut step = Step { rotation: s.rotation.to_cols_array(), offset: s.offset.to_array(), surface: s.surface as u32, ..Step::default() };
            step.interaction = match s.interaction {
                crate::system::Interaction::Refract => INTERACTION_REFRACT,
                crate::system::Interaction::Reflect => INTERACTION_REFLECT,
                crate::system::Interaction::Grating { grating, reflective, wavelength_slot } => {
                    step.grating_lines_per_um = grating.lines_per_um;
                    step.grating_order = grating.order;
                    step.wavelength_slot = u32::try_from(wavelength_slot).map_err(|_| Error::invalid(format!("surface {}: grating wavelength slot {wavelength_slot} exceeds u32", s.surface)))?;
                    if reflective {
                        INTERACTION_GRATING_REFLECT
                    } else {
                        INTERACTION_GRATING
                    }
                }
            };
            match &s.shape {
                SurfaceShape::Plane => step.shape = SHAPE_PLANE,
                SurfaceShape::Conic { curvature, conic } => {
                    step.shape = SHAPE_CONIC;
                    step.curvature = *curvature;
                    step.conic = *conic;
                }
                SurfaceShape::EvenAsphere { curvature, conic, coefficients } => {
                    if coefficients.len() > MAX_COEF {
                        return Err(Error::invalid(format!(
                            "surface {}: {} even-asphere terms; the GPU kernels take at most {MAX_COEF} (the spec's limit)",
                            s.surface,
                            coefficients.len()
                        )));
                    }
                    step.shape = SHAPE_ASPHERE;
                    step.curvature = *curvature;
                    step.conic = *conic;
                    step.coef[..coefficients.len()].copy_from_slice(coefficients);
                    step.n_coef = coefficients.len() as u32;
                }
                SurfaceShape::Paraxial { focal_length } => {
                    step.shape = SHAPE_PARAXIAL;
                    step.focal_length = *focal_length;
                }
                SurfaceShape::Toroidal { curvature, conic, coefficients, rotation_curvature } => {
                    if coefficients.len() > MAX_COEF {
                        return Err(Error::invalid(format!("surface {}: {} Toroidal terms; the GPU kernels take at most {MAX_COEF} (the spec's limit)", s.surface, coefficients.len())));
                    }
                    step.shape = SHAPE_TOROIDAL;
                    step.curvature = *curvature;
                    step.conic = *conic;
                    step.rotation_curvature = *rotation_curvature;
                    step.coef[..coefficients.len()].copy_from_slice(coefficients);
                    step.n_coef = coefficients.len() as u32;
                }
            }
            match s.aperture {
                Aperture::None => step.aperture_kind = APERTURE_NONE,
                Aperture::Circular { semi_diameter_mm, min_radius_mm, decenter_x_mm, decenter_y_mm } => {
                    step.aperture_kind = APERTURE_CIRCULAR;
                    step.aperture = [semi_diameter_mm, min_radius_mm, decenter_x_mm, decenter_y_mm];
                }
                Aperture::Rectangular { half_width_x_mm, half_width_y_mm, decenter_x_mm, decenter_y_mm } => {
                    step.aperture_kind = APERTURE_RECTANGULAR;
                    step.aperture = [half_width_x_mm, half_width_y_mm, decenter_x_mm, decenter_y_mm];
                }
                // dc_aperture_contains's DC_APERTURE_OBSCURATION: the closed annulus blocks (Aperture::contains).
                Aperture::CircularObscuration { min_radius_mm, max_radius_mm, decenter_x_mm, decenter_y_mm } => {
                    step.aperture_kind = APERTURE_OBSCURATION;
                    step.aperture = [min_radius_mm, max_radius_mm, decenter_x_mm, decenter_y_mm];
                }
            }
            Ok(step)
        })
        .collect()
}

/// Index tables: one row of [`SequentialSystem::indices`] per distinct wavelength (the index after each
/// surface, then the wavelength itself in a system with gratings), in first-seen order, and each ray's row.
pub(crate) struct IndexTables {
    pub tables: Vec<f64>,
    pub table_of_ray: Vec<u32>,
    /// The length of a row (the batch's `n_surfaces` stride).
    pub n_surfaces: usize,
}

pub(crate) fn index_tables(system: &SequentialSystem, wavelengths_nm: &[f64]) -> Result<IndexTables> {
    let n_surfaces = system.surfaces.len() + usize::from(system.has_grating());
    let mut rows: std::collections::HashMap<u64, u32> = std::collections::HashMap::new();
    let mut tables = Vec::new();
    let mut table_of_ray = Vec::with_capacity(wavelengths_nm.len());
    for &w in wavelengths_nm {
        let row = match rows.get(&w.to_bits()) {
            Some(&r) => r,
            None => {
                let n = system.indices(w)?;
                debug_assert_eq!(n.len(), n_surfaces);
                let r = rows.len() as u32;
                tables.extend_from_slice(&n);
                rows.insert(w.to_bits(), r);
                r
            }
        };
        table_of_ray.push(row);
    }
    Ok(IndexTables { tables, table_of_ray, n_surfaces })
}

/// The sampler's constants (`dc_sampler`).
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub(crate) struct Sampler {
    pub seed: u64,
    pub rays: u32,
    pub mode: u32,
    pub grid_a: u32,
    pub grid_b: u32,
}

/// The paraxial pupil aim (`dc_aim`).
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub(crate) struct Aim {
    pub scale: f64,
    pub sin_marginal: f64,
    pub magnification_sign: f64,
    pub distance_mm: f64,
    pub telecentric: u32,
    /// 1: the object is at infinity (`PupilAim::at_infinity`; fields are angles, rad).
    pub at_infinity: u32,
    /// Ray aiming (`rays::aimed_ray`): the stop radius it aims at (`SequentialSystem::aim_stop_radius_mm`),
    /// 1 when on (paraxial or real), and the steps before the stop in the launch's aim path.
    pub stop_radius_mm: f64,
    pub aiming: u32,
    pub aim_steps: u32,
}

/// The coded mask on a surface inside the system (`dc_surface_mask`, dual-disperser CASSI): its pattern and where
/// it lies on the path. A null `values` (the [`Default`]) is no mask surface.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub(crate) struct SurfaceMask {
    /// `height × width` transmissions, row-major (host or device memory).
    pub values: *const f32,
    pub pitch_mm: f64,
    pub height: u32,
    pub width: u32,
    /// Its step on the traced path ([`MaskSurface::step`]).
    pub step: u32,
    /// [`MaskSampling`]: 0 nearest, 1 bilinear.
    pub bilinear: u32,
}

impl Default for SurfaceMask {
    fn default() -> Self {
        SurfaceMask { values: std::ptr::null(), pitch_mm: 0.0, height: 0, width: 0, step: 0, bilinear: 0 }
    }
}

/// The kernels' [`SurfaceMask`] of a `height × width` mask on `surface`, its values at `values` (a pointer of the
/// memory the kernels read: host or device). Its step is an index of the path, as `n_steps` a u32.
pub(crate) fn surface_mask(surface: &MaskSurface, height: u32, width: u32, values: *const f32) -> SurfaceMask {
    SurfaceMask { values, pitch_mm: surface.pitch_mm, height, width, step: surface.step as u32, bilinear: (surface.sampling == MaskSampling::Bilinear) as u32 }
}

/// A mask's size as the kernels' u32 (`dc_surface_mask`), or an error naming it.
pub(crate) fn mask_size(height: usize, width: usize) -> Result<(u32, u32)> {
    let too_big = |what: &str, v: usize| Error::invalid(format!("GPU kernels: coded mask {what} = {v} exceeds u32"));
    Ok((u32::try_from(height).map_err(|_| too_big("height", height))?, u32::try_from(width).map_err(|_| too_big("width", width))?))
}

/// Scene and detector geometry (`dc_scene`).
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub(crate) struct Scene {
    pub scene_pitch_mm: f64,
    pub detector_x_left_mm: f64,
    pub detector_y_top_mm: f64,
    pub detector_pitch_mm: f64,
    pub scene_height: u32,
    pub scene_width: u32,
}

/// One plane's landing launch (`dc_landing_batch`).
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub(crate) struct LandingBatch {
    pub path: *const Step,
    pub n: *const f64,
    pub pixels: *const u32,
    /// Ray aiming's steps to the stop and its probe ([`aim_path`]); unread with aiming off.
    pub aim_path: *const Step,
    pub u: *mut f64,
    pub v: *mut f64,
    pub status: *mut u8,
    /// Each ray's coded-mask transmission where it crossed the mask surface (null: not written).
    pub w: *mut f64,
    pub surface_mask: SurfaceMask,
    pub sampler: Sampler,
    pub aim: Aim,
    pub scene: Scene,
    pub plane: u64,
    pub n_pixels: u64,
    pub max_coord_mm: f64,
    pub n_steps: u32,
    pub pad: u32,
}

/// One open pixel's footprint window (`dc_window`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Window {
    pub x0: i64,
    pub y0: i64,
    pub w: u32,
    pub h: u32,
    pub off_detector: f64,
}

/// One plane's deposit launch (`dc_deposit_batch`, src/gpu/kernels/dc_accum.h).
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub(crate) struct DepositBatch {
    pub land: LandingBatch,
    pub cube: *const f32,
    pub mask: *const f32,
    pub image: *mut u64,
    pub fixed_scale: f64,
    pub det_w: i64,
    pub det_h: i64,
    pub bands: u32,
    pub k0: u32,
    pub k1: u32,
    pub tw: f32,
    /// 1: the renderer's f32 trace, 0: f64.
    pub f32: u32,
}

/// One plane's Airy gather into its band (`dc_airy_batch`).
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub(crate) struct AiryBatch {
    pub image: *const u64,
    pub band: *mut f64,
    pub taps: *const f32,
    pub det_w: i64,
    pub det_h: i64,
    pub half: i64,
    pub unit: f64,
    pub weight: f64,
}
