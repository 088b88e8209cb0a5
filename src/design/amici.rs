//! The double-Amici parameterisation and the paper's six losses on it.
//!
//! The prism is the AP preset's: entrance face ⟂ the axis tilted by α_c (surface 3, the stop break,
//! picked up by surface 14), first interface at −A1 (surface 5, picked up by 12), central prism's
//! mid-plane at A2/2 (surface 7, picked up by 10), so the outer prisms have apex A1 and the central one A2;
//! outer glass m1 (surfaces 4, 11), central glass m2 (surfaces 6, 9). Prism thicknesses (6 mm) and the
//! relay are the preset's.
use crate::diff::glass_model::GlassMap;
use crate::diff::{DiffSystem, Param, ParamSet};
use crate::error::{Error, Result};
use crate::materials::GlassCatalog;
use crate::optim::Evaluation;
use crate::rays::RayBatch;
use crate::spec::SystemSpec;
use glam::DVec3;

/// Loss weights of the paper: (w_Δ, w_ε, w_D, w_t, w_g per iteration, w_R).
pub const WEIGHTS: [f64; 6] = [1.0, 1.0, 2.5e6, 5e3, 1e10, 10.0];
/// The relay focal length that turns an angle into a spreading on the detector (mm).
pub const RELAY_FOCAL_MM: f64 = 50.0;
/// Wavelengths of the design (nm): λ_min, centre, λ_max.
pub const WAVELENGTHS: [f64; 3] = [450.0, 520.0, 650.0];
/// Half width of the object grid for the distortion loss (mm).
pub const HALF_WIDTH_MM: f64 = 2.5;

/// The parameter cells: α_c, −A1, A2/2 (degrees) and the per-degree scale from design to cell units.
const ANGLE_CELLS: [(&str, f64); 3] = [("s3.tilt_y_deg", 1.0), ("s5.tilt_y_deg", -1.0), ("s7.tilt_y_deg", 0.5)];

/// The AP preset with its outer glass replaced by `g1` and its central glass by `g2`.
pub fn base_spec(g1: &str, g2: &str) -> Result<SystemSpec> {
    let mut spec = crate::presets::spec("ap")?;
    for (i, g) in [(4usize, g1), (11, g1), (6, g2), (9, g2)] {
        spec.surfaces[i].material = Some(g.to_string());
    }
    spec.name = "amici-design".into();
    spec.description = "double-Amici prism designed by diffcassi (design amici)".into();
    Ok(spec)
}

/// A design point: α_c, A1, A2 in degrees.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Angles {
    pub alpha_c_deg: f64,
    pub a1_deg: f64,
    pub a2_deg: f64,
}

/// Metrics of a design point (the quantities the losses are made of).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Metrics {
    /// |Δ|: angle between the 450 nm and 650 nm central chief rays after the prism (degrees).
    pub dispersion_deg: f64,
    /// Angle of the 520 nm central chief ray to the input axis (mrad): x (dispersion plane) and total.
    pub deviation_x_mrad: f64,
    pub deviation_mrad: f64,
    /// Largest |real − predicted| over the loss grid (µm), Zemax's grid-distortion definition.
    pub max_distortion_um: f64,
    /// Smallest θ_critical − θ_incidence over the chief rays probed (degrees; +∞ when no surface can TIR).
    pub tir_margin_deg: f64,
    /// Weighted losses (w·L) in the order Δ, ε, D, t, g, R.
    pub weighted_losses: [f64; 6],
}

/// The merit function of the design: residuals rᵢ with L = Σ rᵢ² = Σ w·Lᵢ.
pub struct AmiciLoss<'a> {
    pub set: ParamSet,
    /// `Some` in the continuous-glass stage: the catalogue map for L_g and the glass names.
    pub glass_map: Option<&'a GlassMap>,
    pub target_dispersion_rad: f64,
    /// Loss grid points per side.
    pub grid: usize,
    /// Weight of L_t (the paper's 5e3 by default).
    pub thickness_weight: f64,
}

impl<'a> AmiciLoss<'a> {
    /// `continuous`: glasses are the model glasses `M1`, `M2` (free n_d, V_d) inserted in `catalog`.
    pub fn new(spec: SystemSpec, catalog: GlassCatalog, continuous: bool, glass_map: Option<&'a GlassMap>, target_dispersion_rad: f64) -> Result<Self> {
        let mut free: Vec<Param> = ANGLE_CELLS.iter().map(|(c, _)| Param::parse(c)).collect::<Result<_>>()?;
        if continuous {
            for t in ["glass_nd:M1", "glass_vd:M1", "glass_nd:M2", "glass_vd:M2"] {
                free.push(Param::parse(t)?);
            }
        }
        let set = ParamSet::new(spec, catalog, free)?;
        Ok(AmiciLoss { set, glass_map: if continuous { glass_map } else { None }, target_dispersion_rad, grid: 7, thickness_weight: WEIGHTS[3] })
    }

    /// Design vector → ParamSet values, and the diagonal d(value)/d(design).
    fn scale(&self) -> Vec<f64> {
        let mut s: Vec<f64> = ANGLE_CELLS.iter().map(|(_, k)| *k).collect();
        s.resize(self.set.len(), 1.0);
        s
    }
    pub fn design_of(&self, x: &[f64]) -> Vec<f64> {
        x.iter().zip(self.scale()).map(|(v, s)| v / s).collect()
    }
    pub fn values_of(&self, u: &[f64]) -> Vec<f64> {
        u.iter().zip(self.scale()).map(|(v, s)| v * s).collect()
    }

    pub fn system_at(&self, u: &[f64]) -> Result<DiffSystem> {
        self.set.with_values(&self.values_of(u))?.build()
    }

    /// Residuals, their Jacobian with respect to the design vector u (degrees, n_d, V_d), and metrics.
    pub fn evaluate_full(&self, u: &[f64], iteration: usize) -> Result<(Evaluation, Metrics)> {
        let n = u.len();
        let ds = self.system_at(u)?;
        let kk = ds.k();
        let scale = self.scale();
        let deg = std::f64::consts::PI / 180.0;
        // Rays: per wavelength, the centre, the grid and four ABCD probes.
        let h = 1e-4 * HALF_WIDTH_MM;
        let g = crate::analysis::linspace(-HALF_WIDTH_MM, HALF_WIDTH_MM, self.grid);
        let mut fields = vec![[0.0, 0.0], [h, 0.0], [-h, 0.0], [0.0, h], [0.0, -h]];
        for &x in &g {
            for &y in &g {
                fields.push([x, y]);
            }
        }
        let per = fields.len();
        let mut rays = RayBatch::default();
        for &w in &WAVELENGTHS {
            rays.extend(&RayBatch::chief_rays(&ds.system, &fields, w)?);
        }
        let j = ds.trace(&rays)?;
        if let Some(i) = (0..rays.len()).find(|&i| !j.usable(i)) {
            return Err(Error::invalid(format!(
                "design loss: chief ray of field {:?} at {} nm is {}",
                fields[i % per],
                WAVELENGTHS[i / per],
                j.traced.status[i].label()
            )));
        }
        let mut res: Vec<f64> = Vec::new();
        let mut jac: Vec<f64> = Vec::new();
        let push = |r: f64, dr_dx: Vec<f64>, res: &mut Vec<f64>, jac: &mut Vec<f64>| {
            res.push(r);
            jac.extend(dr_dx.iter().zip(&scale).map(|(d, s)| d * s));
        };
        // Global output angle (x plane and y plane) of the central chief ray at each wavelength.
        let r_img = ds.system.image().frame.rotation;
        let angle = |ray: usize| -> ([f64; 2], Vec<[f64; 2]>) {
            let d = DVec3::new(j.traced.dir_x[ray], j.traced.dir_y[ray], j.traced.dir_z[ray]);
            let gv = r_img * d;
            let a = [gv.x.atan2(gv.z), gv.y.atan2(gv.z)];
            let da = (0..kk)
                .map(|k| {
                    let dg = ds.image_rotation_tangent[k] * d + r_img * j.d_direction(ray, k);
                    [(gv.z * dg.x - gv.x * dg.z) / (gv.x * gv.x + gv.z * gv.z), (gv.z * dg.y - gv.y * dg.z) / (gv.y * gv.y + gv.z * gv.z)]
                })
                .collect();
            (a, da)
        };
        let (a_lo, da_lo) = angle(0);
        let (a_c, da_c) = angle(per);
        let (a_hi, da_hi) = angle(2 * per);
        // L_Δ: (Δ0 − |Δ|)², Δ as the spreading through the relay (µm).
        let delta = a_hi[0] - a_lo[0];
        let sgn = delta.signum();
        let um = RELAY_FOCAL_MM * 1e3;
        let w = WEIGHTS.map(f64::sqrt);
        push(w[0] * (self.target_dispersion_rad - delta.abs()) * um, (0..kk).map(|k| -w[0] * sgn * (da_hi[k][0] - da_lo[k][0]) * um).collect(), &mut res, &mut jac);
        let r_delta = res[0];
        // L_ε: the largest grid distortion (µm), Zemax's definition (reference = centre, ABCD at the axis).
        let mut worst = (-1.0f64, Vec::new());
        for wl in 0..3 {
            let b = wl * per;
            let pos = |i: usize| [j.traced.x[b + i], j.traced.y[b + i]];
            let dpos = |i: usize, k: usize| {
                let v = j.d_position(b + i, k);
                [v.x, v.y]
            };
            let (p1, p2, p3, p4) = (pos(1), pos(2), pos(3), pos(4));
            let abcd = [(p1[0] - p2[0]) / (2.0 * h), (p3[0] - p4[0]) / (2.0 * h), (p1[1] - p2[1]) / (2.0 * h), (p3[1] - p4[1]) / (2.0 * h)];
            let r0 = pos(0);
            for (gi, f) in fields.iter().enumerate().skip(5) {
                let p = pos(gi);
                let e = [p[0] - r0[0] - abcd[0] * f[0] - abcd[1] * f[1], p[1] - r0[1] - abcd[2] * f[0] - abcd[3] * f[1]];
                let eps = e[0].hypot(e[1]) * 1e3;
                if eps > worst.0 {
                    let de: Vec<f64> = (0..kk)
                        .map(|k| {
                            let (q, q0, q1, q2, q3, q4) = (dpos(gi, k), dpos(0, k), dpos(1, k), dpos(2, k), dpos(3, k), dpos(4, k));
                            let da = [(q1[0] - q2[0]) / (2.0 * h), (q3[0] - q4[0]) / (2.0 * h), (q1[1] - q2[1]) / (2.0 * h), (q3[1] - q4[1]) / (2.0 * h)];
                            let dex = q[0] - q0[0] - da[0] * f[0] - da[1] * f[1];
                            let dey = q[1] - q0[1] - da[2] * f[0] - da[3] * f[1];
                            if eps > 0.0 { 1e3 * (e[0] * dex + e[1] * dey) / (eps / 1e3) } else { 0.0 }
                        })
                        .collect();
                    worst = (eps, de);
                }
            }
        }
        let max_eps = worst.0;
        push(w[1] * max_eps, worst.1.iter().map(|v| w[1] * v).collect(), &mut res, &mut jac);
        // L_D: deviation of the centre wavelength's chief ray (mrad), both planes.
        push(w[2] * 1e3 * a_c[0], (0..kk).map(|k| w[2] * 1e3 * da_c[k][0]).collect(), &mut res, &mut jac);
        push(w[2] * 1e3 * a_c[1], (0..kk).map(|k| w[2] * 1e3 * da_c[k][1]).collect(), &mut res, &mut jac);
        let r_dev = (res[2], res[3]);
        // L_t = 2A1² + A2² (radians): residuals √2·A1, A2 in design units (u1 = A1°, u2 = A2°).
        let (a1, a2) = (u[1] * deg, u[2] * deg);
        let wt = self.thickness_weight.sqrt();
        res.push(wt * 2f64.sqrt() * a1);
        jac.extend((0..n).map(|c| if c == 1 { wt * 2f64.sqrt() * deg } else { 0.0 }));
        res.push(wt * a2);
        jac.extend((0..n).map(|c| if c == 2 { wt * deg } else { 0.0 }));
        // L_g = w_g·it·Σ d²(glass, nearest catalogue glass).
        let mut lg = 0.0;
        if let Some(map) = self.glass_map {
            let wg = (WEIGHTS[4] * iteration as f64).sqrt();
            for m in 0..2 {
                let (nd, vd) = (u[3 + 2 * m], u[4 + 2 * m]);
                let near = map.nearest(nd, vd);
                let (rn, rv) = ((nd - near.nd) / map.nd_range, (vd - near.vd) / map.vd_range);
                lg += wg * wg * (rn * rn + rv * rv);
                res.push(wg * rn);
                jac.extend((0..n).map(|c| if c == 3 + 2 * m { wg / map.nd_range } else { 0.0 }));
                res.push(wg * rv);
                jac.extend((0..n).map(|c| if c == 4 + 2 * m { wg / map.vd_range } else { 0.0 }));
            }
        }
        // L_R = softplus(2·min D_TIR)², softplus(x) = ln(1 + e^(5 − x)), D in degrees.
        let (margin, dmargin) = tir_margin(&ds, &rays, per, self.grid)?;
        let (sp, dsp) = if margin.is_finite() {
            let z = 5.0 - 2.0 * margin;
            let sp = if z > 30.0 { z } else { z.exp().ln_1p() };
            (sp, -2.0 / (1.0 + (-z).exp()))
        } else {
            (0.0, 0.0)
        };
        push(w[5] * sp, dmargin.iter().map(|d| w[5] * dsp * d).collect(), &mut res, &mut jac);
        let deviation_mrad = 1e3 * (a_c[0] * a_c[0] + a_c[1] * a_c[1]).sqrt();
        let metrics = Metrics {
            dispersion_deg: delta.abs().to_degrees(),
            deviation_x_mrad: 1e3 * a_c[0],
            deviation_mrad,
            max_distortion_um: max_eps,
            tir_margin_deg: margin,
            weighted_losses: [
                r_delta * r_delta,
                res[1] * res[1],
                r_dev.0 * r_dev.0 + r_dev.1 * r_dev.1,
                self.thickness_weight * (2.0 * a1 * a1 + a2 * a2),
                lg,
                (w[5] * sp).powi(2),
            ],
        };
        Ok((Evaluation::new(res, jac, n), metrics))
    }
}

/// Smallest θ_c − θ_i (degrees) over surfaces going to a lower index, for the centre and corner chief
/// rays at every design wavelength, and its derivative (per ParamSet parameter).
fn tir_margin(ds: &DiffSystem, rays: &RayBatch, per: usize, grid: usize) -> Result<(f64, Vec<f64>)> {
    let kk = ds.k();
    let mut probe = RayBatch::default();
    // The centre and the grid's four corners (grid index 5 + ix·N + iy).
    let corners = [0usize, 5, 5 + grid - 1, 5 + (grid - 1) * grid, 5 + grid * grid - 1];
    for wl in 0..3 {
        for &c in &corners {
            let i = wl * per + c;
            probe.push(rays.origin(i), rays.direction(i), rays.wavelength_nm[i]);
        }
    }
    let mut best = (f64::INFINITY, vec![0.0; kk]);
    for step in 0..ds.step_surfaces().len() {
        for inc in ds.incidence(&probe, step)?.into_iter().flatten() {
            if inc.n1 <= inc.n2 {
                continue;
            }
            let ci = inc.cos_i.clamp(-1.0, 1.0);
            let (ti, si) = (ci.acos(), (1.0 - ci * ci).sqrt().max(1e-12));
            let ratio = inc.n2 / inc.n1;
            let tc = ratio.asin();
            let m = (tc - ti).to_degrees();
            if m < best.0 {
                let cc = (1.0 - ratio * ratio).sqrt().max(1e-12);
                let d = (0..kk)
                    .map(|k| {
                        let dratio = (inc.dn2[k] * inc.n1 - inc.n2 * inc.dn1[k]) / (inc.n1 * inc.n1);
                        (dratio / cc + inc.d_cos_i[k] / si).to_degrees()
                    })
                    .collect();
                best = (m, d);
            }
        }
    }
    Ok(best)
}
