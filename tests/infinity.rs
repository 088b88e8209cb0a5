//! Objects at infinity (issue 42, item 1): field types (angle, object height, paraxial and real image
//! height), the apertures ENPD / FNUM / FLOA, first-order data against closed forms, the round trip of the
//! new fields and apertures through `.zmx`, TOML and JSON, and the bad inputs.
use diffcassi::prelude::*;
use diffcassi::spec::zmx::{import_zmx, to_zmx, ZmxOptions};
use diffcassi::spec::{Cell, FieldType, RayAiming, SurfaceKind, SurfaceSpec, SystemAperture};
use diffcassi::system::FieldUnit;

const INF: f64 = f64::INFINITY;

fn system_spec(name: &str, aperture: SystemAperture, surfaces: Vec<SurfaceSpec>) -> SystemSpec {
    SystemSpec {
        name: name.into(),
        description: String::new(),
        aperture,
        ray_aiming: RayAiming::Off,
        wavelengths_nm: vec![587.6],
        primary_wavelength_nm: 587.6,
        fields_mm: Vec::new(),
        field_type: FieldType::Angle,
        fields_deg: vec![[0.0, 0.0], [0.0, 5.0], [3.0, 4.0]],
        vignetting_factors: Vec::new(),
        wavelength_policy: Default::default(),
        air_index: 1.0,
        glass_catalogs: vec![],
        surfaces,
        mechanics: None,
    }
}

/// An ideal lens of focal length `f` (Zemax Paraxial surface) at the stop, the image at its focus; the stop
/// is `stop_after` mm behind the lens when non-zero (a dummy plane with semi-diameter 2 mm).
fn ideal_lens(f: f64, stop_after: f64, aperture: SystemAperture) -> SystemSpec {
    let mut lens = SurfaceSpec::new(SurfaceKind::Paraxial);
    lens.focal_length_mm = Some(Cell::fixed(f));
    let mut surfaces = vec![SurfaceSpec::standard(None, INF, None)];
    if stop_after == 0.0 {
        lens.stop = true;
        lens.thickness_mm = Cell::fixed(f);
        lens.semi_diameter_mm = Some(5.0);
        surfaces.push(lens);
    } else {
        lens.thickness_mm = Cell::fixed(stop_after);
        surfaces.push(lens);
        let mut stop = SurfaceSpec::standard(None, f - stop_after, None);
        stop.stop = true;
        stop.semi_diameter_mm = Some(2.0);
        surfaces.push(stop);
    }
    surfaces.push(SurfaceSpec::standard(None, 0.0, None));
    system_spec("ideal", aperture, surfaces)
}

/// A thick N-BK7 singlet (R1, R2, centre thickness d) with the stop on its front surface, object at infinity.
fn thick_lens(r1: f64, r2: f64, d: f64, aperture: SystemAperture) -> SystemSpec {
    let mut front = SurfaceSpec::standard(Some(r1), d, Some("N-BK7"));
    front.stop = true;
    front.semi_diameter_mm = Some(6.0);
    let back = SurfaceSpec::standard(Some(r2), 95.0, None);
    system_spec("thick", aperture, vec![SurfaceSpec::standard(None, INF, None), front, back, SurfaceSpec::standard(None, 0.0, None)])
}

fn close(a: f64, b: f64, rel: f64) -> bool {
    (a - b).abs() <= rel * b.abs().max(1e-300)
}

#[test]
fn ideal_lens_images_angle_fields_at_f_tan_theta_for_every_pupil_ray() {
    let f = 50.0;
    let sys = SequentialSystem::build(&ideal_lens(f, 0.0, SystemAperture::EntrancePupilDiameter(10.0))).unwrap();
    assert!(sys.object_at_infinity());
    // fields_deg → radians inside.
    assert_eq!(sys.fields[2], [3f64.to_radians(), 4f64.to_radians()]);
    let tracer = AnalyticTracer::default();
    let pupil = PupilPattern::Hexapolar { rings: 4 }.points();
    for deg in [[0.0, 0.0], [0.0, 5.0], [3.0, 4.0], [-20.0, 10.0]] {
        let field = sys.field_point(deg, FieldUnit::Deg, "test").unwrap();
        let rays = RayBatch::for_field(&sys, field, &pupil, 587.6).unwrap();
        // Every ray of the field is parallel: direction ∝ (tan θx, tan θy, 1) (OpticStudio's angle convention).
        let (tx, ty) = (deg[0].to_radians().tan(), deg[1].to_radians().tan());
        for i in 0..rays.len() {
            let d = rays.direction(i);
            assert!(close(d.x / d.z, tx, 1e-14) || tx == 0.0 && d.x == 0.0, "{deg:?} {i}");
            assert!(close(d.y / d.z, ty, 1e-14) || ty == 0.0 && d.y == 0.0, "{deg:?} {i}");
            assert_eq!(rays.origin(i).z, 0.0);
        }
        let out = tracer.trace(&sys, &rays).unwrap();
        for i in 0..out.len() {
            assert_eq!(out.status[i], RayStatus::Ok);
            assert!((out.x[i] - f * tx).abs() < 1e-11 && (out.y[i] - f * ty).abs() < 1e-11, "{deg:?}: ({}, {})", out.x[i], out.y[i]);
        }
        // The marginal ray fills the 10 mm pupil on the lens (the stop).
        let m = RayBatch::for_field(&sys, field, &[[0.0, 1.0]], 587.6).unwrap();
        let o = m.origin(0);
        assert!((o.y - 5.0).abs() < 1e-12 && (o.x).abs() < 1e-12, "{o:?}");
    }
}

#[test]
fn thin_lens_pupil_and_apertures_match_closed_forms() {
    // Stop s = 20 mm behind an ideal lens f = 100: the entrance pupil is the stop's image,
    // z_ep = s·f/(f − s) = 25 mm after the lens, magnified 1/A = 1/(1 − s/f) = 1.25.
    let (f, s) = (100.0, 20.0);
    let sys = SequentialSystem::build(&ideal_lens(f, s, SystemAperture::EntrancePupilDiameter(8.0))).unwrap();
    let p = sys.pupil;
    assert!(close(p.distance_mm, s * f / (f - s), 1e-14), "{p:?}");
    assert!(close(p.radius_mm, 4.0, 1e-15));
    assert!(close(p.stop_radius_mm, 4.0 * (1.0 - s / f), 1e-14));
    let fo = sys.first_order;
    // BFL from the last surface before the image (the stop plane, s after the lens): f − s.
    assert!(close(fo.efl_mm, f, 1e-14) && close(fo.bfl_mm, f - s, 1e-14), "{fo:?}");
    assert!(close(fo.enp_from_surface1_mm, 25.0, 1e-14));
    // The exit pupil is the stop itself (nothing after it): 20 mm after the lens, 80 mm before the image.
    assert!(close(fo.exp_from_last_surface_mm, 0.0 + 0.0, 1e-12) || fo.exp_from_last_surface_mm.abs() < 1e-12, "{fo:?}");
    // F/# 12.5 → ENPD = f/F# = 8 mm: the same pupil.
    let fnum = SequentialSystem::build(&ideal_lens(f, s, SystemAperture::ImageSpaceFNumber(12.5))).unwrap();
    assert!(close(fnum.pupil.radius_mm, 4.0, 1e-14), "{:?}", fnum.pupil);
    // Float by stop size: the stop's 2 mm semi-diameter → pupil radius 2 / (1 − s/f) = 2.5 mm.
    let float = SequentialSystem::build(&ideal_lens(f, s, SystemAperture::FloatByStopSize)).unwrap();
    assert!(close(float.pupil.radius_mm, 2.5, 1e-14) && close(float.pupil.stop_radius_mm, 2.0, 1e-15), "{:?}", float.pupil);
    // Real rays: the marginal ray of the on-axis field crosses the stop at its edge (ideal lens: exactly
    // paraxial for a parallel beam), and lands on the focus.
    let tracer = AnalyticTracer::default();
    let rays = RayBatch::for_field(&float, [0.0, 0.0], &[[0.0, 1.0], [1.0, 0.0], [0.0, -1.0]], 587.6).unwrap();
    let out = tracer.trace(&float, &rays).unwrap();
    for i in 0..3 {
        assert!(out.x[i].abs() < 1e-12 && out.y[i].abs() < 1e-12);
    }
    let n = float.indices(587.6).unwrap();
    let (x, y) = diffcassi::rays::stop_crossing(&float, &n, rays.origin(0), rays.direction(0)).unwrap();
    assert!(x.abs() < 1e-12 && (y - 2.0).abs() < 1e-12, "({x}, {y})");
}

#[test]
fn thick_lens_first_order_matches_the_lensmaker_formula() {
    let (r1, r2, d) = (50.0, -80.0, 6.0);
    let sys = SequentialSystem::build(&thick_lens(r1, r2, d, SystemAperture::EntrancePupilDiameter(10.0))).unwrap();
    let n = sys.indices(587.6).unwrap()[1];
    assert!(n > 1.5 && n < 1.53);
    let power = (n - 1.0) * (1.0 / r1 - 1.0 / r2 + (n - 1.0) * d / (n * r1 * r2));
    let efl = 1.0 / power;
    let bfl = efl * (1.0 - (n - 1.0) * d / (n * r1));
    let fo = sys.first_order;
    assert!(close(fo.efl_mm, efl, 1e-13), "{} vs {efl}", fo.efl_mm);
    assert!(close(fo.bfl_mm, bfl, 1e-13), "{} vs {bfl}", fo.bfl_mm);
    assert_eq!(fo.enp_from_surface1_mm, 0.0); // the stop is surface 1
    // F/# = EFL / ENPD.
    let fnum = SequentialSystem::build(&thick_lens(r1, r2, d, SystemAperture::ImageSpaceFNumber(4.0))).unwrap();
    assert!(close(2.0 * fnum.pupil.radius_mm, efl / 4.0, 1e-13));
    // Real rays of a small pupil focus at the BFL behind the last surface (aberrations O(h²)).
    let tracer = AnalyticTracer::default();
    let mut spec = thick_lens(r1, r2, d, SystemAperture::EntrancePupilDiameter(1e-3));
    spec.surfaces[2].thickness_mm = Cell::fixed(bfl);
    let near = SequentialSystem::build(&spec).unwrap();
    let out = tracer.trace(&near, &RayBatch::for_field(&near, [0.0, 0.0], &[[0.0, 1.0]], 587.6).unwrap()).unwrap();
    assert!(out.y[0].abs() < 1e-9, "{}", out.y[0]);
}

#[test]
fn image_height_fields_land_where_they_say() {
    let tracer = AnalyticTracer::default();
    // Paraxial image height on an ideal lens: exactly f·tan θ = h.
    let mut spec = ideal_lens(50.0, 0.0, SystemAperture::EntrancePupilDiameter(10.0));
    spec.field_type = FieldType::ParaxialImageHeight;
    spec.fields_deg = vec![];
    spec.fields_mm = vec![[0.0, 0.0], [0.0, 4.0], [-3.0, 2.0]];
    let sys = SequentialSystem::build(&spec).unwrap();
    let out = tracer.trace(&sys, &RayBatch::chief_rays(&sys, &sys.fields, 587.6).unwrap()).unwrap();
    for (k, h) in spec.fields_mm.iter().enumerate() {
        assert!((out.x[k] - h[0]).abs() < 1e-12 && (out.y[k] - h[1]).abs() < 1e-12, "{k}");
    }
    // Real image height on the thick singlet (distortion makes it differ from the paraxial one).
    let mut spec = thick_lens(50.0, -80.0, 6.0, SystemAperture::EntrancePupilDiameter(10.0));
    spec.field_type = FieldType::RealImageHeight;
    spec.fields_deg = vec![];
    spec.fields_mm = vec![[0.0, 0.0], [0.0, 8.0], [5.0, -4.0]];
    let sys = SequentialSystem::build(&spec).unwrap();
    let out = tracer.trace(&sys, &RayBatch::chief_rays(&sys, &sys.fields, 587.6).unwrap()).unwrap();
    for (k, h) in spec.fields_mm.iter().enumerate() {
        assert!((out.x[k] - h[0]).abs() < 1e-10 && (out.y[k] - h[1]).abs() < 1e-10, "{k}: ({}, {})", out.x[k], out.y[k]);
    }
    let mut par = spec.clone();
    par.field_type = FieldType::ParaxialImageHeight;
    let par = SequentialSystem::build(&par).unwrap();
    assert!((par.fields[1][1] - sys.fields[1][1]).abs() > 1e-6, "the real and paraxial fields differ on a real lens");
}

#[test]
fn angle_fields_on_a_finite_object_are_heights_through_the_pupil_centre() {
    // Zemax: for a finite object an angle is the chief ray's slope toward the entrance pupil centre.
    let mut spec = ideal_lens(50.0, 0.0, SystemAperture::EntrancePupilDiameter(10.0));
    spec.surfaces[0].thickness_mm = Cell::fixed(200.0);
    spec.surfaces[1].thickness_mm = Cell::fixed(200.0 / 3.0);
    let sys = SequentialSystem::build(&spec).unwrap();
    assert!(!sys.object_at_infinity());
    let h = -200.0 * 5f64.to_radians().tan();
    assert!((sys.fields[1][1] - h).abs() < 1e-12, "{:?}", sys.fields);
}

#[test]
fn new_fields_and_apertures_round_trip_through_zmx_toml_and_json() {
    let mut specs = vec![
        ideal_lens(50.0, 0.0, SystemAperture::EntrancePupilDiameter(10.0)),
        ideal_lens(100.0, 20.0, SystemAperture::ImageSpaceFNumber(12.5)),
        ideal_lens(100.0, 20.0, SystemAperture::FloatByStopSize),
        thick_lens(50.0, -80.0, 6.0, SystemAperture::ImageSpaceFNumber(4.0)),
    ];
    let mut img = thick_lens(50.0, -80.0, 6.0, SystemAperture::EntrancePupilDiameter(10.0));
    img.field_type = FieldType::RealImageHeight;
    img.fields_deg = vec![];
    img.fields_mm = vec![[0.0, 0.0], [0.1, 7.3]];
    specs.push(img.clone());
    img.field_type = FieldType::ParaxialImageHeight;
    specs.push(img);
    let mut finite = ideal_lens(50.0, 0.0, SystemAperture::ObjectSpaceNa(0.02));
    finite.surfaces[0].thickness_mm = Cell::fixed(200.0);
    finite.fields_deg = vec![[0.0, 1.0 / 3.0]];
    specs.push(finite);
    for spec in &specs {
        SequentialSystem::build(spec).unwrap();
        let zmx = to_zmx(spec).unwrap();
        if spec.object_at_infinity() {
            assert!(zmx.contains("DISZ INFINITY"), "{zmx}");
        }
        let back = import_zmx(zmx.as_bytes(), "x.zmx", None, &ZmxOptions::default()).unwrap();
        assert!(back.ignored.is_empty());
        assert_eq!(back.spec, *spec, "{zmx}");
        let toml = diffcassi::spec::to_toml(spec).unwrap();
        assert_eq!(diffcassi::spec::from_toml(&toml, "x.toml").unwrap(), *spec, "{toml}");
        let json = diffcassi::spec::to_json(spec).unwrap();
        assert!(!json.contains("null"), "{json}");
        assert_eq!(diffcassi::spec::from_json(&json, "x.json").unwrap(), *spec, "{json}");
    }
    // TOML's own `inf` is read too.
    let toml = diffcassi::spec::to_toml(&specs[0]).unwrap().replace("thickness_mm = \"infinity\"", "thickness_mm = inf");
    assert!(toml.contains("= inf"));
    assert_eq!(diffcassi::spec::from_toml(&toml, "x.toml").unwrap(), specs[0]);
}

#[test]
fn existing_presets_keep_their_format_and_fields() {
    for name in diffcassi::presets::NAMES {
        let spec = diffcassi::presets::spec(name).unwrap();
        assert_eq!(spec.field_type, FieldType::ObjectHeight);
        let toml = diffcassi::spec::to_toml(&spec).unwrap();
        assert!(!toml.contains("field_type") && !toml.contains("fields_deg") && !toml.contains("infinity"));
        let sys = SequentialSystem::build(&spec).unwrap();
        assert!(!sys.object_at_infinity());
        // Object heights pass through bit for bit.
        assert_eq!(sys.fields, spec.fields_mm);
        assert!(to_zmx(&spec).unwrap().contains("FTYP 1 0"));
    }
}

#[test]
fn bad_inputs_are_clear_errors() {
    let err = |spec: &SystemSpec| SequentialSystem::build(spec).unwrap_err().to_string();
    let base = ideal_lens(50.0, 0.0, SystemAperture::EntrancePupilDiameter(10.0));
    let mut s = base.clone();
    s.aperture = SystemAperture::ObjectSpaceNa(0.1);
    assert!(err(&s).contains("object at infinity has no object-space NA"), "{}", err(&s));
    let mut s = base.clone();
    s.field_type = FieldType::ObjectHeight;
    s.fields_deg = vec![];
    s.fields_mm = vec![[0.0, 1.0]];
    assert!(err(&s).contains("object heights are meaningless for an object at infinity"), "{}", err(&s));
    for bad in [90.0, -90.0, f64::NAN, 1e9] {
        let mut s = base.clone();
        s.fields_deg = vec![[0.0, bad]];
        assert!(err(&s).contains("fields_deg[0]"), "{}", err(&s));
    }
    let mut s = base.clone();
    s.surfaces[0].thickness_mm = Cell::fixed(f64::NEG_INFINITY);
    assert!(err(&s).contains("-infinity"), "{}", err(&s));
    let mut s = base.clone();
    s.surfaces[1].thickness_mm = Cell::fixed(INF);
    assert!(err(&s).contains("not finite"), "{}", err(&s));
    let mut s = base.clone();
    s.aperture = SystemAperture::FloatByStopSize;
    s.surfaces[1].semi_diameter_mm = None;
    assert!(err(&s).contains("float_by_stop_size"), "{}", err(&s));
    for f in [0.0, -2.0, f64::NAN] {
        let mut s = base.clone();
        s.aperture = SystemAperture::ImageSpaceFNumber(f);
        assert!(err(&s).contains("image_space_f_number"), "{}", err(&s));
    }
    let mut s = base.clone();
    s.fields_mm = vec![[0.0, 1.0]];
    assert!(err(&s).contains("fields_deg"), "{}", err(&s));
    // The wrong field unit for the system.
    let sys = SequentialSystem::build(&base).unwrap();
    let e = sys.field_point([0.0, 1.0], FieldUnit::Mm, "--field-mm").unwrap_err().to_string();
    assert!(e.contains("--field-deg"), "{e}");
    let sp = SequentialSystem::build(&diffcassi::presets::spec("sp").unwrap()).unwrap();
    let e = sp.field_point([0.0, 1.0], FieldUnit::Deg, "--field-deg").unwrap_err().to_string();
    assert!(e.contains("--field-mm"), "{e}");
    // .zmx: object heights at infinity, -INFINITY.
    let zmx = to_zmx(&base).unwrap();
    let bad = zmx.replace("FTYP 0 0", "FTYP 1 0");
    let e = import_zmx(bad.as_bytes(), "x.zmx", None, &ZmxOptions::default()).unwrap_err().to_string();
    assert!(e.contains("FTYP") && e.contains("infinity"), "{e}");
    let bad = zmx.replacen("DISZ INFINITY", "DISZ -INFINITY", 1);
    let e = import_zmx(bad.as_bytes(), "x.zmx", None, &ZmxOptions::default()).unwrap_err().to_string();
    assert!(e.contains("-INFINITY"), "{e}");
}

// ---------------------------------------------------------------- the command line

fn bin() -> std::process::Command {
    std::process::Command::new(env!("CARGO_BIN_EXE_diffcassi"))
}

/// A folder of this test process (under the system temp dir, named by the pid: no fixed shared path).
fn tmp(name: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("diffcassi-infinity-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

/// The thick singlet at infinity (F/4, fields 0°, 2°, 3°) written as `.zmx`.
fn singlet_zmx() -> std::path::PathBuf {
    let mut spec = thick_lens(50.0, -80.0, 6.0, SystemAperture::ImageSpaceFNumber(4.0));
    spec.fields_deg = vec![[0.0, 0.0], [0.0, 2.0], [0.0, 3.0]];
    spec.wavelengths_nm = vec![450.0, 550.0, 650.0];
    spec.primary_wavelength_nm = 550.0;
    let bfl = SequentialSystem::build(&spec).unwrap().first_order.bfl_mm;
    spec.surfaces[2].thickness_mm = Cell::fixed(bfl);
    let path = tmp("singlet.zmx");
    diffcassi::spec::save_spec_file(&spec, &path).unwrap();
    path
}

#[test]
fn cli_trace_field_deg_and_its_errors() {
    let zmx = singlet_zmx();
    let csv = tmp("rays.csv");
    let o = bin().args(["trace", "--system", zmx.to_str().unwrap(), "--wavelength-nm", "550", "--field-deg", "0,2", "--pupil", "grid:5", "--csv", csv.to_str().unwrap()]).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = std::fs::read_to_string(&csv).unwrap();
    let mut lines = text.lines().filter(|l| !l.starts_with('#'));
    let head: Vec<&str> = lines.next().unwrap().split(',').collect();
    let (xi, yi) = (head.iter().position(|h| *h == "x_mm").unwrap(), head.iter().position(|h| *h == "y_mm").unwrap());
    let rows: Vec<Vec<f64>> = lines.map(|l| l.split(',').enumerate().filter(|(k, _)| *k == xi || *k == yi).map(|(_, v)| v.parse().unwrap()).collect()).collect();
    assert_eq!(rows.len(), 13); // grid:5 keeps the points inside the unit circle
    // The 2° field lands near EFL·tan 2° (the singlet at its paraxial focus).
    let efl = SequentialSystem::build(&diffcassi::spec::load_spec_file(&zmx).unwrap()).unwrap().first_order.efl_mm;
    let mean_y = rows.iter().map(|r| r[1]).sum::<f64>() / rows.len() as f64;
    assert!((mean_y - efl * 2f64.to_radians().tan()).abs() < 0.05, "{mean_y}");
    assert!(rows.iter().all(|r| r[0].is_finite() && r[1].is_finite()));
    // The wrong unit, and a bad angle, name the right flag.
    let o = bin().args(["trace", "--system", zmx.to_str().unwrap(), "--wavelength-nm", "550", "--field-mm", "0,2"]).output().unwrap();
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("--field-deg"), "{}", String::from_utf8_lossy(&o.stderr));
    let o = bin().args(["trace", "--preset", "sp", "--wavelength-nm", "550", "--field-deg", "0,2"]).output().unwrap();
    assert!(String::from_utf8_lossy(&o.stderr).contains("--field-mm"), "{}", String::from_utf8_lossy(&o.stderr));
    for bad in ["0,90", "0,nan", "1"] {
        let o = bin().args(["trace", "--system", zmx.to_str().unwrap(), "--wavelength-nm", "550", "--field-deg", bad]).output().unwrap();
        assert_eq!(o.status.code(), Some(1), "{bad}");
        assert!(String::from_utf8_lossy(&o.stderr).contains("--field-deg"), "{bad}: {}", String::from_utf8_lossy(&o.stderr));
    }
    // info prints the first-order data; distortion and spot run at infinity.
    let o = bin().args(["info", "--system", zmx.to_str().unwrap()]).output().unwrap();
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(out.contains("object at infinity") && out.contains("EFL"), "{out}");
    let o = bin().args(["distortion", "--system", zmx.to_str().unwrap(), "--grid", "5", "--csv", tmp("grid.csv").to_str().unwrap()]).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(std::fs::read_to_string(tmp("grid.csv")).unwrap().contains("x_field_tan"));
    let o = bin().args(["spot", "--system", zmx.to_str().unwrap(), "--pupil", "hexapolar:3", "--json", tmp("spots.json").to_str().unwrap()]).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(std::fs::read_to_string(tmp("spots.json")).unwrap().contains("field_deg"));
}

#[test]
fn cli_render_scene_fov_deg_and_its_errors() {
    let zmx = singlet_zmx();
    let z = zmx.to_str().unwrap();
    let small = ["--scene-size", "8", "--planes", "2", "--rays", "2", "--bands", "500,600", "--no-mapping"];
    let render = |extra: &[&str], out: &str| bin().args(["render", "--system", z]).args(small).args(extra).args(["--out", tmp(out).to_str().unwrap()]).output().unwrap();
    let o = render(&[], "none");
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("--scene-fov-deg"), "{}", String::from_utf8_lossy(&o.stderr));
    for bad in ["0", "180", "200", "-5", "nan", "inf"] {
        let o = render(&["--scene-fov-deg", bad], "bad");
        assert_ne!(o.status.code(), Some(0), "{bad}");
        assert!(String::from_utf8_lossy(&o.stderr).contains("--scene-fov-deg"), "{bad}: {}", String::from_utf8_lossy(&o.stderr));
        assert!(!tmp("bad").join("render.json").exists());
    }
    let o = bin().args(["render", "--preset", "sp"]).args(small).args(["--scene-fov-deg", "10", "--out", tmp("sp").to_str().unwrap()]).output().unwrap();
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("finite object"), "{}", String::from_utf8_lossy(&o.stderr));
    let o = render(&["--scene-fov-deg", "6"], "ok");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(tmp("ok").join("render.json")).unwrap()).unwrap();
    assert_eq!(json["scene_fov_deg"], 6.0);
    assert!((json["scene_pitch_rad"].as_f64().unwrap() - 6f64.to_radians() / 8.0).abs() < 1e-18);
    assert!(json["scene_pitch_mm"].is_null());
    assert!(json["ray_stats"]["arrived"].as_u64().unwrap() > 0, "{}", json["ray_stats"]);
    assert!(json["acquisition_total"].as_f64().unwrap().is_finite() && json["acquisition_total"].as_f64().unwrap() > 0.0);
    // --tolerance-um at infinity: the Monte-Carlo spread σ is measured over pixels of the angular pitch (the
    // render's own sampling, not the finite-object placeholder pitch), and every candidate is measured: the
    // Embree backends trace an object at infinity too (the rays start in front of every solid, issue 42).
    let tol = |fov: &str, out: &str| bin().args(["render", "--system", z, "--scene-size", "8", "--planes", "2", "--bands", "500,600", "--no-mapping", "--tolerance-um", "3", "--scene-fov-deg", fov, "--out", tmp(out).to_str().unwrap()]).arg("--calibration-cache").arg(tmp(&format!("{out}-cache"))).output().unwrap();
    let sigma = |text: &str| -> f64 { text.split("σ = ").nth(1).and_then(|t| t.split(" µm").next()).and_then(|v| v.parse().ok()).unwrap_or_else(|| panic!("no σ in: {text}")) };
    let o = tol("0.5", "tol-narrow");
    let out = String::from_utf8_lossy(&o.stdout).to_string() + &String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{out}");
    // (analytic or its f32 lanes, whichever the timing predicts faster; no candidate left out.)
    assert!(out.contains("fidelity: tolerance 3 µm → --backend analytic") && !out.contains("left out"), "{out}");
    let rays = serde_json::from_str::<serde_json::Value>(&std::fs::read_to_string(tmp("tol-narrow").join("render.json")).unwrap()).unwrap()["rays_per_pixel"].as_u64().unwrap();
    let (s_narrow, n) = (sigma(&out), rays as f64);
    // σ/√N within the tolerance, with no more rays than a 0.5 µm trace error would call for.
    assert!(s_narrow / n.sqrt() <= 3.0 && n <= (s_narrow / 2.5).powi(2).ceil(), "σ {s_narrow}, N {n}");
    // 24× wider pixels (12° over 8 pixels) spread their landings more: refused as needing too many rays, naming σ.
    let o = tol("12", "tol-wide");
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("--tolerance-um 3") && sigma(&err) > 4.0 * s_narrow, "{err}");
    assert!(!tmp("tol-wide").join("render.json").exists());
    // reconstruct rebuilds the renderer from the recorded angular extent.
    let o = bin().args(["reconstruct", "--from", tmp("ok").to_str().unwrap(), "--operator", "exact", "--solver", "gap-tv", "--iterations", "2", "--out", tmp("recon").to_str().unwrap()]).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}
