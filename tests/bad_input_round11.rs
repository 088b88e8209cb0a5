//! Round 11 (1 Dec 2026): three held-out probers — the documentation against the program, the statistics and
//! physics of rendering, noise and operators, and the non-sequential side (ghosts, stray light, mechanics,
//! coatings). Each case failed before its fix (docs/robustness.md, "round 11").
use crate::cli_run::{ok_cli as ok, refused_cli as refused, run_cli as run};
/// A biconvex N-BK7 singlet (object 100 mm, NA 0.05), the prober's test system.
use crate::common::SINGLET_TOML as SINGLET;

fn json(path: std::path::PathBuf) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))).unwrap()
}

/// A closed unit cube, outward quads.
const CUBE_OBJ: &str = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nv 0 0 1\nv 1 0 1\nv 0 1 1\nv 1 1 1\n\
                        f 1 3 4 2\nf 5 6 8 7\nf 1 2 6 5\nf 2 4 8 6\nf 4 3 7 8\nf 3 1 5 7\n";

/// The singlet with an absorbing 40 mm box at z = 50–90 mm whose lower edge is at `y0_mm` (−20: across the
/// whole beam; −40: its y < 0 half).
fn singlet_with_box(y0_mm: f64) -> String {
    format!("{SINGLET}\n[mechanics]\ngenerate = false\n[[mechanics.meshes]]\npath = \"box.obj\"\ntranslate_mm = [-20.0, {y0_mm}, 50.0]\nscale = 40.0\n")
}

const SMALL: [&str; 8] = ["--scene-size", "8", "--planes", "2", "--rays", "4", "--no-mapping", "--ghosts"];

fn total(dir: &std::path::Path, out: &str) -> f64 {
    json(dir.join(out).join("render.json"))["acquisition_total"].as_f64().unwrap()
}

/// A user mesh across the beam left `render --ghosts --mechanics`' acquisition byte-identical (the sequential
/// main image has no mechanics; only `absorbed_share` showed it): the rays it stops now leave the main image
/// — all of it for a box across the beam (to the rounding of the render's f32 footprints), half for a box over
/// half the pupil — and render.json says how much (`main_blocked_share`).
#[test]
fn a_mesh_across_the_beam_takes_its_light_from_the_main_image() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    std::fs::write(dir.join("box.obj"), CUBE_OBJ).unwrap();
    std::fs::write(dir.join("singlet.toml"), SINGLET).unwrap();
    std::fs::write(dir.join("full.toml"), singlet_with_box(-20.0)).unwrap();
    std::fs::write(dir.join("half.toml"), singlet_with_box(-40.0)).unwrap();
    let render = |spec: &str, out: &str, mech: bool| {
        let mut a = vec!["render", "--system", spec];
        a.extend(SMALL);
        a.push("2");
        if mech {
            a.push("--mechanics");
        }
        a.extend(["--out", out]);
        ok(dir, &a)
    };
    let plain = render("singlet.toml", "base", false);
    assert!(!plain.contains("the mechanics block"), "{plain}");
    let full = render("full.toml", "full", true);
    assert!(full.contains("the mechanics block 1.000e0 of the main image"), "{full}");
    render("half.toml", "half", true);
    let base = total(dir, "base");
    assert!(base > 100.0);
    assert!(total(dir, "full") <= 1e-6 * base, "a box across the beam leaves {} of {base}", total(dir, "full"));
    let half = total(dir, "half") / base;
    assert!((half - 0.5).abs() < 0.02, "a box over half the pupil leaves {half} of the image");
    let g = &json(dir.join("half/render.json"))["ghosts"];
    assert!((g["main_blocked_share"].as_f64().unwrap() - (1.0 - half)).abs() < 1e-6, "{g}");
    assert!(g["blocked_rays"].as_u64().unwrap() > 0);
    // Without a mesh in the beam nothing is taken: the record says 0.
    assert_eq!(json(dir.join("base/render.json"))["ghosts"]["acquisition_blocked"].as_f64(), Some(0.0));
    // A ghost subsample (--ghost-rays below --rays) still takes every rendered ray the mechanics stop, from a
    // pass over the render's own rays: a subsample's estimate, clamped at 0 per pixel, left 140 of 552 behind
    // a box across the beam and 310–356 behind half of one (a second prober).
    for (spec, want) in [("full.toml", 0.0), ("half.toml", 0.5)] {
        let out = format!("sub-{spec}");
        let mut a = vec!["render", "--system", spec];
        a.extend(SMALL);
        a.extend(["1", "--mechanics", "--ghost-rays", "1", "--cube", "--out", &out]);
        ok(dir, &a);
        let share = total(dir, &out) / base;
        assert!((share - want).abs() < 0.02 && (want > 0.0 || share < 1e-6), "{spec}: {share} of the image is left, not {want}");
        // The per-band images add up to the acquisition.
        let bands: f64 = diffcassi::io::exr::read_exr(dir.join(&out).join("cube.exr")).unwrap().channels.iter().map(|c| c.data.iter().map(|&x| x as f64).sum::<f64>()).sum();
        assert!((bands - total(dir, &out)).abs() <= 1e-6 * base, "{spec}: bands {bands} vs acquisition {}", total(dir, &out));
    }
}

/// `ghosts` ignored the spec's `[mechanics]` silently (a missing mesh file, a box across the beam: the same
/// table, exit 0), and so did `render` without `--mechanics`: both say so. `export-spec` into another folder
/// kept the mesh's path relative to the old one (the exported spec could not be rendered): mesh paths are
/// read relative to the spec file and kept absolute, as glass catalogues are.
#[test]
fn unused_mechanics_are_named_and_exported_mesh_paths_still_resolve() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    std::fs::write(dir.join("box.obj"), CUBE_OBJ).unwrap();
    std::fs::write(dir.join("full.toml"), singlet_with_box(-20.0)).unwrap();
    let out = ok(dir, &["ghosts", "--system", "full.toml", "--rings", "2", "--extended-grid", "2"]);
    assert!(out.contains("note: the spec's [mechanics] section is not used by `ghosts`"), "{out}");
    let out = ok(dir, &["render", "--system", "full.toml", "--scene-size", "8", "--planes", "2", "--rays", "2", "--no-mapping", "--out", "r"]);
    assert!(out.contains("only `render --ghosts K --mechanics` traces the mechanics"), "{out}");
    std::fs::create_dir(dir.join("sub")).unwrap();
    ok(dir, &["export-spec", "--system", "full.toml", "--out", "sub/moved.toml"]);
    let mut a = vec!["render", "--system", "sub/moved.toml"];
    a.extend(SMALL);
    a.extend(["2", "--mechanics", "--out", "moved"]);
    let out = ok(dir, &a);
    assert!(out.contains("the mechanics block 1.000e0"), "{out}");
    // With the mesh paths absolute, a dataset of a project folder moved elsewhere saw "another configuration"
    // (…/P/box.obj ≠ …/Q/box.obj) although `render-dataset` traces no mechanics: they are no part of it.
    let p = dir.join("P");
    std::fs::create_dir_all(p.join("scenes")).unwrap();
    std::fs::copy(dir.join("box.obj"), p.join("box.obj")).unwrap();
    std::fs::copy(dir.join("full.toml"), p.join("sys.toml")).unwrap();
    crate::common::two_small_scenes(&p.join("scenes"));
    let args = ["render-dataset", "--system", "sys.toml", "--scenes", "scenes", "--scene-size", "8", "--bands", "450:650:3", "--planes", "3", "--rays", "2", "--no-mapping", "--out", "ds"];
    ok(&p, &args);
    std::fs::remove_dir_all(p.join("ds/s1")).unwrap();
    std::fs::rename(&p, dir.join("Q")).unwrap();
    let out = ok(&dir.join("Q"), &args);
    assert!(out.contains("rendered 1 of 1 scenes"), "{out}");
}

/// A coating where nothing reflects was recorded and did nothing: on a dummy plane in air (render.json listed
/// it, the main path stayed 0.917), on SP's coincident prism faces 8 and 10 (one virtual N-BK7 interface: the
/// bare numbers exactly); `all=` claimed those surfaces too. Refused, naming the surface and why; `all` skips
/// them; `R1e-400` (read as 0) is refused and `R-0` recorded as 0.
#[test]
fn coatings_where_nothing_reflects_are_refused() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    // The singlet with a dummy plane in air (surface 3) 50 mm before the image.
    let image = "[[surfaces]]\ntype = \"standard\"\nsemi_diameter_mm = 5.0\n";
    let dummy = SINGLET.replace("thickness_mm = 95.0", "thickness_mm = 45.0").replace(image, &format!("[[surfaces]]\ntype = \"standard\"\nthickness_mm = 50.0\nsemi_diameter_mm = 8.0\n{image}"));
    assert_ne!(dummy, SINGLET.replace("thickness_mm = 95.0", "thickness_mm = 45.0"));
    std::fs::write(dir.join("dummy.toml"), &dummy).unwrap();
    ok(dir, &["info", "--system", "dummy.toml"]);
    let base = ["render", "--scene-size", "8", "--planes", "2", "--rays", "2", "--no-mapping", "--ghosts", "2"];
    let with = |extra: &[&'static str]| -> Vec<&str> { base.iter().copied().chain(extra.iter().copied()).collect() };
    refused(dir, &with(&["--system", "dummy.toml", "--coating", "3=R0.5", "--out", "o"]), &["surface 3 is a dummy surface", "AIR", "a coating there would do nothing"]);
    refused(dir, &with(&["--preset", "sp", "--coating", "8=R0.5", "--out", "o"]), &["surface 8 is a dummy surface", "N-BK7"]);
    refused(dir, &with(&["--preset", "sp", "--coating", "10=R0.5", "--out", "o"]), &["surface 10 is a dummy surface"]);
    assert!(!dir.join("o").exists());
    ok(dir, &with(&["--preset", "sp", "--coating", "all=R0.5", "--out", "all"]));
    let coatings = json(dir.join("all/render.json"))["ghosts"]["coatings"].clone();
    let coated: Vec<usize> = coatings.as_array().unwrap().iter().enumerate().filter(|(_, c)| !c.is_null()).map(|(k, _)| k).collect();
    assert_eq!(coated, vec![6, 12, 16, 17, 18], "{coatings}");
    // The spec's own coating on the dummy plane: `ghosts` and `render --ghosts` refuse it.
    let coated_spec = dummy.replacen("thickness_mm = 50.0\nsemi_diameter_mm = 8.0\n", "thickness_mm = 50.0\nsemi_diameter_mm = 8.0\ncoating = { reflectance = 0.5 }\n", 1);
    std::fs::write(dir.join("coated.toml"), coated_spec).unwrap();
    refused(dir, &["ghosts", "--system", "coated.toml", "--rings", "2", "--extended-grid", "2"], &["coating of surface 3", "dummy surface"]);
    refused(dir, &with(&["--system", "coated.toml", "--out", "o"]), &["coating of surface 3"]);
    let (code, out) = run(dir, &with(&["--preset", "sp", "--coating", "all=R1e-400", "--out", "o"]));
    assert_eq!(code, Some(2), "{out}");
    assert!(out.contains("below f64's range"), "{out}");
    ok(dir, &with(&["--preset", "sp", "--coating", "all=R-0", "--out", "zero"]));
    assert_eq!(json(dir.join("zero/render.json"))["ghosts"]["coatings"][6]["reflectance"].to_string(), "0.0");
}

/// `defocus_mm` of a collimated ghost (a plate with its object at infinity) was −40.42 mm at a 5° field
/// (E[u²] − E[u]² left rounding of ~1e-18, above the 1e-30 guard): the sums are taken about the first ray's,
/// so a parallel bundle has no focus, 0, at every field as on axis.
#[test]
fn a_collimated_ghost_has_no_defocus() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let plate = r#"name = "plate at infinity"
ray_aiming = "off"
wavelengths_nm = [520.0]
primary_wavelength_nm = 520.0
fields_mm = []
field_type = "angle"
fields_deg = [[0.0, 0.0], [0.0, 5.0]]
[aperture]
type = "entrance_pupil_diameter"
value = 8.0
[[surfaces]]
type = "standard"
thickness_mm = "infinity"
[[surfaces]]
type = "standard"
stop = true
thickness_mm = 10.0
material = "N-BK7"
semi_diameter_mm = 20.0
[[surfaces]]
type = "standard"
thickness_mm = 20.0
semi_diameter_mm = 20.0
[[surfaces]]
type = "standard"
semi_diameter_mm = 20.0
"#;
    std::fs::write(dir.join("plate.toml"), plate).unwrap();
    ok(dir, &["ghosts", "--system", "plate.toml", "--json", "g.json"]);
    let g = json(dir.join("g.json"));
    let points: Vec<&serde_json::Value> = g["paths"].as_array().unwrap().iter().filter(|p| p["source"].as_str().unwrap().starts_with("point")).collect();
    assert!(points.len() >= 2, "{g}");
    for p in points {
        assert_eq!(p["defocus_mm"].as_f64(), Some(0.0), "{p}");
    }
}

/// `bench` and `bench nonsequential` measured and reported every core under `--threads 1` (accepted and not
/// obeyed); `bench nonsequential`'s ray budget blamed `--rays` for its fixed row-(c) queries.
#[test]
fn bench_obeys_threads_and_names_its_fixed_queries() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let out = ok(dir, &["--threads", "1", "bench", "--preset", "sp", "--rays", "200", "--repeat", "1", "--wavelengths", "2", "--backends", "analytic"]);
    let rows: Vec<&str> = out.lines().filter(|l| l.starts_with("| analytic")).collect();
    assert!(!rows.is_empty(), "{out}");
    for r in rows {
        assert_eq!(r.split('|').nth(2).map(str::trim), Some("1"), "{r}");
    }
    if cfg!(feature = "embree") {
        refused(dir, &["--max-rays", "1000", "bench", "nonsequential", "--rays", "10", "--wavelengths", "1", "--repeat", "1", "--csv", "b.csv"], &["row (c)'s", "mechanics queries"]);
    }
}

/// A flat mask surface written `radius_mm = 1e308` was refused as "not flat" without the value: the message
/// names what makes the surface not a flat Standard one.
#[test]
fn a_curved_mask_surface_is_named_with_its_radius() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    ok(dir, &["export-spec", "--preset", "ddsp", "--out", "ddsp.toml"]);
    let spec = std::fs::read_to_string(dir.join("ddsp.toml")).unwrap();
    let curved = spec.replacen("thickness_mm = 43.2\nsemi_diameter_mm = 12.0\n", "thickness_mm = 43.2\nsemi_diameter_mm = 12.0\nradius_mm = 1e308\n", 1);
    assert_ne!(curved, spec, "the mask surface's lines");
    std::fs::write(dir.join("curved.toml"), curved).unwrap();
    refused(dir, &["info", "--system", "curved.toml"], &["coded_mask: radius_mm = 1e308", "flat Standard surface"]);
}

/// A paraxial lens at zero thickness before a flat glass face: the non-sequential walk skipped the second hit
/// (within the first's offset), so a reflectance-1 coating on the face let 42 % through (a second prober).
/// Refused, naming both surfaces; 1 µm between them walks as it should (the coated face reflects everything).
#[test]
fn a_paraxial_lens_on_a_glass_face_is_refused_by_the_non_sequential_tracers() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let spec = |gap: &str| {
        format!(
            "name = \"t\"\nwavelengths_nm = [450.0, 520.0, 650.0]\nprimary_wavelength_nm = 520.0\nfields_mm = [[0.0, 0.0], [0.0, 0.05]]\n\
             [aperture]\ntype = \"object_space_na\"\nvalue = 0.05\n\
             [[surfaces]]\ntype = \"standard\"\nthickness_mm = 100.0\n\
             [[surfaces]]\ntype = \"paraxial\"\nthickness_mm = {gap}\nfocal_length_mm = 1000.0\nsemi_diameter_mm = 8.0\n\
             [[surfaces]]\ntype = \"standard\"\nstop = true\nthickness_mm = 4.0\nmaterial = \"N-BK7\"\nsemi_diameter_mm = 8.0\n\
             [[surfaces]]\ntype = \"standard\"\nradius_mm = -26.0\nthickness_mm = 95.0\nsemi_diameter_mm = 8.0\n\
             [[surfaces]]\ntype = \"standard\"\nsemi_diameter_mm = 5.0\n"
        )
    };
    std::fs::write(dir.join("px0.toml"), spec("0.0")).unwrap();
    std::fs::write(dir.join("px1.toml"), spec("0.001")).unwrap();
    let base = ["render", "--scene-size", "8", "--planes", "2", "--rays", "4", "--no-mapping", "--ghosts", "1", "--coating", "2=R1"];
    let with = |extra: &[&'static str]| -> Vec<&str> { base.iter().copied().chain(extra.iter().copied()).collect() };
    refused(dir, &with(&["--system", "px0.toml", "--out", "o"]), &["paraxial lens of surface 1 and the face of surface 2 touch"]);
    refused(dir, &["ghosts", "--system", "px0.toml"], &["paraxial lens of surface 1"]);
    let out = ok(dir, &with(&["--system", "px1.toml", "--out", "o1"]));
    assert!(out.contains("main path 0.0000"), "{out}");
    // A fourth prober: a curved face, and the detector, touching a paraxial lens lost light too (a ghost 5 %,
    // the image 24 %, exit 0): refused alike.
    std::fs::write(dir.join("curved.toml"), spec("0.0").replace("stop = true\n", "stop = true\nradius_mm = 40.0\n")).unwrap();
    refused(dir, &["ghosts", "--system", "curved.toml"], &["paraxial lens of surface 1 and the face of surface 2 touch"]);
    let at_image = spec("0.0").replace("thickness_mm = 95.0\nsemi_diameter_mm = 8.0\n", "thickness_mm = 95.0\nsemi_diameter_mm = 8.0\n[[surfaces]]\ntype = \"paraxial\"\nthickness_mm = 0.0\nfocal_length_mm = 1000.0\nsemi_diameter_mm = 8.0\n").replace("thickness_mm = 0.0\nfocal_length_mm = 1000.0\nsemi_diameter_mm = 8.0\n[[surfaces]]\ntype = \"standard\"\nstop", "thickness_mm = 0.001\nfocal_length_mm = 1000.0\nsemi_diameter_mm = 8.0\n[[surfaces]]\ntype = \"standard\"\nstop");
    std::fs::write(dir.join("at_image.toml"), at_image).unwrap();
    refused(dir, &["render", "--system", "at_image.toml", "--scene-size", "8", "--planes", "2", "--rays", "2", "--no-mapping", "--ghosts", "1", "--out", "o2"], &["the detector of surface 5 touch"]);
}
