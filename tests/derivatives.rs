//! Jacobians of traced rays against f64 central finite differences (Richardson-extrapolated), for every
//! parameter kind on all four presets; plus the degenerate cases and the hit-tangent building block.
//!
//! Criterion: |J − FD| ≤ 1e-6·|FD| or ≤ 1e-9 (mm, or direction units) absolute.
//! `cargo test --release --test integration derivatives:: -- --nocapture` prints the worst agreement per parameter.
use crate::common;
use common::{ap_like, sp_like};
use diffcassi::diff::hit::{hit_tangent, ShapeTangent};
use diffcassi::diff::{HitJacobianBatch, JacobianBatch, Param, ParamSet};
use diffcassi::materials::GlassCatalog;
use diffcassi::prelude::*;
use diffcassi::spec::Cell;
use diffcassi::surfaces::{intersect, SurfaceShape};
use diffcassi::tracer::hits::{sequential_hits, HitKind, HitLog};
#[cfg(feature = "embree")]
use diffcassi::{
    surfaces::MeshResolution,
    tracer::embree::{EmbreeOptions, EmbreeTracer, Refinement},
};
use glam::DVec3;

fn rays_for(sys: &SequentialSystem) -> RayBatch {
    let pupil = [[0.0, 0.0], [0.7, 0.0], [0.0, 0.7], [-0.5, -0.5]];
    let mut b = RayBatch::default();
    for &w in &[450.0, 520.0, 650.0] {
        for &f in &sys.spec.fields_mm {
            b.extend(&RayBatch::for_field(sys, f, &pupil, w).unwrap());
        }
    }
    b
}

/// Outputs (x, y, z, dx, dy, dz) per ray, or None when the ray did not arrive.
fn outputs(sys: &SequentialSystem, rays: &RayBatch) -> Vec<Option<[f64; 6]>> {
    let t = AnalyticTracer::default().trace(sys, rays).unwrap();
    (0..t.len())
        .map(|i| (t.status[i] == RayStatus::Ok).then(|| [t.x[i], t.y[i], t.z[i], t.dir_x[i], t.dir_y[i], t.dir_z[i]]))
        .collect()
}

/// Evaluate the outputs with parameter k moved by `delta`.
fn moved(set: &ParamSet, rays: &RayBatch, k: usize, delta: f64) -> Vec<Option<[f64; 6]>> {
    let p = &set.free[k];
    let mut rays = rays.clone();
    let sys = match p {
        Param::Wavelength => {
            rays.wavelength_nm.iter_mut().for_each(|w| *w += delta);
            set.system().unwrap()
        }
        Param::RayOrigin(a) => {
            let col = [&mut rays.origin_x, &mut rays.origin_y, &mut rays.origin_z][*a].iter_mut();
            col.for_each(|v| *v += delta);
            set.system().unwrap()
        }
        Param::RayDirection(a) => {
            let col = [&mut rays.dir_x, &mut rays.dir_y, &mut rays.dir_z][*a].iter_mut();
            col.for_each(|v| *v += delta);
            set.system().unwrap()
        }
        _ => {
            let mut x = set.values_or_zero();
            x[k] += delta;
            set.with_system_values(&x).system().unwrap()
        }
    };
    outputs(&sys, &rays)
}

trait Helpers {
    fn values_or_zero(&self) -> Vec<f64>;
    fn with_system_values(&self, x: &[f64]) -> ParamSet;
}
impl Helpers for ParamSet {
    fn values_or_zero(&self) -> Vec<f64> {
        self.free.iter().map(|p| self.value(p).unwrap_or(0.0)).collect()
    }
    fn with_system_values(&self, x: &[f64]) -> ParamSet {
        let mut s = self.clone();
        for (p, v) in self.free.iter().zip(x) {
            if !p.is_ray_parameter() {
                s.set(p, *v).unwrap();
            }
        }
        s
    }
}

fn step_for(p: &Param) -> f64 {
    match p {
        Param::Cell { column, .. } if column.ends_with("_deg") => 1e-3,
        Param::Cell { column, .. } if column == "conic" => 1e-2,
        Param::Cell { column, .. } if column == "asphere_1" => 1e-5,
        Param::Cell { column, .. } if column.starts_with("asphere_") => 1e-5,
        Param::Cell { .. } => 1e-3,
        Param::Curvature { .. } => 1e-5,
        Param::GlassNd(_) => 1e-4,
        Param::GlassVd(_) => 1e-3,
        Param::Wavelength => 1e-2,
        Param::RayOrigin(_) => 1e-3,
        Param::RayDirection(_) => 1e-4,
    }
}

/// Richardson-extrapolated central differences of every ray's outputs for parameter k: central differences
/// at h, h/2, h/4, extrapolated twice (error O(h⁶)). `None` for rays that do not arrive at every step.
fn finite_differences(set: &ParamSet, rays: &RayBatch, k: usize) -> Vec<Option<[f64; 6]>> {
    let h = step_for(&set.free[k]);
    let d = |h: f64| {
        let (a, b) = (moved(set, rays, k, h), moved(set, rays, k, -h));
        a.iter().zip(&b).map(|(a, b)| match (a, b) { (Some(a), Some(b)) => Some(std::array::from_fn::<f64, 6, _>(|c| (a[c] - b[c]) / (2.0 * h))), _ => None }).collect::<Vec<_>>()
    };
    let (d1, d2, d3) = (d(h), d(h / 2.0), d(h / 4.0));
    (0..rays.len())
        .map(|i| {
            let (a, b, e) = (d1[i]?, d2[i]?, d3[i]?);
            Some(std::array::from_fn(|c| {
                let (r1, r2) = ((4.0 * b[c] - a[c]) / 3.0, (4.0 * e[c] - b[c]) / 3.0);
                (16.0 * r2 - r1) / 15.0
            }))
        })
        .collect()
}

/// Check every column of `jb` against the finite differences `fds[k][ray]`; returns the number of
/// compared entries.
fn against_fd(label: &str, source: &str, set: &ParamSet, fds: &[Vec<Option<[f64; 6]>>], jb: &JacobianBatch) -> usize {
    let mut compared = 0;
    for (k, fd_k) in fds.iter().enumerate() {
        let mut worst = (0.0f64, 0.0f64); // (relative error, |fd|) of the worst entry
        let mut ok_rays = 0;
        for (i, fd_i) in fd_k.iter().enumerate() {
            let Some(fd_i) = fd_i else { continue };
            if !jb.usable(i) {
                continue;
            }
            ok_rays += 1;
            for (c, &fd) in fd_i.iter().enumerate() {
                let j = jb.row(i, c)[k];
                let err = (j - fd).abs();
                let tol = (1e-6 * fd.abs()).max(1e-9);
                assert!(
                    err <= tol,
                    "{label} {source} {}: ray {i} component {c}: jacobian {j:e} vs finite difference {fd:e} (|Δ| {err:e} > {tol:e})",
                    set.free[k]
                );
                compared += 1;
                let rel = if fd.abs() > 1e-6 { err / fd.abs() } else { 0.0 };
                if rel > worst.0 {
                    worst = (rel, fd.abs());
                }
            }
        }
        assert!(ok_rays >= fd_k.len() / 2, "{label} {source} {}: only {ok_rays} rays compared", set.free[k]);
        println!("{label:4} {source:16} {:22} worst relative error vs FD {:.1e} ({} rays)", set.free[k].name(), worst.0, ok_rays);
    }
    compared
}

/// Check every column of the Jacobian (analytic hits and, with Embree and `with_embree`, refined Embree
/// hits of user geometry and of a 1 µm mesh) against finite differences; returns the number of compared
/// entries.
fn check(label: &str, spec: SystemSpec, free: &[&str], with_embree: bool) -> usize {
    let params: Vec<Param> = free.iter().map(|t| Param::parse(t).unwrap()).collect();
    let set = ParamSet::new(spec, GlassCatalog::builtin(), params).unwrap();
    let ds = set.build().unwrap();
    let rays = rays_for(&ds.system);
    let jb = ds.trace(&rays).unwrap();
    // The values are the plain tracer's, bit for bit.
    let plain = AnalyticTracer::default().trace(&ds.system, &rays).unwrap();
    assert_eq!(plain, jb.traced, "{label}: the Jacobian trace must not change the values");
    let fds: Vec<_> = (0..set.len()).map(|k| finite_differences(&set, &rays, k)).collect();
    #[cfg(not(feature = "embree"))]
    let _ = with_embree;
    #[allow(unused_mut)]
    let mut compared = against_fd(label, "analytic", &set, &fds, &jb);
    // The same Jacobians from the analytic hits through the hit-record path.
    let (traced, log) = sequential_hits(&ds.system, &rays).unwrap();
    let from_log = ds.jacobian_from_hits(&rays, &traced, &log).unwrap();
    let worst = agreement(label, "sequential hits", &jb, &from_log, 1e-15);
    assert!(worst <= 1e-11, "{label}: sequential hit records: {worst:e}");
    #[cfg(feature = "embree")]
    for (source, opts) in embree_backends().into_iter().filter(|_| with_embree) {
        let hj = ds.trace_embree(&EmbreeTracer::new(opts), &rays).unwrap();
        agreement(label, source, &jb, &hj, 1e-15);
        compared += against_fd(label, source, &set, &fds, &hj.batch);
    }
    compared
}

/// Compare Jacobians from recorded hits with the analytic ones: every ray that arrives analytically must
/// have an available Jacobian, equal to ≤ 1e-9 of the largest magnitude of its column (the same output
/// component and parameter over the batch; entries that are small by cancellation differ by f64
/// rounding of the large terms), plus `abs_floor` absolute. Returns that worst relative difference.
pub(crate) fn agreement(label: &str, source: &str, jb: &JacobianBatch, hj: &HitJacobianBatch, abs_floor: f64) -> f64 {
    let kk = jb.k();
    let mut scale = vec![0.0f64; 6 * kk];
    for i in (0..jb.len()).filter(|&i| jb.usable(i)) {
        for c in 0..6 {
            for (k, a) in jb.row(i, c).iter().enumerate() {
                scale[c * kk + k] = scale[c * kk + k].max(a.abs());
            }
        }
    }
    let (mut worst, mut n) = (0.0f64, 0usize);
    for i in 0..jb.len() {
        assert_eq!(jb.traced.status[i], hj.batch.traced.status[i], "{label} {source}: ray {i} status");
        if !jb.usable(i) {
            continue;
        }
        assert!(hj.unavailable[i].is_none(), "{label} {source}: ray {i} unavailable: {:?}", hj.unavailable[i]);
        assert!((jb.traced.x[i] - hj.batch.traced.x[i]).abs() < 1e-9 && (jb.traced.y[i] - hj.batch.traced.y[i]).abs() < 1e-9);
        n += 1;
        for c in 0..6 {
            for (k, (a, b)) in jb.row(i, c).iter().zip(hj.batch.row(i, c)).enumerate() {
                let (err, s) = ((a - b).abs(), scale[c * kk + k]);
                assert!(err <= 1e-9 * s + abs_floor, "{label} {source}: ray {i} component {c} {}: {b:e} vs analytic {a:e} (column scale {s:e})", jb.params[k]);
                if s > 1e-12 {
                    worst = worst.max(err / s);
                }
            }
        }
    }
    assert!(n >= jb.len() / 2, "{label} {source}: only {n} rays");
    println!("{label:4} {source:16} vs analytic-hit Jacobians: worst difference {worst:.1e} of the column's largest entry ({n} rays)");
    worst
}

#[cfg(feature = "embree")]
fn embree_backends() -> [(&'static str, EmbreeOptions); 2] {
    [
        ("embree-user", EmbreeOptions::user(Refinement::F64)),
        ("embree-mesh 1um", EmbreeOptions::mesh(MeshResolution::MaxSagErrorUm(1.0), Refinement::F64)),
    ]
}

const RAY_PARAMS: [&str; 7] = ["wavelength", "ray.origin_x", "ray.origin_y", "ray.origin_z", "ray.dir_x", "ray.dir_y", "ray.dir_z"];

/// [`sp_like`] for the Embree backends: the break tilts the second half of the split prism (surface 10)
/// against the first (surface 8), and with the two faces coincident the sequential model crosses
/// surface 10 at negative distance for some rays, a path no physical (non-sequential) trace takes — the
/// Embree Jacobians of those rays are reported unavailable (tested below). A 0.1 mm air gap (surface 8's
/// thickness) puts surface 10 ahead of surface 8 everywhere on the aperture.
fn sp_gap(name: &str) -> SystemSpec {
    let mut spec = sp_like(name);
    spec.surfaces[8].thickness_mm = Cell::fixed(0.1);
    spec
}

fn sp_params(extra: &[&'static str]) -> Vec<&'static str> {
    let mut v = common::SP_LIKE_PARAMS.to_vec();
    v.push("s18.thickness_mm");
    v.extend_from_slice(&RAY_PARAMS);
    v.extend_from_slice(extra);
    v
}

#[test]
fn jacobians_match_finite_differences_sp() {
    assert!(check("sp", sp_like("sp"), &sp_params(&[]), false) > 1000);
    assert!(check("sp+gap", sp_gap("sp"), &sp_params(&[]), true) > 1000);
}

#[test]
fn jacobians_match_finite_differences_msp() {
    assert!(check("msp", sp_like("msp"), &sp_params(&[]), false) > 1000);
    assert!(check("msp+gap", sp_gap("msp"), &sp_params(&[]), true) > 1000);
}

#[test]
fn jacobians_match_finite_differences_ap() {
    let mut v = common::AP_LIKE_PARAMS.to_vec();
    v.extend_from_slice(&["s1.thickness_mm", "s15.thickness_mm"]);
    v.extend_from_slice(&RAY_PARAMS);
    assert!(check("ap", ap_like("ap", 4), &v, true) > 1000);
}

#[test]
fn jacobians_match_finite_differences_map() {
    let mut v = common::MAP_LIKE_PARAMS.to_vec();
    v.push("s20.thickness_mm");
    v.extend_from_slice(&RAY_PARAMS);
    assert!(check("map", ap_like("map", 6), &v, true) > 1000);
}

/// The presets exactly as shipped (no surface made aspheric, no break tilted): Jacobians from analytic hits
/// and, with Embree, from refined Embree hits (user geometry, 1 µm mesh) agree with each other and with
/// finite differences. Parameters are those every surface of the shipped presets carries.
#[test]
fn jacobians_match_finite_differences_on_the_shipped_presets() {
    let sp = ["s0.thickness_mm", "s2.focal_length_mm", "s4.tilt_x_deg", "s4.tilt_y_deg", "s4.decenter_x_mm", "s6.thickness_mm", "s9.tilt_x_deg", "s9.tilt_y_deg", "s15.thickness_mm", "s16.curvature", "s17.radius_mm", "s18.thickness_mm", "glass_nd:N-BK7", "glass_vd:SF10"];
    let ap = ["s0.thickness_mm", "s1.focal_length_mm", "s3.tilt_x_deg", "s3.tilt_y_deg", "s4.thickness_mm", "s5.tilt_y_deg", "s7.tilt_y_deg", "glass_nd:N-SK2", "glass_vd:N-SF10"];
    let map = ["s0.thickness_mm", "s1.focal_length_mm", "s4.tilt_x_deg", "s5.tilt_y_deg", "s6.curvature", "s7.tilt_y_deg", "s9.thickness_mm", "s18.tilt_y_deg", "s19.tilt_x_deg", "s20.thickness_mm", "glass_nd:N-SK2", "glass_vd:N-SF10"];
    for (name, params) in [("sp", &sp[..]), ("msp", &sp[..]), ("ap", &ap[..]), ("map", &map[..])] {
        let mut free: Vec<&str> = params.to_vec();
        free.extend_from_slice(&RAY_PARAMS);
        assert!(check(&format!("{name} as shipped"), presets::spec(name).unwrap(), &free, true) > 500, "{name}");
    }
}

/// d(cell `col` of surface `surface`)/d(free parameter k) by central differences of the build's own solve,
/// Richardson-extrapolated from steps h and h/2.
fn solved_cell_derivative(set: &ParamSet, k: usize, h: f64, surface: usize, col: &str) -> f64 {
    let val = |d: f64| {
        let mut x = set.values().unwrap();
        x[k] += d;
        set.with_values(&x).unwrap().system().unwrap().spec.surfaces[surface].cell(col).unwrap().value
    };
    let fd = |h: f64| (val(h) - val(-h)) / (2.0 * h);
    (4.0 * fd(h / 2.0) - fd(h)) / 3.0
}

#[test]
fn chief_ray_solve_and_pickup_derivatives_are_those_of_the_build() {
    // d(solved cell)/dθ against finite differences of the build's own solve.
    let set = ParamSet::new(presets::spec("sp").unwrap(), GlassCatalog::builtin(), vec![Param::parse("s4.tilt_x_deg").unwrap(), Param::parse("glass_nd:N-BK7").unwrap()]).unwrap();
    let ds = set.build().unwrap();
    for (k, h) in [(0usize, 1e-3), (1, 1e-5)] {
        for col in ["decenter_x_mm", "decenter_y_mm", "tilt_y_deg"] {
            let rich = solved_cell_derivative(&set, k, h, 15, col);
            let j = ds.cell_tangents[15][col][k];
            assert!((j - rich).abs() <= (1e-6 * rich.abs()).max(1e-9), "s15.{col} / {}: {j} vs {rich}", set.free[k]);
        }
    }
    // The pickup s14.tilt_x = −s4.tilt_x.
    assert_eq!(ds.cell_tangents[14]["tilt_x_deg"][0], -1.0);
}

/// The chief-ray solve with the **object at infinity**: the chief ray of the first field (2°, 3°) has the fixed
/// direction (tan θx, tan θy, 1) and passes through the entrance-pupil centre, so it starts on surface 1's
/// plane at (−tan θx·z_p, −tan θy·z_p, 0) with z_p the pupil distance, which the lens's curvature, radius,
/// thickness and glass move (the stop is behind the lens). d(solved decenters and tilts)/dθ against central
/// differences (Richardson) of the build's own solve, 1e-6 relative.
#[test]
fn chief_ray_solve_derivatives_at_infinity_are_those_of_the_build() {
    let spec = common::singlet_at_infinity(true);
    let free = ["s1.curvature", "s2.radius_mm", "s1.thickness_mm", "glass_nd:N-BK7"];
    let set = ParamSet::new(spec, GlassCatalog::builtin(), free.iter().map(|t| Param::parse(t).unwrap()).collect()).unwrap();
    let ds = set.build().unwrap();
    assert!(ds.system.object_at_infinity());
    let mut worst = 0.0f64;
    for (k, h) in [(0usize, 1e-5), (1, 1e-2), (2, 1e-3), (3, 1e-5)] {
        for col in ["decenter_x_mm", "decenter_y_mm", "tilt_x_deg", "tilt_y_deg"] {
            let rich = solved_cell_derivative(&set, k, h, 4, col);
            let j = ds.cell_tangents[4][col][k];
            let rel = (j - rich).abs() / rich.abs();
            println!("s4.{col:>13} / {:>15}: derivative {j:+.12e}  fd {rich:+.12e}  rel {rel:.1e}", free[k]);
            assert!(rich.abs() > 1e-6 && (j - rich).abs() <= 1e-6 * rich.abs(), "s4.{col} / {}: {j} vs {rich}", free[k]);
            worst = worst.max(rel);
        }
    }
    println!("chief-ray solve at infinity: worst relative error {worst:.1e}");
}

/// The chief-ray solve for **every field type**: the traced field (object height, or field angle at
/// infinity) is itself a function of the parameters when the spec gives it in another unit — an angle θ on a
/// finite object is the height −z_p·tan θ, a paraxial image height h is h/k (finite) or atan(h/k) (at
/// infinity), k the paraxial chief ray's image height per unit field — and the solve's derivative carries
/// that term. The singlet of `singlet_at_infinity` with its chief-ray break, at infinity and with the object
/// 100 mm before the lens; free: the object distance (finite), the lens's curvature, radius, thickness and
/// glass, and the break's thickness (the image distance: it moves k only). d(solved decenters and tilts)/dθ
/// against central differences (Richardson) of the build's own solve, 1e-6 relative, or 1e-9 absolute where
/// the solve does not move (the image distance for heights and angles; the object distance for an angle on
/// a finite object, which keeps the chief ray). Real image heights are refused by the build, naming the type
/// and the surface.
#[test]
fn chief_ray_solve_derivatives_for_every_field_type_are_those_of_the_build() {
    use diffcassi::spec::FieldType;
    let finite = |field_type: FieldType, fields_mm: Vec<[f64; 2]>, fields_deg: Vec<[f64; 2]>| {
        let mut spec = common::singlet_at_infinity(true);
        spec.surfaces[0].thickness_mm = Cell::fixed(100.0);
        (spec.field_type, spec.fields_mm, spec.fields_deg) = (field_type, fields_mm, fields_deg);
        spec
    };
    let mut image_at_infinity = common::singlet_at_infinity(true);
    (image_at_infinity.field_type, image_at_infinity.fields_mm, image_at_infinity.fields_deg) = (FieldType::ParaxialImageHeight, vec![[1.5, 2.5], [0.0, 0.0]], vec![]);
    let cases = [
        ("object height, finite", finite(FieldType::ObjectHeight, vec![[3.0, 4.0], [0.0, 0.0]], vec![])),
        ("angle, finite", finite(FieldType::Angle, vec![], vec![[2.0, 3.0], [0.0, 0.0]])),
        ("paraxial image height, finite", finite(FieldType::ParaxialImageHeight, vec![[1.5, 2.5], [0.0, 0.0]], vec![])),
        ("angle, at infinity", common::singlet_at_infinity(true)),
        ("paraxial image height, at infinity", image_at_infinity),
    ];
    let mut worst = 0.0f64;
    for (label, spec) in cases {
        let mut free = vec![("s1.curvature", 1e-5), ("s2.radius_mm", 1e-2), ("s1.thickness_mm", 1e-3), ("glass_nd:N-BK7", 1e-5), ("s4.thickness_mm", 1e-2)];
        if !spec.object_at_infinity() {
            free.push(("s0.thickness_mm", 1e-2));
        }
        let set = ParamSet::new(spec, GlassCatalog::builtin(), free.iter().map(|(t, _)| Param::parse(t).unwrap()).collect()).unwrap();
        let ds = set.build().unwrap();
        for (k, (name, h)) in free.iter().enumerate() {
            for col in ["decenter_x_mm", "decenter_y_mm", "tilt_x_deg", "tilt_y_deg"] {
                let rich = solved_cell_derivative(&set, k, *h, 4, col);
                let j = ds.cell_tangents[4][col][k];
                let rel = (j - rich).abs() / rich.abs();
                println!("{label:>34}: s4.{col:>13} / {name:>15}: derivative {j:+.12e}  fd {rich:+.12e}  rel {rel:.1e}");
                assert!((j - rich).abs() <= (1e-6 * rich.abs()).max(1e-9), "{label}: s4.{col} / {name}: {j} vs {rich}");
                if rich.abs() > 1e-9 {
                    worst = worst.max(rel);
                }
            }
        }
    }
    println!("chief-ray solve, every field type: worst relative error {worst:.1e}");
    // Real image heights: the object field is a real-ray solve of the built system; a chief-ray solve needs
    // it before, so the build refuses the pair, naming the field type and the surface.
    let real = finite(FieldType::RealImageHeight, vec![[1.5, 2.5]], vec![]);
    let e = ParamSet::new(real, GlassCatalog::builtin(), vec![Param::parse("s1.curvature").unwrap()]).and_then(|set| set.build()).err().expect("refused").to_string();
    assert!(e.contains("real image height") && e.contains("surface 4"), "{e}");
}

#[test]
fn degenerate_requests_are_reported() {
    let set = ParamSet::new(presets::spec("ap").unwrap(), GlassCatalog::builtin(), vec![]).unwrap();
    let ds = set.build().unwrap();
    let rays = RayBatch::chief_rays(&ds.system, &[[0.0, 0.0]], 520.0).unwrap();
    assert!(ds.trace(&rays).unwrap_err().to_string().contains("no free parameters"));
    // A parameter that does not act: the image surface's thickness → an exact zero column.
    let set = ParamSet::new(presets::spec("ap").unwrap(), GlassCatalog::builtin(), vec![Param::parse("s17.thickness_mm").unwrap()]).unwrap();
    let j = set.build().unwrap().trace(&rays).unwrap();
    assert!(j.jac.iter().all(|v| *v == 0.0));
    // A vignetted ray: classified, zero row, no NaN anywhere.
    let set = ParamSet::new(presets::spec("sp").unwrap(), GlassCatalog::builtin(), vec![Param::parse("s4.tilt_x_deg").unwrap()]).unwrap();
    let ds = set.build().unwrap();
    let mut rays = RayBatch::chief_rays(&ds.system, &[[0.0, 0.0]], 520.0).unwrap();
    rays.push(DVec3::new(0.0, 0.0, 0.0), DVec3::new(0.3, 0.0, 1.0).normalize(), 520.0);
    rays.push(DVec3::new(f64::NAN, 0.0, 0.0), DVec3::Z, 520.0);
    let j = ds.trace(&rays).unwrap();
    assert_eq!(j.traced.status[0], RayStatus::Ok);
    assert_ne!(j.traced.status[1], RayStatus::Ok);
    assert_eq!(j.traced.status[2], RayStatus::InvalidInput);
    assert!(j.jac.iter().all(|v| v.is_finite()));
    assert!(j.row(1, 0).iter().chain(j.row(2, 1)).all(|v| *v == 0.0));
}

#[test]
fn jacobians_do_not_depend_on_thread_count() {
    let set = ParamSet::new(presets::spec("msp").unwrap(), GlassCatalog::builtin(), ["s4.tilt_x_deg", "glass_vd:N-BK7", "wavelength"].iter().map(|t| Param::parse(t).unwrap()).collect()).unwrap();
    let ds = set.build().unwrap();
    let rays = RayBatch::seeded_workload(&ds.system, 3000, &[450.0, 650.0], 3).unwrap();
    let run = |threads| rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap().install(|| ds.trace(&rays).unwrap());
    let (a, b) = (run(1), run(2));
    assert_eq!(a.traced, b.traced);
    assert!(a.jac.iter().zip(&b.jac).all(|(x, y)| x.to_bits() == y.to_bits()));
}

/// A hit found another way (as a mesh backend would: an approximate point refined by Newton along the ray
/// onto the exact surface) gives the same derivatives as the analytic hit: only (point, direction,
/// surface) enter.
#[test]
fn hit_tangent_needs_only_the_refined_hit() {
    let s = SurfaceShape::EvenAsphere { curvature: 1.0 / 33.34, conic: -0.3, coefficients: vec![1e-5, -2e-7] };
    let p = DVec3::new(3.0, -2.0, -10.0);
    let d = DVec3::new(0.05, 0.02, 1.0).normalize();
    let exact = intersect(&s, p, d).unwrap();
    // "Mesh" hit: 20 µm off along the ray, then Newton on f(t) = z − sag.
    let mut t = exact.t + 0.02;
    for _ in 0..20 {
        let q = p + d * t;
        let (gx, gy) = s.sag_gradient(q.x, q.y);
        t -= (q.z - s.sag(q.x, q.y)) / (d.z - gx * d.x - gy * d.y);
    }
    let refined = p + d * t;
    assert!((refined - exact.point).length() < 1e-12);
    let dshape = ShapeTangent { curvature: 1.0, ..Default::default() };
    for dray in [DVec3::X, DVec3::new(0.0, 1.0, 0.3), DVec3::ZERO] {
        let a = hit_tangent(&s, exact.point, d, dray, &dshape);
        let b = hit_tangent(&s, refined, d, dray, &dshape);
        assert!((a.point - b.point).length() < 1e-9 && (a.normal - b.normal).length() < 1e-9);
    }
}

/// The (n_d, V_d) Cauchy model against the catalogue's Sellmeier curves over 450–650 nm.
#[test]
fn glass_model_deviation_from_catalogue() {
    let cat = GlassCatalog::builtin();
    for name in ["N-BK7", "N-SK2", "N-SF10", "N-BAF10", "SF10", "SK10"] {
        let g = cat.get(name).unwrap();
        let dev = diffcassi::diff::glass_model::model_deviation(&g, 450.0, 650.0);
        println!("glass_model {name:8} nd {:.5} vd {:.2}: max |n_cauchy − n_catalogue| over 450–650 nm = {dev:.2e}", g.nd, g.vd);
        assert!(dev < 2e-3, "{name}: {dev}");
    }
}

/// A ray whose recorded path is not the sequential one gets no Jacobian, with a reason: real Embree rays
/// (SP's split prism with its two coincident halves tilted against each other: the sequential model
/// crosses the second face at negative distance, Embree cannot), a followed total internal reflection
/// (as the Embree walker records it), a hit off the exact surface; and the batch-level errors.
#[test]
fn hit_paths_differing_from_the_sequential_one_are_reported() {
    let params = ["s4.tilt_x_deg", "glass_nd:N-BK7", "s16.curvature"].iter().map(|t| Param::parse(t).unwrap()).collect();
    let set = ParamSet::new(sp_like("sp"), GlassCatalog::builtin(), params).unwrap();
    let ds = set.build().unwrap();
    let rays = rays_for(&ds.system);
    let jb = ds.trace(&rays).unwrap();

    // Followed total internal reflection, recorded on the third interaction of ray 0.
    let (traced, log) = sequential_hits(&ds.system, &rays).unwrap();
    let mut tir = log.clone();
    tir.hits[tir.offsets[0] + 2].kind = HitKind::Reflection;
    let r = ds.jacobian_from_hits(&rays, &traced, &tir).unwrap();
    let why = r.unavailable[0].as_deref().unwrap();
    assert!(why.contains("total internal reflection") && why.contains("followed"), "{why}");
    assert!(!r.batch.usable(0) && r.batch.row(0, 0).iter().chain(r.batch.row(0, 4)).all(|v| *v == 0.0));
    assert_eq!(r.available_count(), jb.traced.ok_count() - 1);
    // A hit 1 µm off the surface (an unrefined mesh hit).
    let mut off = log.clone();
    off.hits[off.offsets[1] + 4].point.z += 1e-3;
    let why = ds.jacobian_from_hits(&rays, &traced, &off).unwrap().unavailable[1].clone().unwrap();
    assert!(why.contains("off the exact surface"), "{why}");
    // A skipped refracting surface.
    let mut skip = log.clone();
    skip.hits.remove(skip.offsets[2] + 3);
    for o in &mut skip.offsets[3..] {
        *o -= 1;
    }
    let why = ds.jacobian_from_hits(&rays, &traced, &skip).unwrap().unavailable[2].clone().unwrap();
    assert!(why.contains("was not hit"), "{why}");
    // Batch-level errors.
    let short = HitLog::from_rays((0..3).map(|i| log.ray(i).to_vec()));
    assert!(ds.jacobian_from_hits(&rays, &traced, &short).unwrap_err().to_string().contains("must be equal"));

    #[cfg(feature = "embree")]
    {
        let hj = ds.trace_embree(&EmbreeTracer::new(EmbreeOptions::user(Refinement::F64)), &rays).unwrap();
        let (mut differ, mut agree, mut max_shift_um) = (0, 0, 0.0f64);
        for i in 0..rays.len() {
            if !jb.usable(i) || hj.batch.traced.status[i] != RayStatus::Ok {
                continue;
            }
            match &hj.unavailable[i] {
                Some(why) => {
                    assert!(why.contains("path differs from the sequential one") && why.contains("surface 10"), "{why}");
                    assert!(!hj.batch.usable(i) && (0..6).all(|c| hj.batch.row(i, c).iter().all(|v| *v == 0.0)));
                    let shift = 1e3 * (hj.batch.traced.x[i] - jb.traced.x[i]).hypot(hj.batch.traced.y[i] - jb.traced.y[i]);
                    max_shift_um = max_shift_um.max(shift);
                    differ += 1;
                }
                None => {
                    for c in 0..6 {
                        for (a, b) in jb.row(i, c).iter().zip(hj.batch.row(i, c)) {
                            assert!((a - b).abs() <= 1e-9 * a.abs().max(1.0), "ray {i}: {b:e} vs {a:e}");
                        }
                    }
                    agree += 1;
                }
            }
        }
        println!("sp (coincident tilted prism halves), embree-user: {differ} rays reported unavailable (their Embree landing points differ from the sequential ones by up to {max_shift_um:.3} µm), {agree} agree");
        assert!(differ > 0 && agree > 0);
        // Unrefined hits are not on the surface whose equation is differentiated.
        let e = ds.trace_embree(&EmbreeTracer::new(EmbreeOptions::user(Refinement::None)), &rays).unwrap_err();
        assert!(e.to_string().contains("refine f64"), "{e}");
    }
}
