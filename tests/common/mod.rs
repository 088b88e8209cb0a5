//! Shared helpers for the integration tests: locating `../shared/reference`, reading Zemax exports, and
//! waiting for a CLI child process under a time limit.
#![allow(dead_code)]
use std::path::PathBuf;

/// `../shared/reference` beside the repository, or `None` (the caller prints SKIP and returns).
pub fn reference_dir() -> Option<PathBuf> {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/reference");
    p.is_dir().then_some(p)
}

#[macro_export]
macro_rules! require_reference {
    () => {
        match common::reference_dir() {
            Some(p) => p,
            None => {
                eprintln!("SKIP {}: ../shared/reference is absent", module_path!());
                return;
            }
        }
    };
}

/// A CSV with `#` header comments: (comments, column names, rows).
pub fn read_commented_csv(path: &std::path::Path) -> (Vec<String>, Vec<String>, Vec<Vec<f64>>) {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut comments = Vec::new();
    let mut header = Vec::new();
    let mut rows = Vec::new();
    for line in text.lines() {
        let l = line.trim();
        if l.is_empty() {
            continue;
        }
        if let Some(c) = l.strip_prefix('#') {
            comments.push(c.trim().to_string());
        } else if header.is_empty() {
            header = l.split(',').map(|s| s.trim().to_string()).collect();
        } else {
            rows.push(l.split(',').map(|s| s.trim().parse::<f64>().unwrap_or_else(|_| panic!("{}: bad number in `{l}`", path.display()))).collect());
        }
    }
    (comments, header, rows)
}

pub fn column(header: &[String], name: &str) -> usize {
    header.iter().position(|h| h == name).unwrap_or_else(|| panic!("no column {name} in {header:?}"))
}

/// A Zemax grid-distortion export: (Xref, Yref, rows of (x_field, y_field, real_x_abs, real_y_abs, pred_x_rel, pred_y_rel)).
pub fn zemax_grid(path: &std::path::Path) -> ([f64; 2], Vec<[f64; 6]>) {
    let (comments, header, rows) = read_commented_csv(path);
    let line = comments.iter().find(|c| c.contains("Xref_mm=")).expect("Xref line");
    let num = |key: &str| -> f64 {
        let s = &line[line.find(key).unwrap() + key.len()..];
        s.split_whitespace().next().unwrap().parse().unwrap()
    };
    let reference = [num("Xref_mm="), num("Yref_mm=")];
    let (xf, yf, rx, ry, px, py) = (
        column(&header, "x_field_mm"),
        column(&header, "y_field_mm"),
        column(&header, "real_x_mm"),
        column(&header, "real_y_mm"),
        column(&header, "pred_x_mm"),
        column(&header, "pred_y_mm"),
    );
    (reference, rows.iter().map(|r| [r[xf], r[yf], r[rx] + reference[0], r[ry] + reference[1], r[px], r[py]]).collect())
}

/// A Zemax ray-position export: (field (x, y) mm, rows of (px, py, x, y)).
pub fn zemax_rays(path: &std::path::Path) -> ([f64; 2], Vec<[f64; 4]>) {
    let (comments, header, rows) = read_commented_csv(path);
    let get = |key: &str| -> f64 {
        comments.iter().find_map(|c| c.strip_prefix(key)).map(|v| v.trim().parse().unwrap()).unwrap_or_else(|| panic!("no {key}"))
    };
    let field = [get("x_field_mm:"), get("y_field_mm:")];
    let (a, b, c, d) = (column(&header, "px"), column(&header, "py"), column(&header, "x_mm"), column(&header, "y_mm"));
    (field, rows.iter().map(|r| [r[a], r[b], r[c], r[d]]).collect())
}

pub const SYSTEMS: [(&str, &str); 2] = [("sp", "SP_single_prism_aligned"), ("ap", "AP_amici_prism_aligned")];
pub const WAVELENGTHS: [(usize, f64); 3] = [(1, 450.0), (2, 520.0), (3, 650.0)];

/// SP/mSP with surface 16 made an even asphere and surface 9 an order-1 break (tilted and decentred), so every
/// parameter kind acts (the Jacobian tests of `tests/derivatives.rs` and the acquisition gradients of
/// `tests/render_gradient.rs`).
pub fn sp_like(name: &str) -> diffcassi::spec::SystemSpec {
    use diffcassi::spec::{Cell, SurfaceKind};
    let mut spec = diffcassi::presets::spec(name).unwrap();
    spec.surfaces[16].kind = SurfaceKind::EvenAsphere;
    spec.surfaces[16].asphere_coefficients = vec![Cell::fixed(1e-5), Cell::fixed(-2e-7)];
    spec.surfaces[16].conic = Some(Cell::fixed(0.0));
    spec.surfaces[9].order = 1;
    spec.surfaces[9].tilt_x_deg = Some(Cell::fixed(0.5));
    spec.surfaces[9].decenter_y_mm = Some(Cell::fixed(0.1));
    spec
}

/// A thick N-BK7 singlet with the **object at infinity** (issue 42): R1 = 50 mm, R2 = −80 mm, 6 mm thick
/// (f ≈ 60 mm), the stop on a plane 5 mm behind it (so the paraxial entrance pupil, the stop's image through
/// the lens, moves with the lens's curvatures, thickness and glass), entrance pupil 8 mm, the image 48 mm
/// behind the stop (near the paraxial focus), fields (θx, θy) = (2°, 3°) first (an off-axis chief ray), then
/// on axis; no clear apertures (no ray is vignetted, so none changes status under a small change).
/// `chief_ray_break`: a Coordinate Break 20 mm after the stop whose decenters and tilts x, y are chief-ray
/// solves (the image 28 mm after it).
pub fn singlet_at_infinity(chief_ray_break: bool) -> diffcassi::spec::SystemSpec {
    use diffcassi::spec::{Cell, FieldType, RayAiming, SurfaceKind, SurfaceSpec, SystemAperture, SystemSpec};
    let mut stop = SurfaceSpec::standard(None, 48.0, None);
    stop.stop = true;
    let mut surfaces = vec![SurfaceSpec::standard(None, f64::INFINITY, None), SurfaceSpec::standard(Some(50.0), 6.0, Some("N-BK7")), SurfaceSpec::standard(Some(-80.0), 5.0, None), stop];
    if chief_ray_break {
        surfaces[3].thickness_mm = Cell::fixed(20.0);
        let mut cb = SurfaceSpec::new(SurfaceKind::CoordinateBreak);
        cb.thickness_mm = Cell::fixed(28.0);
        (cb.decenter_x_mm, cb.decenter_y_mm, cb.tilt_x_deg, cb.tilt_y_deg) = (Some(Cell::chief_ray(0.0)), Some(Cell::chief_ray(0.0)), Some(Cell::chief_ray(0.0)), Some(Cell::chief_ray(0.0)));
        surfaces.push(cb);
    }
    surfaces.push(SurfaceSpec::standard(None, 0.0, None));
    SystemSpec {
        name: "singlet at infinity".into(),
        description: String::new(),
        aperture: SystemAperture::EntrancePupilDiameter(8.0),
        ray_aiming: RayAiming::Off,
        wavelengths_nm: vec![450.0, 550.0, 650.0],
        primary_wavelength_nm: 550.0,
        fields_mm: Vec::new(),
        field_type: FieldType::Angle,
        fields_deg: vec![[2.0, 3.0], [0.0, 0.0]],
        vignetting_factors: Vec::new(),
        wavelength_policy: Default::default(),
        air_index: 1.0,
        glass_catalogs: vec![],
        surfaces,
        mechanics: None,
    }
}

/// AP/mAP with the prism's entrance face (surface `entrance`) made a weak even asphere (radius 200 mm), so
/// curvature, conic and asphere terms act on a refracting surface.
pub fn ap_like(name: &str, entrance: usize) -> diffcassi::spec::SystemSpec {
    use diffcassi::spec::{Cell, SurfaceKind};
    let mut spec = diffcassi::presets::spec(name).unwrap();
    let s = &mut spec.surfaces[entrance];
    s.kind = SurfaceKind::EvenAsphere;
    s.radius_mm = Some(Cell::fixed(200.0));
    s.conic = Some(Cell::fixed(0.0));
    s.asphere_coefficients = vec![Cell::fixed(1e-4), Cell::fixed(1e-6)];
    spec
}

/// The optical parameters of [`sp_like`] every kind of which acts on the detector image: thicknesses,
/// focal length, tilts, decentres, curvature, radius, conic, asphere terms, n_d and V_d (the image surface's
/// thickness, which moves no ray, is added by the Jacobian tests only).
pub const SP_LIKE_PARAMS: [&str; 22] = [
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

/// The optical parameters of [`ap_like`] (AP, entrance surface 4) of the acquisition-gradient test; the
/// Jacobian tests add `s1.thickness_mm` and `s15.thickness_mm`, which that test does not use.
pub const AP_LIKE_PARAMS: [&str; 18] = [
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

/// The optical parameters of [`ap_like`] built from mAP (entrance surface 6) of the acquisition-gradient
/// test; the Jacobian tests add `s20.thickness_mm`, which that test does not use.
pub const MAP_LIKE_PARAMS: [&str; 15] = [
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

/// Wait for `child` at most `limit`, polling every 20 ms; kill it past the limit (`None`: it was killed).
pub fn wait_with_limit(child: &mut std::process::Child, start: std::time::Instant, limit: std::time::Duration) -> Option<std::process::ExitStatus> {
    loop {
        if let Some(s) = child.try_wait().unwrap() {
            return Some(s);
        }
        if start.elapsed() >= limit {
            let _ = child.kill();
            let _ = child.wait();
            return None;
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
}

/// A scene cube's values (H, W, B, f32) in the differentiable renderer's layout (N = 1, B, H, W), f64.
pub fn cube_nbhw(scene: &diffcassi::scene::SpectralCube) -> Vec<f64> {
    let (hw, nb) = (scene.height * scene.width, scene.wavelengths_nm.len());
    let mut out = vec![0.0f64; nb * hw];
    for q in 0..hw {
        for b in 0..nb {
            out[b * hw + q] = scene.data[q * nb + b] as f64;
        }
    }
    out
}

/// A biconvex N-BK7 singlet (object 100 mm, NA 0.05) as a spec file's text: the held-out probers' test system
/// (rounds 11 and 12).
pub const SINGLET_TOML: &str = r#"name = "singlet"
wavelengths_nm = [450.0, 520.0, 650.0]
primary_wavelength_nm = 520.0
fields_mm = [[0.0, 0.0], [0.0, 0.05]]
[aperture]
type = "object_space_na"
value = 0.05
[[surfaces]]
type = "standard"
thickness_mm = 100.0
[[surfaces]]
type = "standard"
stop = true
radius_mm = 51.0
thickness_mm = 4.0
material = "N-BK7"
semi_diameter_mm = 8.0
[[surfaces]]
type = "standard"
radius_mm = -51.0
thickness_mm = 95.0
semi_diameter_mm = 8.0
[[surfaces]]
type = "standard"
semi_diameter_mm = 5.0
"#;

/// Two 8×8×3 scenes `s0.npy`, `s1.npy` (distinct patterns in [0, 1)) with their wavelengths (450, 550, 650 nm)
/// in the existing folder `scenes`: the probers' small `render-dataset` input (rounds 11 and 12).
pub fn two_small_scenes(scenes: &std::path::Path) {
    for k in 0..2 {
        let v: Vec<f32> = (0..8 * 8 * 3).map(|i| ((i * 7 + k * 3) % 11) as f32 / 11.0).collect();
        diffcassi::io::npy::write_npy_f32(scenes.join(format!("s{k}.npy")), &[8, 8, 3], &v).unwrap();
        diffcassi::io::npy::write_npy_f64(scenes.join(format!("s{k}_wavelengths_nm.npy")), &[3], &[450.0, 550.0, 650.0]).unwrap();
    }
}
