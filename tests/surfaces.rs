//! Mirrors (`GLAS MIRROR`), Toroidal surfaces and diffraction gratings (issue 42): exact traces against
//! closed-form results, classified bad cases, the spec formats both ways, the lane kernels against the
//! scalar one, and Jacobians against central differences.
//!
//! `cargo test --release --test integration surfaces:: -- --nocapture` prints the worst Jacobian agreement per parameter.
use diffcassi::diff::{Param, ParamSet};
use diffcassi::materials::GlassCatalog;
use diffcassi::prelude::*;
use diffcassi::spec::zmx::{import_zmx, to_zmx, ZmxOptions};
use diffcassi::spec::{SurfaceKind, SurfaceSpec, SystemAperture};
use diffcassi::tracer::{Kernel, SimdLevel};
use glam::DVec3;

pub(crate) fn system(name: &str, surfaces: Vec<SurfaceSpec>, na: f64) -> SystemSpec {
    SystemSpec {
        name: name.into(),
        description: String::new(),
        aperture: SystemAperture::ObjectSpaceNa(na),
        ray_aiming: Default::default(),
        wavelengths_nm: vec![450.0, 520.0, 650.0],
        primary_wavelength_nm: 520.0,
        fields_mm: vec![[0.0, 0.0], [0.0, 1.0], [1.0, 0.5]],
        field_type: Default::default(),
        fields_deg: vec![],
        vignetting_factors: Vec::new(),
        wavelength_policy: Default::default(),
        air_index: 1.0,
        glass_catalogs: vec![],
        surfaces,
        mechanics: None,
    }
}

pub(crate) fn stop(mut s: SurfaceSpec) -> SurfaceSpec {
    s.stop = true;
    s
}

pub(crate) fn mirror(radius: Option<f64>, conic: Option<f64>, thickness: f64) -> SurfaceSpec {
    let mut s = SurfaceSpec::standard(radius, thickness, Some("MIRROR"));
    s.conic = conic.map(diffcassi::spec::Cell::fixed);
    s
}

/// A concave ellipsoidal mirror whose foci are 100 mm and 50 mm in front of its vertex: the object point at
/// one focus is imaged perfectly onto the other (1/s + 1/s′ = 2/|R|, k = −((s − s′)/(s + s′))²), and the
/// image lies at the negative thickness −50 mm (OpticStudio's convention after a mirror).
fn ellipsoid_mirror() -> SystemSpec {
    let (s, s2): (f64, f64) = (100.0, 50.0);
    let r = -2.0 * s * s2 / (s + s2);
    let k = -((s - s2) / (s + s2)).powi(2);
    system("ellipsoid", vec![SurfaceSpec::standard(None, s, None), stop(mirror(Some(r), Some(k), -s2)), SurfaceSpec::standard(None, 0.0, None)], 0.1)
}

/// Two 45° fold mirrors built with Coordinate Breaks (OpticStudio's fold-mirror idiom: break, mirror, break;
/// the thickness after the second break is negative), then a singlet and the image.
pub(crate) fn fold_mirrors() -> SystemSpec {
    let cb = |tx: f64, t: f64| SurfaceSpec::coordinate_break(0.0, 0.0, tx, 0.0, 0.0, t);
    system(
        "fold",
        vec![
            SurfaceSpec::standard(None, 40.0, None),
            stop(SurfaceSpec::standard(None, 20.0, None)),
            cb(45.0, 0.0),
            mirror(None, None, 0.0),
            cb(45.0, -30.0),
            cb(-45.0, 0.0),
            mirror(None, None, 0.0),
            cb(-45.0, 20.0),
            SurfaceSpec::standard(Some(30.0), 4.0, Some("N-BK7")),
            SurfaceSpec::standard(Some(-30.0), 25.0, None),
            SurfaceSpec::standard(None, 0.0, None),
        ],
        0.05,
    )
}

/// A plane transmission grating in air (lines/µm `t`, order `m`) 20 mm behind the stop, the image 30 mm on.
pub(crate) fn plane_grating(t: f64, m: i32) -> SystemSpec {
    system(
        "grating",
        vec![SurfaceSpec::standard(None, 50.0, None), stop(SurfaceSpec::grating(None, t, m, 30.0, None)), SurfaceSpec::standard(None, 0.0, None)],
        0.05,
    )
}

/// A curved grating on the front of an N-BK7 lens (conic substrate), then the lens's back, then the image.
pub(crate) fn curved_grating() -> SystemSpec {
    let mut g = SurfaceSpec::grating(Some(40.0), 0.3, -1, 5.0, Some("N-BK7"));
    g.conic = Some(diffcassi::spec::Cell::fixed(-0.5));
    g.stop = true;
    system("curved grating", vec![SurfaceSpec::standard(None, 60.0, None), g, SurfaceSpec::standard(Some(-60.0), 40.0, None), SurfaceSpec::standard(None, 0.0, None)], 0.05)
}

pub(crate) fn toroid_lens(rotation: Option<f64>) -> SystemSpec {
    let mut t = SurfaceSpec::toroidal(Some(20.0), rotation, 5.0, Some("N-BK7"));
    t.stop = true;
    system("toroid", vec![SurfaceSpec::standard(None, 80.0, None), t, SurfaceSpec::standard(None, 40.0, None), SurfaceSpec::standard(None, 0.0, None)], 0.05)
}

fn build(spec: &SystemSpec) -> SequentialSystem {
    SequentialSystem::build(spec).unwrap_or_else(|e| panic!("{}: {e}", spec.name))
}

fn trace(sys: &SequentialSystem, rays: &RayBatch) -> TracedBatch {
    AnalyticTracer::with_kernel(Kernel::Scalar).trace(sys, rays).unwrap()
}

#[test]
fn ellipsoidal_mirror_images_its_focus_perfectly_behind_a_negative_thickness() {
    let sys = build(&ellipsoid_mirror());
    let mut rays = RayBatch::default();
    for (px, py) in [(0.0, 0.0), (1.0, 0.0), (0.0, -1.0), (0.6, 0.7), (-0.3, 0.9)] {
        rays.extend(&RayBatch::for_field(&sys, [0.0, 0.0], &[[px, py]], 520.0).unwrap());
    }
    let out = trace(&sys, &rays);
    for i in 0..out.len() {
        assert_eq!(out.status[i], RayStatus::Ok);
        assert!(out.x[i].abs() < 1e-12 && out.y[i].abs() < 1e-12, "ray {i}: ({}, {})", out.x[i], out.y[i]);
        assert!(out.dir_z[i] < 0.0, "after the mirror the ray travels toward −z");
    }
    // The marginal ray (pupil edge) lands as precisely as the chief ray; an off-axis point does not.
    let off = trace(&sys, &RayBatch::for_field(&sys, [0.0, 1.0], &[[0.0, 1.0], [0.0, -1.0]], 520.0).unwrap());
    assert!((off.y[0] - off.y[1]).abs() > 1e-6);
    // Paraxially the image is inverted with magnification −s′/s = −0.5.
    let chief = trace(&sys, &RayBatch::chief_rays(&sys, &[[0.0, 1e-4]], 520.0).unwrap());
    assert!((chief.y[0] / 1e-4 + 0.5).abs() < 1e-6, "magnification {}", chief.y[0] / 1e-4);
}

#[test]
fn fold_mirrors_keep_the_lens_focus_and_reverse_twice() {
    let folded = build(&fold_mirrors());
    // The unfolded twin: the same path lengths 20 + 30 + 20 mm in a straight line.
    let mut unfolded = fold_mirrors();
    unfolded.surfaces = vec![
        SurfaceSpec::standard(None, 40.0, None),
        stop(SurfaceSpec::standard(None, 70.0, None)),
        SurfaceSpec::standard(Some(30.0), 4.0, Some("N-BK7")),
        SurfaceSpec::standard(Some(-30.0), 25.0, None),
        SurfaceSpec::standard(None, 0.0, None),
    ];
    let straight = build(&unfolded);
    for field in [[0.0, 0.0], [0.0, 1.0], [1.0, 0.5]] {
        let pupil = [[0.0, 0.0], [0.5, 0.0], [0.0, 0.5], [-0.4, -0.4]];
        let a = trace(&folded, &RayBatch::for_field(&folded, field, &pupil, 520.0).unwrap());
        let b = trace(&straight, &RayBatch::for_field(&straight, field, &pupil, 520.0).unwrap());
        for i in 0..a.len() {
            assert_eq!(a.status[i], RayStatus::Ok);
            // Two reflections about x: y is mirrored twice (back to itself); the path is the same.
            assert!((a.x[i] - b.x[i]).abs() < 1e-12 && (a.y[i] - b.y[i]).abs() < 1e-12, "field {field:?} ray {i}: ({}, {}) vs ({}, {})", a.x[i], a.y[i], b.x[i], b.y[i]);
        }
    }
}

#[test]
fn grazing_mirror_and_bad_rays_are_classified_never_nan() {
    // A ray parallel to a flat mirror never meets it; one at 1e-9 rad from grazing reflects.
    let spec = system("flat", vec![SurfaceSpec::standard(None, 10.0, None), stop(mirror(None, None, -10.0)), SurfaceSpec::standard(None, 0.0, None)], 0.05);
    let sys = build(&spec);
    let mut rays = RayBatch::default();
    rays.push(DVec3::new(0.0, 0.0, 0.0), DVec3::new(0.0, 1.0, 0.0), 520.0);
    rays.push(DVec3::new(0.0, 0.0, 0.0), DVec3::new(0.0, 1.0, 1e-9), 520.0);
    rays.push(DVec3::new(0.0, 0.0, 0.0), DVec3::new(f64::NAN, 0.0, 1.0), 520.0);
    for kernel in [Kernel::Scalar, Kernel::Simd(None)] {
        let out = AnalyticTracer::with_kernel(kernel).trace(&sys, &rays).unwrap();
        assert_eq!(out.status[0], RayStatus::Missed);
        assert_ne!(out.status[1], RayStatus::Ok, "a 1e-9 rad ray reaches the mirror 1e10 mm away: out of range");
        assert_eq!(out.status[2], RayStatus::InvalidInput);
        assert!(out.x.iter().chain(&out.y).chain(&out.dir_z).all(|v| v.is_finite()));
    }
    // Mirrors on the object or image surface, or on a Paraxial surface, are spec errors naming the field.
    let mut bad = spec.clone();
    bad.surfaces[2].material = Some("MIRROR".into());
    let e = SequentialSystem::build(&bad).unwrap_err().to_string();
    assert!(e.contains("material") && e.contains("MIRROR"), "{e}");
}

#[test]
fn plane_grating_follows_the_grating_equation() {
    // Independent of the library: n sin θ₂ = n sin θ₁ − mλT in the y–z plane, then straight to z = 30 mm.
    let (t, m) = (0.6, 1);
    let sys = build(&plane_grating(t, m));
    for &wl in &[450.0, 520.0, 650.0] {
        for &(x0, y0) in &[(0.0, 0.0), (0.5, -1.0), (-1.0, 2.0)] {
            let o = DVec3::new(x0, y0, 0.0);
            let d = DVec3::new(0.01, -0.02, 1.0).normalize();
            let mut rays = RayBatch::default();
            rays.push(o, d, wl);
            let out = trace(&sys, &rays);
            assert_eq!(out.status[0], RayStatus::Ok);
            let hit = o + d * (50.0 / d.z);
            let (l, mm) = (d.x, d.y - m as f64 * wl * 1e-3 * t);
            let n = (1.0 - l * l - mm * mm).sqrt();
            let x = hit.x + l / n * 30.0;
            let y = hit.y + mm / n * 30.0;
            assert!((out.x[0] - x).abs() < 1e-12 && (out.y[0] - y).abs() < 1e-12, "{wl} nm: ({}, {}) vs ({x}, {y})", out.x[0], out.y[0]);
            assert!((out.dir_y[0] - mm).abs() < 1e-15 && (out.dir_x[0] - l).abs() < 1e-15);
        }
    }
}

#[test]
fn evanescent_orders_and_bad_gratings_are_classified_or_refused() {
    // 2 lines/µm at 650 nm: |mλT| = 1.3 > 1: the first order does not propagate in air.
    let sys = build(&plane_grating(2.0, 1));
    let rays = RayBatch::for_field(&sys, [0.0, 0.0], &[[0.0, 0.0], [0.5, 0.5]], 650.0).unwrap();
    for kernel in [Kernel::Scalar, Kernel::Simd(None)] {
        let out = AnalyticTracer::with_kernel(kernel).trace(&sys, &rays).unwrap();
        assert!(out.status.iter().all(|s| *s == RayStatus::Evanescent), "{:?}", out.status);
        assert!(out.surface.iter().all(|s| *s == 1));
        assert!(out.x.iter().chain(&out.y).chain(&out.dir_x).all(|v| *v == 0.0));
    }
    assert_eq!(RayStatus::Evanescent.label(), "evanescent");
    for (lines, what) in [(0.0, "0"), (-1.0, "-1"), (f64::NAN, "NaN"), (f64::INFINITY, "inf")] {
        let e = SequentialSystem::build(&plane_grating(lines, 1)).unwrap_err().to_string();
        assert!(e.contains("grating_lines_per_um") && e.contains(what), "{e}");
    }
    let mut half = plane_grating(0.5, 1);
    half.surfaces[1].grating_order = Some(diffcassi::spec::Cell::fixed(0.5));
    assert!(SequentialSystem::build(&half).unwrap_err().to_string().contains("grating_order"));
    half.surfaces[1].grating_order = Some(diffcassi::spec::Cell::fixed(1e12));
    let e = SequentialSystem::build(&half).unwrap_err().to_string();
    assert!(e.contains("grating_order") && e.contains("magnitude at most 10⁶"), "{e}");
    let mut eff = plane_grating(0.5, 1);
    eff.surfaces[1].grating_efficiency = Some(1.5);
    assert!(SequentialSystem::build(&eff).unwrap_err().to_string().contains("grating_efficiency"));
    // A .zmx DGRATING with 0 lines: refused by the reader, naming the surface, the line and the record
    // (`PARM`, parameter 1), as the file's other errors are (round 19; it named the spec's field).
    let mut z = to_zmx(&plane_grating(0.5, 1)).unwrap();
    z = z.replace("PARM 1 0.5", "PARM 1 0");
    let e = import_zmx(z.as_bytes(), "g.zmx", None, &ZmxOptions::default()).map(|_| ()).unwrap_err().to_string();
    assert!(e.contains("`PARM`: surface 1 (Diffraction Grating) parameter 1, lines per µm, is 0"), "{e}");
}

#[test]
fn toroid_sections_are_the_spheres_of_its_two_radii() {
    // Rays in the y–z plane see the YZ curve (radius 20); rays in the x–z plane the radius of rotation.
    let sphere = |r: f64| {
        let mut s = toroid_lens(None);
        s.surfaces[1] = stop(SurfaceSpec::standard(Some(r), 5.0, Some("N-BK7")));
        build(&s)
    };
    for rot in [None, Some(35.0), Some(-50.0)] {
        let tor = build(&toroid_lens(rot));
        let yz = RayBatch::for_field(&tor, [0.0, 1.0], &[[0.0, 0.8], [0.0, -0.6], [0.0, 0.0]], 520.0).unwrap();
        let a = trace(&tor, &yz);
        let b = trace(&sphere(20.0), &yz);
        for i in 0..a.len() {
            assert!((a.y[i] - b.y[i]).abs() < 1e-11 && a.x[i].abs() < 1e-15, "{rot:?} yz ray {i}: {} vs {}", a.y[i], b.y[i]);
        }
        let xz = RayBatch::for_field(&tor, [1.0, 0.0], &[[0.8, 0.0], [-0.6, 0.0]], 520.0).unwrap();
        let a = trace(&tor, &xz);
        match rot {
            // The cylinder: no power in x, so x-z rays go on as through a plane.
            None => {
                let b = trace(&sphere(1e9), &xz);
                for i in 0..a.len() {
                    assert!((a.x[i] - b.x[i]).abs() < 1e-6, "cylinder xz ray {i}: {} vs {}", a.x[i], b.x[i]);
                }
            }
            Some(r) => {
                let b = trace(&sphere(r), &xz);
                for i in 0..a.len() {
                    assert!((a.x[i] - b.x[i]).abs() < 1e-11 && a.y[i].abs() < 1e-15, "{r} xz ray {i}: {} vs {}", a.x[i], b.x[i]);
                }
            }
        }
    }
    let mut zero = toroid_lens(Some(1.0));
    zero.surfaces[1].rotation_radius_mm = Some(diffcassi::spec::Cell::fixed(0.0));
    assert!(SequentialSystem::build(&zero).unwrap_err().to_string().contains("rotation_radius_mm"));
}

pub(crate) fn all_new_kinds() -> SystemSpec {
    let mut t = SurfaceSpec::toroidal(Some(-25.0), Some(40.0), 4.0, Some("N-BK7"));
    t.asphere_coefficients = vec![diffcassi::spec::Cell::fixed(1.0e-5), diffcassi::spec::Cell::fixed(-3.0e-8)];
    t.conic = Some(diffcassi::spec::Cell::fixed(-0.3));
    let mut g = SurfaceSpec::grating(Some(-200.0), 0.0830131767, -1, 20.0, None);
    g.grating_efficiency = Some(0.73);
    let mut m = mirror(Some(-120.0), Some(-1.0), -30.0);
    m.comment = "paraboloid".into();
    system(
        "all",
        vec![
            SurfaceSpec::standard(None, 50.0, None),
            stop(SurfaceSpec::toroidal(Some(30.0), None, 3.0, Some("N-BK7"))),
            SurfaceSpec::standard(None, 10.0, None),
            t,
            SurfaceSpec::standard(None, 10.0, None),
            g,
            SurfaceSpec::coordinate_break(0.0, 0.0, 10.0, 0.0, 0.0, 0.0),
            m,
            SurfaceSpec::standard(None, 0.0, None),
        ],
        0.02,
    )
}

#[test]
fn new_surfaces_round_trip_bit_identical_through_toml_json_and_zmx() {
    let spec = all_new_kinds();
    build(&spec);
    let t = diffcassi::spec::to_toml(&spec).unwrap();
    assert_eq!(diffcassi::spec::from_toml(&t, "x.toml").unwrap(), spec);
    let j = diffcassi::spec::to_json(&spec).unwrap();
    assert_eq!(diffcassi::spec::from_json(&j, "x.json").unwrap(), spec);
    let z = to_zmx(&spec).unwrap();
    for needle in ["TYPE TOROIDAL", "TYPE DGRATING", "GLAS MIRROR", "PARM 1 40.0", "PARM 2 1e-5", "PARM 1 0.0830131767", "PARM 2 -1.0", "DCGE 0.73", "XDAT 1 0"] {
        assert!(z.contains(needle), "`{needle}` missing from\n{z}");
    }
    let back = import_zmx(z.as_bytes(), "all.zmx", None, &ZmxOptions::default()).unwrap();
    assert!(back.ignored.is_empty());
    assert_eq!(back.spec.surfaces, spec.surfaces);
    // And the same traced landings.
    let (a, b) = (build(&spec), build(&back.spec));
    let rays = RayBatch::for_field(&a, [0.0, 0.5], &[[0.0, 0.0], [0.3, 0.3]], 520.0).unwrap();
    assert_eq!(trace(&a, &rays), trace(&b, &rays));
}

#[test]
fn zmx_reader_takes_opticstudio_records_and_refuses_zernike_terms() {
    let text = "MODE SEQ\nUNIT MM X W X CM MR CPMM\nOBNA 0.05 0\nFTYP 1 0 1 1 0 0 0\nXFLN 0\nYFLN 0\nWAVM 1 0.55 1\nPWAV 1\n\
SURF 0\n  TYPE STANDARD\n  CURV 0.0 0 0 0 0 \"\"\n  DISZ 50\nSURF 1\n  STOP\n  TYPE TOROIDAL\n  CURV 0.05 0 0 0 0 \"\"\n  PARM 0 0\n  PARM 1 0\n  PARM 2 0\n  PARM 3 0\n  \
XDAT 1 0.000000000000E+00 0 0 1.0 0.0 0 \"\"\n  XDAT 2 1.000000000000E+02 0 0 1.0 0.0 0 \"\"\n  DISZ 5\n  GLAS N-BK7 0 0 1.5 40 0 0 0 0 0 0\nSURF 2\n  TYPE DGRATING\n  CURV 0.0\n  \
PARM 1 0.2\n  PARM 2 -1\n  DISZ -20\n  GLAS MIRROR 0 0 1.5 40 0 0 0 0 0 0\nSURF 3\n  TYPE STANDARD\n  DISZ 0\n";
    let got = import_zmx(text.as_bytes(), "t.zmx", None, &ZmxOptions::default()).unwrap();
    let s = &got.spec.surfaces;
    assert_eq!((s[1].kind, s[1].rotation_radius_mm.clone(), s[1].radius_mm.as_ref().map(|c| c.value)), (SurfaceKind::Toroidal, None, Some(20.0)));
    assert_eq!(s[2].kind, SurfaceKind::DiffractionGrating);
    assert!(s[2].is_mirror());
    assert_eq!((s[2].grating_lines_per_um.as_ref().unwrap().value, s[2].grating_order.as_ref().unwrap().value), (0.2, -1.0));
    let sys = build(&got.spec);
    let out = trace(&sys, &RayBatch::for_field(&sys, [0.0, 0.0], &[[0.0, 0.0], [0.5, 0.5]], 550.0).unwrap());
    assert!(out.status.iter().all(|s| *s == RayStatus::Ok));
    let e = import_zmx(text.replace("XDAT 1 0.000000000000E+00", "XDAT 1 3").as_bytes(), "t.zmx", None, &ZmxOptions::default()).unwrap_err().to_string();
    assert!(e.contains("XDAT") && e.contains("Zernike"), "{e}");
    let e = import_zmx(text.replace("TYPE DGRATING", "TYPE BINARY_2").as_bytes(), "t.zmx", None, &ZmxOptions::default()).unwrap_err().to_string();
    assert!(e.contains("BINARY_2") && e.contains("line"), "{e}");
}

#[test]
fn lane_kernels_equal_the_scalar_kernel_on_mirrors_toroids_and_gratings() {
    for spec in [ellipsoid_mirror(), fold_mirrors(), plane_grating(0.6, 1), plane_grating(2.0, 1), curved_grating(), toroid_lens(Some(35.0)), toroid_lens(None), all_new_kinds()] {
        let sys = build(&spec);
        let mut rays = RayBatch::default();
        for &w in &[450.0, 520.0, 650.0] {
            for &f in &sys.spec.fields_mm {
                rays.extend(&RayBatch::for_field(&sys, f, &[[0.0, 0.0], [0.9, 0.0], [0.0, -0.9], [0.5, 0.5], [-0.7, 0.2]], w).unwrap());
            }
        }
        let scalar = AnalyticTracer::with_kernel(Kernel::Scalar).trace(&sys, &rays).unwrap();
        for level in SimdLevel::available() {
            let simd = AnalyticTracer::with_kernel(Kernel::Simd(Some(level))).trace(&sys, &rays).unwrap();
            assert_eq!(simd, scalar, "{} at {level:?}", spec.name);
        }
        // The f32 lanes: same statuses, landings within 1 µm.
        let f32 = diffcassi::tracer::AnalyticF32Tracer::new(SimdLevel::detect()).trace(&sys, &rays).unwrap();
        for i in 0..rays.len() {
            assert_eq!(f32.status[i], scalar.status[i], "{} ray {i}", spec.name);
            assert!((f32.x[i] - scalar.x[i]).abs() < 1e-3 && (f32.y[i] - scalar.y[i]).abs() < 1e-3, "{} ray {i}", spec.name);
        }
    }
}

// ---- Jacobians against central differences -------------------------------------------------------------

fn outputs(sys: &SequentialSystem, rays: &RayBatch) -> Vec<Option<[f64; 6]>> {
    let t = AnalyticTracer::default().trace(sys, rays).unwrap();
    (0..t.len()).map(|i| (t.status[i] == RayStatus::Ok).then(|| [t.x[i], t.y[i], t.z[i], t.dir_x[i], t.dir_y[i], t.dir_z[i]])).collect()
}

fn moved(set: &ParamSet, rays: &RayBatch, k: usize, delta: f64) -> Vec<Option<[f64; 6]>> {
    let mut rays = rays.clone();
    let sys = match &set.free[k] {
        Param::Wavelength => {
            rays.wavelength_nm.iter_mut().for_each(|w| *w += delta);
            set.system().unwrap()
        }
        Param::RayOrigin(a) => {
            [&mut rays.origin_x, &mut rays.origin_y, &mut rays.origin_z][*a].iter_mut().for_each(|v| *v += delta);
            set.system().unwrap()
        }
        Param::RayDirection(a) => {
            [&mut rays.dir_x, &mut rays.dir_y, &mut rays.dir_z][*a].iter_mut().for_each(|v| *v += delta);
            set.system().unwrap()
        }
        p => {
            let mut s = set.clone();
            s.set(p, set.value(p).unwrap() + delta).unwrap();
            s.system().unwrap()
        }
    };
    outputs(&sys, &rays)
}

fn step_for(p: &Param) -> f64 {
    match p {
        Param::Cell { column, .. } if column.ends_with("_deg") => 1e-3,
        Param::Cell { column, .. } if column == "conic" => 1e-3,
        Param::Curvature { .. } => 1e-4,
        Param::Wavelength => 1e-2,
        Param::RayDirection(_) => 1e-4,
        _ => 1e-3,
    }
}

/// Richardson-extrapolated central differences (h, h/2, h/4; error O(h⁶)).
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

fn check_jacobians(spec: SystemSpec, free: &[&str]) {
    let params: Vec<Param> = free.iter().map(|t| Param::parse(t).unwrap()).collect();
    let set = ParamSet::new(spec.clone(), GlassCatalog::builtin(), params).unwrap();
    let ds = set.build().unwrap();
    let mut rays = RayBatch::default();
    for &w in &[450.0, 520.0, 650.0] {
        for &f in &ds.system.spec.fields_mm {
            rays.extend(&RayBatch::for_field(&ds.system, f, &[[0.0, 0.0], [0.7, 0.0], [0.0, 0.7], [-0.5, -0.5]], w).unwrap());
        }
    }
    let jb = ds.trace(&rays).unwrap();
    assert_eq!(AnalyticTracer::default().trace(&ds.system, &rays).unwrap(), jb.traced, "{}: values are the plain tracer's", spec.name);
    for k in 0..set.len() {
        let fd = finite_differences(&set, &rays, k);
        let (mut worst, mut compared) = (0.0f64, 0);
        for (i, fd_i) in fd.iter().enumerate() {
            let Some(fd_i) = fd_i else { continue };
            if !jb.usable(i) {
                continue;
            }
            for (c, &f) in fd_i.iter().enumerate() {
                let j = jb.row(i, c)[k];
                let err = (j - f).abs();
                assert!(err <= (1e-6 * f.abs()).max(1e-9), "{} {}: ray {i} component {c}: jacobian {j:e} vs FD {f:e}", spec.name, set.free[k]);
                if f.abs() > 1e-6 {
                    worst = worst.max(err / f.abs());
                }
                compared += 1;
            }
        }
        assert!(compared >= rays.len() * 3, "{} {}: only {compared} entries compared", spec.name, set.free[k]);
        println!("{:16} {:22} worst relative error vs FD {worst:.1e} ({compared} entries)", spec.name, set.free[k].name());
    }
}

#[test]
fn jacobians_through_mirrors_equal_central_differences() {
    let mut e = ellipsoid_mirror();
    e.fields_mm = vec![[0.0, 0.0], [0.0, 2.0], [1.5, 1.0]];
    check_jacobians(e, &["s0.thickness_mm", "s1.curvature", "s1.conic", "s1.thickness_mm", "wavelength", "ray.origin_y", "ray.dir_x"]);
    check_jacobians(fold_mirrors(), &["s2.tilt_x_deg", "s4.tilt_x_deg", "s5.tilt_y_deg", "s4.thickness_mm", "s6.curvature", "glass_nd:N-BK7", "wavelength", "ray.dir_y"]);
}

#[test]
fn jacobians_through_gratings_equal_central_differences() {
    let mut g = plane_grating(0.6, 1);
    g.surfaces.insert(1, SurfaceSpec::coordinate_break(0.0, 0.0, 3.0, -2.0, 0.0, 0.0));
    check_jacobians(g, &["s1.tilt_x_deg", "s1.tilt_y_deg", "s0.thickness_mm", "s2.thickness_mm", "s2.curvature", "wavelength", "ray.origin_x", "ray.dir_y"]);
    check_jacobians(curved_grating(), &["s1.curvature", "s1.conic", "s1.thickness_mm", "glass_nd:N-BK7", "glass_vd:N-BK7", "wavelength", "ray.dir_x", "ray.dir_y"]);
    // A reflective grating (GLAS MIRROR on a DGRATING), folded back.
    let mut r = plane_grating(0.3, 1);
    r.surfaces[1].material = Some("MIRROR".into());
    r.surfaces[1].thickness_mm = diffcassi::spec::Cell::fixed(-30.0);
    r.surfaces.insert(1, SurfaceSpec::coordinate_break(0.0, 0.0, 10.0, 0.0, 0.0, 0.0));
    check_jacobians(r, &["s1.tilt_x_deg", "s2.thickness_mm", "wavelength", "ray.dir_y"]);
}

#[test]
fn jacobians_through_toroids_equal_central_differences_and_their_figure_is_refused() {
    let mut t = toroid_lens(Some(35.0));
    t.surfaces.insert(1, SurfaceSpec::coordinate_break(0.2, -0.1, 1.0, 2.0, 0.0, 0.0));
    check_jacobians(t.clone(), &["s1.tilt_x_deg", "s1.tilt_y_deg", "s1.decenter_x_mm", "s2.thickness_mm", "glass_nd:N-BK7", "wavelength", "ray.dir_x"]);
    let e = ParamSet::new(t, GlassCatalog::builtin(), vec![Param::parse("s2.rotation_radius_mm").unwrap()]).unwrap_err().to_string();
    assert!(e.contains("Toroidal"), "{e}");
}

// ---- the grating CASSI preset -------------------------------------------------------------------------

#[test]
fn gsp_grating_is_computed_from_sp_span_and_disperses_alike() {
    let sp = build(&diffcassi::presets::spec("sp").unwrap());
    let gsp = build(&diffcassi::presets::spec("gsp").unwrap());
    let span = |sys: &SequentialSystem| {
        let a = trace(sys, &RayBatch::chief_rays(sys, &[[0.0, 0.0]], 450.0).unwrap());
        let b = trace(sys, &RayBatch::chief_rays(sys, &[[0.0, 0.0]], 650.0).unwrap());
        assert_eq!((a.status[0], b.status[0]), (RayStatus::Ok, RayStatus::Ok));
        (b.x[0] - a.x[0], b.y[0] - a.y[0])
    };
    let (s_sp, _) = span(&sp);
    // T from the grating equation and the doublet's nominal 50 mm focal length (the preset's doc).
    let f = 50.0;
    let spread = |t: f64| {
        let th = |l: f64| (l * 1e-3 * t).asin();
        f * ((th(650.0) - th(520.0)).tan() + (th(520.0) - th(450.0)).tan())
    };
    let (mut lo, mut hi) = (0.0, 1.0);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if spread(mid) < s_sp {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    assert!((lo - diffcassi::presets::GSP_LINES_PER_UM).abs() < 1e-12, "T = {lo} vs the preset's {}", diffcassi::presets::GSP_LINES_PER_UM);
    let (s_g, dy) = span(&gsp);
    println!("450–650 nm span of the centre field: SP {:.2} µm, gsp {:.2} µm (y {:.2e})", s_sp * 1e3, s_g * 1e3, dy);
    assert!(s_g * s_sp > 0.0, "dispersion along +x in both");
    assert!((s_g - s_sp).abs() < 0.02 * s_sp, "gsp span {s_g} vs SP {s_sp}");
    assert!(dy.abs() < 1e-9);
    // Every field and wavelength arrives, and the primary chief ray lands on the detector centre.
    for w in [450.0, 520.0, 650.0] {
        let out = trace(&gsp, &RayBatch::chief_rays(&gsp, &gsp.spec.fields_mm, w).unwrap());
        assert!(out.status.iter().all(|s| *s == RayStatus::Ok) && out.x.iter().chain(&out.y).all(|v| v.abs() < 5.0));
    }
    let c = trace(&gsp, &RayBatch::chief_rays(&gsp, &[[0.0, 0.0]], 520.0).unwrap());
    assert!(c.x[0].abs() < 1e-9 && c.y[0].abs() < 1e-9);
    // The GPU plan and the reverse-mode renderer gradient refuse it by name.
    assert!(gsp.special_surface().unwrap().contains("diffraction grating"));
}

fn cli(args: &[&str]) -> String {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_diffcassi")).args(args).output().unwrap();
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success(), "diffcassi {}: {text}", args.join(" "));
    text
}

#[test]
fn gsp_renders_reconstructs_and_joins_the_study() {
    let dir = tempfile::tempdir().unwrap();
    let p = |s: &str| dir.path().join(s).display().to_string();
    cli(&["render", "--preset", "gsp", "--scene-size", "64", "--out", &p("r")]);
    let json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.path().join("r/render.json")).unwrap()).unwrap();
    assert!(json.to_string().contains("gsp"));
    let exr = std::fs::metadata(dir.path().join("r/acquisition.exr")).unwrap();
    assert!(exr.len() > 1000);
    let t = cli(&["reconstruct", "--from", &p("r"), "--operator", "exact", "--solver", "gap-tv", "--iterations", "5", "--out", &p("gap")]);
    assert!(t.contains("gsp / exact / gap-tv"), "{t}");
    let t = cli(&["reconstruct", "--from", &p("r"), "--operator", "exact", "--solver", "pnp-gap", "--iterations", "6", "--tv-warmup", "3", "--out", &p("pnp")]);
    assert!(t.contains("gsp / exact / pnp-gap"), "{t}");
    for solver in ["gap", "pnp"] {
        assert!(dir.path().join(solver).join("cube.npy").is_file(), "{solver}: no cube.npy");
    }
    cli(&["study", "--presets", "sp,gsp", "--operators", "exact", "--solvers", "gap-tv", "--synthetic", "1", "--scene-size", "32", "--iterations", "5", "--out", &p("study")]);
    let md = std::fs::read_to_string(dir.path().join("study/study.md")).unwrap();
    assert!(md.contains("gSP") && md.contains("SP"), "{md}");
    // The GPU kernels trace the grating too (docs/gpu.md): the host twin renders gsp (tests/gpu_render.rs holds it to
    // the CPU render), and render.json says where it ran.
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_diffcassi")).args(["render", "--preset", "gsp", "--scene-size", "16", "--device", "cpu-twin", "--out", &p("twin")]).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.path().join("twin/render.json")).unwrap()).unwrap();
    assert_eq!(json["device"]["device"], "cpu-twin", "{}", json["device"]);
}

// ---- reverse mode (the acquisition's adjoint sweep) through mirrors, gratings and toroids -------------

/// The scalar reverse sweep (`diff::adjoint`: `AdjointPlan::trace` + `backward`) through mirrors (the
/// ellipsoid, the fold pair), gratings (a tilted plane grating, the curved grating on a lens, a reflective
/// grating; index and wavelength-table adjoints) and a decentred, tilted toroid, against the forward-mode
/// tangents that `jacobians_through_*` check against central differences: for a random λ on the landing's
/// position and direction, λᵀJ ray by ray, ≤ 1e-12 of the ray's largest term; the sweep's trace lands where the
/// scalar tracer lands, bit for bit.
#[test]
fn adjoint_sweep_through_mirrors_gratings_and_toroids_equals_the_forward_tangents() {
    use diffcassi::diff::adjoint::{AdjointPlan, AdjointSums, RayTape};
    let mut e = ellipsoid_mirror();
    e.fields_mm = vec![[0.0, 0.0], [0.0, 2.0], [1.5, 1.0]];
    let mut g = plane_grating(0.6, 1);
    g.surfaces.insert(1, SurfaceSpec::coordinate_break(0.0, 0.0, 3.0, -2.0, 0.0, 0.0));
    let mut r = plane_grating(0.3, 1);
    r.surfaces[1].material = Some("MIRROR".into());
    r.surfaces[1].thickness_mm = diffcassi::spec::Cell::fixed(-30.0);
    r.surfaces.insert(1, SurfaceSpec::coordinate_break(0.0, 0.0, 10.0, 0.0, 0.0, 0.0));
    let mut t = toroid_lens(Some(35.0));
    t.surfaces.insert(1, SurfaceSpec::coordinate_break(0.2, -0.1, 1.0, 2.0, 0.0, 0.0));
    let cases: Vec<(SystemSpec, &[&str])> = vec![
        (e, &["s0.thickness_mm", "s1.curvature", "s1.conic", "s1.thickness_mm"]),
        (fold_mirrors(), &["s2.tilt_x_deg", "s4.tilt_x_deg", "s5.tilt_y_deg", "s4.thickness_mm", "s6.curvature", "glass_nd:N-BK7"]),
        (g, &["s1.tilt_x_deg", "s1.tilt_y_deg", "s0.thickness_mm", "s2.thickness_mm", "s2.curvature"]),
        (curved_grating(), &["s1.curvature", "s1.conic", "s1.thickness_mm", "glass_nd:N-BK7", "glass_vd:N-BK7"]),
        (r, &["s1.tilt_x_deg", "s2.thickness_mm"]),
        (t, &["s1.tilt_x_deg", "s1.tilt_y_deg", "s1.decenter_x_mm", "s2.thickness_mm", "glass_nd:N-BK7"]),
        (diffcassi::presets::spec("gsp").unwrap(), &["s0.thickness_mm", "s2.focal_length_mm", "s3.tilt_x_deg", "s3.tilt_z_deg", "s8.curvature", "glass_nd:SF10"]),
    ];
    let mut state = 0x2545_F491_4F6C_DD1Du64;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    for (spec, free) in cases {
        let name = spec.name.clone();
        let params: Vec<Param> = free.iter().map(|p| Param::parse(p).unwrap()).collect();
        let ds = ParamSet::new(spec, GlassCatalog::builtin(), params).unwrap().build().unwrap();
        let (mut worst, mut rays) = (0.0f64, 0);
        for w in [450.0, 520.0, 650.0] {
            let plan = AdjointPlan::new(&ds, &[w]).unwrap();
            let (n, dn) = ds.index_tangents(w).unwrap();
            let mut batch = RayBatch::default();
            for &f in &ds.system.fields_or_axis() {
                batch.extend(&RayBatch::for_field(&ds.system, f, &[[0.0, 0.0], [0.7, 0.0], [0.0, 0.7], [-0.5, -0.5], [0.3, -0.6]], w).unwrap());
            }
            let j = ds.trace(&batch).unwrap();
            let scalar = trace(&ds.system, &batch);
            let mut tape = RayTape::default();
            for i in 0..batch.len() {
                // The direction made unit as the tracer makes it (`tracer::kernel::unit_direction`).
                let (o, d) = (batch.origin(i), batch.direction(i) / batch.direction(i).length_squared().sqrt());
                let traced = plan.trace(&ds, &n, o, d, &mut tape);
                assert_eq!(traced.is_ok(), scalar.status[i] == RayStatus::Ok, "{name}: ray {i}");
                let Ok((p, dir)) = traced else { continue };
                assert_eq!((p.x, p.y, dir.z), (scalar.x[i], scalar.y[i], scalar.dir_z[i]), "{name}: ray {i} lands as the scalar tracer's");
                if !j.usable(i) {
                    continue;
                }
                let lambda: [f64; 6] = std::array::from_fn(|_| next() - 0.5);
                let mut sums = AdjointSums::new(&plan);
                assert!(plan.backward(&ds, &mut tape, lambda, &mut sums), "{name}: ray {i}");
                let mut grad = vec![0.0; ds.k()];
                plan.contract(&ds, &sums, &dn, &mut grad);
                // Each parameter's λᵀJ, compared relative to the ray's largest term (over its parameters).
                let terms: Vec<[f64; 6]> = (0..ds.k())
                    .map(|k| {
                        let (dp, dd) = (j.d_position(i, k), j.d_direction(i, k));
                        [lambda[0] * dp.x, lambda[1] * dp.y, lambda[2] * dp.z, lambda[3] * dd.x, lambda[4] * dd.y, lambda[5] * dd.z]
                    })
                    .collect();
                let scale = terms.iter().flatten().fold(0.0f64, |a, b| a.max(b.abs()));
                if scale == 0.0 {
                    // No parameter moves this ray (the ellipsoid's on-axis ray stays on the axis).
                    assert!(grad.iter().all(|g| g.abs() <= 1e-12), "{name}: ray {i}: {grad:?}");
                    continue;
                }
                for (gk, t) in grad.iter().zip(&terms) {
                    worst = worst.max((gk - t.iter().sum::<f64>()).abs() / scale);
                }
                rays += 1;
            }
        }
        println!("{name:16}: adjoint sweep vs forward tangents over {rays} rays, {} parameters: worst {worst:.1e}", ds.k());
        assert!(rays >= 15, "{name}: only {rays} rays arrived");
        assert!(worst <= 1e-12, "{name}: {worst:e}");
    }
}

/// The differentiable renderer (`render::gradient`, co-design and torch's `CassiRenderer`) through a grating
/// and mirrors: ∂L/∂θ of L = Σ g·render(θ) for the grating CASSI preset `gsp` and the fold-mirror relay
/// against central differences of the same-sample loss (steps moving landings by ~1e-4 pixel), ≤ 1e-6
/// relative to max(|∂L/∂θ_k|, 1e-3 of the largest); these systems' rays are swept ray by ray (the scalar
/// sweep), and the vjp equals the one computed with the scalar kernel throughout, bit for bit.
#[test]
fn render_gradients_through_a_grating_and_mirrors_equal_finite_differences() {
    use diffcassi::render::{gradient::DiffRenderer, RenderConfig, SpectralSampling};
    let bands = vec![480.0, 560.0, 640.0];
    let mut fold = fold_mirrors();
    fold.surfaces[9].thickness_mm = diffcassi::spec::Cell::fixed(24.0);
    let cases: Vec<(SystemSpec, &[&str])> = vec![
        (diffcassi::presets::spec("gsp").unwrap(), &["s3.tilt_x_deg", "s3.tilt_z_deg", "s2.focal_length_mm", "s8.curvature", "glass_nd:SF10"]),
        (fold, &["s2.tilt_x_deg", "s5.tilt_y_deg", "s4.thickness_mm", "s8.curvature", "glass_nd:N-BK7"]),
    ];
    for (spec, free) in cases {
        let name = spec.name.clone();
        let mut cfg = RenderConfig::paper(5);
        cfg.spectral = SpectralSampling::with_planes(bands.clone(), 3).unwrap();
        cfg.rays_per_pixel = 2;
        cfg.seed = 7;
        let params: Vec<Param> = free.iter().map(|p| Param::parse(p).unwrap()).collect();
        let set = ParamSet::new(spec, GlassCatalog::builtin(), params).unwrap();
        let r = DiffRenderer::new(set.clone(), cfg.clone(), bands.clone()).unwrap();
        let hw = 25;
        let scene: Vec<f64> = (0..2 * 3 * hw).map(|i| 0.2 + ((i * 37) % 17) as f64 / 17.0).collect();
        let mask: Vec<f64> = (0..hw).map(|i| if i % 4 == 1 { 0.0 } else { 0.3 + ((i * 7) % 5) as f64 / 7.0 }).collect();
        let (h, w) = r.image_shape();
        let g: Vec<f64> = (0..2 * h * w).map(|i| ((i * 13) % 11) as f64 / 11.0 - 0.5).collect();
        let v = r.vjp(&scene, 2, &mask, &g).unwrap();
        let mut scalar = cfg.clone();
        scalar.kernel = Kernel::Scalar;
        let vs = DiffRenderer::new(set, scalar, bands.clone()).unwrap().vjp(&scene, 2, &mask, &g).unwrap();
        assert_eq!(v.params, vs.params, "{name}: the SIMD landings with the scalar sweep give the scalar kernel's bits");
        let x0 = r.values().unwrap();
        let scale = v.params.iter().fold(0.0f64, |a, b| a.max(b.abs()));
        assert!(scale > 0.0, "{name}");
        let loss = |x: &[f64]| -> f64 { r.with_values(x).unwrap().render(&scene, 2, &mask).unwrap().iter().zip(&g).map(|(a, b)| a * b).sum() };
        let mut worst = 0.0f64;
        for k in 0..x0.len() {
            let step = match &r.set.free[k] {
                Param::Cell { column, .. } if column.ends_with("_deg") => 1e-6,
                Param::Curvature { .. } => 1e-8,
                Param::GlassNd(_) => 1e-7,
                _ => 1e-6,
            };
            let hk = step * x0[k].abs().max(1.0);
            let (mut xp, mut xm) = (x0.clone(), x0.clone());
            xp[k] += hk;
            xm[k] -= hk;
            let fd = (loss(&xp) - loss(&xm)) / (2.0 * hk);
            let err = (fd - v.params[k]).abs() / v.params[k].abs().max(1e-3 * scale);
            println!("{name:6} {:>18}: vjp {:+.9e}  fd {:+.9e}  rel {err:.1e}", r.set.free[k].name(), v.params[k], fd);
            worst = worst.max(err);
        }
        println!("{name}: worst relative error {worst:.2e} over {} parameters", x0.len());
        assert!(worst <= 1e-6, "{name}: {worst:e}");
    }
}
