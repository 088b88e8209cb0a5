//! Bad input: every case is a clear error naming the file/surface, the field and the value — never a
//! panic, never a silent wrong number.
use diffcassi::prelude::*;
use diffcassi::spec::{self, Cell, Driver, Pickup};

fn sp() -> SystemSpec {
    presets::spec("sp").unwrap()
}

/// Build the spec (after a TOML round trip, as a user file would be read) and return the error text.
fn build_err(spec: &SystemSpec) -> String {
    let text = spec::to_toml(spec).unwrap();
    match spec::from_toml(&text, "user.toml") {
        Err(e) => e.to_string(),
        Ok(s) => match SequentialSystem::build(&s) {
            Err(e) => e.to_string(),
            Ok(_) => panic!("expected an error for spec `{}`", s.name),
        },
    }
}

fn toml_err(text: &str) -> String {
    spec::from_toml(text, "user.toml").expect_err("must fail").to_string()
}

fn assert_mentions(msg: &str, parts: &[&str]) {
    for p in parts {
        assert!(msg.contains(p), "error `{msg}` should mention `{p}`");
    }
}

#[test]
fn unknown_glass() {
    let mut s = sp();
    s.surfaces[6].material = Some("N-BK8".into());
    assert_mentions(&build_err(&s), &["surface 6", "material", "N-BK8", "N-BK7"]);
}

#[test]
fn wavelength_outside_glass_range() {
    let mut s = sp();
    s.wavelengths_nm = vec![200.0, 520.0];
    assert_mentions(&build_err(&s), &["surface 6", "N-BK7", "200"]);
    // …unless extrapolation is explicitly allowed.
    s.wavelength_policy = diffcassi::materials::WavelengthPolicy::AllowExtrapolation;
    assert!(SequentialSystem::build(&s).is_ok());
}

#[test]
fn wavelength_outside_range_at_trace_time() {
    let sys = SequentialSystem::build(&sp()).unwrap();
    // Ray generation refuses it…
    let e = RayBatch::chief_rays(&sys, &[[0.0, 0.0]], 3000.0).unwrap_err().to_string();
    assert_mentions(&e, &["3000", "N-BK7"]);
    // …and so does the tracer for a hand-made batch.
    let mut rays = RayBatch::default();
    rays.push(glam::DVec3::ZERO, glam::DVec3::Z, 3000.0);
    let e = AnalyticTracer::default().trace(&sys, &rays).unwrap_err().to_string();
    assert_mentions(&e, &["3000", "N-BK7"]);
}

#[test]
fn negative_semi_diameter() {
    let mut s = sp();
    s.surfaces[16].semi_diameter_mm = Some(-1.0);
    assert_mentions(&build_err(&s), &["surface 16", "semi_diameter_mm", "-1"]);
}

#[test]
fn negative_aperture() {
    let mut s = sp();
    s.surfaces[16].aperture = Some(diffcassi::surfaces::Aperture::circular(-2.0));
    assert_mentions(&build_err(&s), &["surface 16", "aperture", "-2"]);
}

#[test]
fn malformed_toml() {
    let e = toml_err("name = \"x\"\naperture = { type = \"object_space_na\", value = 0.05 \n[[surfaces]]");
    assert_mentions(&e, &["user.toml", "TOML", "line"]);
}

#[test]
fn unknown_surface_type() {
    let text = spec::to_toml(&sp()).unwrap().replacen("type = \"paraxial\"", "type = \"toroidal\"", 1);
    assert_mentions(&toml_err(&text), &["user.toml", "toroidal", "paraxial"]);
}

#[test]
fn nan_in_a_spec() {
    let mut s = sp();
    s.surfaces[3].tilt_y_deg = Some(Cell::fixed(f64::NAN));
    assert_mentions(&build_err(&s), &["surface 3", "tilt_y_deg", "NaN"]);
}

#[test]
fn pickup_from_a_missing_surface() {
    let mut s = sp();
    s.surfaces[11].tilt_y_deg = Some(Cell { value: 30.0, variable: false, driver: Driver::Pickup(Pickup { surface: 42, scale: 1.0, offset: 0.0, column: None }) });
    assert_mentions(&build_err(&s), &["surface 11", "tilt_y_deg", "42"]);
}

#[test]
fn pickup_cycle() {
    let mut s = sp();
    s.surfaces[7].tilt_y_deg = Some(Cell::pickup(30.0, 11, 1.0));
    assert_mentions(&build_err(&s), &["cycle"]);
}

#[test]
fn empty_system() {
    let mut s = sp();
    s.surfaces.clear();
    assert_mentions(&build_err(&s), &["surfaces"]);
}

#[test]
fn unknown_field_is_named() {
    let text = spec::to_toml(&sp()).unwrap().replacen("thickness_mm = 50.0", "thicknes_mm = 50.0", 1);
    assert_mentions(&toml_err(&text), &["thicknes_mm"]);
}

#[test]
fn zero_focal_length_and_zero_radius() {
    let mut s = sp();
    s.surfaces[2].focal_length_mm = Some(Cell::fixed(0.0));
    assert_mentions(&build_err(&s), &["surface 2", "focal_length_mm"]);
    let mut s = sp();
    s.surfaces[16].radius_mm = Some(Cell::fixed(0.0));
    assert_mentions(&build_err(&s), &["surface 16", "radius_mm"]);
}

#[test]
fn material_on_a_coordinate_break() {
    let mut s = sp();
    s.surfaces[3].material = Some("N-BK7".into());
    assert_mentions(&build_err(&s), &["surface 3", "material", "Coordinate Break"]);
}

#[test]
fn two_stops_and_stop_on_image() {
    let mut s = sp();
    s.surfaces[1].stop = true;
    assert_mentions(&build_err(&s), &["stop"]);
    let mut s = sp();
    s.surfaces[8].stop = false;
    s.surfaces[19].stop = true;
    assert_mentions(&build_err(&s), &["surface 19", "stop"]);
}

#[test]
fn numerical_aperture_out_of_range() {
    let mut s = sp();
    s.aperture = spec::SystemAperture::ObjectSpaceNa(1.5);
    assert_mentions(&build_err(&s), &["object_space_na", "1.5"]);
}

#[test]
fn chief_ray_solve_on_a_radius() {
    let mut s = sp();
    s.surfaces[16].radius_mm = Some(Cell::chief_ray(33.34));
    assert_mentions(&build_err(&s), &["surface 16", "radius_mm", "chief-ray"]);
}

#[test]
fn column_not_of_this_surface_type() {
    let mut s = sp();
    s.surfaces[16].tilt_x_deg = Some(Cell::fixed(1.0));
    assert_mentions(&build_err(&s), &["surface 16", "tilt_x_deg", "Standard"]);
}

#[test]
fn malformed_prescription_csv() {
    use diffcassi::spec::zemax_csv::{import_prescription, SystemData};
    let good = presets::prescription_csv("sp").unwrap();
    let bad = good.replacen("50.000 V", "fifty V", 1);
    let e = import_prescription(&bad, "bad.csv", &SystemData::paper_defaults()).unwrap_err().to_string();
    assert_mentions(&e, &["bad.csv", "line", "thickness", "fifty"]);
    let bad = good.replacen("-19.680", "-19.680 Q", 1);
    let e = import_prescription(&bad, "bad.csv", &SystemData::paper_defaults()).unwrap_err().to_string();
    assert_mentions(&e, &["bad.csv", "par4", "Q"]);
    let bad = good.replacen(",Coordinate Break,", ",Toroidal,", 1);
    let e = import_prescription(&bad, "bad.csv", &SystemData::paper_defaults()).unwrap_err().to_string();
    assert_mentions(&e, &["bad.csv", "Toroidal"]);
}

#[test]
fn missing_glass_catalogue_file() {
    let mut s = sp();
    s.glass_catalogs = vec!["/nonexistent/MISSING.AGF".into()];
    let e = SequentialSystem::build(&s).unwrap_err().to_string();
    assert_mentions(&e, &["MISSING.AGF"]);
}

#[test]
fn non_finite_rays_are_classified_not_propagated() {
    let sys = SequentialSystem::build(&sp()).unwrap();
    let mut rays = RayBatch::default();
    rays.push(glam::DVec3::new(f64::NAN, 0.0, 0.0), glam::DVec3::Z, 520.0);
    rays.push(glam::DVec3::ZERO, glam::DVec3::new(0.0, 0.0, f64::INFINITY), 520.0);
    rays.push(glam::DVec3::ZERO, glam::DVec3::ZERO, 520.0);
    let out = AnalyticTracer::default().trace(&sys, &rays).unwrap();
    assert!(out.status.iter().all(|s| *s == RayStatus::InvalidInput));
    assert!(out.x.iter().chain(&out.y).all(|v| v.is_finite()));
}

#[test]
fn unknown_preset() {
    assert_mentions(&presets::spec("xp").unwrap_err().to_string(), &["xp", "sp, ap, msp, map"]);
}
