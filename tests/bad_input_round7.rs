//! Bad input, round 7 (30 Nov 2026): three held-out probers (users' lens files against rayoptics,
//! determinism and numerics, the records and pipelines across commands). Each case runs the real binary or
//! the library: what was silently wrong is refused or right, with a message naming the problem.
use std::path::Path;

use crate::cli_run::{ok_cli as ok, refused_cli as refused, run_cli as run};

fn json(p: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap()
}

const CSV_HEADER: &str = "surf,type,comment,radius,thickness,material,semi_diameter,conic,par1,par2,par3,par4,par5";

/// The prescription CSV reader: an empty asphere cell keeps the later terms at their powers (par2 was read
/// as the r² term); an unknown column (a Coordinate Break's order flag in `par6`) and a cell the surface
/// type does not have are refused instead of dropped; a `P` cell without a source is a pickup of unknown
/// source (`P?`), which stops a fit freeing its column (SP's CSV recovered 0.0018° of a 5° tilt) and a
/// `.zmx` export, while glasses and other columns stay free.
#[test]
fn prescription_csv_cells_keep_their_meaning() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let rows = |asph: &str| format!("{CSV_HEADER}\n0,OBJECT Standard,,inf,100,,3,0,,,,,\n1,STOP Even Asphere,,50,5,N-BK7,6,0,{asph}\n2,Standard,,-200,95,,6,0,,,,,\n3,IMAGE Standard,,inf,,,12,0,,,,,\n");
    std::fs::write(dir.join("gap.csv"), rows(",-2e-5,,,")).unwrap();
    std::fs::write(dir.join("zero.csv"), rows("0,-2e-5,,,")).unwrap();
    let gap = diffcassi::spec::load_spec_file(dir.join("gap.csv")).unwrap();
    let zero = diffcassi::spec::load_spec_file(dir.join("zero.csv")).unwrap();
    let coeffs = |s: &diffcassi::spec::SystemSpec| s.surfaces[1].asphere_coefficients.iter().map(|c| c.value).collect::<Vec<_>>();
    assert_eq!(coeffs(&gap), vec![0.0, -2e-5], "par2 is the r⁴ term whether par1 is empty or 0");
    assert_eq!(coeffs(&gap), coeffs(&zero));
    std::fs::write(dir.join("par6.csv"), format!("{CSV_HEADER},par6\n0,OBJECT Standard,,inf,100,,3,0,,,,,,\n1,STOP Standard,,inf,5,,6,0,,,,,,\n2,Coordinate Break,,,0,,,,1,0,10,0,0,1\n3,IMAGE Standard,,inf,,,12,0,,,,,,\n")).unwrap();
    refused(dir, &["info", "--system", "par6.csv"], &["par6.csv", "line 1", "unknown column `par6`"]);
    std::fs::write(dir.join("cbr.csv"), format!("{CSV_HEADER}\n0,OBJECT Standard,,inf,100,,3,0,,,,,\n1,STOP Standard,,inf,5,,6,0,,,,,\n2,Coordinate Break,,25,0,,,,0,0,10,0,0\n3,IMAGE Standard,,inf,,,12,0,,,,,\n")).unwrap();
    refused(dir, &["info", "--system", "cbr.csv"], &["line 4, column `radius`", "Coordinate Break"]);

    std::fs::write(dir.join("sp.csv"), diffcassi::presets::prescription_csv("sp").unwrap()).unwrap();
    let info = ok(dir, &["info", "--system", "sp.csv"]);
    assert!(info.contains("tilt y 30.0000 P?"), "{info}");
    refused(dir, &["calibrate", "--from", "sp.csv", "--observed", "msp", "--free", "s4.tilt_x_deg", "--setup", "small", "--report", "c.json"], &["s4.tilt_x_deg", "surface 14 tilt_x_deg", "unknown_pickup"]);
    refused(dir, &["export-spec", "--system", "sp.csv", "--out", "sp.zmx"], &["pickups of unknown source", "surface 11 tilt_y_deg"]);
    assert!(!dir.join("c.json").exists() && !dir.join("sp.zmx").exists());
    // A glass is no pickup's column: free.
    let set = diffcassi::diff::ParamSet::new(diffcassi::spec::load_spec_file(dir.join("sp.csv")).unwrap(), diffcassi::materials::GlassCatalog::builtin(), vec![diffcassi::diff::Param::parse("glass_nd:N-BK7").unwrap()]);
    assert!(set.is_ok(), "{:?}", set.err());
    // The TOML form round-trips; with the sources given, the fit recovers the tilt as from the preset.
    ok(dir, &["export-spec", "--system", "sp.csv", "--out", "sp.toml"]);
    let toml = std::fs::read_to_string(dir.join("sp.toml")).unwrap();
    assert_eq!(toml.matches("unknown_pickup = true").count(), 3, "{toml}");
    let back = diffcassi::spec::load_spec_file(dir.join("sp.toml")).unwrap();
    assert_eq!(back.unknown_pickups(), vec!["surface 11 tilt_y_deg", "surface 14 tilt_x_deg", "surface 14 tilt_z_deg"]);
    let bad = toml.replacen("unknown_pickup = true", "unknown_pickup = true\nsolve = \"chief_ray\"", 1);
    std::fs::write(dir.join("two.toml"), bad).unwrap();
    refused(dir, &["info", "--system", "two.toml"], &["one driver"]);
    // The presets keep their unsourced P cells fixed (documented): their fits stay available.
    assert!(diffcassi::presets::spec("ap").unwrap().unknown_pickups().is_empty());
}

/// `.zmx` files: a curved object surface was shown and not traced (refused); `GCAT HIKARI` with `GLAS SF10`
/// takes HIKARI's SF10, not the built-in SCHOTT subset's (OpticStudio searches the file's catalogues); a
/// catalogue glass referenced to 25 °C in a 20 °C system is refused (dn/dT is not modelled); classic Mac
/// line ends (CR alone) read.
#[test]
fn zmx_object_glass_catalogue_and_line_ends() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let lens = |obj_curv: &str, gcat: &str, glass: &str| {
        format!("VERS 190513 30 123457\nMODE SEQ\nNAME probe\nUNIT MM X W X CM MR CPMM\nENPD 10\nENVD 2.0E+1 1 0\nGCAT {gcat}\nFTYP 0 0 1 1 0 0 0\nXFLN 0\nYFLN 0\nWAVM 1 0.5876 1\nPWAV 1\nSURF 0\n  CURV {obj_curv}\n  DISZ 100\nSURF 1\n  STOP\n  CURV 0.02\n  DISZ 5\n  GLAS {glass} 0 0 1.5 40 0 0 0 0 0 0\n  DIAM 6 1 0 0 1 \"\"\nSURF 2\n  CURV -0.005\n  DISZ 95\nSURF 3\n  DISZ 0\n")
    };
    std::fs::write(dir.join("curved.zmx"), lens("-0.01", "SCHOTT", "N-BK7")).unwrap();
    refused(dir, &["info", "--system", "curved.zmx"], &["curved.zmx", "surface 0", "radius_mm", "curved object surface is not modelled"]);
    std::fs::write(dir.join("flat.zmx"), lens("0", "SCHOTT", "N-BK7")).unwrap();
    ok(dir, &["info", "--system", "flat.zmx"]);

    std::fs::write(dir.join("hikari.zmx"), lens("0", "HIKARI", "SF10")).unwrap();
    let spec = diffcassi::spec::load_spec_file(dir.join("hikari.zmx")).unwrap();
    let sys = diffcassi::system::SequentialSystem::build(&spec).unwrap();
    let hikari = diffcassi::materials::GlassCatalog::from_entry("builtin:HIKARI").unwrap();
    let want = hikari.get("SF10").unwrap().refractive_index(450.0).unwrap();
    let subset = diffcassi::materials::GlassCatalog::builtin().get("SF10").unwrap().refractive_index(450.0).unwrap();
    assert!((want - subset).abs() > 1e-5, "HIKARI's and SCHOTT's SF10 differ ({want} vs {subset})");
    let got = sys.indices(450.0).unwrap()[1];
    assert_eq!(got, want, "GCAT HIKARI: HIKARI's SF10 (SCHOTT's is {subset})");
    // A subset glass in none of the named catalogues is still found, with a note.
    std::fs::write(dir.join("ohara.zmx"), lens("0", "OHARA", "N-BK7")).unwrap();
    let out = ok(dir, &["import-zmx", "ohara.zmx", "--out", "ohara.toml"]);
    assert!(out.contains("none of the file's catalogues") && out.contains("built-in SCHOTT subset"), "{out}");

    std::fs::create_dir(dir.join("gd")).unwrap();
    std::fs::write(dir.join("gd/MYCAT.AGF"), "NM HOTGLASS 2 0 1.5168 64.17 0 1\nGC\nED 7.1 8.3 2.51 0.0008 0\nCD 1.03961212 0.00600069867 0.231792344 0.0200179144 1.01046945 103.560653\nTD 1.0E-04 0 0 0 0 0.17 25\nLD 0.3 2.5\n").unwrap();
    std::fs::write(dir.join("gd/hot.zmx"), lens("0", "MYCAT", "HOTGLASS")).unwrap();
    refused(dir, &["info", "--system", "gd/hot.zmx"], &["HOTGLASS", "25 °C", "20 °C", "not modelled"]);

    std::fs::write(dir.join("mac.zmx"), lens("0", "SCHOTT", "N-BK7").replace('\n', "\r")).unwrap();
    let a = ok(dir, &["info", "--system", "mac.zmx"]);
    let b = ok(dir, &["info", "--system", "flat.zmx"]);
    assert_eq!(a.replace("mac.zmx", "flat.zmx"), b);
}

/// The render folder names its acquisition (`acquisition_f32le_sha256`): another run's acquisition.exr, or
/// a cube's multi-channel EXR copied in, is refused by `reconstruct` (it reconstructed either, exit 0); a
/// resumed `study` re-renders a scene whose acquisition was replaced; a float NPY mask is taken at the 16-bit
/// steps mask.png holds (the render equals one from that PNG, bit for bit); an f32 render records its tracer
/// as `analytic-f32`.
#[test]
fn render_folders_name_their_acquisition() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let base = ["render", "--preset", "sp", "--scene-size", "8", "--planes", "4", "--rays", "1"];
    let with = |extra: &[&'static str]| {
        let mut a = base.to_vec();
        a.extend_from_slice(extra);
        a
    };
    ok(dir, &with(&["--mask-seed", "1", "--cube", "--out", "r"]));
    ok(dir, &with(&["--mask-seed", "1", "--seed", "7", "--out", "other"]));
    ok(dir, &["reconstruct", "--from", "r", "--iterations", "2", "--out", "rec"]);
    let exr = std::fs::read(dir.join("r/acquisition.exr")).unwrap();
    std::fs::copy(dir.join("other/acquisition.exr"), dir.join("r/acquisition.exr")).unwrap();
    refused(dir, &["reconstruct", "--from", "r", "--iterations", "2", "--out", "rec2"], &["acquisition.exr", "not the acquisition this render wrote", "acquisition_f32le_sha256"]);
    std::fs::copy(dir.join("r/cube.exr"), dir.join("r/acquisition.exr")).unwrap();
    refused(dir, &["reconstruct", "--from", "r", "--iterations", "2", "--out", "rec2"], &["acquisition.exr", "no `Y`", "not an acquisition"]);
    assert!(!dir.join("rec2").exists());
    std::fs::write(dir.join("r/acquisition.exr"), exr).unwrap();
    ok(dir, &["reconstruct", "--from", "r", "--iterations", "2", "--out", "rec2", "--force"]);

    // A float mask: the render equals the one from the mask.png it wrote.
    let vals: Vec<f64> = (0..64).map(|k| ((k * 37 % 64) as f64 / 63.0 * 0.999_999_7).min(1.0)).collect();
    diffcassi::io::write_npy_f64(dir.join("fmask.npy"), &[8, 8], &vals).unwrap();
    ok(dir, &with(&["--mask", "fmask.npy", "--out", "fm"]));
    ok(dir, &with(&["--mask", "fm/mask.png", "--out", "fm2"]));
    let a = diffcassi::io::exr::read_exr(dir.join("fm/acquisition.exr")).unwrap();
    let b = diffcassi::io::exr::read_exr(dir.join("fm2/acquisition.exr")).unwrap();
    assert!(a.channels[0].data.iter().zip(&b.channels[0].data).all(|(x, y)| x.to_bits() == y.to_bits()), "a float NPY mask renders as its mask.png does");

    ok(dir, &with(&["--precision", "f32", "--out", "f32"]));
    assert_eq!(json(&dir.join("f32/render.json"))["tracer"], "analytic-f32");
    let rec = ok(dir, &["reconstruct", "--from", "f32", "--iterations", "2", "--out", "rf32"]);
    assert_eq!(json(&dir.join("rf32/reconstruct.json"))["tracer"], "analytic-f32", "{rec}");
    assert_eq!(json(&dir.join("r/render.json"))["tracer"], "analytic-f64");

    // A study resumed after one scene's acquisition was replaced renders that scene again.
    let study = ["study", "--presets", "sp", "--operators", "shift", "--solvers", "gap-tv", "--synthetic", "2", "--scene-size", "12", "--bands", "450:650:4", "--planes", "4", "--rays", "1", "--iterations", "2", "--out", "st"];
    ok(dir, &study);
    let s0 = dir.join("st/renders/sp/synthetic00/acquisition.exr");
    let own = std::fs::read(&s0).unwrap();
    std::fs::copy(dir.join("st/renders/sp/synthetic01/acquisition.exr"), &s0).unwrap();
    let out = ok(dir, &study);
    assert!(out.contains("rendered 1 scenes"), "{out}");
    assert_eq!(std::fs::read(&s0).unwrap(), own, "re-rendered to the same bytes");
    let sj = json(&dir.join("st/study.json"));
    assert!(sj.to_string().contains("\"fit\":null"), "synthetic scenes record no fit");
}

/// Output folders: a `--force`d reconstruction into a render's folder kept its own set list, so a later
/// plain render there deletes nothing of it; `evaluate --truth` of a render folder, `reconstruct --from` a
/// dataset root and `study --solvers gap-tv,` are refused naming the problem; a value of 1e-30 is written
/// as such in messages, not as 30 zeros.
#[test]
fn output_folders_and_messages() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let base = ["render", "--preset", "sp", "--scene-size", "8", "--planes", "4", "--rays", "1"];
    let mut a = base.to_vec();
    a.extend(["--out", "both"]);
    ok(dir, &a);
    a.truncate(base.len());
    a.extend(["--out", "r1"]);
    ok(dir, &a);
    ok(dir, &["reconstruct", "--from", "r1", "--out", "both", "--force", "--iterations", "2"]);
    let mut b = base.to_vec();
    b.extend(["--seed", "1", "--out", "both"]);
    ok(dir, &b);
    for f in ["cube.npy", "reconstruct.json", "render.json", "acquisition.exr"] {
        assert!(dir.join("both").join(f).is_file(), "{f} kept");
    }
    refused(dir, &["evaluate", "--truth", "r1", "--estimate", "both/cube.npy"], &["r1", "a render folder, not a scene"]);
    ok(dir, &["make-scene", "--synthetic", "0", "--size", "8", "--out", "scenes/a.npy"]);
    ok(dir, &["render-dataset", "--scenes", "scenes", "--preset", "sp", "--scene-size", "8", "--planes", "4", "--rays", "1", "--out", "ds"]);
    refused(dir, &["reconstruct", "--from", "ds", "--out", "x"], &["a render-dataset output", "ds/SCENE"]);
    refused(dir, &["study", "--presets", "sp", "--solvers", "gap-tv,", "--synthetic", "1", "--scene-size", "8", "--out", "st"], &["--solvers", "empty entry"]);
    refused(dir, &["study", "--presets", "sp", "--solvers", "gap-tv,foo", "--synthetic", "1", "--scene-size", "8", "--out", "st"], &["--solvers `gap-tv,foo`", "entry `foo`"]);
    let (_, out) = run(dir, &["render", "--preset", "sp", "--scene-size", "8", "--planes", "2", "--rays", "1", "--tolerance-um", "1e-30", "--out", "t"]);
    assert!(out.contains("1e-30") && !out.contains("0.0000000000"), "{out}");
    refused(dir, &["render", "--preset", "sp", "--scene-size", "8", "--rays", "1", "--bands", "380:2500:4", "--planes", "8", "--out", "g"], &["render plane 0 at 203.333333 nm", "half a band beyond", "N-BK7"]);
    refused(dir, &["render", "--preset", "sp", "--scene-size", "8", "--rays", "1", "--bands", "650,450", "--planes", "2", "--out", "g"], &["--bands"]);
}

/// A closed stdout ends the binary quietly (it panicked with "failed printing to stdout: Broken pipe").
#[test]
fn a_closed_stdout_is_no_panic() {
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_diffcassi"))
        .args(["info", "--preset", "sp"])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    let o = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!err.contains("panicked"), "{err}");
}

/// A scene within the radiance limit whose acquisition exceeds what `reconstruct` accepts is refused by
/// `render`, nothing written (reconstruct refused it afterwards).
#[test]
fn an_acquisition_beyond_the_reconstruct_limit_is_refused_at_render() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let wl: Vec<f64> = (0..8).map(|k| 450.0 + 200.0 * k as f64 / 7.0).collect();
    let cube = vec![3e29f64; 8 * 8 * 8];
    diffcassi::io::write_npy_f64(dir.join("big.npy"), &[8, 8, 8], &cube).unwrap();
    diffcassi::io::write_npy_f64(dir.join("big_wavelengths_nm.npy"), &[8], &wl).unwrap();
    refused(dir, &["render", "--preset", "sp", "--scene", "big.npy", "--scene-size", "8", "--bands", "450:650:8", "--planes", "8", "--rays", "1", "--out", "r"], &["the acquisition reaches", "scale the scene's radiance down"]);
    assert!(!dir.join("r").exists());
}

/// A one-band scene fills every plane with its band's value: now reported as spectral extrapolation (it was
/// never, whatever the planes); a scene spanning the render's bands still is not.
#[test]
fn a_one_band_scene_is_reported_as_extrapolated() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let one = diffcassi::scene::SpectralCube::new(8, 8, vec![520.0], vec![0.5; 64], "test").unwrap();
    diffcassi::scene::save_npy(&one, &dir.join("one.npy")).unwrap();
    let out = ok(dir, &["render", "--preset", "sp", "--scene", "one.npy", "--scene-size", "8", "--bands", "450:650:4", "--planes", "8", "--rays", "1", "--out", "o"]);
    assert!(out.contains("lie beyond the scene's bands (520.0–520.0 nm)"), "{out}");
    assert!(json(&dir.join("o/render.json"))["spectral_extrapolation"]["planes"].as_u64().unwrap() >= 6);
    let full = diffcassi::scene::SpectralCube::new(8, 8, vec![450.0, 516.7, 583.3, 650.0], vec![0.5; 8 * 8 * 4], "test").unwrap();
    diffcassi::scene::save_npy(&full, &dir.join("full.npy")).unwrap();
    let out = ok(dir, &["render", "--preset", "sp", "--scene", "full.npy", "--scene-size", "8", "--bands", "450:650:4", "--planes", "8", "--rays", "1", "--out", "f"]);
    assert!(!out.contains("beyond the scene's bands"), "{out}");
}

/// PnP's record says what ended its TV phase (`tv_phase_stopped_by`: the TV rule's τ, or --tv-warmup) beside
/// what ended the run (it said `stopped_by: iterations` while τ had ended the TV phase); `from` is absolute.
#[test]
fn pnp_records_what_ended_its_tv_phase() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    ok(dir, &["render", "--preset", "sp", "--scene-size", "16", "--planes", "28", "--rays", "1", "--out", "r"]);
    ok(dir, &["reconstruct", "--from", "r", "--solver", "pnp-gap", "--out", "p"]);
    let j = json(&dir.join("p/reconstruct.json"));
    let st = &j["stopping"];
    let by = st["tv_phase_stopped_by"].as_str().unwrap_or_else(|| panic!("{st}"));
    assert!(by == "discrepancy" || by == "iterations", "{st}");
    assert!(st["tv_phase_iterations"].as_u64().is_some(), "{st}");
    ok(dir, &["reconstruct", "--from", "r", "--solver", "pnp-gap", "--tv-warmup", "1", "--out", "p1"]);
    let st = &json(&dir.join("p1/reconstruct.json"))["stopping"];
    assert!(st["tv_phase_iterations"] == 1 || st["tv_phase_stopped_by"] == "discrepancy", "{st}");
    assert!(Path::new(j["from"].as_str().unwrap()).is_absolute(), "{}", j["from"]);
    let (code, out) = run(dir, &["distortion", "--preset", "sp", "--grid", "3"]);
    assert_eq!(code, Some(0), "{out}");
    assert!(out.contains("max distortion") && !out.contains("rays that arrived"), "{out}");
}

/// `reconstruct` rebuilds an Embree render's tracer from render.json (its name did not parse, and the exact
/// operator was silently the analytic tracer's); a tracer name it cannot read is refused, naming the field.
#[test]
fn reconstruct_rebuilds_the_renders_tracer() {
    if !diffcassi::tracer::BackendConfig::available(diffcassi::tracer::Backend::EmbreeUser) {
        return;
    }
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    ok(dir, &["render", "--preset", "sp", "--scene-size", "8", "--planes", "4", "--rays", "1", "--backend", "embree-user", "--out", "r"]);
    assert_eq!(json(&dir.join("r/render.json"))["tracer"], "embree-user,refine=f64");
    ok(dir, &["reconstruct", "--from", "r", "--iterations", "2", "--out", "x"]);
    assert_eq!(json(&dir.join("x/reconstruct.json"))["tracer"], "embree-user,refine=f64");
    let jp = dir.join("r/render.json");
    let mut j = json(&jp);
    j["tracer"] = serde_json::json!("raytracer");
    std::fs::write(&jp, serde_json::to_string_pretty(&j).unwrap()).unwrap();
    refused(dir, &["reconstruct", "--from", "r", "--iterations", "2", "--out", "y"], &["render.json", "field `tracer`", "raytracer", "--backend"]);
}
