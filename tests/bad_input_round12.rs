//! Round 12 (1 Dec 2026): what round 11 left noted, and a twelfth held-out battery. Each case failed before its
//! fix (docs/robustness.md, "round 12").
use crate::cli_run::{ok_cli as ok, run_cli as run};

/// A biconvex singlet (object 100 mm, NA 0.05) in glass `X1` of a catalogue beside the spec (`cat/mine.agf`,
/// N-BK7's Sellmeier coefficients with B1 = `b1`).
const SINGLET_X1: &str = r#"name = "singlet"
wavelengths_nm = [450.0, 520.0, 650.0]
primary_wavelength_nm = 520.0
fields_mm = [[0.0, 0.0], [0.0, 0.05]]
glass_catalogs = ["cat/mine.agf"]
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
material = "X1"
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

fn catalogue(b1: &str) -> String {
    format!("CC test\nNM X1 2 0 1.5168 64.17 0 1\nCD {b1} 0.00600069867 0.231792344 0.0200179144 1.01046945 103.560653\nLD 0.3 2.5\n")
}

/// A spec's relative `glass_catalogs` entry is made absolute on load, so `render-dataset` recorded the absolute
/// path: a project folder moved elsewhere saw "another configuration" and refused to resume, while an edited
/// catalogue at the same path resumed with the old glass. The configuration names a catalogue by its content.
#[test]
fn a_dataset_names_its_glass_catalogues_by_content() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("P");
    std::fs::create_dir_all(p.join("scenes")).unwrap();
    std::fs::create_dir_all(p.join("cat")).unwrap();
    std::fs::write(p.join("cat/mine.agf"), catalogue("1.03961212")).unwrap();
    std::fs::write(p.join("sys.toml"), SINGLET_X1).unwrap();
    for k in 0..2 {
        let v: Vec<f32> = (0..8 * 8 * 3).map(|i| ((i * 7 + k * 3) % 11) as f32 / 11.0).collect();
        diffcassi::io::npy::write_npy_f32(p.join(format!("scenes/s{k}.npy")), &[8, 8, 3], &v).unwrap();
        diffcassi::io::npy::write_npy_f64(p.join(format!("scenes/s{k}_wavelengths_nm.npy")), &[3], &[450.0, 550.0, 650.0]).unwrap();
    }
    let args = ["render-dataset", "--system", "sys.toml", "--scenes", "scenes", "--scene-size", "8", "--bands", "450:650:3", "--planes", "3", "--rays", "2", "--no-mapping", "--out", "ds"];
    ok(&p, &args);
    std::fs::remove_dir_all(p.join("ds/s1")).unwrap();
    let q = d.path().join("Q");
    std::fs::rename(&p, &q).unwrap();
    let out = ok(&q, &args);
    assert!(out.contains("rendered 1 of 1 scenes"), "{out}");
    // The catalogue edited in place: another glass, so another configuration (refused, naming the catalogue).
    std::fs::write(q.join("cat/mine.agf"), catalogue("1.05")).unwrap();
    let (code, text) = run(&q, &args);
    assert_eq!(code, Some(1), "{text}");
    assert!(text.contains("glass_catalogs[0]") && text.contains("mine.agf ("), "{text}");
}
