//! [`DiffSystem`]: a built system plus the derivatives of everything the per-ray kernel reads — path-step
//! rotations and offsets, surface figures, refractive indices — with respect to the free parameters.
//!
//! How the system-level derivatives are obtained (forward mode with [`super::dual::Dn`], replaying
//! [`SequentialSystem::build`] in the same order):
//! - **Frames**: the vertex frames are composed exactly as the build does (Coordinate Break
//!   R·Rx(a)·Ry(b)·Rz(c) after a decenter for order 0, the reverse for order 1; thickness along the new z),
//!   so δR and δo follow from the chain rule; a path step's (R_toᵀ R_from, R_fromᵀ(o_to − o_from)) too.
//! - **Pickups**: value = scale·source + offset ⇒ δvalue = scale·δsource (recursively, through chains).
//! - **Chief-ray solves**: the solved value s(θ) is the root of g(s, θ) = 0, g the chief ray's coordinate
//!   in the new frame (its x, y at the new origin for decenters; its direction's y, x components for the
//!   tilts). By the implicit function theorem ds/dθ = −(∂g/∂θ)/(∂g/∂s). The root has a closed form
//!   (the decenter is the crossing point, the tilts are atan2 of the direction), and differentiating that
//!   closed form gives exactly −g_θ/g_s; ∂g/∂θ comes from tracing the primary chief ray with tangents
//!   through the surfaces placed so far (the same per-ray kernel), from an object ray whose direction
//!   moves with the paraxial entrance pupil (its y–nu trace is differentiated too). For an object at
//!   infinity the chief ray's direction is (tan θx, tan θy, 1) and its start on surface 1's vertex plane,
//!   (−tan θx·z_p, −tan θy·z_p, 0), moves with the pupil distance z_p. The traced field itself moves when the
//!   spec gives it in another unit: an angle θ on a finite object is the height −z_p·tan θ, a paraxial image
//!   height h is h/k (finite object) or the angle atan(h/k) (at infinity), k the paraxial chief ray's image
//!   height per unit field (its y–nu trace through every surface, differentiated); those tangents enter the
//!   chief ray's start and direction ([`DiffSystem::first_field`]). Real image heights are refused (the
//!   build does not solve a break for them either).
//! - **Indices**: a model glass's n(λ; n_d, V_d) is differentiated analytically; dn/dλ of catalogue
//!   glasses comes from [`super::dispersion`]. Chief-ray solves use the primary wavelength, so the ray
//!   wavelength parameter does not move them.
use super::dual::*;
use super::glass_model::CauchyGlass;
use super::hit::ShapeTangent;
use super::kernel::{trace_tangents, StepTangent};
use super::param::{Param, ParamSet};
use crate::error::{Error, Result};
use crate::materials::Medium;
use crate::spec::{Driver, FieldType, RayAiming, SurfaceKind, SystemSpec};
use crate::system::SequentialSystem;
use glam::{DMat3, DVec3};
use std::collections::{BTreeMap, HashMap};

const CB_COLUMNS: [&str; 5] = ["decenter_x_mm", "decenter_y_mm", "tilt_x_deg", "tilt_y_deg", "tilt_z_deg"];

/// A system with the derivatives of its geometry and media with respect to free parameters.
#[derive(Clone, Debug)]
pub struct DiffSystem {
    /// The traceable system at the current parameter values.
    pub system: SequentialSystem,
    pub params: Vec<Param>,
    /// One per `system.path` step.
    pub(crate) steps: Vec<StepTangent>,
    /// δR, δo of the image surface's frame (global), per parameter.
    pub image_rotation_tangent: Vec<DMat3>,
    pub image_origin_tangent: Vec<DVec3>,
    /// Derivative of every resolved numeric cell (surface → column → per-parameter tangent), including
    /// pickups and chief-ray solves.
    pub cell_tangents: Vec<BTreeMap<String, Vec<f64>>>,
    models: BTreeMap<String, CauchyGlass>,
}

/// A frame with dual entries.
#[derive(Clone)]
struct DFrame {
    o: V3,
    r: M3,
}

impl DFrame {
    fn identity(k: usize) -> Self {
        DFrame { o: v3_const(DVec3::ZERO, k), r: m3_const(DMat3::IDENTITY, k) }
    }
    fn point_to_local(&self, p: &V3) -> V3 {
        m3_mul_v3(&m3_transpose(&self.r), &v3_sub(p, &self.o))
    }
    fn point_to_global(&self, p: &V3) -> V3 {
        v3_add(&self.o, &m3_mul_v3(&self.r, p))
    }
    fn advanced(&self, t: &Dn) -> Self {
        DFrame { o: v3_add(&self.o, &v3_scale(&m3_col(&self.r, 2), t)), r: self.r.clone() }
    }
}

fn deg(v: &Dn) -> Dn {
    v.scale(std::f64::consts::PI / 180.0)
}
fn to_deg(v: &Dn) -> Dn {
    v.scale(180.0 / std::f64::consts::PI)
}

/// [`crate::geometry::coordinate_break_frame`] with duals (lengths mm, angles radians).
fn cb_frame(f: &DFrame, dx: &Dn, dy: &Dn, a: &Dn, b: &Dn, c: &Dn, order: u8) -> DFrame {
    let k = dx.k();
    let dec = [dx.clone(), dy.clone(), Dn::constant(0.0, k)];
    if order == 0 {
        let o = f.point_to_global(&dec);
        DFrame { o, r: m3_mul(&f.r, &m3_mul(&m3_mul(&rot_x(a), &rot_y(b)), &rot_z(c))) }
    } else {
        let r = m3_mul(&f.r, &m3_mul(&m3_mul(&rot_z(c), &rot_y(b)), &rot_x(a)));
        DFrame { o: v3_add(&f.o, &m3_mul_v3(&r, &dec)), r }
    }
}

/// The chief-ray solve of a break (mirror of the build's closed form) with duals; values mm / degrees.
fn solve_break(p: &V3, d: &V3, v: &[Dn; 5], solved: [bool; 5], order: u8) -> [Dn; 5] {
    let k = p[0].k();
    let mut v = v.clone();
    if order == 0 {
        if solved[0] {
            v[0] = p[0].clone();
        }
        if solved[1] {
            v[1] = p[1].clone();
        }
        if solved[2] {
            v[2] = to_deg(&(-&d[1]).atan2(&d[2]));
        }
        if solved[3] {
            let d1 = m3_mul_v3(&m3_transpose(&rot_x(&deg(&v[2]))), d);
            v[3] = to_deg(&d1[0].atan2(&d1[2]));
        }
        if solved[4] {
            v[4] = Dn::constant(0.0, k);
        }
    } else {
        let dz = m3_mul_v3(&m3_transpose(&rot_z(&deg(&v[4]))), d);
        if solved[3] {
            let h = (&(&dz[1] * &dz[1]) + &(&dz[2] * &dz[2])).sqrt();
            v[3] = to_deg(&dz[0].atan2(&h));
        }
        let d2 = m3_mul_v3(&m3_transpose(&rot_y(&deg(&v[3]))), &dz);
        if solved[2] {
            v[2] = to_deg(&(-&d2[1]).atan2(&d2[2]));
        }
        if solved[4] {
            v[4] = Dn::constant(0.0, k);
        }
        let r = m3_mul(&m3_mul(&rot_z(&deg(&v[4])), &rot_y(&deg(&v[3]))), &rot_x(&deg(&v[2])));
        let rt = m3_transpose(&r);
        let (mut pr, dr) = (m3_mul_v3(&rt, p), m3_mul_v3(&rt, d));
        if dr[2].v != 0.0 {
            let s = &pr[2] / &dr[2];
            pr = v3_sub(&pr, &v3_scale(&dr, &s));
        }
        if solved[0] {
            v[0] = pr[0].clone();
        }
        if solved[1] {
            v[1] = pr[1].clone();
        }
    }
    v
}

/// Per surface, per column: a cell's tangent (`None` while it depends on a chief-ray solve not placed yet).
type CellTangents = [HashMap<String, Option<Vec<f64>>>];

/// Cell `col` of surface `i` as a dual: its resolved value with its tangent, or constant while it has none
/// (or no such cell: value 0).
fn cell_dual(spec: &SystemSpec, dcell: &CellTangents, i: usize, col: &str, kk: usize) -> Dn {
    let value = spec.surfaces[i].cell(col).map(|c| c.value).unwrap_or(0.0);
    match dcell[i].get(col) {
        Some(Some(d)) => Dn::new(value, d.clone()),
        _ => Dn::constant(value, kk),
    }
}

/// The build's paraxial y–nu trace at the primary wavelength ([`crate::system::paraxial`]) with duals: per
/// surface OpticStudio's signed index after it (each mirror flips the sign after it), its paraxial power
/// (c + 2α₁ times the index step, or n′/f for a paraxial lens; 0 for a break) and the thickness the trace uses
/// after it ([`SystemSpec::traced_thickness`]).
struct Paraxial {
    n: Vec<Dn>,
    power: Vec<Dn>,
    thickness: Vec<Dn>,
}

impl Paraxial {
    fn new(ds: &DiffSystem, dcell: &CellTangents, n: &[f64], dn: &[f64]) -> Paraxial {
        let kk = ds.k();
        let spec = &ds.system.spec;
        let dual = |i: usize, col: &str| cell_dual(spec, dcell, i, col, kk);
        let signs: Vec<f64> = spec.surfaces.iter().scan(1.0, |sg, s| {
            if s.is_mirror() {
                *sg = -*sg;
            }
            Some(*sg)
        }).collect();
        let nd: Vec<Dn> = (0..spec.surfaces.len()).map(|i| Dn::new(n[i], dn[i * kk..(i + 1) * kk].to_vec()).scale(signs[i])).collect();
        let power = |i: usize| -> Dn {
            let s = &spec.surfaces[i];
            match s.kind {
                SurfaceKind::Standard | SurfaceKind::EvenAsphere | SurfaceKind::DiffractionGrating | SurfaceKind::Toroidal => {
                    let c = match ds.params.iter().position(|p| *p == Param::Curvature { surface: i }) {
                        Some(k) => Dn::seed(s.radius_mm.as_ref().map(|r| 1.0 / r.value).unwrap_or(0.0), kk, k),
                        None if s.radius_mm.is_some() => dual(i, "radius_mm").recip(),
                        None => Dn::constant(0.0, kk),
                    };
                    let c = if matches!(s.kind, SurfaceKind::EvenAsphere | SurfaceKind::Toroidal) && !s.asphere_coefficients.is_empty() { &c + &dual(i, "asphere_1").scale(2.0) } else { c };
                    &c * &(&nd[i] - &nd[i - 1])
                }
                SurfaceKind::Paraxial => &nd[i] / &dual(i, "focal_length_mm"),
                SurfaceKind::CoordinateBreak => Dn::constant(0.0, kk),
            }
        };
        // (Surface 0, the object, has no power: it is never refracted at.)
        let power = std::iter::once(Dn::constant(0.0, kk)).chain((1..spec.surfaces.len()).map(power)).collect();
        let thickness = (0..spec.surfaces.len()).map(|i| spec.traced_thickness(i, Dn::constant(0.0, kk), || dual(i, "thickness_mm"))).collect();
        Paraxial { n: nd, power, thickness }
    }

    /// (y, nu) just after surface `to` (refracted) of the ray with (y, nu) just after surface `from`.
    fn trace_after(&self, from: usize, to: usize, y0: Dn, nu0: Dn) -> (Dn, Dn) {
        let (mut y, mut nu) = (y0, nu0);
        for i in from + 1..=to {
            y = &y + &(&(&self.thickness[i - 1] * &nu) / &self.n[i - 1]);
            nu = &nu - &(&y * &self.power[i]);
        }
        (y, nu)
    }

    /// Height at the stop (on it, not refracted) of the ray leaving the object plane with (y0, nu0).
    fn height_at_stop(&self, stop: usize, y0: Dn, nu0: Dn) -> Dn {
        if stop == 0 {
            return y0;
        }
        // Traced and refracted up to the surface before the stop, then carried to it.
        let (y, nu) = self.trace_after(0, stop - 1, y0, nu0);
        &y + &(&(&self.thickness[stop - 1] * &nu) / &self.n[stop - 1])
    }
}

/// Pass-1 tangent of a cell (`None` when it depends on a chief-ray solve), mirroring the build's resolve.
fn cell_tangent(spec: &SystemSpec, free: &[Param], i: usize, col: &str, depth: usize) -> Result<Option<Vec<f64>>> {
    let kk = free.len();
    if depth > spec.surfaces.len() {
        return Err(Error::invalid("pickup cycle"));
    }
    let Some(cell) = spec.surfaces[i].cell(col) else { return Ok(Some(vec![0.0; kk])) };
    match &cell.driver {
        Driver::Fixed => {
            let mut d = vec![0.0; kk];
            if let Some(k) = free.iter().position(|p| matches!(p, Param::Cell { surface, column } if *surface == i && column == col)) {
                d[k] = 1.0;
            }
            Ok(Some(d))
        }
        // Never free (ParamSet refuses system parameters beside one): it does not move.
        Driver::UnknownPickup => Ok(Some(vec![0.0; kk])),
        Driver::ChiefRay => Ok(None),
        Driver::Pickup(p) => {
            let src = p.column.as_deref().unwrap_or(col);
            Ok(cell_tangent(spec, free, p.surface, src, depth + 1)?.map(|d| d.iter().map(|x| p.scale * x).collect()))
        }
    }
}

impl DiffSystem {
    /// Build the system of `set` and the derivatives of its path with respect to `set.free`.
    pub fn new(set: &ParamSet) -> Result<DiffSystem> {
        let system = set.system()?;
        let kk = set.free.len();
        let spec = system.spec.clone();
        let n = spec.surfaces.len();
        let models = set.models.clone();
        let mut ds = DiffSystem {
            system,
            params: set.free.clone(),
            steps: Vec::new(),
            image_rotation_tangent: vec![DMat3::ZERO; kk],
            image_origin_tangent: vec![DVec3::ZERO; kk],
            cell_tangents: vec![BTreeMap::new(); n],
            models,
        };
        // Pass 1: tangents of every cell not depending on a solve.
        let mut dcell: Vec<HashMap<String, Option<Vec<f64>>>> = vec![HashMap::new(); n];
        for i in 0..n {
            for col in spec.surfaces[i].present_columns() {
                let t = cell_tangent(&spec, &set.free, i, &col, 0)?;
                dcell[i].insert(col, t);
            }
        }
        let value = |i: usize, col: &str| spec.surfaces[i].cell(col).map(|c| c.value).unwrap_or(0.0);
        let dual = |dcell: &CellTangents, i: usize, col: &str| cell_dual(&spec, dcell, i, col, kk);

        // Indices at the primary wavelength and their tangents (no wavelength parameter: solves use the
        // primary wavelength whatever the rays' wavelength).
        let primary = spec.primary_wavelength_nm;
        let (n_primary, dn_primary) = ds.index_tangents_inner(primary, false)?;
        let has_solves = spec.surfaces.iter().any(|s| s.present_columns().iter().any(|c| s.cell(c).map(|c| c.driver == Driver::ChiefRay).unwrap_or(false)));
        // The paraxial trace and the pupil distance z_p the chief ray aims at (pass-1 cells: a solve moves no
        // paraxial datum).
        let paraxial = if has_solves {
            let parax = Paraxial::new(&ds, &dcell, &n_primary, &dn_primary);
            let pd = ds.pupil_distance(&parax)?;
            Some((parax, pd))
        } else {
            None
        };

        let mut current = DFrame::identity(kk);
        let mut last_step_frame = DFrame::identity(kk);
        let mut image_frame = DFrame::identity(kk);
        for i in 0..n {
            let s = &spec.surfaces[i];
            let surface_frame = current.clone();
            let mut next = current.clone();
            let mut shape_tangent: Option<Vec<ShapeTangent>> = None;
            if s.kind == SurfaceKind::CoordinateBreak {
                for col in CB_COLUMNS {
                    if let Some(Driver::Pickup(p)) = s.cell(col).map(|c| &c.driver) {
                        if matches!(dcell[i].get(col), Some(None)) {
                            let src = p.column.as_deref().unwrap_or(col);
                            let d = dcell[p.surface].get(src).cloned().flatten().ok_or_else(|| {
                                Error::invalid(format!("surface {i} {col}: pickup source {} {src} is not resolved before this surface", p.surface))
                            })?;
                            dcell[i].insert(col.to_string(), Some(d.iter().map(|x| p.scale * x).collect()));
                        }
                    }
                }
                let solved: [bool; 5] = CB_COLUMNS.map(|c| s.cell(c).map(|c| c.driver == Driver::ChiefRay).unwrap_or(false));
                if solved.iter().any(|b| *b) {
                    let (parax, pd) = paraxial.as_ref().expect("computed: the spec has solves");
                    let (p, d) = ds.chief_ray_at(i, &last_step_frame, &surface_frame, parax, pd, &n_primary, &dn_primary)?;
                    // Unsolved columns keep their (possibly free or picked-up) values.
                    let v: [Dn; 5] = std::array::from_fn(|k| if solved[k] { Dn::constant(value(i, CB_COLUMNS[k]), kk) } else { dual(&dcell, i, CB_COLUMNS[k]) });
                    let sol = solve_break(&p, &d, &v, solved, s.order);
                    for (k, col) in CB_COLUMNS.iter().enumerate() {
                        if solved[k] {
                            if (sol[k].v - value(i, col)).abs() > 1e-6 * (1.0 + value(i, col).abs()) {
                                return Err(Error::invalid(format!(
                                    "surface {i} {col}: chief-ray solve replay gives {} but the build solved {}",
                                    sol[k].v,
                                    value(i, col)
                                )));
                            }
                            dcell[i].insert(col.to_string(), Some(sol[k].d.clone()));
                        }
                    }
                }
                let g = |c: &str| dual(&dcell, i, c);
                next = cb_frame(&current, &g("decenter_x_mm"), &g("decenter_y_mm"), &deg(&g("tilt_x_deg")), &deg(&g("tilt_y_deg")), &deg(&g("tilt_z_deg")), s.order);
            } else {
                // Curvature: a free curvature, or c = 1/R with δc = −δR/R².
                let curvature = match set.free.iter().position(|p| *p == Param::Curvature { surface: i }) {
                    Some(k) => Dn::seed(s.radius_mm.as_ref().map(|r| 1.0 / r.value).unwrap_or(0.0), kk, k),
                    None => match &s.radius_mm {
                        Some(_) => dual(&dcell, i, "radius_mm").recip(),
                        None => Dn::constant(0.0, kk),
                    },
                };
                let conic = dual(&dcell, i, "conic");
                let focal = dual(&dcell, i, "focal_length_mm");
                let asph: Vec<Dn> = (1..=s.asphere_coefficients.len()).map(|j| dual(&dcell, i, &format!("asphere_{j}"))).collect();
                shape_tangent = Some(
                    (0..kk)
                        .map(|k| {
                            let mut t = ShapeTangent { curvature: curvature.d[k], conic: conic.d[k], focal_length: focal.d[k], ..Default::default() };
                            for (j, a) in asph.iter().enumerate() {
                                t.asphere[j] = a.d[k];
                            }
                            t
                        })
                        .collect(),
                );
            }
            // (Surface 0's of an object at infinity is the 0 of the start plane at surface 1's vertex.)
            let thickness = spec.traced_thickness(i, Dn::constant(0.0, kk), || dual(&dcell, i, "thickness_mm"));
            if i > 0 {
                if let Some(shape) = shape_tangent {
                    let offset = last_step_frame.point_to_local(&surface_frame.o);
                    let rotation = m3_mul(&m3_transpose(&surface_frame.r), &last_step_frame.r);
                    let mut st = StepTangent::zero(kk);
                    st.shape = shape;
                    for k in 0..kk {
                        st.rotation[k] = m3_tangent(&rotation, k);
                        st.offset[k] = v3_tangent(&offset, k);
                        if st.rotation[k] != DMat3::ZERO || st.offset[k] != DVec3::ZERO {
                            st.frame_active.push(k);
                        }
                    }
                    let step = &ds.system.path[ds.steps.len()];
                    debug_assert!((v3_value(&offset) - step.offset).length() < 1e-9 * (1.0 + step.offset.length()));
                    debug_assert_eq!(step.surface, i);
                    ds.steps.push(st);
                    last_step_frame = surface_frame.clone();
                }
            }
            if i == n - 1 {
                image_frame = surface_frame.clone();
            }
            current = next.advanced(&thickness);
        }
        for k in 0..kk {
            ds.image_rotation_tangent[k] = m3_tangent(&image_frame.r, k);
            ds.image_origin_tangent[k] = v3_tangent(&image_frame.o, k);
        }
        for (i, m) in dcell.into_iter().enumerate() {
            for (col, d) in m {
                ds.cell_tangents[i].insert(col, d.unwrap_or_else(|| vec![0.0; kk]));
            }
        }
        Ok(ds)
    }

    pub fn k(&self) -> usize {
        self.params.len()
    }

    /// Indices after every surface at `wavelength_nm` and their tangents `dn[surface * K + k]`.
    pub fn index_tangents(&self, wavelength_nm: f64) -> Result<(Vec<f64>, Vec<f64>)> {
        self.index_tangents_inner(wavelength_nm, true)
    }

    fn index_tangents_inner(&self, wavelength_nm: f64, with_wavelength: bool) -> Result<(Vec<f64>, Vec<f64>)> {
        let kk = self.k();
        let n = self.system.indices(wavelength_nm)?;
        let mut dn = vec![0.0; n.len() * kk];
        for (i, s) in self.system.surfaces.iter().enumerate() {
            let Medium::Glass(g) = &s.medium_after else { continue };
            let (dnd, dvd, dl) = match self.models.get(&g.name) {
                Some(m) => {
                    let (_, a, b, c) = m.index_derivatives(wavelength_nm);
                    (a, b, c)
                }
                None => (0.0, 0.0, super::dispersion::index_and_slope(&g.formula, wavelength_nm).1),
            };
            for (k, p) in self.params.iter().enumerate() {
                dn[i * kk + k] = match p {
                    Param::GlassNd(name) if *name == g.name => dnd,
                    Param::GlassVd(name) if *name == g.name => dvd,
                    Param::Wavelength if with_wavelength => dl,
                    _ => 0.0,
                };
            }
        }
        // A system with gratings carries the wavelength itself after the indices (SequentialSystem::indices).
        if n.len() > self.system.surfaces.len() && with_wavelength {
            let slot = self.system.surfaces.len();
            for (k, p) in self.params.iter().enumerate() {
                if *p == Param::Wavelength {
                    dn[slot * kk + k] = 1.0;
                }
            }
        }
        Ok((n, dn))
    }

    /// Distance object → paraxial entrance pupil as a dual (the y–nu trace of
    /// [`crate::system::EntrancePupil`] differentiated); infinite (telecentric) has no tangent. For an object
    /// at infinity the distance from surface 1's vertex plane (the z = 0 plane the parallel rays start on).
    fn pupil_distance(&self, parax: &Paraxial) -> Result<Dn> {
        let kk = self.k();
        let stop = self.system.stop_index;
        // y_stop = A·y0 + B·nu0; the chief ray crosses the axis at z = n0·B/A from the object plane.
        let (a, b) = (parax.height_at_stop(stop, Dn::constant(1.0, kk), Dn::constant(0.0, kk)), parax.height_at_stop(stop, Dn::constant(0.0, kk), Dn::constant(1.0, kk)));
        if a.v.abs() < 1e-14 * b.v.abs() {
            return Ok(Dn::constant(f64::INFINITY, kk));
        }
        let d = &(&parax.n[0] * &b) / &a;
        if (d.v - self.system.pupil.distance_mm).abs() > 1e-9 * (1.0 + d.v.abs()) {
            return Err(Error::invalid(format!("pupil replay {} mm differs from the build's {} mm", d.v, self.system.pupil.distance_mm)));
        }
        Ok(d)
    }

    /// The paraxial chief ray's image height per unit field k (mm per mm of object height, or per unit tan θ
    /// at infinity) as a dual: [`crate::system::FirstOrder::chief_image_height_per_field`] differentiated —
    /// the ray through the pupil centre (z_p = `pd`) from unit height, or at infinity with unit tan θ, traced
    /// to the last surface before the image, then on to the image plane: k = y + t·nu/n there.
    fn chief_image_height_per_field(&self, parax: &Paraxial, pd: &Dn) -> Dn {
        let kk = self.k();
        let last = self.system.spec.surfaces.len() - 2;
        let n0 = &parax.n[0];
        let (y0, nu0) = if self.system.object_at_infinity() {
            (-pd, n0.clone())
        } else if !pd.v.is_finite() {
            (Dn::constant(1.0, kk), Dn::constant(0.0, kk))
        } else {
            (Dn::constant(1.0, kk), -&(n0 / pd))
        };
        let (y, nu) = parax.trace_after(0, last, y0, nu0);
        &y + &(&(&parax.thickness[last] * &nu) / &parax.n[last])
    }

    /// The first field as the chief ray starts from it — an object height (mm) on a finite object, a field
    /// angle (rad) at infinity — with its tangents: [`crate::system::fields`]'s conversion of the spec's field
    /// type, differentiated. Object heights, and angles at infinity, are the spec's numbers (no tangent); an
    /// angle θ on a finite object is the height −z_p·tan θ; a paraxial image height h is h/k on a finite
    /// object and the angle atan(h/k) at infinity, k [`Self::chief_image_height_per_field`]. Values are the
    /// build's (the replay checked against them), tangents the replay's. Real image heights (a real-ray
    /// solve of the built system) are refused, as the build refuses a chief-ray solve with them.
    fn first_field(&self, i: usize, parax: &Paraxial, pd: &Dn) -> Result<[Dn; 2]> {
        let kk = self.k();
        let spec = &self.system.spec;
        let Some(&built) = self.system.fields.first() else { return Ok([Dn::constant(0.0, kk), Dn::constant(0.0, kk)]) };
        let given = spec.field_values()[0];
        let at_infinity = self.system.object_at_infinity();
        let field: [Dn; 2] = match spec.field_type {
            FieldType::ObjectHeight => return Ok(built.map(|f| Dn::constant(f, kk))),
            FieldType::Angle if at_infinity => return Ok(built.map(|f| Dn::constant(f, kk))),
            FieldType::Angle => given.map(|deg| pd.scale(-deg.to_radians().tan())),
            FieldType::ParaxialImageHeight => {
                let k = self.chief_image_height_per_field(parax, pd);
                given.map(|h_mm| {
                    let f = &Dn::constant(h_mm, kk) / &k;
                    if at_infinity { f.atan() } else { f }
                })
            }
            FieldType::RealImageHeight => {
                return Err(Error::invalid(format!(
                    "surface {i}: derivatives of a chief-ray solve with {} fields are not implemented (the object field is a real-ray solve of the built system, which the build does not do for a chief-ray solve either): use another field type",
                    spec.field_type.label()
                )))
            }
        };
        for (f, b) in field.iter().zip(built) {
            if (f.v - b).abs() > 1e-9 * (1.0 + b.abs()) {
                return Err(Error::invalid(format!("surface {i}: field replay {} differs from the build's {b} ({})", f.v, spec.field_type.label())));
            }
        }
        let [fx, fy] = field;
        Ok([Dn::new(built[0], fx.d), Dn::new(built[1], fy.d)])
    }

    /// The primary chief ray of the first field ([`Self::first_field`]), aimed at the pupil centre `pd`,
    /// traced with tangents through the steps placed so far and met with the plane z = 0 of the break at
    /// surface `i`: (point, direction) in the break's frame.
    #[allow(clippy::too_many_arguments)]
    fn chief_ray_at(&self, i: usize, last: &DFrame, brk: &DFrame, parax: &Paraxial, pd: &Dn, n: &[f64], dn: &[f64]) -> Result<(V3, V3)> {
        let kk = self.k();
        let sys = &self.system;
        let m = self.steps.len();
        let stop_placed = sys.stop_index < i;
        if sys.spec.ray_aiming != RayAiming::Off && stop_placed {
            return Err(Error::invalid(format!(
                "surface {i}: derivatives of chief-ray solves under real ray aiming are not implemented (set ray_aiming = \"off\" or fix the solve)"
            )));
        }
        let (origin, dir): (V3, V3) = if sys.object_at_infinity() {
            // An object at infinity: the field is the field angles (θx, θy) (rad). The chief ray has the
            // direction (tan θx, tan θy, 1) normalised and passes through the entrance-pupil centre, on the axis
            // at z_p from surface 1's vertex plane ([`crate::rays::PupilAim::parallel_ray`] with a zero pupil
            // point); it starts where it crosses that plane (z = 0), at (−tan θx·z_p, −tan θy·z_p, 0), which
            // moves with the parameters through z_p (and θ, for a field given as an image height).
            if !pd.v.is_finite() {
                // (The build refuses this system; a telecentric pupil has no centre a parallel beam can aim at.)
                return Err(Error::invalid(format!(
                    "surface {i}: chief-ray solve with the object at infinity and the entrance pupil at infinity too (pupil distance {} mm: the stop is at the front focal point): no pupil centre for the chief ray to pass through",
                    pd.v
                )));
            }
            let [tx, ty] = self.first_field(i, parax, pd)?.map(|f| f.tan());
            let inv = (&(&(&tx * &tx) + &(&ty * &ty)) + &Dn::constant(1.0, kk)).sqrt().recip();
            ([-&(pd * &tx), -&(pd * &ty), Dn::constant(0.0, kk)], [&tx * &inv, &ty * &inv, inv])
        } else {
            // A finite object: from the object point (x, y, 0) through the pupil centre (0, 0, z_p).
            let [x, y] = self.first_field(i, parax, pd)?;
            let dir = if !pd.v.is_finite() {
                v3_const(DVec3::Z, kk)
            } else {
                let w = [-&x, -&y, pd.clone()];
                let w = if pd.v < 0.0 { v3_scale(&w, &Dn::constant(-1.0, kk)) } else { w };
                v3_normalize(&w)
            };
            ([x, y, Dn::constant(0.0, kk)], dir)
        };
        let (o0, d0) = (v3_value(&origin), v3_value(&dir));
        let mut dp: Vec<DVec3> = (0..kk).map(|k| v3_tangent(&origin, k)).collect();
        let mut dd: Vec<DVec3> = (0..kk).map(|k| v3_tangent(&dir, k)).collect();
        let (p, d) = trace_tangents(&sys.path[..m], &self.steps[..m], n, dn, o0, d0, &mut dp, &mut dd)
            .map_err(|(st, s)| Error::invalid(format!("surface {i}: chief ray {} at surface {s} while differentiating its solve", st.label())))?;
        let (p, d) = (v3_from(p, &dp), v3_from(d, &dd));
        let pg = last.point_to_global(&p);
        let dg = m3_mul_v3(&last.r, &d);
        let pl = brk.point_to_local(&pg);
        let dl = m3_mul_v3(&m3_transpose(&brk.r), &dg);
        if dl[2].v == 0.0 {
            return Err(Error::invalid(format!("surface {i}: chief ray parallel to the break plane")));
        }
        let t = &(-&pl[2]) / &dl[2];
        Ok((v3_add(&pl, &v3_scale(&dl, &t)), dl))
    }
}
