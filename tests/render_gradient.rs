//! The differentiable acquisition (`render::gradient`): vector–Jacobian products against central finite
//! differences of the same-sample acquisition for every parameter kind on SP, AP, mSP, mAP; against
//! finite differences of a many-ray expected image (the boundary bias included); scene and mask gradients
//! (the acquisition is linear in both); thread-count independence; the mapping cube's Jacobian; bad input.
//!
//! `cargo test --release --test render_gradient -- --nocapture` prints the measured errors.
use diffcassi::diff::{Param, ParamSet};
use diffcassi::materials::GlassCatalog;
use diffcassi::render::gradient::DiffRenderer;
use diffcassi::render::{RenderConfig, SpectralSampling};
use diffcassi::spec::{Cell, SurfaceKind, SystemSpec};

/// A small deterministic generator (xorshift) for scenes, masks and upstream gradients.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
    fn vec(&mut self, n: usize) -> Vec<f64> {
        (0..n).map(|_| self.next()).collect()
    }
}

const BANDS: [f64; 3] = [450.0, 550.0, 650.0];

fn config(size: usize, planes: usize, rays: usize, seed: u64) -> RenderConfig {
    let mut cfg = RenderConfig::paper(size);
    cfg.spectral = SpectralSampling::with_planes(BANDS.to_vec(), planes).unwrap();
    cfg.rays_per_pixel = rays;
    cfg.seed = seed;
    cfg
}

fn renderer(spec: SystemSpec, free: &[&str], cfg: RenderConfig) -> DiffRenderer {
    let params: Vec<Param> = free.iter().map(|t| Param::parse(t).unwrap()).collect();
    let set = ParamSet::new(spec, GlassCatalog::builtin(), params).unwrap();
    DiffRenderer::new(set, cfg, BANDS.to_vec()).unwrap()
}

/// Scene (N = 2), mask (some pixels closed, the others in (0, 1]) and an upstream gradient.
fn inputs(r: &DiffRenderer, seed: u64) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let mut rng = Rng(0x9E37_79B9_7F4A_7C15 ^ seed);
    let hw = r.config.scene_height * r.config.scene_width;
    let scene = rng.vec(2 * BANDS.len() * hw);
    let mask: Vec<f64> = rng.vec(hw).into_iter().map(|v| if v < 0.25 { 0.0 } else { v }).collect();
    let (h, w) = r.image_shape();
    let g: Vec<f64> = rng.vec(2 * h * w).into_iter().map(|v| v - 0.5).collect();
    (scene, mask, g)
}

fn loss(r: &DiffRenderer, scene: &[f64], mask: &[f64], g: &[f64]) -> f64 {
    r.render(scene, 2, mask).unwrap().iter().zip(g).map(|(a, b)| a * b).sum()
}

/// A step that moves landings by ~1e-4 pixel (so that few rays cross a pixel edge or change status).
fn step_for(p: &Param) -> f64 {
    match p {
        Param::Cell { column, .. } if column.ends_with("_deg") => 1e-6,
        Param::Cell { column, .. } if column == "conic" => 1e-5,
        Param::Cell { column, .. } if column.starts_with("asphere_") => 1e-9,
        Param::Cell { .. } => 1e-6,
        Param::Curvature { .. } => 1e-8,
        Param::GlassNd(_) => 1e-7,
        Param::GlassVd(_) => 1e-7,
        _ => unreachable!(),
    }
}

/// Central finite differences of the same-sample loss for every parameter, against the VJP; returns the
/// largest relative error (|fd − vjp| / max(|vjp|, 1e-3 · max_k |vjp_k|)).
fn check_same_sample(label: &str, spec: SystemSpec, free: &[&str]) -> f64 {
    let r = renderer(spec, free, config(5, 3, 2, 7));
    let (scene, mask, g) = inputs(&r, 1);
    let v = r.vjp(&scene, 2, &mask, &g).unwrap();
    let x0 = r.values().unwrap();
    let scale = v.params.iter().fold(0.0f64, |a, b| a.max(b.abs()));
    let mut worst = 0.0f64;
    for k in 0..x0.len() {
        let h = step_for(&r.set.free[k]) * x0[k].abs().max(1.0);
        let at = |d: f64| {
            let mut x = x0.clone();
            x[k] += d;
            loss(&r.with_values(&x).unwrap(), &scene, &mask, &g)
        };
        let fd = (at(h) - at(-h)) / (2.0 * h);
        let err = (fd - v.params[k]).abs() / v.params[k].abs().max(1e-3 * scale);
        println!("{label} {:>18}: vjp {:+.9e}  fd {:+.9e}  rel {:.1e}", r.set.free[k].name(), v.params[k], fd, err);
        worst = worst.max(err);
    }
    println!("{label}: worst relative error {worst:.2e} over {} parameters", x0.len());
    worst
}

/// SP/mSP with surface 16 an even asphere and break 9 of order 1 tilted (every parameter kind acts), as
/// the Jacobian tests of `tests/derivatives.rs`.
fn sp_like(name: &str) -> SystemSpec {
    let mut spec = diffcassi::presets::spec(name).unwrap();
    spec.surfaces[16].kind = SurfaceKind::EvenAsphere;
    spec.surfaces[16].asphere_coefficients = vec![Cell::fixed(1e-5), Cell::fixed(-2e-7)];
    spec.surfaces[16].conic = Some(Cell::fixed(0.0));
    spec.surfaces[9].order = 1;
    spec.surfaces[9].tilt_x_deg = Some(Cell::fixed(0.5));
    spec.surfaces[9].decenter_y_mm = Some(Cell::fixed(0.1));
    spec
}

/// AP/mAP with the prism's entrance face a weak even asphere.
fn ap_like(name: &str, entrance: usize) -> SystemSpec {
    let mut spec = diffcassi::presets::spec(name).unwrap();
    let s = &mut spec.surfaces[entrance];
    s.kind = SurfaceKind::EvenAsphere;
    s.radius_mm = Some(Cell::fixed(200.0));
    s.conic = Some(Cell::fixed(0.0));
    s.asphere_coefficients = vec![Cell::fixed(1e-4), Cell::fixed(1e-6)];
    spec
}

const SP_PARAMS: [&str; 22] = [
    "s0.thickness_mm",
    "s2.focal_length_mm",
    "s3.tilt_y_deg",
    "s4.tilt_x_deg",
    "s4.tilt_y_deg",
    "s4.tilt_z_deg",
    "s4.decenter_x_mm",
    "s5.tilt_y_deg",
    "s6.thickness_mm",
    "s7.tilt_y_deg",
    "s9.tilt_x_deg",
    "s9.decenter_y_mm",
    "s15.thickness_mm",
    "s16.curvature",
    "s16.conic",
    "s16.asphere_1",
    "s16.asphere_2",
    "s17.radius_mm",
    "glass_nd:N-BK7",
    "glass_vd:N-BK7",
    "glass_nd:N-BAF10",
    "glass_vd:SF10",
];

#[test]
fn vjp_matches_same_sample_finite_differences_sp_and_msp() {
    assert!(check_same_sample("sp", sp_like("sp"), &SP_PARAMS) <= 1e-6);
    assert!(check_same_sample("msp", sp_like("msp"), &SP_PARAMS) <= 1e-6);
}

#[test]
fn vjp_matches_same_sample_finite_differences_ap_and_map() {
    let ap = [
        "s0.thickness_mm",
        "s1.focal_length_mm",
        "s3.tilt_x_deg",
        "s3.tilt_y_deg",
        "s3.decenter_y_mm",
        "s4.curvature",
        "s4.conic",
        "s4.asphere_1",
        "s4.asphere_2",
        "s4.thickness_mm",
        "s5.tilt_y_deg",
        "s7.tilt_y_deg",
        "s7.thickness_mm",
        "s13.curvature",
        "glass_nd:N-SK2",
        "glass_vd:N-SK2",
        "glass_nd:N-SF10",
        "glass_vd:N-SF10",
    ];
    assert!(check_same_sample("ap", ap_like("ap", 4), &ap) <= 1e-6);
    let map = [
        "s0.thickness_mm",
        "s1.focal_length_mm",
        "s4.tilt_x_deg",
        "s5.tilt_y_deg",
        "s6.curvature",
        "s6.conic",
        "s6.asphere_1",
        "s6.asphere_2",
        "s7.tilt_y_deg",
        "s9.tilt_y_deg",
        "s9.thickness_mm",
        "s18.tilt_y_deg",
        "s19.tilt_x_deg",
        "glass_nd:N-SK2",
        "glass_vd:N-SF10",
    ];
    assert!(check_same_sample("map", ap_like("map", 6), &map) <= 1e-6);
}
