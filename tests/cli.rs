//! The command line: the interfaces other checks rely on, outputs, and errors (non-zero exit, clear text).
use crate::common;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_diffcassi"))
}

fn run(args: &[&str]) -> Output {
    bin().args(args).output().expect("the binary runs")
}

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("diffcassi-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn csv(path: &Path) -> (Vec<String>, Vec<Vec<String>>) {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines().filter(|l| !l.starts_with('#') && !l.trim().is_empty());
    let header = lines.next().unwrap().split(',').map(String::from).collect();
    (header, lines.map(|l| l.split(',').map(String::from).collect()).collect())
}

#[test]
fn distortion_interface_writes_absolute_positions() {
    let out = tmp("grid.csv");
    let o = run(&["distortion", "--preset", "sp", "--wavelength-nm", "450", "--grid", "13", "--half-width-mm", "2.5", "--csv", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let (h, rows) = csv(&out);
    assert_eq!(rows.len(), 169);
    for c in ["x_field_mm", "y_field_mm", "real_x_mm", "real_y_mm"] {
        assert!(h.iter().any(|x| x == c), "column {c} in {h:?}");
    }
    // Absolute: the on-axis row sits at Zemax's Xref (−0.398348 mm at 450 nm), not at 0.
    let ix = h.iter().position(|c| c == "real_x_mm").unwrap();
    let fx = h.iter().position(|c| c == "x_field_mm").unwrap();
    let fy = h.iter().position(|c| c == "y_field_mm").unwrap();
    let axis = rows.iter().find(|r| r[fx].parse::<f64>().unwrap() == 0.0 && r[fy].parse::<f64>().unwrap() == 0.0).unwrap();
    assert!((axis[ix].parse::<f64>().unwrap() + 0.398348).abs() < 1e-5);
}

#[test]
fn spot_interface_reads_pupil_csv() {
    let pupil = tmp("pupil.csv");
    std::fs::write(&pupil, "# comment line\nidx,px,py,other\n0,0,0,x\n1,0.5,-0.25,y\n2,1,0,z\n").unwrap();
    let out = tmp("spot.csv");
    let o = run(&["spot", "--preset", "ap", "--wavelength-nm", "520", "--field-mm", "2.5,0", "--pupil-csv", pupil.to_str().unwrap(), "--csv", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let (h, rows) = csv(&out);
    assert_eq!(&h[..5], &["px", "py", "x_mm", "y_mm", "status"]);
    assert_eq!(rows.len(), 3);
    assert!(rows.iter().all(|r| r[4] == "ok"));
    assert_eq!(rows[1][0].parse::<f64>().unwrap(), 0.5);
}

/// A spot whose every ray is lost (a grating of 10 lines/µm: its first order cannot propagate at 520 nm) is a
/// warning that says why — the outcome, the surface, the count — and appears in the JSON as `rays_lost`; a
/// `--png` of nothing is refused, nothing written. `trace`, `distortion` and `mapping` say why too.
#[test]
fn spot_says_why_no_ray_arrived() {
    let mut spec = diffcassi::presets::spec("gsp").unwrap();
    let g = spec.surfaces.iter().position(|s| s.grating_lines_per_um.is_some()).unwrap();
    spec.surfaces[g].grating_lines_per_um = Some(10.0.into());
    for s in &mut spec.surfaces {
        for c in [&mut s.decenter_x_mm, &mut s.decenter_y_mm, &mut s.tilt_y_deg].into_iter().flatten() {
            c.driver = diffcassi::spec::Driver::Fixed;
        }
    }
    let sys = tmp("gsp10.toml");
    std::fs::write(&sys, diffcassi::spec::to_toml(&spec).unwrap()).unwrap();
    let (json, png) = (tmp("gsp10_spot.json"), tmp("gsp10_spot.png"));
    let o = run(&["spot", "--system", sys.to_str().unwrap(), "--wavelength-nm", "520", "--field-mm", "0,0", "--pupil", "hexapolar:2", "--json", json.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let e = stderr(&o);
    assert!(e.contains("no ray reached the image") && e.contains(&format!("19 evanescent at surface {g}")) && e.contains("grating order"), "{e}");
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let spot = &v["spots"][0];
    assert_eq!(spot["rays_ok"], 0);
    assert_eq!(spot["rays_lost"], serde_json::json!([{"status": "evanescent", "surface": g, "count": 19}]));
    let o = run(&["spot", "--system", sys.to_str().unwrap(), "--wavelength-nm", "520", "--pupil", "hexapolar:2", "--png", png.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("--png") && stderr(&o).contains("nothing to plot"), "{}", stderr(&o));
    assert!(!png.exists());
    // trace, distortion and mapping say the same: the outcome, the surface, the count.
    let o = run(&["trace", "--system", sys.to_str().unwrap(), "--wavelength-nm", "520", "--field-mm", "0,0", "--pupil", "hexapolar:2"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(out.contains("0 ok, 19 failed") && out.contains(&format!("failed: 19 evanescent at surface {g}")), "{out}");
    let o = run(&["distortion", "--system", sys.to_str().unwrap(), "--wavelength-nm", "520", "--grid", "3"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains(&format!("5 evanescent at surface {g}")), "{}", stderr(&o));
    let npy = tmp("gsp10_map.npy");
    let o = run(&["mapping", "--system", sys.to_str().unwrap(), "--wavelengths-nm", "520", "--height", "4", "--width", "4", "--npy", npy.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("no chief ray reached the image") && stderr(&o).contains(&format!("520 nm: evanescent at surface {g}")), "{}", stderr(&o));
    // A working system loses no ray: `rays_lost` is empty and nothing is said.
    let o = run(&["spot", "--preset", "sp", "--wavelength-nm", "520", "--field-mm", "0,0", "--pupil", "hexapolar:2", "--json", json.to_str().unwrap()]);
    assert!(o.status.success() && !stderr(&o).contains("warning"), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(v["spots"][0]["rays_lost"], serde_json::json!([]));
}

#[test]
fn spot_interface_matches_zemax_export_on_axis() {
    let refdir = match common::reference_dir() {
        Some(d) => d,
        None => return eprintln!("SKIP spot_interface_matches_zemax_export_on_axis: no ../shared"),
    };
    let export = refdir.join("zemax/AP_amici_prism_aligned/ray_positions_wavelength_W2_field_F4.csv");
    let out = tmp("spot_ap.csv");
    let o = run(&["spot", "--preset", "ap", "--wavelength-nm", "520", "--field-mm", "2.5,2.5", "--pupil-csv", export.to_str().unwrap(), "--csv", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let (_, rows) = csv(&out);
    let (_, zemax) = common::zemax_rays(&export);
    assert_eq!(rows.len(), zemax.len());
    for (r, z) in rows.iter().zip(&zemax) {
        let (x, y): (f64, f64) = (r[2].parse().unwrap(), r[3].parse().unwrap());
        assert!((x - z[2]).abs() < 1.5e-4 && (y - z[3]).abs() < 1.5e-4, "ray ({}, {})", z[0], z[1]);
    }
}

#[test]
fn system_file_works_like_the_preset() {
    let spec = tmp("sp.toml");
    let o = run(&["export-spec", "--preset", "sp", "--out", spec.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let a = tmp("a.csv");
    let b = tmp("b.csv");
    assert!(run(&["distortion", "--preset", "sp", "--grid", "5", "--csv", a.to_str().unwrap()]).status.success());
    assert!(run(&["distortion", "--system", spec.to_str().unwrap(), "--grid", "5", "--csv", b.to_str().unwrap()]).status.success());
    assert_eq!(csv(&a).1, csv(&b).1);
}

#[test]
fn mapping_writes_npy() {
    let out = tmp("map.npy");
    let o = run(&["mapping", "--preset", "ap", "--height", "8", "--width", "6", "--wavelengths-nm", "450,650", "--npy", out.to_str().unwrap(), "--f64"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let (shape, data) = diffcassi::io::read_npy_f64(&out).unwrap();
    assert_eq!(shape, vec![8, 6, 2, 2]);
    assert!(data.iter().all(|v| v.is_finite()));
    assert!(out.with_file_name("map_valid.npy").exists());
}

#[test]
fn report_writes_tables_and_plots() {
    let dir = tmp("report");
    let o = run(&["report", "--preset", "ap", "--out", dir.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    for f in ["system.txt", "system.toml", "spots.csv", "spots.png", "distortion_450nm.png", "distortion_520nm.csv", "dispersion.png", "report.json"] {
        assert!(dir.join(f).exists(), "{f}");
    }
}

fn assert_fails(args: &[&str], mentions: &[&str]) {
    let o = run(args);
    assert!(!o.status.success(), "{args:?} should fail");
    assert_ne!(o.status.code(), Some(0));
    let e = stderr(&o);
    assert!(!e.contains("panicked"), "{args:?} panicked: {e}");
    for m in mentions {
        assert!(e.contains(m), "{args:?}: `{e}` should mention `{m}`");
    }
}

#[test]
fn errors_exit_non_zero_with_clear_messages() {
    assert_fails(&["info", "--preset", "xp"], &["unknown preset", "xp"]);
    assert_fails(&["info"], &["--preset"]);
    assert_fails(&["info", "--system", "/nonexistent/s.toml"], &["/nonexistent/s.toml"]);
    let bad = tmp("bad.toml");
    std::fs::write(&bad, "name = 'x'\nsurfaces = [ {").unwrap();
    assert_fails(&["info", "--system", bad.to_str().unwrap()], &["bad.toml", "TOML"]);
    let yml = tmp("bad.yml");
    std::fs::write(&yml, "list_origin: [ [0, 0\n").unwrap();
    assert_fails(&["info", "--system", yml.to_str().unwrap()], &["bad.yml"]);
    assert_fails(&["distortion", "--preset", "sp", "--wavelength-nm", "3000"], &["3000", "N-BK7"]);
    assert_fails(&["spot", "--preset", "sp", "--field-mm", "1;2"], &["--field-mm", "1;2"]);
    assert_fails(&["spot", "--preset", "sp", "--wavelength-nm", "abc"], &["abc"]);
    assert_fails(&["spot", "--preset", "sp", "--pupil", "spiral:3"], &["spiral"]);
    assert_fails(&["distortion", "--preset", "sp", "--half-width-mm", "nan"], &["half width"]);
    let pupil = tmp("pupil_bad.csv");
    std::fs::write(&pupil, "px,py\n0.1,zero\n").unwrap();
    assert_fails(&["spot", "--preset", "sp", "--pupil-csv", pupil.to_str().unwrap()], &["pupil_bad.csv", "zero"]);
    assert_fails(&["nosuchcommand"], &["nosuchcommand"]);
}

#[test]
fn help_reads_well() {
    let o = run(&["--help"]);
    assert!(o.status.success());
    let t = String::from_utf8_lossy(&o.stdout);
    for c in ["info", "trace", "spot", "distortion", "dispersion", "mapping", "report", "bench"] {
        assert!(t.contains(c), "--help lists {c}");
    }
}
